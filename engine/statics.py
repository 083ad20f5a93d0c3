"""Static equilibrium: minimise the total potential by damped Newton.

Equilibrium under gravity with pinned vertices held in place (lecture notes, "Potential
energy": the rest shape under load is the minimiser of the potential) solves

    min_x  Pi(x) = W(x) - sum_{free i} m_i g . x_i        with x_i = x0_i for pinned i        (P)

i.e. the net force f_i(x) + m_i g = 0 at every free vertex (f = -grad W).  Newton with the
PSD Hessian H (springs (S4), bending Gauss-Newton) and a Levenberg term:

    (H(x) + mu M) dx = f(x) + M g      (free rows; pinned dx = 0, engine.solvers (L2))        (N2)
    mu = nu lambda_ref min(1, r) + 1e-14 lambda_ref

lambda_ref is the Gershgorin bound on the largest eigenvalue of M^-1 H at x0, so nu is a
dimensionless weight; mu vanishes as the residual r -> 0 (Levenberg-Marquardt with
mu ~ |gradient| keeps Newton's fast final convergence) and keeps (N2) solvable where H is
singular: springs have no transverse stiffness at their rest length (a straight chain, a
flat sheet) and the PSD projection drops it in compression.  nu adapts like a trust region
from the gain ratio rho = actual / predicted decrease of Pi: /2 after a full step with
rho > 0.75, x4 after a shortened step or rho < 0.25, x100 (and retry) if no step length
decreases Pi.  Each step is backtracked (halving) until Armijo's condition
Pi(x + s dx) <= Pi(x) - 1e-4 s (f + M g).dx holds, so Pi decreases monotonically; at
round-off level (the full step's predicted decrease (f + M g).dx below the round-off of Pi,
64 eps (|W| + |Pi|), where Armijo's test compares noise, or no decrease measurable) the full
step is taken if it lowers r.  A linear solve that stops short of ``linear_tol`` (a direct
solve of an ill-conditioned system reaches about cond x eps: long chains) is still used as an
inexact Newton direction while its relative residual is at most 1e-3.

Once r < 1e-2 (``exact_below``) the exact Hessian is tried instead of the PSD one (``exact``):
near a stable equilibrium it is positive definite and Newton converges quadratically, while
the PSD projection converges only linearly wherever springs are compressed (a draped cloth:
measured on a 12x12 cloth, PSD alone stalls at r ~ 2e-7 after 200 steps; with the switch it
reaches 1e-11 in 65).  Where the exact Hessian fails (indefinite: failed factorisation,
p.Ap <= 0, no descent, or a shortened step) the PSD one is used, and the exact one retried
every 10 steps.  If r stops improving while Pi no longer decreases measurably for 5 steps,
the forces have reached their round-off floor (stiff springs: force errors ~ c/L^2 x 1e-16 m)
and the solve stops, reporting it.

Cost: a stiff sheet hanging from two corners starting flat is a hard, large-rotation
problem: 12x12 to 20x20 cloths with E = 1e3 .. 1e5 N/m took 65 .. 250 Newton steps from
the flat state (each one sparse factorisation); start from a better x0 (e.g. the end of
a damped dynamic run) or raise max_iter for such cases.

Residual (dimensionless):

    r = max_{free i} |f_i + m_i g|  /  max_{free i} |m_i g|       (with gravity)
    r = max_{free i} |f_i|          /  max_{all i} |f_i|           (no gravity: the largest
                                                                    elastic force, i.e. the load
                                                                    the pins put in)

Reactions: the force each pin must supply, R_i = -(f_i + m_i g) at pinned i (0 elsewhere),
including the weight of the pinned vertex itself, so that at equilibrium sum_i R_i = -M g
summed over all vertices = the total weight (net internal force is zero by translation
invariance).

Reference: a vertical chain of springs with lumped masses, c = E h (k = E,
1D spring of the notes), hanging from its top has the node displacements
u(p) = (rho g / E)(L p - p^2/2) exactly: segment j carries the weight below its lower node,
rho g (L - p_{j+1/2}), so its strain is rho g (L - p_{j+1/2})/E and summing h times the strains
gives (rho g/E)(L p_k - h^2 k^2/2).
"""

import math
from typing import NamedTuple

import numpy as np
import taichi as ti

from engine.errors import ParameterError
from engine.stability import gershgorin_lambda_max, lambda_max_power
from engine.solvers import SOLVERS, SolverError, make_solver
from engine.fields import (WorkArrays, axpy_into, copy_vec3, dot_vec3, float_dtype, mass_dot, scalar_array, vec3_array,
                           vec3_ndarray, zero_vec3)
from engine.model import Model

__all__ = ["StaticResult", "solve_static"]

ARMIJO_C1 = 1e-4
MAX_BACKTRACKS = 30
MAX_REJECTIONS = 12
NU_MIN, NU_MAX = 1e-10, 1e8
NU_START, NU_DOWN, NU_UP = 1e-3, 2.0, 4.0
MAX_STALLS = 5
INEXACT_RESIDUAL = 1e-3  # a linear solve that did not reach linear_tol is still used up to this residual


class StaticResult(NamedTuple):
    """Outcome of :func:`solve_static`.

    x          (n, 3) equilibrium positions [m] (numpy float64)
    iterations Newton steps taken
    residual   dimensionless net-force residual r (module docstring)
    converged  r <= tol
    reactions  (n, 3) forces the pins supply [N] (0 at free vertices)
    history    r before each Newton step and at the end
    message    why it stopped, if it did not converge
    """
    x: np.ndarray
    iterations: int
    residual: float
    converged: bool
    reactions: np.ndarray
    history: list = []
    message: str = ""


@ti.kernel
def _gravity_work(x: vec3_array, xref: vec3_array, mass: scalar_array, inv_mass: scalar_array,
                  g: ti.math.vec3) -> float:
    # sum_{free i} m_i g . (x_i - xref_i)   (gravity potential relative to xref, sign flipped)
    s = 0.0
    for i in range(x.shape[0]):
        if inv_mass[i] > 0.0:
            s += mass[i] * g.dot(x[i] - xref[i])
    return s


def _lambda_ref(model: Model, x) -> float:
    try:
        lam = gershgorin_lambda_max(model, x)
    except NotImplementedError:
        lam = abs(lambda_max_power(model, x, psd=True))
    return lam if lam > 0.0 else 1.0


def solve_static(model: Model, x0=None, tol: float = 1e-10, max_iter: int = 100, solver: str = "cholesky", *,
                 linear_tol: float = 1e-10, max_linear_iter: int = 10000,
                 raise_on_failure: bool = True, exact: bool = True, exact_below: float = 1e-2,
                 verbose: bool = False) -> StaticResult:
    """Equilibrium of ``model`` under gravity with its pins held at ``x0`` (default: rest X).

    Newton on (P) with (N2) and Armijo backtracking (module docstring).  ``tol``: residual r
    to reach; ``max_iter``: Newton steps; ``solver``: "cholesky" (default) or "pcg" with
    relative tolerance ``linear_tol`` (and ``max_linear_iter`` CG iterations).  ``exact``:
    switch to the exact Hessian once r < ``exact_below``; ``verbose``: print each step.
    Pinned vertices stay at their x0 positions (so x0 can pull a sheet).
    Non-convergence raises :class:`engine.solvers.SolverError` (one line: residual, tolerance,
    iterations, reason), or with ``raise_on_failure=False`` returns ``converged=False``.
    """
    if solver not in SOLVERS:
        raise ParameterError(f"--solver must be one of {', '.join(SOLVERS)} (got {solver!r})")
    tol = float(tol)
    if not (math.isfinite(tol) and tol > 0.0):
        raise ParameterError(f"static tolerance must be finite and > 0 (got {tol!r})")
    max_iter = int(max_iter)
    if max_iter < 0:
        raise ParameterError(f"max_iter must be >= 0 (got {max_iter})")
    n = model.n
    x_start = model.X if x0 is None else np.asarray(x0, dtype=np.float64)
    if x_start.shape != (n, 3) or not np.isfinite(x_start).all():
        raise ParameterError(f"x0 must be finite with shape ({n}, 3), got {x_start.shape}")

    lin = make_solver(solver, tol=linear_tol, max_iter=max_linear_iter)
    x = vec3_ndarray(n, x_start)
    xref = vec3_ndarray(n, x_start)
    work = WorkArrays(n)  # this solve's own work arrays
    f, dx, trial = work.vec3("f"), work.vec3("dx"), work.vec3("trial")
    mass = model.mass[:, None]
    g = model.gravity[None, :]
    free = model.free
    has_gravity = bool(model.gravity.any()) and bool(free.any())
    weight_scale = float(np.linalg.norm(mass[free] * g, axis=1).max()) if has_gravity else 0.0

    def net_and_residual(xa):
        """f = -grad Pi on free vertices (in ``f``); returns (r, f_elastic numpy)."""
        zero_vec3(f)
        model.add_elastic_forces(xa, f)
        fe = f.to_numpy().astype(np.float64)
        net = fe + mass * g
        net[~free] = 0.0
        f.from_numpy(net.astype(float_dtype()))
        worst = float(np.linalg.norm(net, axis=1).max()) if free.any() else 0.0
        scale = weight_scale if has_gravity else float(np.linalg.norm(fe, axis=1).max())
        r = 0.0 if worst == 0.0 else (worst / scale if scale > 0.0 else math.inf)
        return r, fe

    def mass_norm2(a) -> float:
        return mass_dot(a, a, model.mass_nd, model.inv_mass_nd)

    def potential(xa) -> float:
        Pi = model.elastic_energy(xa)
        if has_gravity:
            Pi -= _gravity_work(xa, xref, model.mass_nd, model.inv_mass_nd, model.gravity_vec)
        return Pi

    def roundoff(xa, Pi_a) -> float:
        """What a change of Pi below which is not measurable: 64 eps (|W| + |Pi|)."""
        return 64.0 * np.finfo(np.float64).eps * (abs(model.elastic_energy(xa)) + abs(Pi_a) + 1e-300)

    lam_ref = _lambda_ref(model, x)
    nu = NU_START
    stalls = 0
    Pi = potential(x)
    r, fe = net_and_residual(x)
    history = [r]
    iterations = 0
    rejections = 0
    message = ""
    exact_ok = True  # try the exact Hessian once close (quadratic convergence where the PSD one is slow)
    while r > tol:
        if iterations >= max_iter:
            message = f"max_iter={max_iter} Newton steps reached"
            break
        mu = nu * lam_ref * min(1.0, r) + 1e-14 * lam_ref
        use_exact = exact and exact_ok and r < exact_below
        info = lin.solve(model, x, f, dx, mu, 1.0, psd=not use_exact)  # (H + mu M) dx = f + M g
        # inexact Newton: a solve short of linear_tol (a direct solve of an ill-conditioned system stops
        # at ~ cond x eps) still gives a descent direction that cuts r by about its residual
        usable = info.converged or (math.isfinite(info.residual) and info.residual <= INEXACT_RESIDUAL)
        slope = dot_vec3(f, dx) if usable else 0.0  # -(grad Pi . dx) > 0 for a descent direction
        if use_exact and not (usable and slope > 0.0):
            exact_ok = False  # indefinite here: back to the PSD Hessian
            continue
        if not usable:
            message = info.describe()
            break
        s = 1.0
        accepted = False
        if slope <= roundoff(x, Pi):
            # the full step's predicted decrease of Pi is below Pi's round-off: Armijo's test would
            # compare noise (and accept a random fraction of the step); the residual decides instead
            axpy_into(x, dx, 1.0, trial)
            r_t, _ = net_and_residual(trial)
            if r_t < r:
                accepted, Pi_t = True, potential(trial)
            else:
                net_and_residual(x)  # restore f at x
        for _ in range(0 if accepted else MAX_BACKTRACKS + 1):
            axpy_into(x, dx, s, trial)
            Pi_t = potential(trial)
            if Pi_t <= Pi - ARMIJO_C1 * s * slope:
                accepted = True
                break
            s *= 0.5
        if not accepted:
            # no measurable decrease: round-off level near the minimum, or a poor direction
            axpy_into(x, dx, 1.0, trial)
            r_t, _ = net_and_residual(trial)
            if r_t < r:
                accepted, s, Pi_t = True, 1.0, potential(trial)
            else:
                net_and_residual(x)  # restore f at x
                if use_exact:
                    exact_ok = False
                    continue
                rejections += 1
                nu = min(nu * 100.0, NU_MAX)
                if rejections > MAX_REJECTIONS:
                    message = "line search found no decrease of the potential (round-off or a singular direction)"
                    break
                continue
        if use_exact and s < 1.0:
            exact_ok = False
        copy_vec3(trial, x)
        iterations += 1
        rejections = 0
        # trust-region-like update of nu from the gain ratio of the accepted step
        curv = slope - mu * mass_norm2(dx)  # dx.H dx, from (H + mu M) dx = f + M g
        predicted = s * slope - 0.5 * s * s * curv
        rho = (Pi - Pi_t) / predicted if predicted > 0.0 else 0.0
        if s == 1.0 and rho > 0.75:
            nu = max(nu / NU_DOWN, NU_MIN)
        elif s < 1.0 or rho < 0.25:
            nu = min(nu * NU_UP, NU_MAX)
        decrease = Pi - Pi_t
        Pi = Pi_t
        r_prev = r
        r, fe = net_and_residual(x)
        history.append(r)
        # round-off floor: Pi no longer measurably decreases and r stops improving
        noise = roundoff(x, Pi)
        stalls = stalls + 1 if (decrease <= noise and r > 0.5 * r_prev) else 0
        if stalls >= MAX_STALLS and r > tol:
            message = (f"stalled at the round-off floor of the forces for {MAX_STALLS} steps "
                       f"(stiff springs: forces ~ stiffness x 1e-16 m); ask for tol >= {4 * r:.1e}")
            break
        if verbose:
            print(f"  newton {iterations}: r={r:.3e} step={s:g} rho={rho:.2f} "
                  f"mu/lam={mu / lam_ref:.2e} exact={use_exact}")
        if not exact_ok and iterations % 10 == 0:
            exact_ok = True  # retry the exact Hessian now and then

    xs = x.to_numpy().astype(np.float64)
    xs[model.pinned] = x_start[model.pinned]
    reactions = np.zeros((n, 3))
    reactions[model.pinned] = -(fe + mass * g)[model.pinned]
    converged = bool(r <= tol)
    if not converged and not message:
        message = "not converged"
    result = StaticResult(xs, iterations, float(r), converged, reactions, history, "" if converged else message)
    if not converged and raise_on_failure:
        raise SolverError(f"solve_static ({solver}) did not converge: residual {r:.3e} > tol {tol:.1e} after "
                          f"{iterations} Newton iterations; {message}")
    return result
