"""Explicit time integrators, the CFL time-step limit and blow-up detection.

Newton's second law for lumped masses, M dv/dt = f(x) = -dW/dx, with a = M^-1 f + g for free
vertices and a = 0, v = 0 for pinned ones (inverse mass 0):

  forward Euler      x+ = x + dt v ;          v+ = v + dt a(x)          (both from the old state)
  symplectic Euler   v+ = v + dt a(x) ;       x+ = x + dt v+
  velocity Verlet    v* = v + dt/2 a(x) ;     x+ = x + dt v* ;   v+ = v* + dt/2 a(x+)
                     (kick-drift-kick; a(x+) is cached for the next step)

Stability (lecture notes, "Courant-Friedrichs-Lewy (CFL) condition"):
linearising about the rest state, each mode oscillates with w^2 an eigenvalue of M^-1 K.
Symplectic Euler and Verlet are stable iff dt <= 2 / w_max; forward Euler multiplies each
mode's energy by about (1 + w^2 dt^2) per step, so it is unstable at every dt without damping.

:func:`stable_dt_estimate` bounds lambda_max = w_max^2 by Gershgorin's theorem on M^-1 H:

    lambda_max <= max over free vertices i and axes a of (1/m_i) sum_cols |H_(i,a),col|

which for springs at rest is (1/m_i) sum_{e ~ i} 2 (c_e/L_e^2) |d_a| |d|_1 (d the unit edge
direction; <= (1/m_i) sum 4 c_e/L_e^2, the cruder per-element bound).  Every eigenvalue
lies in a Gershgorin disc, so dt = 2/sqrt(bound) is conservative (never above the true limit);
for a straight 1D rod it is exact (dt = h/c).  :func:`lambda_max_power` estimates lambda_max by
power iteration with Hessian-vector products (a Rayleigh quotient: a lower bound of
lambda_max, hence a dt estimate from above; use it with a safety factor).
"""

import math

import numpy as np
import taichi as ti

from engine import diagnostics, errors
from engine.fields import float_dtype, free_dot, mass_dot, scalar_array, scale_vec3, vec3_array, zero_vec3
from engine.model import Model, State


class BlowUpError(errors.BlowUpError):
    """The simulation diverged.  Attributes: step (0-based index of the step after which it was
    detected), time, energy, dt, dt_stable (= stable_dt), integrator.  A subclass of the engine's
    BlowUpError, so lesson runners catch blow-ups from every integrator the same way."""

    def __init__(self, message: str, *, step: int, time: float, energy: float, dt: float,
                 dt_stable: float, integrator: str):
        RuntimeError.__init__(self, message)
        self.cause = message
        self.stable_dt = dt_stable
        self.step = step
        self.time = time
        self.energy = energy
        self.dt = dt
        self.dt_stable = dt_stable
        self.integrator = integrator


# --------------------------------------------------------------------------------------------
# Update kernels (one pass over the vertices each)
# --------------------------------------------------------------------------------------------

@ti.kernel
def forward_euler_update(x: vec3_array, v: vec3_array, f: vec3_array, inv_mass: scalar_array,
                         g: ti.math.vec3, dt: float):
    # x+ = x + dt v ; v+ = v + dt (M^-1 f(x) + g)
    for i in range(x.shape[0]):
        if inv_mass[i] > 0.0:
            x[i] += dt * v[i]
            v[i] += dt * (inv_mass[i] * f[i] + g)
        else:
            v[i] = ti.math.vec3(0.0)


@ti.kernel
def symplectic_euler_update(x: vec3_array, v: vec3_array, f: vec3_array, inv_mass: scalar_array,
                            g: ti.math.vec3, dt: float):
    # v+ = v + dt (M^-1 f(x) + g) ; x+ = x + dt v+
    for i in range(x.shape[0]):
        if inv_mass[i] > 0.0:
            v[i] += dt * (inv_mass[i] * f[i] + g)
            x[i] += dt * v[i]
        else:
            v[i] = ti.math.vec3(0.0)


@ti.kernel
def verlet_kick_drift(x: vec3_array, v: vec3_array, a: vec3_array, inv_mass: scalar_array, dt: float):
    # v* = v + dt/2 a ; x+ = x + dt v*
    for i in range(x.shape[0]):
        if inv_mass[i] > 0.0:
            v[i] += 0.5 * dt * a[i]
            x[i] += dt * v[i]
        else:
            v[i] = ti.math.vec3(0.0)


@ti.kernel
def accel_kick(v: vec3_array, f: vec3_array, a: vec3_array, inv_mass: scalar_array, g: ti.math.vec3,
               half_dt: float):
    # a = M^-1 f + g (0 if pinned) ; v += half_dt a
    for i in range(v.shape[0]):
        if inv_mass[i] > 0.0:
            a[i] = inv_mass[i] * f[i] + g
            v[i] += half_dt * a[i]
        else:
            a[i] = ti.math.vec3(0.0)
            v[i] = ti.math.vec3(0.0)


# --------------------------------------------------------------------------------------------
# Integrators
# --------------------------------------------------------------------------------------------

class ExplicitIntegrator:
    """Base: ``step(model, state, dt, n_steps)`` = ``begin`` once, then ``advance`` n_steps times.
    Work arrays live on the model (allocated once), so stepping allocates nothing."""

    name = "explicit"
    implicit = False

    def begin(self, model: Model, state: State) -> None:
        """Prepare caches that depend on the current state (nothing for one-stage methods)."""

    def advance(self, model: Model, state: State, dt: float) -> None:
        raise NotImplementedError

    def step(self, model: Model, state: State, dt: float, n_steps: int = 1) -> None:
        dt = float(dt)
        self.begin(model, state)
        for _ in range(int(n_steps)):
            self.advance(model, state, dt)

    def _elastic_forces(self, model: Model, state: State):
        f = model.work_vec3("f")
        zero_vec3(f)
        model.add_elastic_forces(state.x, f)
        return f

    def __repr__(self) -> str:
        return f"<integrator {self.name}>"


class ForwardEuler(ExplicitIntegrator):
    name = "forward-euler"

    def advance(self, model, state, dt):
        f = self._elastic_forces(model, state)
        forward_euler_update(state.x, state.v, f, model.inv_mass_nd, model.gravity_vec, dt)
        state.t += dt


class SymplecticEuler(ExplicitIntegrator):
    """``fused`` (default): springs [+ one bending energy] models take one kernel launch per step
    (:mod:`engine.integrators.fused_step`, bitwise the same result); others the generic path."""

    name = "symplectic-euler"

    def __init__(self, fused: bool = True):
        self.fused = bool(fused)

    def advance(self, model, state, dt):
        if self.fused:
            from engine.integrators.fused_step import fused_symplectic_step
            one_launch = fused_symplectic_step(model)
            if one_launch is not None:
                one_launch(state, float(dt))
                state.t += dt
                return
        f = self._elastic_forces(model, state)
        symplectic_euler_update(state.x, state.v, f, model.inv_mass_nd, model.gravity_vec, dt)
        state.t += dt


class VelocityVerlet(ExplicitIntegrator):
    """Kick-drift-kick.  The acceleration a(x) is computed in :meth:`begin` (one extra force
    evaluation per ``step`` call, not per step) and then carried from step to step."""

    name = "velocity-verlet"

    def begin(self, model, state):
        f = self._elastic_forces(model, state)
        accel_kick(state.v, f, model.work_vec3("a"), model.inv_mass_nd, model.gravity_vec, 0.0)

    def advance(self, model, state, dt):
        a = model.work_vec3("a")
        verlet_kick_drift(state.x, state.v, a, model.inv_mass_nd, dt)
        f = self._elastic_forces(model, state)
        accel_kick(state.v, f, a, model.inv_mass_nd, model.gravity_vec, 0.5 * dt)
        state.t += dt


# --------------------------------------------------------------------------------------------
# Stability: CFL estimates
# --------------------------------------------------------------------------------------------

def gershgorin_lambda_max(model: Model, x=None) -> float:
    """Gershgorin upper bound on the largest eigenvalue of M^-1 H (free vertices), H the exact
    Hessian at x (default: the rest state).  Every energy must implement gershgorin_row_sums."""
    x = model.X_nd if x is None else x
    rows = np.zeros((model.n, 3))
    for e in model.energies:
        rows += e.gershgorin_row_sums(x)
    free = model.free
    if not free.any():
        return 0.0
    return float((rows[free].max(axis=1) / model.mass[free]).max())


@ti.kernel
def _minv_scale(y: vec3_array, u: vec3_array, inv_mass: scalar_array, scale: float):
    # u = scale M^-1 y on free vertices, 0 on pinned
    for i in range(y.shape[0]):
        u[i] = scale * inv_mass[i] * y[i]


def lambda_max_power(model: Model, x=None, psd: bool = False, iters: int = 500, rtol: float = 1e-8,
                     seed: int = 0) -> float:
    """Largest-magnitude eigenvalue of M^-1 H restricted to free vertices, by power iteration
    with Hessian-vector products: u <- M^-1 H u, lambda = (u.H u)/(u.M u) (Rayleigh quotient of
    the symmetric pencil (H, M)).  x defaults to the rest state."""
    x = model.X_nd if x is None else x
    if not model.free.any():
        return 0.0
    u, y = model.work_vec3("power_u"), model.work_vec3("power_y")
    rng = np.random.default_rng(seed)
    u0 = rng.standard_normal((model.n, 3))
    u0[model.pinned] = 0.0
    u.from_numpy(u0.astype(float_dtype()))
    scale_vec3(u, 1.0 / math.sqrt(mass_dot(u, u, model.mass_nd, model.inv_mass_nd)))
    lam_old = math.inf
    lam = 0.0
    for _ in range(int(iters)):
        zero_vec3(y)
        model.add_hessian_product(x, u, y, psd)
        lam = free_dot(u, y, model.inv_mass_nd, False)  # u.H u with u.M u = 1
        _minv_scale(y, u, model.inv_mass_nd, 1.0)
        norm2 = mass_dot(u, u, model.mass_nd, model.inv_mass_nd)
        if norm2 == 0.0:
            return 0.0
        scale_vec3(u, 1.0 / math.sqrt(norm2))
        if abs(lam - lam_old) <= rtol * abs(lam):
            break
        lam_old = lam
    return float(lam)


def stable_dt_estimate(model: Model, method: str = "gershgorin", x=None) -> float:
    """Largest stable dt for symplectic Euler / velocity Verlet: 2 / sqrt(lambda_max(M^-1 H)).

    method="gershgorin" (default): conservative bound at the rest state (or x).
    method="power": power-iteration estimate (close to the true limit, not conservative).
    Returns inf when nothing is stiff."""
    if method not in ("gershgorin", "power"):
        raise ValueError(f"method must be 'gershgorin' or 'power' (got {method!r})")
    lam = gershgorin_lambda_max(model, x) if method == "gershgorin" else abs(lambda_max_power(model, x))
    return 2.0 / math.sqrt(lam) if lam > 0 else math.inf


# --------------------------------------------------------------------------------------------
# Running with blow-up detection
# --------------------------------------------------------------------------------------------

def _blowup_message(name: str, step: int, t: float, E: float, bound: float | None, dt: float,
                    dt_stable: float) -> str:
    what = "is not finite" if not math.isfinite(E) else f"exceeds the bound {bound:.4g} J"
    ratio = dt / dt_stable if math.isfinite(dt_stable) and dt_stable > 0 else 0.0
    if name == "forward-euler":
        cause = ("forward Euler adds energy to every undamped oscillation at any dt (it is unstable "
                 "for springs); use symplectic-euler, velocity-verlet or backward-euler")
    elif ratio > 1.0:
        cause = (f"dt is {ratio:.2f}x the CFL limit: explicit steps must not outrun the fastest mode "
                 f"(dt <= 2/w_max); reduce dt below {dt_stable:.3g} s or use backward-euler")
    else:
        cause = ("dt is below the rest-state CFL limit, so large deformation or compression probably "
                 "raised the stiffness (or an external input injected energy); reduce dt or use backward-euler")
    return (f"{name} blew up at step {step} (t={t:.4g} s): total energy {E:.4g} J {what}; "
            f"dt={dt:.3g} s vs CFL estimate dt_stable={dt_stable:.3g} s; likely cause: {cause}")


def run(model: Model, state: State, dt: float, n_steps: int, integrator="symplectic-euler",
        energy_bound: float | None = None, check_every: int = 1) -> np.ndarray:
    """Advance ``n_steps`` steps, computing the total energy after every ``check_every``-th step
    (and after the last).  Raises :class:`BlowUpError` at the first check where the energy is
    not finite or exceeds ``energy_bound`` (J).  ``check_every=0`` disables checks.

    Returns the total energies at the checks (numpy, one per check)."""
    from engine.integrators import get

    integ = get(integrator) if isinstance(integrator, str) else integrator
    dt = float(dt)
    n_steps = int(n_steps)
    if check_every <= 0:
        integ.step(model, state, dt, n_steps)
        return np.zeros(0)
    history = []
    if hasattr(integ, "advance"):
        integ.begin(model, state)
        advance = integ.advance
    else:  # e.g. an implicit integrator with only step(): one step per call
        def advance(model, state, dt):
            integ.step(model, state, dt, 1)
    for s in range(n_steps):
        advance(model, state, dt)
        if (s + 1) % check_every == 0 or s == n_steps - 1:
            E = diagnostics.total_energy(model, state)
            history.append(E)
            if not math.isfinite(E) or (energy_bound is not None and E > energy_bound):
                try:
                    dts = stable_dt_estimate(model)
                except NotImplementedError:  # an energy without a Gershgorin bound
                    dts = stable_dt_estimate(model, method="power")
                raise BlowUpError(_blowup_message(integ.name, s, state.t, E, energy_bound, dt, dts),
                                  step=s, time=state.t, energy=E, dt=dt, dt_stable=dts, integrator=integ.name)
    return np.asarray(history)
