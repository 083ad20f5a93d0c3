"""The stages of ``rod-waves`` (their narratives are in narrative.md) and the runs and measurements
only they make; the rods they build, how their runs are drawn and what each stage costs are in
scene.py.

Runs are either *scene* runs (stages 2 and 4: pulses, d'Alembert, reflection, smooth E), which use
``--integrator`` (symplectic Euler by default), or *fixed* runs (stage 3), whose claims are about
one particular integrator. Under symplectic Euler and velocity Verlet the scene experiments compare
with the undamped wave theory; under backward (or forward) Euler with what that scheme itself
predicts at the run's dt: the initial state is evolved mode by mode with the scheme's exact 2x2
step matrix (:class:`engine.theory.schemes.ModalReference`, numpy) and measured the same way.
"""
from __future__ import annotations

import math

import numpy as np

from engine.analysis import fit_slope, geometric_growth, peak
from engine.errors import BlowUpError
from engine.integrators.loop import run as run_loop
from engine.integrators.stepper import Stepper
from engine.scenes import Rod

from .._framework import Experiment, check_interrupt
from .._measure import central_gradient, expect, modal_tracks, observation_steps, track_peaks
from .._scene import progress_bar
from .scene import (announce_work, draw_stencil_check, gaussian, gaussian_slope, method_label, pulse_width, simulate,
                    uniform_rod, varying_rod)


SYMPLECTIC = ("symplectic-euler", "velocity-verlet")  # no damping: the undamped theory applies
MODAL_MAX_NODES = 5001     # the modal reference of a damped scheme holds all n^2 mode shapes (200 MB here)
QUIET_CHUNK = 20_000_000   # node-steps per launch of stage 3's unrecorded runs (a progress update each)


# ------------------------------------------------------------------------- stage 1

def stage_energy(ctx):
    cfg = ctx.cfg
    p = np.linspace(0.0, 1.0, cfg.nodes)
    rod = varying_rod(cfg, p)
    rng = np.random.default_rng(1)
    u = 0.01 * np.sin(3 * np.pi * p) + 1e-4 * rng.standard_normal(cfg.nodes)
    x = p + u
    f = rod.forces(x)
    idx = np.linspace(0, cfg.nodes - 1, 41).astype(int)  # central finite differences of W on these nodes
    fd = -central_gradient(rod.energy, x, 1e-6, at=idx)
    rest_force = np.max(np.abs(rod.forces(p.copy()))) / cfg.E
    s = 0.01  # W of a uniform stretch is 1/2 E s^2 L (a closed form to compare the sum with)
    W_stretch = Rod(p, cfg.E, cfg.rho).energy((1 + s) * p)
    # the two sides weigh the node's spacings differently (lumped mass vs segment length), and the spacings
    # h_j = p_j+1 - p_j are known only to eps max|p| / h relative: the check is good to that, not to a fixed 1e-12
    stencil_tol = max(1e-12, 4 * np.finfo(np.float64).eps * float(np.abs(x).max()) / float(rod.h.min()))
    if ctx.rec.enabled:
        draw_stencil_check(ctx.rec, rod, p, u, f / rod.mass, _stencil(rod, x))
    return [
        Experiment("force/mass equals the PDE's finite-difference stencil (max rel. difference)",
                   0.0, _stencil_error(rod, x, f), stencil_tol, "abs", id="force-is-pde-stencil"),
        Experiment("force equals -dW/dx by central differences (rel. error)", 0.0,
                   np.linalg.norm(fd - f[idx]) / np.linalg.norm(f[idx]), 1e-6, "abs", id="force-is-energy-gradient"),
        Experiment("no force on the unstretched rod (max |f| / E)", 0.0, rest_force, 1e-14, "abs",
                   id="no-force-at-rest"),
        Experiment("uniform 1% stretch stores W = 1/2 E s^2 L", 0.5 * cfg.E * s * s, W_stretch, 1e-9, "rel", "J",
                   id="uniform-stretch-energy"),
    ]


def _stencil(rod: Rod, x) -> np.ndarray:
    """The PDE's centred stencil (1/rho) d/dp(E (dx/dp - 1)) at the interior nodes, written from the
    formula, not from the engine."""
    E, h = rod.E, rod.h
    sigma = (x[1:] - x[:-1]) / h - 1.0
    rho_node = 0.5 * (rod.rho[1:] + rod.rho[:-1])
    return (E[1:] * sigma[1:] - E[:-1] * sigma[:-1]) / h[1:] / rho_node


def _stencil_error(rod: Rod, x, f) -> float:
    """Max |force/mass - the PDE's centred stencil| / max |stencil|."""
    stencil = _stencil(rod, x)
    return np.max(np.abs(f[1:-1] / rod.mass[1:-1] - stencil)) / np.max(np.abs(stencil))


# ------------------------------------------------------------------ the scene runs of stages 2 and 4

def scene_method(ctx) -> str:
    """The integrator of the scene runs: symplectic Euler unless ``--integrator`` chooses another."""
    return ctx.integrator_name("symplectic-euler")


def run_scene(ctx, name: str, rod: Rod, u0, v0, dt: float, n_steps: int, method: str, regions=(),
              every: int | None = None, label: str | None = None, interface: float | None = None):
    """A scene run from displacement u0 and velocity v0 under ``method``, following the peaks of
    ``regions`` (see :func:`lessons._measure.track_peaks`). The energy may not exceed 10x its start
    (forward Euler is stopped there and reported at the step). Returns ((tracks, u_end), predicted):
    for a non-symplectic method ``predicted`` is (tracks, u_end) measured the same way, at the same
    steps, on the scheme's modal prediction; otherwise None."""
    every = every or ctx.cfg.record_every
    st = rod.new_state(u0, v0)
    E0 = rod.energy(st.x) + rod.kinetic(st)
    tracks, obs = track_peaks(rod.p, regions)
    simulate(ctx, name, rod, st, dt, n_steps, method, energy_bound=10 * E0, observe=obs, every=every, label=label,
             interface=interface)
    result = (tracks, st.displacement(rod))
    if method in SYMPLECTIC:
        return result, None
    steps = observation_steps(n_steps, every) if regions else [n_steps]
    return result, modal_tracks(rod, u0, v0, dt, method, steps, regions)


def fitted_speed(track, t_min, t_max):
    """The peak's speed fitted over t_min < t < t_max."""
    t, xp, _ = np.array(track).T
    keep = (t > t_min) & (t < t_max)
    return fit_slope(t[keep], xp[keep])


def modal_reference_refused(ctx, method: str, stage: int) -> list | None:
    """Under backward Euler the scene experiments compare with the scheme's modal prediction, which
    holds every mode shape (nodes^2 numbers): past MODAL_MAX_NODES the stage is not run and says so."""
    n = ctx.cfg.nodes
    if method != "backward-euler" or n <= MODAL_MAX_NODES:
        return None
    return [Experiment("backward Euler's modal prediction can be computed for this rod", MODAL_MAX_NODES, n, 0, "<=",
                       "nodes", id=f"modal-reference-stage{stage}",
                       reason=f"the prediction holds all {n}^2 mode shapes ({8 * n * n / 2 ** 30:.2g} GiB); "
                              f"use --nodes <= {MODAL_MAX_NODES} with --integrator backward-euler")]


def dispersion_speed_error(nu: float, w: float) -> float:
    """Relative slowdown of a Gaussian pulse w node spacings wide at CFL number nu under symplectic
    Euler: the grid's dispersion w = c k (1 - (1 - nu^2)(k h)^2/24) moves its peak at about
    c (1 - (1 - nu^2)/(8 w^2))."""
    return (1.0 - min(nu, 1.0) ** 2) / (8.0 * w * w)


def dispersion_spread(nu: float, h: float, sigma: float, distance: float) -> float:
    """(beta t)^(1/3) / sigma after the pulse has travelled ``distance``: beta = c h^2 (1 - nu^2)/24 is
    the cubic term of the grid's dispersion; past about 0.2 the pulse's peak drops measurably."""
    return ((1.0 - min(nu, 1.0) ** 2) * h * h * distance / 24.0) ** (1.0 / 3.0) / sigma


def speed_reason(nu: float, w: float, tol: float) -> str:
    e = dispersion_speed_error(nu, w)
    if e <= 0.2 * tol:
        return ""
    return (f"grid dispersion: a pulse {w:.3g} node spacings wide moves at about (1 - (1 - nu^2)/(8 w^2)) c = "
            f"{1 - e:.4g} c at nu = {min(nu, 1.0):g} (short waves travel slower on the grid); use a wider --width "
            "or more --nodes")


def spread_reason(nu: float, h: float, sigma: float, distance: float) -> str:
    q = dispersion_spread(nu, h, sigma, distance)
    if q <= 0.15:
        return ""
    return (f"grid dispersion: over its {distance:g} m the pulse ({sigma / h:.3g} node spacings wide) spreads by "
            f"(beta t)^(1/3) = {q:.2f} sigma (beta = c h^2 (1 - nu^2)/24), which lowers and shifts its peak; use a "
            "wider --width or more --nodes")


# ------------------------------------------------------------------------- stage 2

def stage_sound(ctx):
    cfg = ctx.cfg
    method = scene_method(ctx)
    refused = modal_reference_refused(ctx, method, 2)
    if refused:
        return refused
    announce_work(ctx, 2)
    rod = uniform_rod(cfg)
    c, h = float(rod.wave_speed()[0]), float(rod.h[0])
    exps = [_pulse_speed(ctx, rod, method, f"right_nu{nu}", nu, 0.25, +1, f"right-moving pulse speed at nu = {nu}",
                         id=f"pulse-speed-nu{nu}", label=f"pulse to the right, CFL number {nu:g}")
            for nu in (0.25, 0.5, 1.0)]
    nu = min(cfg.cfl, 1.0)
    exps.append(_pulse_speed(ctx, rod, method, "left", nu, 0.75, -1, f"left-moving pulse speed at nu = {nu}",
                             id="pulse-speed-left", label=f"pulse to the left, CFL number {nu:g}"))
    exps += _dalembert(ctx, rod, method, nu * h / c)
    return exps


def _pulse_speed(ctx, rod, method, name, nu, center, direction, claim, id, label=None):
    """A Gaussian pulse at ``center`` launched towards ``direction`` (+1 right, -1 left) at CFL
    number ``nu``: its peak's speed over the middle of the run, against +-c."""
    cfg = ctx.cfg
    c, h = float(rod.wave_speed()[0]), float(rod.h[0])
    sigma, A = pulse_width(cfg, h), cfg.amplitude
    dt = nu * h / c
    n_steps = int(round(0.5 / c / dt))
    u0, v0 = gaussian(rod.p, center, sigma, A), -direction * c * gaussian_slope(rod.p, center, sigma, A)
    ((track,), _), pred = run_scene(ctx, name, rod, u0, v0, dt, n_steps, method, [(0.0, 1.0, 1)], label=label)
    speed = lambda track: fitted_speed(track, 0.05 / c, 0.45 / c)
    e = expect(ctx, method, claim, direction * c, speed(track), pred and speed(pred[0][0]), 5e-3, unit="m/s", id=id)
    if pred is None:  # against the undamped theory: the grid's own dispersion is what can make it fail
        e.reason = speed_reason(nu, sigma / h, 5e-3)
    return e


def _dalembert(ctx, rod, method, dt):
    """A pulse released from rest splits into two halves running apart at +-c with height A/2
    (under backward Euler: what the scheme predicts, and the diffusion estimate of the height)."""
    cfg = ctx.cfg
    c, h = float(rod.wave_speed()[0]), float(rod.h[0])
    sigma, A = pulse_width(cfg, h), cfg.amplitude
    n_steps = int(round(0.4 / c / dt))
    ((left, right), _), pred = run_scene(ctx, "dalembert", rod, gaussian(rod.p, 0.5, sigma, A), None, dt,
                                         n_steps, method, [(0.0, 0.5, 1), (0.5, 1.0, 1)],
                                         label="pulse released from rest splits in two (d'Alembert)")
    speed = lambda track: fitted_speed(track, 0.1 / c, np.inf)  # once the halves have separated
    amplitude = lambda tracks: 0.5 * (tracks[0][-1][2] + tracks[1][-1][2])  # at the end
    exps = [
        expect(ctx, method, "d'Alembert: left half moves at -c", -c, speed(left), pred and speed(pred[0][0]), 5e-3,
               unit="m/s", id="dalembert-left-speed"),
        expect(ctx, method, "d'Alembert: right half moves at +c", c, speed(right), pred and speed(pred[0][1]), 5e-3,
               unit="m/s", id="dalembert-right-speed"),
        expect(ctx, method, "d'Alembert: each half has amplitude A/2", A / 2, amplitude((left, right)),
               pred and amplitude(pred[0]), 1e-2, unit="m", id="dalembert-half-amplitude"),
    ]
    if method in SYMPLECTIC:
        nu = c * dt / h
        for e in exps[:2]:
            e.reason = speed_reason(nu, sigma / h, 5e-3)
        exps[2].reason = spread_reason(nu, h, sigma, c * n_steps * dt)
    if method == "backward-euler":
        # long waves: per-step factor (1 + (c k dt)^2)^-1/2 ~ exp(-c^2 k^2 dt^2/2), i.e. diffusion with
        # D = c^2 dt/2 over t = n dt: a Gaussian's variance grows by 2 D t
        t = n_steps * dt
        exps.append(Experiment("backward Euler: each half flattens like diffusion with D = c^2 dt/2, "
                               "height A/2 sigma/sqrt(sigma^2 + c^2 dt t)",
                               A / 2 * sigma / math.sqrt(sigma ** 2 + c * c * dt * t), amplitude((left, right)),
                               1e-2, "rel", "m", id="backward-euler-diffusion-height"))
    return exps


# ------------------------------------------------------------------------- stage 3

def stage_cfl(ctx):
    cfg = ctx.cfg
    announce_work(ctx, 3)
    rod = uniform_rod(cfg)
    c, h = float(rod.wave_speed()[0]), float(rod.h[0])
    N = cfg.cfl_steps
    below = _survives(ctx, rod, 0.99, N, "symplectic_nu0.99", quiet=False)
    above = _survives(ctx, rod, 1.01, N, "symplectic_nu1.01", quiet=False)
    if above is not None:
        ctx.progress(f"detected: {above}")
    exps = [
        Experiment(f"symplectic Euler at nu = 0.99 survives {N} steps", N, N if below is None else below.step, 0,
                   ">=", "steps", id="symplectic-nu0.99-survives"),
        Experiment(f"symplectic Euler at nu = 1.01 blows up within {N} steps (step detected)",
                   N, above.step if above else math.inf, 0, "<=", "steps", id="symplectic-nu1.01-blows-up"),
        _top_mode_growth(ctx, rod),
        Experiment("stability limit found by bisection equals h/c", h / c, _bisect_limit(ctx, rod) * h / c, 1e-2,
                   "rel", "s", id="stability-limit-bisection"),
    ]
    pinned = uniform_rod(cfg, pinned=(0, cfg.nodes - 1))
    j = 8
    for nu in (0.1, 0.5, 1.0):
        g, wdt, _ = _mode_growth(ctx, pinned, j, nu, "forward-euler", 10)
        exps.append(Experiment(f"forward Euler, nu = {nu}: mode energy factor per step = 1 + (w dt)^2",
                               1 + wdt * wdt, g, 1e-9, "rel", id=f"forward-euler-mode-growth-nu{nu}"))
    g, wdt, _ = _mode_growth(ctx, pinned, j, 10.0, "backward-euler", 20)
    exps.append(Experiment("backward Euler, nu = 10: mode energy factor per step = 1/(1 + (w dt)^2)",
                           1 / (1 + wdt * wdt), g, 1e-6, "rel", id="backward-euler-mode-decay-nu10"))
    exps.append(Experiment("backward Euler at nu = 10: energy never exceeds its start (max E/E0)",
                           1.0, _backward_euler_energy_ratio(ctx, rod, 10.0), 0, "<=",
                           id="backward-euler-nu10-energy-bounded"))
    return exps


def _survives(ctx, rod, nu, n_steps, name, quiet=True):
    """None if symplectic Euler at CFL number ``nu`` keeps a slightly noisy pulse's energy below
    100x its start for ``n_steps``, else the BlowUpError (a fixed run; ``quiet``: not recorded)."""
    c, h = float(rod.wave_speed().max()), float(rod.h.min())
    rng = np.random.default_rng(7)
    A = ctx.cfg.amplitude
    u0 = gaussian(rod.p, 0.5, pulse_width(ctx.cfg, h), A) + 1e-6 * A * rng.standard_normal(rod.n)
    st = rod.new_state(u0)
    E0 = rod.energy(st.x)
    try:
        if quiet:
            _quiet_run(ctx, f"{name} nu = {nu:.5f}", rod, st, nu * h / c, n_steps, "symplectic-euler", 100 * E0)
        else:
            simulate(ctx, name, rod, st, nu * h / c, n_steps, "symplectic-euler", energy_bound=100 * E0,
                     every=max(ctx.cfg.record_every, 100), fixed=True,
                     label=f"symplectic Euler, CFL number {nu:g} ({'below' if nu < 1 else 'above'} the limit 1)",
                     energy="drift" if nu < 1 else "split")
        return None
    except BlowUpError as exc:
        return exc


def _quiet_run(ctx, name, rod, st, dt, n_steps, method, energy_bound):
    """The rod's stepper through the one run loop (engine.integrators.loop.run), nothing recorded:
    launches of at most QUIET_CHUNK node-steps, so a long run shows its progress bar and can be
    interrupted. The rod's many-steps kernel is serial, so the chunks step exactly as one launch would."""
    chunk = max(QUIET_CHUNK // rod.n, 1)
    advance = Stepper(rod, method).advancer(st, dt, n_steps, energy_bound)
    run_loop(advance, n_steps, chunk, check_interrupt=check_interrupt, progress=progress_bar(ctx, name, n_steps))


def _top_mode_growth(ctx, rod):
    """The top mode alone (neighbours in opposite directions) at nu = 1.01: its energy is
    multiplied by lambda^2 every step, lambda the larger root of l + 1/l = 2 - (w dt)^2."""
    c, h = float(rod.wave_speed()[0]), float(rod.h[0])
    a = 2.0 * 1.01  # w_max dt
    lam = ((2 - a * a) - math.sqrt((2 - a * a) ** 2 - 4)) / 2
    # 1e-12 m at the default amplitude (never less: far above the positions' round-off, 1e-16 m, and small
    # enough to stay linear while its energy grows ~1e10 times over the 40 steps)
    top = rod.new_state(1e-9 * max(ctx.cfg.amplitude, 1e-3) * (-1.0) ** np.arange(rod.n))
    K, W = Stepper(rod, "symplectic-euler").energies(top, 1.01 * h / c, 40)
    ctx.note_integrator("top_mode_nu1.01", "symplectic-euler", fixed=True)
    # Starting from rest excites both roots; the 1/lambda part has died out by step 30.
    return Experiment("top mode at nu = 1.01: energy factor per step = lambda^2",
                      lam * lam, geometric_growth(K + W, 10), 1e-6, "rel", id="top-mode-growth-nu1.01")


def _bisect_limit(ctx, rod) -> float:
    """The largest CFL number at which symplectic Euler survives, by bisection to 1e-4."""
    lo, hi = 0.5, 1.5
    runs = 0
    while hi - lo > 1e-4:
        mid = 0.5 * (lo + hi)
        runs += 1
        if _survives(ctx, rod, mid, ctx.cfg.cfl_steps, "bisect") is None:
            lo = mid
        else:
            hi = mid
    ctx.note_integrator(f"bisection ({runs} runs)", "symplectic-euler", fixed=True)
    ctx.progress(f"bisection: largest stable nu in [{lo:.5f}, {hi:.5f}]")
    return lo


def _mode_growth(ctx, rod, j, nu, method, n_steps):
    """Per-step energy factor of mode j on a rod with both ends pinned, and w_j (a fixed run)."""
    ctx.note_integrator(f"mode{j}_nu{nu}", method_label(method), fixed=True)
    c, h = float(rod.wave_speed()[0]), float(rod.h[0])
    dt = nu * h / c
    shape = np.sin(j * np.pi * rod.p)
    st = rod.new_state(1e-3 * shape)
    E0 = rod.energy(st.x)
    K, W = Stepper(rod, method).energies(st, dt, n_steps)
    E = np.concatenate([[E0], K + W])
    w = 2 * c / h * np.sin(j * np.pi * h / 2)  # discrete dispersion of the pinned rod
    return geometric_growth(E, n_steps), w * dt, E


def _backward_euler_energy_ratio(ctx, rod, nu) -> float:
    """Max E/E0 of a pulse under backward Euler at CFL number ``nu`` (a fixed, recorded run)."""
    cfg = ctx.cfg
    c, h = float(rod.wave_speed()[0]), float(rod.h[0])
    st = rod.new_state(gaussian(rod.p, 0.5, pulse_width(cfg, h), cfg.amplitude))
    E0 = rod.energy(st.x)
    K, W = simulate(ctx, f"backward_nu{nu:g}", rod, st, nu * h / c, 1000, "backward-euler", energy_bound=100 * E0,
                    fixed=True, label=f"backward Euler, CFL number {nu:g}: stable, damped")
    return float(np.max(K + W)) / E0


# ------------------------------------------------------------------------- stage 4

def stage_heterogeneous(ctx):
    cfg = ctx.cfg
    refused = modal_reference_refused(ctx, scene_method(ctx), 4)
    if refused:
        return refused
    announce_work(ctx, 4)
    exps = _interface_run(ctx, "stiffer", 4 * cfg.E, cfg.rho)
    exps += _interface_run(ctx, "softer", cfg.E / 4, cfg.rho)
    exps += _interface_run(ctx, "denser", cfg.E, 4 * cfg.rho)
    exps += _smooth_rod(ctx)
    return exps


def _interface_run(ctx, name, E2, rho2):
    """A pulse from material 1 meets material 2 at p = 0.5: reflected and transmitted amplitudes
    against R and T from the impedances (under backward Euler: the scheme's prediction, and the
    ratio R/T, which its damping keeps)."""
    cfg = ctx.cfg
    n = cfg.nodes
    p = np.linspace(0, 1, n)
    mid = 0.5 * (p[1:] + p[:-1])
    E = np.where(mid < 0.5, cfg.E, E2)
    rho = np.where(mid < 0.5, cfg.rho, rho2)
    rod = Rod(p, E, rho)
    c1, c2 = math.sqrt(cfg.E / cfg.rho), math.sqrt(E2 / rho2)
    Z1, Z2 = math.sqrt(cfg.E * cfg.rho), math.sqrt(E2 * rho2)
    h = 1.0 / (n - 1)
    sigma = pulse_width(cfg, h) * max(1.0, c1 / c2)  # the transmitted pulse keeps >= width nodes
    A = cfg.amplitude
    method = scene_method(ctx)
    u0, v0 = gaussian(p, 0.25, sigma, A), -c1 * gaussian_slope(p, 0.25, sigma, A)
    dt = 0.5 * h / max(c1, c2)
    # Stop when the reflected pulse is 0.12 m (or, for a wide pulse, 6 sigma) back from the interface, or
    # the transmitted one 0.15 m from the far end, whichever comes first.
    gap = max(0.12, 6 * sigma)
    t_end = 0.25 / c1 + min(gap / c1, 0.35 / c2)
    what = {"stiffer": "stiffer right half (E × 4)", "softer": "softer right half (E / 4)",
            "denser": "denser right half (rho × 4)"}.get(name, name)
    (_, u), pred = run_scene(ctx, name, rod, u0, v0, dt, int(round(t_end / dt)), method,
                             label=f"{what}: Z2 = {Z2 / Z1:g} Z1, interface (grey) at p = 0.5", interface=0.5)
    reflected = lambda u: peak(p, u, 0.0, 0.5 - 4 * sigma)[1] / A
    transmitted = lambda u: peak(p, u, 0.5 + 4 * sigma * c2 / c1, 1.0)[1] / A
    R, T = (Z1 - Z2) / (Z1 + Z2), 2 * Z1 / (Z1 + Z2)
    exps = [
        expect(ctx, method, f"{name}: reflected amplitude / incident = (Z1-Z2)/(Z1+Z2), Z2/Z1 = {Z2 / Z1:g}", R,
               reflected(u), pred and reflected(pred[1]), 2e-2, id=f"{name}-reflected"),
        expect(ctx, method, f"{name}: transmitted amplitude / incident = 2 Z1/(Z1+Z2)", T, transmitted(u),
               pred and transmitted(pred[1]), 2e-2, id=f"{name}-transmitted"),
    ]
    if method == "backward-euler":  # damping by frequency, which the interface keeps: the ratio survives
        exps.append(Experiment(f"{name}, backward Euler: reflected / transmitted amplitude = R/T = (Z1-Z2)/(2 Z1)",
                               R / T, reflected(u) / transmitted(u), 2e-2, "rel",
                               id=f"{name}-reflected-over-transmitted"))
    too_wide = _separation_reason(sigma, sigma * c2 / c1, c1 * t_end - 0.25, c2 * (t_end - 0.25 / c1))
    if method in SYMPLECTIC:  # the peaks are read after the run: the grid's dispersion of each pulse
        exps[0].reason = too_wide or spread_reason(c1 * dt / h, h, sigma, c1 * t_end)
        exps[1].reason = too_wide or spread_reason(c2 * dt / h, h, sigma * c2 / c1, 0.25 + c2 * (t_end - 0.25 / c1))
    else:
        for e in exps:
            e.reason = too_wide
    return exps


def _separation_reason(sigma: float, sigma_t: float, back: float, on: float) -> str:
    """Why an interface run cannot tell its pulses apart, if it cannot: the incident pulse (width
    ``sigma``, starting 0.25 m from the interface and from the end) must clear both by 4 sigma, the
    reflected one travel ``back`` >= 5 sigma (it is read more than 4 sigma from the interface) and stay
    3 sigma from the end, the transmitted one (width ``sigma_t``) travel ``on`` >= 5 sigma_t and stay
    3 sigma_t from the far end."""
    if 4 * sigma <= 0.25 and 5 * sigma <= back <= 0.5 - 3 * sigma and 5 * sigma_t <= on <= 0.5 - 3 * sigma_t:
        return ""
    return (f"the pulse is too wide for the 1 m rod: sigma = {sigma:.3g} m (transmitted {sigma_t:.3g} m) cannot "
            f"separate from the interface and stay clear of the ends (reflected pulse {back:.3g} m back, transmitted "
            f"{on:.3g} m on); use a narrower --width or more --nodes")


def _smooth_rod(ctx):
    """Smoothly varying stiffness, c(p) = c0 (1 + 1.5 p): the pulse's speed at three points
    against the local sqrt(E/rho)."""
    cfg = ctx.cfg
    n = cfg.nodes
    p = np.linspace(0, 1, n)
    mid = 0.5 * (p[1:] + p[:-1])
    c0 = math.sqrt(cfg.E / cfg.rho)
    rod = Rod(p, cfg.E * (1 + 1.5 * mid) ** 2, cfg.rho)
    h = 1.0 / (n - 1)
    sigma, A = pulse_width(cfg, h), cfg.amplitude
    method = scene_method(ctx)
    u0, v0 = gaussian(p, 0.15, sigma, A), -c0 * gaussian_slope(p, 0.15, sigma, A)
    dt = 0.5 * h / float(rod.wave_speed().max())
    t_end = math.log((1 + 1.5 * 0.85) / (1 + 1.5 * 0.15)) / (1.5 * c0)  # arrival at p = 0.85
    ((track,), _), pred = run_scene(ctx, "smooth", rod, u0, v0, dt, int(t_end / dt), method, [(0.0, 1.0, 1)],
                                    every=10, label="smoothly stiffening rod, c(p) = c0 (1 + 1.5 p)")

    def local_speed(track, where):
        """(fitted speed, sqrt(E/rho) at the mean position) over 11 samples around p = where."""
        t, xp, _ = np.array(track).T
        k = np.argmin(np.abs(xp - where))
        sl = slice(max(k - 5, 0), k + 6)
        return fit_slope(t[sl], xp[sl]), c0 * (1 + 1.5 * float(np.mean(xp[sl])))

    exps = []
    for where in (0.3, 0.5, 0.7):
        speed, local = local_speed(track, where)
        e = expect(ctx, method, f"smooth E(p): pulse speed near p = {where} equals sqrt(E(p)/rho)",
                   local, speed, pred and local_speed(pred[0][0], where)[0], 1e-2, unit="m/s",
                   id=f"smooth-speed-p{where}")
        if pred is None:  # the pulse widens as it speeds up (sigma c(p)/c0): its narrowest is at the start
            e.reason = speed_reason(float(rod.wave_speed()[0]) * dt / h, sigma / h, 1e-2)
        exps.append(e)
    return exps
