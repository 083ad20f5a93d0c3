"""Open a recording in the real Rerun viewer, headless, and look at it.

``HeadlessViewer`` starts an X server of its own (``Xvfb``, on a display number it picks
itself with ``-displayfd``), the viewer that ships with ``rerun-sdk`` on a free port and on
that display (``--renderer vulkan``: Mesa's lavapipe where there is no GPU), connects
``rerun.experimental.ViewerClient`` to it and waits until the recording is loaded and a
first frame is painted::

    from lessons.tools.screenshots import drawn_fraction
    from lessons.tools.viewer import HeadlessViewer

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
from __future__ import annotations

import copy
import os
import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

from .screenshots import drawn_fraction
from .viewer_processes import SETTLE_SIZE, ViewerProcesses, PortTaken, Procs, stop_process
from .viewer_requirements import ViewerUnavailable, check_available

SCENE_CLASSES = ("3D", "2D")
# Components a 3D/2D view does not draw (text and plots), for view_has_data.
_NOT_SPATIAL = ("TextDocument:", "TextLog:", "Scalars:", "SeriesLines:", "SeriesPoints:", "BarChart:",
                "RecordingInfo:", "RecordingProperties:")


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



class HeadlessViewer(ViewerProcesses):
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
        self._procs = Procs()
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
                except PortTaken:
                    stop_process(self._procs.viewer)
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
        procs, self._procs = self._procs, Procs()
        try:
            stop_process(procs.viewer)
        finally:
            stop_process(procs.xvfb)
            if self._scratch is not None:
                shutil.rmtree(self._scratch, ignore_errors=True)
                self._scratch = None

    def __del__(self):
        try:
            self.close()
        except Exception:
            pass


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
        take = lambda: self.client.take_screenshot(max_size=SETTLE_SIZE)  # noqa: E731
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

