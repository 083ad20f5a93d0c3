"""Lesson ``rod-waves``: the 1D elastic rod, its sound waves and the CFL limit.

Physics lives in :mod:`engine.rod`; this module builds scenes, runs them, measures and
narrates.

Runs are either *scene* runs (stages 2 and 4: pulses, d'Alembert, reflection, smooth E), which use
``--integrator`` (symplectic Euler by default), or *fixed* runs (stage 3), whose claims are about
one particular integrator. Under symplectic Euler and velocity Verlet the scene experiments compare
with the undamped wave theory; under backward (or forward) Euler with what that scheme itself
predicts at the run's dt: the initial state is evolved mode by mode with the scheme's exact 2x2
step matrix (:class:`engine.rod.ModalReference`, numpy) and measured the same way.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from engine.analysis import fit_slope, geometric_growth, peak
from engine.errors import BlowUpError, ParameterError
from engine.rod import Rod

from ._framework import Experiment, Lesson, Stage, param
from ._measure import central_gradient, expect, modal_tracks, observation_steps, rod_node_strain, track_peaks
from ._scene import run_chunked


@dataclass
class RodWavesConfig:
    E: float = param(1.0, "Young's modulus of the rod (1D: force per unit strain)", "N", ge=1e-6, le=1e12)
    rho: float = param(1.0, "linear density of the rod", "kg/m", ge=1e-6, le=1e6)
    nodes: int = param(1001, "nodes on the rod of rest length 1 m (h = 1/(nodes-1))", ge=101, le=200001)
    cfl: float = param(0.5, "CFL number nu = c dt / h for runs that do not sweep it", gt=0, le=1000)
    width: float = param(10.0, "Gaussian pulse width sigma, in node spacings", ge=2, le=100)
    amplitude: float = param(1e-3, "pulse amplitude (displacement)", "m", gt=0, le=0.01)
    cfl_steps: int = param(10_000, "steps a run must survive to count as stable in stage 3", ge=100, le=10**7)
    record_every: int = param(20, "log the rod geometry every k-th step", ge=1)

    def validate(self):
        h = 1.0 / (self.nodes - 1)
        if self.width * h > 0.05:
            raise ParameterError(
                f"--width must be <= {0.05 / h:.3g} node spacings for --nodes {self.nodes} "
                f"(the pulse must be narrow next to the 1 m rod; got {self.width})")


# ------------------------------------------------------------------ shared machinery

def gaussian(p, center, sigma, amplitude):
    return amplitude * np.exp(-0.5 * ((p - center) / sigma) ** 2)


def gaussian_slope(p, center, sigma, amplitude):
    return -(p - center) / sigma ** 2 * gaussian(p, center, sigma, amplitude)


SYMPLECTIC = ("symplectic-euler", "velocity-verlet")  # no damping: the undamped theory applies


def scene_method(ctx) -> str:
    """The integrator of the scene runs: symplectic Euler unless ``--integrator`` chooses another."""
    return ctx.integrator_name("symplectic-euler")


def method_label(method: str) -> str:
    """How a run's integrator is noted. The rod's backward Euler is one exact tridiagonal (Thomas)
    solve per step: ``--solver/--tol`` do not apply to it."""
    return "backward-euler (tridiagonal, exact)" if method == "backward-euler" else method


def simulate(ctx, name: str, rod: Rod, state, dt: float, n_steps: int, method: str = "symplectic-euler",
             energy_bound: float | None = None, observe=None, every: int | None = None, fixed: bool = False):
    """Run ``n_steps`` of ``method`` (already chosen: see :func:`scene_method`) in chunks of
    ``every`` steps (one kernel launch each), logging the rod and its energies to the recorder
    and calling ``observe(step, t, u)`` after each chunk (and at step 0). The run is noted,
    as ``fixed`` or not. Returns (kinetic, potential) per step. A blow-up is logged, marked in
    the recording and re-raised."""
    rec = ctx.rec
    every = every or ctx.cfg.record_every
    ctx.note_integrator(name, method_label(method), fixed)
    rec.run(name)
    gain = 0.1 / max(ctx.cfg.amplitude, 1e-300)

    def log(step):
        if rec.enabled:
            x = state.x.to_numpy()
            rec.set_time(step, step * dt)
            rec.rod(x, rod.p, rod_node_strain(x, rod.p), gain=gain)

    def draw(step):
        log(step)
        if observe:
            observe(step, step * dt, state.displacement(rod))

    return run_chunked(ctx, name, dt, n_steps, every, draw=draw,
                       advance=lambda chunk, done: rod.run(state, dt, chunk, method, energy_bound,
                                                           step_offset=done))


def uniform_rod(cfg, pinned=()) -> Rod:
    return Rod.uniform(cfg.nodes, 1.0, cfg.E, cfg.rho, pinned)


def run_scene(ctx, name: str, rod: Rod, u0, v0, dt: float, n_steps: int, method: str, regions=(),
              every: int | None = None):
    """A scene run from displacement u0 and velocity v0 under ``method``, following the peaks of
    ``regions`` (see :func:`track_peaks`). The energy may not exceed 10x its start (forward Euler
    is stopped there and reported at the step). Returns ((tracks, u_end), predicted): for a
    non-symplectic method ``predicted`` is (tracks, u_end) measured the same way, at the same
    steps, on the scheme's modal prediction; otherwise None."""
    every = every or ctx.cfg.record_every
    st = rod.new_state(u0, v0)
    E0 = rod.energy(st.x) + rod.kinetic(st)
    tracks, obs = track_peaks(rod.p, regions)
    simulate(ctx, name, rod, st, dt, n_steps, method, energy_bound=10 * E0, observe=obs, every=every)
    result = (tracks, st.displacement(rod))
    if method in SYMPLECTIC:
        return result, None
    steps = observation_steps(n_steps, every) if regions else [n_steps]
    return result, modal_tracks(rod, u0, v0, dt, method, steps, regions)


# ------------------------------------------------------------------------- stage 1

S1_TEXT = """
Cut the rod into segments between nodes p_i. Segment j stores the energy of a stretched
spring, 1/2 E_j (strain_j)^2 times its rest length h_j, where strain_j = (x_{j+1} - x_j)/h_j - 1
is the fractional change of length. Summing gives the rod's potential energy W(x), and the
force on node i is minus the derivative of W with respect to x_i.

Written out, that derivative is E_i strain_i - E_{i-1} strain_{i-1}: the difference of the
tensions on the two sides of the node. Divide by the node's mass (half of each neighbouring
segment) and it is exactly the centred finite-difference formula for (1/rho) d/dp(E (dx/dp - 1)),
the rod's equation of motion. So differentiating a discrete energy and discretising the PDE
give the same scheme here. We check this node by node, check the gradient against central
finite differences of W, and check that an unstretched rod feels no force.
"""


def stage_energy(ctx):
    cfg = ctx.cfg
    n = cfg.nodes
    p = np.linspace(0.0, 1.0, n)
    mid = 0.5 * (p[1:] + p[:-1])
    E = cfg.E * (1.0 + 0.5 * np.sin(2 * np.pi * mid))      # a rod whose stiffness varies
    rho = cfg.rho * (1.0 + 0.3 * np.cos(2 * np.pi * mid))  # and whose density varies
    rod = Rod(p, E, rho)
    rng = np.random.default_rng(1)
    u = 0.01 * np.sin(3 * np.pi * p) + 1e-4 * rng.standard_normal(n)
    x = p + u
    f = rod.forces(x)
    a = f / rod.mass
    # The PDE's centred stencil, written from the formula (not from the engine).
    h = rod.h
    sigma = (x[1:] - x[:-1]) / h - 1.0
    rho_node = 0.5 * (rho[1:] + rho[:-1])
    stencil = (E[1:] * sigma[1:] - E[:-1] * sigma[:-1]) / h[1:] / rho_node
    stencil_err = np.max(np.abs(a[1:-1] - stencil)) / np.max(np.abs(stencil))
    # Central finite differences of W on a sample of nodes.
    idx = np.linspace(0, n - 1, 41).astype(int)
    fd = -central_gradient(rod.energy, x, 1e-6, at=idx)
    fd_err = np.linalg.norm(fd - f[idx]) / np.linalg.norm(f[idx])
    rest_force = np.max(np.abs(rod.forces(p.copy()))) / cfg.E
    # W of a uniform stretch is 1/2 E s^2 L (a closed form to compare the sum with).
    s = 0.01
    stretch_rod = Rod(p, cfg.E, cfg.rho)
    W_stretch = stretch_rod.energy((1 + s) * p)
    return [
        Experiment("force/mass equals the PDE's finite-difference stencil (max rel. difference)",
                   0.0, stencil_err, 1e-12, "abs"),
        Experiment("force equals -dW/dx by central differences (rel. error)", 0.0, fd_err, 1e-6, "abs"),
        Experiment("no force on the unstretched rod (max |f| / E)", 0.0, rest_force, 1e-14, "abs"),
        Experiment("uniform 1% stretch stores W = 1/2 E s^2 L", 0.5 * cfg.E * s * s, W_stretch, 1e-9, "rel", "J"),
    ]


# ------------------------------------------------------------------------- stage 2

S2_TEXT = """
Any shape x0 that slides along the rod without changing, x(p, t) = p + u0(p - c t), solves
the homogeneous wave equation when c^2 = E/rho: the speed of sound is sqrt(E/rho), a material
property. We launch a Gaussian bump of displacement with the velocity -c u0'(p) that makes it
move right, follow its peak, and fit its speed. The CFL number nu = c dt/h says how many node
spacings sound crosses per step; we try nu = 0.25, 0.5 and 1. The discrete rod is slightly
dispersive (short waves travel slower), but a pulse ten node spacings wide is smooth enough
that its peak moves at c to better than half a percent, and at nu = 1 symplectic Euler on a
uniform rod happens to be exact for every wavelength.

With the opposite velocity the same bump travels left. With no initial velocity at all,
d'Alembert's solution says it splits into two half-height copies running apart at +-c.

These are scene runs: they use the integrator chosen with --integrator (symplectic Euler by
default). Velocity Verlet moves the nodes exactly as symplectic Euler does, only with velocities
shifted by half a step, so it has the same dispersion and the same claims hold. Backward Euler is
different: each mode of angular frequency w shrinks by 1/sqrt(1 + (w dt)^2) per step and turns by
atan(w dt) instead of w dt. For long waves this acts like diffusion with D = c^2 dt/2 riding on
the wave: the pulse still moves at nearly c, but flattens and widens, its variance growing by
c^2 dt t. "Each half has height A/2" is then simply false, so under backward Euler every
experiment compares with what the scheme itself predicts at that dt: the initial pulse is split
into the rod's normal modes, each mode is advanced with backward Euler's exact 2x2 step matrix
(numpy), the modes are summed and the result is measured exactly like the simulation. The
undamped value is printed beside it, and one more experiment checks the diffusion estimate of
the halves' height. The rod's backward-Euler step is an exact tridiagonal solve, so --solver and
--tol do not apply to it. Forward Euler amplifies every mode: its runs are stopped, and
reported, at the step where the energy passes ten times its start.
"""


def stage_sound(ctx):
    cfg = ctx.cfg
    rod = uniform_rod(cfg)
    method = scene_method(ctx)
    c = float(rod.wave_speed()[0])
    h = float(rod.h[0])
    sigma, A = cfg.width * h, cfg.amplitude

    def speed(track, t_min, t_max):
        t, xp, _ = np.array(track).T
        keep = (t > t_min / c) & (t < t_max / c)
        return fit_slope(t[keep], xp[keep])

    exps = []
    for nu in (0.25, 0.5, 1.0):
        dt = nu * h / c
        n_steps = int(round(0.5 / c / dt))
        u0, v0 = gaussian(rod.p, 0.25, sigma, A), -c * gaussian_slope(rod.p, 0.25, sigma, A)
        ((track,), _), pred = run_scene(ctx, f"right_nu{nu}", rod, u0, v0, dt, n_steps, method, [(0.0, 1.0, 1)])
        exps.append(expect(ctx, method, f"right-moving pulse speed at nu = {nu}", c, speed(track, 0.05, 0.45),
                           pred and speed(pred[0][0], 0.05, 0.45), 5e-3, unit="m/s"))

    nu = min(cfg.cfl, 1.0)
    dt = nu * h / c
    n_steps = int(round(0.5 / c / dt))
    u0, v0 = gaussian(rod.p, 0.75, sigma, A), c * gaussian_slope(rod.p, 0.75, sigma, A)
    ((track,), _), pred = run_scene(ctx, "left", rod, u0, v0, dt, n_steps, method, [(0.0, 1.0, 1)])
    exps.append(expect(ctx, method, f"left-moving pulse speed at nu = {nu}", -c, speed(track, 0.05, 0.45),
                       pred and speed(pred[0][0], 0.05, 0.45), 5e-3, unit="m/s"))

    n_steps = int(round(0.4 / c / dt))
    regions = [(0.0, 0.5, 1), (0.5, 1.0, 1)]
    ((left, right), _), pred = run_scene(ctx, "dalembert", rod, gaussian(rod.p, 0.5, sigma, A), None, dt,
                                         n_steps, method, regions)
    amplitude = lambda tracks: 0.5 * (tracks[0][-1][2] + tracks[1][-1][2])  # at the end
    exps += [  # speeds once the halves have separated (t > 0.1/c)
        expect(ctx, method, "d'Alembert: left half moves at -c", -c, speed(left, 0.1, np.inf),
               pred and speed(pred[0][0], 0.1, np.inf), 5e-3, unit="m/s"),
        expect(ctx, method, "d'Alembert: right half moves at +c", c, speed(right, 0.1, np.inf),
               pred and speed(pred[0][1], 0.1, np.inf), 5e-3, unit="m/s"),
        expect(ctx, method, "d'Alembert: each half has amplitude A/2", A / 2, amplitude((left, right)),
               pred and amplitude(pred[0]), 1e-2, unit="m"),
    ]
    if method == "backward-euler":
        # long waves: per-step factor (1 + (c k dt)^2)^-1/2 ~ exp(-c^2 k^2 dt^2/2), i.e. diffusion with
        # D = c^2 dt/2 over t = n dt: a Gaussian's variance grows by 2 D t
        t = n_steps * dt
        exps.append(Experiment("backward Euler: each half flattens like diffusion with D = c^2 dt/2, "
                               "height A/2 sigma/sqrt(sigma^2 + c^2 dt t)",
                               A / 2 * sigma / math.sqrt(sigma ** 2 + c * c * dt * t), amplitude((left, right)),
                               1e-2, "rel", "m"))
    return exps


# ------------------------------------------------------------------------- stage 3

S3_TEXT = """
An explicit step only uses each node's neighbours, so information moves at most one node
spacing per step. The Courant-Friedrichs-Lewy condition asks that this numerical speed h/dt be
at least the physical one, c: nu = c dt/h <= 1. For symplectic Euler this is also exactly the
stability limit. Its highest mode (neighbouring nodes moving in opposite directions) has
angular frequency w_max = 2c/h, and the scheme is stable only while w_max dt <= 2, i.e. dt <= h/c.

Just above the limit the highest mode is amplified every step by a factor lambda with
lambda + 1/lambda = 2 - (w_max dt)^2, so its energy grows by lambda^2 per step: at nu = 1.01
that is about 1.76 per step, which we measure from the energy log. The run is stopped at the
step where the energy leaves its bound and the step is reported. Bisection on nu finds the
limit numerically.

Forward Euler is worse: for every mode it multiplies the energy by exactly 1 + (w dt)^2 per
step, so it gains energy at any dt. Backward Euler does the opposite, 1/(1 + (w dt)^2) per step,
and stays stable at any dt, even nu = 10, at the price of damping motion that should not be
damped. For this linear rod each backward-Euler step is one tridiagonal solve.

Every run in this stage is fixed: each claim is about one named integrator, so --integrator does
not change them (they are marked [fixed] in the stage's list of integrators).
"""


def _survives(ctx, rod, nu, n_steps, name, quiet=True):
    c, h = float(rod.wave_speed().max()), float(rod.h.min())
    rng = np.random.default_rng(7)
    A = ctx.cfg.amplitude
    u0 = gaussian(rod.p, 0.5, ctx.cfg.width * h, A) + 1e-6 * A * rng.standard_normal(rod.n)
    st = rod.new_state(u0)
    E0 = rod.energy(st.x)
    try:
        if quiet:
            rod.run(st, nu * h / c, n_steps, "symplectic-euler", energy_bound=100 * E0)
        else:
            simulate(ctx, name, rod, st, nu * h / c, n_steps, "symplectic-euler", energy_bound=100 * E0,
                     every=max(ctx.cfg.record_every, 100), fixed=True)
        return None
    except BlowUpError as exc:
        return exc


def _mode_growth(ctx, rod, j, nu, method, n_steps):
    """Per-step energy factor of mode j on a rod with both ends pinned, and w_j (a fixed run)."""
    ctx.note_integrator(f"mode{j}_nu{nu}", method_label(method), fixed=True)
    c, h = float(rod.wave_speed()[0]), float(rod.h[0])
    dt = nu * h / c
    shape = np.sin(j * np.pi * rod.p)
    st = rod.new_state(1e-3 * shape)
    E0 = rod.energy(st.x)
    K, W = rod.run(st, dt, n_steps, method)
    E = np.concatenate([[E0], K + W])
    w = 2 * c / h * np.sin(j * np.pi * h / 2)  # discrete dispersion of the pinned rod
    return geometric_growth(E, n_steps), w * dt, E


def stage_cfl(ctx):
    cfg = ctx.cfg
    rod = uniform_rod(cfg)
    c, h = float(rod.wave_speed()[0]), float(rod.h[0])
    N = cfg.cfl_steps
    exps = []
    exc = _survives(ctx, rod, 0.99, N, "symplectic_nu0.99", quiet=False)
    exps.append(Experiment(f"symplectic Euler at nu = 0.99 survives {N} steps", N,
                           N if exc is None else exc.step, 0, ">=", "steps"))
    exc = _survives(ctx, rod, 1.01, N, "symplectic_nu1.01", quiet=False)
    exps.append(Experiment(f"symplectic Euler at nu = 1.01 blows up within {N} steps (step detected)",
                           N, exc.step if exc else math.inf, 0, "<=", "steps"))
    if exc is not None:
        ctx.progress(f"detected: {exc}")
    # The top mode alone (neighbours in opposite directions) at nu = 1.01: its energy
    # is multiplied by lambda^2 every step, lambda the larger root of l + 1/l = 2 - (w dt)^2.
    a = 2.0 * 1.01  # w_max dt
    lam = ((2 - a * a) - math.sqrt((2 - a * a) ** 2 - 4)) / 2
    top = rod.new_state(1e-9 * cfg.amplitude * (-1.0) ** np.arange(rod.n))
    E0 = rod.energy(top.x)
    K, W = rod.run(top, 1.01 * h / c, 40, "symplectic-euler")
    ctx.note_integrator("top_mode_nu1.01", "symplectic-euler", fixed=True)
    # Starting from rest excites both roots; the 1/lambda part has died out by step 30.
    exps.append(Experiment("top mode at nu = 1.01: energy factor per step = lambda^2",
                           lam * lam, geometric_growth(K + W, 10), 1e-6, "rel"))
    lo, hi = 0.5, 1.5
    runs = 0
    while hi - lo > 1e-4:
        mid = 0.5 * (lo + hi)
        runs += 1
        if _survives(ctx, rod, mid, N, "bisect") is None:
            lo = mid
        else:
            hi = mid
    ctx.note_integrator(f"bisection ({runs} runs)", "symplectic-euler", fixed=True)
    ctx.progress(f"bisection: largest stable nu in [{lo:.5f}, {hi:.5f}]")
    exps.append(Experiment("stability limit found by bisection equals h/c", h / c, lo * h / c, 1e-2, "rel", "s"))

    pinned = uniform_rod(cfg, pinned=(0, cfg.nodes - 1))
    j = 8
    for nu in (0.1, 0.5, 1.0):
        g, wdt, _ = _mode_growth(ctx, pinned, j, nu, "forward-euler", 10)
        exps.append(Experiment(f"forward Euler, nu = {nu}: mode energy factor per step = 1 + (w dt)^2",
                               1 + wdt * wdt, g, 1e-9, "rel"))
    g, wdt, E = _mode_growth(ctx, pinned, j, 10.0, "backward-euler", 20)
    exps.append(Experiment("backward Euler, nu = 10: mode energy factor per step = 1/(1 + (w dt)^2)",
                           1 / (1 + wdt * wdt), g, 1e-6, "rel"))
    st = rod.new_state(gaussian(rod.p, 0.5, cfg.width * h, cfg.amplitude))
    E0 = rod.energy(st.x)
    K, W = simulate(ctx, "backward_nu10", rod, st, 10 * h / c, 1000, "backward-euler", energy_bound=100 * E0,
                    fixed=True)
    exps.append(Experiment("backward Euler at nu = 10: energy never exceeds its start (max E/E0)",
                           1.0, float(np.max(K + W)) / E0, 0, "<="))
    return exps


# ------------------------------------------------------------------------- stage 4

S4_TEXT = """
Now let the material change along the rod. Where two materials meet, the displacement and
the tension E du/dp must both be continuous. A pulse arriving from material 1 therefore
splits: a reflected pulse with amplitude R = (Z1 - Z2)/(Z1 + Z2) and a transmitted one with
T = 2 Z1/(Z1 + Z2), where Z = sqrt(E rho) is the impedance. Hitting a stiffer rod (Z2 > Z1)
flips the reflection upside down; hitting a softer one keeps it upright and the transmitted
pulse is taller than the incoming one. The transmitted pulse is also stretched or squeezed
by c2/c1 because its front and back cross the interface at different times.

When E varies smoothly, nothing reflects noticeably and the pulse simply travels at the local
speed sqrt(E(p)/rho(p)): we follow it and compare its speed at several points with that value.

These are scene runs (--integrator). Under backward Euler both pulses are damped on the way, so
their amplitudes are compared with the scheme's modal prediction instead of R and T. One thing
survives the damping: backward Euler damps by temporal frequency (w dt), and an interface
reflects and transmits without changing the frequency (the transmitted pulse is longer or
shorter, but oscillates at the same rate), so both pulses lose the same fraction and the ratio
reflected/transmitted is still R/T = (Z1 - Z2)/(2 Z1). We check that too.
"""


def _interface_run(ctx, name, E2, rho2):
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
    sigma = cfg.width * h * max(1.0, c1 / c2)  # the transmitted pulse keeps >= width nodes
    A = cfg.amplitude
    method = scene_method(ctx)
    u0, v0 = gaussian(p, 0.25, sigma, A), -c1 * gaussian_slope(p, 0.25, sigma, A)
    dt = 0.5 * h / max(c1, c2)
    # Stop when the reflected pulse is 0.12 m back from the interface (or the transmitted
    # one 0.12 m from the far end, whichever comes first).
    t_end = 0.25 / c1 + min(0.12 / c1, 0.35 / c2)
    (_, u), pred = run_scene(ctx, name, rod, u0, v0, dt, int(round(t_end / dt)), method)
    reflected = lambda u: peak(p, u, 0.0, 0.5 - 4 * sigma)[1] / A
    transmitted = lambda u: peak(p, u, 0.5 + 4 * sigma * c2 / c1, 1.0)[1] / A
    R, T = (Z1 - Z2) / (Z1 + Z2), 2 * Z1 / (Z1 + Z2)
    exps = [
        expect(ctx, method, f"{name}: reflected amplitude / incident = (Z1-Z2)/(Z1+Z2), Z2/Z1 = {Z2 / Z1:g}", R,
               reflected(u), pred and reflected(pred[1]), 2e-2),
        expect(ctx, method, f"{name}: transmitted amplitude / incident = 2 Z1/(Z1+Z2)", T, transmitted(u),
               pred and transmitted(pred[1]), 2e-2),
    ]
    if method == "backward-euler":  # damping by frequency, which the interface keeps: the ratio survives
        exps.append(Experiment(f"{name}, backward Euler: reflected / transmitted amplitude = R/T = (Z1-Z2)/(2 Z1)",
                               R / T, reflected(u) / transmitted(u), 2e-2, "rel"))
    return exps


def stage_heterogeneous(ctx):
    cfg = ctx.cfg
    exps = _interface_run(ctx, "stiffer", 4 * cfg.E, cfg.rho)
    exps += _interface_run(ctx, "softer", cfg.E / 4, cfg.rho)
    exps += _interface_run(ctx, "denser", cfg.E, 4 * cfg.rho)
    # Smoothly varying stiffness: c(p) = c0 (1 + 1.5 p).
    n = cfg.nodes
    p = np.linspace(0, 1, n)
    mid = 0.5 * (p[1:] + p[:-1])
    c0 = math.sqrt(cfg.E / cfg.rho)
    E = cfg.E * (1 + 1.5 * mid) ** 2
    rod = Rod(p, E, cfg.rho)
    h = 1.0 / (n - 1)
    sigma, A = cfg.width * h, cfg.amplitude
    method = scene_method(ctx)
    u0, v0 = gaussian(p, 0.15, sigma, A), -c0 * gaussian_slope(p, 0.15, sigma, A)
    dt = 0.5 * h / float(rod.wave_speed().max())
    t_end = math.log((1 + 1.5 * 0.85) / (1 + 1.5 * 0.15)) / (1.5 * c0)  # arrival at p = 0.85
    ((track,), _), pred = run_scene(ctx, "smooth", rod, u0, v0, dt, int(t_end / dt), method, [(0.0, 1.0, 1)],
                                    every=10)

    def local_speed(track, where):
        """(fitted speed, sqrt(E/rho) at the mean position) over 11 samples around p = where."""
        t, xp, _ = np.array(track).T
        k = np.argmin(np.abs(xp - where))
        sl = slice(max(k - 5, 0), k + 6)
        return fit_slope(t[sl], xp[sl]), c0 * (1 + 1.5 * float(np.mean(xp[sl])))

    for where in (0.3, 0.5, 0.7):
        speed, local = local_speed(track, where)
        exps.append(expect(ctx, method, f"smooth E(p): pulse speed near p = {where} equals sqrt(E(p)/rho)",
                           local, speed, pred and local_speed(pred[0][0], where)[0], 1e-2, unit="m/s"))
    return exps


LESSON = Lesson(
    id="rod-waves",
    title="1D rod: energy, sound waves, the CFL limit, impedance",
    summary="A rod of springs: forces from its energy, the speed of sound sqrt(E/rho), "
            "explicit stability (CFL) against implicit damping, and waves meeting changes of material.",
    config=RodWavesConfig,
    stages=[
        Stage("energy and force", S1_TEXT, stage_energy),
        Stage("sound waves", S2_TEXT, stage_sound),
        Stage("the CFL limit", S3_TEXT, stage_cfl),
        Stage("a heterogeneous rod", S4_TEXT, stage_heterogeneous),
    ],
    order=1,
)
