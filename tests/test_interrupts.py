"""Ctrl-C and SIGTERM during a run: the recording is finalised and readable, the results so
far are written, and the exit code says what happened (130 / 143)."""
import json
import os
import signal
import subprocess
import sys
import time

import pytest

from engine.recorder import summarize
from tests.helpers import ROOT


@pytest.mark.parametrize("sig,code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_signal_during_run_finalises_recording_and_results(tmp_path, sig, code):
    env = dict(os.environ, PYTHONPATH=str(ROOT), ELASTIC_CACHE_DIR=str(ROOT / ".ti_cache"))
    # Stage 1 is quick and produces results; a huge stage-3 run keeps it busy afterwards.
    proc = subprocess.Popen(
        [sys.executable, "-m", "lessons", "run", "rod-waves", "--cfl-steps", "10000000",
         "--record", "r.rrd", "--results", "res.json"],
        cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    seen = []
    deadline = time.time() + 120
    while time.time() < deadline:
        line = proc.stdout.readline()
        seen.append(line)
        if "stage 3/4" in line:
            break
    time.sleep(1.0)
    proc.send_signal(sig)
    out, _ = proc.communicate(timeout=120)
    assert proc.returncode == code, "".join(seen) + out
    assert (tmp_path / "r.rrd").exists() and not list(tmp_path.glob(".*partial*"))
    info = summarize(tmp_path / "r.rrd")
    assert "/stage1/results" in info and "/stage3/narrative" in info
    rows = json.loads((tmp_path / "res.json").read_text())
    assert {r["stage"] for r in rows} >= {1, 2}
    rerun = os.path.join(os.path.dirname(sys.executable), "rerun")
    verify = subprocess.run([rerun, "rrd", "verify", str(tmp_path / "r.rrd")],
                            capture_output=True, text=True)
    assert verify.returncode == 0, verify.stderr
