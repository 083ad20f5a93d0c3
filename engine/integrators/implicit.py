"""Backward Euler as Newton's method on the incremental potential (Baraff & Witkin 1998).

Backward Euler for M dv/dt = f(x) + M g (f = -grad W, lumped M, pinned vertices fixed):

    x+ = x_n + dt v+,      M (v+ - v_n) = dt (f(x+) + M g - D v+)                        (BE)

with optional Rayleigh damping D = alpha M + beta H_n (H_n the PSD Hessian at x_n, frozen for
the step).  (BE) is the stationarity condition of the *incremental potential*

    Phi(x) = 1/(2 dt^2) |x - x_n - dt v_n|_M^2 + W(x) - W(x_n) - sum_i m_i g.(x_i - x_n,i)
             + 1/(2 dt) (x - x_n)^T D (x - x_n)                                           (IP)

(grad Phi = 0  <=>  (BE) with v+ = (x - x_n)/dt), so a step minimises Phi.  At x = x_n,
Phi = the kinetic energy 1/2 |v_n|_M^2.

Newton on (IP) from x = x_n (engine.newton.minimize, the loop the static solve uses too), with the PSD
Hessian H (springs (S4), bending Gauss-Newton):

    A dx = -grad Phi(x),    A = (1/dt^2 + alpha/dt) M + H(x) + (beta/dt) H_n            (N1)

(at the first iteration x = x_n, so A = (1/dt^2 + alpha/dt) M + (1 + beta/dt) H(x_n)).  One
iteration from x_n is exactly Baraff & Witkin's linearised step, their eq. (16)

    (M - dt^2 df/dx) dv = dt (f_n + dt df/dx v_n),   dx = dt (v_n + dv)

(substitute dv = dx/dt - v_n into (N1) with df/dx = -H).  More iterations converge to the true
backward Euler step.  The PSD projection makes later iterations converge only linearly where
springs are compressed or hinges bent, so once |grad Phi| < 1e-2 |grad Phi(x_n)| the exact
Hessian is tried (``exact_near_solution``); where it is indefinite (failed factorisation,
p.Ap <= 0 in CG, or not a descent direction) or needs a shortened step, the PSD one is used
again (the exact one is retried every 5 iterations).  With ``line_search`` each Newton step
is backtracked (halving) until  Phi(x + s dx) < Phi(x)  and Armijo's condition
Phi(x + s dx) <= Phi(x) + 1e-4 s grad Phi . dx  hold, so Phi decreases strictly
monotonically; the values are kept in the step's StepInfo.objectives.  If no step length down to 2^-30
decreases Phi measurably (round-off level, next to the minimum) the iteration stops there
(StepInfo.line_search_failed).

Newton stops when |grad Phi(x)| <= newton_tol max(|grad Phi(x_n)|, |M g|) (the weight keeps a
settled hanging body from chasing round-off).  Linear solves go through
:mod:`engine.solvers` ("pcg", "cholesky", "pardiso" or "direct", relative tolerance ``tol``); a linear solve that
does not reach ``tol`` raises :class:`engine.solvers.SolverError` and leaves the state as
it was before the step.  Finally v+ = (x+ - x_n)/dt; pinned vertices keep x and get v = 0.

Energy behaviour: for a linear problem every mode's energy is multiplied
by exactly 1/(1 + w^2 dt^2) per step (the amplification matrix in the variables (w x, v) is
a rotation divided by sqrt(1 + w^2 dt^2)); the method is first-order accurate and stable at
any dt.
"""

import math
from dataclasses import dataclass, field

import taichi as ti

from engine import newton
from engine.errors import ParameterError
from engine.launch import kernel as fast_kernel
from engine.solvers import SOLVERS, LinearSolver, SolverError, make_solver
from engine.fields import copy_vec3, dot_vec3, scalar_array, serial_pass, sub_into, vec3_array, zero_vec3
from engine.model import State

EXACT_RETRY = 5     # after a failure, retry the exact Hessian every EXACT_RETRY Newton iterations
EXACT_BELOW = 1e-2  # try the exact Hessian once |grad Phi| < EXACT_BELOW |grad Phi(x_n)|


# --------------------------------------------------------------------------------------------
# Kernels (one pass over the vertices each; pinned vertices: inv_mass == 0)
# --------------------------------------------------------------------------------------------

def newton_coefficients(dt: float, alpha: float = 0.0, beta: float = 0.0) -> tuple[float, float]:
    """(a, b) of the Newton matrix A = a M + b H of (N1) at x = x_n: a = 1/dt^2 + alpha/dt,
    b = 1 + beta/dt (1/s^2, 1)."""
    return 1.0 / (dt * dt) + alpha / dt, 1.0 + beta / dt


@ti.func
def newton_residual(f_i, m_i, x_i, xn_i, v_i, inv_dt2, alpha_over_dt, dt):
    """-grad Phi at one free vertex (N): f_i - m_i (x_i - x_n,i - dt v_n,i)/dt^2 - alpha m_i (x_i - x_n,i)/dt,
    given 1/dt^2 and alpha/dt; f_i includes the weight m_i g."""
    d = x_i - xn_i
    return f_i - m_i * (inv_dt2 * (d - dt * v_i) + alpha_over_dt * d)


@ti.func
def step_velocity(x_i, xn_i, inv_dt):
    """v+ = (x+ - x_n)/dt at one free vertex, given 1/dt (m/s)."""
    return inv_dt * (x_i - xn_i)


@fast_kernel
def _be_residual(x: vec3_array, xn: vec3_array, v: vec3_array, f: vec3_array, mass: scalar_array,
                 inv_mass: scalar_array, inv_dt2: float, alpha_over_dt: float, dt: float,
                 rhs: vec3_array, serial: ti.template()) -> float:
    # rhs = -grad Phi = f(x) + M g - M (x - x_n - dt v_n)/dt^2 - alpha M (x - x_n)/dt  (free; f has M g)
    # returns |rhs|^2 (serialized: summed in vertex order)
    s = 0.0
    ti.loop_config(serialize=serial)
    for i in range(x.shape[0]):
        r = ti.math.vec3(0.0)
        if inv_mass[i] > 0.0:
            r = newton_residual(f[i], mass[i], x[i], xn[i], v[i], inv_dt2, alpha_over_dt, dt)
        rhs[i] = r
        s += r.dot(r)
    return s


@ti.kernel
def _be_add_scaled(rhs: vec3_array, hq: vec3_array, coef: float, inv_mass: scalar_array) -> float:
    # rhs -= coef hq (free); returns |rhs|^2   (the beta H_n (x - x_n)/dt damping force)
    s = 0.0
    for i in range(rhs.shape[0]):
        if inv_mass[i] > 0.0:
            rhs[i] -= coef * hq[i]
            s += rhs[i].dot(rhs[i])
    return s


@fast_kernel
def _be_inertia(x: vec3_array, xn: vec3_array, v: vec3_array, mass: scalar_array, inv_mass: scalar_array,
                gx: float, gy: float, gz: float, inv_dt2: float, alpha_over_dt: float, dt: float) -> float:
    # sum_free m_i [ |x - x_n - dt v_n|^2/(2 dt^2) + alpha/(2 dt) |x - x_n|^2 - g.(x - x_n) ]   (IP)
    # (g as three scalars: a vector argument is never launched directly, engine.launch)
    g = ti.math.vec3(gx, gy, gz)
    s = 0.0
    for i in range(x.shape[0]):
        if inv_mass[i] > 0.0:
            d = x[i] - xn[i]
            e = d - dt * v[i]
            s += mass[i] * (0.5 * inv_dt2 * e.dot(e) + 0.5 * alpha_over_dt * d.dot(d) - g.dot(d))
    return s


@fast_kernel
def _be_finish(x: vec3_array, xn: vec3_array, v: vec3_array, inv_mass: scalar_array, inv_dt: float,
               serial: ti.template()):
    # v+ = (x+ - x_n)/dt ; pinned: x = x_n, v = 0
    ti.loop_config(serialize=serial)
    for i in range(x.shape[0]):
        if inv_mass[i] > 0.0:
            v[i] = step_velocity(x[i], xn[i], inv_dt)
        else:
            x[i] = xn[i]
            v[i] = ti.math.vec3(0.0)


# --------------------------------------------------------------------------------------------
# Integrator
# --------------------------------------------------------------------------------------------

@dataclass
class StepInfo:
    """What the last step did.  Lists have one entry per Newton iteration (linear solve), except
    ``gradient_norms`` (|grad Phi| before each solve, plus after the last one when
    newton_iterations > 1) and ``objectives`` (Phi at x_n, then after each accepted step)."""
    newton_iterations: int = 0
    linear_iterations: list = field(default_factory=list)
    linear_residuals: list = field(default_factory=list)
    gradient_norms: list = field(default_factory=list)
    objectives: list = field(default_factory=list)
    step_sizes: list = field(default_factory=list)
    newton_converged: bool = False
    line_search_failed: bool = False
    solves: int = 0                  # every linear solve of the step, refused exact-Hessian ones included,
    all_linear_iterations: int = 0   # and their iterations


class BackwardEuler:
    """Backward Euler by Newton on the incremental potential (module docstring).

    Parameters
      solver            "pcg" | "cholesky" | "pardiso" | "direct" (or a LinearSolver instance;
                        engine.solvers: "direct" is pardiso when MKL is installed, else cholesky)
      tol               relative residual of each linear solve (engine.solvers (L3))
      newton_iterations Newton iterations per step (1 = Baraff & Witkin's linearised step)
      newton_tol        stop when |grad Phi| <= newton_tol max(|grad Phi(x_n)|, |M g|)
      line_search       backtracking Armijo line search on Phi (monotone decrease)
      rayleigh_alpha    mass-proportional damping alpha [1/s]   (D = alpha M + beta H)
      rayleigh_beta     stiffness-proportional damping beta [s]
      max_iter          CG iteration limit of each linear solve (pcg)
      exact_near_solution  with newton_iterations > 1, try the exact Hessian near the solution

    ``advance(ctx, state, dt) -> StepInfo`` is one step; a :class:`engine.integrators.stepper.Stepper`
    drives it, handing it its StepContext (the model, its work arrays and its own linear solver, of
    this integrator's kind and options) and keeping the StepInfo (``stepper.last_info``) and the
    totals (``stepper.stats``). The integrator keeps nothing between steps.
    """

    name = "backward-euler"
    implicit = True

    def __init__(self, solver="pcg", tol: float = 1e-8, newton_iterations: int = 1, newton_tol: float = 1e-8,
                 line_search: bool = True, rayleigh_alpha: float = 0.0, rayleigh_beta: float = 0.0,
                 max_iter: int = 1000, exact_near_solution: bool = True):
        if not isinstance(solver, LinearSolver) and solver not in SOLVERS:
            raise ParameterError(f"--solver must be one of {', '.join(SOLVERS)} (got {solver!r})")
        tol = float(tol)
        if not (math.isfinite(tol) and 0.0 < tol < 1.0):
            raise ParameterError(f"--tol must be in (0, 1) (got {tol!r})")
        newton_iterations = int(newton_iterations)
        if newton_iterations < 1:
            raise ParameterError(f"newton_iterations must be >= 1 (got {newton_iterations})")
        newton_tol = float(newton_tol)
        if not (math.isfinite(newton_tol) and newton_tol >= 0.0):
            raise ParameterError(f"newton_tol must be finite and >= 0 (got {newton_tol!r})")
        for nm, val in (("rayleigh_alpha", rayleigh_alpha), ("rayleigh_beta", rayleigh_beta)):
            if not (math.isfinite(float(val)) and float(val) >= 0.0):
                raise ParameterError(f"{nm} must be finite and >= 0 (got {val!r})")
        try:
            self.solver = make_solver(solver, tol=tol, max_iter=max_iter)
        except ValueError as exc:  # e.g. 'pardiso' without MKL installed: one line, names the option
            raise ParameterError(f"--solver {solver}: {exc}") from None
        self.tol = self.solver.tol
        self.newton_iterations = newton_iterations
        self.newton_tol = newton_tol
        self.line_search = bool(line_search)
        self.rayleigh_alpha = float(rayleigh_alpha)
        self.rayleigh_beta = float(rayleigh_beta)
        self.exact_near_solution = bool(exact_near_solution)

    def begin(self, ctx, state: State) -> None:
        """Nothing to prepare (kept for the integrator protocol)."""

    # -- one step ------------------------------------------------------------------------------
    def advance(self, ctx, state: State, dt: float) -> StepInfo:
        """One step of ``ctx.model`` with ``ctx.work``'s arrays and ``ctx.solver``; returns what it did.
        Newton on (IP) is engine.newton's minimiser (the same loop as the static solve)."""
        dt = float(dt)
        if not (math.isfinite(dt) and dt > 0.0):
            raise ParameterError(f"dt must be finite and > 0 (got {dt!r})")
        model = ctx.model
        if model.dampers and self.rayleigh_beta > 0.0:
            raise ParameterError("rayleigh_beta and a membrane's Baraff-Witkin damping cannot be combined in one "
                                 "backward-Euler step; use one of them")
        work = {k: ctx.work.vec3("be_" + k) for k in ("xn", "f", "rhs", "dx", "trial", "d", "hq")}
        x = state.x
        copy_vec3(x, work["xn"])
        problem = _StepProblem(self, ctx, state, dt, work)
        n = self.newton_iterations
        opts = newton.Options(max_iter=n, exact=self.exact_near_solution and n > 1, exact_retry=EXACT_RETRY,
                              line_search=self.line_search, strict_decrease=True, final_residual=n > 1)
        res = newton.minimize(problem, x, work["trial"], work["dx"], opts)
        info = StepInfo(newton_iterations=len(res.linear), linear_iterations=[lin.iterations for lin in res.linear],
                        linear_residuals=[lin.residual for lin in res.linear], gradient_norms=problem.gradient_norms,
                        objectives=res.objectives, step_sizes=res.step_sizes,
                        newton_converged=res.status == "converged",
                        line_search_failed=res.status == "line_search_failed", solves=res.solves,
                        all_linear_iterations=res.linear_iterations)
        if res.status == "linear":
            copy_vec3(work["xn"], x)  # leave the state as it was
            raise SolverError(f"backward-euler step at t={state.t:.6g} s, Newton iteration {len(res.linear)}: "
                              f"{res.linear[-1].describe()}; raise max_iter or tol, or use solver='cholesky'")
        _be_finish(x, work["xn"], state.v, model.inv_mass_nd, 1.0 / dt, serial_pass(model.n))
        state.t += dt
        return info

    def __repr__(self) -> str:
        return (f"<integrator backward-euler solver={self.solver.name} tol={self.tol:g} "
                f"newton_iterations={self.newton_iterations} line_search={self.line_search}>")


class _StepProblem(newton.Problem):
    """(IP) of one step for engine.newton: Phi, -grad Phi (in ``rhs``) and |grad Phi|, and the
    direction of (N1) from the integrator's solver with the stepper's set-up."""

    def __init__(self, be: BackwardEuler, ctx, state: State, dt: float, work: dict):
        self.be, self.solver, self.model, self.dt, self.work = be, ctx.solver, ctx.model, dt, work
        self.forces = ctx.forces
        self.xn, self.v, self.rhs = work["xn"], state.v, work["rhs"]
        self.inv_dt2, self.a_dt = 1.0 / (dt * dt), be.rayleigh_alpha / dt
        self.mass_coef, self.hess_coef = newton_coefficients(dt, be.rayleigh_alpha, be.rayleigh_beta)
        self.W_n = self.model.elastic_energy(self.xn) if be.line_search else 0.0
        self.g0 = None
        self.gradient_norms = []
        self.serial = serial_pass(self.model.n)
        self.g = tuple(float(c) for c in self.model.gravity_vec)

    def objective(self, x) -> float:
        """Phi(x) of (IP)."""
        be, model, xn, dt = self.be, self.model, self.xn, self.dt
        phi = _be_inertia(x, xn, self.v, model.mass_nd, model.inv_mass_nd, *self.g, self.inv_dt2,
                          self.a_dt, dt)
        phi += model.elastic_energy(x) - self.W_n
        if be.rayleigh_beta > 0.0 or model.dampers:
            d, hq = self._damping_product(x)
            if model.dampers:   # 1/(2 dt) (x - x_n)^T D_n (x - x_n), engine.energies.membrane (M3)
                phi += 0.5 / dt * dot_vec3(d, hq)
            else:
                phi += 0.5 * be.rayleigh_beta / dt * dot_vec3(d, hq)
        return phi

    def _damping_product(self, x):
        """(d, hq): d = x - x_n and hq = D_n d, with D_n the membrane's damping matrix or (Rayleigh beta)
        the PSD Hessian at x_n."""
        d, hq = self.work["d"], self.work["hq"]
        sub_into(x, self.xn, d)
        zero_vec3(hq)
        if self.model.dampers:
            self.model.add_damping_product(self.xn, d, hq)
        else:
            self.model.add_hessian_product(self.xn, d, hq, True)
        return d, hq

    def residual(self, x, k: int) -> float:
        """rhs = -grad Phi(x); returns |grad Phi|."""
        model, work, be, dt = self.model, self.work, self.be, self.dt
        self.forces(x, work["f"])
        g2 = _be_residual(x, self.xn, self.v, work["f"], model.mass_nd, model.inv_mass_nd, self.inv_dt2, self.a_dt,
                          dt, self.rhs, self.serial)
        if k > 0 and (be.rayleigh_beta > 0.0 or model.dampers):   # at x = x_n (k = 0) their terms vanish
            _, hq = self._damping_product(x)   # the damping force -D_n v+ = -D_n (x - x_n)/dt, or beta H_n
            coef = 1.0 / dt if model.dampers else be.rayleigh_beta / dt
            g2 = _be_add_scaled(self.rhs, hq, coef, model.inv_mass_nd)
        gnorm = math.sqrt(g2)
        self.gradient_norms.append(gnorm)
        if self.g0 is None:
            # the scale the tolerance is relative to: |grad Phi(x_n)|, but at least the weight |M g| (a settled
            # hanging body has a round-off-sized gradient that Newton cannot reduce by newton_tol again)
            self.g0 = max(gnorm, model.weight_norm)
        return gnorm

    def converged(self, r: float) -> bool:
        return r <= self.be.newton_tol * self.g0 or r == 0.0

    def near(self, r: float) -> bool:
        return r < EXACT_BELOW * self.g0

    def direction(self, x, dx, k: int, psd: bool, mu: float):
        """(N1), filtered on pinned vertices."""
        be, model, solver, dt = self.be, self.model, self.solver, self.dt
        if model.dampers:                               # + D_n/dt, the damping's Jacobian
            return solver.solve(model, x, self.rhs, dx, self.mass_coef, self.hess_coef, psd=psd,
                                extra=(1.0 / dt, self.xn, "damping"))
        if k == 0 or be.rayleigh_beta == 0.0:           # x = x_n: the damping Hessian is H(x)
            return solver.solve(model, x, self.rhs, dx, self.mass_coef, self.hess_coef, psd=psd)
        return solver.solve(model, x, self.rhs, dx, self.mass_coef, 1.0, psd=psd,   # H(x) + (beta/dt) H_n
                            extra=(be.rayleigh_beta / dt, self.xn))
