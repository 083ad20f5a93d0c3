"""One Newton minimiser for the engine's two minimisations: the static equilibrium (the potential
Pi, :mod:`engine.statics`) and the backward-Euler step (the incremental potential Phi,
:mod:`engine.integrators.implicit`).

A :class:`Problem` says what is minimised; :func:`minimize` is the loop both use:

    r = residual(x)                              (fills rhs = -grad, free rows; r: the stopping measure)
    until converged(r) or max_iter steps:
        A dx = rhs                               (direction: the problem's Newton matrix + mu M, from its
                                                  solver; the exact Hessian near the solution, else the PSD one)
        slope = rhs . dx  (> 0: a descent direction)
        s = 1, 1/2, 1/4, ...  until  phi(x + s dx) <= phi(x) - c1 s slope   (Armijo, c1 = 1e-4)   (LS)
        x <- x + s dx,  r = residual(x)

The exact Hessian is tried once the problem says x is near the solution (``near``); where it is
refused (the solve fails or the direction is not one of descent) or needs a shortened step, the PSD
Hessian is used again and the exact one retried every ``exact_retry`` accepted steps.

What differs between the two is an :class:`Options` field, not a second loop:
  - ``levenberg`` (the static solve): mu = nu lambda_ref min(1, r) + 1e-14 lambda_ref with nu adapted
    from the gain ratio like a trust region, a step the line search rejects retried with nu x 100,
    a linear solve short of its tolerance still used up to a relative residual ``inexact_residual``,
    and the round-off rules of engine.statics (a full step whose predicted decrease is below the
    objective's round-off is judged by the residual; a stall at the force's round-off floor stops);
  - ``strict_decrease`` (the backward-Euler step): phi(x + s dx) < phi(x) besides (LS), and no
    measurable decrease at any s stops the iteration there (``line_search_failed``);
  - ``line_search`` False takes the full step; ``final_residual`` False stops after the last step
    without evaluating the residual again (Baraff and Witkin's single linearised step).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from engine.fields import axpy_inplace, axpy_into, copy_vec3, dot_vec3

ARMIJO_C1 = 1e-4
MAX_BACKTRACKS = 30
MAX_REJECTIONS = 12
NU_MIN, NU_MAX = 1e-10, 1e8
NU_START, NU_DOWN, NU_UP = 1e-3, 2.0, 4.0
MAX_STALLS = 5


class Problem:
    """What :func:`minimize` minimises. Subclasses hold the work arrays ``rhs`` (-grad at the point of
    the last :meth:`residual`) and implement the methods below."""

    rhs = None

    def objective(self, x) -> float:
        """The function minimised at x."""
        raise NotImplementedError

    def residual(self, x, k: int) -> float:
        """Fill ``rhs`` with -grad at x (free rows; 0 on pinned ones) and return the stopping measure
        (k: accepted steps so far)."""
        raise NotImplementedError

    def converged(self, r: float) -> bool:
        raise NotImplementedError

    def near(self, r: float) -> bool:
        """Whether x is close enough to the solution to try the exact Hessian."""
        raise NotImplementedError

    def direction(self, x, dx, k: int, psd: bool, mu: float):
        """Solve the Newton system (+ mu M) dx = rhs; returns the solver's LinearInfo."""
        raise NotImplementedError

    def roundoff(self, x, phi: float) -> float:
        """A change of the objective below which it is not measurable (Levenberg mode only)."""
        return 0.0

    def mass_norm2(self, dx) -> float:
        """|dx|_M^2 (Levenberg mode only: the gain ratio's model decrease)."""
        return 0.0


@dataclass
class Options:
    max_iter: int
    exact: bool = True
    exact_retry: int = 10
    line_search: bool = True
    strict_decrease: bool = False
    final_residual: bool = True
    levenberg: bool = False
    lambda_ref: float = 1.0
    inexact_residual: float = 0.0


@dataclass
class Result:
    """``status``: "converged", "max_iter", "linear" (the last solve in ``linear`` failed),
    "no_decrease" (the line search found none: Levenberg mode gives up after MAX_REJECTIONS),
    "stalled" (round-off floor), "line_search_failed" (strict mode: no measurable decrease left)
    or "" (stopped after max_iter steps without a final residual)."""
    iterations: int = 0
    residual: float = math.inf
    status: str = ""
    history: list = field(default_factory=list)     # r before each step and after the last
    objectives: list = field(default_factory=list)  # phi at the start and after each accepted step
    step_sizes: list = field(default_factory=list)
    linear: list = field(default_factory=list)      # LinearInfo of each solve whose direction was used
    solves: int = 0                                 # every solve, refused exact ones included ...
    linear_iterations: int = 0                      # ... and their iterations


def minimize(problem: Problem, x, trial, dx, opts: Options, verbose: bool = False) -> Result:
    """Minimise ``problem`` from x (modified in place; ``trial`` and ``dx`` are work arrays of x's shape)."""
    res = Result()
    phi = problem.objective(x) if opts.line_search else 0.0
    if opts.line_search:
        res.objectives.append(phi)
    r = problem.residual(x, 0)
    res.history.append(r)
    k = 0
    exact_ok = True
    nu, rejections, stalls = NU_START, 0, 0
    lam = opts.lambda_ref
    while True:
        if problem.converged(r):
            res.status = "converged"
            break
        if k >= opts.max_iter:
            res.status = "max_iter"
            break
        mu = nu * lam * min(1.0, r) + 1e-14 * lam if opts.levenberg else 0.0
        use_exact = opts.exact and exact_ok and problem.near(r)
        lin = problem.direction(x, dx, k, not use_exact, mu)
        res.solves += 1
        res.linear_iterations += lin.iterations
        # inexact Newton (Levenberg mode): a solve short of its tolerance (a direct solve of an ill-conditioned
        # system stops at ~ cond x eps) still gives a descent direction that cuts r by about its residual
        usable = lin.converged or (opts.inexact_residual > 0.0 and math.isfinite(lin.residual)
                                   and lin.residual <= opts.inexact_residual)
        # -grad . dx > 0 for a descent direction; read only to judge an exact-Hessian step, by the line search
        # and by Levenberg's gain ratio (a full step without them skips the reduction)
        slope = dot_vec3(problem.rhs, dx) if usable and (use_exact or opts.line_search or opts.levenberg) else 0.0
        if use_exact and not (usable and slope > 0.0):
            exact_ok = False   # indefinite here: back to the PSD Hessian
            continue
        res.linear.append(lin)
        if not usable:
            res.status = "linear"
            break
        s, accepted, phi_t, in_place = 1.0, False, phi, False
        if not opts.line_search:
            axpy_inplace(x, dx, 1.0)   # the full step, taken in x itself (no trial point to judge)
            accepted = in_place = True
        elif opts.levenberg and slope <= problem.roundoff(x, phi):
            # the full step's predicted decrease is below the objective's round-off: Armijo's test would
            # compare noise (and accept a random fraction of the step); the residual decides instead
            axpy_into(x, dx, 1.0, trial)
            if problem.residual(trial, k) < r:
                accepted, phi_t = True, problem.objective(trial)
            else:
                problem.residual(x, k)   # restore rhs at x
        if not accepted:
            for _ in range(MAX_BACKTRACKS + 1):
                axpy_into(x, dx, s, trial)
                phi_t = problem.objective(trial)
                if (phi_t < phi or not opts.strict_decrease) and phi_t <= phi - ARMIJO_C1 * s * slope:
                    accepted = True
                    break
                s *= 0.5
        if not accepted and opts.strict_decrease:
            res.status = "line_search_failed"   # no measurable decrease left (round-off level): stop here
            break
        if not accepted:
            # no measurable decrease: round-off level near the minimum, or a poor direction
            axpy_into(x, dx, 1.0, trial)
            if problem.residual(trial, k) < r:
                accepted, s, phi_t = True, 1.0, problem.objective(trial)
            else:
                problem.residual(x, k)   # restore rhs at x
                res.linear.pop()
                if use_exact:
                    exact_ok = False
                    continue
                rejections += 1
                nu = min(nu * 100.0, NU_MAX)
                if rejections > MAX_REJECTIONS:
                    res.status = "no_decrease"
                    break
                continue
        if use_exact and s < 1.0:
            exact_ok = False
        if not in_place:
            copy_vec3(trial, x)
        k += 1
        rejections = 0
        res.step_sizes.append(s)
        if opts.line_search:
            res.objectives.append(phi_t)
        if opts.levenberg:   # trust-region-like update of nu from the gain ratio of the accepted step
            curv = slope - mu * problem.mass_norm2(dx)   # dx.H dx, from (H + mu M) dx = rhs
            predicted = s * slope - 0.5 * s * s * curv
            rho = (phi - phi_t) / predicted if predicted > 0.0 else 0.0
            if s == 1.0 and rho > 0.75:
                nu = max(nu / NU_DOWN, NU_MIN)
            elif s < 1.0 or rho < 0.25:
                nu = min(nu * NU_UP, NU_MAX)
        decrease = phi - phi_t
        phi = phi_t
        if not opts.final_residual and k >= opts.max_iter:
            break   # one linearised step: no final gradient
        r_prev = r
        r = problem.residual(x, k)
        res.history.append(r)
        if opts.levenberg:   # round-off floor: the objective no longer measurably decreases and r stops improving
            noise = problem.roundoff(x, phi)
            stalls = stalls + 1 if (decrease <= noise and r > 0.5 * r_prev) else 0
            if stalls >= MAX_STALLS and not problem.converged(r):
                res.status = "stalled"
                break
        if verbose:
            print(f"  newton {k}: r={r:.3e} step={s:g} mu/lam={mu / lam:.2e} exact={use_exact}")
        if not exact_ok and k % opts.exact_retry == 0:
            exact_ok = True   # retry the exact Hessian now and then
    res.iterations = k
    res.residual = r
    return res


__all__ = ["ARMIJO_C1", "MAX_BACKTRACKS", "Options", "Problem", "Result", "minimize"]
