"""The springs lesson's exercise: one spring's energy, force and Hessian block (S1)-(S3), and the
symplectic Euler and velocity Verlet updates (E2), (E3).

The student's functions take the engine's place in every kernel of the lesson (the generic step,
the fused cloth step, the many-steps kernel, the static solver's Hessian), and each is checked on
its own first: the energy against (S1), the force against finite differences of the energy, the
Hessian block against finite differences of the force, the updates against one step by hand.
"""

import numpy as np
import taichi as ti

from engine.energies import springs as S
from engine.integrators import kernels as K
from .._exercise import call_student, TI_FUNC, Sampler, Task, agreement, central_difference, deviation, \
    factor_text, first_bad, ratio, substitute

from engine.fields import mat3_array as mat3s, scalar_array as floats, vec3_array as vec3s


# ------------------------------------------------------------------ calling one spring's functions

def _spring_call(func, out_kind: str):
    """A kernel calling ``func(d, L, c)`` for a batch; ``out_kind``: 's' float, 'v' vec3, 'm' mat3."""
    if out_kind == "s":
        @ti.kernel
        def run(d: vec3s, L: floats, c: floats, out: floats):
            for i in range(d.shape[0]):
                out[i] = func(d[i], L[i], c[i])
    elif out_kind == "v":
        @ti.kernel
        def run(d: vec3s, L: floats, c: floats, out: vec3s):
            for i in range(d.shape[0]):
                out[i] = func(d[i], L[i], c[i])
    else:
        @ti.kernel
        def run(d: vec3s, L: floats, c: floats, out: mat3s):
            for i in range(d.shape[0]):
                out[i] = func(d[i], L[i], c[i])
    shape = {"s": (), "v": (3,), "m": (3, 3)}[out_kind]

    def call(d, L, c):
        out = np.zeros((len(d),) + shape)
        run(np.ascontiguousarray(d, float), np.ascontiguousarray(L, float), np.ascontiguousarray(c, float), out)
        return out
    return call


@ti.func
def _engine_force(d, L, c):
    return S.spring_force(d, 1.0 / L, c / L)


@ti.func
def _engine_block(d, L, c):
    return S.spring_block(d, 1.0 / L, c / L, 0)


def _springs(n: int = 48, seed: int = 11):
    """Springs to check on: edge vectors d (m) of lengths 0.5 L to 1.6 L in random directions, the
    first four exactly at rest length; rest lengths L (m) and coefficients c (J)."""
    s = Sampler(seed)
    L = s.uniform(n, 0.5, 2.0)
    c = s.uniform(n, 1.0, 10.0)
    stretch = s.uniform(n, 0.5, 1.6)
    stretch[:4] = 1.0
    u = s.vectors(n)
    u /= np.linalg.norm(u, axis=1)[:, None]
    return u * (stretch * L)[:, None], L, c


def _where(d, L, i: int) -> str:
    return f"spring {i} (l = {np.linalg.norm(d[i]):.3g} m, L = {L[i]:.3g} m)"


# ------------------------------------------------------------------ the checks

def check_energy(func) -> list:
    d, L, c = _springs()
    got = call_student("spring_energy", _spring_call(func, "s"), d, L, c)
    ref = _spring_call(S.spring_energy, "s")(d, L, c)
    dev = deviation(got, ref)
    tol = 1e-10
    reason = ""
    if not dev <= tol:
        i = first_bad(got, ref, tol)
        r = factor_text(ratio(got, ref))
        if not np.all(np.isfinite(got)):
            reason = f"spring_energy returns NaN or inf at {_where(d, L, i)}"
        elif np.any(np.abs(got[:4]) > 1e-12 * np.abs(ref).max()):
            reason = ("spring_energy is not zero at the rest length (l = L): the strain is l/L - 1; "
                      "is the rest length used?")
        elif r:
            reason = f"spring_energy is {r} 1/2 c (l/L - 1)^2" + (": the 1/2 is missing" if r == "twice" else "")
        else:
            reason = (f"spring_energy differs from 1/2 c (l/L - 1)^2 at {_where(d, L, i)}: "
                      f"{got[i]:.6g} J instead of {ref[i]:.6g} J")
    return [agreement("spring_energy = 1/2 c (l/L - 1)^2 (S1), 48 springs (max rel. deviation)",
                      "ex-spring-energy", dev, tol, reason)]


def check_force(func) -> list:
    d, L, c = _springs()
    got = call_student("spring_force", _spring_call(func, "v"), d, L, c)
    energy = _spring_call(S.spring_energy, "s")
    ref = -central_difference(lambda dd: energy(dd, np.repeat(L, 3), np.repeat(c, 3)), d, 1e-6)
    dev = deviation(got, ref)
    tol = 1e-6
    reason = ""
    if not dev <= tol:
        i = first_bad(got, ref, tol)
        r = factor_text(ratio(got, ref))
        if not np.all(np.isfinite(got)):
            reason = f"spring_force returns NaN or inf at {_where(d, L, i)}"
        elif np.any(np.abs(got[:4]) > 1e-9 * np.abs(ref).max()):
            reason = "spring_force is not zero at the rest length (l = L): is the rest length used?"
        elif r == "minus":
            reason = ("spring_force has the wrong sign: it is +dW/dx, so a stretched spring would push its "
                      "ends apart; the force is minus the gradient")
        elif r:
            reason = f"spring_force is {r} -dW/dx of (S1)"
        else:
            reason = f"force is not -dW/dx: FD error {dev:.2g} at {_where(d, L, i)}"
    return [agreement("spring_force = -dW/dx of (S1) by finite differences (S2), 48 springs",
                      "ex-spring-force", dev, tol, reason)]


def check_hessian(func) -> list:
    d, L, c = _springs()
    got = call_student("spring_hessian", _spring_call(func, "m"), d, L, c)
    force = _spring_call(_engine_force, "v")
    ref = -central_difference(lambda dd: force(dd, np.repeat(L, 3), np.repeat(c, 3)), d, 1e-6)
    dev = deviation(got, ref)
    tol = 1e-6
    reason = ""
    if not dev <= tol:
        i = first_bad(got, ref, tol)
        r = factor_text(ratio(got, ref))
        n = d / np.linalg.norm(d, axis=1)[:, None]
        along = np.einsum("nij,nj->ni", got - ref, n)
        if not np.all(np.isfinite(got)):
            reason = f"spring_hessian returns NaN or inf at {_where(d, L, i)}"
        elif np.abs(got - np.transpose(got, (0, 2, 1))).max() > 1e-9 * np.abs(ref).max():
            reason = "spring_hessian is not symmetric: a Hessian block K = d^2W/dd^2 is"
        elif r == "minus":
            reason = "spring_hessian has the wrong sign: it is df/dx; the Hessian is -df/dx = d^2W/dx^2"
        elif r:
            reason = f"spring_hessian is {r} d^2W/dx^2 of (S1)"
        elif np.abs(along).max() <= 1e-6 * np.abs(ref).max():
            reason = ("spring_hessian is right along the spring but not across it: the transverse term "
                      "(c/L^2)(1 - L/l)(I - n n^T) is missing or wrong")
        else:
            reason = f"Hessian is not -df/dx: FD error {dev:.2g} at {_where(d, L, i)}"
    return [agreement("spring_hessian = -df/dx by finite differences of the force (S3), 48 springs",
                      "ex-spring-hessian", dev, tol, reason)]


def _update_call(func, n_in: int):
    """A kernel calling func(x, v, a, dt) -> (x+, v+) (n_in = 4) or func(v, a, dt) -> v+ (n_in = 3)."""
    if n_in == 4:
        @ti.kernel
        def run(x: vec3s, v: vec3s, a: vec3s, dt: floats, xo: vec3s, vo: vec3s):
            for i in range(x.shape[0]):
                xo[i], vo[i] = func(x[i], v[i], a[i], dt[i])

        def call(x, v, a, dt):
            xo, vo = np.zeros_like(x), np.zeros_like(v)
            run(x, v, a, dt, xo, vo)
            return xo, vo
    else:
        @ti.kernel
        def run(v: vec3s, a: vec3s, dt: floats, vo: vec3s):
            for i in range(v.shape[0]):
                vo[i] = func(v[i], a[i], dt[i])

        def call(v, a, dt):
            vo = np.zeros_like(v)
            run(v, a, dt, vo)
            return vo
    return call


def _states(n: int = 32, seed: int = 5):
    s = Sampler(seed)
    return s.vectors(n), s.vectors(n), s.vectors(n, 10.0), s.uniform(n, 1e-3, 0.1)


def _one_step(name: str, got, ref, what: str, id: str, diagnose) -> list:
    dev = max(deviation(g, r) for g, r in zip(got, ref))
    tol = 1e-13
    reason = "" if dev <= tol else diagnose()
    return [agreement(f"{name}: {what}, 32 random states (max rel. deviation)", id, dev, tol, reason)]


def check_symplectic(func) -> list:
    x, v, a, dt = _states()
    xo, vo = call_student("symplectic_euler", _update_call(func, 4), x, v, a, dt)
    v1 = v + dt[:, None] * a
    x1 = x + dt[:, None] * v1

    def diagnose():
        if not (np.all(np.isfinite(xo)) and np.all(np.isfinite(vo))):
            return "symplectic_euler returns NaN or inf"
        if deviation(vo, v1) > 1e-13:
            return "symplectic_euler's velocity is not v + dt a"
        if deviation(xo, x + dt[:, None] * v) <= 1e-13:
            return ("symplectic_euler moves x with the old velocity: that is forward Euler (E1); symplectic "
                    "Euler moves x with the new velocity v+ (E2)")
        return "symplectic_euler's position is not x + dt v+"
    return _one_step("symplectic_euler", (xo, vo), (x1, v1), "one step = v+ = v + dt a, x+ = x + dt v+ (E2)",
                     "ex-symplectic-euler", diagnose)


def check_kick_drift(func) -> list:
    x, v, a, dt = _states(seed=6)
    xo, vo = call_student("verlet_kick_drift", _update_call(func, 4), x, v, a, dt)
    vh = v + 0.5 * dt[:, None] * a
    xh = x + dt[:, None] * vh

    def diagnose():
        if not (np.all(np.isfinite(xo)) and np.all(np.isfinite(vo))):
            return "verlet_kick_drift returns NaN or inf"
        if deviation(vo, v + dt[:, None] * a) <= 1e-13:
            return "verlet_kick_drift kicks by dt a: velocity Verlet's first kick is half a step, dt/2 a"
        if deviation(vo, vh) > 1e-13:
            return "verlet_kick_drift's velocity is not v + dt/2 a"
        return "verlet_kick_drift's position is not x + dt v* (the half-kicked velocity)"
    return _one_step("verlet_kick_drift", (xo, vo), (xh, vh), "v* = v + dt/2 a, x+ = x + dt v* (E3)",
                     "ex-verlet-kick-drift", diagnose)


def check_kick(func) -> list:
    _, v, a, dt = _states(seed=8)
    vo = call_student("verlet_kick", _update_call(func, 3), v, a, dt)
    ref = v + 0.5 * dt[:, None] * a

    def diagnose():
        if not np.all(np.isfinite(vo)):
            return "verlet_kick returns NaN or inf"
        if deviation(vo, v + dt[:, None] * a) <= 1e-13:
            return "verlet_kick kicks by dt a: velocity Verlet's second kick is half a step, dt/2 a(x+)"
        return "verlet_kick is not v* + dt/2 a(x+)"
    return _one_step("verlet_kick", (vo,), (ref,), "v+ = v* + dt/2 a(x+) (E3)", "ex-verlet-kick", diagnose)


# ------------------------------------------------------------------ taking the engine's place

def install_energy(func) -> None:
    substitute(S.spring_energy, func)


def install_force(func) -> None:
    @ti.func
    def spring_force(d, inv_L, c_over_L):
        return func(d, 1.0 / inv_L, c_over_L / inv_L)
    substitute(S.spring_force, spring_force)


def install_hessian(func) -> None:
    @ti.func
    def spring_block(d: ti.math.vec3, inv_L: float, c_over_L: float, psd: ti.i32) -> ti.math.mat3:
        L = 1.0 / inv_L
        H = func(d, L, c_over_L * L)
        l = d.norm()
        if psd != 0 and l > 0.0:   # (S4): the engine clips the transverse term of a compressed spring
            s = 1.0 - L / l
            if s < 0.0:
                n = d / l
                H -= (c_over_L * inv_L * s) * (ti.math.eye(3) - n.outer_product(n))
        return H
    substitute(S.spring_block, spring_block)


def _install_update(symplectic=None, kick_drift=None, kick=None) -> None:
    """The engine's one update function (engine.integrators.kernels.vertex_update) with the
    student's symplectic Euler and velocity Verlet in place of the engine's formulas."""
    engine_update = K.vertex_update
    SE, VV = K.SYMPLECTIC_EULER, K.VELOCITY_VERLET
    STEP, DRIFT, KICK_DRIFT, ACCEL_KICK = K.STEP, K.DRIFT, K.KICK_DRIFT, K.ACCEL_KICK
    own_se, own_kd, own_k = symplectic is not None, kick_drift is not None, kick is not None

    @ti.func
    def vertex_update(method: ti.template(), phase: ti.template(), xi, vi, ai, f_i, inv_m, g, dt, zero):
        xo, vo, ao = engine_update(method, phase, xi, vi, ai, f_i, inv_m, g, dt, zero)
        if ti.static(method == SE and own_se):
            if inv_m > 0.0:
                if ti.static(phase == DRIFT):   # the drift alone: x + dt v with no acceleration
                    xs, vs = symplectic(xi, vi, zero, dt)
                    xo = xs
                else:
                    xs, vs = symplectic(xi, vi, inv_m * f_i + g, dt)
                    vo = vs
                    if ti.static(phase == STEP):
                        xo = xs
        if ti.static(method == VV and phase == KICK_DRIFT and own_kd):
            if inv_m > 0.0:
                xo, vo = kick_drift(xi, vi, ai, dt)
        if ti.static(method == VV and phase == ACCEL_KICK and own_k):
            if inv_m > 0.0:
                vo = kick(vi, ao, 2.0 * dt)   # the engine passes the half step here
        return xo, vo, ao
    substitute(K.vertex_update, vertex_update)


_UPDATES: dict = {}


def install_symplectic(func) -> None:
    _UPDATES["symplectic"] = func


def install_kick_drift(func) -> None:
    _UPDATES["kick_drift"] = func


def install_kick(func) -> None:
    _UPDATES["kick"] = func


def finish_install() -> None:
    """After the tasks' installs: the update functions go in together (one vertex_update)."""
    if _UPDATES:
        _install_update(**_UPDATES)


ALL_STAGES = (1, 2, 3, 4, 5)

TASKS = [
    Task("spring_energy", TI_FUNC, "d, L, c", """\
The elastic energy of one spring (S1), in J.

d: the edge vector x_i - x_j of the spring (m, a ti.math.vec3); L: its rest length (m);
c: its coefficient (J; c = k L for a spring of stiffness k, E A for an area-scaled one).
The strain is the relative change of length, l/L - 1 with l = |d|; the energy is half the
coefficient times the strain squared.""", install_energy, check_energy, ALL_STAGES, "float"),
    Task("spring_force", TI_FUNC, "d, L, c", """\
The force on the end i of one spring (S2), in N (a ti.math.vec3); the end j gets its negative.

d, L, c as in spring_energy. The force is minus the gradient of the energy with respect to x_i:
it points along d, pulls the ends together when the spring is stretched and apart when it is
compressed, and vanishes at the rest length. Return the zero vector when l = 0.""",
         install_force, check_force, ALL_STAGES, "ti.math.vec3"),
    Task("spring_hessian", TI_FUNC, "d, L, c", """\
The Hessian block K = d^2 W / d x_i^2 of one spring (S3), in N/m (a ti.math.mat3); the spring's
full Hessian over (x_i, x_j) is [[K, -K], [-K, K]].

d, L, c as in spring_energy; n = d / l. K has a part along the spring (the stiffness c/L^2
acting on n n^T) and a transverse part across it (proportional to 1 - L/l, so negative when
the spring is compressed). Write the exact block; the engine clips the transverse part of a
compressed spring itself where it needs a positive semi-definite matrix.""",
         install_hessian, check_hessian, (1, 5), "ti.math.mat3"),
    Task("symplectic_euler", TI_FUNC, "x, v, a, dt", """\
One symplectic (semi-implicit) Euler step of one vertex (E2): returns (x_new, v_new).

x: position (m), v: velocity (m/s), a: acceleration at x (m/s^2, forces over mass plus gravity),
all ti.math.vec3 (or floats: the same code must work for both); dt: the time step (s).
The velocity is updated first from the acceleration; the position then moves with the NEW
velocity.""", install_symplectic, check_symplectic, (2, 3, 4), "x_new, v_new"),
    Task("verlet_kick_drift", TI_FUNC, "x, v, a, dt", """\
The first half of a velocity Verlet step (E3): returns (x_new, v_half).

x, v, a, dt as in symplectic_euler. A half kick of the velocity with the acceleration at x,
then a full drift of the position with that half-kicked velocity.""",
         install_kick_drift, check_kick_drift, (2, 3, 4), "x_new, v_half"),
    Task("verlet_kick", TI_FUNC, "v_half, a_new, dt", """\
The second half of a velocity Verlet step (E3): returns v_new.

v_half: the velocity after the first half kick (m/s); a_new: the acceleration at the new
position (m/s^2); dt: the time step (s). A second half kick.""",
         install_kick, check_kick, (2, 3, 4), "v_new"),
]
