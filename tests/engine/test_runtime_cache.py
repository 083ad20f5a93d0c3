"""The offline kernel cache is written when a process exits, so a second process compiles nothing."""
import subprocess
import sys

from tests.helpers import ROOT

SCRIPT = """
from engine import runtime
runtime.init(cache_dir={cache!r})
from engine.scenes import cloth
c = cloth(8)
st = c.model.make_state()
from engine.integrators import Stepper, get
Stepper(c.model, get("symplectic-euler")).step(st, 1e-4, 3)
"""


def test_a_plain_exit_writes_the_kernel_cache(tmp_path):
    cache = tmp_path / "cache"
    r = subprocess.run([sys.executable, "-c", SCRIPT.format(cache=str(cache))], cwd=ROOT, capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    files = [p for p in cache.rglob("*") if p.is_file()]
    assert len(files) >= 3 and any(p.suffix == ".tic" for p in files)
