"""python -m lessons view FILE.rrd --web: Rerun's web viewer served from the installed rerun-sdk (no
network), its address printed once it answers, stopped by Ctrl-C; bad input in one line, exit 2."""
import re
import signal
import socket
import subprocess
import sys
import time
import urllib.parse
import urllib.request

import pytest

from lessons.app.view import web_address
from tests.helpers import start_web_view, write_points_recording


@pytest.fixture(scope="module")
def small_rrd(tmp_path_factory):
    return write_points_recording(tmp_path_factory.mktemp("view") / "points.rrd", steps=5, points=100,
                                  app="elastic_lessons_test_view")


def cli(*args):
    return subprocess.run([sys.executable, "-m", "lessons", "view", *map(str, args)], capture_output=True,
                          text=True, timeout=120)


def test_the_web_viewer_is_served_and_stops_on_ctrl_c(small_rrd):
    proc, match = start_web_view(small_rrd, r"open (http://127\.0\.0\.1:(\d+)/\?url=(\S+))")
    try:
        url, port = match.group(1), int(match.group(2))
        proxy = urllib.parse.unquote(match.group(3))
        grpc_port = int(re.search(r":(\d+)/proxy$", proxy).group(1))
        assert url == web_address("127.0.0.1", port, grpc_port)
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=10) as r:
            assert r.status == 200 and "Rerun" in r.read().decode()
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/re_viewer_bg.wasm", timeout=30) as r:
            assert r.status == 200 and len(r.read()) > 10_000_000   # the viewer itself, from the package
        with socket.create_connection(("127.0.0.1", grpc_port), timeout=5):
            pass   # the recording's proxy listens
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=30)
        assert proc.returncode == 0, err
        assert "stopped: the web viewer is closed" in out
        time.sleep(0.5)
        with pytest.raises(OSError):   # the server went with it
            socket.create_connection(("127.0.0.1", port), timeout=2).close()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_a_port_in_use_is_refused_in_one_line(small_rrd):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        busy = s.getsockname()[1]
        done = cli(small_rrd, "--web", "--port", busy)
    assert done.returncode == 2
    assert done.stderr.strip() == (f"python -m lessons: error: --port {busy} is in use on 127.0.0.1; choose another "
                                   f"(--port 0 picks a free one)")


@pytest.mark.parametrize("make,needle", [
    (lambda d: d / "missing.rrd", "no such recording"),
    (lambda d: (d / "text.rrd").write_text("not a recording\n") and d / "text.rrd", "is not a readable Rerun recording"),
])
def test_a_file_that_is_not_a_recording_is_refused(tmp_path, make, needle):
    done = cli(make(tmp_path), "--web")
    assert done.returncode == 2 and needle in done.stderr and len(done.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize("flag,value", [("--port", 70000), ("--grpc-port", -1)])
def test_ports_out_of_range_are_refused(small_rrd, flag, value):
    done = cli(small_rrd, "--web", flag, value)
    assert done.returncode == 2 and f"{flag} must be in 0..65535 (got {value})" in done.stderr
