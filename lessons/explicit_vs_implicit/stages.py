"""Stage 1 of ``explicit-vs-implicit``, the CFL limit and stepping far over it (its narrative is
in narrative.md): the hanging cloth's explicit limit, symplectic Euler just below and just above
it, the seed's modal growth, backward Euler far above it and why a run has not settled, each with
the reasons it gives when a claim fails. What backward Euler costs and buys (stages 2 and 3) is
in :mod:`.stages_tradeoffs`; the cloth's modes, the seed, the watched backward-Euler integrator,
the drawings and the estimates of each stage's time are in :mod:`.scene`.

Every run of this lesson is fixed: each claim is about one particular integrator, so
``--integrator/--solver/--tol`` leave them alone. numpy is used for set-up, eigen-analysis and
the reference formulas.
"""
import math
from dataclasses import dataclass

import numpy as np

from engine import diagnostics
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
from .._scene import simulate
from .scene import Watched, announce, cloth_logger, free_modes, in_plane_seed

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
