"""The scenes of ``springs``, how they are drawn, and what each stage costs.

Three parts, in this order: the builders (the chains, the one spring, the tetrahedral frame, the
varying rod of stage 3 on its three kinds of grid, the hanging rod), the drawing (the spring network
coloured by strain and each stage's views), and the budget (each stage's time on the reference CPU,
``stage_seconds`` and ``BUDGET``, and ``check_work``, which refuses a configuration up front).
The stages that use them are in stages.py and stages_dynamics.py.
"""
from __future__ import annotations

import math

import numpy as np

from engine import mesh as meshes
from engine.constants import G
from engine.errors import ParameterError
from engine.fields import vec3_ndarray
from engine.model import Model
from engine.scenes import Rod
from lessons.views import RunView

from .._budget import StageCost, check_stages
from .._measure import edge_strain


# ------------------------------------------------------------------ builders

def chain_edges(n: int) -> np.ndarray:
    return np.stack([np.arange(n - 1), np.arange(1, n)], axis=1)


def chain_masses(Ls: np.ndarray, rho: float) -> np.ndarray:
    """Lumped node masses of a chain of segments of lengths ``Ls`` and linear density ``rho``:
    each node gets half of each neighbouring segment."""
    m = np.zeros(Ls.size + 1)
    m[:-1] += 0.5 * rho * Ls
    m[1:] += 0.5 * rho * Ls
    return m


class OneSpring:
    """One spring of constant k and rest length ~0.3 m in a random orientation: its energy W(x)
    and force f(x) from the engine, and the force differentiated by hand."""

    def __init__(self, k: float, rng):
        L = 0.3
        direction = rng.standard_normal(3)
        X = np.array([[0.1, -0.2, 0.05], [0.0, 0.0, 0.0]])
        X[1] = X[0] + L * direction / np.linalg.norm(direction)
        self.k, self.X = k, X
        self.model = Model.from_springs(X, np.array([[0, 1]]), k=k, mass=1.0)
        self.L = float(self.model.springs.L_np[0])
        self._state = self.model.make_state()
        self._f = vec3_ndarray(2)

    def W(self, x):
        self._state.assign(x=x)
        return self.model.potential_energy(self._state.x)

    def force(self, x):
        self._state.assign(x=x)
        self.model.forces(self._state.x, self._f)
        return self._f.to_numpy().astype(np.float64)

    def closed_form(self, x):
        d = x[0] - x[1]
        l = np.linalg.norm(d)
        return -self.k * (l / self.L - 1.0) * d / l

    def placed(self, rng, stretch: float) -> np.ndarray:
        """The spring at ``stretch`` times its rest length, in a random orientation and place."""
        d = rng.standard_normal(3)
        x = np.empty((2, 3))
        x[1] = rng.standard_normal(3) * 0.1
        x[0] = x[1] + stretch * self.L * d / np.linalg.norm(d)
        return x


def swinging_chain(cfg):
    n = cfg.chain_nodes
    X = np.zeros((n, 3))
    X[:, 0] = np.linspace(0.0, 1.0, n)
    m = np.full(n, 1.0 / (n - 1))  # 1 kg chain, lumped from a uniform density
    m[[0, -1]] *= 0.5
    model = Model.from_springs(X, chain_edges(n), k=cfg.chain_k, mass=m, pinned=[0], gravity=(0.0, 0.0, -G))
    v = np.zeros((n, 3))
    v[:, 1] = 0.5 * X[:, 0]  # a sideways push: the chain swings in 3D
    return model, X.copy(), v


def tet_frame(cfg, jiggle=0.01, drift=0.1, spin=3.0, seed=3, rigid=True):
    mesh = meshes.tet_box(3, 2, 2, size=(0.2, 0.1, 0.1))
    X = np.asarray(mesh.vertices)
    model = Model.from_springs(X, mesh.edges, k=cfg.frame_k, mass=0.05)
    rng = np.random.default_rng(seed)
    x0 = X + jiggle * rng.standard_normal(X.shape)
    v0 = 20 * jiggle * rng.standard_normal(X.shape)
    if rigid:
        v0 += np.array([drift, 0.0, 0.0]) + np.cross([0.0, 0.0, spin], X - X.mean(axis=0))
    return model, x0, v0


def _E_of_p(p):
    return 1.0 + 0.5 * np.sin(2 * np.pi * p)


def _dE_of_p(p):
    return np.pi * np.cos(2 * np.pi * p)


def u(p):
    return 0.01 * np.sin(3 * np.pi * p) + 0.005 * np.cos(2 * np.pi * p + 0.3)


def _du(p):
    return 0.03 * np.pi * np.cos(3 * np.pi * p) - 0.01 * np.pi * np.sin(2 * np.pi * p + 0.3)


def _d2u(p):
    return -0.09 * np.pi ** 2 * np.sin(3 * np.pi * p) - 0.02 * np.pi ** 2 * np.cos(2 * np.pi * p + 0.3)


def force_density_exact(p):
    # d/dp (E(p) (x'(p) - 1)) with x = p + u: E' u' + E u''
    return _dE_of_p(p) * _du(p) + _E_of_p(p) * _d2u(p)


def grid(kind: str, n: int) -> np.ndarray:
    s = np.linspace(0.0, 1.0, n)
    if kind == "uniform":
        return s
    if kind == "graded":
        return s + 0.2 * np.sin(np.pi * s)  # smooth, monotone (p'(s) >= 1 - 0.2 pi > 0)
    rng = np.random.default_rng(1000 + n)  # random spacings in [0.5, 1.5] h
    h = rng.uniform(0.5, 1.5, n - 1)
    p = np.concatenate([[0.0], np.cumsum(h)])
    return p / p[-1]


def rod_on(p):
    mid = 0.5 * (p[1:] + p[:-1])
    return Rod(p, _E_of_p(mid), 1.0)


def chain_lengths(kind: str, h: float) -> np.ndarray:
    if kind == "uniform":
        n = int(round(1.0 / h))
        return np.full(n, 1.0 / n)
    if kind == "alternating":
        L = np.tile([h, 2 * h], int(round(1.0 / (3 * h))))
        return L / L.sum()
    # graded: L(p) = h (1 + p), from h at p = 0 to 2h at p = 1
    p = [0.0]
    while p[-1] < 1.0:
        p.append(p[-1] + h * (1.0 + p[-1]))
    p = np.asarray(p) / p[-1]
    return np.diff(p)


def chain_model(Ls: np.ndarray, k: np.ndarray, rho: float):
    p = np.concatenate([[0.0], np.cumsum(Ls)])
    n = p.size
    X = np.zeros((n, 3))
    X[:, 0] = p
    return Model.from_springs(X, chain_edges(n), k=k, mass=chain_masses(Ls, rho)), p


def hanging_rod(cfg, kind):
    n = cfg.hang_nodes
    s = np.linspace(0.0, 1.0, n)
    p = s if kind == "uniform" else s + 0.2 * np.sin(np.pi * s)
    X = np.zeros((n, 3))
    X[:, 2] = -p
    model = Model.from_springs(X, chain_edges(n), k=cfg.E, mass=chain_masses(np.diff(p), cfg.rho), pinned=[0],
                               gravity=(0.0, 0.0, -G))
    return model, p


# ------------------------------------------------------------------ drawing

def draw_springs(rec, model: Model, x: np.ndarray, scale: float | None = None, prefix: str = "",
                 radius: float = 0.006) -> None:
    """The spring network as line strips coloured by strain on the run's fixed scale (blue
    compressed, white at rest, red stretched) and its nodes (pinned ones dark red), under
    ``prefix`` (a body's name when a run draws several side by side)."""
    sp = model.springs
    segs = np.stack([x[sp.edges_np[:, 0]], x[sp.edges_np[:, 1]]], axis=1)
    colors = rec.colors(edge_strain(x, sp.edges_np, sp.L_np), "signed", "strain", scale)
    rec.line_strips(prefix + "springs", segs, colors=colors, radii=0.4 * radius)
    rec.points(prefix + "nodes", x, colors=np.where(model.pinned[:, None], [[200, 40, 40]], [[170, 170, 170]]),
               radii=radius)


ONE_SPRING_POSES = ("at rest", "stretched by 30%", "compressed by 20%")


def draw_one_spring(rec, spring: OneSpring, configs) -> None:
    """The spring at rest, stretched and compressed, side by side 0.5 m apart along x (each moved
    so that its midpoint sits there; orientations as measured), coloured by strain, with the force
    on each end as a thin green line from the node (the longest 0.3 L) and a label under each."""
    rec.run("one_spring", RunView(label="one spring in a random orientation: at rest, stretched, compressed "
                                        "(force on each end: green)", camera="front", energy=None))
    rec.set_time(0, 0.0)
    poses = [spring.X] + list(configs)
    fmax = max(np.abs(spring.force(xs)).max() for xs in poses[1:])
    under = []
    for i, (xs, entity) in enumerate(zip(poses, ("rest", "stretched", "compressed"))):
        shift = np.array([0.5 * i, 0.0, 0.0]) - xs.mean(axis=0)
        x = xs + shift
        draw_springs(rec, spring.model, x, scale=0.3, prefix=f"{entity}/", radius=0.012)
        fs = spring.force(xs)
        arrows = np.stack([x, x + 0.3 * spring.L * fs / fmax], axis=1)
        rec.line_strips(f"{entity}/force", arrows, colors=[[40, 200, 40]], radii=0.0025)
        under.append([0.5 * i, 0.0, -0.25])
    rec.labels("labels", under, ONE_SPRING_POSES)


METHOD_NAMES = {"symplectic-euler": "symplectic Euler", "velocity-verlet": "velocity Verlet",
                "forward-euler": "forward Euler"}
FORWARD_EULER_SHOWN = 1000  # steps of the forward-Euler chain on its view's timeline (it is stopped within them)


def chain_strain_scale(model: Model) -> float:
    """The chain's strain drawn at full colour: 3 M g / k, the top link's strain when a pendulum
    of the chain's whole mass M, dropped from the horizontal, passes below its pin (tension 3 M g)."""
    sp = model.springs
    return 3.0 * float(model.mass.sum()) * G / float(np.max(sp.c_np / sp.L_np))  # k = c / L


def chain_view(model: Model, method: str, n_steps: int) -> tuple:
    """(log, view) of a swinging-chain run: the chain seen from the front (it swings down in the
    x-z plane, pushed sideways along y), strain on the scale of :func:`chain_strain_scale`, its
    kinetic, potential and total energy plotted (its total is near 0 J, so a relative drift would
    say nothing)."""
    scale = chain_strain_scale(model)
    log = lambda rec, s: draw_springs(rec, model, s.x.to_numpy(), scale, radius=0.015)
    label = (f"chain, {METHOD_NAMES[method]}, {n_steps:,} steps" if method != "forward-euler" else
             f"chain, forward Euler, first {FORWARD_EULER_SHOWN} steps")
    return log, RunView(label=label, camera="front", energy="split")


def frame_view(model: Model, x0: np.ndarray, method: str) -> tuple:
    """(log, view) of a spinning-frame run. The frame drifts at 0.1 m/s (5 m, 25 times its size,
    over the default 10^5 steps): it is drawn as seen from its centre of mass, which stays where it
    starts; strain on the scale of the largest initial strain of the jiggle; the relative drift of
    its total energy plotted."""
    sp = model.springs
    scale = float(np.max(np.abs(edge_strain(x0, sp.edges_np, sp.L_np))))
    m = model.mass / model.mass.sum()
    c0 = m @ x0

    def log(rec, s):
        x = s.x.to_numpy().astype(np.float64)
        draw_springs(rec, model, x - m @ x + c0, scale, radius=0.006)
    return log, RunView(label=f"tet frame about its centre of mass, {METHOD_NAMES[method]}", camera="outside",
                        energy="drift")


def draw_force_density(rec, kind, p, dens):
    """The coarsest grid's force density at its interior nodes (orange dots: their spacing is the
    grid's) on the exact d/dp(E(x'-1)) (a blue line), drawn over p in [0, 1] at height 0.5 for the
    exact curve's largest |value|."""
    n = p.size
    rec.run(f"force_density_{kind}", RunView(label=f"force density, {kind} grid of {n} nodes: discrete (orange) · "
                                                    "exact (blue)", camera="top", energy=None))
    rec.set_time(0, 0.0)
    fine = np.linspace(0.0, 1.0, 1001)
    scale = 0.5 / np.max(np.abs(force_density_exact(fine)))
    rec.line_strips("exact", [np.stack([fine, scale * force_density_exact(fine), np.zeros(fine.size)], axis=1)],
                    colors=[[70, 130, 240]], radii=0.002)
    rec.points("discrete", np.stack([p, scale * dens, np.zeros(n)], axis=1)[1:-1], colors=[[240, 160, 30]],
               radii=0.008)


def draw_hanging(rec, kind, model, x, top_strain):
    """The rod unloaded and hanging in equilibrium side by side (0.3 m apart along x), seen from the
    front, coloured by strain on the scale of the exact top strain rho g L / E."""
    rec.run(f"hanging_{kind}", RunView(label=f"{kind} grid, {model.n} nodes: unloaded | hanging", camera="front",
                                       energy=None))
    rec.set_time(0, 0.0)
    shift = np.array([0.3, 0.0, 0.0])
    draw_springs(rec, model, model.X, top_strain, prefix="unloaded/")
    draw_springs(rec, model, x + shift, top_strain, prefix="hanging/")
    rec.labels("labels", [[0.0, 0.0, 0.08], [0.3, 0.0, 0.08]], ["unloaded", "hanging"])


# ------------------------------------------------------------------ the budget: each stage's time

STEP_S = 1e-6        # s per step of the many-steps kernel on a chain of ~12 nodes (reference 2-thread CPU)
LAUNCH_S = 1e-3      # s per launch of a recorded run (energies copied out, observations)
NODE_STEP_S = 2e-8   # s per node-step of stage 4's runs on long chains (observations included)
MAX_LAUNCH_STEPS = 2**31 - 1  # steps one launch of the many-steps kernel can take
WOBBLE_T = {"chain": 1.0, "frame": 0.5}  # s: the energy-wobble runs of stage 2
WOBBLE_STEPS = 200   # a wobble run covers WOBBLE_T or at least this many of the coarser steps (soft springs)


def wobble_time(net: str, dt: float) -> float:
    """The time the energy-wobble runs of ``net`` cover: WOBBLE_T[net], or WOBBLE_STEPS steps of dt where
    the springs are so soft that dt is long."""
    return max(WOBBLE_T[net], WOBBLE_STEPS * dt)


def _chain_dt_stable(cfg) -> float:
    """The engine's Gershgorin dt of the swinging chain, in closed form: every node's row of M^-1 H
    sums to 4 k (n - 1)^2 (springs k/L with L = 1/(n - 1), masses 1/(n - 1), halved at the ends)."""
    return 1.0 / ((cfg.chain_nodes - 1) * math.sqrt(cfg.chain_k))


def _frame_dt_stable(cfg) -> float:
    """The engine's Gershgorin dt of the tet frame (numpy: rows 2 (k/L) |d_a| sum_b |d_b| of each
    spring's block (k/L) d d^T at rest, summed over a vertex's springs, over its mass)."""
    mesh = meshes.tet_box(3, 2, 2, size=(0.2, 0.1, 0.1))
    X, e = np.asarray(mesh.vertices), np.asarray(mesh.edges)
    D = X[e[:, 1]] - X[e[:, 0]]
    L = np.linalg.norm(D, axis=1)
    d = np.abs(D / L[:, None])
    row = 2 * (cfg.frame_k / L)[:, None] * d * d.sum(axis=1)[:, None]
    lam = np.zeros((len(X), 3))
    np.add.at(lam, e[:, 0], row)
    np.add.at(lam, e[:, 1], row)
    return 2.0 / math.sqrt(float(lam.max()) / 0.05)


def stage2_plan(cfg) -> dict:
    """What stage 2 steps, before it runs: the step of each network, its longest single launch, and
    the stage's time on the reference CPU (every run at most its planned steps: forward Euler's
    chain counted as if it never blew up, in its launches of 5 steps)."""
    N = cfg.steps
    dts = {"chain": cfg.dt_fraction * _chain_dt_stable(cfg), "frame": cfg.dt_fraction * _frame_dt_stable(cfg)}
    step = {"chain": STEP_S * max(1.0, cfg.chain_nodes / 12), "frame": STEP_S}
    seconds, longest = 0.0, 0
    for net, dt in dts.items():
        wobble = wobble_time(net, dt) / max(dt / 2, 1e-300)  # the run at dt/2 is the longer (a float: it may be huge)
        longest = max(longest, wobble)
        seconds += 2 * (N * step[net] + N / cfg.record_every * LAUNCH_S)  # the two symplectic runs
        seconds += 2 * 1.5 * wobble * step[net]  # each method at dt and dt/2
    seconds += N * step["chain"] + N / 5 * LAUNCH_S + 4000 * STEP_S  # forward Euler: chain, frame modes
    return dict(dt=dts, longest=longest, seconds=seconds)


def stage4_seconds(cfg) -> float:
    """Stage 4's time on the reference CPU: five pulse runs of about 0.9 x segments steps (dt half the
    limit h/c, 0.45 m travelled) on chains of up to 1.5 x segments nodes."""
    n = cfg.wave_segments
    return 5 * (0.9 * n * 1.5 * n * NODE_STEP_S + 100 * LAUNCH_S)


def stage_seconds(cfg, stage: int) -> float:
    """Stage ``stage``'s time on the reference CPU: stage 2's runs (:func:`stage2_plan`) and stage 4's
    pulses (:func:`stage4_seconds`); stages 1, 3 and 5 do not step in time (0)."""
    if stage == 2:
        return stage2_plan(cfg)["seconds"]
    if stage == 4:
        return stage4_seconds(cfg)
    return 0.0


BUDGET = {
    2: StageCost(flags="--steps, --dt-fraction, --record-every, --chain-k, --frame-k",
                 advice="use fewer --steps, a larger --dt-fraction or --record-every, or softer --chain-k/--frame-k"),
    4: StageCost(flags="--wave-segments", advice="use fewer --wave-segments"),
}


def check_work(cfg) -> None:
    """Refuse what stage 2 cannot run (a launch past the kernel's 2^31 - 1 steps) or what would take
    hours."""
    check_stages(cfg, stage_seconds, BUDGET)
    plan = stage2_plan(cfg)
    if plan["longest"] > MAX_LAUNCH_STEPS:
        raise ParameterError(
            f"--dt-fraction {cfg.dt_fraction:g}: stage 2's energy-wobble runs would take {plan['longest']:.3g} steps "
            f"in one launch, more than the kernel's {MAX_LAUNCH_STEPS} (use --dt-fraction >= "
            f"{cfg.dt_fraction * plan['longest'] / MAX_LAUNCH_STEPS:.2g})")
