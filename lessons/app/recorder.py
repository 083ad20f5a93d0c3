"""Rerun recordings of lesson runs. The only module that imports rerun.

One :class:`Recorder` per lesson run writes one ``.rrd`` file through its own
``rr.RecordingStream`` (never the global stream). The recording is collected in memory and
written by :meth:`Recorder.close` into a temporary file beside the target (created when the
recorder is made, as the proof that the file can be written there), which is then renamed onto
the target (:mod:`lessons.app.outfile`): a crash, a kill or a full disk never leaves a truncated file
under the final name, and never destroys the earlier one. A run that did not complete is written
to ``<stem>.partial.rrd`` and says so in the file (the ``run`` recording property).

The recorder also plans what a student sees when the file is opened: it notes every stage, every
run, whether a run drew geometry, where that geometry lies, which colour scale it used and
whether it logged energies or events, and :meth:`Recorder.blueprint` turns that plan into the
viewer's layout (sent with the file on :meth:`close`, and after every stage when streaming live):

- one tab per stage, named "<N>. <title>", opening on the first stage that drew geometry;
- in a tab, one scene view per run that drew geometry, named by the run's label (and its colour
  key), with a camera placed from the run's bounding box (``top``: looking down on the x-y plane,
  for rods and flat sheets; ``front``: looking along +y at a cloth hanging in the x-z plane;
  ``outside``: an oblique eye outside a 3D body); beside it the run's energy plot;
- the stage's narrative (and any other documents it logged), its event log when a run marked
  something (a blow-up and its message), and its results table across the bottom.

Timelines:
    ``progress``  per mille of the run's span (its planned duration unless the stage gives one):
                  every run of every stage plays over 0..1000, so any tab shows its own runs at
                  the same point of their runs and none has to be found on a long timeline;
    ``sim_time``  simulated seconds since the start of the run (runs overlap);
    ``step``      the time step of the run.

Entity layout (``S`` = ``stage<N>``, ``R`` = run name inside the stage):
    /S/narrative, /S/results, /S/<doc>   markdown TextDocuments, static
    /S/R/...                             the run's geometry (rod, springs, mesh, labels)
    /S/R/energy/{kinetic,potential,total}   Scalars (J), at most ENERGY_SAMPLES per run: the
                                         lowest and highest sample of each bin of steps, so a
                                         curve that oscillates faster than a bin is drawn as
                                         its envelope, not aliased
    /S/R/energy_change/relative          (E - E_1)/|E_1| of the total, for runs about
                                         conservation (``energy="drift"``)
    /S/R/events                          TextLog (blow-ups)

:class:`NullRecorder` has the same methods and does nothing; ``enabled`` is False so
callers can skip building colours and arrays altogether.
"""
from __future__ import annotations

import math
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from .outfile import OutputFile, OutputWriteError

__all__ = ["Recorder", "NullRecorder", "RunView", "strain_colors", "magnitude_colors", "check_writable",
           "summarize", "run_status", "OutputWriteError", "PROGRESS_TICKS", "FRAMES_PER_RUN"]

PROGRESS_TICKS = 1000       # a run's span on the ``progress`` timeline
FRAMES_PER_RUN = 200        # geometry frames a run draws at most (tens per period of a wave)
MIN_FRAMES_PER_RUN = 20     # ... and at least, when its span allows
RUN_GEOMETRY_BYTES = 900_000  # a run's geometry budget (bytes of arrays logged), which sets its frames
ENERGY_SAMPLES = 2000       # energy samples per series and run at most (min and max per bin)
RAW_ENERGY_SAMPLES = 4 * ENERGY_SAMPLES  # samples held before the bin width is fixed
PLAYBACK_SECONDS = 20.0     # a run plays in this many seconds at the viewer's 1x speed
LIVE_PORT = 9876            # the port of the viewer a live recorder spawns (Rerun's default)
CAMERAS = ("top", "front", "outside")
KEYS_DOC = "colour_keys"    # the stage's document listing every run's colour scale
# the energy series: name and colour (the plots name them in their titles, with no legend)
SERIES = {"kinetic": ("kinetic", (90, 200, 90)), "potential": ("potential", (90, 150, 255)),
          "total": ("total", (235, 235, 235)), "relative": ("(E - E1) / |E1|", (255, 190, 60))}
ENERGY_PLOT_NAME = "J: K green · W blue · E white"
DRIFT_PLOT_NAME = "(E − E1) / |E1|: drift of the total energy"
FOV_Y = math.radians(55.0)  # the 3D view's vertical field of view (the viewer's default)


def strain_colors(strain: np.ndarray, scale: float | None = None) -> np.ndarray:
    """Map signed strain to RGB (uint8): blue = compressed, white = rest, red = stretched.

    ``scale`` is the strain that saturates the colour (default: max |strain|).
    """
    s = np.asarray(strain, dtype=np.float64)
    if scale is None:
        scale = float(np.max(np.abs(s))) if s.size else 1.0
    t = np.clip(s / (scale if scale > 0 else 1.0), -1.0, 1.0)
    out = np.empty(s.shape + (3,), dtype=np.float64)
    pos, neg = t >= 0, t < 0
    # white -> red for tension, white -> blue for compression
    out[pos] = np.stack([np.ones(pos.sum()), 1 - t[pos], 1 - t[pos]], axis=-1)
    out[neg] = np.stack([1 + t[neg], 1 + t[neg], np.ones(neg.sum())], axis=-1)
    return (out * 255).astype(np.uint8)


def magnitude_colors(value: np.ndarray, scale: float | None = None) -> np.ndarray:
    """Map a non-negative quantity (e.g. energy density) to a dark-blue -> yellow ramp."""
    v = np.asarray(value, dtype=np.float64)
    if scale is None:
        scale = float(np.max(v)) if v.size else 1.0
    t = np.clip(v / (scale if scale > 0 else 1.0), 0.0, 1.0)[..., None]
    lo, hi = np.array([40, 40, 120.0]), np.array([255, 220, 40.0])
    return (lo + t * (hi - lo)).astype(np.uint8)


def check_writable(path: str | os.PathLike) -> Path:
    """Return the resolved path if a file can be created there; raise OSError otherwise.

    Creates missing parent directories (that is what a user asking for
    ``--record out/run.rrd`` wants) but writes nothing else. The checks are those of
    :meth:`lessons.app.outfile.OutputFile.check` (a regular file or a new name; a name that fits).
    """
    out = OutputFile(path)
    out.check()
    _, missing = out._existing_ancestor()
    try:
        for d in reversed(missing):
            os.mkdir(d)
    except OSError:
        for d in missing:
            try:
                d.rmdir()
            except OSError:
                pass
        raise
    return out.path


# ------------------------------------------------------------------------------ the plan

@dataclass
class RunView:
    """How a run is shown: its view's ``label``, the ``camera`` (one of CAMERAS; default: the
    lesson's), what its energy plot shows (``"split"``: kinetic, potential and total; ``"drift"``:
    the relative change of the total, for runs about conservation; None: no plot) and its ``span``
    on the progress timeline in simulated seconds (default: the run's planned duration; give the
    stage's longest run's to keep runs of different lengths in step)."""

    label: str | None = None
    camera: str | None = None
    energy: str | None = "split"
    span: float | None = None

    def __post_init__(self):
        if self.camera is not None and self.camera not in CAMERAS:
            raise ValueError(f"camera must be one of {CAMERAS} (got {self.camera!r})")
        if self.energy not in ("split", "drift", None):
            raise ValueError(f"energy must be 'split', 'drift' or None (got {self.energy!r})")


@dataclass
class RunPlan:
    """What one run recorded (filled in as it logs)."""

    name: str
    entity: str
    label: str
    camera: str
    energy: str | None
    span: float | None = None
    n_steps: int | None = None
    duration: float | None = None     # planned simulated time (n_steps x dt)
    lo: np.ndarray | None = None      # bounding box of everything drawn
    hi: np.ndarray | None = None
    box0: tuple | None = None         # the first frame's box
    frames: int = 0                   # geometry frames drawn
    aspect: float | None = None       # width/height its camera was placed for (set by the layout)
    frame_bytes: int = 0              # bytes of the first frame's arrays
    has_energy: bool = False
    has_events: bool = False
    keys: dict = field(default_factory=dict)   # quantity -> colour key text
    scales: dict = field(default_factory=dict)  # quantity -> fixed colour scale

    @property
    def has_geometry(self) -> bool:
        return self.frames > 0


@dataclass
class StagePlan:
    index: int
    title: str
    runs: list = field(default_factory=list)
    docs: list = field(default_factory=list)   # markdown entities besides narrative/results
    has_results: bool = False
    events: bool = False                       # a run (or the stage) logged an event

    @property
    def scene_runs(self) -> list:
        return [r for r in self.runs if r.has_geometry]

    @property
    def has_events(self) -> bool:
        return self.events or any(r.has_events for r in self.runs)


def _camera(run: RunPlan, aspect: float) -> rrb.EyeControls3D:
    """An eye that frames the run's bounding box in a view of width/height ``aspect``: looking at
    the box's centre from the camera's direction, as close as lets every corner of the box inside
    the field of view (FOV_Y tall, aspect x as wide), with a 12% margin (the views come out a
    little narrower than the layout assumes when the narrative column is wide)."""
    lo, hi = run.lo, run.hi
    centre = 0.5 * (lo + hi)
    if run.camera == "top":
        direction, up = np.array([0, 0, 1.0]), np.array([0, 1.0, 0])
    elif run.camera == "front":
        direction, up = np.array([0, -1.0, 0]), np.array([0, 0, 1.0])
    else:  # outside: oblique, from the front-right and above
        direction = np.array([0.75, -1.1, 0.7])
        direction /= np.linalg.norm(direction)
        up = np.array([0, 0, 1.0])
    up_v = up - (up @ direction) * direction
    up_v /= np.linalg.norm(up_v)
    right = np.cross(-direction, up_v)
    run.aspect = aspect
    tan = math.tan(FOV_Y / 2)
    corners = np.array(np.meshgrid(*zip(lo, hi))).reshape(3, -1).T - centre
    # a corner o is seen at depth d - o.direction; it fits when |o.up| <= tan * depth and
    # |o.right| <= aspect * tan * depth
    need = np.maximum(np.abs(corners @ up_v) / tan, np.abs(corners @ right) / (tan * max(aspect, 1e-3)))
    distance = float(np.max(1.12 * need + corners @ direction))
    distance = max(distance, 1e-3 + float(np.max(corners @ direction)), 1e-6)
    position = centre + distance * direction
    return rrb.EyeControls3D(kind=rrb.Eye3DKind.Orbital, position=position.tolist(),
                             look_target=centre.tolist(), eye_up=up.tolist())


# Where the grid of scene views sits in a 1600 x 1000 window with the panels collapsed: about
# 1150 x 620 pixels (the narrative column takes the rest of the width, the results the rest of
# the height). Cameras are placed for the cells of that area.
_GRID_W, _GRID_H = 1150.0, 580.0


def _grid_shape(runs: list) -> tuple[int, bool]:
    """(columns, strip): rods and other long flat things go one per row, their plot beside them."""
    n = len(runs)
    extents = [np.maximum(r.hi - r.lo, 1e-9) for r in runs]
    strip = all(r.camera == "top" and e[0] > 3.0 * e[1] for r, e in zip(runs, extents))
    if strip:
        return 1, True
    return (1 if n == 1 else 2 if n <= 6 else 3), False


def stage_view(stage: StagePlan) -> rrb.Container:
    """The tab of one stage (see the module docstring)."""
    origin = f"/stage{stage.index}"
    side = [rrb.TextDocumentView(origin=f"{origin}/narrative", name="narrative")]
    side += [rrb.TextDocumentView(origin=f"{origin}/{d}", name=d.replace("_", " ")) for d in stage.docs]
    if stage.has_events:
        side.append(rrb.TextLogView(origin=origin, name="events (blow-ups and warnings)"))
    side_panel = side[0] if len(side) == 1 else rrb.Vertical(*side, row_shares=[3] + [2] * (len(side) - 1))
    runs = stage.scene_runs
    results = rrb.TextDocumentView(origin=f"{origin}/results", name="results")
    name = f"{stage.index}. {stage.title}"
    if not runs:  # the results take the scenes' place
        return rrb.Horizontal(results, side_panel, column_shares=[3, 1], name=name)
    columns, strip = _grid_shape(runs)
    rows = math.ceil(len(runs) / columns)
    cell_w, cell_h = _GRID_W / columns, _GRID_H / rows
    side_by_side = strip or cell_w > 1.8 * cell_h  # a wide cell: the plot beside the scene, not under it
    cells = []
    for run in runs:
        has_plot = run.energy is not None and run.has_energy
        scene_w = cell_w * (0.675 if (has_plot and side_by_side) else 1.0)
        scene_h = cell_h * (0.7 if (has_plot and not side_by_side) else 1.0) - 24  # title bar
        key = "; ".join(run.keys.values())
        scene = rrb.Spatial3DView(origin=run.entity, name=run.label + (f" · {key}" if key else ""),
                                  eye_controls=_camera(run, scene_w / max(scene_h, 1.0)),
                                  line_grid=rrb.LineGrid3D(visible=run.camera == "outside"))
        if not has_plot:
            cells.append(scene)
            continue
        if run.energy == "drift":
            plot = rrb.TimeSeriesView(origin=f"{run.entity}/energy_change", name=DRIFT_PLOT_NAME,
                                      plot_legend=rrb.PlotLegend(visible=False))
        else:
            plot = rrb.TimeSeriesView(origin=f"{run.entity}/energy", name=ENERGY_PLOT_NAME,
                                      plot_legend=rrb.PlotLegend(visible=False))
        cells.append(rrb.Horizontal(scene, plot, column_shares=[2.7, 1.3]) if side_by_side
                     else rrb.Vertical(scene, plot, row_shares=[2.3, 1]))
    grid = rrb.Grid(*cells, grid_columns=columns)
    left = rrb.Vertical(grid, results, row_shares=[2.4, 1])
    return rrb.Horizontal(left, side_panel, column_shares=[3, 1], name=name)


def lesson_blueprint(stages: list, active: int | None = None) -> rrb.Blueprint:
    """The layout of a recording from its plan (a list of StagePlan): one tab per stage, opening
    on stage ``active`` (default: the first that drew geometry), panels collapsed, the progress
    timeline playing one run in PLAYBACK_SECONDS, looping."""
    if active is None:
        active = next((s.index for s in stages if s.scene_runs), stages[0].index if stages else None)
    tabs = [stage_view(s) for s in stages]
    active_tab = next((i for i, s in enumerate(stages) if s.index == active), 0)
    return rrb.Blueprint(
        rrb.Tabs(*tabs, active_tab=active_tab) if tabs else rrb.Tabs(),
        rrb.TimePanel(timeline="progress", fps=PROGRESS_TICKS / PLAYBACK_SECONDS, play_state="playing",
                      loop_mode="all", state="collapsed"),
        rrb.BlueprintPanel(state="collapsed"), rrb.SelectionPanel(state="collapsed"),
        collapse_panels=True)


# ------------------------------------------------------------------------------ recorders

class NullRecorder:
    """A recorder that records nothing and costs nothing."""

    enabled = False
    path = None

    def __init__(self, *args, **kwargs):
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def stage(self, index: int, title: str, narrative: str) -> None:
        pass

    def run(self, name: str, view: RunView | None = None, n_steps: int | None = None,
            dt: float | None = None, draw_every: int | None = None) -> str:
        return name

    def wants_frame(self, step: int, sim_time: float) -> bool:
        return False

    def frame_spacing(self, n_steps: int) -> int:
        return n_steps or 1

    def colors(self, values, kind: str = "signed", quantity: str = "strain", scale: float | None = None):
        return None

    def set_time(self, step: int, sim_time: float) -> None:
        pass

    def points(self, *args, **kwargs) -> None:
        pass

    def rod(self, *args, **kwargs) -> None:
        pass

    def line_strips(self, *args, **kwargs) -> None:
        pass

    def springs(self, *args, **kwargs) -> None:
        pass

    def mesh(self, *args, **kwargs) -> None:
        pass

    def labels(self, *args, **kwargs) -> None:
        pass

    def energies(self, *args, **kwargs) -> None:
        pass

    def scalar_series(self, *args, **kwargs) -> None:
        pass

    def markdown(self, *args, **kwargs) -> None:
        pass

    def mark(self, *args, **kwargs) -> None:
        pass

    def close(self, *args, **kwargs) -> None:
        pass


class Recorder(NullRecorder):
    """Writes one lesson's recording to ``path`` (atomically, on :meth:`close`).

    ``title`` names the recording in the viewer; ``camera`` is the default camera of the lesson's
    runs; ``live`` also streams to a Rerun viewer (spawned, or the one at ``live`` if it is a
    ``rerun+http://`` address) that follows the stage being run. ``path`` None with ``live``
    streams only."""

    enabled = True

    def __init__(self, path: str | os.PathLike | None, application_id: str, title: str = "",
                 camera: str = "outside", live: bool | str = False, strict: bool = False):
        super().__init__()
        if camera not in CAMERAS:
            raise ValueError(f"camera must be one of {CAMERAS} (got {camera!r})")
        if path is None:
            self.output = None
        else:
            self.output = path if isinstance(path, OutputFile) else OutputFile(path)
            if self.output.tmp is None:
                self.output.prepare()  # the temporary file beside the target, created now
        self.path = self.output.path if self.output is not None else None
        self.written: Path | None = None  # where close() put the file
        self._rec = rr.RecordingStream(application_id)
        if strict:
            rr.set_strict_mode(True)
        # The file's bytes are collected in memory (a recording is a few MB: its frames and energy
        # samples are bounded per run) and written by close() itself, so that a write error (a
        # full disk) is an OSError here, not a message from the SDK's writer thread, and the
        # earlier file under the final name is kept.
        self._stream = self._rec.binary_stream() if self.output is not None else None
        sinks = [self._stream] if self._stream is not None else []
        self.live = bool(live)
        self.live_error = None  # why streaming to the viewer failed, if it did
        if live:
            url = live if isinstance(live, str) else None
            if url is None:  # a viewer of our own, the one installed beside this Python if there is one
                exe = Path(sys.executable).with_name("rerun")
                rr.spawn(port=LIVE_PORT, connect=False, hide_welcome_screen=True,
                         executable_path=str(exe) if exe.exists() else None)
                url = f"rerun+http://127.0.0.1:{LIVE_PORT}/proxy"
            sinks.append(rr.GrpcSink(url))
        if not sinks:
            raise ValueError("a Recorder needs a path or live=True")
        self._rec.set_sinks(*sinks)
        self.title = title
        if title:
            self._rec.send_recording_name(title)
        self.default_camera = camera
        self.stages: list[StagePlan] = []
        self._prefix = ""
        self._stage = ""
        self._closed = False
        self._static_done: set[str] = set()
        self._frame_bytes = 0         # bytes logged in the current frame
        self._outbox: dict = {}       # entity -> kept energy samples not yet sent
        self._reset_run()

    def _reset_run(self) -> None:
        """The state of the current run, empty: between runs and before the first."""
        self._run = None
        self._frame_tick = -1         # progress tick of the run's last set_time (-1: none yet)
        self._next_target = None      # the progress tick the run's next frame is meant for
        self._chunk_ticks = 0.0       # progress ticks between the moments the run can draw
        self._pending: list = []      # energy samples not yet binned: (step, K, W)
        self._pending_count = 0
        self._energy_width = None     # steps per energy bin, fixed once the run has run long
        self._energy_dt = 0.0
        self._energy_first_total = None

    # --- structure --------------------------------------------------------------
    def stage(self, index: int, title: str, narrative: str) -> None:
        """Start stage ``index``; its narrative goes to /stage<index>/narrative."""
        self._end_stage()
        self._stage = f"stage{index}"
        self._prefix = self._stage
        self.stages.append(StagePlan(index, title))
        self.markdown("narrative", f"# {index}. {title}\n\n{narrative}")
        if self.live:
            self._send_live_layout()

    def run(self, name: str, view: RunView | None = None, n_steps: int | None = None,
            dt: float | None = None, draw_every: int | None = None) -> str:
        """Start a run inside the current stage; returns its entity prefix. ``n_steps`` and ``dt``
        (planned) set its span on the progress timeline unless ``view.span`` does; ``draw_every``:
        the steps between the moments the run can draw (its chunks), so the frames it is asked
        for are the chunk ends nearest to evenly spaced ones."""
        self._end_run()
        view = view or RunView()
        safe = "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in name)
        self._prefix = f"{self._stage}/{safe}" if self._stage else safe
        span = view.span
        if span is None and n_steps and dt:
            span = n_steps * dt
        self._run = RunPlan(name=name, entity=f"/{self._prefix}", label=view.label or name,
                            camera=view.camera or self.default_camera, energy=view.energy,
                            span=span if span and span > 0 else None, n_steps=n_steps,
                            duration=n_steps * dt if n_steps and dt else None)
        self._energy_dt = float(dt or 0.0)
        self._chunk_ticks = (PROGRESS_TICKS * draw_every * dt / self._run.span
                             if draw_every and dt and self._run.span else 0.0)
        if self.stages:
            self.stages[-1].runs.append(self._run)
        if self.live:  # show the runs so far, on this stage's tab
            self._send_live_layout()
        return self._prefix

    def _send_live_layout(self) -> None:
        if self.stages:
            self._rec.send_blueprint(self.blueprint(active=self.stages[-1].index), make_active=True,
                                     make_default=False)

    def _end_run(self) -> None:
        if self._run is not None:
            self._flush_energies(final=True)
            self._close_frame()
        self._reset_run()

    def _end_stage(self) -> None:
        """Finish the current run and write the stage's colour keys, one line per run with any."""
        self._end_run()
        keyed = [r for r in self.stages[-1].runs if r.keys and r.has_geometry] if self.stages else []
        if keyed:
            self.markdown(KEYS_DOC, "Colours, each on a scale fixed for the whole run:\n\n" + "\n".join(
                f"- **{r.label}**: " + "; ".join(r.keys.values()) for r in keyed))

    def _tick(self, sim_time: float, step: int) -> int:
        run = self._run
        if run is None or run.span is None:
            return int(step)
        return int(round(PROGRESS_TICKS * float(sim_time) / run.span))

    def _allowed_frames(self) -> int:
        run = self._run
        if run is None or run.frame_bytes <= 0:
            return FRAMES_PER_RUN
        return int(min(FRAMES_PER_RUN, max(MIN_FRAMES_PER_RUN, RUN_GEOMETRY_BYTES // run.frame_bytes)))

    def wants_frame(self, step: int, sim_time: float) -> bool:
        """Whether a run stepping through ``step`` should draw its geometry now: the first frame,
        then about FRAMES_PER_RUN evenly spaced on the progress timeline (fewer when a frame is
        large: RUN_GEOMETRY_BYTES per run), and the run's last step."""
        run = self._run
        if run is None or run.span is None or self._frame_tick < 0:
            return True
        if run.n_steps is not None and step >= run.n_steps:
            return True
        spacing = PROGRESS_TICKS / self._allowed_frames()
        # the frames are meant for the moments k * spacing; a run draws at the chunk end nearest
        # to the next of them (at most half a chunk early), and skips those it has passed
        reach = self._tick(sim_time, step) + 0.5 * self._chunk_ticks + 1e-9
        if self._next_target is None:
            self._next_target = spacing
        if reach < self._next_target:
            return False
        while self._next_target <= reach:
            self._next_target += spacing
        return True

    def frame_spacing(self, n_steps: int) -> int:
        """The step spacing a run of ``n_steps`` needs to offer FRAMES_PER_RUN frames."""
        return max(1, n_steps // FRAMES_PER_RUN)

    def _path(self, entity: str) -> str:
        return f"/{self._prefix}/{entity}" if self._prefix else f"/{entity}"

    def set_time(self, step: int, sim_time: float) -> None:
        """Set the timelines for the geometry drawn next: ``step`` = steps done in this run."""
        self._close_frame()
        tick = self._tick(sim_time, step)
        self._frame_tick = tick
        self._rec.set_time("progress", sequence=tick)
        self._rec.set_time("sim_time", duration=float(sim_time))
        self._rec.set_time("step", sequence=int(step))

    def _close_frame(self) -> None:
        if self._run is not None and self._frame_bytes:
            if self._run.frames == 0:
                self._run.frame_bytes = self._frame_bytes
                if self._run.lo is not None:
                    self._run.box0 = (self._run.lo.copy(), self._run.hi.copy())
            self._run.frames += 1
            if self.live and self._run.frames == 1:  # its view can be shown now
                self._send_live_layout()
        self._frame_bytes = 0

    def _drew(self, points: np.ndarray, *arrays, frame: bool = True) -> None:
        """Note drawn geometry: its bounding box and (``frame``: it is per-frame data) its bytes in
        this frame."""
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if frame:
            self._frame_bytes += pts.size * 4 + sum(np.asarray(a).nbytes for a in arrays if a is not None) + 1
        run = self._run
        if run is None or pts.size == 0:
            return
        finite = pts[np.all(np.isfinite(pts), axis=1)]
        if finite.size == 0:
            return
        if run.frames == 0:  # the first frame sets the box
            lo, hi = finite.min(axis=0), finite.max(axis=0)
            run.lo = lo if run.lo is None else np.minimum(run.lo, lo)
            run.hi = hi if run.hi is None else np.maximum(run.hi, hi)
            return
        # later frames widen it by what stays within two body sizes of it (a body that moves
        # or sags stays framed; the far-flung nodes of a blow-up do not pull the camera away)
        lo0, hi0 = run.box0 if run.box0 is not None else (run.lo, run.hi)
        c0, size = 0.5 * (lo0 + hi0), float(np.max(hi0 - lo0))
        near = finite[np.all(np.abs(finite - c0) <= 0.5 * (hi0 - lo0) + 2.0 * size, axis=1)]
        if near.size:
            run.lo = np.minimum(run.lo, near.min(axis=0))
            run.hi = np.maximum(run.hi, near.max(axis=0))

    # --- colours ----------------------------------------------------------------
    def colors(self, values, kind: str = "signed", quantity: str = "strain", scale: float | None = None):
        """Colours of ``values`` on the run's fixed scale for ``quantity``: ``scale`` if given,
        else the largest |value| the first time the run shows a non-zero value. ``kind``
        "signed": blue (-scale) / white (0) / red (+scale); "magnitude": dark blue (0) to yellow
        (scale). The scale goes into the run's view name as the colour key."""
        v = np.asarray(values, dtype=np.float64)
        run = self._run
        fixed = run.scales.get(quantity) if run is not None else None
        if fixed is None:
            fixed = scale if scale is not None else (float(np.max(np.abs(v))) if v.size else 0.0)
            if run is not None and fixed > 0:
                run.scales[quantity] = fixed
                run.keys[quantity] = (f"{quantity}: blue −{fixed:.2g} · white 0 · red +{fixed:.2g}"
                                      if kind == "signed" else f"{quantity}: blue 0 → yellow {fixed:.2g}")
        scale_ = fixed if fixed and fixed > 0 else 1.0
        return strain_colors(v, scale_) if kind == "signed" else magnitude_colors(v, scale_)

    # --- geometry ----------------------------------------------------------------
    def points(self, entity: str, positions, colors=None, radii=None, labels=None) -> None:
        pts = np.asarray(positions)
        self._drew(pts, colors)
        self._rec.log(self._path(entity), rr.Points3D(pts, colors=colors, radii=radii, labels=labels))

    def labels(self, entity: str, positions, texts, colors=None) -> None:
        """Text labels at points (e.g. the name of each of several bodies drawn side by side)."""
        pts = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
        self._drew(pts, frame=False)  # framed by the camera, but static: not a frame of the run
        self._rec.log(self._path(entity), rr.Points3D(pts, labels=list(texts), radii=0.0,
                                                      colors=colors if colors is not None else [[230, 230, 230]]),
                      static=True)

    def rod(self, x: np.ndarray, p: np.ndarray, strain_nodes: np.ndarray | None = None,
            gain: float = 1.0, radius: float = 0.004, scale: float | None = None) -> None:
        """Rod nodes at (p_i, 0, 0) (static) coloured by strain on the run's fixed scale, and the
        displacement profile (p_i, gain*u_i, 0) drawn above them."""
        n = x.size
        pts = np.zeros((n, 3))
        pts[:, 0] = p
        colors = self.colors(strain_nodes, "signed", "strain", scale) if strain_nodes is not None else None
        nodes = self._path("rod/nodes")
        if nodes not in self._static_done:  # the nodes stay where they are drawn: only their colours change
            self._rec.log(nodes, rr.Points3D(pts, radii=radius), static=True)
            self._static_done.add(nodes)
        self._drew(pts[[0, -1]], colors)
        if colors is not None:
            self._rec.log(nodes, rr.Points3D.from_fields(colors=colors))
        prof = np.zeros((n, 3))
        prof[:, 0] = p
        prof[:, 1] = gain * (x - p)
        prof = prof[_corners(prof[:, 0], prof[:, 1])]  # drawn the same, smaller
        self._drew(prof)
        self._rec.log(self._path("rod/displacement"),
                      rr.LineStrips3D([prof], colors=[[230, 160, 30]], radii=radius * 0.6))

    def line_strips(self, entity: str, strips, colors=None, radii=None) -> None:
        pts = np.concatenate([np.asarray(s, dtype=np.float64).reshape(-1, 3) for s in strips]) if len(strips) else np.zeros((0, 3))
        self._drew(pts, colors)
        self._rec.log(self._path(entity), rr.LineStrips3D(strips, colors=colors, radii=radii))

    def springs(self, x: np.ndarray, edges: np.ndarray, strain: np.ndarray | None = None,
                entity: str = "springs", scale: float | None = None, radii=None) -> None:
        """Springs as two-point line strips, coloured by strain on the run's fixed scale."""
        segs = np.stack([x[edges[:, 0]], x[edges[:, 1]]], axis=1)
        colors = self.colors(strain, "signed", "strain", scale) if strain is not None else None
        self._drew(segs.reshape(-1, 3), colors)
        self._rec.log(self._path(entity), rr.LineStrips3D(segs, colors=colors, radii=radii))

    def mesh(self, x: np.ndarray, triangles: np.ndarray, vertex_colors=None, entity: str = "mesh") -> None:
        """Triangle mesh; the index buffer is logged once as static, positions per frame."""
        path = self._path(entity)
        if path not in self._static_done:
            self._rec.log(path, rr.Mesh3D.from_fields(triangle_indices=np.asarray(triangles, dtype=np.uint32)),
                          static=True)
            self._static_done.add(path)
        self._drew(np.asarray(x), vertex_colors)
        self._rec.log(path, rr.Mesh3D.from_fields(vertex_positions=np.asarray(x), vertex_colors=vertex_colors))

    # --- scalars and text ---------------------------------------------------------
    def _columns(self, steps: np.ndarray):
        dt = self._energy_dt
        run = self._run
        times = dt * steps
        if run is not None and run.span is not None:
            ticks = np.rint(PROGRESS_TICKS * times / run.span).astype(np.int64)
        else:
            ticks = steps
        return [rr.TimeColumn("progress", sequence=ticks), rr.TimeColumn("sim_time", duration=times),
                rr.TimeColumn("step", sequence=steps)]

    def scalar_series(self, entity: str, values: np.ndarray, steps: np.ndarray) -> None:
        """Scalars at the run's ``steps``, sent as one column (styled once: SERIES)."""
        values = np.asarray(values, dtype=np.float64)
        if values.size == 0:
            return
        path = self._path(entity)
        if path not in self._static_done:
            name, color = SERIES.get(entity.rsplit("/", 1)[-1], (entity.rsplit("/", 1)[-1], (200, 200, 200)))
            self._rec.log(path, rr.SeriesLines(colors=[color], names=[name], widths=[1.5],
                                               aggregation_policy="minmax"), static=True)
            self._static_done.add(path)
        self._rec.send_columns(self._path(entity), indexes=self._columns(np.asarray(steps, dtype=np.int64)),
                               columns=rr.Scalars.columns(scalars=values))

    def energies(self, kinetic, potential, dt: float, first_step: int = 0) -> None:
        """Kinetic and potential energy (J) after steps first_step+1, first_step+2, ...; at most
        ENERGY_SAMPLES per series and run are kept (the lowest and highest of each bin)."""
        kinetic = np.asarray(kinetic, dtype=np.float64)
        potential = np.asarray(potential, dtype=np.float64)
        if kinetic.size == 0:
            return
        if not self._energy_dt:
            self._energy_dt = float(dt)
        steps = first_step + 1 + np.arange(kinetic.size)
        self._pending.append((steps, kinetic, potential))
        self._pending_count += kinetic.size
        if self._run is not None:
            self._run.has_energy = True
        # the first RAW_ENERGY_SAMPLES samples are kept as they are, so a run that stops early
        # (a blow-up) is binned by the steps it ran, not by the steps it planned
        if self._energy_width is None and self._pending_count <= RAW_ENERGY_SAMPLES:
            return
        self._flush_energies(final=False)

    def _bin(self, last_step: int) -> int:
        """Steps per bin: from the run's planned steps once it has run long, else from the steps
        it ran (``last_step``)."""
        if self._energy_width is None:
            run = self._run
            planned = run.n_steps if run is not None and run.n_steps else 0
            n = planned if self._pending_count > RAW_ENERGY_SAMPLES else last_step
            self._energy_width = max(1, math.ceil(2 * max(n, last_step) / ENERGY_SAMPLES))
        return self._energy_width

    def _flush_energies(self, final: bool) -> None:
        if not self._pending:
            if final:
                self._send_energies(True)
            return
        steps = np.concatenate([p[0] for p in self._pending])
        K = np.concatenate([p[1] for p in self._pending])
        W = np.concatenate([p[2] for p in self._pending])
        width = self._bin(int(steps[-1]))
        bins = (steps - 1) // width
        if not final:  # keep the last (maybe incomplete) bin for the next call
            done = bins < bins[-1]
            if not done.any():
                self._pending = [(steps, K, W)]
                return
            self._pending = [(steps[~done], K[~done], W[~done])]
            self._pending_count = int((~done).sum())
            steps, K, W, bins = steps[done], K[done], W[done], bins[done]
        else:
            self._pending = []
            self._pending_count = 0
        total = K + W
        if self._energy_first_total is None:
            self._energy_first_total = float(total[0])
        series = {"energy/kinetic": K, "energy/potential": W, "energy/total": total}
        if self._run is not None and self._run.energy == "drift":
            e0 = self._energy_first_total
            series["energy_change/relative"] = (total - e0) / (abs(e0) if e0 else 1.0)
        for entity, values in series.items():
            keep = _envelope(bins, values) if width > 1 else np.arange(values.size)
            self._outbox.setdefault(entity, []).append((steps[keep], values[keep]))
        self._send_energies(final)

    def _send_energies(self, final: bool) -> None:
        """Send the kept samples in columns of at least 1000 (one chunk each, not one per call)."""
        for entity, parts in list(self._outbox.items()):
            if final or sum(len(p[0]) for p in parts) >= 1000:
                self.scalar_series(entity, np.concatenate([p[1] for p in parts]),
                                   np.concatenate([p[0] for p in parts]))
                del self._outbox[entity]

    def markdown(self, entity: str, text: str, static: bool = True) -> None:
        """A markdown TextDocument under the current stage (not the current run)."""
        path = f"/{self._stage}/{entity}" if self._stage else f"/{entity}"
        self._rec.log(path, rr.TextDocument(text, media_type=rr.MediaType.MARKDOWN), static=static)
        if self.stages:
            st = self.stages[-1]
            if entity == "results":
                st.has_results = True
            elif entity != "narrative" and entity not in st.docs:
                st.docs.append(entity)

    def mark(self, text: str, level: str = "WARN") -> None:
        """A time-stamped event at the current run (e.g. 'blew up here')."""
        self._rec.log(self._path("events"), rr.TextLog(text, level=level))
        if self._run is not None:
            self._run.has_events = True
        if self.stages:
            self.stages[-1].events = True

    # --- layout and lifetime --------------------------------------------------------
    def blueprint(self, active: int | None = None) -> rrb.Blueprint:
        """The viewer layout for what has been recorded so far (see :func:`lesson_blueprint`)."""
        return lesson_blueprint(self.stages, active)

    def close(self, keep: bool = True, active: int | None = None, status: dict | None = None) -> Path | None:
        """Send the layout, flush, and write the file: onto its final name, or (``status`` given
        with ``complete`` False, a run that did not finish) onto ``<stem>.partial.rrd`` unless the
        output was made with ``overwrite_partial``. ``status`` (complete, exit_reason, stages
        asked and completed, ...) is written into the file as the recording property ``run``
        (:func:`run_status` reads it back); a partial recording also says so in its name and in
        a "run status" document in its last stage. ``keep`` False deletes the file instead.
        Returns where the file went (None if nowhere). A write error raises OutputWriteError
        after removing the temporary file: the earlier file is untouched."""
        if self._closed:
            return self.written if keep else None
        self._closed = True
        data = None
        try:
            if status is not None:
                self._send_status(status)
            self._end_stage()
            if self.stages:
                self._rec.send_blueprint(self.blueprint(active), make_active=True, make_default=True)
            try:
                self._rec.flush()
            except RuntimeError as exc:  # the live viewer went away: the file is still finished
                if not self.live:
                    raise
                self.live_error = str(exc)
            self._rec.disconnect()
        finally:
            if self._stream is not None:
                try:
                    data = self._stream.read(flush=False)
                except Exception:  # nothing readable: no file is written (an earlier one is kept)
                    data = None
            if self.output is not None:
                if keep and data is not None:
                    self.output.write_bytes(data)  # raises OutputWriteError (temporary file removed)
                    complete = True if status is None else bool(status.get("complete"))
                    self.written = self.output.commit(complete)
                else:
                    self.output.discard()
        return self.written if keep else None

    def _send_status(self, status: dict) -> None:
        """The run's completeness, as the recording property ``run`` (and, for a run that did not
        complete, in the recording's name and a document in the last stage's tab)."""
        values = {}
        for key, value in status.items():
            if isinstance(value, (list, tuple)):
                value = [str(v) for v in value] if any(not isinstance(v, (int, float)) for v in value) else list(value)
                if not value:
                    continue
            elif value is None:
                continue
            elif not isinstance(value, (bool, int, float, str)):
                value = str(value)
            values[key] = value
        self._rec.send_property("run", rr.AnyValues(**values))
        if not status.get("complete", True):
            done = ", ".join(str(s) for s in status.get("stages_completed") or []) or "none"
            reason = status.get("exit_reason", "did not complete")
            if self.title:
                self._rec.send_recording_name(f"{self.title} (PARTIAL: {reason})")
            if self.stages:
                self.markdown("run_status", f"**This recording is partial**: {reason}. Stages completed: {done} "
                                            f"(asked: {', '.join(str(s) for s in status.get('stages_requested') or [])}).")


def _corners(px: np.ndarray, py: np.ndarray, tol: float = 1e-4) -> np.ndarray:
    """Indices of the points of the polyline (px, py) to draw: all but the inner points of
    stretches at rest (|py| below ``tol`` times the curve's height at the point and both its
    neighbours), so a rod at rest ahead of and behind a pulse is drawn by its ends alone."""
    n = px.size
    if n < 3:
        return np.arange(n)
    height = float(np.max(np.abs(py))) or 1.0
    flat = np.abs(py) <= tol * height
    inner = np.r_[False, flat[:-2] & flat[1:-1] & flat[2:], False]
    return np.flatnonzero(~inner)


def _envelope(bins: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Indices of the lowest and highest value in each bin (in time order)."""
    order = np.lexsort((values, bins))
    b = bins[order]
    first = np.r_[True, b[1:] != b[:-1]]
    last = np.r_[b[1:] != b[:-1], True]
    keep = np.union1d(order[first], order[last])
    return keep


def run_status(path: str | os.PathLike) -> dict | None:
    """The recording property ``run`` written by :meth:`Recorder.close` (complete, exit_reason,
    stages_requested, stages_completed, ...), or None if the file has none."""
    from rerun.chunk import RrdReader

    status = None
    for chunk in RrdReader(str(path)).stream():
        if str(chunk.entity_path) == "/__properties/run":
            for row in chunk.to_record_batch().to_pylist():
                status = {k: (v[0] if isinstance(v, list) and len(v) == 1 and k != "stages_requested"
                              and k != "stages_completed" else v)
                          for k, v in row.items() if not k.startswith("rerun.")}
    return status


def summarize(path: str | os.PathLike) -> dict[str, dict]:
    """Read a recording back: per entity path, its chunk count, row count, whether it has
    static data, and the sorted ``progress`` (and ``step``) values it was logged at. For tests
    and for inspecting a recording without the viewer."""
    from rerun.chunk import RrdReader

    out: dict[str, dict] = {}
    for chunk in RrdReader(str(path)).stream():
        info = out.setdefault(chunk.entity_path, dict(chunks=0, rows=0, static_chunks=0, frames=[], steps=[],
                                                      components=set()))
        batch = chunk.to_record_batch()
        info["chunks"] += 1
        info["rows"] += batch.num_rows
        info["static_chunks"] += int(chunk.is_static)
        info["components"].update(n for n in batch.schema.names if ":" in n)
        if "progress" in batch.schema.names:
            info["frames"].extend(batch.column("progress").to_pylist())
        if "step" in batch.schema.names:
            info["steps"].extend(batch.column("step").to_pylist())
    for info in out.values():
        info["frames"].sort()
        info["steps"].sort()
    return out
