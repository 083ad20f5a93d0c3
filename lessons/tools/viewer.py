"""Open a recording in the real Rerun viewer, headless, and look at it.

``HeadlessViewer`` starts an X server of its own (``Xvfb``, on a display number it picks
itself with ``-displayfd``), the viewer that ships with ``rerun-sdk`` on a free port and on
that display (``--renderer vulkan``: Mesa's lavapipe where there is no GPU), connects
``rerun.experimental.ViewerClient`` to it and waits until the recording is loaded and a
first frame is painted::

    from lessons.tools.viewer import HeadlessViewer, drawn_fraction

    with HeadlessViewer("recordings/bending.rrd", size=(1600, 1000)) as v:
        v.set_time(None, "start")                   # pause (recordings open playing) and settle
        for i, tab in enumerate(v.tabs()):          # the root Tabs container, in order
            v.show_tab(i)                           # and wait until the picture is steady
            for view in v.views():                  # the views in the tab shown
                png = v.screenshot_view(view.id)
                print(tab.name, view.view_class, view.name, view.errors, drawn_fraction(png))
        whole = v.screenshot_window()               # the whole window, PNG at `size`

The viewer fetches a recording's chunks as its views need them, so a picture right after
opening, switching tabs or moving the time cursor can lack data: ``settle()`` retakes small
pictures until two in a row are identical (which never happens while playing, hence pausing).

Everything is found from the viewer's own blueprint and state (tab containers, views, their
classes and reports), never from names the lessons happen to use. Views of tabs that are not
shown cannot be photographed (the viewer answers "not found"), and a view's ``reports`` are
those of the last frame it was drawn in: show its tab first.

The viewer runs with ``HOME`` and ``XDG_*`` pointed at a scratch directory, because it
remembers each application's blueprint edits between runs: without that, what it shows "at
open" would depend on earlier sessions (including this harness's own tab switching).

Requirements (Debian/Ubuntu): ``apt-get install -y xvfb xauth mesa-vulkan-drivers libvulkan1
libxkbcommon-x11-0 libgl1 libegl1``. When something is missing, ``ViewerUnavailable`` says
what. Processes (viewer, Xvfb) are always stopped and reaped on leaving the ``with`` block,
on errors and Ctrl-C too, and get SIGTERM if the Python process dies (PR_SET_PDEATHSIG). A
viewer that stops answering is killed after ``call_timeout`` (ViewerTimeout) instead of
hanging the caller.
"""
from __future__ import annotations

import copy
import ctypes.util
import glob
import io
import json
import os
import re
import select
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

APT_INSTALL = ("apt-get install -y xvfb xauth mesa-vulkan-drivers libvulkan1 libxkbcommon-x11-0 "
               "libgl1 libegl1")
SCENE_CLASSES = ("3D", "2D")
# A pixel is "drawn" when one of its channels differs from the background by more than this
# (0-255). Measured on the viewer's dark theme: the 3D grid lines and the faint plot grid stay
# below it (background 13, grid up to ~55: the lines' antialiased cores reach ~45 over the
# background), meshes, lines, points and text are far above.
DRAWN_TOLERANCE = 48

_POINTER_MARGIN = 64  # pixels of X screen right of and below the window, where the pointer waits
_SETTLE_SIZE = 480  # longest side of the pictures settle() compares (cheaper than full size)
# Components a 3D/2D view does not draw (text and plots), for view_has_data.
_NOT_SPATIAL = ("TextDocument:", "TextLog:", "Scalars:", "SeriesLines:", "SeriesPoints:", "BarChart:",
                "RecordingInfo:", "RecordingProperties:")
_ICD_DIRS = ("/usr/share/vulkan/icd.d", "/etc/vulkan/icd.d", "/usr/local/share/vulkan/icd.d")


class ViewerUnavailable(RuntimeError):
    """The headless viewer cannot run here; the message names what is missing and how to get it."""


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


class Tab(NamedTuple):
    id: str    # blueprint path of the tab's container (or view), e.g. "/container/<uuid>"
    name: str  # the tab's title: its display name, else what the viewer would call it


@dataclass(frozen=True)
class ViewInfo:
    id: str                 # the view id ViewerClient takes (a uuid)
    view_class: str         # "3D", "2D", "TimeSeries", "TextDocument", "TextLog", ...
    name: str
    origin: str
    visible: bool
    reports: tuple = ()     # rerun.experimental.ViewReport: severity "warning"/"error", summary, details
    query: str = ""         # the view's entity query (ViewContents), "" when unknown

    @property
    def is_scene(self) -> bool:
        return self.view_class in SCENE_CLASSES

    @property
    def errors(self) -> list[str]:
        return [r.summary + (f" ({r.details})" if r.details else "") for r in self.reports
                if r.severity == "error"]

    @property
    def warnings(self) -> list[str]:
        return [r.summary + (f" ({r.details})" if r.details else "") for r in self.reports
                if r.severity != "error"]


# --- what is missing -------------------------------------------------------------------------

def find_rerun(rerun_exe: str | os.PathLike | None = None) -> str | None:
    """The viewer binary: the one given, else the native binary inside the ``rerun_cli`` package
    (rather than its Python shim, which would sit between us and the viewer process), else
    ``rerun`` next to this Python or on PATH."""
    if rerun_exe is not None:
        return shutil.which(str(rerun_exe)) or (str(rerun_exe) if Path(rerun_exe).is_file() else None)
    if os.environ.get("RERUN_CLI_PATH") and Path(os.environ["RERUN_CLI_PATH"]).is_file():
        return os.environ["RERUN_CLI_PATH"]
    try:
        import rerun_cli
        native = Path(rerun_cli.__file__).with_name("rerun")
        if native.is_file() and os.access(native, os.X_OK):
            return str(native)
    except ImportError:
        pass
    beside = Path(sys.executable).with_name("rerun")
    if beside.is_file():
        return str(beside)
    return shutil.which("rerun")


def vulkan_icds() -> list[str]:
    """Installed Vulkan drivers (ICD manifests), from VK_ICD_FILENAMES/VK_DRIVER_FILES or the usual dirs."""
    listed = os.environ.get("VK_DRIVER_FILES") or os.environ.get("VK_ICD_FILENAMES")
    if listed:
        return [p for p in listed.split(os.pathsep) if Path(p).is_file()]
    return sorted(p for d in _ICD_DIRS for p in glob.glob(os.path.join(d, "*.json")))


def missing(rerun_exe: str | os.PathLike | None = None) -> list[str]:
    """What the headless viewer needs and this machine lacks (empty when all is there)."""
    lacks = []
    if shutil.which("Xvfb") is None:
        lacks.append("Xvfb (the virtual X server; Debian package xvfb)")
    if find_rerun(rerun_exe) is None:
        lacks.append("the rerun viewer binary (pip package rerun-sdk)")
    if ctypes.util.find_library("vulkan") is None:
        lacks.append("the Vulkan loader libvulkan.so.1 (Debian package libvulkan1)")
    if not vulkan_icds():
        lacks.append("a Vulkan driver: no ICD manifest in " + ", ".join(_ICD_DIRS)
                     + " (Mesa's software driver lavapipe: Debian package mesa-vulkan-drivers)")
    if ctypes.util.find_library("xkbcommon-x11") is None:
        lacks.append("libxkbcommon-x11 (Debian package libxkbcommon-x11-0)")
    return lacks


def check_available(rerun_exe: str | os.PathLike | None = None) -> None:
    lacks = missing(rerun_exe)
    if lacks:
        raise ViewerUnavailable("cannot run the Rerun viewer headless: missing " + "; ".join(lacks)
                                + f". Install with: {APT_INSTALL}")


# --- pictures --------------------------------------------------------------------------------

def decode_png(png: bytes):
    """RGB pixels (H x W x 3 uint8 numpy array) of a PNG."""
    import numpy as np
    from PIL import Image  # Pillow comes with matplotlib, a dependency of the project
    with Image.open(io.BytesIO(png)) as im:
        return np.asarray(im.convert("RGB"))


def background_colour(rgb) -> tuple[int, int, int]:
    """The most common colour of the picture: the view's background."""
    import numpy as np
    flat = rgb.reshape(-1, 3)
    packed = (flat[:, 0].astype(np.uint32) << 16) | (flat[:, 1].astype(np.uint32) << 8) | flat[:, 2]
    values, counts = np.unique(packed, return_counts=True)
    top = int(values[counts.argmax()])
    return (top >> 16) & 255, (top >> 8) & 255, top & 255


def drawn_fraction(png: bytes, tolerance: int = DRAWN_TOLERANCE, margin: int = 2) -> float:
    """Fraction of the pixels (``margin`` pixels at each border left out: the view's frame)
    whose colour differs from the dominant (background) colour by more than ``tolerance`` in
    some channel. An empty 3D view (background and grid) gives about 0; geometry gives its
    share of the picture."""
    import numpy as np
    rgb = decode_png(png)
    if margin and rgb.shape[0] > 2 * margin and rgb.shape[1] > 2 * margin:
        rgb = rgb[margin:-margin, margin:-margin]
    if rgb.size == 0:
        return 0.0
    bg = np.array(background_colour(rgb), dtype=np.int16)
    diff = np.abs(rgb.astype(np.int16) - bg).max(axis=2)
    return float((diff > tolerance).mean())


def png_size(png: bytes) -> tuple[int, int]:
    """(width, height) from the PNG header."""
    if png[:8] != b"\x89PNG\r\n\x1a\n":
        raise ValueError("not a PNG")
    return int.from_bytes(png[16:20], "big"), int.from_bytes(png[20:24], "big")


# --- the viewer ------------------------------------------------------------------------------

def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _stop(proc: subprocess.Popen | None, grace: float = 5.0) -> None:
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


def _tail(path: Path, lines: int = 15) -> str:
    """The last lines of a log, colour codes removed; its ERROR/panic lines first if they are earlier."""
    try:
        text = [_ANSI.sub("", line) for line in path.read_text(errors="replace").splitlines()]
    except OSError:
        return ""
    last = text[-lines:]
    errors = [line for line in text[:-lines] if re.search(r"\bERROR\b|panicked|error:", line)][-lines:]
    return "\n".join(errors + (["..."] if errors else []) + last)


@dataclass
class _Procs:
    xvfb: subprocess.Popen | None = None
    viewer: subprocess.Popen | None = None


class HeadlessViewer:
    """The Rerun viewer on a recording, on a private X display; use as a context manager.

    ``size``: window size in logical points (= pixels here: the display's scale is 1); the Xvfb
    screen is a little larger (the pointer waits outside the window). ``timeout``: seconds to wait for the viewer to come up and load the recording.
    ``renderer``: the viewer's ``--renderer`` (vulkan; lavapipe where there is no GPU).
    ``call_timeout``: seconds one ViewerClient call may take before the viewer is taken for hung
    (killed; ViewerTimeout).
    """

    drawn_fraction = staticmethod(drawn_fraction)

    def __init__(self, path: str | os.PathLike, size: tuple[int, int] = (1600, 1000), *,
                 timeout: float = 90.0, renderer: str = "vulkan",
                 rerun_exe: str | os.PathLike | None = None, call_timeout: float = 60.0):
        self.path = Path(path).resolve()
        self.size = (int(size[0]), int(size[1]))
        self.timeout = timeout
        self.renderer = renderer
        self.rerun_exe = rerun_exe
        self.call_timeout = call_timeout
        self.client = None  # the ViewerClient (every call with a deadline of call_timeout)
        self.store_id: str | None = None
        self.display: str | None = None
        self.port: int | None = None
        self.open_seconds: float | None = None  # how long start() took
        self.settled: bool | None = None  # whether the last settle() saw two identical frames
        self._procs = _Procs()
        self._scratch: Path | None = None

    # -- life cycle --

    def __enter__(self) -> "HeadlessViewer":
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def start(self) -> None:
        if not self.path.is_file():
            raise FileNotFoundError(f"no recording at {self.path}")
        check_available(self.rerun_exe)
        t0 = time.monotonic()
        self._scratch = Path(tempfile.mkdtemp(prefix="elastic-viewer-"))
        try:
            self._start_xvfb()
            for attempt in range(3):  # a port taken between picking and binding: try another
                try:
                    self._start_viewer()
                    self._wait_loaded(t0 + self.timeout)
                    break
                except _PortTaken:
                    _stop(self._procs.viewer)
                    self._procs.viewer = None
                    if attempt == 2:
                        raise ViewerUnavailable("the Rerun viewer could not get a free port (3 tries)")
        except BaseException:
            self.close()
            raise
        self.open_seconds = time.monotonic() - t0

    def close(self) -> None:
        """Stop the viewer and Xvfb (reaping both) and remove the scratch directory; idempotent."""
        self.client = None
        procs, self._procs = self._procs, _Procs()
        try:
            _stop(procs.viewer)
        finally:
            _stop(procs.xvfb)
            if self._scratch is not None:
                shutil.rmtree(self._scratch, ignore_errors=True)
                self._scratch = None

    def __del__(self):
        try:
            self.close()
        except Exception:
            pass

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
            raise ViewerUnavailable("Xvfb did not start: " + (_tail(self._scratch / "xvfb.log") or "no output")
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
            log = _tail(self._viewer_log, 25)
            # Someone took the port between _free_port() and the viewer binding it: the viewer
            # then streams the recording to whatever listens there and exits 0.
            if re.search(r"already in use|already listening at this address|Another viewer is already running", log):
                raise _PortTaken()
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
                                        f"({last_error}). Its last output:\n{_tail(self._viewer_log)}")
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
        self.client.take_screenshot(max_size=_SETTLE_SIZE)  # returns once a frame is painted
        self._viewer_died()

    # -- state --

    def state(self):
        """``ViewerClient.get_state()``: recordings, timelines, views with reports, loading."""
        return self.client.get_state()

    def blueprint(self) -> dict:
        """The recording's blueprint as the viewer holds it (dict keyed by blueprint entity path)."""
        return self.client.get_blueprint(store_id=self.store_id).blueprint

    def timelines(self) -> dict:
        """{name: rerun.experimental.Timeline} of the recording (type and start/end)."""
        rec = next(r for r in self.state().recordings if r.store_id == self.store_id)
        return {t.name: t for t in rec.timelines}

    def play_state(self) -> str:
        """The time panel's play state from the blueprint: "Paused", "Playing" or "Following"."""
        panel = (self.blueprint().get("/time_panel") or {}).get("TimePanelBlueprint") or {}
        return panel.get("play_state", "")

    def current_time(self) -> tuple[str | None, int | None]:
        """(timeline, raw time: sequence number or nanoseconds) of the time cursor."""
        rec = next(r for r in self.state().recordings if r.store_id == self.store_id)
        return rec.current_timeline, rec.current_time

    def pause(self) -> None:
        """Stop playback where the cursor is."""
        self.client.set_time(play_state="paused", recording=self.store_id)

    def logs(self, after: int | None = None):
        """The viewer's own log lines (LogEntry: sequence, level, target, message)."""
        return self.client.get_logs(after)

    # Blueprint paths come in two spellings: "/container/<id>" in the blueprint the viewer makes
    # itself, "container/<id>" (relative) in contents and active_tab of one a recording sends;
    # "contents" may also be a single path instead of a list. Keys are always absolute.

    @staticmethod
    def _key(path: str) -> str:
        return "/" + path.lstrip("/")

    @staticmethod
    def _contents(container: dict) -> list[str]:
        contents = container.get("contents") or []
        return [contents] if isinstance(contents, str) else list(contents)

    def _container(self, bp: dict, path: str | None) -> dict | None:
        return None if path is None else (bp.get(self._key(path)) or {}).get("ContainerBlueprint")

    def _root(self, bp: dict) -> str | None:
        root = ((bp.get("/viewport") or {}).get("ViewportBlueprint") or {}).get("root_container")
        return None if root is None else f"/container/{root}"

    def _tabs_container(self, bp: dict) -> str | None:
        """The root container if it is a Tabs container, else the first Tabs container below it
        (breadth first), else None."""
        queue = [self._root(bp)]
        while queue:
            path = queue.pop(0)
            c = self._container(bp, path)
            if c is None:
                continue
            if c.get("container_kind") == "Tabs":
                return self._key(path)
            queue += [self._key(p) for p in self._contents(c) if self._key(p).startswith("/container/")]
        return None

    def _name(self, bp: dict, path: str) -> str:
        part = bp.get(self._key(path)) or {}
        if "ContainerBlueprint" in part:
            c = part["ContainerBlueprint"]
            return c.get("display_name") or f"{c.get('container_kind', '')} container"
        v = part.get("ViewBlueprint") or {}
        return v.get("display_name") or v.get("space_origin") or self._key(path)

    def _tabs(self, bp: dict) -> list[Tab]:
        tabs = self._tabs_container(bp)
        if tabs is None:
            root = self._root(bp)
            return [Tab(root, self._name(bp, root))] if root else []
        return [Tab(self._key(p), self._name(bp, p)) for p in self._contents(self._container(bp, tabs))]

    def _active(self, bp: dict) -> Tab | None:
        tabs = self._tabs_container(bp)
        all_tabs = self._tabs(bp)
        if tabs is None:
            return all_tabs[0] if all_tabs else None
        active = self._container(bp, tabs).get("active_tab")
        if not active:  # the viewer shows the first tab
            return all_tabs[0] if all_tabs else None
        return next((t for t in all_tabs if t.id == self._key(active)), Tab(self._key(active), "?"))

    def tabs(self) -> list[Tab]:
        """The tabs of the root Tabs container (or of the first Tabs container under the root), in
        order; ids as "/container/<id>" (or "/view/<id>" for a tab that is a single view). A
        layout without tabs is one tab: its root container."""
        return self._tabs(self.blueprint())

    def active_tab(self) -> Tab | None:
        """The tab shown (the Tabs container's active_tab; the first tab when it has none)."""
        return self._active(self.blueprint())

    def active_tab_index(self) -> int | None:
        bp = self.blueprint()
        active, ids = self._active(bp), [t.id for t in self._tabs(bp)]
        return ids.index(active.id) if active is not None and active.id in ids else None

    def show_tab(self, tab: int | str | Tab, settle: bool = True) -> Tab:
        """Make a tab the active one (index, id, name, or Tab) by writing the Tabs container's
        ``active_tab`` in the blueprint; then (``settle``) wait until the window's picture is
        steady, so that its views are drawn and their reports are fresh."""
        bp = self.blueprint()
        tabs_path = self._tabs_container(bp)
        all_tabs = self._tabs(bp)
        if isinstance(tab, int):
            chosen = all_tabs[tab]
        else:
            key = tab.id if isinstance(tab, Tab) else tab
            matches = [t for t in all_tabs if key in (t.id, t.name) or self._key(key) == t.id]
            if not matches:
                raise KeyError(f"no tab {key!r}; tabs: {[t.name for t in all_tabs]}")
            chosen = matches[0]
        if tabs_path is not None and self._active(bp) != chosen:
            new = copy.deepcopy(bp)
            container = new[tabs_path]["ContainerBlueprint"]
            # write the tab the way the container's contents spell it
            container["active_tab"] = next(p for p in self._contents(container) if self._key(p) == chosen.id)
            self.client.set_blueprint(new, store_id=self.store_id)
            if self.active_tab() != chosen:
                raise RuntimeError(f"the viewer did not switch to tab {chosen.name!r}")
        if settle:
            self.settle()
        return chosen

    def _view_paths(self, bp: dict, path: str) -> list[str]:
        path = self._key(path)
        if path.startswith("/view/"):
            return [path]
        return [v for p in self._contents(self._container(bp, path) or {}) for v in self._view_paths(bp, p)]

    def views(self, tab: int | str | Tab | None = None) -> list[ViewInfo]:
        """The views inside a tab (default: the active one), in layout order, with the viewer's
        class, name and reports for each. ``tab="all"``: every view of the blueprint."""
        bp = self.blueprint()
        if tab == "all":
            paths = [p for p in bp if p.startswith("/view/") and p.count("/") == 2]
        else:
            if tab is None:
                chosen = self._active(bp)
            elif isinstance(tab, int):
                chosen = self._tabs(bp)[tab]
            elif isinstance(tab, Tab):
                chosen = tab
            else:
                chosen = next((t for t in self._tabs(bp) if tab in (t.id, t.name) or self._key(tab) == t.id), None)
                if chosen is None:
                    raise KeyError(f"no tab {tab!r}")
            paths = self._view_paths(bp, chosen.id) if chosen else []
        by_id = {v.view_id.replace("-", ""): v for v in self.state().views}
        out = []
        for p in paths:
            vid = p.removeprefix("/view/")
            v = by_id.get(vid.replace("-", ""))
            vb = (bp.get(p) or {}).get("ViewBlueprint") or {}
            query = ((bp.get(p + "/ViewContents") or {}).get("ViewContents") or {}).get("query", "")
            if isinstance(query, list):
                query = "\n".join(query)
            if v is None:  # in the blueprint, not (yet) in the state
                out.append(ViewInfo(vid, vb.get("class_identifier", ""), vb.get("display_name", ""),
                                    vb.get("space_origin", ""), True, (), query))
            else:
                out.append(ViewInfo(v.view_id, v.view_class, v.name, v.origin, v.visible, tuple(v.reports), query))
        return out

    def view_has_data(self, view: ViewInfo) -> bool:
        """Whether the recording holds, under the entities the view's query takes in, the kind of
        data the view shows (TimeSeries: Scalars; TextDocument/TextLog: their text; other
        classes: any component). Read from the recording's schema, so it ignores time: data
        logged after the time cursor counts. The query's exclusions are ignored."""
        want = {"TimeSeries": ("Scalars:",), "TextDocument": ("TextDocument:text",),
                "TextLog": ("TextLog:text",)}.get(view.view_class)
        for root in _query_roots(view.query, view.origin):
            schema = self.client.get_recording_schema(self.store_id, entity_path=root, max_entities=100000)
            for entity in schema.entities:
                for c in entity.components:
                    if want is not None and c.component.startswith(want):
                        return True
                    if want is None and not c.component.startswith(_NOT_SPATIAL):
                        return True
        return False

    # -- time --

    def set_time(self, timeline: str | None, value: int | float | str | None = None, paused: bool = True,
                 settle: bool = True) -> None:
        """Put the time cursor on ``timeline`` (None: the current one) at ``value``: a sequence
        number for a sequence timeline, seconds for a duration or timestamp timeline, or
        "start"/"end" of the timeline's range; ``None`` only switches to the timeline.
        ``paused``: stop playback (else play from there). ``settle``: when paused, wait until
        the picture is steady (the data at that time fetched and drawn)."""
        import numpy as np
        timeline = timeline or self.current_time()[0]
        tl = self.timelines().get(timeline)
        if tl is None:
            raise KeyError(f"no timeline {timeline!r}; timelines: {sorted(self.timelines())}")
        kwargs = {}
        if value is not None:
            if value in ("start", "end"):
                raw = tl.start if value == "start" else tl.end
                if tl.time_type == "sequence":
                    kwargs["sequence"] = int(raw)
                elif tl.time_type == "duration":
                    kwargs["duration"] = np.timedelta64(int(raw), "ns")
                else:
                    kwargs["timestamp"] = np.datetime64(int(raw), "ns")
            elif tl.time_type == "sequence":
                kwargs["sequence"] = int(value)
            elif tl.time_type == "duration":
                kwargs["duration"] = float(value)
            else:
                kwargs["timestamp"] = float(value)
        self.client.set_time(timeline, play_state="paused" if paused else "playing",
                             recording=self.store_id, **kwargs)
        if paused and settle:
            self.settle()

    # -- pictures --

    def screenshot_window(self, settle: bool = False) -> bytes:
        """PNG of the whole viewer window (``size`` pixels, panels and all). ``settle``: first
        wait until the picture stops changing (see settle)."""
        if settle:
            self.settle()
        return self.client.take_screenshot()

    def screenshot_view(self, view_id: str, settle: bool = False) -> bytes:
        """PNG of one view (its contents, without the tab strip above it). The view must be in
        the tab shown (else the viewer answers "not found": RuntimeError naming the view).
        ``settle``: retake until two in a row are the same."""
        take = lambda: self._view_png(view_id)  # noqa: E731
        return _steady(take, time.monotonic() + 30)[0] if settle else take()

    def _view_png(self, view_id: str) -> bytes:
        try:
            return self.client.take_screenshot(view_id)
        except Exception as exc:
            if "not found" in str(exc).lower():
                raise RuntimeError(f"view {view_id} is not on screen (show its tab first)") from exc
            raise

    def settle(self, timeout: float = 30.0, tries: int = 10) -> bool:
        """Wait until the window's picture stops changing: take (downscaled) pictures until two
        in a row are identical, at most ``tries`` or ``timeout`` seconds. The viewer fetches a
        recording's chunks as the views need them, so the first frames after opening, after
        switching tabs or after moving the time cursor can lack data. While playing, the
        picture never settles. Returns whether it settled (also kept as ``self.settled``)."""
        take = lambda: self.client.take_screenshot(max_size=_SETTLE_SIZE)  # noqa: E731
        _, self.settled = _steady(take, time.monotonic() + timeout, tries)
        return self.settled


def _steady(take, deadline: float, tries: int = 10) -> tuple[bytes, bool]:
    """Take pictures until two in a row are identical: (the last one, whether they were)."""
    previous = take()
    for _ in range(tries - 1):
        if time.monotonic() > deadline:
            break
        current = take()
        if current == previous:
            return current, True
        previous = current
    return previous, False


def _query_roots(query: str, origin: str) -> list[str]:
    """The entity paths a view's query includes (``+ $origin/**`` -> origin), as subtree roots."""
    roots = []
    for line in (query or "$origin/**").splitlines():
        line = line.strip()
        if not line or line.startswith("-"):
            continue
        line = line.lstrip("+").strip().replace("$origin", origin.rstrip("/") or "")
        line = line.removesuffix("/**").removesuffix("**") or "/"
        roots.append(line if line.startswith("/") else "/" + line)
    return roots or [origin or "/"]


class _PortTaken(Exception):
    pass
