"""The stages of ``springs`` that step in time (their narratives are in narrative.md): energy
conservation (stage 2) and stiffness from the speed of sound (stage 4), with the runs and
measurements only they make; the stages that do not step in time (1, 3 and 5) are in
:mod:`.stages`, and the scenes, their drawing and each stage's cost in scene.py.

Runs are *fixed* (stage 2: its claims are about symplectic Euler, velocity Verlet and forward
Euler themselves) or *scene* runs (stage 4's pulses), which use ``--integrator``: the explicit
choices run in the fused kernel, backward Euler through :func:`lessons._scene.simulate` with the
engine's implicit integrator (``--solver/--tol/--newton-iterations`` apply). numpy is used only
for set-up, analysis and the reference formulas the engine is compared with.

Stage 2 alone takes about 200 lines: two networks under three methods, each with its drift, its
energy wobble's order (and the round-off that can hide it), its momenta, and forward Euler's
blow-up against a modal prediction.
"""
from __future__ import annotations

import math

import numpy as np
import scipy.linalg as sla

from engine import diagnostics
from engine.analysis import fit_slope
from engine.constants import EXPLICIT
from engine.errors import BlowUpError
from engine.integrators import Stepper, get as get_integrator
from engine.model import Model
from engine.scenes import Rod
from engine.stability import stable_dt_estimate
from lessons.views import RunView

from .._budget import announce
from .._framework import Experiment
from .._measure import expect, modal_tracks, observation_steps, rod_node_strain, track_peaks
from .._scene import simulate as scene_simulate
from .scene import (FORWARD_EULER_SHOWN, METHOD_NAMES, chain_lengths, chain_model, chain_view, frame_view,
                    stage2_plan, stage4_seconds, swinging_chain, tet_frame, wobble_time)


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
        K, W = Stepper(model, method, many_steps=True).energies(a, dt, 100)
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
    K, W = Stepper(model, method, many_steps=True).energies(st, dt, int(round(T / dt)))
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
    K, W = Stepper(model, "forward-euler", many_steps=True).energies(st, dt, n_fe)
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
        Stepper(model, "forward-euler", many_steps=True).energies(st, dt, n_fe, energy_bound=bound)
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
