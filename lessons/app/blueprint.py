"""The layout a recording opens on in the Rerun viewer (its blueprint), and the plan it is made
from. The recorder (:mod:`lessons.app.recorder`) plans what a student sees when the file is
opened: it notes every stage, every run, whether a run drew geometry, where that geometry lies,
which colour scale it used and whether it logged energies or events, and
:meth:`Recorder.blueprint` turns that plan into the viewer's layout (sent with the file on
:meth:`Recorder.close`, and after every stage when streaming live):

- one tab per stage, named "<N>. <title>", opening on the first stage that drew geometry;
- in a tab, one scene view per run that drew geometry, named by the run's label (and its colour
  key), with a camera placed from the run's bounding box (``top``: looking down on the x-y plane,
  for rods and flat sheets; ``front``: looking along +y at a cloth hanging in the x-z plane;
  ``outside``: an oblique eye outside a 3D body); beside it the run's energy plot;
- the stage's narrative (and any other documents it logged), its event log when a run marked
  something (a blow-up and its message), and its results table across the bottom.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import rerun.blueprint as rrb


PROGRESS_TICKS = 1000       # a run's span on the ``progress`` timeline
PLAYBACK_SECONDS = 20.0     # a run plays in this many seconds at the viewer's 1x speed
ENERGY_PLOT_NAME = "{unit}: K · W · E"   # unit: the run's energy unit (RunPlan.energy_unit); colours: ENERGY_KEY
ENERGY_KEY = "energy plots: K kinetic green, W potential blue, E = K + W white"
DRIFT_PLOT_NAME = "(E − E1)/|E1|"
FOV_Y = math.radians(55.0)  # the 3D view's vertical field of view (the viewer's default)


# ------------------------------------------------------------------------------ the plan

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
    energy_unit: str = "J"                # the energies are plotted in this unit (J, mJ, µJ, ...: values of 1 - 1000)
    plot: tuple[str, str] | None = None   # RunView.plot
    has_series: bool = False              # logged a series of its own (scalar_series)
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


def _aspect(run: RunPlan) -> float:
    """Width / height of the run's bounding box as its camera sees it."""
    ext = np.maximum(run.hi - run.lo, 1e-9) if run.lo is not None else np.ones(3)
    if run.camera == "top":
        return float(ext[0] / ext[1])
    if run.camera == "front":
        return float(ext[0] / ext[2])
    return 1.0


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
        own_plot = run.plot is not None and run.has_series
        has_plot = own_plot or (run.energy is not None and run.has_energy)
        # beside its plot, a scene takes the width its body needs at the cell's height (a square cloth
        # needs little of a wide cell), between 60% and 67.5% of the cell: the plot and its (short) title get the rest
        share = min(0.675, max(0.6, 1.1 * (cell_h - 24) * _aspect(run) / cell_w)) if side_by_side else 1.0
        scene_w = cell_w * (share if has_plot else 1.0)
        scene_h = cell_h * (0.7 if (has_plot and not side_by_side) else 1.0) - 24  # title bar
        key = "; ".join(run.keys.values())
        scene = rrb.Spatial3DView(origin=run.entity, name=run.label + (f" · {key}" if key else ""),
                                  eye_controls=_camera(run, scene_w / max(scene_h, 1.0)),
                                  line_grid=rrb.LineGrid3D(visible=run.camera == "outside"))
        if not has_plot:
            cells.append(scene)
            continue
        if own_plot:
            plot = rrb.TimeSeriesView(origin=f"{run.entity}/{run.plot[0]}", name=run.plot[1],
                                      plot_legend=rrb.PlotLegend(visible=False))
        elif run.energy == "drift":
            plot = rrb.TimeSeriesView(origin=f"{run.entity}/energy_change", name=DRIFT_PLOT_NAME,
                                      plot_legend=rrb.PlotLegend(visible=False))
        else:
            plot = rrb.TimeSeriesView(origin=f"{run.entity}/energy", name=ENERGY_PLOT_NAME.format(unit=run.energy_unit),
                                      plot_legend=rrb.PlotLegend(visible=False))
        cells.append(rrb.Horizontal(scene, plot, column_shares=[share, 1.0 - share]) if side_by_side
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
