"""Ctrl-C, SIGTERM and SIGHUP during a run: the recording and the results so far are finalised,
written beside (never over) the complete files of an earlier run and marked partial, and the
exit code says what happened (128 + the signal: 130 / 143 / 129)."""
import os
import signal
import subprocess
import sys
import time

import pytest

from lessons.app.recorder_read import run_status, summarize
from lessons.app.results import read_results
from tests.helpers import ROOT


@pytest.mark.parametrize("sig,code", [(signal.SIGINT, 130), (signal.SIGTERM, 143), (signal.SIGHUP, 129)])
def test_signal_during_run_finalises_partial_output_beside_the_earlier_files(tmp_path, sig, code):
    env = dict(os.environ, PYTHONPATH=str(ROOT), ELASTIC_CACHE_DIR=str(ROOT / ".ti_cache"))
    earlier = {"r.rrd": b"an earlier complete recording", "res.json": b'{"complete": true, "experiments": []}'}
    for name, data in earlier.items():
        (tmp_path / name).write_bytes(data)
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
    time.sleep(0.5)  # inside stage 3's long run
    proc.send_signal(sig)
    out, _ = proc.communicate(timeout=120)
    assert proc.returncode == code, "".join(seen) + out
    for name, data in earlier.items():  # the complete files of the earlier run are untouched
        assert (tmp_path / name).read_bytes() == data
    assert not list(tmp_path.glob(".*partial*"))  # no temporary file left
    info = summarize(tmp_path / "r.partial.rrd")
    assert "/stage1/results" in info and "/stage3/narrative" in info
    status = run_status(tmp_path / "r.partial.rrd")
    assert status["complete"] is False and status["exit_code"] == code
    assert status["stages_requested"] == [1, 2, 3, 4] and status["stages_completed"] == [1, 2]
    doc = read_results(tmp_path / "res.partial.json")
    assert doc["complete"] is False and doc["exit_code"] == code and signal.Signals(sig).name in doc["exit_reason"]
    assert doc["stages_completed"] == {"rod-waves": [1, 2]}
    assert {r["stage"] for r in doc["experiments"]} == {1, 2}
    assert "Traceback" not in out
    rerun = os.path.join(os.path.dirname(sys.executable), "rerun")
    verify = subprocess.run([rerun, "rrd", "verify", str(tmp_path / "r.partial.rrd")],
                            capture_output=True, text=True)
    assert verify.returncode == 0, verify.stderr


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_whose_exception_was_swallowed_stops_the_run_at_the_next_chunk(sig):
    """A signal that lands inside a __del__ (e.g. a Taichi ndarray being freed) has its exception
    printed and dropped by Python; the handler also notes it, and the run loop raises it at the
    next chunk instead of running on."""
    from lessons.app.recorder_null import NullRecorder
    from lessons._framework import Terminated, pending_signal, note_signal
    from lessons._scene import _recorded_run

    class Ctx:
        rec = NullRecorder()

        @staticmethod
        def timed(label, n):
            import contextlib
            return contextlib.nullcontext()

    chunks = []

    def advance(chunk, done):
        chunks.append(done)
        if done == 20:
            note_signal(sig)  # the handler ran, but its exception was swallowed
        return list(range(done + 1, done + chunk + 1)), [0.0] * chunk, [0.0] * chunk

    expected = KeyboardInterrupt if sig == signal.SIGINT else Terminated
    try:
        with pytest.raises(expected):
            _recorded_run(Ctx(), "run", 1e-3, 1000, 10, advance, state=None)
    finally:
        pending_signal.clear()
    assert chunks == [0, 10, 20]
