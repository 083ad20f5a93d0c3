"""The stages of ``springs`` (their narratives are in narrative.md) and the runs and measurements
only they make; the scenes they build, how those are drawn and what each stage costs are in scene.py.

Runs are *fixed* (stage 2: its claims are about symplectic Euler, velocity Verlet and forward
Euler themselves) or *scene* runs (stage 4's pulses), which use ``--integrator``: the explicit
choices run in the fused kernel, backward Euler through :func:`lessons._scene.simulate` with the
engine's implicit integrator (``--solver/--tol/--newton-iterations`` apply). Stages 1, 3 and 5
do not step in time. numpy is used only for set-up, analysis and the reference formulas the
engine is compared with.

The file runs to about 550 lines because stage 2 alone takes 200 of them: two networks under three
methods, each with its drift, its energy wobble's order (and the round-off that can hide it), its
momenta, and forward Euler's blow-up against a modal prediction.
"""
from __future__ import annotations

import math
import time

import numpy as np
import scipy.linalg as sla

from engine import diagnostics
from engine.analysis import convergence_order, fit_slope
from engine.constants import EXPLICIT, G
from engine.errors import BlowUpError
from engine.integrators import Stepper, get as get_integrator
from engine.integrators.explicit import run_many_steps
from engine.model import Model
from engine.scenes import Rod
from engine.stability import stable_dt_estimate
from engine.statics import solve_static
from lessons.views import RunView

from .._budget import announce
from .._framework import Experiment
from .._measure import (central_difference, central_gradient, expect, modal_tracks, observation_steps,
                        random_rotation, rod_node_strain, track_peaks)
from .._scene import simulate as scene_simulate
from .scene import (FORWARD_EULER_SHOWN, METHOD_NAMES, OneSpring, chain_lengths, chain_model, chain_view,
                    draw_force_density, draw_hanging, draw_one_spring, force_density_exact, frame_view, grid,
                    hanging_rod, rod_on, stage2_plan, stage4_seconds, swinging_chain, tet_frame, u, wobble_time)


# ------------------------------------------------------------------------- stage 1

def stage_one_spring(ctx):
    cfg = ctx.cfg
    rng = np.random.default_rng(11)
    spring = OneSpring(cfg.k, rng)
    configs = [spring.placed(rng, stretch) for stretch in (1.3, 0.8)]  # stretched by 30%, compressed by 20%
    fd_err, dir_err, closed_err, par_err, third_err = _derivative_errors(spring, configs, rng)
    rest_force = float(np.abs(spring.force(spring.X)).max()) / cfg.k
    x = configs[0]
    W0, rigid_err, rot_force_err = _rigid_motion_errors(spring, x, rng)
    W_formula = 0.5 * cfg.k * (np.linalg.norm(x[0] - x[1]) / spring.L - 1.0) ** 2 * spring.L
    if ctx.rec.enabled:
        draw_one_spring(ctx.rec, spring, configs)
    return [
        Experiment("energy W equals 1/2 k (l/L - 1)^2 L", W_formula, W0, 1e-13, "rel", "J", id="energy-formula"),
        Experiment("force equals -dW/dx_i by central differences (rel. error, eps = 1e-6)", 0.0, fd_err, 1e-7, "abs",
                   id="force-is-energy-gradient"),
        Experiment("directional derivative g'(0) = grad W . q for random q (rel. error)", 0.0, dir_err, 1e-7, "abs",
                   id="directional-derivative"),
        Experiment("no force at the rest length (max |f| / k)", 0.0, rest_force, 1e-14, "abs", id="no-force-at-rest"),
        Experiment("force is parallel to the spring: |f x d| / (|f||d|) = sin(angle)", 0.0, par_err, 1e-14, "abs",
                   id="force-along-spring"),
        Experiment("equal and opposite forces on the two ends: |f_i + f_j| / |f_i|", 0.0, third_err, 1e-15, "abs",
                   id="equal-and-opposite"),
        Experiment("energy unchanged by a rigid rotation + translation (rel. change)", 0.0, rigid_err, 1e-12, "abs",
                   id="rigid-motion-energy"),
        Experiment("force turns with the rigid rotation: |f(Rx+t) - R f(x)| / |f|", 0.0, rot_force_err, 1e-12, "abs",
                   id="rigid-motion-force"),
        Experiment("engine force equals the closed form -k (l/L - 1)(x_i - x_j)/l (rel. error)",
                   0.0, closed_err, 1e-13, "abs", id="closed-form-force"),
    ]


def _derivative_errors(spring: OneSpring, configs, rng, eps: float = 1e-6):
    """Largest errors over ``configs`` of: the force against central differences of W, the
    directional derivative along 5 random q against grad W . q, the force against the closed
    form, the force's angle to the spring, and the two ends' force balance."""
    fd_err, dir_err, closed_err, par_err, third_err = 0.0, 0.0, 0.0, 0.0, 0.0
    for x in configs:
        f = spring.force(x)
        fd = -central_gradient(spring.W, x, eps)
        fd_err = max(fd_err, np.linalg.norm(fd - f) / np.linalg.norm(f))
        grad = -f
        for _ in range(5):
            q = rng.standard_normal((2, 3))
            dq = central_difference(spring.W, x, q, eps)  # g'(0)
            dir_err = max(dir_err, abs(dq - np.sum(grad * q)) / (np.linalg.norm(grad) * np.linalg.norm(q)))
        cf = spring.closed_form(x)
        closed_err = max(closed_err, np.linalg.norm(f[0] - cf) / np.linalg.norm(cf))
        d = x[0] - x[1]
        par_err = max(par_err, np.linalg.norm(np.cross(f[0], d)) / (np.linalg.norm(f[0]) * np.linalg.norm(d)))
        third_err = max(third_err, np.linalg.norm(f[0] + f[1]) / np.linalg.norm(f[0]))
    return fd_err, dir_err, closed_err, par_err, third_err


def _rigid_motion_errors(spring: OneSpring, x, rng):
    """(W(x), relative change of W, and of the force against the rotated force) under a random
    rotation and translation."""
    R, t = random_rotation(rng, negate_all=True), rng.standard_normal(3)
    W0, f0 = spring.W(x), spring.force(x)
    xr = x @ R.T + t
    return W0, abs(spring.W(xr) - W0) / W0, np.linalg.norm(spring.force(xr) - f0 @ R.T) / np.linalg.norm(f0)


# ------------------------------------------------------------------------- stage 2

ORDER = {"symplectic-euler": 1, "velocity-verlet": 2}


def stage_conservation(ctx):
    cfg = ctx.cfg
    announce(ctx, stage2_plan(cfg)["seconds"], bound=True)
    exps = _fused_matches_stepwise(ctx)
    nets = {"chain": swinging_chain(cfg), "frame": tet_frame(cfg)}
    for net, (model, x0, v0) in nets.items():
        dt = cfg.dt_fraction * stable_dt_estimate(model)
        scale = None  # the energy the drift is measured against (set by the first run)
        for method in ("symplectic-euler", "velocity-verlet"):
            run_exps, scale = _conservation_run(ctx, net, model, x0, v0, dt, method, scale)
            exps += run_exps
        if net == "chain":
            exps.append(_forward_euler_chain(ctx, model, x0, v0, dt, scale))
    exps += _forward_euler_modes(ctx)
    return exps


def simulate_fused(ctx, name: str, model: Model, state, dt: float, n_steps: int, method: str,
                   every: int, energy_bound: float | None = None, observe=None, log=None, fixed: bool = False,
                   view: RunView | None = None):
    """A run of the many-steps kernel (``method`` already chosen) through the one lesson runner
    (``lessons._scene.simulate``), shown as ``view``. Returns (kinetic, potential) per step."""
    _, K, W = scene_simulate(ctx, name, model, state, dt, n_steps, method, every, energy_bound, observe=observe,
                             log=log, fixed=fixed, view=view, chosen=True)
    return K, W


def _fused_matches_stepwise(ctx):
    """The fused kernel against the engine's step-by-step integrators (100 steps, frame with spin)."""
    model, x0, v0 = tet_frame(ctx.cfg)
    dt = ctx.cfg.dt_fraction * stable_dt_estimate(model)
    exps = []
    for method in ("symplectic-euler", "velocity-verlet", "forward-euler"):
        a, b = model.make_state(x0, v0), model.make_state(x0, v0)
        K, W = run_many_steps(model, a, dt, 100, method)
        Stepper(model, get_integrator(method)).step(b, dt, 100)
        ctx.note_integrator(f"fused_vs_stepwise_{method}", method, fixed=True)
        xa, xb = a.numpy().x, b.numpy().x
        E_ref = diagnostics.total_energy(model, b)
        dev = max(np.abs(xa - xb).max() / 0.2, abs(K[-1] + W[-1] - E_ref) / E_ref)
        exps.append(Experiment(f"fused kernel = engine's {method} step by step (100 steps, max rel. diff.)",
                               0.0, dev, 1e-12, "abs", id=f"fused-equals-stepwise-{method}"))
    return exps


def _momentum_watch(model, P0, J0):
    """(observe, dP, dJ, mv, mxv): ``observe(step, state)`` keeps the largest deviations of the
    linear and angular momentum from P0, J0 and their scales sum m|v| and sum m|x||v| (the frame
    drifts away from the origin, so the largest |x| seen sets the round-off scale of J)."""
    dP, dJ, mv, mxv = [0.0], [0.0], [0.0], [0.0]

    def observe(step, s):
        x, v, _ = s.numpy()
        speed = np.linalg.norm(v, axis=1)
        mv[0] = max(mv[0], float(np.sum(model.mass * speed)))
        mxv[0] = max(mxv[0], float(np.sum(model.mass * np.linalg.norm(x, axis=1) * speed)))
        dP[0] = max(dP[0], float(np.abs(diagnostics.linear_momentum(model, s) - P0).max()))
        dJ[0] = max(dJ[0], float(np.abs(diagnostics.angular_momentum(model, s) - J0).max()))
    return observe, dP, dJ, mv, mxv


def _conservation_run(ctx, net, model, x0, v0, dt, method, scale):
    """One symplectic run of ``cfg.steps`` steps: no drift of the energy (against ``scale``, or,
    at the first run, the chain's peak kinetic energy / the frame's initial energy), the
    wobble's order in dt, and (frame) the momenta. Returns (experiments, scale)."""
    cfg = ctx.cfg
    N = cfg.steps
    st = model.make_state(x0, v0)
    E0 = diagnostics.total_energy(model, st)
    P0, J0 = diagnostics.linear_momentum(model, st), diagnostics.angular_momentum(model, st)
    observe, dP, dJ, mv, mxv = _momentum_watch(model, P0, J0)
    log, view = chain_view(model, method, N) if net == "chain" else frame_view(model, x0, method)
    K, W = simulate_fused(ctx, f"{net}_{method}", model, st, dt, N, method, cfg.record_every,
                          observe=observe if net == "frame" else None, log=log, fixed=True, view=view)
    E = K + W
    tenth = N // 10
    if scale is None:
        scale = float(K.max()) if net == "chain" else E0
    what = "peak kinetic energy" if net == "chain" else "initial energy"
    exps = [Experiment(f"{net}, {method}: no drift over {N} steps (|mean E last tenth - first tenth| / {what})",
                       0.01, abs(E[-tenth:].mean() - E[:tenth].mean()) / scale, 0, "<=", id=f"{net}-{method}-no-drift")]
    T = wobble_time(net, dt)
    a1, E1 = _wobble(ctx, f"{net}_{method}_wobble_dt", model, x0, v0, dt, T, method)
    a2, E2 = _wobble(ctx, f"{net}_{method}_wobble_dt/2", model, x0, v0, dt / 2, T, method)
    ctx.progress(f"{net} {method}: energy wobble over {T:.4g} s: {a1:.4g} J at dt, {a2:.4g} J at dt/2")
    # the wobble must stand out of the total energy's round-off (eps |E| per sample) to show its order
    noise = WOBBLE_NOISE * np.finfo(np.float64).eps * max(E1, E2)
    steps = int(round(T / (dt / 2)))
    reason = ""
    if a2 <= noise:
        reason = (f"round-off: the energy wobble at dt/2 ({a2:.2g} J) is within {WOBBLE_NOISE:g} ulps of the total "
                  f"energy ({max(E1, E2):.3g} J): the integration error is below what f64 resolves")
    elif steps > WOBBLE_ROUNDOFF_STEPS:
        # measured: velocity Verlet's order shows at 7e5 steps per run (chain k = 1e7 N) and is lost at 2e6 (1e8 N)
        reason = (f"round-off: the run at dt/2 takes {steps:.3g} steps (stiff links or a small --dt-fraction), and the "
                  f"round-off they accumulate in the positions is comparable to {METHOD_NAMES[method]}'s energy wobble "
                  f"({a2:.2g} J), which then no longer scales as dt^{ORDER[method]}; a softer --{net}-k or a larger "
                  "--dt-fraction shows the order")
    exps.append(Experiment(f"{net}, {method}: energy wobble ratio at dt vs dt/2 = 2^order",
                           2.0 ** ORDER[method], a1 / a2 if a2 > 0 else math.inf, 0.05, "rel",
                           id=f"{net}-{method}-wobble-order", reason=reason))
    if net == "frame":
        exps.append(Experiment(f"frame, {method}: linear momentum conserved (max |P - P0| / max sum m|v|)",
                               0.0, dP[0] / mv[0], 1e-12, "abs", id=f"frame-{method}-linear-momentum"))
        exps.append(Experiment(f"frame, {method}: angular momentum conserved (max |J - J0| / max sum m|x||v|)",
                               0.0, dJ[0] / mxv[0], 1e-12, "abs", id=f"frame-{method}-angular-momentum"))
    return exps, scale


WOBBLE_NOISE = 1000  # ulps of the total energy a wobble must exceed to be measured
WOBBLE_ROUNDOFF_STEPS = 1_000_000  # past this many steps a run's accumulated round-off blurs the wobble's order


def _wobble(ctx, name, model, x0, v0, dt, T, method):
    """(max - min of the total energy over time T, its largest |value|) (a fixed run of ``method``)."""
    ctx.note_integrator(name, method, fixed=True)
    st = model.make_state(x0, v0)
    E0 = diagnostics.total_energy(model, st)
    K, W = run_many_steps(model, st, dt, int(round(T / dt)), method)
    E = np.concatenate([[E0], K + W])
    return float(E.max() - E.min()), float(np.abs(E).max())


def _forward_euler_chain(ctx, model, x0, v0, dt, scale):
    """Forward Euler on the chain gains a full swing's kinetic energy (``scale``), detected at the step."""
    N = ctx.cfg.steps
    st = model.make_state(x0, v0)
    E0 = diagnostics.total_energy(model, st)
    log, view = chain_view(model, "forward-euler", N)
    view.span = FORWARD_EULER_SHOWN * dt  # its timeline: the first steps, where it is stopped
    try:  # chunks of 5 steps: the recorder can draw the few hundred steps before the stop every 5 steps
        simulate_fused(ctx, "chain_forward-euler", model, st, dt, N, "forward-euler", 5,
                       energy_bound=E0 + scale, fixed=True, log=log, view=view)
        step = math.inf
    except BlowUpError as exc:
        step = exc.step
        ctx.progress(f"detected: {exc}")
    # forward Euler multiplies a mode's energy by 1 + (w dt)^2 per step, and w dt <= 2 dt-fraction (the
    # CFL estimate is a lower bound of the limit 2/w_max): at most this over the run
    most = math.exp(min(N * math.log1p((2 * ctx.cfg.dt_fraction) ** 2), 700.0))
    reason = (f"forward Euler gains at most (1 + (w_max dt)^2)^N = {most:.6g} times a mode's energy over the {N} steps "
              f"at --dt-fraction {ctx.cfg.dt_fraction:g} (w_max dt <= 2 x dt-fraction): the chain's fast modes start "
              "too small to gain a swing's energy so slowly; more --steps or a larger --dt-fraction shows it")
    return Experiment(f"chain, forward Euler: energy grows by one peak kinetic energy within {N} steps "
                      "(step detected)", N, step, 0, "<=", "steps", id="chain-forward-euler-blows-up", reason=reason)


def _forward_euler_modes(ctx):
    """Forward Euler on a small-amplitude frame at rest (no drift or spin): the energy growth and
    the step where the blow-up detector trips, both predicted by a modal analysis."""
    model, x0, _ = tet_frame(ctx.cfg, jiggle=1e-5, rigid=False)
    dt = ctx.cfg.dt_fraction * stable_dt_estimate(model)
    growth, E_modes = _modal_growth(model, x0, dt)
    st = model.make_state(x0)
    E0 = diagnostics.total_energy(model, st)
    # the window: as many steps (at most 2000) as keep the predicted growth below 30x, so the
    # amplitude stays small and the motion linear
    n_fe = int(np.arange(1, 2001)[max(np.searchsorted(growth, 30.0) - 1, 0)])
    K, W = run_many_steps(model, st, dt, n_fe, "forward-euler")
    ctx.note_integrator("frame_forward-euler_growth", "forward-euler", fixed=True)
    predicted = float(growth[n_fe - 1])
    exps = [Experiment("frame, forward Euler: energy growth over n steps = sum_k E_k (1 + w_k^2 dt^2)^n / E0",
                       predicted, (K[-1] + W[-1]) / E0, 1e-3, "rel", id="frame-forward-euler-growth")]
    factor = min(10.0, 0.5 * predicted)  # 10 E0, crossed inside the window (unless dt is tiny)
    bound = factor * E0
    predicted_step = int(np.argmax(growth * E_modes.sum() > bound))  # 0-based index of the step
    ctx.progress(f"forward Euler window: {n_fe} steps, predicted growth {predicted:.4g}, bound {factor:.3g} E0")
    st = model.make_state(x0)
    try:
        ctx.note_integrator("frame_forward-euler_detect", "forward-euler", fixed=True)
        run_many_steps(model, st, dt, n_fe, "forward-euler", energy_bound=bound)
        detected = math.inf
    except BlowUpError as exc:
        detected = exc.step
    exps.append(Experiment(f"frame, forward Euler: blow-up (E > {factor:.3g} E0) detected at the step modal theory "
                           "predicts", predicted_step, detected, 1, "abs", "steps", id="frame-forward-euler-detected-step"))
    return exps


def _modal_growth(model, x0, dt):
    """Forward Euler multiplies mode k's energy E_k by 1 + w_k^2 dt^2 per step: the predicted
    growth sum_k E_k (1 + w_k^2 dt^2)^n / sum_k E_k for n = 1..2000, and the E_k of ``x0``."""
    H = model.dense_hessian(model.X_nd, psd=False)
    M = np.repeat(model.mass, 3)
    w2, Phi = sla.eigh(H, np.diag(M))  # Phi^T M Phi = I
    w2 = np.clip(w2, 0.0, None)  # rigid modes: w = 0
    q0 = Phi.T @ (M * (x0 - model.X).reshape(-1))
    E_modes = 0.5 * w2 * q0 ** 2
    steps = np.arange(1, 2001)
    growth = (E_modes[None, :] * (1 + w2[None, :] * dt * dt) ** steps[:, None]).sum(axis=1) / E_modes.sum()
    return growth, E_modes


# ------------------------------------------------------------------------- stage 3

def stage_variational(ctx):
    exps = [_gradient_is_stencil(kind) for kind in ("graded", "random")]
    exps.append(_directional_derivative())
    for kind, theory, tol in (("uniform", 2.0, 0.1), ("graded", 2.0, 0.1), ("random", 1.0, 0.15)):
        exps += _force_density_order(ctx, kind, theory, tol)
    return exps


def _gradient_is_stencil(kind):
    """-grad W equals the nodal length times the FD stencil of d/dp(E(x'-1)), on a 401-node grid."""
    p = grid(kind, 401)
    rod = rod_on(p)
    h = rod.h
    x = p + u(p)
    f = rod.forces(x)
    F = rod.E * (np.diff(x) / h - 1.0)  # tension E (dx/dp - 1) per segment
    stencil = (F[1:] - F[:-1]) / (0.5 * (h[1:] + h[:-1]))
    ell = 0.5 * (h[1:] + h[:-1])
    diff = np.max(np.abs(f[1:-1] - ell * stencil)) / np.max(np.abs(f[1:-1]))
    return Experiment(f"{kind} grid: -grad W = nodal length x FD stencil of d/dp(E(x'-1)) (max rel. diff.)", 0.0,
                      diff, 1e-13, "abs", id=f"{kind}-gradient-is-stencil")


def _directional_derivative():
    """The discrete energy's derivative along a smooth test function q is -sum_i f_i q_i."""
    p = grid("graded", 401)
    rod = rod_on(p)
    x = p + u(p)
    q = np.sin(2 * np.pi * p) * p
    dq = central_difference(rod.energy, x, q, 1e-6)
    fq = -float(np.dot(rod.forces(x), q))
    return Experiment("discrete D_q W (central differences in eps) = -sum_i f_i q_i", fq, dq, 1e-7, "rel", "J",
                      id="rod-directional-derivative")


def _force_density_order(ctx, kind, theory, tol):
    """The force density (nodal force / nodal length) against the exact d/dp(E(x'-1)) on five
    refinements: the order of its rms error (and, on the graded grid, of its max error)."""
    sizes = np.array([101, 201, 401, 801, 1601])
    err_rms, err_max = [], []
    for n in sizes:
        p = grid(kind, n)
        rod = rod_on(p)
        h = rod.h
        ell = np.zeros(n)
        ell[:-1] += 0.5 * h
        ell[1:] += 0.5 * h
        dens = rod.forces(p + u(p)) / ell
        e = (dens - force_density_exact(p))[1:-1]  # interior nodes (the ends carry boundary terms)
        err_rms.append(math.sqrt(np.sum(ell[1:-1] * e * e)))
        err_max.append(np.max(np.abs(e)))
        if ctx.rec.enabled and n == sizes[0]:
            draw_force_density(ctx.rec, kind, p, dens)
    h = 1.0 / (sizes - 1)
    o_rms = convergence_order(h, np.array(err_rms))
    ctx.progress(f"{kind}: rms errors {np.array(err_rms)}, order {o_rms:.3f}")
    exps = [Experiment(f"{kind} grid: force density -> d/dp(E(x'-1)), order of the rms error",
                       theory, o_rms, tol, "abs", id=f"{kind}-force-density-order")]
    if kind == "graded":
        exps.append(Experiment("graded grid: order of the max error", theory,
                               convergence_order(h, np.array(err_max)), tol, "abs", id="graded-force-density-max-order"))
    return exps


# ------------------------------------------------------------------------- stage 4

UNDAMPED = ("symplectic-euler", "velocity-verlet")


MODAL_MAX_NODES = 5001  # backward Euler's modal reference holds all n^2 mode shapes of a chain (200 MB here)


def stage_sound(ctx):
    cfg = ctx.cfg
    if ctx.integrator_name("symplectic-euler") == "backward-euler" and cfg.wave_segments + 1 > MODAL_MAX_NODES:
        n = cfg.wave_segments + 1  # the uniform chain, the longest
        return [Experiment("backward Euler's modal prediction can be computed for these chains", MODAL_MAX_NODES, n, 0,
                           "<=", "nodes", id="modal-reference-stage4",
                           reason=f"the prediction holds all n^2 mode shapes of chains of up to {n} nodes "
                                  f"({8 * n * n / 2 ** 30:.2g} GiB); use --wave-segments <= {MODAL_MAX_NODES - 1} "
                                  "with --integrator backward-euler")]
    announce(ctx, stage4_seconds(cfg), bound=True)
    rho = cfg.rho
    c = math.sqrt(cfg.E / rho)
    h = 1.0 / cfg.wave_segments
    sigma = 30 * h  # ten periods of the alternating pattern
    method = ctx.integrator_name("symplectic-euler")
    exps = []
    speeds, predicted_speeds = [], []
    for kind in ("uniform", "alternating", "graded"):
        Ls = chain_lengths(kind, h)
        k = np.full(Ls.size, rho * c * c)  # k_j = rho c^2, i.e. kappa_j = rho c^2 / L_j
        model, p = chain_model(Ls, k, rho)
        view = RunView(label=f"k_j = rho c^2 on {LENGTHS[kind]} ({Ls.size} segments)", camera="top", energy=None,
                       span=_pulse_time(c))
        v, v_pred = _pulse_speed(ctx, f"matched_{kind}", model, p, c, sigma, k, rho, view=view)
        speeds.append(v)
        predicted_speeds.append(v_pred)
        exps.append(expect(ctx, method, f"k_j = rho c^2 ({kind} lengths, {Ls.size} segments): pulse speed = c",
                           c, v, v_pred, 1e-2, unit="m/s", id=f"matched-{kind}-speed"))
    spread = lambda v: (max(v) - min(v)) / c
    exps.append(expect(ctx, method, "k_j = rho c^2: spread of the three speeds (max - min) / c", 0.0,
                       spread(speeds), None if v_pred is None else spread(predicted_speeds), 1e-2, "abs",
                       id="matched-speed-spread"))
    kappa = rho * c * c / h  # one Hooke constant, chosen to give c on the uniform chain of spacing h
    const = []
    for kind in ("uniform", "alternating"):
        Ls = chain_lengths(kind, h)
        model, p = chain_model(Ls, kappa * Ls, rho)  # notes' k = kappa L
        predicted = math.sqrt(kappa * Ls.mean() / rho)  # sqrt(k_eff L_mean / m_mean), k_eff = kappa L_mean
        view = RunView(label=f"one Hooke constant kappa on {LENGTHS[kind]} ({Ls.size} segments)", camera="top",
                       energy=None, span=_pulse_time(c))
        v, v_pred = _pulse_speed(ctx, f"constant_kappa_{kind}", model, p, predicted, sigma, kappa * Ls, rho,
                                 view=view)
        const.append(v)
        exps.append(expect(ctx, method, f"one Hooke constant kappa ({kind} lengths): speed = sqrt(kappa L_mean / "
                           "rho)", predicted, v, v_pred, 1e-2, unit="m/s", id=f"constant-kappa-{kind}-speed"))
    exps.append(Experiment("one Hooke constant: the two patterns' speeds differ by more than 1% (rel. diff.)",
                           0.01, abs(const[1] - const[0]) / const[0], 0, ">=", id="constant-kappa-patterns-differ"))
    return exps


LENGTHS = {"uniform": "uniform lengths h", "alternating": "alternating lengths h, 2h",
           "graded": "graded lengths h (1 + p)"}
PULSE_TRAVEL = 0.45  # m: the pulse runs' length, in distance travelled at the speed they are sized with


def _pulse_time(c_scale: float) -> float:
    """The planned duration of a pulse run sized with speed ``c_scale`` (the last step at or before it).
    Given as every run's span (the one of the slowest speed, c): the runs play in step and a faster
    chain's pulse gets there sooner."""
    return PULSE_TRAVEL / c_scale


def _pulse_speed(ctx, name, model, p, c_scale, sigma, k, rho, p0=0.25, view=None):
    """Release a Gaussian bump at p0 from rest; fit the speed of the right-moving half's peak
    once it has separated from the left half. ``c_scale`` only sets the run time.

    A scene run: ``--integrator`` chooses the method (symplectic Euler by default; the explicit
    ones run in the fused kernel, backward Euler through :func:`lessons._scene.simulate`). Returns
    (measured speed, predicted speed): the prediction is None for the undamped symplectic methods,
    else the same fit on the scheme's own solution. Moving along its axis the chain is exactly a
    linear 1D rod with E_j = k_j and the same lumped masses, so that solution is
    :class:`engine.theory.schemes.ModalReference` (each normal mode advanced with the scheme's 2x2 step matrix).
    """
    method = ctx.integrator_name("symplectic-euler")
    A = 1e-4
    u0 = A * np.exp(-0.5 * ((p - p0) / sigma) ** 2)
    x0 = model.X.copy()
    x0[:, 0] += u0
    st = model.make_state(x0)
    bound = 10 * diagnostics.total_energy(model, st)  # forward Euler is stopped (and reported) there
    dt = 0.5 * stable_dt_estimate(model)
    n_steps = int(_pulse_time(c_scale) / dt)
    every = max(n_steps // 100, 1)
    region = [(p0, 1.0, 1)]  # the right-moving half
    (track,), observe = track_peaks(p, region)
    strain_scale = A / sigma * math.exp(-0.5)  # the released bump's largest strain

    def log(rec, s):  # the chain along x, its displacement drawn along y (0.1 m for the bump's amplitude)
        x = s.x.to_numpy()[:, 0]
        rec.rod(x, p, rod_node_strain(x, p), gain=0.1 / A, scale=strain_scale)

    on_state = lambda step, s: observe(step, step * dt, s.x.to_numpy()[:, 0] - p)
    if method in EXPLICIT:
        simulate_fused(ctx, name, model, st, dt, n_steps, method, every, energy_bound=bound, observe=on_state,
                       log=log, view=view)
    else:  # backward Euler (with --solver/--tol/--newton-iterations) via the engine's integrator
        scene_simulate(ctx, name, model, st, dt, n_steps, "symplectic-euler", every=every, energy_bound=bound,
                       observe=on_state, log=log, view=view)

    def fit(track):  # the peak's speed once the halves have separated
        return fit_slope(*np.array([(t, x) for t, x, _ in track if t * c_scale > 6 * sigma]).T)

    if method in UNDAMPED:
        return fit(track), None
    steps = observation_steps(n_steps, every)  # the observation steps of both runners
    (ref_track,), _ = modal_tracks(Rod(p, k, rho), u0, None, dt, method, steps, region)
    return fit(track), fit(ref_track)


# ------------------------------------------------------------------------- stage 5

def stage_hanging(ctx):
    exps = []
    for kind in ("uniform", "graded"):
        exps += _hanging(ctx, kind)
    return exps


HANG_TOL = 1e-10      # the static solve's residual (net force / a node's weight), unless round-off forbids it
HANG_TOL_MAX = 1e-6   # past this the forces' round-off swamps the weight: the claims fail, saying so


def force_roundoff(model, sag: float) -> float:
    """The round-off floor of the static residual r = max |f + m g| / max |m g| of a chain: a spring's
    tension c/L (l/L - 1) is computed from positions known to eps max|x| (x within ``sag`` of the rest
    shape), so each tension is uncertain by (c/L) eps (2 max|x| / L + 2), and a node's net force by
    twice that (measured floors: 0.3-0.4 of this, hanging rods of 50..5000 nodes)."""
    sp = model.springs
    eps = np.finfo(np.float64).eps
    xmax = float(np.abs(model.X).max()) + sag
    dT = sp.c_np / sp.L_np * eps * (2 * xmax / sp.L_np + 2)
    weight = float(np.max(model.mass[model.free] * np.linalg.norm(model.gravity)))
    return 2 * float(dT.max()) / weight


def _hanging(ctx, kind, tol=HANG_TOL):
    """The static equilibrium of the hanging rod on a ``kind`` grid against u = (rho g/E)(L p - p^2/2),
    and the pin's reaction against the weight. The solve's tolerance is HANG_TOL, or twice the residual's
    round-off floor (:func:`force_roundoff`) where that is larger (a long or stiff rod); past HANG_TOL_MAX
    the claims cannot be checked in f64 and fail with that reason."""
    cfg = ctx.cfg
    model, p = hanging_rod(cfg, kind)
    floor = force_roundoff(model, cfg.rho * G / (2 * cfg.E))
    tol = min(max(tol, 2 * floor), HANG_TOL_MAX)
    reason = "" if 2 * floor <= HANG_TOL_MAX else (
        f"round-off: the rod's spring forces are known only to {floor:.1e} of a node's weight (E / (rho g h^2) = "
        f"{cfg.E / (cfg.rho * G * float(np.max(np.diff(p))) ** 2):.2g}; positions carry 1e-16 m), so its sag cannot be "
        f"resolved to {HANG_TOL_MAX:g}; use a smaller --E/--rho or fewer --hang-nodes")
    t0 = time.perf_counter()
    res = solve_static(model, tol=tol, raise_on_failure=False, max_iter=max(100, 4 * int(math.log2(cfg.hang_nodes)) + 50))
    ctx.progress(f"{kind}: Newton {res.iterations} iterations, residual {res.residual:.3g} "
                 f"({time.perf_counter() - t0:.2f} s)")
    x = np.asarray(res.x)
    u = -(x[:, 2] - model.X[:, 2])
    u_exact = cfg.rho * G / cfg.E * (p - 0.5 * p * p)
    err = float(np.max(np.abs(u - u_exact)) / np.max(np.abs(u_exact)))
    weight = cfg.rho * G * 1.0
    if ctx.rec.enabled:
        draw_hanging(ctx.rec, kind, model, x, cfg.rho * G / cfg.E)
    return [
        Experiment(f"{kind} grid: static solver converged (net-force residual <= tol)", tol, res.residual, 0, "<=",
                   id=f"hanging-{kind}-converged", reason=reason or res.message),
        # a residual r leaves each tension wrong by at most (n - 1) r max(m g), hence u by at most
        # (n - 1) r max(m) g L / E = 2 (n - 1) max(m) / (rho L) r u_max
        Experiment(f"{kind} grid: nodal displacement = (rho g/E)(L p - p^2/2) (max rel. error)",
                   0.0, err, 2 * (cfg.hang_nodes - 1) * model.mass.max() / cfg.rho * tol, "abs",
                   id=f"hanging-{kind}-displacement", reason=reason),
        # R - weight = sum of the free nodes' residual forces: at most (n - 1) r max(m g)
        Experiment(f"{kind} grid: pin reaction carries the whole weight rho g L", weight,
                   float(res.reactions[0, 2]), (cfg.hang_nodes - 1) * tol, "rel", "N", id=f"hanging-{kind}-pin-reaction",
                   reason=reason),
    ]
