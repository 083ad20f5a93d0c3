"""Test helpers: run a lesson stage headless, run the CLI in a subprocess."""
import contextlib
import os
import subprocess
import sys
from pathlib import Path

from lessons.app.recorder_null import NullRecorder
from lessons._framework import StageContext, Stepping

ROOT = Path(__file__).resolve().parent.parent


def run_stage(lesson, index, rec=None, stepping=None, used=None, **overrides):
    """Run one stage of a lesson without printing; returns {id: Experiment} (the ids are checked
    to be unique).

    ``stepping``: a lessons._framework.Stepping (or a dict of its fields, e.g.
    dict(integrator="backward-euler")); ``used``: a list that receives the stage's
    "run: integrator" notes."""
    cfg = lesson.config(**overrides)
    if isinstance(stepping, dict):
        stepping = Stepping(**stepping)
    ctx = StageContext(lesson, cfg, rec or NullRecorder(), index, quiet=True, stepping=stepping)
    if rec is not None:
        rec.stage(index, lesson.stages[index - 1].title, lesson.stages[index - 1].narrative)
    experiments = lesson.stages[index - 1].run(ctx)
    if used is not None:
        used.extend(ctx.integrators_used)
    by_id = {e.id: e for e in experiments}
    assert len(by_id) == len(experiments), f"duplicate experiment ids: {[e.id for e in experiments]}"
    return by_id


def assert_unique_ids(stages):
    """The experiment ids of a lesson's stages ({index: {id: Experiment}}) are unique across them."""
    ids = [i for s in stages.values() for i in s]
    assert len(ids) == len(set(ids)), sorted(i for i in set(ids) if ids.count(i) > 1)


def assert_all_passed(experiments):
    failed = [f"{e.id} ({e.claim}): theory {e.theory!r}, measured {e.measured!r}, {e.tolerance_text()}"
              for e in experiments.values() if not e.passed]
    assert not failed, "\n".join(failed)


def cli(*args, cwd, timeout=300, env=None):
    """Run ``python -m lessons ARGS`` in ``cwd``; returns CompletedProcess (text)."""
    full_env = dict(os.environ, PYTHONPATH=str(ROOT), ELASTIC_CACHE_DIR=str(ROOT / ".ti_cache"))
    full_env.update(env or {})
    return subprocess.run([sys.executable, "-m", "lessons", *args], cwd=cwd, capture_output=True,
                          text=True, timeout=timeout, env=full_env)


def main_in(tmp_path, monkeypatch, capture, *argv, stdin=None):
    """lessons.app.cli.main(argv) run in tmp_path (stdin replaced when given); returns (rc, stdout,
    stderr) as ``capture`` (pytest's capsys, or capfd to include what the Rerun SDK printed) saw them."""
    import lessons.app.cli as cli_mod
    monkeypatch.chdir(tmp_path)
    if stdin is not None:
        monkeypatch.setattr(sys, "stdin", stdin)
    rc = cli_mod.main(list(argv))
    captured = capture.readouterr()
    return rc, captured.out, captured.err


def write_points_recording(path, steps: int = 20, points: int = 2000, app: str = "elastic_lessons_test") -> Path:
    """A small recording written by the SDK: ``points`` points over ``steps`` steps of a ``step`` timeline
    (smooth positions, so that it is compressed)."""
    import numpy as np
    import rerun as rr
    rec = rr.RecordingStream(app)
    rec.save(str(path))
    for step in range(steps):
        rec.set_time("step", sequence=step)
        rec.log("points", rr.Points3D(np.linspace(0.0, 1.0 + step, 3 * points).reshape(points, 3)))
    rec.flush()
    rec.disconnect()
    return Path(path)


def free_port() -> int:
    import socket
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextlib.contextmanager
def notebook_asset_server(timeout: float = 60.0):
    """rerun-notebook's own asset server (``python -m rerun_notebook serve``: the widget's JavaScript and
    the viewer's WebAssembly from the installed package) on a free port; yields the widget's address,
    a value for RERUN_NOTEBOOK_ASSET. One server for many kernels: with serve-local each kernel starts
    its own and gzips the 67 MB viewer first (about 3 s)."""
    import time
    import urllib.request
    port = free_port()
    proc = subprocess.Popen([sys.executable, "-m", "rerun_notebook", "serve", "--bind-address", "127.0.0.1",
                             "--port", str(port)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    url = f"http://127.0.0.1:{port}/widget.js"
    try:
        deadline = time.monotonic() + timeout
        while True:
            try:
                urllib.request.urlopen(url, timeout=5).close()
                break
            except OSError:
                if proc.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError(f"rerun-notebook's asset server did not answer at {url}: "
                                       f"{proc.stderr.read().decode(errors='replace')[-500:] if proc.poll() is not None else 'timed out'}")
                time.sleep(0.1)
        yield url
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def start_web_view(rrd, pattern: str):
    """``python -m lessons view RRD --web`` on free ports: (the process, the match of ``pattern`` in the
    line it prints once the page answers). Fails with that line and the server's error output, the
    server stopped, when the line does not match."""
    import re
    proc = subprocess.Popen([sys.executable, "-m", "lessons", "view", str(rrd), "--web", "--port", "0",
                             "--grpc-port", "0"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    line = proc.stdout.readline()   # printed once the page answers
    match = re.search(pattern, line)
    if match is None:
        err = proc.stderr.read() if proc.poll() is not None else ""
        proc.kill()
        proc.communicate()
        raise AssertionError((line, err))
    return proc, match
