"""The processes behind :class:`lessons.tools.viewer.HeadlessViewer`: a private X server (Xvfb)
and the Rerun viewer on it, started, watched and stopped, and the ViewerClient connected to it
with a deadline on every call. :class:`ViewerProcesses` is a part of HeadlessViewer, which holds
the state its methods use."""
from __future__ import annotations

import ctypes.util
import json
import os
import re
import select
import signal
import socket
import subprocess
import sys
import threading
import time
import uuid
from dataclasses import dataclass
from pathlib import Path

from .viewer_requirements import APT_INSTALL, ViewerUnavailable, find_rerun

_POINTER_MARGIN = 64  # pixels of X screen right of and below the window, where the pointer waits
SETTLE_SIZE = 480  # longest side of the pictures settle() compares (cheaper than full size)


def unreadable_recording(path: str | os.PathLike) -> str | None:
    """Why ``path`` is not a recording the viewer can show (rerun's own reader fails on it: a
    corrupted, truncated or foreign file; or it holds no data), in one line; None when it reads
    to its end. The viewer itself would only wait for it to load. Reading takes milliseconds per MB."""
    import warnings

    from rerun.chunk import RrdReader
    try:
        with warnings.catch_warnings():  # e.g. "RRD file has no footer/manifest" (a truncated file)
            warnings.simplefilter("ignore")
            chunks = sum(1 for _ in RrdReader(str(path)).stream())
    except Exception as exc:
        text = " ".join(str(exc).split()) or type(exc).__name__
        return re.sub(r"^Failed to read RRD file at .*?: ", "", text)
    return None if chunks else "it holds no data"


class ViewerTimeout(ViewerUnavailable):
    """The viewer stopped answering (a call took longer than ``call_timeout``); it was killed."""


class _Guarded:
    """A ViewerClient whose every call has a deadline. ViewerClient's calls can block forever
    when the other end never answers (seen: a port answered by something that is not a viewer),
    so each call runs in a thread of its own; one that takes longer than ``seconds`` gets the
    viewer killed (which ends the call when the viewer was the one not answering) and raises
    ViewerTimeout, leaving the thread behind if it still hangs. Waiting this way also keeps
    Ctrl-C working during a call."""

    def __init__(self, client, seconds: float, on_timeout):
        self._client, self._seconds, self._on_timeout = client, seconds, on_timeout

    def __getattr__(self, name):
        attr = getattr(self._client, name)
        if not callable(attr):
            return attr

        def call(*args, **kwargs):
            box = {}

            def run():
                try:
                    box["result"] = attr(*args, **kwargs)
                except BaseException as exc:  # handed to the caller
                    box["error"] = exc
            worker = threading.Thread(target=run, name=f"viewer-{name}", daemon=True)
            worker.start()
            worker.join(self._seconds)
            if worker.is_alive():
                self._on_timeout()
                worker.join(5)
                raise ViewerTimeout(f"the Rerun viewer did not answer {name}() within {self._seconds:.0f} s "
                                    "and was stopped")
            if "error" in box:
                raise box["error"]
            return box["result"]
        return call


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def stop_process(proc: subprocess.Popen | None, grace: float = 5.0) -> None:
    """SIGTERM the process's group (it was started in a session of its own), then SIGKILL, and reap it."""
    if proc is None:
        return
    for sig, wait in ((signal.SIGTERM, grace), (signal.SIGKILL, grace)):
        if proc.poll() is not None:
            break
        try:
            os.killpg(proc.pid, sig)
        except (ProcessLookupError, PermissionError):
            try:
                proc.send_signal(sig)
            except ProcessLookupError:
                pass
        try:
            proc.wait(timeout=wait)
        except subprocess.TimeoutExpired:
            continue
    try:
        os.killpg(proc.pid, signal.SIGKILL)  # anything the process left behind in its group
    except (ProcessLookupError, PermissionError):
        pass
    if proc.poll() is None:
        proc.wait(timeout=grace)


def _die_with_parent() -> None:
    """In the child before exec: get SIGTERM when the process that started it dies (Linux), so
    that a killed test run leaves no viewer or Xvfb behind. (Strictly: when the thread that
    started it ends, so start the viewer from a thread that outlives its use.)"""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGTERM, 0, 0, 0)  # PR_SET_PDEATHSIG
    except Exception:
        pass


def _park_pointer(display: str, x: int, y: int) -> bool:
    """Move the X pointer of ``display`` to (x, y) with libX11 (best effort)."""
    name = ctypes.util.find_library("X11")
    if name is None:
        return False
    try:
        x11 = ctypes.CDLL(name)
        x11.XOpenDisplay.restype = ctypes.c_void_p
        x11.XOpenDisplay.argtypes = [ctypes.c_char_p]
        x11.XDefaultRootWindow.restype = ctypes.c_ulong
        x11.XDefaultRootWindow.argtypes = [ctypes.c_void_p]
        x11.XWarpPointer.argtypes = [ctypes.c_void_p, ctypes.c_ulong, ctypes.c_ulong, ctypes.c_int, ctypes.c_int,
                                     ctypes.c_uint, ctypes.c_uint, ctypes.c_int, ctypes.c_int]
        x11.XSync.argtypes = [ctypes.c_void_p, ctypes.c_int]
        x11.XCloseDisplay.argtypes = [ctypes.c_void_p]
        dpy = x11.XOpenDisplay(display.encode())
        if not dpy:
            return False
        try:
            x11.XWarpPointer(dpy, 0, x11.XDefaultRootWindow(dpy), 0, 0, 0, 0, x, y)
            x11.XSync(dpy, 0)
        finally:
            x11.XCloseDisplay(dpy)
        return True
    except (OSError, AttributeError):
        return False


_ANSI = re.compile(r"\x1b\[[0-9;]*[A-Za-z]")


def log_tail(path: Path, lines: int = 15) -> str:
    """The last lines of a log, colour codes removed; its ERROR/panic lines first if they are earlier."""
    try:
        text = [_ANSI.sub("", line) for line in path.read_text(errors="replace").splitlines()]
    except OSError:
        return ""
    last = text[-lines:]
    errors = [line for line in text[:-lines] if re.search(r"\bERROR\b|panicked|error:", line)][-lines:]
    return "\n".join(errors + (["..."] if errors else []) + last)


@dataclass
class Procs:
    xvfb: subprocess.Popen | None = None
    viewer: subprocess.Popen | None = None



class PortTaken(Exception):
    pass


class ViewerProcesses:
    """HeadlessViewer's X server and viewer processes (its ``size``, ``path``, ``renderer``,
    ``rerun_exe``, ``timeout``, ``call_timeout``, ``_scratch`` and ``_procs``)."""

    def _start_xvfb(self) -> None:
        # The screen is a little larger than the window (which the viewer puts at 0,0) and the
        # pointer is parked in that margin: Xvfb starts it mid-screen, where egui would take it
        # for a hover (plot legends and tooltips in the pictures).
        w, h = self.size[0] + _POINTER_MARGIN, self.size[1] + _POINTER_MARGIN
        read_fd, write_fd = os.pipe()
        log = open(self._scratch / "xvfb.log", "wb")
        try:
            self._procs.xvfb = subprocess.Popen(
                ["Xvfb", "-displayfd", str(write_fd), "-screen", "0", f"{w}x{h}x24", "-nolisten", "tcp",
                 "-noreset"],
                stdin=subprocess.DEVNULL, stdout=log, stderr=log, pass_fds=(write_fd,), start_new_session=True,
                preexec_fn=_die_with_parent if sys.platform.startswith("linux") else None)
        except OSError as exc:
            os.close(read_fd)
            raise ViewerUnavailable(f"cannot start Xvfb ({exc}). Install with: {APT_INSTALL}") from exc
        finally:
            os.close(write_fd)
            log.close()
        number = b""
        deadline = time.monotonic() + 20
        try:
            while not number.endswith(b"\n") and time.monotonic() < deadline:
                ready, _, _ = select.select([read_fd], [], [], 0.2)
                if ready:
                    chunk = os.read(read_fd, 64)
                    if not chunk:
                        break
                    number += chunk
                elif self._procs.xvfb.poll() is not None:
                    break
        finally:
            os.close(read_fd)
        if not number.strip().isdigit():
            raise ViewerUnavailable("Xvfb did not start: " + (log_tail(self._scratch / "xvfb.log") or "no output")
                                    + f". Install with: {APT_INSTALL}")
        self.display = ":" + number.strip().decode()
        _park_pointer(self.display, self.size[0] + _POINTER_MARGIN // 2, self.size[1] + _POINTER_MARGIN // 2)

    def _viewer_env(self) -> dict:
        env = dict(os.environ)
        home = self._scratch / "home"
        for sub in ("data", "config", "cache", "runtime"):
            (home / sub).mkdir(parents=True, exist_ok=True)
        (home / "runtime").chmod(0o700)
        # A fresh home would make every run the viewer's "first session" (with its analytics
        # banner); say analytics are off instead, as `rerun analytics disable` writes it.
        (home / "config" / "rerun").mkdir(exist_ok=True)
        config = home / "config" / "rerun" / "analytics.json"
        config.write_text(json.dumps({"analytics_enabled": False, "analytics_id": uuid.uuid4().hex, "metadata": {},
                                      "config_file_path": str(config),
                                      "data_dir_path": str(home / "data" / "rerun" / "analytics")}))
        env.update(DISPLAY=self.display, HOME=str(home), XDG_DATA_HOME=str(home / "data"),
                   XDG_CONFIG_HOME=str(home / "config"), XDG_CACHE_HOME=str(home / "cache"),
                   XDG_RUNTIME_DIR=str(home / "runtime"), NO_COLOR="1")
        for var in ("WAYLAND_DISPLAY", "RERUN_CLI_PATH"):
            env.pop(var, None)
        return env

    def _start_viewer(self) -> None:
        exe = find_rerun(self.rerun_exe)
        self.port = _free_port()
        w, h = self.size
        self._viewer_log = self._scratch / f"viewer-{self.port}.log"
        with open(self._viewer_log, "wb") as log:
            self._procs.viewer = subprocess.Popen(
                [exe, "--port", str(self.port), "--renderer", self.renderer, "--window-size", f"{w}x{h}",
                 "--hide-welcome-screen", str(self.path)],
                stdin=subprocess.DEVNULL, stdout=log, stderr=log, env=self._viewer_env(),
                cwd=self._scratch, start_new_session=True,
                preexec_fn=_die_with_parent if sys.platform.startswith("linux") else None)
        self.client = None  # connected in _wait_loaded, once the viewer's server is up

    def _kill_viewer(self) -> None:
        """SIGKILL the viewer's process group (from the watchdog thread; close() reaps it)."""
        proc = self._procs.viewer
        if proc is not None:
            try:
                os.killpg(proc.pid, signal.SIGKILL)
            except (ProcessLookupError, PermissionError):
                pass

    def _viewer_died(self) -> None:
        proc = self._procs.viewer
        if proc is not None and proc.poll() is not None:
            log = log_tail(self._viewer_log, 25)
            # Someone took the port between _free_port() and the viewer binding it: the viewer
            # then streams the recording to whatever listens there and exits 0.
            if re.search(r"already in use|already listening at this address|Another viewer is already running", log):
                raise PortTaken()
            hint = ""
            if re.search(r"No graphics adapter|Adapter selection failed|enumerate_adapters|ERROR_INCOMPATIBLE_DRIVER",
                         log):
                hint = (" (no usable Vulkan adapter: install Mesa's lavapipe, package mesa-vulkan-drivers, "
                        "or a GPU driver)")
            raise ViewerUnavailable(f"the Rerun viewer exited with code {proc.returncode}{hint}. "
                                    f"Its last output:\n{log}\nInstall with: {APT_INSTALL}")

    def _wait_loaded(self, deadline: float) -> None:
        """Until the server answers, the recording is in, nothing is loading, the blueprint
        has its viewport, and a first frame is painted."""
        from rerun.experimental import ViewerClient
        last_error = "no answer"
        while True:
            self._viewer_died()
            if time.monotonic() > deadline:
                raise ViewerUnavailable(f"the Rerun viewer did not load {self.path} within {self.timeout:.0f} s "
                                        f"({last_error}). Its last output:\n{log_tail(self._viewer_log)}")
            try:
                if self.client is None:  # connecting fails ("transport error") until the server is up
                    self.client = _Guarded(ViewerClient, self.call_timeout, self._kill_viewer).connect(
                        f"rerun+http://127.0.0.1:{self.port}/proxy")
                    self.client = _Guarded(self.client, self.call_timeout, self._kill_viewer)
                state = self.client.get_state()
                rec = next((r for r in state.recordings if r.store_id == state.active_recording), None)
                if state.loading:
                    last_error = "still loading: " + "; ".join(s.status for s in state.loading)
                elif rec is None:
                    last_error = "no recording open yet"
                elif not any(t.end is not None for t in rec.timelines):
                    last_error = "the recording has no data yet"
                else:
                    bp = self.client.get_blueprint(store_id=rec.store_id).blueprint
                    if "/viewport" not in bp:
                        last_error = "no blueprint yet"
                    else:
                        self.store_id = rec.store_id
                        break
            except ViewerTimeout:
                raise
            except Exception as exc:  # the server is not up yet
                last_error = f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
            time.sleep(0.25)
        self._viewer_died()
        self.client.take_screenshot(max_size=SETTLE_SIZE)  # returns once a frame is painted
        self._viewer_died()
