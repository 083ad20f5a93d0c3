"""``python -m lessons view FILE.rrd [--web]``: open a recording in Rerun's viewer.

Without ``--web`` the desktop viewer opens the file (it needs a display). With ``--web`` the
viewer that comes with rerun-sdk is served over HTTP, for a course server reached through a
browser: ``rerun FILE --serve-web`` hosts the web viewer (its page and WebAssembly, from the
installed package: nothing is fetched from a network) on ``--port`` and the recording on a gRPC
proxy on ``--grpc-port``; once the page answers, the address to open is printed and the
command waits until Ctrl-C (or SIGTERM) stops it, which stops the server. ``--bind`` says on which
address both listen: 127.0.0.1 (default) for this machine only (reach it through an SSH tunnel or
the course server's proxy), 0.0.0.0 for every interface.

Exit codes: 0 stopped by Ctrl-C (or the desktop viewer closed), 1 the viewer could not start
(its last log lines are printed), 2 bad input (a file that is missing or not a readable
recording, a port out of range or in use), each in one line.
"""
from __future__ import annotations

import socket
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.parse
import urllib.request
from pathlib import Path

from .arguments import Parser, UsageError
from .._framework import Terminated
from ..tools.viewer_processes import log_tail, stop_process, unreadable_recording
from ..tools.viewer_requirements import find_rerun

READY_TIMEOUT_S = 60.0   # how long the web viewer may take to answer (the first start unpacks its assets)


def _parser() -> Parser:
    p = Parser(prog="python -m lessons view",
               description="Open a recording in Rerun's viewer: the desktop viewer, or with --web Rerun's web "
                           "viewer served on this machine (its assets come from the installed rerun-sdk).")
    p.add_argument("file", metavar="FILE.rrd", help="the recording (python -m lessons run LESSON writes "
                                                    "recordings/<lesson>.rrd)")
    p.add_argument("--web", action="store_true", help="serve the web viewer over HTTP and print its address "
                                                      "(for a browser; Ctrl-C stops it)")
    p.add_argument("--port", type=int, default=9090, help="HTTP port of the web viewer (default 9090; 0: a free "
                                                          "one)")
    p.add_argument("--grpc-port", type=int, default=9876, help="port of the recording's gRPC proxy (default "
                                                               "9876; 0: a free one)")
    p.add_argument("--bind", default="127.0.0.1", help="address the web viewer and the proxy listen on "
                                                       "(default 127.0.0.1: this machine only; 0.0.0.0: every "
                                                       "interface)")
    return p


def _port(flag: str, value: int, bind: str) -> int:
    """A usable port: ``value`` if it is free on ``bind``, a free one for 0; UsageError otherwise."""
    if not 0 <= value <= 65535:
        raise UsageError(f"{flag} must be in 0..65535 (got {value})")
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((bind, value))
        except OSError as exc:
            if value == 0:
                raise UsageError(f"--bind {bind}: cannot listen there ({exc.strerror})") from None
            raise UsageError(f"{flag} {value} is in use on {bind}; choose another ({flag} 0 picks a free one)") \
                from None
        return s.getsockname()[1]


def _readable(path: Path) -> None:
    if not path.is_file():
        raise UsageError(f"no such recording: {path}")
    problem = unreadable_recording(path)
    if problem:
        raise UsageError(f"{path} is not a readable Rerun recording ({problem}); record it again: python -m lessons "
                         f"run LESSON --record {path}")


def web_address(host: str, port: int, grpc_port: int) -> str:
    """The page to open: the web viewer, told where the recording's proxy is."""
    proxy = f"rerun+http://{host}:{grpc_port}/proxy"
    return f"http://{host}:{port}/?url={urllib.parse.quote(proxy, safe='')}"


def _answers(url: str) -> bool:
    try:
        with urllib.request.urlopen(url, timeout=2) as r:
            return r.status == 200
    except (urllib.error.URLError, OSError):
        return False


def view(argv: list[str], out=sys.stdout, err=sys.stderr) -> int:
    args = _parser().parse_args(argv)
    path = Path(args.file)
    _readable(path)
    rerun = find_rerun()
    if rerun is None:
        print("python -m lessons view: the viewer (rerun-sdk's rerun) is not installed: pip install rerun-sdk",
              file=err, flush=True)
        return 1
    if not args.web:
        return subprocess.call([rerun, str(path)])
    host = "127.0.0.1" if args.bind in ("0.0.0.0", "") else args.bind
    port = _port("--port", args.port, args.bind)
    grpc_port = _port("--grpc-port", args.grpc_port, args.bind)
    if port == grpc_port:
        raise UsageError(f"--port and --grpc-port must differ (both {port})")
    log = tempfile.NamedTemporaryFile(mode="w", prefix="rerun-web-", suffix=".log")   # read only if it fails
    proc = subprocess.Popen([rerun, str(path), "--serve-web", "--web-viewer-port", str(port), "--port",
                             str(grpc_port), "--bind", args.bind], stdout=log, stderr=subprocess.STDOUT,
                            start_new_session=True)
    try:
        page = f"http://{host}:{port}/"
        deadline = time.monotonic() + READY_TIMEOUT_S
        while not _answers(page):
            if proc.poll() is not None or time.monotonic() > deadline:
                stop_process(proc)
                output = " | ".join(log_tail(Path(log.name), 8).splitlines()) or "no output"
                print(f"python -m lessons view: the web viewer did not start ({output})", file=err, flush=True)
                return 1
            time.sleep(0.2)
        print(f"serving {path} with Rerun's web viewer: open {web_address(host, port, grpc_port)}  (Ctrl-C stops it)",
              file=out, flush=True)
        proc.wait()
        print("python -m lessons view: the web viewer stopped by itself", file=err, flush=True)
        return 1
    except (KeyboardInterrupt, Terminated):
        print("stopped: the web viewer is closed", file=out, flush=True)
        return 0
    finally:
        stop_process(proc)   # the server and anything it started (its own process group)
        log.close()

