"""The springs lesson's exercise: one spring's energy, force and Hessian block (S1)-(S3), and the
symplectic Euler and velocity Verlet updates (E2), (E3).

The student's functions take the engine's place in every kernel of the lesson (the generic step,
the fused cloth step, the many-steps kernel, the static solver's Hessian), and each is checked on
its own first: the energy against (S1), the force against finite differences of the energy, the
Hessian block against finite differences of the force, the updates against one step by hand.
"""

import math

import numpy as np
import taichi as ti

from engine.energies import springs as S
from engine.integrators import kernels as K
from .._exercise import TI_FUNC, Sampler, StudentError, Task, agreement, central_difference, deviation, \
    explain_failure, matches, substitute

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


def _springs(n: int = 64, seed: int = 11):
    """Springs to check on: edge vectors d (m) from 0.3 L to 2 L long in random directions, the first
    six exactly at rest length; rest lengths L from 1 mm to 100 m and coefficients c from 0.01 to
    10^4 J (several scales, so that a formula right only for L = 1 or c = 1 shows)."""
    s = Sampler(seed)
    L = s.log_uniform(n, 1e-3, 1e2)
    c = s.log_uniform(n, 1e-2, 1e4)
    stretch = s.uniform(n, 0.3, 2.0)
    stretch[:6] = 1.0
    u = s.vectors(n)
    u /= np.linalg.norm(u, axis=1)[:, None]
    return u * (stretch * L)[:, None], L, c


def _where(d, L, i: int) -> str:
    return f"spring {i} (l = {np.linalg.norm(d[i]):.3g} m, L = {L[i]:.3g} m)"


# ------------------------------------------------------------------ the checks

def check_energy(student) -> list:
    d, L, c = _springs()
    got = student.via(_spring_call, "s")(d, L, c)
    l = np.linalg.norm(d, axis=1)
    ref = 0.5 * c * (l / L - 1.0) ** 2
    dev = deviation(got, ref, scale=c)
    tol = 1e-10
    reason = ""
    if not dev <= tol:
        mistakes = [
            (0.5 * c * (l - L) ** 2, "uses the stretch l - L as the strain: the strain is l/L - 1, "
                                     "dimensionless"),
            (0.5 * c * ((l / L) ** 2 - 1.0) ** 2, "uses (l/L)^2 - 1 as the strain: (S1)'s strain is l/L - 1"),
            (0.5 * c * (l / L - 1.0) ** 2 * L, "is L times (S1), 1/2 c (l/L - 1)^2 L: c = k L already holds "
                                               "the L of the notes' 1/2 k (l/L - 1)^2 L"),
            (0.5 * c * (l / L - 1.0) ** 2 / L, "divides by L: (S1) is 1/2 c (l/L - 1)^2 with c in J"),
        ]
        reason = explain_failure(
            "spring_energy", got, ref, tol, scale=c, of="1/2 c (l/L - 1)^2", where=lambda i: _where(d, L, i),
            checks=[(lambda: np.any(np.abs(got[:6]) > 1e-12 * c[:6]),
                     "spring_energy is not zero at the rest length (l = L): the strain is l/L - 1; "
                     "is the rest length used?")],
            mistakes=mistakes,
            factor_notes={"twice": ": the 1/2 is missing"},
            otherwise=lambda i: (f"spring_energy differs from 1/2 c (l/L - 1)^2 at {_where(d, L, i)}: "
                                 f"{got[i]:.6g} J instead of {ref[i]:.6g} J"))
    return [agreement(f"spring_energy = 1/2 c (l/L - 1)^2 (S1), {len(d)} springs, L from 1 mm to 100 m "
                      f"(max deviation / c)", "ex-spring-energy", dev, tol, reason)]


def check_force(student) -> list:
    d, L, c = _springs()
    got = student.via(_spring_call, "v")(d, L, c)
    l = np.linalg.norm(d, axis=1)
    n = d / l[:, None]
    energy = _spring_call(S.spring_energy, "s")
    h = 1e-6 * L
    ref = -central_difference(lambda dd: energy(dd * np.repeat(h, 3)[:, None], np.repeat(L, 3), np.repeat(c, 3)),
                              d / h[:, None], 1.0) / h[:, None]   # steps of 1e-6 L at each spring's own scale
    scale = c / L
    dev = deviation(got, ref, scale)
    tol = 1e-6
    at_zero = student.via(_spring_call, "v")(np.zeros((3, 3)), L[:3], c[:3])
    reason = ""
    if not dev <= tol:
        strain = (l / L - 1.0)[:, None]
        mistakes = [
            (-(c / L)[:, None] * strain * d, "points along d, not along the unit vector d/l: the force is "
                                             "-(c/L)(l/L - 1) d/l"),
            (-c[:, None] * strain * n, "is missing 1/L: dW/dl = (c/L)(l/L - 1), the chain rule through l/L"),
            (-(c / L ** 2)[:, None] * strain * n, "divides by L once too often: dW/dl = (c/L)(l/L - 1)"),
            (-(c / L)[:, None] * (l - L)[:, None] * n, "uses l - L as the strain: it is l/L - 1"),
            (-(c / L)[:, None] * strain * d / L[:, None], "divides d by L, not by l: the direction is the unit "
                                                          "vector d/l"),
        ]
        reason = explain_failure(
            "spring_force", got, ref, tol, scale, of="-dW/dx of (S1)", where=lambda i: _where(d, L, i),
            checks=[(lambda: np.any(np.abs(got[:6]) > 1e-9 * scale[:6, None]),
                     "spring_force is not zero at the rest length (l = L): is the rest length used?")],
            sign="it is +dW/dx, so a stretched spring would push its ends apart; the force is minus the gradient",
            mistakes=mistakes,
            otherwise=lambda i: f"force is not -dW/dx: deviation {dev:.2g} of c/L at {_where(d, L, i)}")
    zero_dev = deviation(at_zero, np.zeros((3, 3)), scale=(c / L)[:3])
    zero_reason = "" if zero_dev <= 1e-12 else (
        "spring_force returns NaN or inf at l = 0 (d/l is 0/0): the template asks for the zero vector there"
        if not np.all(np.isfinite(at_zero)) else "spring_force is not the zero vector at l = 0")
    return [agreement(f"spring_force = -dW/dx of (S1) by finite differences (S2), {len(d)} springs "
                      f"(max deviation / (c/L))", "ex-spring-force", dev, tol, reason),
            agreement("spring_force is the zero vector when l = 0 (the template's promise)", "ex-spring-force-zero",
                      zero_dev, 1e-12, zero_reason)]


def check_hessian(student) -> list:
    d, L, c = _springs()
    got = student.via(_spring_call, "m")(d, L, c)
    force = _spring_call(_engine_force, "v")
    h = 1e-6 * L
    ref = -central_difference(lambda dd: force(dd * np.repeat(h, 3)[:, None], np.repeat(L, 3), np.repeat(c, 3)),
                              d / h[:, None], 1.0) / h[:, None, None]
    scale = c / L ** 2
    dev = deviation(got, ref, scale)
    tol = 1e-6
    reason = ""
    if not dev <= tol:
        l = np.linalg.norm(d, axis=1)
        n = d / l[:, None]
        nnT = np.einsum("ni,nj->nij", n, n)
        along = (c / L ** 2)[:, None, None] * nnT
        across = (c / L ** 2 * (1.0 - L / l))[:, None, None] * (np.eye(3) - nnT)
        clipped = along + np.where((l < L)[:, None, None], 0.0, across)
        mistakes = [
            (along, "has only the part along the spring: the transverse term (c/L^2)(1 - L/l)(I - n n^T) is "
                    "missing"),
            (clipped, "clips the transverse term of compressed springs: write the exact block, the engine "
                      "clips it where it needs to"),
            (along - across, "has the transverse term with the wrong sign: it is (c/L^2)(1 - L/l)(I - n n^T)"),
            (along + (c / L ** 2 * (1.0 - l / L))[:, None, None] * (np.eye(3) - nnT),
             "has 1 - l/L in the transverse term: it is 1 - L/l (the tension over l)"),
            (along + (c / L ** 2 * (l / L - 1.0))[:, None, None] * (np.eye(3) - nnT),
             "has the strain l/L - 1 in the transverse term: it is 1 - L/l (the tension over l), equal only to "
             "first order in the strain"),
            (along + (c / L ** 2 * (1.0 - L / l))[:, None, None] * np.eye(3),
             "puts the transverse term on I: it acts across the spring only, (1 - L/l)(I - n n^T)"),
            ((along + across) * L[:, None, None], "is L times the block: the prefactor is c/L^2 (c/L from "
                                                  "dW/dl, 1/L more from the strain)"),
        ]
        reason = explain_failure(
            "spring_hessian", got, ref, tol, scale, of="d^2W/dx^2 of (S1)", where=lambda i: _where(d, L, i),
            checks=[(lambda: np.abs(got - np.transpose(got, (0, 2, 1))).max(axis=(1, 2)).max(initial=0)
                     > 1e-9 * scale.max(), "spring_hessian is not symmetric: a Hessian block K = d^2W/dd^2 is")],
            sign="it is df/dx; the Hessian is -df/dx = d^2W/dx^2",
            mistakes=mistakes,
            otherwise=lambda i: f"Hessian is not -df/dx: deviation {dev:.2g} of c/L^2 at {_where(d, L, i)}")
    return [agreement(f"spring_hessian = -df/dx by finite differences of the force (S3), {len(d)} springs "
                      f"(max deviation / (c/L^2))", "ex-spring-hessian", dev, tol, reason)]


def _update_call(func, n_in: int, scalar: bool = False):
    """A kernel calling func(x, v, a, dt) -> (x+, v+) (n_in = 4) or func(v, a, dt) -> v+ (n_in = 3),
    on vec3 states or (``scalar``) on floats."""
    arr = floats if scalar else vec3s
    if n_in == 4:
        @ti.kernel
        def run(x: arr, v: arr, a: arr, dt: floats, xo: arr, vo: arr):
            for i in range(x.shape[0]):
                xo[i], vo[i] = func(x[i], v[i], a[i], dt[i])

        def call(x, v, a, dt):
            xo, vo = np.zeros_like(x), np.zeros_like(v)
            run(x, v, a, dt, xo, vo)
            return xo, vo
    else:
        @ti.kernel
        def run(v: arr, a: arr, dt: floats, vo: arr):
            for i in range(v.shape[0]):
                vo[i] = func(v[i], a[i], dt[i])

        def call(v, a, dt):
            vo = np.zeros_like(v)
            run(v, a, dt, vo)
            return vo
    return call


def _states(n: int = 32, seed: int = 5):
    """Random states: vec3 x, v, a and steps dt from 1e-5 to 1 s; and the same as floats."""
    s = Sampler(seed)
    vec = (s.vectors(n), s.vectors(n), s.vectors(n, 10.0), s.log_uniform(n, 1e-5, 1.0))
    flat = (s.vectors(n)[:, 0].copy(), s.vectors(n)[:, 0].copy(), s.vectors(n, 10.0)[:, 0].copy(),
            s.log_uniform(n, 1e-5, 1.0))
    return vec, flat


def _one_step(student, n_in: int, reference, what: str, id: str, diagnose, seed: int) -> list:
    """The update on vec3 states and on floats (the template promises both) against ``reference``."""
    exps = []
    for states, scalar in zip(_states(seed=seed), (False, True)):
        states = states if n_in == 4 else states[1:]
        try:
            got = student.via(_update_call, n_in, scalar)(*states)
        except StudentError as exc:
            if not scalar:
                raise
            got, why = None, f"{exc}: the same code must work when x, v and a are floats (the rod)"
        got = got if isinstance(got, tuple) else (got,) if got is not None else None
        ref = reference(*states)
        ref = ref if isinstance(ref, tuple) else (ref,)
        if got is not None:
            dev = max(deviation(g, r) for g, r in zip(got, ref))
            why = "" if dev <= 1e-13 else diagnose(states, got)
        else:
            dev = math.inf
        kind = "floats" if scalar else "vec3"
        exps.append(agreement(f"{student.name}: {what}, 32 random {kind} states, dt from 1e-5 to 1 s "
                              f"(max rel. deviation)", f"{id}{'-float' if scalar else ''}", dev, 1e-13, why))
    return exps


def check_symplectic(student) -> list:
    def reference(x, v, a, dt):
        v1 = v + _col(dt, v) * a
        return x + _col(dt, v) * v1, v1

    def diagnose(states, got):
        x, v, a, dt = states
        xo, vo = got
        if not (np.all(np.isfinite(xo)) and np.all(np.isfinite(vo))):
            return "symplectic_euler returns NaN or inf"
        if matches(vo, v + 0.5 * _col(dt, v) * a, tol=1e-13):
            return "symplectic_euler kicks by dt/2 a: symplectic Euler's kick is a whole step, v+ = v + dt a"
        if deviation(vo, v + _col(dt, v) * a) > 1e-13:
            return "symplectic_euler's velocity is not v + dt a"
        if deviation(xo, x + _col(dt, v) * v) <= 1e-13:
            return ("symplectic_euler moves x with the old velocity: that is forward Euler (E1); symplectic "
                    "Euler moves x with the new velocity v+ (E2)")
        return "symplectic_euler's position is not x + dt v+"
    return _one_step(student, 4, reference, "one step = v+ = v + dt a, x+ = x + dt v+ (E2)", "ex-symplectic-euler",
                     diagnose, 5)


def _col(dt, like):
    return dt[:, None] if np.ndim(like) == 2 else dt


def check_kick_drift(student) -> list:
    def reference(x, v, a, dt):
        vh = v + 0.5 * _col(dt, v) * a
        return x + _col(dt, v) * vh, vh

    def diagnose(states, got):
        x, v, a, dt = states
        xo, vo = got
        dt = _col(dt, v)
        if not (np.all(np.isfinite(xo)) and np.all(np.isfinite(vo))):
            return "verlet_kick_drift returns NaN or inf"
        if deviation(vo, v + dt * a) <= 1e-13:
            return "verlet_kick_drift kicks by dt a: velocity Verlet's first kick is half a step, dt/2 a"
        if deviation(vo, v + 0.5 * dt * a) > 1e-13:
            return "verlet_kick_drift's velocity is not v + dt/2 a"
        if deviation(xo, x + dt * v) <= 1e-13:
            return "verlet_kick_drift drifts with the old velocity: the drift uses the half-kicked v*"
        if deviation(xo, x + 0.5 * dt * (v + 0.5 * dt * a)) <= 1e-13:
            return "verlet_kick_drift drifts half a step: the drift is a whole step, x+ = x + dt v*"
        return "verlet_kick_drift's position is not x + dt v* (the half-kicked velocity)"
    return _one_step(student, 4, reference, "v* = v + dt/2 a, x+ = x + dt v* (E3)", "ex-verlet-kick-drift",
                     diagnose, 6)


def check_kick(student) -> list:
    def reference(v, a, dt):
        return v + 0.5 * _col(dt, v) * a

    def diagnose(states, got):
        v, a, dt = states
        (vo,) = got
        if not np.all(np.isfinite(vo)):
            return "verlet_kick returns NaN or inf"
        if deviation(vo, v + _col(dt, v) * a) <= 1e-13:
            return "verlet_kick kicks by dt a: velocity Verlet's second kick is half a step, dt/2 a(x+)"
        return "verlet_kick is not v* + dt/2 a(x+)"
    return _one_step(student, 3, reference, "v+ = v* + dt/2 a(x+) (E3)", "ex-verlet-kick", diagnose, 8)


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

LABELS = {   # the equations this exercise cites, defined in its template (what, not how)
    "S1": "W = 1/2 c (l/L - 1)^2, one spring's energy (c = k L; l = |x_i - x_j|, L the rest length)",
    "S2": "the force on the spring's end i: minus the gradient of (S1) with respect to x_i",
    "S3": "the Hessian block of (S1): its second derivative with respect to x_i",
    "E1": "forward Euler: position and velocity both move with the old state",
    "E2": "symplectic Euler: the velocity first, with the acceleration at x; the position then with the new velocity",
    "E3": "velocity Verlet: half a kick, a whole drift, and half a kick with the acceleration at the new position",
}

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
