"""Static equilibrium: minimise the total potential by damped Newton.

Equilibrium under gravity with pinned vertices held in place (lecture notes, "Potential
energy": the rest shape under load is the minimiser of the potential) solves

    min_x  Pi(x) = W(x) - sum_{free i} m_i g . x_i        with x_i = x0_i for pinned i        (P)

i.e. the net force f_i(x) + m_i g = 0 at every free vertex (f = -grad W).  Newton (the engine's one
minimiser, engine.newton.minimize, in its Levenberg mode; the backward-Euler step uses the same
loop) with the PSD Hessian H (springs (S4), bending Gauss-Newton) and a Levenberg term:

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
from engine import newton
from engine.fields import WorkArrays, float_dtype, mass_dot, scalar_array, vec3_array, vec3_ndarray, zero_vec3
from engine.model import Model

__all__ = ["StaticResult", "solve_static"]

INEXACT_RESIDUAL = 1e-3  # a linear solve that did not reach linear_tol is still used up to this residual
EXACT_RETRY = 10         # after the exact Hessian failed, retry it every EXACT_RETRY Newton steps


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


class _StaticProblem(newton.Problem):
    """(P) for engine.newton: Pi, r and f + M g (in ``rhs``) at x, the direction of (N2)."""

    def __init__(self, model: Model, x_start: np.ndarray, solver, tol: float, exact_below: float):
        n = model.n
        self.model, self.solver, self.tol, self.exact_below = model, solver, tol, exact_below
        self.xref = vec3_ndarray(n, x_start)
        self.rhs = vec3_ndarray(n)
        self.mass = model.mass[:, None]
        self.g = model.gravity[None, :]
        self.free = model.free
        self.has_gravity = bool(model.gravity.any()) and bool(self.free.any())
        self.weight_scale = (float(np.linalg.norm(self.mass[self.free] * self.g, axis=1).max())
                             if self.has_gravity else 0.0)
        self.elastic_forces = None

    def residual(self, x, k: int) -> float:
        """rhs = f + M g = -grad Pi on free vertices; returns r (module docstring)."""
        model, f = self.model, self.rhs
        zero_vec3(f)
        model.add_elastic_forces(x, f)
        fe = f.to_numpy().astype(np.float64)
        net = fe + self.mass * self.g
        net[~self.free] = 0.0
        f.from_numpy(net.astype(float_dtype()))
        worst = float(np.linalg.norm(net, axis=1).max()) if self.free.any() else 0.0
        scale = self.weight_scale if self.has_gravity else float(np.linalg.norm(fe, axis=1).max())
        self.elastic_forces = fe
        return 0.0 if worst == 0.0 else (worst / scale if scale > 0.0 else math.inf)

    def objective(self, x) -> float:
        model = self.model
        Pi = model.elastic_energy(x)
        if self.has_gravity:
            Pi -= _gravity_work(x, self.xref, model.mass_nd, model.inv_mass_nd, model.gravity_vec)
        return Pi

    def converged(self, r: float) -> bool:
        return r <= self.tol

    def near(self, r: float) -> bool:
        return r < self.exact_below

    def direction(self, x, dx, k: int, psd: bool, mu: float):
        return self.solver.solve(self.model, x, self.rhs, dx, mu, 1.0, psd=psd)   # (H + mu M) dx = f + M g

    def roundoff(self, x, phi: float) -> float:
        """What a change of Pi below which is not measurable: 64 eps (|W| + |Pi|)."""
        return 64.0 * np.finfo(np.float64).eps * (abs(self.model.elastic_energy(x)) + abs(phi) + 1e-300)

    def mass_norm2(self, dx) -> float:
        return mass_dot(dx, dx, self.model.mass_nd, self.model.inv_mass_nd)


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

    problem = _StaticProblem(model, x_start, make_solver(solver, tol=linear_tol, max_iter=max_linear_iter),
                             tol, exact_below)
    x = vec3_ndarray(n, x_start)
    work = WorkArrays(n)  # this solve's own work arrays
    opts = newton.Options(max_iter=max_iter, exact=exact, exact_retry=EXACT_RETRY, levenberg=True,
                          lambda_ref=_lambda_ref(model, x), inexact_residual=INEXACT_RESIDUAL)
    res = newton.minimize(problem, x, work.vec3("trial"), work.vec3("dx"), opts, verbose=verbose)
    r, iterations, history = res.residual, res.iterations, res.history
    message = {"max_iter": f"max_iter={max_iter} Newton steps reached",
               "linear": res.linear[-1].describe() if res.linear else "",
               "no_decrease": "line search found no decrease of the potential (round-off or a singular direction)",
               "stalled": (f"stalled at the round-off floor of the forces for {newton.MAX_STALLS} steps "
                           f"(stiff springs: forces ~ stiffness x 1e-16 m); ask for tol >= {4 * r:.1e}")}.get(
        res.status, "")
    fe = problem.elastic_forces
    mass, g = model.mass[:, None], model.gravity[None, :]

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
