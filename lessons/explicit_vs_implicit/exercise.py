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
from .._exercise import call_student, NUMPY, TI_FUNC, Sampler, StudentError, Task, agreement, deviation, factor_text, \
    first_bad, ratio, substitute


def _vertices(n: int = 32, seed: int = 4):
    s = Sampler(seed)
    return dict(f=s.vectors(n, 5.0), m=s.uniform(n, 0.1, 2.0), x=s.vectors(n), xn=s.vectors(n), v=s.vectors(n),
                dt=s.uniform(n, 1e-3, 0.1))


def check_residual(func) -> list:
    @ti.kernel
    def run(f: vec3_array, m: scalar_array, x: vec3_array, xn: vec3_array, v: vec3_array, dt: scalar_array,
            out: vec3_array):
        for i in range(f.shape[0]):
            out[i] = func(f[i], m[i], x[i], xn[i], v[i], dt[i])
    s = _vertices()
    got = np.zeros_like(s["f"])
    call_student("newton_residual", run, s["f"], s["m"], s["x"], s["xn"], s["v"], s["dt"], got)
    dt, m = s["dt"][:, None], s["m"][:, None]
    inertia = m * (s["x"] - s["xn"] - dt * s["v"]) / dt ** 2
    ref = s["f"] - inertia
    dev = deviation(got, ref)
    tol = 1e-12
    reason = ""
    if not dev <= tol:
        i = first_bad(got, ref, tol)
        if not np.all(np.isfinite(got)):
            reason = f"newton_residual returns NaN or inf at vertex {i}"
        elif deviation(got, s["f"] + inertia) <= 1e-9:
            reason = ("newton_residual adds the inertia term: -grad Phi = f - M (x - x_n - dt v_n)/dt^2 (the inertia "
                      "pulls x back towards x_n + dt v_n)")
        elif deviation(got, s["f"] - m * (s["x"] - s["xn"] - dt * s["v"]) / dt) <= 1e-9:
            reason = "newton_residual divides the inertia term by dt, not dt^2: a missing dt"
        elif deviation(got, s["f"] - m * (s["x"] - s["xn"]) / dt ** 2) <= 1e-9:
            reason = "newton_residual leaves out dt v_n: the inertia term is M (x - x_n - dt v_n)/dt^2"
        else:
            r = factor_text(ratio(got, ref))
            reason = (f"newton_residual is {r} -grad Phi" if r else
                      f"newton_residual is not f - M (x - x_n - dt v_n)/dt^2: deviation {dev:.2g} at vertex {i}")
    return [agreement("newton_residual = -grad Phi = f - M (x - x_n - dt v_n)/dt^2 (IP), 32 random vertices",
                      "ex-newton-residual", dev, tol, reason)]


def check_coefficients(func) -> list:
    exps = []
    rows = []
    for dt in (1e-3, 1.0 / 60, 0.5, 2.0):
        try:
            a, b = func(dt)
            a, b = float(a), float(b)
        except Exception as exc:  # noqa: BLE001
            raise StudentError(f"newton_coefficients: raised or did not return two numbers: {type(exc).__name__}: "
                               f"{' '.join(str(exc).split())[:160]}") from None
        rows.append((dt, a, b))
    got = np.array([[a * dt * dt, b] for dt, a, b in rows])
    ref = np.ones_like(got)
    dev = deviation(got, ref) if np.all(np.isfinite(got)) else math.inf
    tol = 1e-14
    reason = ""
    if not dev <= tol:
        dt, a, b = rows[1]
        if not np.all(np.isfinite(got)):
            reason = "newton_coefficients returns NaN or inf"
        elif abs(a * dt - 1) < 1e-9:
            reason = "newton_coefficients' mass coefficient is 1/dt: a missing dt (it is 1/dt^2)"
        elif abs(a - 1) < 1e-9:
            reason = ("newton_coefficients' mass coefficient is 1: a missing dt^2 (A = M/dt^2 + H is the Newton "
                      "matrix of Phi; M - dt^2 df/dx is the same matrix times dt^2)")
        elif abs(b - 1) > 1e-9:
            reason = f"newton_coefficients' Hessian coefficient is {b:.6g}; with a = 1/dt^2 it is 1"
        else:
            reason = f"newton_coefficients' mass coefficient is {a:.6g} at dt = {dt:.4g} s; it is 1/dt^2"
    exps.append(agreement("newton_coefficients(dt) = (1/dt^2, 1): A = M/dt^2 + H (N1), at dt = 1 ms ... 2 s "
                          "(max rel. dev. of (a dt^2, b) from (1, 1))", "ex-newton-coefficients", dev, tol, reason))
    return exps


def check_velocity(func) -> list:
    @ti.kernel
    def run(x: vec3_array, xn: vec3_array, dt: scalar_array, out: vec3_array):
        for i in range(x.shape[0]):
            out[i] = func(x[i], xn[i], dt[i])
    s = _vertices(seed=12)
    got = np.zeros_like(s["x"])
    call_student("step_velocity", run, s["x"], s["xn"], s["dt"], got)
    ref = (s["x"] - s["xn"]) / s["dt"][:, None]
    dev = deviation(got, ref)
    tol = 1e-13
    reason = ""
    if not dev <= tol:
        r = factor_text(ratio(got, ref))
        if not np.all(np.isfinite(got)):
            reason = "step_velocity returns NaN or inf"
        elif r == "minus":
            reason = "step_velocity has the wrong sign: v+ = (x+ - x_n)/dt"
        elif deviation(got, ref / s["dt"][:, None]) <= 1e-9:
            reason = "step_velocity divides by dt^2: v+ = (x+ - x_n)/dt"
        else:
            reason = f"step_velocity is not (x+ - x_n)/dt (deviation {dev:.2g})"
    return [agreement("step_velocity = (x+ - x_n)/dt, 32 random vertices", "ex-step-velocity", dev, tol, reason,
                      "m/s")]


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
