"""The explicit-vs-implicit lesson's exercise: one backward-Euler Newton step (N1).

The engine assembles and solves the Newton system; the student writes what defines it: the
right-hand side -grad Phi at a vertex, the coefficients of the matrix A = a M + b H, and the
velocity update after the step. They take the engine's place in its backward-Euler step, and are
checked on their own first.
"""
import math

import numpy as np
import taichi as ti

from engine.fields import scalar_array, vec3_array
from engine.integrators import implicit as I
from .._exercise import NUMPY, TI_FUNC, Sampler, StudentError, Task, agreement, deviation, direct, factor_text, \
    first_bad, matches, ratio, substitute


def _vertices(n: int = 48, seed: int = 4):
    """Random vertices: forces, masses from 1 g to 10 kg, positions and steps dt from 1e-5 to 1 s."""
    s = Sampler(seed)
    return dict(f=s.vectors(n, 5.0), m=s.log_uniform(n, 1e-3, 10.0), x=s.vectors(n), xn=s.vectors(n),
                v=s.vectors(n), dt=s.log_uniform(n, 1e-5, 1.0))


def _residual_call(func):
    @ti.kernel
    def run(f: vec3_array, m: scalar_array, x: vec3_array, xn: vec3_array, v: vec3_array, dt: scalar_array,
            out: vec3_array):
        for i in range(f.shape[0]):
            out[i] = func(f[i], m[i], x[i], xn[i], v[i], dt[i])

    def call(f, m, x, xn, v, dt):
        out = np.zeros_like(f)
        run(f, m, x, xn, v, dt, out)
        return out
    return call


def _velocity_call(func):
    @ti.kernel
    def run(x: vec3_array, xn: vec3_array, dt: scalar_array, out: vec3_array):
        for i in range(x.shape[0]):
            out[i] = func(x[i], xn[i], dt[i])

    def call(x, xn, dt):
        out = np.zeros_like(x)
        run(x, xn, dt, out)
        return out
    return call


def check_residual(student) -> list:
    s = _vertices()
    got = student.via(_residual_call)(s["f"], s["m"], s["x"], s["xn"], s["v"], s["dt"])
    dt, m, f = s["dt"][:, None], s["m"][:, None], s["f"]
    drift = s["x"] - s["xn"] - dt * s["v"]
    inertia = m * drift / dt ** 2
    ref = f - inertia
    scale = np.abs(ref).max(axis=1)
    dev = deviation(got, ref, scale)
    tol = 1e-12
    reason = ""
    if not dev <= tol:
        i = first_bad(got, ref, tol, scale)
        named = next((text for wrong, text in [
            (-ref, "has the wrong sign: it returns grad Phi = M (x - x_n - dt v_n)/dt^2 - f; the right-hand side "
                   "is -grad Phi = f - M (x - x_n - dt v_n)/dt^2"),
            (f + inertia, "adds the inertia term: -grad Phi = f - M (x - x_n - dt v_n)/dt^2 (the inertia pulls x back "
                          "towards x_n + dt v_n)"),
            (f - m * drift / dt, "divides the inertia term by dt, not dt^2: a missing dt"),
            (f - m * (s["x"] - s["xn"]) / dt ** 2, "leaves out dt v_n: the inertia term is M (x - x_n - dt v_n)/dt^2"),
            (f - drift / dt ** 2, "leaves out the mass: the inertia term is M (x - x_n - dt v_n)/dt^2"),
            (f - drift / (m * dt ** 2), "divides by the mass: the inertia term is M (x - x_n - dt v_n)/dt^2"),
            (dt ** 2 * f - m * drift, "is dt^2 times -grad Phi (Baraff and Witkin's scaling): the engine's matrix is "
                                      "A = M/dt^2 + H, which goes with -grad Phi itself"),
            (f - m * (s["x"] - s["xn"] + dt * s["v"]) / dt ** 2, "adds dt v_n: the inertia term is "
                                                                  "M (x - x_n - dt v_n)/dt^2"),
        ] if matches(got, wrong, scale)), "")
        if not np.all(np.isfinite(got)):
            reason = f"newton_residual returns NaN or inf at vertex {i}"
        elif named:
            reason = f"newton_residual {named}"
        else:
            r = factor_text(ratio(got, ref))
            reason = (f"newton_residual is {r} -grad Phi" if r else
                      f"newton_residual is not f - M (x - x_n - dt v_n)/dt^2: deviation {dev:.2g} at vertex {i} "
                      f"(m = {s['m'][i]:.3g} kg, dt = {s['dt'][i]:.3g} s)")
    return [agreement(f"newton_residual = -grad Phi = f - M (x - x_n - dt v_n)/dt^2 (IP), {len(ref)} random "
                      f"vertices, m from 1 g to 10 kg, dt from 1e-5 to 1 s", "ex-newton-residual", dev, tol, reason)]


def check_coefficients(student) -> list:
    rows = []
    call = student.via(direct)
    for dt in (1e-5, 1e-3, 1.0 / 60, 0.5, 2.0):
        out = call(dt)
        if out.shape != (2,):
            raise StudentError(f"newton_coefficients: returns {out.shape[0] if out.ndim == 1 else out.shape} "
                               f"numbers, expected two: (a, b)")
        rows.append((dt, float(out[0]), float(out[1])))
    got = np.array([[a * dt * dt, b] for dt, a, b in rows])
    ref = np.ones_like(got)
    dev = deviation(got, ref) if np.all(np.isfinite(got)) else math.inf
    tol = 1e-14
    reason = ""
    if not dev <= tol:
        dt, a, b = rows[2]
        if not np.all(np.isfinite(got)):
            reason = "newton_coefficients returns NaN or inf"
        elif abs(a - 1) < 1e-9 and abs(b - dt * dt) < 1e-9 * dt * dt:
            reason = ("newton_coefficients returns Baraff and Witkin's (1, dt^2), which is dt^2 A: that goes with a "
                      "right-hand side times dt^2; the engine's is -grad Phi itself, so A = M/dt^2 + H: (1/dt^2, 1)")
        elif abs(a * dt - 1) < 1e-9:
            reason = "newton_coefficients' mass coefficient is 1/dt: a missing dt (it is 1/dt^2)"
        elif abs(a - 1) < 1e-9:
            reason = ("newton_coefficients' mass coefficient is 1: a missing dt^2 (A = M/dt^2 + H is the Newton "
                      "matrix of Phi; M - dt^2 df/dx is the same matrix times dt^2)")
        elif abs(b - 1) > 1e-9:
            reason = f"newton_coefficients' Hessian coefficient is {b:.6g}; with a = 1/dt^2 it is 1"
        else:
            bad = next(row for row in rows if abs(row[1] * row[0] ** 2 - 1) > tol)
            reason = f"newton_coefficients' mass coefficient is {bad[1]:.6g} at dt = {bad[0]:.4g} s; it is 1/dt^2"
    return [agreement("newton_coefficients(dt) = (1/dt^2, 1): A = M/dt^2 + H (N1), at dt = 10 us ... 2 s "
                      "(max rel. dev. of (a dt^2, b) from (1, 1))", "ex-newton-coefficients", dev, tol, reason)]


def check_velocity(student) -> list:
    s = _vertices(seed=12)
    got = student.via(_velocity_call)(s["x"], s["xn"], s["dt"])
    dt = s["dt"][:, None]
    ref = (s["x"] - s["xn"]) / dt
    scale = np.abs(ref).max(axis=1)
    dev = deviation(got, ref, scale)
    tol = 1e-13
    reason = ""
    if not dev <= tol:
        r = factor_text(ratio(got, ref))
        if not np.all(np.isfinite(got)):
            reason = "step_velocity returns NaN or inf"
        elif r == "minus":
            reason = "step_velocity has the wrong sign: v+ = (x+ - x_n)/dt"
        elif matches(got, ref / dt, scale):
            reason = "step_velocity divides by dt^2: v+ = (x+ - x_n)/dt"
        elif matches(got, ref * dt * dt, scale):
            reason = "step_velocity multiplies by dt instead of dividing: v+ = (x+ - x_n)/dt"
        elif r:
            reason = f"step_velocity is {r} (x+ - x_n)/dt"
        else:
            reason = f"step_velocity is not (x+ - x_n)/dt (deviation {dev:.2g})"
    return [agreement("step_velocity = (x+ - x_n)/dt, 48 random vertices, dt from 1e-5 to 1 s", "ex-step-velocity",
                      dev, tol, reason, "m/s")]


def install_residual(func) -> None:
    @ti.func
    def newton_residual(f_i, m_i, x_i, xn_i, v_i, inv_dt2, alpha_over_dt, dt):
        return func(f_i, m_i, x_i, xn_i, v_i, dt) - m_i * alpha_over_dt * (x_i - xn_i)
    substitute(I.newton_residual, newton_residual)


def install_coefficients(func) -> None:
    def newton_coefficients(dt, alpha=0.0, beta=0.0):
        a, b = func(dt)
        return float(a) + alpha / dt, float(b) + beta / dt
    substitute(I.newton_coefficients, newton_coefficients)


def install_velocity(func) -> None:
    @ti.func
    def step_velocity(x_i, xn_i, inv_dt):
        return func(x_i, xn_i, 1.0 / inv_dt)
    substitute(I.step_velocity, step_velocity)


LABELS = {   # the equations this exercise cites, defined in its template (what, not how)
    "IP": "Phi(x) = |x - x_n - dt v_n|^2_M/(2 dt^2) + W(x) - (gravity's work), backward Euler's incremental "
          "potential: the step is its minimum",
    "N1": "one Newton step on (IP): A dx = -grad Phi, with A the Hessian of Phi",
}

TASKS = [
    Task("newton_residual", TI_FUNC, "f, m, x, x_n, v_n, dt", """\
The right-hand side of backward Euler's Newton system at one free vertex: -grad Phi, in N
(a ti.math.vec3).

f: the force on the vertex at the current iterate x, its weight included (N); m: its mass (kg);
x: the current iterate, x_n: the position at the start of the step (m); v_n: the velocity at
the start of the step (m/s); dt: the time step (s). Phi is the incremental potential (IP):
the inertia term |x - x_n - dt v_n|^2_M / (2 dt^2) plus the elastic energy (minus gravity's
work); minus its gradient is the force minus the inertia term's gradient.""",
         install_residual, check_residual, (), "ti.math.vec3"),
    Task("newton_coefficients", NUMPY, "dt", """\
The coefficients (a, b) of backward Euler's Newton matrix A = a M + b H (N1), where M is the
lumped mass matrix and H the stiffness (the Hessian of the elastic energy).

dt: the time step (s). The Newton step solves A dx = -grad Phi for the change of positions dx
(the engine assembles A from your a and b and solves it). A is the Hessian of Phi; multiplied
by dt^2 it is Baraff and Witkin's M - dt^2 df/dx. Returns (a in 1/s^2, b dimensionless).""",
         install_coefficients, check_coefficients, (), "(a, b)"),
    Task("step_velocity", TI_FUNC, "x_new, x_n, dt", """\
The velocity at the end of a backward-Euler step, in m/s (a ti.math.vec3).

x_new: the position after the step, x_n: the position before it (m); dt: the time step (s).
Backward Euler moves x by dt times the NEW velocity, so the new velocity follows from the
two positions.""", install_velocity, check_velocity, (), "ti.math.vec3"),
]
