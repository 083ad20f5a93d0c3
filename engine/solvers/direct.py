"""``cholesky`` and ``pardiso``: sparse direct LL^T of the assembled system (L1)-(L2), with the
residual check (L3) and iterative refinement they share (:class:`DirectSolver`); what each does
is described in :mod:`engine.solvers`."""
import math
import time

import numpy as np
import taichi as ti

from engine.fields import scalar_array, vec3_array, vec3_ndarray, zero_vec3
from engine.launch import kernel as fast_kernel
from engine.model import Model
from engine.solvers.assembly import CSRPattern, assemble_energy, assemble_mass, assemble_system, triplet_capacity
from engine.solvers.operator import LinearSolver, LinearSolveInfo, apply_plan, hessian_plan, scaled_operator, element_terms
from engine.solvers.pardiso import PARDISO_IPARMS, Pardiso, SymmetricUpper, pardiso_available

__all__ = ["DirectSolver", "CholeskySolver", "PardisoSolver", "PARDISO_IPARMS", "pardiso_available", "upper_product",
           "norm", "PRECISIONS"]


def upper_product(U, y: np.ndarray, diag: np.ndarray | None = None) -> np.ndarray:
    """A y for the symmetric A stored as its upper triangle U (scipy CSR), without building A:
    U y + U^T y - diag(U) y.  ``diag``: U's diagonal when already at hand."""
    return U @ y + U.T @ y - (U.diagonal() if diag is None else diag) * y


def norm(a: np.ndarray) -> float:
    """|a| without BLAS: numpy's threaded ddot leaves an OpenBLAS thread spinning on the second
    core for ~0.1 s (unless OPENBLAS_THREAD_TIMEOUT was set before numpy loaded, see
    engine/__init__.py), which slowed the factorisation that follows by ~1.7x."""
    return math.sqrt(float(np.square(a).sum()))


STALL = 0.5   # a refinement step must at least halve the residual, or refinement has stalled

f64_flat = ti.types.ndarray(dtype=ti.f64, ndim=1)


@fast_kernel
def _read_rhs(b: vec3_array, inv_mass: scalar_array, c: ti.f64, rhs: f64_flat):
    """rhs (numpy f64, 3n) = b / c on free vertices, 0 on pinned ones: numpy's
    ``b.to_numpy().astype(f64).reshape(-1) / c`` with pinned rows zeroed, without a new array."""
    ti.loop_config(serialize=True)
    for i in range(b.shape[0]):
        for d in ti.static(range(3)):
            r = ti.cast(0.0, ti.f64)
            if inv_mass[i] > 0.0:
                r = ti.cast(b[i][d], ti.f64) / c
            rhs[3 * i + d] = r


@fast_kernel
def _write_solution(sol: f64_flat, y: vec3_array):
    """y = sol (numpy f64, 3n) in the runtime's precision: ``y.from_numpy(sol.reshape(-1, 3))``."""
    ti.loop_config(serialize=True)
    for i in range(y.shape[0]):
        y[i] = ti.math.vec3(sol[3 * i], sol[3 * i + 1], sol[3 * i + 2])


class DirectSolver(LinearSolver):
    """A sparse direct solve of (L1)-(L2), shared by the backends: assemble A' = A/c, factorise,
    back-substitute, then check the residual (L3) with the matrix-free product and take up to
    ``refinements`` steps of iterative refinement while it is above the tolerance and falls by at
    least STALL per step; past them, ``_escalate`` may give a more accurate factorisation of the same
    A' to start again from (PARDISO's mixed precision: f64 after f32).  A subclass
    gives ``_factorize(model, entry, x, a', psd, extra) -> bool`` (False: A' is not positive
    definite) and ``_backsolve(entry, rhs) -> solution`` (numpy, 3n).  ``last_timings`` holds the
    last solve's seconds: assembly, factorization, solve (back-substitutions and refinement)."""

    def __init__(self, tol: float = 1e-8, max_iter: int = 1000, refinements: int = 2):
        super().__init__(tol, max_iter)
        self.refinements = int(refinements)
        self.last_timings: dict = {}

    def _setup(self, model: Model) -> dict:
        entry = self._entry(model)
        if "q" not in entry:
            entry["q"] = vec3_ndarray(model.n)
            entry["free_dofs"] = np.repeat(model.free, 3)
        return entry

    def _factorize(self, model: Model, entry: dict, x, a_s: float, psd: bool, extra) -> bool:
        raise NotImplementedError

    def _backsolve(self, entry: dict, rhs: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def _escalate(self, model: Model, entry: dict) -> bool:
        """Replace the factorisation of the A' just assembled by a more accurate one (True), or say
        there is none (False: the solve ends with the residual it has).  Here: none."""
        return False

    product_reads_y = True   # the residual reads y (sol copied into it before each check)

    def _residual(self, model: Model, entry: dict, x, a_s: float, psd: bool, extra, rhs: np.ndarray):
        """``residual(sol, y) -> rhs - A' sol`` (numpy, 3n; pinned rows not yet zeroed) for the check (L3);
        ``y`` holds sol as a vec3 ndarray when ``product_reads_y``.  Here the matrix-free operator (L1)
        in Taichi kernels."""
        plan = hessian_plan(model, x, psd, extra, work=entry["work"])
        q = entry["q"]

        def residual(sol, y):
            apply_plan(model, plan, a_s, y, q)
            return rhs - q.to_numpy().astype(np.float64).reshape(-1)
        return residual

    def solve(self, model: Model, x, b, y, mass_coef: float, hess_coef: float = 1.0,
              psd: bool = True, extra=None) -> LinearSolveInfo:
        a, c = self._coefficients(mass_coef, hess_coef)
        entry = self._setup(model)
        free = entry["free_dofs"]
        rhs = entry.get("rhs")
        if rhs is None:
            rhs = entry["rhs"] = np.empty(3 * model.n, dtype=np.float64)
            entry["out"] = np.empty(3 * model.n, dtype=np.float64)
        out = entry["out"]   # the solution handed to y from one array (its launch is then a bound one)

        def write(sol):
            np.copyto(out, sol)
            _write_solution(out, y)
        # read before the factorisation: a Taichi launch right after a PARDISO factorisation costs
        # ~0.2-0.3 ms more than the same launch before it (measured at 64^2, the kernel itself ~0.08 ms)
        _read_rhs(b, model.inv_mass_nd, float(c), rhs)
        t0 = time.perf_counter()
        ok = self._factorize(model, entry, x, a / c, psd, scaled_operator(extra, c))
        t1 = time.perf_counter()
        self.last_timings = {"assembly": entry.pop("_assembly_s", 0.0), "factorization": t1 - t0, "solve": 0.0}
        self.last_timings["factorization"] -= self.last_timings["assembly"]
        if not ok:
            zero_vec3(y)
            return self._info(1, math.inf, f"{self.name} factorization failed (matrix not positive definite)")
        bnorm = norm(rhs)
        if bnorm == 0.0:
            zero_vec3(y)
            return self._info(0, 0.0)
        sol = np.asarray(self._backsolve(entry, rhs), dtype=np.float64).reshape(-1)
        if self.product_reads_y:
            write(sol)
        residual_of = self._residual(model, entry, x, a / c, psd, scaled_operator(extra, c), rhs)
        it, previous = 1, math.inf
        while True:
            res = residual_of(sol, y)  # rhs - A' sol
            res[~free] = 0.0
            residual = norm(res) / bnorm
            if residual <= self.tol:
                break
            # refinement has run its course: too many steps, stalled (the factor is too far from A') or
            # overflowed; a solver with a more accurate factorisation of the same A' starts again from it
            if it > self.refinements or not residual < STALL * previous:
                if not self._escalate(model, entry):
                    break
                sol = np.asarray(self._backsolve(entry, rhs), dtype=np.float64).reshape(-1)
                previous = math.inf
            else:
                sol = sol + np.asarray(self._backsolve(entry, res), dtype=np.float64).reshape(-1)  # refinement
                previous = residual
            if self.product_reads_y:
                write(sol)
            it += 1
        if not self.product_reads_y:
            write(sol)
        self.last_timings["solve"] = time.perf_counter() - t1
        return self._info(it, residual)


class CholeskySolver(DirectSolver):
    """Sparse LL^T (Eigen via ``ti.linalg.SparseSolver``), pattern analysed once per model."""

    name = "cholesky"

    def __init__(self, tol: float = 1e-8, max_iter: int = 1000, refinements: int = 2):
        super().__init__(tol, max_iter, refinements)
        self.last_assembly_triplets: int | None = None

    def _setup(self, model: Model) -> dict:
        entry = super()._setup(model)
        if "builder" not in entry:
            cap = triplet_capacity(model)
            N = 3 * model.n
            entry["capacity"] = cap
            entry["builder"] = ti.linalg.SparseMatrixBuilder(N, N, max_num_triplets=cap, dtype=ti.f64)
            entry["solver"] = ti.linalg.SparseSolver(dtype=ti.f64, solver_type="LLT")
            entry["analyzed"] = False
        return entry

    def assemble(self, model: Model, x, mass_coef: float, hess_coef: float = 1.0, psd: bool = True,
                 extra=None):
        """The f64 SparseMatrix holding the LOWER TRIANGLE of the symmetric (L1)/c (plus
        extra[0]/c H_psd(extra[1])), pinned rows/columns replaced by the identity.  Eigen's LL^T
        reads only the lower triangle, so the upper one is not assembled (about half the
        triplets and assembly time); do not multiply with it."""
        entry = self._setup(model)
        c = float(hess_coef)
        a_s = float(mass_coef) / c
        extra = scaled_operator(extra, c)
        if extra is None:
            B = entry["builder"]
        else:  # the same pattern with every element block written twice
            if "builder2" not in entry:
                N = 3 * model.n
                entry["builder2"] = ti.linalg.SparseMatrixBuilder(
                    N, N, max_num_triplets=2 * entry["capacity"] - 3 * model.n, dtype=ti.f64)
            B = entry["builder2"]
        assemble_mass(B, model.mass_nd, model.inv_mass_nd, a_s)
        for scale, e, blocks in element_terms(model, x, psd, extra, entry.setdefault("factors", {})):
            assemble_energy(B, e, blocks, model.inv_mass_nd, scale)
        return B.build()  # empties the builder; lower triangle of the symmetric A' only

    def _factorize(self, model, entry, x, a_s, psd, extra) -> bool:
        t0 = time.perf_counter()
        A = self.assemble(model, x, a_s, 1.0, psd, extra)
        entry["_assembly_s"] = time.perf_counter() - t0
        S = entry["solver"]
        if not entry["analyzed"]:
            S.analyze_pattern(A)
            entry["analyzed"] = True
        S.factorize(A)
        return bool(S.info())

    def _backsolve(self, entry, rhs):
        return entry["solver"].solve(rhs)


PRECISIONS = ("mixed", "double")
MIXED_REFINEMENTS = 6   # f32 factor: each refinement step gains ~1e-4..1e-5 on the cloths (64^2, 128^2)


class PardisoSolver(DirectSolver):
    """Sparse LL^T with MKL PARDISO (supernodal, multi-threaded).  The upper triangle of A' is
    assembled into a CSR pattern fixed per model (:class:`engine.solvers.assembly.CSRPattern`: one gather
    kernel per energy, a parallel loop over block rows, no atomics, bitwise reproducible), the
    symbolic analysis is done once per model and only the numeric factorisation per solve.

    ``precision="mixed"`` (the default): PARDISO factorises and back-substitutes in f32 and the
    solution is refined in f64 against the f64 A' (the residual (L3) of the f64 system, as always)
    until it is at or below ``tol``: on the hanging cloths (64^2-128^2, dt = 1/60 s) the f32 solve
    starts at ~6e-5 and one refinement step reaches ~3e-8, two ~2e-11, and the f32 factorisation
    takes ~0.6 of the f64 one.  When the f32 factorisation fails, refinement stalls (the f32 factor
    is too far from A': a condition number near 1/eps_f32) or has not reached ``tol`` after
    MIXED_REFINEMENTS steps, the same A' is factorised in f64 and the solve starts again from it
    (``escalations`` counts those solves).  ``precision="double"``: f64 only; reaches ~1e-13
    whatever tol."""

    name = "pardiso"

    def __init__(self, tol: float = 1e-8, max_iter: int = 1000, refinements: int | None = None,
                 precision: str = "mixed"):
        if not pardiso_available():
            raise ValueError("solver 'pardiso' needs MKL PARDISO, which is not installed: "
                             "pip install 'elastic-lessons[fast]' (x86-64), or use solver 'direct' or 'cholesky'")
        if precision not in PRECISIONS:
            raise ValueError(f"precision must be one of {', '.join(PRECISIONS)}, got {precision!r}")
        self.precision = precision
        if refinements is None:
            refinements = MIXED_REFINEMENTS if precision == "mixed" else 2
        super().__init__(tol, max_iter, refinements)
        self.escalations = 0

    def _setup(self, model: Model) -> dict:
        entry = super()._setup(model)
        if "pattern" not in entry:
            import scipy.sparse
            from engine.runtime import threads
            pattern = CSRPattern(model)
            values = np.zeros(pattern.nnz, dtype=np.float64)
            N = 3 * model.n
            A = scipy.sparse.csr_matrix((values, pattern.indices, pattern.indptr), shape=(N, N), copy=False)
            A.has_sorted_indices = True
            entry["pattern"], entry["matrix"] = pattern, A
            entry["_pardiso_threads"] = threads(2)
        return entry

    def assemble_values(self, model: Model, entry: dict, x, a_s: float, psd: bool, extra) -> np.ndarray:
        """Write the values of A' (P1) at x into the pattern's CSR values; returns them (numpy)."""
        pattern, A = entry["pattern"], entry["matrix"]
        values = A.data  # the kernels write the CSR values in place (a numpy array: no copy on the CPU)
        terms = element_terms(model, x, psd, extra, entry.setdefault("factors", {}))
        assemble_system(pattern, values, model, a_s, terms, once_each=extra is None)
        ti.sync()
        return values

    def _instance(self, entry: dict, single: bool) -> Pardiso:
        """The PARDISO instance of this precision for the model's pattern (analysed at its first use)."""
        key = "pardiso32" if single else "pardiso"
        if key not in entry:
            A = entry["matrix"]
            entry[key] = Pardiso(A.indptr, A.indices, entry["_pardiso_threads"], single=single)
        return entry[key]

    def _factorize(self, model, entry, x, a_s, psd, extra) -> bool:
        t0 = time.perf_counter()
        self.assemble_values(model, entry, x, a_s, psd, extra)
        entry["_assembly_s"] = time.perf_counter() - t0
        values = entry["matrix"].data
        if self.precision == "mixed":
            entry["current"] = self._instance(entry, True)
            if entry["current"].factorize(values):
                return True
            self.escalations += 1       # not positive definite in f32: try f64
        entry["current"] = self._instance(entry, False)
        return entry["current"].factorize(values)

    def _escalate(self, model, entry) -> bool:
        if not entry["current"].single:
            return False
        self.escalations += 1
        entry["current"] = self._instance(entry, False)
        return entry["current"].factorize(entry["matrix"].data)

    def _backsolve(self, entry, rhs):
        return entry["current"].solve(rhs)

    product_reads_y = False   # A' sol from the assembled matrix: y is written once, at the end

    def _residual(self, model, entry, x, a_s, psd, extra, rhs):
        """rhs - A' sol from the upper triangle U just factorised, by MKL's threaded symmetric product on
        U's own arrays (engine.solvers.pardiso.SymmetricUpper): the same matrix, no second pass over the
        elements (at 128^2 about 0.5 ms, against 2-2.5 ms for scipy's U sol + U^T sol - diag(U) sol and
        ~6 ms for the matrix-free product with its copies)."""
        if "product" not in entry:
            entry["product"] = SymmetricUpper(entry["matrix"], entry["_pardiso_threads"])
        product = entry["product"]
        return lambda sol, y: product.residual(rhs, sol)
