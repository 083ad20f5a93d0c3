"""The scene of ``explicit-vs-implicit``: what its stages build (the cloth's modes, the in-plane
seed that starts its runs, the watched backward-Euler integrator), how its runs are drawn, and the
estimates of each stage's time with the budget they are checked against.

numpy is used for set-up and eigen-analysis.
"""
import math

import numpy as np

from engine.fields import vec3_ndarray
from lessons.views import RunView

from .._budget import StageCost, announce as announce_budget, check_stages
from .._measure import edge_strain, vertex_strain

# ------------------------------------------------------------------ builders: modes, seed, integrator

class Watched:
    """A backward-Euler integrator that keeps, for every step, what its solves did: the largest
    linear residual, the CG iterations, the Newton iterations, and whether the incremental
    potential went down at every Newton iteration and the iteration converged: |grad Phi| fell
    by newton_tol (relative to at least the weight, so a settled cloth converges at once), or the
    line search found no measurable decrease left (none at all, or only decreases below Phi's
    round-off to the last iteration)."""

    def __init__(self, integrator):
        self.integrator = integrator
        self.residuals, self.iterations, self.newton, self.monotone, self.converged = [], [], [], [], []
        self.solves = 0

    def __getattr__(self, name):  # name, implicit, solver, tol, begin, ... of the wrapped integrator
        return getattr(self.integrator, name)

    def advance(self, ctx, state, dt):
        model = ctx.model
        info = self.integrator.advance(ctx, state, dt)
        self.residuals.append(max(info.linear_residuals, default=0.0))
        self.iterations.append(sum(info.linear_iterations))
        self.solves += len(info.linear_iterations)
        self.newton.append(info.newton_iterations)
        obj = info.objectives
        self.monotone.append(all(b < a for a, b in zip(obj, obj[1:])))
        converged = info.newton_converged or info.line_search_failed or self.integrator.newton_iterations == 1
        if not converged and len(obj) >= 2:
            # Newton ran to its cap taking tiny steps that lowered Phi by less than its round-off (64 eps x
            # the energies it is a difference of): no measurable decrease was left, as when the line search fails
            noise = 64 * np.finfo(np.float64).eps * (abs(model.potential_energy(state.x)) + abs(model.elastic_energy(state.x)))
            converged = obj[-2] - obj[-1] <= noise
        self.converged.append(converged)
        return info


def free_modes(model, x, planar: bool = True):
    """Angular frequencies w and mode shapes (n, 3) of M^-1 H at x over the free vertices (dense
    eigen-decomposition; small models only). ``planar``: only the in-plane (x, z) motions."""
    H = model.dense_hessian(vec3_ndarray(model.n, x), psd=False)
    axes = [0, 2] if planar else [0, 1, 2]
    free = np.flatnonzero(model.free)
    dofs = (3 * free[:, None] + np.asarray(axes)[None, :]).ravel()
    s = 1.0 / np.sqrt(np.repeat(model.mass[free], len(axes)))
    w2, V = np.linalg.eigh(s[:, None] * H[np.ix_(dofs, dofs)] * s[None, :])
    shapes = np.zeros((len(w2), model.n, 3))
    for k in range(len(w2)):
        u = np.zeros(3 * model.n)
        u[dofs] = s * V[:, k]
        shapes[k] = u.reshape(-1, 3)
    return np.sqrt(np.maximum(w2, 0.0)), w2, shapes


def in_plane_seed(model, size: float, seed: int) -> np.ndarray:
    """A random displacement in the cloth's plane (x and z), zero at the pins."""
    rng = np.random.default_rng(seed)
    d = np.zeros((model.n, 3))
    d[:, [0, 2]] = size * rng.standard_normal((model.n, 2))
    d[model.pinned] = 0.0
    return d


# ------------------------------------------------------------------ drawing

def cloth_logger(scene, scale: float, gain: float = 1.0):
    """log(rec, state) for simulate(): the cloth coloured by the mean strain of the springs at each
    vertex (blue compressed, red stretched; full colour at ``scale``), its displacement from the
    rest shape drawn ``gain`` times larger."""
    sp = scene.springs
    tris = scene.mesh.triangles
    X = scene.model.X

    def log(rec, state):
        x = state.x.to_numpy().astype(np.float64)
        s = vertex_strain(len(x), sp.edges_np, edge_strain(x, sp.edges_np, sp.L_np))
        rec.mesh(X + gain * (x - X) if gain != 1.0 else x, tris, rec.colors(s, "signed", "strain", scale))
    return log


COST_COLOURS = {"explicit": (230, 160, 30), "pcg": (90, 150, 255), "direct": (90, 200, 90)}


def draw_cost_curves(rec, rows, frame_dt: float) -> None:
    """Stage 3's picture (one frame): the cost curves as a log-log chart drawn in the plane, wall-clock
    seconds per simulated second against E for symplectic Euler at its limit and backward Euler with
    pcg and with the direct solver at one frame, a tick per decade and each curve named at its end."""
    direct = rows[0]["direct_name"]
    curves = {"explicit": ("symplectic Euler", [r["t_exp"] for r in rows]),
              "pcg": ("backward Euler, pcg", [r["t_pcg"] for r in rows]),
              "direct": (f"backward Euler, {direct}", [r["t_direct"] for r in rows])}
    lx = np.log10([r["E"] for r in rows])
    ly = {key: np.log10(np.maximum(np.asarray(t, dtype=np.float64), 1e-12)) for key, (_, t) in curves.items()}
    finite = np.concatenate([v[np.isfinite(v)] for v in ly.values()])
    x0, x1 = math.floor(lx.min()), math.ceil(lx.max())
    y0, y1 = math.floor(finite.min()), math.ceil(finite.max())
    W, H = 1.6, 1.0   # the chart's box in the plane (m of the scene)

    def at(x, y):
        return np.column_stack([(np.asarray(x) - x0) / max(x1 - x0, 1) * W, (np.asarray(y) - y0) / max(y1 - y0, 1) * H,
                                np.zeros(np.size(x))])
    rec.run("cost", RunView(label=f"wall-clock s per simulated s against E (log-log; backward Euler at dt = "
                                  f"{frame_dt:.3g} s)", camera="top", energy=None))
    rec.set_time(0, 0.0)
    grey = [120, 120, 120]
    axes = [np.array([[0, 0, 0], [W, 0, 0]]), np.array([[0, 0, 0], [0, H, 0]])]
    ticks = [at([d, d], [y0, y0])[:, :] + np.array([[0, 0, 0], [0, -0.02, 0]]) for d in range(x0, x1 + 1)]
    ticks += [at([x0, x0], [d, d]) + np.array([[0, 0, 0], [-0.02, 0, 0]]) for d in range(y0, y1 + 1)]
    rec.line_strips("axes", axes + ticks, colors=[grey] * (len(axes) + len(ticks)), radii=0.002)
    labels = [(at([d], [y0])[0] + [0, -0.06, 0], f"1e{d} N/m") for d in range(x0, x1 + 1)]
    labels += [(at([x0], [d])[0] + [-0.12, 0, 0], f"1e{d} s/s") for d in range(y0, y1 + 1)]
    rec.labels("ticks", [p for p, _ in labels], [t for _, t in labels], colors=[[170, 170, 170]] * len(labels))
    ends = {}
    for key, (name, _) in curves.items():
        ok = np.isfinite(ly[key])
        pts = at(lx[ok], ly[key][ok])
        rec.line_strips(f"{key}/curve", [pts], colors=[COST_COLOURS[key]], radii=0.005)
        rec.points(f"{key}/runs", pts, colors=[COST_COLOURS[key]] * len(pts), radii=0.014)
        if len(pts):
            ends[key] = pts[-1] + [0.03, 0, 0]
    last = -math.inf
    for key in sorted(ends, key=lambda k: ends[k][1]):   # names at the curves' ends, 0.07 apart at least
        ends[key][1] = max(ends[key][1], last + 0.07)
        last = ends[key][1]
        rec.labels(f"{key}/name", [ends[key]], [curves[key][0]], colors=[COST_COLOURS[key]])


def timings_table(rows) -> str:
    """The sweep as a markdown table (shown under the stage's results)."""
    direct = rows[0]["direct_name"] if rows else "direct"
    lines = [f"| E (N/m) | explicit dt (µs) | steps / s | CG / step | √(1 + w²dt²) | explicit | BE-PCG | BE-{direct} |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['E']:.3g} | {r['dt_exp'] * 1e6:.1f} | {r['steps_exp']:.0f} | {r['cg_pcg']:.0f} | "
                     f"{r['sqrt_cond']:.0f} | {r['t_exp']:.3g} | {r['t_pcg']:.3g} | {r['t_direct']:.3g} |")
    lines.append("\nsteps / s: explicit steps per simulated second; CG / step: PCG iterations per backward-Euler "
                 f"step; √(1 + w²dt²): the square root of the condition-number bound at dt = one frame; explicit, "
                 f"BE-PCG, BE-{direct} (the fastest direct solver installed): wall-clock seconds per simulated second.")
    return "\n".join(lines)


# ------------------------------------------------------------------ estimates and budget: the parameters' limits

# seconds per step on the reference 2-thread CPU for a 16 x 16 cloth (more vertices: proportionally more)
EXPLICIT_STEP_S = 1.7e-3       # symplectic Euler with bending (one force evaluation)
BE_ONE_NEWTON_STEP_S = 17e-3   # backward Euler, one Newton iteration, pcg (~120 CG iterations at 10 x the limit)
BE_NEWTON_STEP_S = 65e-3       # backward Euler, Newton converged (~3.5 iterations at 100 x the limit)
STAGE2_SECONDS = 14.7          # stage 2 at the defaults (88 coarsest steps), most of it its convergence runs
MAX_WEIGHT_STRAIN = 0.1        # rho g L / E, the strain the cloth's weight may cause (1e-3 at the defaults)


def limit_estimate(n: int, E: float, rho: float, B: float) -> float:
    """The explicit limit 2/w_max of an n x n cloth without building it (for the up-front checks):
    w_max^2 ~ max(1.72 E/(rho h^2), 8.9 B/(rho h^4)), the stretching and the bending bounds measured
    by power iteration on the flat cloth (within a few % of either where it dominates)."""
    h = 1.0 / (n - 1)
    with np.errstate(divide="ignore", over="ignore", invalid="ignore"):  # extreme values: inf or 0, then refused
        lam = max(np.float64(1.72) * E / (np.float64(rho) * h * h), np.float64(8.9) * B / (np.float64(rho) * h ** 4))
        return float(2.0 / np.sqrt(lam)) if lam > 0 else math.inf


def stage_seconds(cfg, stage: int) -> float:
    """An estimate of stage ``stage``'s time on the reference CPU (every run to its planned end)."""
    if stage == 1:
        dt = limit_estimate(cfg.n, cfg.E, cfg.rho, cfg.B)
        if not 0 < dt < math.inf:  # a limit under the float range (a vanishing density): never-ending
            return math.inf if not dt > 0 else 0.0
        size = max(1.0, cfg.n * cfg.n / 256)
        explicit = cfg.explicit_time / dt * (1 / cfg.below + 2 / cfg.above) * EXPLICIT_STEP_S
        implicit = cfg.implicit_time / dt * (BE_ONE_NEWTON_STEP_S * math.sqrt(cfg.big / 10) / cfg.big
                                             + BE_NEWTON_STEP_S * math.sqrt(cfg.huge / 100) / cfg.huge)
        return size * (explicit + implicit)
    if stage == 2:  # the convergence runs: about 70 x n0 steps, n0 = conv_time / (0.3 x the limit)
        d = type(cfg)()
        n0 = lambda c: max(20.0, c.conv_time / max(0.3 * limit_estimate(c.conv_n, c.E, c.rho, c.B), 1e-300))
        return STAGE2_SECONDS * n0(cfg) / n0(d) * max(1.0, cfg.conv_n ** 2 / d.conv_n ** 2)
    return 0.0


BUDGET = {
    1: StageCost(flags="--n, --E, --rho, --B, --explicit-time, --implicit-time, --below, --big, --huge",
                 advice="use a softer, heavier or smaller cloth, or shorter times"),
    2: StageCost(flags="--conv-n, --conv-time, --E, --rho, --B",
                 advice="use a softer, heavier or smaller cloth, or shorter times"),
}


def check_work(cfg) -> None:
    """Refuse a configuration whose stage 1 or 2 would take more than the lessons' budget."""
    check_stages(cfg, stage_seconds, BUDGET)


def announce(ctx, stage: int) -> None:
    announce_budget(ctx, stage_seconds(ctx.cfg, stage), bound=True)
