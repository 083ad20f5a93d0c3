"""Lesson ``explicit-vs-implicit``: the CFL limit of explicit time stepping, backward Euler's
unconditional stability, what it costs in accuracy and what it buys in speed.

The lecture notes remark that implicit methods pass information across the whole mesh in
a single step, so the CFL limit does not bind them. Physics lives in the engine
(:mod:`engine.integrators.explicit`, :mod:`engine.integrators.implicit`, :mod:`engine.linalg`,
:mod:`engine.scenes`, :mod:`engine.statics`); this module builds the hanging cloth, runs it,
measures and narrates. numpy is used for set-up, eigen-analysis and the reference formulas.
"""
import math
import time
from dataclasses import dataclass

import numpy as np

from engine import diagnostics
from engine.analysis import fit_slope
from engine.errors import BlowUpError, ParameterError
from engine.integrators import make_integrator
from engine.integrators.explicit import gershgorin_lambda_max, lambda_max_power
from engine.model import vec3_ndarray
from engine.recorder import strain_colors
from engine.scenes import cloth
from engine.statics import solve_static

from ._framework import Experiment, Lesson, Stage, param
from ._measure import edge_strain, vertex_strain
from ._scene import simulate


@dataclass
class ExplicitImplicitConfig:
    n: int = param(16, "stage 1: vertices per side of the hanging cloth (1 m x 1 m, pinned at its two top "
                   "corners)", ge=6, le=40)
    E: float = param(1e3, "stages 1-2: stretching modulus of the cloth (Young's modulus x thickness)", "N/m",
                     gt=0, le=1e7)
    rho: float = param(0.1, "areal density of every cloth in the lesson", "kg/m^2", gt=0, le=100)
    B: float = param(1e-4, "bending modulus of every cloth in the lesson", "N m", ge=0, le=1)
    below: float = param(0.9, "stage 1: dt of the stable explicit run, as a fraction of the true limit", gt=0,
                         lt=1)
    above: float = param(1.1, "stage 1: dt of the unstable explicit run, as a multiple of the true limit", gt=1,
                         le=3)
    explicit_time: float = param(1.0, "stage 1: simulated time the explicit runs must survive", "s", gt=0, le=10)
    implicit_time: float = param(2.0, "stage 1: simulated time of the backward-Euler runs", "s", gt=0, le=20)
    big: float = param(10.0, "stage 1: dt of the first backward-Euler run / the explicit limit", ge=2, le=1000)
    huge: float = param(100.0, "stage 1: dt of the second backward-Euler run / the explicit limit", ge=2,
                        le=10000)
    seed_size: float = param(1e-9, "stage 1: random in-plane displacement that seeds the fastest modes", "m",
                             gt=0, le=1e-3)
    seed: int = param(0, "random seed of that displacement", ge=0)
    mode_n: int = param(7, "stage 2: vertices per side of the small cloth whose modes are excited", ge=4, le=12)
    conv_n: int = param(9, "stage 2: vertices per side of the cloth of the convergence study", ge=4, le=16)
    conv_time: float = param(0.05, "stage 2: simulated time of the convergence runs (falling from rest)", "s",
                             gt=0, le=1)
    speed_n: int = param(32, "stage 3: vertices per side of the cloth of the timing runs", ge=8, le=96)
    E_soft: float = param(10.0, "stage 3: softest stretching modulus of the sweep", "N/m", gt=0)
    E_stiff: float = param(1e5, "stage 3: stiffest stretching modulus of the sweep", "N/m", gt=0, le=1e8)
    E_values: int = param(5, "stage 3: moduli in the sweep (log-spaced)", ge=3, le=9)
    frame_dt: float = param(1 / 60, "stage 3: backward Euler's time step (one video frame)", "s", gt=0, le=0.1)
    frames: int = param(8, "stage 3: frames (of --frame-dt) after the release that every timing run covers", ge=3,
                        le=600)
    record_every: int = param(10, "log the cloth every k-th step", ge=1)

    def validate(self):
        if self.huge <= self.big:
            raise ParameterError(f"--huge must be larger than --big (got {self.huge} <= {self.big})")
        if self.E_stiff <= self.E_soft:
            raise ParameterError(f"--E-stiff must be larger than --E-soft (got {self.E_stiff} <= {self.E_soft})")


# ------------------------------------------------------------------ shared machinery

def cloth_logger(scene, offset=(0.0, 0.0, 0.0), scale: float | None = None, skip: int = 1):
    """log(rec, state) for simulate(): the cloth coloured by strain (blue compressed, red
    stretched); with ``skip`` > 1 only every skip-th call draws (and always the first)."""
    sp = scene.springs
    tris = scene.mesh.triangles
    calls = [0]

    def log(rec, state):
        k = calls[0]
        calls[0] += 1
        if k % skip:
            return
        x = state.x.to_numpy().astype(np.float64)
        s = vertex_strain(len(x), sp.edges_np, edge_strain(x, sp.edges_np, sp.L_np))
        rec.mesh(x + np.asarray(offset), tris, strain_colors(s, scale))
    return log


class Watched:
    """A backward-Euler integrator that keeps, for every step, what its solves did: the largest
    linear residual, the CG iterations, the Newton iterations, and whether the incremental
    potential went down at every Newton iteration and the iteration converged: |grad Phi| fell
    by newton_tol (relative to at least the weight, so a settled cloth converges at once), or the
    line search found no measurable decrease left."""

    def __init__(self, integrator):
        self.integrator = integrator
        self.residuals, self.iterations, self.newton, self.monotone, self.converged = [], [], [], [], []
        self.solves = 0

    def __getattr__(self, name):  # name, implicit, solver, tol, begin, ... of the wrapped integrator
        return getattr(self.integrator, name)

    def advance(self, model, state, dt):
        self.integrator.advance(model, state, dt)
        info = self.integrator.last_info
        self.residuals.append(max(info.linear_residuals, default=0.0))
        self.iterations.append(sum(info.linear_iterations))
        self.solves += len(info.linear_iterations)
        self.newton.append(info.newton_iterations)
        obj = info.objectives
        self.monotone.append(all(b < a for a, b in zip(obj, obj[1:])))
        self.converged.append(info.newton_converged or info.line_search_failed
                              or self.integrator.newton_iterations == 1)


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


def symplectic_euler_growth(z: float) -> float:
    """Largest |eigenvalue| of symplectic Euler's step matrix for a mode with (w dt)^2 = z:
    x+ = (1 - z) x + dt v, v+ = v - w^2 dt x, so lambda^2 - (2 - z) lambda + 1 = 0."""
    b = 2.0 - z
    disc = b * b - 4.0
    if disc <= 0.0:
        return 1.0  # complex pair on the unit circle: stable
    return (abs(b) + math.sqrt(disc)) / 2.0


def in_plane_seed(model, size: float, seed: int) -> np.ndarray:
    """A random displacement in the cloth's plane (x and z), zero at the pins."""
    rng = np.random.default_rng(seed)
    d = np.zeros((model.n, 3))
    d[:, [0, 2]] = size * rng.standard_normal((model.n, 2))
    d[model.pinned] = 0.0
    return d


# ------------------------------------------------------------------------- stage 1

S1_TEXT = """
An explicit step builds the new state from forces evaluated at the old one, so during one step a
vertex hears only from its direct neighbours: numerically, information crosses one edge per step.
The CFL condition asks that this be at least as fast as the physics, and for a network of springs
it becomes a statement about the fastest vibration. Linearise about a state: every small motion is
a sum of modes, each oscillating at an angular frequency w, with w^2 an eigenvalue of M^-1 H
(lumped masses M, Hessian H of the potential). Symplectic Euler and velocity Verlet keep a mode
bounded iff w dt <= 2. Beyond that the mode's 2x2 step matrix has a real eigenvalue below -1: the
mode changes sign and grows by a fixed factor every step, so even a nanometre of noise becomes a
visible explosion within tens of steps. The largest stable step is 2/w_max, and since w_max grows
like the speed of sound sqrt(E/rho) over the edge length, so does the number of steps per second.

The scene is the hanging cloth shared with the benchmarks (16 x 16 vertices by default on a
1 m square, pinned at its two top corners, area-scaled springs, dihedral bending, gravity),
released from its flat rest shape. Its true limit comes from w_max, found by power iteration on
M^-1 H at the hanging equilibrium (the static solver finds it; the fastest modes are short
in-plane spring vibrations, which the small sag barely changes) and checked against a dense
eigen-decomposition. The engine's cheap Gershgorin bound (absolute row sums of H over the mass)
can only overestimate w_max^2, so its dt is safe. On this grid it is also tight: about 0.9 of the
true limit. Cruder estimates waste more: adding 4c/L^2 for every spring at a vertex (each spring
alone at its worst) gives about half the limit, and the rod formula h/c with the edge length h
about two thirds, because a 2D sheet is not a chain. All three are printed.

Symplectic Euler then runs at 0.9 and at 1.1 times the true limit, both seeded with the same
random in-plane displacement of a nanometre. It stays in the plane because the flat hanging
shape is unstable to folding out of it (that is the bending lesson's subject), and here every
run should head for one and the same equilibrium. The first run survives its full second. The
second run is stopped by the energy check at the step where the total energy passes the start
plus everything the fall can release, and the message names the CFL limit. A twin run with the
opposite seed isolates the seed's own evolution, (x+ - x-)/2, which we compare with the
linearised prediction: the seed split into modes, each advanced with its own step matrix. Many
modes sit just below the fastest one, so the growth per step is a little below the fastest mode's
factor, and the prediction accounts for all of them.

Backward Euler solves for the new positions in a system that couples every vertex to every
other, so one step carries information across the whole sheet: the notes' "infinitely fast". Its
new state is the minimiser of the incremental potential
Phi(x) = |x - x_n - dt v_n|^2_M/(2 dt^2) + W(x) (inertia pulls towards where the old velocity
would carry the cloth; elasticity and gravity pull towards rest). A minimiser exists at every
dt, and when W is convex it never holds more energy than the state it started from, so the step
cannot blow up. We run it at 10 x the explicit limit with one Newton iteration per step (Baraff
and Witkin's linearised step) and at 100 x with Newton iterated until the gradient of Phi has
dropped by 1e-8 (relative to the larger of its starting value and |M g|, the vertices' weights). In
both, a line search keeps Phi decreasing at every Newton iteration, and PCG solves each linear
system to a relative residual of 1e-8. The total energy never exceeds the initial energy plus
the work done by gravity, the cloth settles onto the static equilibrium to within a thousandth
of its sag, and the pinned corners do not move.

Every run in this stage tests one particular integrator (symplectic Euler's CFL limit, backward
Euler's stability), so they are all fixed: --integrator, --solver and --tol leave them alone.
"""


def stage_cfl(ctx):
    cfg = ctx.cfg
    scene = cloth(cfg.n, 1.0, E=cfg.E, rho=cfg.rho, B=cfg.B)
    model, X = scene.model, scene.model.X
    eq = solve_static(model, tol=1e-7, max_iter=200, raise_on_failure=False)
    x_eq = eq.x
    sag = float(np.abs(X - x_eq).max())
    ctx.progress(f"hanging equilibrium: {eq.iterations} Newton steps, residual {eq.residual:.1e}, "
                 f"largest sag {sag * 1e3:.2f} mm")
    x_eq_nd = vec3_ndarray(model.n, x_eq)
    lam_power = abs(lambda_max_power(model, x_eq_nd))
    lam_gersh = gershgorin_lambda_max(model, x_eq_nd)
    dt_true = 2.0 / math.sqrt(lam_power)
    dt_gersh = 2.0 / math.sqrt(lam_gersh)
    c = math.sqrt(cfg.E / cfg.rho)
    h = 1.0 / (cfg.n - 1)
    exps = []
    modes = None
    if 3 * cfg.n * cfg.n <= 2000:  # dense eigen-decomposition on small cloths
        _, w2, shapes = free_modes(model, x_eq, planar=False)
        modes = (w2, shapes)
        exps.append(Experiment("power iteration's w_max^2 equals the dense eigenvalue of M^-1 H (hanging state)",
                               float(w2.max()), lam_power, 1e-4, "rel", "1/s^2"))
    # the cruder per-spring estimate: every spring adds 4 c/L^2 to both of its vertices' rows
    sp = scene.springs
    crude = np.zeros(model.n)
    np.add.at(crude, sp.edges_np.ravel(), np.repeat(4.0 * sp.c_np / sp.L_np ** 2, 2))
    dt_crude = 2.0 / math.sqrt(float((crude[model.free] / model.mass[model.free]).max()))
    ctx.progress(f"explicit limit 2/w_max = {dt_true * 1e3:.4f} ms (power iteration); Gershgorin bound "
                 f"{dt_gersh * 1e3:.4f} ms = {dt_gersh / dt_true:.3f} x the true limit; per-spring sum 4c/L^2: "
                 f"{dt_crude / dt_true:.3f} x; the rod formula h/c = {h / c * 1e3:.4f} ms = {h / c / dt_true:.3f} x")
    exps.append(Experiment(f"Gershgorin's dt is safe: at most the true limit (ratio {dt_gersh / dt_true:.3f})",
                           dt_true, dt_gersh, 0, "<=", "s"))

    seed = in_plane_seed(model, cfg.seed_size, cfg.seed)
    E0 = diagnostics.total_energy(model, model.make_state(X))
    E_eq = model.potential_energy(x_eq_nd)
    release = E0 - E_eq  # what the fall from the flat shape to the hanging one can set free
    bound = E0 + release
    ctx.progress(f"energy: start {E0:.6g} J, equilibrium {E_eq:.6g} J; blow-up bound start + release = {bound:.6g} J")
    strain_scale = float(np.abs(edge_strain(x_eq, scene.springs.edges_np, scene.springs.L_np)).max())

    # symplectic Euler below the limit: survives the whole run
    dt = cfg.below * dt_true
    n_below = int(math.ceil(cfg.explicit_time / dt))
    state = model.make_state(X + seed)
    try:
        steps, K, W = simulate(ctx, f"symplectic_{cfg.below:g}x", model, state, dt, n_below, "symplectic-euler",
                               every=cfg.record_every, energy_bound=bound, fixed=True,
                               log=cloth_logger(scene, (-1.2, 0.0, 0.0), strain_scale))
        survived = int(steps[-1])
        ctx.progress(f"{cfg.below:g} x limit: largest energy excess {(K + W).max() - E0:.2e} J over {n_below} steps")
    except BlowUpError as exc:
        survived = exc.step
        ctx.progress(f"{cfg.below:g} x limit: {exc}")
    pinned_moved = float(np.abs(state.numpy().x[model.pinned] - X[model.pinned]).max())
    exps.append(Experiment(f"symplectic Euler at {cfg.below:g} x the limit survives {n_below} steps "
                           f"({cfg.explicit_time:g} s)", n_below, survived, 0, ">="))

    # symplectic Euler above the limit: blows up, detected at the step. A second run with the
    # opposite seed gives the seed's own evolution as the odd part (x+ - x-)/2 (the fall, and
    # whatever the release itself excites, cancel), to compare with the modal prediction.
    dt = cfg.above * dt_true
    n_above = int(math.ceil(cfg.explicit_time / dt))
    detected, message, tracks = [], [], []
    for sign, name in ((1.0, f"symplectic_{cfg.above:g}x"), (-1.0, f"symplectic_{cfg.above:g}x_opposite_seed")):
        state = model.make_state(X + sign * seed)
        track = []
        try:
            simulate(ctx, name, model, state, dt, n_above, "symplectic-euler", every=1, energy_bound=bound,
                     fixed=True, log=cloth_logger(scene, (-1.2, 0.0, 0.0), strain_scale),
                     observe=lambda s, st: track.append(st.x.to_numpy().astype(np.float64)))
            detected.append(n_above)
            message.append("")
        except BlowUpError as exc:
            detected.append(exc.step)
            message.append(str(exc))
        tracks.append(track)
    ctx.progress(f"{cfg.above:g} x limit: {message[0] or 'no blow-up'}")
    exps += [
        Experiment(f"symplectic Euler at {cfg.above:g} x the limit blows up within {n_above} steps (step detected)",
                   n_above - 1, detected[0], 0, "<="),
        Experiment("the blow-up message names the CFL limit", 1.0, float("CFL limit" in message[0]), 0, "abs"),
    ]
    if modes is not None and min(len(tracks[0]), len(tracks[1])) >= 2:
        # linearised about the start (the flat sheet): the runs stay within a few mm of it
        _, w2, shapes = free_modes(model, X, planar=True)
        last = min(len(tracks[0]), len(tracks[1])) - 1  # the last step both runs reached
        odd = 0.5 * (tracks[0][last] - tracks[1][last])
        measured = math.sqrt(float((model.mass[:, None] * odd ** 2).sum()))
        # each mode k: x+ = (1 - w_k^2 dt^2) x + dt v, v+ = v - w_k^2 dt x, from x = c_k, v = 0
        coef = np.einsum("kij,i,ij->k", shapes, model.mass, seed)  # M-orthonormal shapes
        xk, vk = coef.copy(), np.zeros_like(coef)
        for _ in range(last):
            vk = vk - w2 * dt * xk
            xk = xk + dt * vk
        predicted = float(np.linalg.norm(xk))
        start = float(np.linalg.norm(coef))
        unstable = int(np.count_nonzero((w2 * dt * dt > 4.0) & (np.abs(coef) > 0)))
        lam = symplectic_euler_growth((cfg.above * 2.0) ** 2)
        per_step = (measured / start) ** (1 / last)
        ctx.progress(f"the seed grew {measured / start:.4g}x in {last} steps ({per_step:.3f} per "
                     f"step); modal prediction {predicted / start:.4g}x; {unstable} modes have w dt > 2, the fastest "
                     f"grows {lam:.3f}x per step")
        exps.append(Experiment(f"the seed grows as the modes' step matrices predict ({unstable} modes with w dt > 2; "
                               f"growth over {last} steps)", predicted / start, measured / start, 1e-2, "rel"))

    # backward Euler far above the limit: at `big` x one Newton iteration per step (Baraff-Witkin's
    # linearised step), at `huge` x Newton iterated to convergence (the incremental potential's minimiser)
    w1 = None
    if modes is not None:
        w2, shapes = modes
        in_plane = np.abs(shapes[:, :, 1]).max(axis=1) < 1e-9 * np.abs(shapes).max(axis=(1, 2))
        w1 = math.sqrt(float(w2[in_plane & (w2 > 0)].min()))
    residuals, bad_steps = [], 0
    for k, (factor, newton) in enumerate(((cfg.big, 1), (cfg.huge, 50))):
        dt = factor * dt_true
        n_steps = int(math.ceil(cfg.implicit_time / dt))
        be = Watched(make_integrator("backward-euler", solver="pcg", tol=1e-8, newton_iterations=newton,
                                     newton_tol=1e-8, max_iter=5000, exact_near_solution=False))
        state = model.make_state(X + seed)
        every = max(1, min(cfg.record_every, n_steps // 20))
        steps, K, W = simulate(ctx, f"backward_euler_{factor:g}x", model, state, dt, n_steps, be, every=every,
                               fixed=True, log=cloth_logger(scene, (1.2 * k, 0.0, 0.0), strain_scale))
        x = state.numpy().x
        pinned_moved = max(pinned_moved, float(np.abs(x[model.pinned] - X[model.pinned]).max()))
        distance = float(np.abs(x - x_eq).max()) / sag
        bad = sum(1 for m, c_ in zip(be.monotone, be.converged) if not (m and c_))
        if w1 is not None:
            ctx.progress(f"slowest in-plane mode w1 = {w1:.4g} rad/s: linear theory leaves (1 + w1^2 dt^2)^(-N/2) = "
                         f"{(1 + (w1 * dt) ** 2) ** (-n_steps / 2):.1e} of its amplitude after {n_steps} steps")
        ctx.progress(f"backward Euler at {factor:g} x ({dt * 1e3:.3g} ms, {n_steps} steps): Newton "
                     f"{np.mean(be.newton):.1f} iterations/step, CG {np.sum(be.iterations) / max(be.solves, 1):.0f} "
                     f"iterations/solve, largest residual {max(be.residuals):.1e}; energy max - start "
                     f"{(K + W).max() - E0:.2e} J; distance to equilibrium / sag {distance:.1e}")
        exps += [
            Experiment(f"backward Euler at {factor:g} x the limit: total energy never exceeds the start "
                       "(initial energy + work of gravity)", E0, float((K + W).max()), 0, "<=", "J"),
            Experiment(f"backward Euler at {factor:g} x: reaches the hanging equilibrium after "
                       f"{n_steps * dt:.3g} s (max |x - x_eq| / largest sag)", 0.0, distance, 1e-3, "abs"),
        ]
        residuals.append(max(be.residuals))
        bad_steps += bad
    exps += [
        Experiment(f"every Newton iteration lowered the incremental potential, and at {cfg.huge:g} x Newton "
                   "converged in every step (steps that failed)", 0, bad_steps, 0, "abs"),
        Experiment("every linear solve reached its tolerance (largest relative residual)", 1e-8, max(residuals), 0,
                   "<="),
        Experiment("pinned corners never moved (max displacement over all runs)", 0.0, pinned_moved, 0, "abs", "m"),
    ]
    return exps


# ------------------------------------------------------------------------- stage 2

S2_TEXT = """
Stability is not accuracy. For a single mode of angular frequency w, backward Euler's step is
x+ = x + dt v+, v+ = v - w^2 dt x+. Its 2x2 matrix has eigenvalues (1 +- i w dt)/(1 + w^2 dt^2): a
rotation by atan(w dt), shrunk by 1/sqrt(1 + w^2 dt^2). So each step multiplies every mode's energy
by 1/(1 + w^2 dt^2), whatever its amplitude. Well-resolved motion (w dt << 1) hardly notices, a
mode with w dt = 1 loses half its energy per step, and modes far above the explicit limit vanish
almost at once. That is why large steps are stable, and also why implicitly stepped cloth can look
as if it moved through honey: the damping is set by dt, not by the material.

We measure this on a small cloth without gravity, so that its flat rest shape is an equilibrium.
We excite one in-plane eigenmode (from a dense eigen-decomposition of M^-1 H) with an amplitude of
a micrometre, take three backward-Euler steps with Newton converged, and compare the energy factor
per step with 1/(1 + w^2 dt^2) for w dt from 0.1 to 30. The amplitude factor is its square root.

Order of accuracy: a 9 x 9 cloth falls from rest for 0.05 s, and its final positions are compared
with a reference. The reference is velocity Verlet at 1/4 and 1/8 of the finest step, with its dt^2
error removed by Richardson extrapolation; the size of that correction confirms Verlet's second
order at a step 8 times smaller. Every method uses the same steps, 0.3, 0.15 and 0.075 of the
explicit limit. Halving dt halves backward Euler's error (first order) and quarters Verlet's
(second order). Backward Euler only reaches its asymptotic rate once dt resolves the vibrations
the release excites: at a few times coarser steps it damps them away rather than approximating
them, and its error then hardly shrinks as dt is refined.

Symplectic Euler is first order as well, and the reason is worth seeing. Its positions obey the
same three-term recurrence as Verlet's, x_{n+1} - 2 x_n + x_{n-1} = dt^2 a(x_n). They differ only in
the first step, which adds dt^2 a(x_0) instead of dt^2 a(x_0)/2, as if the initial velocity were off
by dt a(x_0)/2. That single O(dt) error at the start is carried to the end. Start symplectic Euler
from v_0 - dt a(x_0)/2 (the velocity half a step earlier) and its positions are Verlet's to
round-off, hence second order. Starting from an equilibrium, where a(x_0) = 0, gives the same
result automatically.

All runs are fixed: the damping factor and the orders belong to these particular integrators.
"""


def stage_accuracy(ctx):
    cfg = ctx.cfg
    exps = []
    # --- damping of one eigenmode
    scene = cloth(cfg.mode_n, 1.0, E=cfg.E, rho=cfg.rho, B=cfg.B, gravity=0.0)
    model, X = scene.model, scene.model.X
    w, _, shapes = free_modes(model, X, planar=True)
    order = np.argsort(w)
    low, mid, top = order[0], order[len(order) // 2], order[-1]
    amplitude = 1e-6
    cases = [(low, 0.1), (low, 1.0), (mid, 0.3), (mid, 3.0), (top, 30.0)]
    for k, (mode, wdt) in enumerate(cases):
        dt = wdt / w[mode]
        u = shapes[mode] * (amplitude / np.abs(shapes[mode]).max())
        state = model.make_state(X + u)
        E0 = diagnostics.total_energy(model, state)  # the rest shape has zero energy (no gravity)
        be = make_integrator("backward-euler", solver="cholesky", tol=1e-12, newton_iterations=5, newton_tol=1e-12)
        steps, K, W = simulate(ctx, f"mode{mode}_wdt{wdt:g}", model, state, dt, 3, be, every=1, fixed=True,
                               log=cloth_logger(scene, (1.2 * k, 0.0, 0.0)))
        factor = float(((K[-1] + W[-1]) / E0) ** (1.0 / 3.0))
        theory = 1.0 / (1.0 + wdt * wdt)
        ctx.progress(f"mode {mode} (w = {w[mode]:.4g} rad/s), w dt = {wdt:g}: energy factor per step {factor:.6f}, "
                     f"theory {theory:.6f}; amplitude factor {math.sqrt(factor):.6f}")
        exps.append(Experiment(f"backward Euler: energy factor per step of a mode at w dt = {wdt:g} is "
                               "1/(1 + w^2 dt^2)", theory, factor, 1e-4, "rel"))

    # --- convergence orders
    scene = cloth(cfg.conv_n, 1.0, E=cfg.E, rho=cfg.rho, B=cfg.B)
    model, X = scene.model, scene.model.X
    T = cfg.conv_time
    dt_limit = 2.0 / math.sqrt(abs(lambda_max_power(model)))
    n0 = max(20, int(math.ceil(T / (0.3 * dt_limit))))  # coarsest level: dt <= 0.3 x the explicit limit
    levels = [n0, 2 * n0, 4 * n0]

    def run(name, integ, n_steps, v0=None):
        state = model.make_state(X, v0)
        simulate(ctx, name, model, state, T / n_steps, n_steps, integ, every=n_steps, energy_every=n_steps,
                 fixed=True, log=cloth_logger(scene))
        return state.numpy().x

    ref_fine = run("reference_verlet_fine", "velocity-verlet", 8 * levels[-1])
    ref_coarse = run("reference_verlet_coarse", "velocity-verlet", 4 * levels[-1])
    ref = (4.0 * ref_fine - ref_coarse) / 3.0  # Richardson: removes Verlet's dt^2 term
    ref_err = float(np.abs(ref_fine - ref).max())
    errors, finals = {}, {}
    be = make_integrator("backward-euler", solver="cholesky", tol=1e-12, newton_iterations=20, newton_tol=1e-9)
    for name, integ in (("symplectic-euler", "symplectic-euler"), ("velocity-verlet", "velocity-verlet"),
                        ("backward-euler", be)):
        finals[name] = [run(f"{name}_N{n}", integ, n) for n in levels]
        errors[name] = [float(np.abs(x - ref).max()) for x in finals[name]]
    # symplectic Euler started half a step earlier: v0 - dt a(x0)/2, a(x0) = g on the free vertices at rest
    n = levels[-1]
    v_half = np.where(model.free[:, None], -0.5 * (T / n) * model.gravity[None, :], 0.0)
    x_shifted = run(f"symplectic-euler_half-step-start_N{n}", "symplectic-euler", n, v_half)
    same = float(np.abs(x_shifted - finals["velocity-verlet"][-1]).max()) / errors["velocity-verlet"][-1]
    orders = {}
    dts = T / np.asarray(levels, dtype=float)
    for name in errors:
        ratios = np.asarray(errors[name][:-1]) / np.asarray(errors[name][1:])
        orders[name] = math.log2(ratios[-1])  # from the two finest levels
        ctx.progress(f"{name}: dt = {', '.join(f'{d * 1e3:.3g}' for d in dts)} ms -> max position error "
                     f"{', '.join(f'{e:.3e}' for e in errors[name])} m "
                     f"(ratios {', '.join(f'{r:.3f}' for r in ratios)}), "
                     f"order {orders[name]:.3f} from the finest pair")
    ctx.progress(f"reference: Richardson correction {ref_err:.1e} m; symplectic Euler from the half-step velocity "
                 f"vs Verlet: {same:.1e} of Verlet's error")
    exps += [
        Experiment("backward Euler converges at first order in dt (log2 of the error ratio, finest halving)", 1.0,
                   orders["backward-euler"], 0.1, "abs"),
        Experiment("symplectic Euler (from rest under gravity) converges at first order", 1.0,
                   orders["symplectic-euler"], 0.1, "abs"),
        Experiment("velocity Verlet converges at second order", 2.0, orders["velocity-verlet"], 0.15, "abs"),
        Experiment("symplectic Euler started from v0 - dt a(x0)/2 has Verlet's positions (difference / Verlet's "
                   "error)", 0.0, same, 1e-6, "abs"),
        Experiment("the reference's Verlet run has 1/64 of the finest run's error (8x smaller dt, second order; "
                   "Richardson correction / finest error)", 1.0 / 64.0, ref_err / errors["velocity-verlet"][-1], 0.05,
                   "rel"),
    ]
    return exps


# ------------------------------------------------------------------------- stage 3

S3_TEXT = """
An explicit step is cheap (one force evaluation), but the CFL limit sets how many are needed:
1/dt grows like the speed of sound, sqrt(E/rho). A backward-Euler step costs a linear solve, but
its dt is chosen for the picture; here it is one video frame, 1/60 s. (A dt chosen to meet an
accuracy target would depend on what is measured, and stage 2 showed how much damping a
frame-sized step brings.) The question is where the two costs cross as the material stiffens.

We sweep the stretching modulus of a 32 x 32 cloth from a soft rubbery sheet (10 N/m) to a woven
fabric (1e5 N/m) and time each method over the same eight frames (0.13 s) after the flat
release. Symplectic Euler runs at 0.9 x its true limit at rest (from power iteration; in
practice one would use the safe Gershgorin bound, a little smaller). That limit belongs to the
linearisation about the rest shape. The softest sheets, kept in their plane, are crushed by
their own weight within a fraction of a second, and compressed springs stiffen sideways. At E =
10 and 100 N/m, 0.9 x the rest limit blows up after about a quarter of a second, so a usable explicit step for
the whole fall would be smaller still. The timed frames end well before that, and every timed
run is checked to have stayed bounded. Backward Euler takes one Newton iteration per step
(Baraff and Witkin's linearised step, what cloth simulators use at frame rate) and solves with
block-Jacobi PCG (relative residual 1e-8) or with a sparse Cholesky factorisation. Wall-clock
times on a shared 2-core machine are noisy, so they are printed, not asserted. The counts behind
them are deterministic, and those are checked: explicit steps per simulated second grow like
E^(1/2); backward Euler keeps its frame step with bounded energy at every E; and PCG's
iterations per solve grow with E, but no faster than the square root of the condition-number
bound 1 + w_max^2 dt^2.

In fact they grow much more slowly than that bound, and then stop growing (about 330 per solve on
this mesh). Once the mass term is negligible, the system is essentially the stiffness matrix, and
the number of CG iterations is set by how many sweeps it takes to carry information across the
mesh. That depends on the mesh, not on E. This is the notes' remark in numbers: the implicit
solve passes information across the whole cloth in every step, and the price, paid per step,
stops growing with stiffness. A sparse factorisation costs the same at every E. So above a
crossover modulus implicit stepping wins, by a factor that keeps growing like sqrt(E); below it,
explicit stepping is cheaper. The crossover is printed and written to the recording, both in
seconds and in sweeps over the mesh.

All runs are fixed: the comparison is between these two integrators.
"""


def _crossover(Es, t_explicit, t_implicit):
    """E where the explicit/implicit cost ratio crosses 1 (log-linear interpolation), or None."""
    r = np.log(np.asarray(t_explicit) / np.asarray(t_implicit))
    logE = np.log(np.asarray(Es))
    for i in range(len(r) - 1):
        if r[i] < 0 <= r[i + 1] or r[i] >= 0 > r[i + 1]:
            f = r[i] / (r[i] - r[i + 1])
            return float(math.exp(logE[i] + f * (logE[i + 1] - logE[i])))
    return None


def stage_speed(ctx):
    cfg = ctx.cfg
    Es = np.geomspace(cfg.E_soft, cfg.E_stiff, cfg.E_values)
    rows = []
    be_energy_excess = -math.inf
    blown = []
    window = cfg.frames * cfg.frame_dt  # every run covers the same simulated time from the same release
    for k, E in enumerate(Es):
        scene = cloth(cfg.speed_n, 1.0, E=float(E), rho=cfg.rho, B=cfg.B)
        model, X = scene.model, scene.model.X
        dt_limit = 2.0 / math.sqrt(abs(lambda_max_power(model, rtol=1e-6)))
        E0 = diagnostics.total_energy(model, model.make_state(X))
        bound = E0 + float(model.mass.sum()) * float(np.linalg.norm(model.gravity)) * 1.0  # + weight x 1 m
        offset = (1.2 * k, 0.0, 0.0)
        row = dict(E=float(E), sqrt_cond=math.sqrt(1.0 + (2.0 / dt_limit * cfg.frame_dt) ** 2))
        runs = [("symplectic", "symplectic-euler", 0.9 * dt_limit, int(math.ceil(window / (0.9 * dt_limit))))]
        runs += [(f"backward_euler_{solver}", Watched(make_integrator("backward-euler", solver=solver, tol=1e-8,
                                                                    newton_iterations=1, max_iter=100000)),
                  cfg.frame_dt, cfg.frames) for solver in ("pcg", "cholesky")]
        for j, (label, integ, dt, n) in enumerate(runs):
            stamps = []
            state = model.make_state(X)
            name = f"E{E:.3g}_{label}"
            try:
                steps, K, W = simulate(ctx, name, model, state, dt, n, integ, every=1, energy_every=n,
                                       energy_bound=bound, fixed=True,
                                       log=cloth_logger(scene, (offset[0], 0.0, -1.2 * j), skip=n),
                                       observe=lambda s, st: stamps.append(time.perf_counter()))
            except BlowUpError as exc:
                blown.append(name)
                ctx.progress(f"{name}: {exc}")
                K = W = np.array([math.inf])
            per_step = float(np.median(np.diff(stamps[1:]))) if len(stamps) > 2 else math.nan  # first step left out
            row[f"t_{label}"] = per_step / dt  # wall-clock seconds per simulated second
            if j == 0:
                row.update(dt_exp=dt, steps_exp=1.0 / dt)
            else:
                be_energy_excess = max(be_energy_excess, float((K + W).max() - E0))
                row[f"cg_{label}"] = float(np.mean(integ.iterations)) if integ.iterations else math.nan
        row["t_exp"], row["t_pcg"], row["t_cholesky"] = (row["t_symplectic"], row["t_backward_euler_pcg"],
                                                         row["t_backward_euler_cholesky"])
        row["cg_pcg"] = row["cg_backward_euler_pcg"]
        rows.append(row)
        ctx.progress(f"E = {E:.3g} N/m: explicit dt {row['dt_exp'] * 1e6:.1f} us, {row['steps_exp']:.0f} steps/s, "
                     f"{row['t_exp']:.2f} s per simulated s; backward Euler dt {cfg.frame_dt * 1e3:.2f} ms: pcg "
                     f"{row['cg_pcg']:.0f} CG iterations/step, {row['t_pcg']:.2f} s per simulated s; cholesky "
                     f"{row['t_cholesky']:.2f} s per simulated s")
    steps_exp = np.array([r["steps_exp"] for r in rows])
    cg = np.array([r["cg_pcg"] for r in rows])
    slope_exp = fit_slope(np.log(Es), np.log(steps_exp))
    slope_cg = fit_slope(np.log(Es), np.log(cg))
    slope_cond = fit_slope(np.log(Es), np.log([r["sqrt_cond"] for r in rows]))
    # work in sweeps over the mesh per simulated second: one force evaluation per explicit step,
    # one Hessian product per CG iteration plus one force evaluation per backward-Euler step
    sweeps_exp = steps_exp
    sweeps_pcg = (cg + 1.0) / cfg.frame_dt
    count_cross = _crossover(Es, sweeps_exp, sweeps_pcg)
    lines = ["| E (N/m) | explicit dt (us) | explicit steps / sim s | PCG iterations / step | sqrt(1 + w_max^2 dt^2) | "
             "explicit s / sim s | BE-PCG s / sim s | BE-Cholesky s / sim s |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['E']:.3g} | {r['dt_exp'] * 1e6:.1f} | {r['steps_exp']:.0f} | {r['cg_pcg']:.0f} | "
                     f"{r['sqrt_cond']:.0f} | {r['t_exp']:.3g} | {r['t_pcg']:.3g} | {r['t_cholesky']:.3g} |")
    summary = []
    for solver in ("pcg", "cholesky"):
        cross = _crossover(Es, [r["t_exp"] for r in rows], [r[f"t_{solver}"] for r in rows])
        if cross is None:
            faster = "backward Euler" if rows[0][f"t_{solver}"] < rows[0]["t_exp"] else "symplectic Euler"
            text = (f"backward Euler ({solver}) vs symplectic Euler: no crossover in the sweep "
                    f"({faster} faster throughout)")
        else:
            text = (f"backward Euler ({solver}) vs symplectic Euler: wall-clock crossover at E ~ {cross:.3g} N/m "
                    f"(explicit cheaper below, implicit above)")
        summary.append(text)
        ctx.progress(text)
    counts = (f"in sweeps over the mesh per simulated second (explicit: 1 per step; PCG: 1 per CG iteration + 1 per "
              f"step) the crossover is " + (f"at E ~ {count_cross:.3g} N/m" if count_cross else "outside the sweep"))
    summary.append(counts)
    ctx.progress(counts)
    ctx.progress(f"explicit steps per simulated second ~ E^{slope_exp:.3f}; PCG iterations per step ~ E^{slope_cg:.3f} "
                 f"(sqrt(1 + w_max^2 dt^2) ~ E^{slope_cond:.3f})")
    ctx.rec.markdown("timings", "## Wall-clock per simulated second (timed on this run's machine; noisy)\n\n"
                     + "\n".join(lines) + "\n\n" + "\n\n".join(summary)
                     + f"\n\nExplicit steps per simulated second ~ E^{slope_exp:.3f}; PCG iterations per step ~ "
                       f"E^{slope_cg:.3f}; sqrt(1 + w_max^2 dt^2) ~ E^{slope_cond:.3f}.")
    return [
        Experiment(f"every timed run stayed bounded over the {cfg.frames} frames after the release (runs that "
                   "blew up)", 0, len(blown), 0, "abs"),
        Experiment("explicit steps per simulated second grow like E^(1/2) (log-log slope over the sweep)", 0.5,
                   slope_exp, 0.02, "rel"),
        Experiment(f"backward Euler keeps dt = {cfg.frame_dt:.4g} s at every E: energy never exceeds the start "
                   "(largest excess over the sweep)", 0.0, be_energy_excess, 0, "<=", "J"),
        Experiment("PCG iterations per step grow with E (stiffest / softest)", 1.0, cg[-1] / cg[0], 0, ">="),
        Experiment("PCG iterations per step grow no faster than sqrt(1 + w_max^2 dt^2), the square root of the "
                   "condition-number bound (log-log slopes over the sweep)", slope_cond, slope_cg, 0, "<="),
    ]


LESSON_STAGES = [
    Stage("the CFL limit, and stepping far over it", S1_TEXT, stage_cfl),
    Stage("what implicit costs: numerical damping and first-order accuracy", S2_TEXT, stage_accuracy),
    Stage("what implicit buys: wall-clock per simulated second against stiffness", S3_TEXT, stage_speed),
]

LESSON = Lesson(
    id="explicit-vs-implicit",
    title="Explicit vs implicit time stepping: the CFL limit, backward Euler's stability, damping and cost",
    summary="The hanging cloth under symplectic Euler just below and just above its CFL limit, and under "
            "backward Euler at 10x and 100x that limit; backward Euler's numerical damping 1/(1 + w^2 dt^2) "
            "and first-order accuracy against the explicit methods' orders; wall-clock per simulated second "
            "against stiffness and the crossover modulus.",
    config=ExplicitImplicitConfig,
    stages=LESSON_STAGES,
    order=5,
)
