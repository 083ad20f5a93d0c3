"""The stages of ``explicit-vs-implicit`` (their narratives are in narrative.md) and the
measurements they make; the cloth's modes, the seed, the watched backward-Euler integrator, the
drawings and the estimates of each stage's time are in :mod:`.scene`.

Every run of this lesson is fixed: each claim is about one particular integrator, so
``--integrator/--solver/--tol`` leave them alone. numpy is used for set-up, eigen-analysis and
the reference formulas.

This file is longer than the suite's usual 500 lines: stage 1 alone makes six measurements of the
hanging cloth (its limit, the runs below and above it, the seed's modal growth, backward Euler far
above it and why a run has not settled), each with the reasons it gives when a claim fails.
"""
import math
import time
from dataclasses import dataclass

import numpy as np

from engine import diagnostics
from engine.analysis import fit_slope
from engine.constants import G
from engine.errors import BlowUpError
from engine.integrators import make_integrator
from engine.stability import gershgorin_lambda_max, lambda_max_power
from engine.theory.schemes import symplectic_euler_growth
from engine.fields import vec3_ndarray
from lessons.views import RunView
from engine.scenes import cloth
from engine.statics import solve_static

from .._framework import Experiment
from .._measure import edge_strain, vertex_strain
from .._scene import simulate
from .scene import Watched, announce, cloth_logger, draw_cost_curves, free_modes, in_plane_seed, timings_table

EXPLICIT_CHUNK = 50            # stage 3: explicit steps per timed launch (about a 60 fps frame's at 3e-4 s)
SETTLED = 1e-3                 # "reaches the hanging equilibrium": max |x - x_eq| / sag at the end


# ------------------------------------------------------------------------- stage 1

def stage_cfl(ctx):
    cfg = ctx.cfg
    announce(ctx, 1)
    scene = cloth(cfg.n, 1.0, E=cfg.E, rho=cfg.rho, B=cfg.B)
    cl, exps = _hanging_cloth(ctx, scene)
    survived, n_below, pinned_moved = _symplectic_below(ctx, cl)
    exps.append(Experiment(f"symplectic Euler at {cfg.below:g} x the limit survives {n_below} steps "
                           f"({cfg.explicit_time:g} s)", n_below, survived, 0, ">=", id="symplectic-below-survives"))
    exps += _symplectic_above(ctx, cl)
    exps += _backward_euler_far_above(ctx, cl, pinned_moved)
    return exps


@dataclass
class _HangingCloth:
    """Stage 1's scene and what every run in it is measured against."""

    scene: object
    x_eq: np.ndarray       # the hanging equilibrium
    sag: float             # its largest displacement from the flat rest shape
    dt_true: float         # the explicit limit 2/w_max (power iteration at x_eq)
    modes: tuple | None    # (w^2, shapes) of the dense eigen-decomposition at x_eq (small cloths only)
    seed: np.ndarray       # the in-plane displacement every run starts from (or its opposite)
    E0: float              # the flat start's energy
    bound: float           # the blow-up bound: E0 + what the fall can release
    strain_scale: float    # the strain drawn at full colour

    @property
    def model(self):
        return self.scene.model


def _hanging_cloth(ctx, scene):
    """The hanging equilibrium, the explicit limit (power iteration, checked against the dense
    eigenvalue on small cloths; Gershgorin's bound and two cruder estimates printed), the seed
    and the energy bound. Returns (the measured scene, the limit's experiments)."""
    cfg = ctx.cfg
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
    exps = []
    modes = None
    if 3 * cfg.n * cfg.n <= 2000:  # dense eigen-decomposition on small cloths
        _, w2, shapes = free_modes(model, x_eq, planar=False)
        modes = (w2, shapes)
        exps.append(Experiment("power iteration's w_max^2 equals the dense eigenvalue of M^-1 H (hanging state)",
                               float(w2.max()), lam_power, 1e-4, "rel", "1/s^2", id="power-iteration-w-max"))
    _print_cruder_limits(ctx, scene, dt_true, dt_gersh)
    exps.append(Experiment(f"Gershgorin's dt is safe: at most the true limit (ratio {dt_gersh / dt_true:.3f})",
                           dt_true, dt_gersh, 0, "<=", "s", id="gershgorin-dt-safe"))
    seed = in_plane_seed(model, cfg.seed_size, cfg.seed)
    # the start is the seeded flat sheet (the twin run's opposite seed stores the same energy to third order)
    E0 = diagnostics.total_energy(model, model.make_state(X + seed))
    E_eq = model.potential_energy(x_eq_nd)
    E_flat = diagnostics.total_energy(model, model.make_state(X))
    release = E_flat - E_eq  # what the fall from the flat shape to the hanging one can set free
    # symplectic Euler's K + W of a mode at w dt = 2 b swings up to 1/(1 - b^2) of what it holds: the seed's
    # energy (fast modes) may appear that much larger at 'below' x the limit without anything blowing up
    bound = E0 + release + max(E0 - E_flat, 0.0) * cfg.below ** 2 / (1 - cfg.below ** 2)
    ctx.progress(f"energy: start {E0:.6g} J, equilibrium {E_eq:.6g} J; blow-up bound start + release = {bound:.6g} J")
    # full colour: rho g L / E, the strain of the 1 m sheet's weight hung from its whole top edge (about the
    # median strain of the hanging cloth; its corners, where the weight gathers, go beyond it)
    strain_scale = cfg.rho * G * 1.0 / cfg.E
    return _HangingCloth(scene, x_eq, sag, dt_true, modes, seed, E0, bound, strain_scale), exps


def _print_cruder_limits(ctx, scene, dt_true, dt_gersh):
    """The explicit limit by Gershgorin, by the per-spring sum 4c/L^2 (every spring adds 4 c/L^2 to
    both of its vertices' rows) and by the rod formula h/c, as fractions of the true limit."""
    cfg = ctx.cfg
    model = scene.model
    c = math.sqrt(cfg.E / cfg.rho)
    h = 1.0 / (cfg.n - 1)
    sp = scene.springs
    crude = np.zeros(model.n)
    np.add.at(crude, sp.edges_np.ravel(), np.repeat(4.0 * sp.c_np / sp.L_np ** 2, 2))
    dt_crude = 2.0 / math.sqrt(float((crude[model.free] / model.mass[model.free]).max()))
    ctx.progress(f"explicit limit 2/w_max = {dt_true * 1e3:.4f} ms (power iteration); Gershgorin bound "
                 f"{dt_gersh * 1e3:.4f} ms = {dt_gersh / dt_true:.3f} x the true limit; per-spring sum 4c/L^2: "
                 f"{dt_crude / dt_true:.3f} x; the rod formula h/c = {h / c * 1e3:.4f} ms = {h / c / dt_true:.3f} x")


def _symplectic_below(ctx, cl: _HangingCloth):
    """Symplectic Euler just below the limit: (steps survived, steps of the run, how far the pins
    moved)."""
    cfg = ctx.cfg
    model, X = cl.model, cl.model.X
    dt = cfg.below * cl.dt_true
    n_below = int(math.ceil(cfg.explicit_time / dt))
    state = model.make_state(X + cl.seed)
    # stage 1's energy plots show the total's relative change: the total is mostly the weight's potential
    # energy, beside which a blow-up (bound: start + release, a few mJ) or backward Euler's damping is invisible
    try:
        steps, K, W = simulate(ctx, f"symplectic_{cfg.below:g}x", model, state, dt, n_below, "symplectic-euler",
                               every=cfg.record_every, energy_bound=cl.bound, fixed=True,
                               log=cloth_logger(cl.scene, cl.strain_scale),
                               view=RunView(label=f"symplectic Euler, {cfg.below:g} × the limit", energy="drift"))
        survived = int(steps[-1])
        ctx.progress(f"{cfg.below:g} x limit: largest energy excess {(K + W).max() - cl.E0:.2e} J over {n_below} "
                     "steps")
    except BlowUpError as exc:
        survived = exc.step
        ctx.progress(f"{cfg.below:g} x limit: {exc}")
    pinned_moved = float(np.abs(state.numpy().x[model.pinned] - X[model.pinned]).max())
    return survived, n_below, pinned_moved


def _symplectic_above(ctx, cl: _HangingCloth):
    """Symplectic Euler just above the limit blows up, detected at the step. A second run with the
    opposite seed gives the seed's own evolution as the odd part (x+ - x-)/2 (the fall, and
    whatever the release itself excites, cancel), to compare with the modal prediction."""
    cfg = ctx.cfg
    model, X = cl.model, cl.model.X
    dt = cfg.above * cl.dt_true
    n_above = int(math.ceil(cfg.explicit_time / dt))
    # shown over about 1.5 x the steps the fastest mode (growing lam per step) takes to lift the seed's energy
    # (at most 1/2 w_max^2 M |seed|^2) to the blow-up bound, not over the second it was planned for
    lam = symplectic_euler_growth((cfg.above * 2.0) ** 2)
    seed_energy = 0.5 * (2.0 / cl.dt_true) ** 2 * float((model.mass[:, None] * cl.seed ** 2).sum())
    seed_energy = max(seed_energy, 1e-300)  # (a seed that small is refused up front; never divide by 0)
    grow = math.log(max((cl.bound - cl.E0) / seed_energy, 1.0)) / (2.0 * math.log(lam)) if lam > 1 else n_above
    span = min(n_above, int(math.ceil(1.5 * grow)) + 1) * dt
    detected, message, tracks = [], [], []
    for sign, name, what in ((1.0, f"symplectic_{cfg.above:g}x", ""),
                             (-1.0, f"symplectic_{cfg.above:g}x_opposite_seed", ", opposite seed")):
        state = model.make_state(X + sign * cl.seed)
        track = []
        try:
            simulate(ctx, name, model, state, dt, n_above, "symplectic-euler", every=1, energy_bound=cl.bound,
                     fixed=True, log=cloth_logger(cl.scene, cl.strain_scale),
                     observe=lambda s, st: track.append(st.x.to_numpy().astype(np.float64)),
                     view=RunView(label=f"symplectic Euler, {cfg.above:g} × the limit{what}", energy="drift",
                                  span=span))
            detected.append(n_above)
            message.append("")
        except BlowUpError as exc:
            detected.append(exc.step)
            message.append(str(exc))
        tracks.append(track)
    ctx.progress(f"{cfg.above:g} x limit: {message[0] or 'no blow-up'}")
    short = "" if n_above >= 1.5 * grow else (
        f"too short: the run has {n_above} steps (--explicit-time {cfg.explicit_time:g} s), and the seed's fastest mode, "
        f"growing {lam:.3g} x per step, needs about {grow:.0f} to lift its energy ({seed_energy:.2g} J) to the blow-up "
        f"bound; a longer --explicit-time or a larger --seed-size shows it")
    exps = [
        Experiment(f"symplectic Euler at {cfg.above:g} x the limit blows up within {n_above} steps (step detected)",
                   n_above - 1, detected[0], 0, "<=", id="symplectic-above-blows-up", reason=short),
        Experiment("the blow-up message names the CFL limit", 1.0, float("CFL limit" in message[0]), 0, "abs",
                   id="blow-up-message-names-cfl", reason=short),
    ]
    if cl.modes is not None and min(len(tracks[0]), len(tracks[1])) >= 2:
        exps.append(_seed_growth(ctx, cl, dt, tracks))
    return exps


def _seed_growth(ctx, cl: _HangingCloth, dt, tracks):
    """The odd part of the two runs against the seed advanced mode by mode with symplectic Euler's
    step matrix, linearised about the start (the flat sheet: the runs stay within a few mm of it)."""
    cfg = ctx.cfg
    model, X = cl.model, cl.model.X
    _, w2, shapes = free_modes(model, X, planar=True)
    last = min(len(tracks[0]), len(tracks[1])) - 1  # the last step both runs reached
    odd = 0.5 * (tracks[0][last] - tracks[1][last])
    measured = math.sqrt(float((model.mass[:, None] * odd ** 2).sum()))
    # each mode k: x+ = (1 - w_k^2 dt^2) x + dt v, v+ = v - w_k^2 dt x, from x = c_k, v = 0
    coef = np.einsum("kij,i,ij->k", shapes, model.mass, cl.seed)  # M-orthonormal shapes
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
    # the prediction is linear about the flat sheet: it holds while the runs stay near it
    moved = float(np.abs(0.5 * (tracks[0][last] + tracks[1][last]) - X).max())
    h = 1.0 / (cfg.n - 1)
    reason = (f"nonlinear: the prediction is linearised about the flat sheet, but in the {last} steps to the blow-up "
              f"({last * dt:.3g} s) the cloth moved {moved:.3g} m ({moved / h:.2g} of a spacing) as it fell; a stiffer "
              f"--E (a shorter limit, fewer seconds to the blow-up) or a larger --seed-size keeps it near the flat sheet")
    return Experiment(f"the seed grows as the modes' step matrices predict ({unstable} modes with w dt > 2; "
                      f"growth over {last} steps)", predicted / start, measured / start, 1e-2, "rel",
                      id="seed-growth-modal", reason=reason)


def _backward_euler_far_above(ctx, cl: _HangingCloth, pinned_moved: float):
    """Backward Euler far above the limit: at ``big`` x one Newton iteration per step (Baraff-Witkin's
    linearised step), at ``huge`` x Newton iterated to convergence (the incremental potential's
    minimiser). Energy bounded, the hanging equilibrium reached, every solve converged, the pins
    still (``pinned_moved``: how far they moved in the explicit run)."""
    cfg = ctx.cfg
    model, X = cl.model, cl.model.X
    w1 = None
    if cl.modes is not None:
        w2, shapes = cl.modes
        in_plane = np.abs(shapes[:, :, 1]).max(axis=1) < 1e-9 * np.abs(shapes).max(axis=(1, 2))
        if np.any(in_plane & (w2 > 0)):
            w1 = math.sqrt(float(w2[in_plane & (w2 > 0)].min()))
    exps, residuals, bad_steps = [], [], 0
    for which, factor, newton in (("big", cfg.big, 1), ("huge", cfg.huge, 50)):
        dt = factor * cl.dt_true
        n_steps = int(math.ceil(cfg.implicit_time / dt))
        be = Watched(make_integrator("backward-euler", solver="pcg", tol=1e-8, newton_iterations=newton,
                                     newton_tol=1e-8, max_iter=5000, exact_near_solution=False))
        state = model.make_state(X + cl.seed)
        every = max(1, min(cfg.record_every, n_steps // 20))
        newton_text = "1 Newton step" if newton == 1 else "Newton converged"
        steps, K, W = simulate(ctx, f"backward_euler_{factor:g}x", model, state, dt, n_steps, be, every=every,
                               fixed=True, log=cloth_logger(cl.scene, cl.strain_scale),
                               view=RunView(label=f"backward Euler, {factor:g} × the limit, {newton_text}",
                                            energy="drift"))
        x = state.numpy().x
        pinned_moved = max(pinned_moved, float(np.abs(x[model.pinned] - X[model.pinned]).max()))
        distance = float(np.abs(x - cl.x_eq).max()) / cl.sag
        bad = sum(1 for m, c_ in zip(be.monotone, be.converged) if not (m and c_))
        if w1 is not None:
            ctx.progress(f"slowest in-plane mode w1 = {w1:.4g} rad/s: linear theory leaves (1 + w1^2 dt^2)^(-N/2) = "
                         f"{(1 + (w1 * dt) ** 2) ** (-n_steps / 2):.1e} of its amplitude after {n_steps} steps")
        ctx.progress(f"backward Euler at {factor:g} x ({dt * 1e3:.3g} ms, {n_steps} steps): Newton "
                     f"{np.mean(be.newton):.1f} iterations/step, CG {np.sum(be.iterations) / max(be.solves, 1):.0f} "
                     f"iterations/solve, largest residual {max(be.residuals):.1e}; energy max - start "
                     f"{(K + W).max() - cl.E0:.2e} J; distance to equilibrium / sag {distance:.1e}")
        exps += [
            Experiment(f"backward Euler at {factor:g} x the limit: total energy never exceeds the start "
                       "(initial energy + work of gravity)", cl.E0, float((K + W).max()), 0, "<=", "J",
                       id=f"backward-euler-{which}-energy-bounded"),
            Experiment(f"backward Euler at {factor:g} x: reaches the hanging equilibrium after "
                       f"{n_steps * dt:.3g} s (max |x - x_eq| / largest sag)", 0.0, distance, SETTLED, "abs",
                       id=f"backward-euler-{which}-reaches-equilibrium",
                       reason=_unsettled_reason(ctx, cl, w1, dt, n_steps, factor, distance)),
        ]
        residuals.append(max(be.residuals))
        bad_steps += bad
    return exps + [
        Experiment(f"every Newton iteration lowered the incremental potential, and at {cfg.huge:g} x Newton "
                   "converged in every step (steps that failed)", 0, bad_steps, 0, "abs", id="newton-steps-sound"),
        Experiment("every linear solve reached its tolerance (largest relative residual)", 1e-8, max(residuals), 0,
                   "<=", id="linear-solves-converged"),
        Experiment("pinned corners never moved (max displacement over all runs)", 0.0, pinned_moved, 0, "abs", "m",
                   id="pins-never-moved"),
    ]


def _unsettled_reason(ctx, cl: _HangingCloth, w1, dt: float, n_steps: int, factor: float, distance: float) -> str:
    """Why a backward-Euler run has not settled, when linear theory says it cannot have: the cloth is
    undamped, and only the scheme's numerical damping (1 + w^2 dt^2)^(-1/2) per step brings it to rest;
    its slowest in-plane mode w1 keeps (1 + w1^2 dt^2)^(-N/2) of its amplitude. Computed only for a run
    that did not settle (w1 by shift-invert Lanczos where the dense modes were not computed)."""
    if distance <= SETTLED:
        return ""
    w1 = slowest_in_plane(cl.model, cl.x_eq) if w1 is None else w1
    left = (1 + (w1 * dt) ** 2) ** (-n_steps / 2)
    if left <= SETTLED / 3:
        return ""  # theory says it should have settled: no excuse to give
    needed = 2 * dt * math.log(1 / SETTLED) / math.log1p((w1 * dt) ** 2)
    return (f"numerical damping too weak at this dt: the cloth itself is undamped, and backward Euler at {factor:g} x the "
            f"limit (dt = {dt * 1e3:.3g} ms; the limit shrinks on finer or stiffer cloths) keeps (1 + w1^2 dt^2)^(-N/2) = "
            f"{left:.2g} of its slowest in-plane mode (w1 = {w1:.3g} rad/s) after its {n_steps} steps; settling to "
            f"{SETTLED:g} takes about {needed:.3g} s (--implicit-time) or a larger --{'big' if factor == ctx.cfg.big else 'huge'}")


def slowest_in_plane(model, x) -> float:
    """w1, the slowest in-plane angular frequency of M^-1 H at x (the cloth's own plane, x and z), by
    shift-invert Lanczos on the dense in-plane Hessian (scipy): for the reason of a failure only."""
    from scipy.sparse.linalg import eigsh

    H = model.dense_hessian(vec3_ndarray(model.n, x), psd=False)
    free = np.flatnonzero(model.free)
    dofs = (3 * free[:, None] + np.array([0, 2])[None, :]).ravel()
    s = 1.0 / np.sqrt(np.repeat(model.mass[free], 2))
    A = s[:, None] * H[np.ix_(dofs, dofs)] * s[None, :]
    w2 = eigsh(A, k=1, sigma=0.0, which="LM", return_eigenvectors=False)
    return math.sqrt(max(float(w2[0]), 0.0))


# ------------------------------------------------------------------------- stage 2

def stage_accuracy(ctx):
    announce(ctx, 2)
    return _mode_damping(ctx) + _convergence_orders(ctx)


def _mode_damping(ctx):
    """One in-plane eigenmode of a small cloth without gravity, three backward-Euler steps with
    Newton converged: the energy factor per step against 1/(1 + w^2 dt^2), w dt from 0.1 to 30."""
    cfg = ctx.cfg
    exps = []
    scene = cloth(cfg.mode_n, 1.0, E=cfg.E, rho=cfg.rho, B=cfg.B, gravity=0.0)
    model, X = scene.model, scene.model.X
    w, _, shapes = free_modes(model, X, planar=True)
    order = np.argsort(w)
    low, mid, top = order[0], order[len(order) // 2], order[-1]
    which = {low: "slowest", mid: "middle", top: "fastest"}
    amplitude = 1e-6
    cases = [(low, 0.1), (low, 1.0), (mid, 0.3), (mid, 3.0), (top, 30.0)]
    gain = 0.05 / amplitude  # the mode drawn 5 cm out of shape
    for mode, wdt in cases:
        dt = wdt / w[mode]
        u = shapes[mode] * (amplitude / np.abs(shapes[mode]).max())
        state = model.make_state(X + u)
        E0 = diagnostics.total_energy(model, state)  # the rest shape has zero energy (no gravity)
        be = make_integrator("backward-euler", solver="cholesky", tol=1e-12, newton_iterations=5, newton_tol=1e-12)
        theory = 1.0 / (1.0 + wdt * wdt)
        view = RunView(label=f"w dt = {wdt:g}, {which[mode]} mode ({mode}), drawn ×{gain:g}")
        steps, K, W = simulate(ctx, f"mode{mode}_wdt{wdt:g}", model, state, dt, 3, be, every=1, fixed=True,
                               log=cloth_logger(scene, float(np.abs(_vertex_strain(scene, X + u)).max()), gain),
                               view=view)
        factor = float(((K[-1] + W[-1]) / E0) ** (1.0 / 3.0))
        ctx.progress(f"mode {mode} (w = {w[mode]:.4g} rad/s), w dt = {wdt:g}: energy factor per step {factor:.6f}, "
                     f"theory {theory:.6f}; amplitude factor {math.sqrt(factor):.6f}")
        exps.append(Experiment(f"backward Euler: energy factor per step of a mode at w dt = {wdt:g} is "
                               "1/(1 + w^2 dt^2)", theory, factor, 1e-4, "rel", id=f"damping-wdt{wdt:g}"))
    return exps


def _vertex_strain(scene, x) -> np.ndarray:
    sp = scene.springs
    return vertex_strain(len(x), sp.edges_np, edge_strain(x, sp.edges_np, sp.L_np))


def _convergence_orders(ctx):
    """A small cloth falls from rest for conv_time: each method's final positions against a
    Richardson-extrapolated Verlet reference at three step sizes; the orders from the finest pair,
    and symplectic Euler from the half-step velocity against Verlet."""
    cfg = ctx.cfg
    scene = cloth(cfg.conv_n, 1.0, E=cfg.E, rho=cfg.rho, B=cfg.B)
    model, X = scene.model, scene.model.X
    T = cfg.conv_time
    dt_limit = 2.0 / math.sqrt(abs(lambda_max_power(model)))
    n0 = max(20, int(math.ceil(T / (0.3 * dt_limit))))  # coarsest level: dt <= 0.3 x the explicit limit
    levels = [n0, 2 * n0, 4 * n0]

    def run(name, integ, n_steps, v0=None):  # measurements only: nothing drawn
        state = model.make_state(X, v0)
        simulate(ctx, name, model, state, T / n_steps, n_steps, integ, every=n_steps, energy_every=n_steps,
                 fixed=True)
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
    # the two runs agree in exact arithmetic; in f64 each of their n steps rounds the positions (|x| ~ 1 m) by
    # eps |x|, a random walk: their difference is good to about sqrt(n) eps max|x| (measured: 0.2-0.4 of that),
    # which on a stiff cloth (many small steps, a tiny Verlet error) can exceed 1e-6 of Verlet's error
    same_tol = max(1e-6, 4 * math.sqrt(n) * np.finfo(np.float64).eps * float(np.abs(x_shifted).max())
                   / errors["velocity-verlet"][-1])

    def pre_asymptotic(name):
        r = np.asarray(errors[name][:-1]) / np.asarray(errors[name][1:])
        return (f"not yet asymptotic: the error ratios per halving of dt are {', '.join(f'{q:.3f}' for q in r)} (an order "
                f"p gives 2^p), at w_max dt = {2 * dts[-2] / dt_limit:.2g} and {2 * dts[-1] / dt_limit:.2g} on the finest "
                "pair: the stiff modes the release excites are not resolved by these steps; a larger --rho or a softer "
                "--E (fewer, slower modes per step) brings the fast modes' share down")
    return [
        Experiment("backward Euler converges at first order in dt (log2 of the error ratio, finest halving)", 1.0,
                   orders["backward-euler"], 0.1, "abs", id="backward-euler-first-order",
                   reason=pre_asymptotic("backward-euler")),
        Experiment("symplectic Euler (from rest under gravity) converges at first order", 1.0,
                   orders["symplectic-euler"], 0.1, "abs", id="symplectic-euler-first-order",
                   reason=pre_asymptotic("symplectic-euler")),
        Experiment("velocity Verlet converges at second order", 2.0, orders["velocity-verlet"], 0.15, "abs",
                   id="velocity-verlet-second-order", reason=pre_asymptotic("velocity-verlet")),
        Experiment("symplectic Euler started from v0 - dt a(x0)/2 has Verlet's positions (difference / Verlet's "
                   "error)", 0.0, same, same_tol, "abs", id="half-step-start-is-verlet"),
        Experiment("the reference's Verlet run has 1/64 of the finest run's error (8x smaller dt, second order; "
                   "Richardson correction / finest error)", 1.0 / 64.0, ref_err / errors["velocity-verlet"][-1], 0.05,
                   "rel", id="reference-error-one-64th"),
    ]


# ------------------------------------------------------------------------- stage 3

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
    rows, blown = [], []
    be_energy_excess = -math.inf
    for k, E in enumerate(Es):
        row, excess = _timed_runs(ctx, k, float(E), blown)
        rows.append(row)
        be_energy_excess = max(be_energy_excess, excess)
    steps_exp = np.array([r["steps_exp"] for r in rows])
    cg = np.array([r["cg_pcg"] for r in rows])
    slope_exp = fit_slope(np.log(Es), np.log(steps_exp))
    slope_cg = fit_slope(np.log(Es), np.log(cg))
    slope_cond = fit_slope(np.log(Es), np.log([r["sqrt_cond"] for r in rows]))
    summary = _crossovers(ctx, Es, rows, steps_exp, cg)
    ctx.progress(f"explicit steps per simulated second ~ E^{slope_exp:.3f}; PCG iterations per step ~ E^{slope_cg:.3f} "
                 f"(sqrt(1 + w_max^2 dt^2) ~ E^{slope_cond:.3f})")
    if ctx.rec.enabled:
        draw_cost_curves(ctx.rec, rows, cfg.frame_dt)
    ctx.result_notes.append("## Wall-clock per simulated second (timed on this run's machine; noisy)\n\n"
                            + timings_table(rows) + "\n\n" + "\n\n".join(summary)
                            + f"\n\nExplicit steps per simulated second ~ E^{slope_exp:.3f}; PCG iterations per step "
                              f"~ E^{slope_cg:.3f}; sqrt(1 + w_max^2 dt^2) ~ E^{slope_cond:.3f}.")
    return [
        Experiment(f"every timed run stayed bounded over the {cfg.frames} frames after the release (runs that "
                   "blew up)", 0, len(blown), 0, "abs", id="timed-runs-bounded"),
        Experiment("explicit steps per simulated second grow like E^(1/2) (log-log slope over the sweep)", 0.5,
                   slope_exp, 0.02, "rel", id="explicit-steps-grow-like-sqrt-e"),
        Experiment(f"backward Euler keeps dt = {cfg.frame_dt:.4g} s at every E: energy never exceeds the start "
                   "(largest excess over the sweep)", 0.0, be_energy_excess, 0, "<=", "J",
                   id="backward-euler-energy-bounded-at-every-e"),
        Experiment("PCG iterations per step grow with E (stiffest / softest)", 1.0, cg[-1] / cg[0], 0, ">=",
                   id="pcg-iterations-grow"),
        Experiment("PCG iterations per step grow no faster than sqrt(1 + w_max^2 dt^2), the square root of the "
                   "condition-number bound (log-log slopes over the sweep)", slope_cond, slope_cg, 0, "<=",
                   id="pcg-iterations-below-condition-bound"),
    ]


def _timed_runs(ctx, k: int, E: float, blown: list):
    """The k-th cloth of the sweep (modulus E), timed over the same frames after the release:
    symplectic Euler at 0.9 x its limit at rest, backward Euler (one Newton iteration) with pcg
    and with the fastest direct solver installed ("direct": MKL PARDISO, else Eigen's LL^T) at
    the frame step. Returns (the row of counts and times, backward Euler's
    largest energy excess over the start); runs that blew up are appended to ``blown``."""
    cfg = ctx.cfg
    window = cfg.frames * cfg.frame_dt  # every run covers the same simulated time from the same release
    scene = cloth(cfg.speed_n, 1.0, E=E, rho=cfg.rho, B=cfg.B)
    model, X = scene.model, scene.model.X
    dt_limit = 2.0 / math.sqrt(abs(lambda_max_power(model, rtol=1e-6)))
    E0 = diagnostics.total_energy(model, model.make_state(X))
    bound = E0 + float(model.mass.sum()) * float(np.linalg.norm(model.gravity)) * 1.0  # + weight x 1 m
    row = dict(E=E, sqrt_cond=math.sqrt(1.0 + (2.0 / dt_limit * cfg.frame_dt) ** 2))
    runs = [("symplectic", "symplectic-euler", 0.9 * dt_limit, int(math.ceil(window / (0.9 * dt_limit))))]
    runs += [(f"backward_euler_{solver}", Watched(make_integrator("backward-euler", solver=solver, tol=1e-8,
                                                                newton_iterations=1, max_iter=100000)),
              cfg.frame_dt, cfg.frames) for solver in ("pcg", "direct")]
    be_energy_excess = -math.inf
    for j, (label, integ, dt, n) in enumerate(runs):
        stamps = []
        state = model.make_state(X)
        name = f"E{E:.3g}_{label}"
        # explicit steps are timed in chunks of up to EXPLICIT_CHUNK steps, as a run between two
        # displayed frames takes them (one launch each); a backward-Euler step is one frame's step
        chunk = max(1, min(EXPLICIT_CHUNK, n // 20)) if j == 0 else 1
        try:
            # timed and measured only: nothing drawn (drawing would be timed with the steps)
            steps, K, W = simulate(ctx, name, model, state, dt, n, integ, every=chunk, energy_every=n,
                                   energy_bound=bound, fixed=True,
                                   observe=lambda s, st: stamps.append(time.perf_counter()))
        except BlowUpError as exc:
            blown.append(name)
            ctx.progress(f"{name}: {exc}")
            K = W = np.array([math.inf])
        # the first chunk (compilation, caches) left out
        per_step = float(np.median(np.diff(stamps[1:]))) / chunk if len(stamps) > 2 else math.nan
        row[f"t_{label}"] = per_step / dt  # wall-clock seconds per simulated second
        if j == 0:
            row.update(dt_exp=dt, steps_exp=1.0 / dt)
        else:
            be_energy_excess = max(be_energy_excess, float((K + W).max() - E0))
            row[f"cg_{label}"] = float(np.mean(integ.iterations)) if integ.iterations else math.nan
    row["t_exp"], row["t_pcg"], row["t_direct"] = (row["t_symplectic"], row["t_backward_euler_pcg"],
                                                   row["t_backward_euler_direct"])
    row["cg_pcg"] = row["cg_backward_euler_pcg"]
    row["direct_name"] = runs[2][1].solver.name
    ctx.progress(f"E = {E:.3g} N/m: explicit dt {row['dt_exp'] * 1e6:.1f} us, {row['steps_exp']:.0f} steps/s, "
                 f"{row['t_exp']:.2f} s per simulated s; backward Euler dt {cfg.frame_dt * 1e3:.2f} ms: pcg "
                 f"{row['cg_pcg']:.0f} CG iterations/step, {row['t_pcg']:.2f} s per simulated s; "
                 f"{row['direct_name']} {row['t_direct']:.2f} s per simulated s")
    return row, be_energy_excess


def _crossovers(ctx, Es, rows, steps_exp, cg) -> list[str]:
    """Where implicit stepping becomes cheaper than explicit: in wall-clock per solver, and in
    sweeps over the mesh per simulated second (explicit: one force evaluation per step; PCG: one
    Hessian product per CG iteration plus one force evaluation per step). Printed; returned as text."""
    cfg = ctx.cfg
    count_cross = _crossover(Es, steps_exp, (cg + 1.0) / cfg.frame_dt)
    summary = []
    best = [min(r["t_pcg"], r["t_direct"]) for r in rows]
    for solver, times in (("pcg", [r["t_pcg"] for r in rows]), (rows[0]["direct_name"], [r["t_direct"] for r in rows]),
                          ("the faster of the two", best)):
        cross = _crossover(Es, [r["t_exp"] for r in rows], times)
        if cross is None:
            faster = "backward Euler" if times[0] < rows[0]["t_exp"] else "symplectic Euler"
            text = (f"backward Euler ({solver}) vs symplectic Euler on the {cfg.speed_n}^2 cloth: no crossover in "
                    f"the sweep ({faster} faster throughout)")
        else:
            text = (f"backward Euler ({solver}) vs symplectic Euler on the {cfg.speed_n}^2 cloth: wall-clock "
                    f"crossover at E ~ {cross:.3g} N/m (explicit cheaper below, implicit above)")
        summary.append(text)
        ctx.progress(text)
    counts = ("in sweeps over the mesh per simulated second (explicit: 1 per step; PCG: 1 per CG iteration + 1 per "
              "step) the crossover is " + (f"at E ~ {count_cross:.3g} N/m" if count_cross else "outside the sweep"))
    summary.append(counts)
    ctx.progress(counts)
    return summary
