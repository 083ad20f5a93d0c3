"""The linear system of the implicit steps, (L1)-(L3) of :mod:`engine.solvers`: its matrix-free
product (:func:`apply_system`), the per-energy Hessian plan every solver applies, the result of a
solve (:class:`LinearSolveInfo`, :class:`SolverError`) and the solvers' base class."""
import copy
import math
from typing import NamedTuple

import taichi as ti

from engine.fields import WorkArrays, axpy_inplace, scalar_array, vec3_array, zero_vec3
from engine.model import Model


class SolverError(RuntimeError):
    """A linear (or Newton) solve did not reach its tolerance; one-line message naming the
    solver, tolerance, residual and iterations."""


class LinearSolveInfo(NamedTuple):
    """Result of one linear solve: ``iterations`` (CG iterations; for cholesky 1 + refinement
    steps), ``residual`` (true relative residual (L3)), ``converged`` (residual <= tol),
    ``solver`` name, ``tol``, ``max_iter`` and ``message`` (why it failed, if it did)."""
    iterations: int
    residual: float
    converged: bool
    solver: str = ""
    tol: float = 0.0
    max_iter: int = 0
    message: str = ""

    def describe(self) -> str:
        state = "converged" if self.converged else "did NOT converge"
        text = (f"{self.solver} linear solve {state}: relative residual {self.residual:.3e} "
                f"{'<=' if self.converged else '>'} tol {self.tol:.1e} after {self.iterations} iterations "
                f"(max_iter={self.max_iter})")
        return text + (f"; {self.message}" if self.message else "")

    def check(self) -> "LinearSolveInfo":
        """Return self, or raise :class:`SolverError` if the solve did not converge."""
        if not self.converged:
            raise SolverError(self.describe())
        return self



# --------------------------------------------------------------------------------------------
# Kernels: matrix-free operator pieces (pinned vertices: inv_mass == 0)
# --------------------------------------------------------------------------------------------

@ti.kernel
def _mass_product(p: vec3_array, mass: scalar_array, a: float, q: vec3_array):
    # q = a M p  (start of q = A p; the energies then add H p)
    for i in range(p.shape[0]):
        q[i] = a * mass[i] * p[i]


@ti.kernel
def _filtered_scale(q: vec3_array, inv_mass: scalar_array, c: float):
    # q <- c S q  (L2)
    for i in range(q.shape[0]):
        if inv_mass[i] > 0.0:
            q[i] = c * q[i]
        else:
            q[i] = ti.math.vec3(0.0)



# --------------------------------------------------------------------------------------------
# Operator helpers
# --------------------------------------------------------------------------------------------

def hessian_plan(model: Model, x, psd: bool = True, extra=None, blocks: dict | None = None,
                  work: WorkArrays | None = None):
    """One callable per energy, ``add(p, q)``: q += H_e(x) p with the PSD (or exact) Hessian.
    Energies offering the "blocks" product (springs) compute their blocks here, once per solve
    (and put them in ``blocks[id(energy)]`` if a dict is given); the others use
    add_hessian_product.  ``extra`` = (s, x2) appends q += s H_psd(x2) p, and (s, x2, "damping")
    q += s D(x2) p, the dampers' matrix (engine.model.Model.dampers) (matrix-free, through a work
    array of ``work``, or a new one)."""
    plan = []
    if extra is not None and extra[0] != 0.0:
        s, x2 = float(extra[0]), extra[1]
        damping = extra_kind(extra) == "damping"
        t = (WorkArrays(model.n) if work is None else work).vec3("extra")

        def add_extra(p, q):
            zero_vec3(t)
            if damping:
                model.add_damping_product(x2, p, t)
            else:
                model.add_hessian_product(x2, p, t, True)
            axpy_inplace(q, t, s)
        plan.append(add_extra)
    for e in model.energies:
        if "blocks" in e.products:
            eb = e.hessian_blocks(x, psd)
            if blocks is not None:
                blocks[id(e)] = eb
            plan.append(lambda p, q, e=e, eb=eb: e.add_block_product(eb, p, q))
        else:
            plan.append(lambda p, q, e=e: e.add_hessian_product(x, p, q, psd))
    return plan


def scaled_operator(extra, c: float):
    """extra = (s, x2[, kind]) of A = a M + c H(x) + s H(x2) (or s D(x2)), as seen in A' = A / c;
    None if absent."""
    if extra is None or float(extra[0]) == 0.0:
        return None
    return (float(extra[0]) / c, *extra[1:])


def extra_kind(extra) -> str:
    """"hessian" (s H_psd(x2)) or "damping" (s D(x2)) for an extra term (s, x2[, kind])."""
    return extra[2] if len(extra) > 2 else "hessian"


class RankOneFactors(NamedTuple):
    """An element term handed to the assembly as its Gauss-Newton factors: H_e = w_e w_e^T, block
    (a, b) = w_e,a w_e,b^T (:func:`rank_one_block`), instead of the stored k^2 blocks: for a hinge
    4 vectors (96 bytes in f64) written and read instead of 16 3x3 blocks (1152 bytes)."""
    w: object    # (max(m, 1), k) vec3 ndarray


@ti.func
def rank_one_block(w: ti.template(), e, a, b) -> ti.math.mat3:
    """Block (a, b) of the rank-one element Hessian w_e w_e^T (a, b: compile-time or run-time slots)."""
    return w[e, a].outer_product(w[e, b])


def element_terms(model: Model, x, psd: bool, extra, factors: dict | None = None):
    """(scale, energy, blocks) of every element term of A' for the direct solvers' assembly: the
    extra term's first (s H_psd(x2) or s D(x2)), then H(x). Yielded one at a time: an energy
    reuses its blocks buffer at its next hessian_blocks call, so each term must be assembled
    before the next is asked for.  With ``factors`` (a dict the caller keeps: the buffers, one per
    energy), a PSD term of a "rank-one" energy comes as its :class:`RankOneFactors`."""
    def term(e, xx, use_psd):
        if factors is not None and use_psd and "rank-one" in e.products:
            w = factors.get(id(e))
            if w is None:
                w = factors[id(e)] = ti.ndarray(dtype=ti.math.vec3, shape=(max(e.n_elements, 1), e.stencil_size))
            e.gauss_newton_factors(xx, w)
            return RankOneFactors(w)
        return e.hessian_blocks(xx, use_psd)

    if extra is not None:
        s, x2 = extra[0], extra[1]
        if extra_kind(extra) == "damping":
            for e in model.dampers:
                if e.n_elements:
                    yield s, e, e.damping_blocks(x2)
        else:
            for e in model.energies:
                if e.n_elements:
                    yield s, e, term(e, x2, True)
    for e in model.energies:
        if e.n_elements:
            yield 1.0, e, term(e, x, psd)


def apply_plan(model: Model, plan, a: float, p, q) -> None:
    """q = a M p + H p (unfiltered)."""
    _mass_product(p, model.mass_nd, a, q)
    for add in plan:
        add(p, q)


def apply_system(model: Model, x, p, q, mass_coef: float, hess_coef: float = 1.0, psd: bool = True,
                 extra=None) -> None:
    """q = S (mass_coef M + hess_coef H(x)) p, H the PSD Hessian (L1)-(L2); pinned rows of q are 0.
    ``p`` should be 0 on pinned vertices (it is the filtered unknown).  ``psd=False``: exact Hessian."""
    c = float(hess_coef)
    if c <= 0.0:
        raise ValueError(f"hess_coef must be > 0 (got {hess_coef!r})")
    apply_plan(model, hessian_plan(model, x, psd, scaled_operator(extra, c)), float(mass_coef) / c, p, q)
    _filtered_scale(q, model.inv_mass_nd, c)


# --------------------------------------------------------------------------------------------
# Solvers
# --------------------------------------------------------------------------------------------

class LinearSolver:
    """Base class: ``solve(model, x, b, y, mass_coef, hess_coef=1.0) -> LinearSolveInfo`` solves
    (L1)-(L2) for y (overwritten; 0 on pinned vertices).  ``tol`` is the relative residual (L3)
    to reach, ``max_iter`` the iteration limit.  The set-up for a model (work arrays, pattern,
    analysis) is kept for one model at a time: a Stepper solves with its own (:meth:`fresh`)."""

    name = "linear"

    def __init__(self, tol: float = 1e-8, max_iter: int = 1000):
        tol = float(tol)
        if not (math.isfinite(tol) and tol > 0.0):
            raise ValueError(f"solver tolerance must be finite and > 0 (got {tol!r})")
        max_iter = int(max_iter)
        if max_iter < 1:
            raise ValueError(f"solver max_iter must be >= 1 (got {max_iter})")
        self.tol = tol
        self.max_iter = max_iter
        self._model: Model | None = None  # the model the set-up below was built for
        self._set_up: dict | None = None
        self.last_info: LinearSolveInfo | None = None

    def solve(self, model: Model, x, b, y, mass_coef: float, hess_coef: float = 1.0,
              psd: bool = True, extra=None) -> LinearSolveInfo:
        raise NotImplementedError

    def fresh(self) -> "LinearSolver":
        """A solver of the same kind and options with no set-up yet: a Stepper's own, which keeps its
        model's pattern, analysis and work arrays for that stepper alone."""
        twin = copy.copy(self)
        twin._model, twin._set_up, twin.last_info = None, None, None
        if hasattr(twin, "last_timings"):
            twin.last_timings = {}
        return twin

    def _entry(self, model: Model) -> dict:
        """The set-up (work arrays, pattern, analysis) for ``model``: one model at a time, rebuilt
        when the solver is given another model or the model's energy list changed."""
        key = tuple((id(e), e.n_elements) for e in model.energies)
        entry = self._set_up
        if self._model is not model or entry is None or entry["key"] != key:
            entry = self._set_up = {"key": key, "work": WorkArrays(model.n)}
            self._model = model
        return entry

    def _coefficients(self, mass_coef: float, hess_coef: float) -> tuple[float, float]:
        """(a, c) of (L1) as floats; ValueError unless a >= 0 and c > 0."""
        a, c = float(mass_coef), float(hess_coef)
        if c <= 0.0 or a < 0.0:
            raise ValueError(f"{self.name} needs mass_coef >= 0 and hess_coef > 0 (got {a!r}, {c!r})")
        return a, c

    def _info(self, iterations: int, residual: float, message: str = "") -> LinearSolveInfo:
        info = LinearSolveInfo(int(iterations), float(residual), bool(residual <= self.tol), self.name,
                               self.tol, self.max_iter, message)
        self.last_info = info
        return info

    def __repr__(self) -> str:
        return f"<{self.name} solver tol={self.tol:g} max_iter={self.max_iter}>"
