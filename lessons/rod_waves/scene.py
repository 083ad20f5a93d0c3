"""The scenes of ``rod-waves``, how their runs are drawn, and what each stage costs.

Three parts, in this order: the builders (the rods and the Gaussian pulses released on them), the
drawing (:func:`simulate`, the rod's runner through the one lesson runner, which draws the rod as it
goes), and the budget and the parameters' limits (each stage's work in node-steps, converted to
time on the reference CPU by ``stage_seconds``, ``BUDGET`` and ``check_work``, the announce line,
and the observations stage 2's speed fits need). The stages that use them are in stages.py.
"""
from __future__ import annotations

import math

import numpy as np

from engine.scenes import Rod
from lessons.views import RunView

from .._budget import ANNOUNCE_S, WORK_BUDGET_S, StageCost, check_stages, time_text
from .._measure import rod_node_strain
from .._scene import simulate as scene_simulate


# ------------------------------------------------------------------ builders

DEFAULT_WIDTH = 0.01       # m: the pulse width sigma unless --width gives one (in node spacings) ...
DEFAULT_SPACINGS = 10      # ... or this many node spacings on grids coarser than DEFAULT_WIDTH / 10


def pulse_width(cfg, h: float) -> float:
    """The pulse width sigma (m): ``--width`` node spacings, or DEFAULT_WIDTH, or DEFAULT_SPACINGS node
    spacings where that is wider (a pulse narrower than about 5 spacings disperses measurably). A width
    fixed in metres, not in spacings, is what converges: the pulse crosses the same 0.5 m, which is more
    spacings on a finer grid, and a pulse of a fixed count of spacings disperses over each of them."""
    if cfg.width is not None:
        return cfg.width * h
    return max(DEFAULT_WIDTH, DEFAULT_SPACINGS * h)


def gaussian(p, center, sigma, amplitude):
    return amplitude * np.exp(-0.5 * ((p - center) / sigma) ** 2)


def gaussian_slope(p, center, sigma, amplitude):
    return -(p - center) / sigma ** 2 * gaussian(p, center, sigma, amplitude)


def uniform_rod(cfg, pinned=()) -> Rod:
    return Rod.uniform(cfg.nodes, 1.0, cfg.E, cfg.rho, pinned)


def varying_rod(cfg, p) -> Rod:
    """A rod whose stiffness and density vary along it."""
    mid = 0.5 * (p[1:] + p[:-1])
    return Rod(p, cfg.E * (1.0 + 0.5 * np.sin(2 * np.pi * mid)), cfg.rho * (1.0 + 0.3 * np.cos(2 * np.pi * mid)))


# ------------------------------------------------------------------ drawing: the rod's runs

def method_label(method: str) -> str:
    """How a run's integrator is noted. The rod's backward Euler is one exact tridiagonal (Thomas)
    solve per step: ``--solver/--tol`` do not apply to it."""
    return "backward-euler (tridiagonal, exact)" if method == "backward-euler" else method


def simulate(ctx, name: str, rod: Rod, state, dt: float, n_steps: int, method: str = "symplectic-euler",
             energy_bound: float | None = None, observe=None, every: int | None = None, fixed: bool = False,
             label: str | None = None, energy: str = "split", interface: float | None = None):
    """Run ``n_steps`` of ``method`` (already chosen: see :func:`stages.scene_method`) through the one
    lesson runner (``lessons._scene.simulate``: the rod's many-steps kernel, one launch per chunk of ``every``
    steps), drawing the rod and calling ``observe(step, t, u)`` after each chunk (and at step 0).
    Returns (kinetic, potential) per step. A blow-up is drawn, marked in the recording and re-raised.
    The run's view is named ``label`` and seen from above (the rod along x, its displacement
    drawn along y, 0.1 m for the pulse amplitude), with a grey line at ``interface`` if given; its
    energy plot is ``energy`` (RunView)."""
    gain = 0.1 / max(ctx.cfg.amplitude, 1e-300)

    marks = []

    def log(rec, st):
        x = st.positions()
        rec.rod(x, rod.p, rod_node_strain(x, rod.p), gain=gain)
        if interface is not None and not marks:  # once: it stays drawn
            marks.append(True)
            rec.line_strips("interface", [[[interface, -0.04, 0.0], [interface, 0.12, 0.0]]],
                            colors=[[150, 150, 150]], radii=0.002)

    on_state = (lambda step, st: observe(step, step * dt, st.displacement(rod))) if observe else None
    _, K, W = scene_simulate(ctx, name, rod, state, dt, n_steps, method, every or ctx.cfg.record_every,
                             energy_bound, observe=on_state, log=log, fixed=fixed, chosen=True,
                             label=method_label(method), view=RunView(label=label or name, camera="top", energy=energy))
    return K, W


STENCIL_WINDOW = 41   # consecutive nodes stage 1's picture shows (the check covers every node)


def draw_stencil_check(rec, rod, p: np.ndarray, u: np.ndarray, accel: np.ndarray, stencil: np.ndarray) -> None:
    """Stage 1's picture (one frame), STENCIL_WINDOW consecutive nodes around the rod's middle drawn
    across the view: above, the test displacement u (a sine plus noise at each node); below, the
    force per mass the engine computes from the energy's gradient (a line through the nodes) and the
    PDE's centred stencil written from the formula (a dot at each node), to one scale: every dot sits
    on the line, node by node."""
    mid = p.size // 2
    at = np.arange(max(1, mid - STENCIL_WINDOW // 2), min(p.size - 1, mid + STENCIL_WINDOW // 2 + 1))
    rec.run("stencil", RunView(label=f"nodes {at[0]}..{at[-1]}: u (top); force / mass from the energy (line) "
                                     "and the PDE's stencil (dots)", camera="top", energy=None))
    rec.set_time(0, 0.0)
    s = (p[at] - p[at[0]]) / (p[at[-1]] - p[at[0]])   # the window across the view
    zero = np.zeros_like(s)
    du = u[at] - u[at].mean()
    u_gain = 0.12 / max(float(np.abs(du).max()), 1e-300)
    a_gain = 0.2 / max(float(np.abs(stencil[at - 1]).max()), 1e-300)
    rec.line_strips("displacement", [np.column_stack([s, 0.3 + u_gain * du, zero])], colors=[[90, 150, 255]],
                    radii=0.003)
    rec.points("displacement_nodes", np.column_stack([s, 0.3 + u_gain * du, zero]), colors=[[90, 150, 255]],
               radii=0.007)
    rec.line_strips("force_per_mass", [np.column_stack([s, -0.15 + a_gain * accel[at], zero])],
                    colors=[[230, 160, 30]], radii=0.003)
    rec.points("stencil", np.column_stack([s, -0.15 + a_gain * stencil[at - 1], zero]), colors=[[240, 240, 240]],
               radii=0.009)
    rec.labels("labels", [[-0.04, 0.3, 0.0], [-0.04, -0.15, 0.0]], ["u", "f/m"])


# ------------------------------------------------------------------ the budget and the parameters' limits

MIN_FIT_POINTS = 3         # observations a speed fit of stage 2 needs (a line through at least three peaks)
WORK_RATE = 1.2e8          # node-steps per second of the rod's kernel on the reference 2-thread CPU
WORK_BUDGET = WORK_BUDGET_S * WORK_RATE  # node-steps a stage may take (the lessons' hour); more is refused
OBSERVATION_WORK = 10.0    # an observation (copy + peak search) costs about this many node-steps per node ...
CHUNK_WORK = 2e5           # ... on top of a launch's fixed cost (about 1.7 ms: its energies copied out, Python)


def _count_between(n_steps: int, every: int, lo: float, hi: float) -> int:
    """How many observation steps (0, every, 2 every, ..., n_steps) lie strictly between lo and hi."""
    every = max(int(every), 1)
    first = max(math.floor(lo / every) + 1, 0)  # index of the first multiple of every above lo
    last = (n_steps - 1) // every  # ... and of the last one below n_steps
    if math.isfinite(hi):
        last = min(last, math.ceil(hi / every) - 1)  # ... below hi
    return max(last - first + 1, 0) + (1 if lo < n_steps < hi else 0)


def _fit_windows(cfg):
    """(n_steps, window lo, window hi) in steps of every speed fit of stage 2 (see stages._pulse_speed and
    stages._dalembert), with h = 1/(nodes - 1)."""
    h = 1.0 / (cfg.nodes - 1)
    nu_left = min(cfg.cfl, 1.0)
    out = [(int(round(0.5 / (nu * h))), 0.05 / (nu * h), 0.45 / (nu * h)) for nu in (0.25, 0.5, 1.0, nu_left)]
    n = int(round(0.4 / (nu_left * h)))
    return out + [(n, 0.1 / (nu_left * h), math.inf)]


def fewest_fit_points(cfg, every: int | None = None) -> int:
    """The fewest observations any speed fit of stage 2 gets at --record-every ``every``."""
    every = cfg.record_every if every is None else every
    return min(_count_between(n, every, lo, hi) for n, lo, hi in _fit_windows(cfg))


def fit_window_steps(cfg) -> int:
    """Steps of the shortest fit window (the pulse at nu = 1 crossing 0.05..0.45 m)."""
    return int(0.4 * (cfg.nodes - 1))


def largest_record_every(cfg) -> int:
    """The largest --record-every that still gives every speed fit MIN_FIT_POINTS observations."""
    lo, hi = 1, max(int(cfg.record_every), 1)
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if fewest_fit_points(cfg, mid) >= MIN_FIT_POINTS:
            lo = mid
        else:
            hi = mid - 1
    return lo



def stage_work(cfg, stage: int) -> float:
    """Node-steps stage ``stage`` takes (an estimate for the up-front budget and the stage's
    progress line; observations counted as OBSERVATION_WORK node-steps per node)."""
    n = cfg.nodes
    h = 1.0 / (n - 1)
    obs = lambda steps, every: steps / max(every, 1) * (OBSERVATION_WORK + CHUNK_WORK / n)
    if stage == 2:  # (floats: a tiny --cfl gives astronomically many steps, refused, not an overflow)
        per_nu = 1.0 / max(min(cfg.cfl, 1.0) * h, 1e-300)
        steps = [0.5 / (0.25 * h), 0.5 / (0.5 * h), 0.5 / h, 0.5 * per_nu, 0.4 * per_nu]
        return n * sum(st + obs(st, cfg.record_every) for st in steps)
    if stage == 3:  # two recorded runs (launches of max(k, 100) steps), up to 14 bisection runs, backward Euler
        recorded = 2 * cfg.cfl_steps / max(cfg.record_every, 100) * CHUNK_WORK
        return n * (16 * cfg.cfl_steps + 3000 + obs(1000, cfg.record_every)) + recorded
    if stage == 4:  # three interface runs (about 1.5/h, 0.74/h, 0.74/h steps) and the smooth rod (2.1/h)
        return n * (3.0 / h + obs(3.0 / h, cfg.record_every) + 2.1 / h + obs(2.1 / h, 10))
    return 0.0


def work_text(work: float) -> str:
    if not math.isfinite(work):
        return time_text(work)
    return f"about {work:.2g} node-steps, ~{time_text(work / WORK_RATE)} at {WORK_RATE:.2g} node-steps/s"


def stage_seconds(cfg, stage: int) -> float:
    """Stage ``stage``'s time on the reference CPU: its node-steps (:func:`stage_work`) at WORK_RATE."""
    return stage_work(cfg, stage) / WORK_RATE


BUDGET = {
    2: StageCost(flags="--nodes, --cfl, --record-every", advice="use smaller values"),
    3: StageCost(flags="--cfl-steps, --nodes", advice="use smaller values"),
    4: StageCost(flags="--nodes, --record-every", advice="use smaller values"),
}


def check_work(cfg) -> None:
    """Refuse a configuration any of whose stages would take more than the lessons' budget (the
    refusal says how many node-steps that is)."""
    check_stages(cfg, stage_seconds, {
        stage: StageCost(cost.flags, f"that is {stage_work(cfg, stage):.2g} node-steps at {WORK_RATE:.2g} "
                                     f"node-steps/s; {cost.advice}")
        for stage, cost in BUDGET.items()})


def announce_work(ctx, stage: int) -> None:
    """Say up front what a stage expected to take more than ANNOUNCE_S costs."""
    work = stage_work(ctx.cfg, stage)
    if work / WORK_RATE > ANNOUNCE_S:
        ctx.progress(f"this stage steps the rod for {work_text(work)} (a progress bar follows each run on a "
                     f"terminal)")
