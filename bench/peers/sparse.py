"""The implicit step as a user would write it with the sparse solvers pip installs.

Every contender takes one Baraff-Witkin step of the lessons' cloth (bench/baseline.py
``NumpyCloth.implicit_system``: A = M/dt^2 + H_psd(x_n), b = f(x_n) + M g + M v_n/dt over the
free degrees of freedom, the block values scattered into a CSR pattern by a sparse matrix built
once), then solves A dx = b and checks the relative residual ||b - A dx|| / ||b|| with one product
of the matrix it already has (the upper triangle and its transpose for PARDISO: no second
matrix built), as the engine checks its own with a matrix-free product:

``scipy-cg``        scipy.sparse.linalg.cg, Jacobi preconditioner, relative residual ``tol``;
``pyamg-cg``        pyamg smoothed aggregation (3x3 blocks, the three rigid translations as
                    near-null-space modes, the coarsest level solved by a sparse LU), rebuilt
                    every step (the matrix changes), as the preconditioner of CG to ``tol``;
``pardiso``         MKL PARDISO with the engine's settings (engine.solvers.PARDISO_IPARMS: SPD,
                    METIS nested dissection, no refinement inside, the same thread count), called
                    through its C entry point with the index arrays made once, as the engine calls
                    it (engine.solvers.pardiso.Pardiso; pypardiso's own call rebuilds them at every
                    call): the symbolic analysis once, outside the clock, the numeric factorisation
                    and solve every step;
``pardiso-spsolve`` pypardiso.spsolve(A, b) as its README shows it (analysis on every call);
``cholmod``         CHOLMOD through cholespy (the CHOLMOD wheel pip installs; scikit-sparse has no
                    wheel and needs SuiteSparse headers).  cholespy has no refactorisation entry
                    point: every step builds a new solver, so its time includes the symbolic
                    analysis (said in the report's row).

:class:`FactorOnly` is no step at all: PARDISO's numeric factorisation and solve of one fixed
matrix (analysis once, no assembly, no check): what the library alone costs, so that a reader
sees what an engine adds around it.  ``FactorOnly(..., precision="mixed")`` is the engine's own
technique called directly: PARDISO's f32 factorisation and back-substitution, then f64
refinement steps (f32 back-substitution of the f64 residual of the f64 matrix) until the relative
residual is at or below ``tol``: the library alone, doing what the engine's solver does.

Direct solvers reach ~1e-13, so ``tol`` applies to the iterative ones only.  Each step records
its assembly, set-up (analysis, hierarchy or factorisation) and solve seconds and the true
relative residual.
"""
import os
import time

import numpy as np
import scipy.sparse
import scipy.sparse.linalg

from engine.solvers.pardiso import quiet_openmp

PEERS = ("scipy-cg", "pyamg-cg", "pardiso", "pardiso-spsolve", "cholmod")
REANALYSES = {"pardiso-spsolve": "analysis every call (pypardiso.spsolve)",
              "cholmod": "analysis every step (cholespy cannot refactorise)"}
_MODULE = {"pyamg-cg": "pyamg", "pardiso": "pypardiso", "pardiso-spsolve": "pypardiso", "cholmod": "cholespy",
           "pardiso-factor": "pypardiso", "pardiso-factor-mixed": "pypardiso"}


def available(name: str) -> str | None:
    """None if peer ``name`` can run here, else the reason (a missing package)."""
    mod = _MODULE.get(name)
    if mod is None:
        return None
    quiet_openmp()   # the engine's MKL setting, so both drive PARDISO under the same conditions
    try:
        __import__(mod)
    except Exception as exc:  # ImportError, or mkl_rt not found
        return f"{mod} not installed ({type(exc).__name__}): pip install -e '.[peers]'"
    if mod == "pypardiso":
        try:
            import pypardiso
            pypardiso.PyPardisoSolver()
        except Exception as exc:
            return f"MKL PARDISO cannot be loaded ({exc})"
    return None


def _threads() -> int:
    return int(os.environ.get("ELASTIC_THREADS", "2") or 2)


class SparsePeer:
    """One contender stepping a NumpyCloth: ``step(x, v, dt)`` in place; ``last`` holds the
    split timings (assembly_s, setup_s, solve_s), iterations and residual of the last step."""

    def __init__(self, name: str, cloth, tol: float = 1e-5):
        reason = available(name)
        if reason:
            raise RuntimeError(reason)
        self.name, self.cloth, self.tol = name, cloth, float(tol)
        self.last: dict = {}
        self._pardiso = _pardiso_solver() if name == "pardiso-spsolve" else None

    def system(self, x, v, dt):
        return self.cloth.implicit_system(x, v, dt, upper=self.name.startswith("pardiso"))

    def solve(self, A, b):
        """(dx, setup seconds, iterations) for A dx = b."""
        if self.name == "scipy-cg":
            t0 = time.perf_counter()
            M = scipy.sparse.diags(1.0 / A.diagonal())
            count = [0]
            y, info = scipy.sparse.linalg.cg(A, b, rtol=self.tol, atol=0.0, maxiter=100000, M=M,
                                             callback=lambda _: count.__setitem__(0, count[0] + 1))
            if info != 0:
                raise RuntimeError(f"scipy cg did not converge (info={info})")
            return y, 0.0, count[0]
        if self.name == "pyamg-cg":
            import pyamg
            t0 = time.perf_counter()
            B = np.kron(np.ones((A.shape[0] // 3, 1)), np.eye(3))   # rigid translations
            # coarse_solver "splu": pyamg's default ("pinv") inverts the coarsest level densely, and at
            # 64^2 the hierarchy stops at two levels with a 1056-row (cloth) / 1449-row (membrane)
            # coarse matrix: its dense pseudo-inverse, made again every step, took 0.35-0.85 s of a
            # 0.4-0.9 s solve (sparse LU: 92 / 67 ms, the same 13 / 17 iterations); at 128^2 the
            # coarsest level has 210-396 rows and the two are level
            ml = pyamg.smoothed_aggregation_solver(A.tobsr(blocksize=(3, 3)), B=B, symmetry="symmetric",
                                                   max_coarse=500, coarse_solver="splu")
            setup = time.perf_counter() - t0
            res = []
            y = ml.solve(b, tol=self.tol, accel="cg", maxiter=1000, residuals=res)
            return y, setup, max(len(res) - 1, 0)
        if self.name == "pardiso":
            if self._pardiso is None:   # once per pattern (the matrix is built once): not repeated by a run
                from engine.solvers.pardiso import Pardiso
                self._pardiso = Pardiso(A.indptr, A.indices, _threads())
                self._pardiso.analyse(A.data)
            t0 = time.perf_counter()
            if not self._pardiso.factorize(A.data):
                raise RuntimeError("PARDISO: the matrix is not positive definite")
            setup = time.perf_counter() - t0
            return self._pardiso.solve(b), setup, 1
        if self.name == "pardiso-spsolve":
            S = self._pardiso
            S.factorized_A = scipy.sparse.csr_matrix((0, 0))  # a new matrix every step: analysis + factorisation
            y = S.solve(A, b)
            return np.asarray(y).reshape(-1), 0.0, 1
        if self.name == "cholmod":
            from cholespy import CholeskySolverD, MatrixType
            C = A.tocsc()
            t0 = time.perf_counter()
            S = CholeskySolverD(C.shape[0], C.indptr.astype(np.int32), C.indices.astype(np.int32),
                                C.data, MatrixType.CSC)
            setup = time.perf_counter() - t0
            y = np.zeros_like(b)
            S.solve(b, y)
            return y, setup, 1
        raise ValueError(f"unknown peer {self.name!r}; valid: {', '.join(PEERS)}")

    def full_matrix(self, A):
        """The full symmetric matrix from what ``system`` returned (PARDISO takes the upper triangle)."""
        if self.name.startswith("pardiso"):
            return A + scipy.sparse.triu(A, k=1).T
        return A

    def step(self, x, v, dt):
        t0 = time.perf_counter()
        A, b = self.system(x, v, dt)
        t1 = time.perf_counter()
        y, setup, iterations = self.solve(A, b)
        t2 = time.perf_counter()
        self.cloth.apply_step(x, v, y, dt)
        from engine.solvers.direct import norm  # without BLAS, as the engine's check
        nb = norm(b)
        residual = norm(residual_of(A, b, y, upper=self.name.startswith("pardiso"))) / nb if nb > 0 else 0.0
        self.last = dict(assembly_s=t1 - t0, setup_s=setup, solve_s=t2 - t1 - setup, iterations=int(iterations),
                         residual=float(residual))
        return x, v


def residual_of(A, b, y, upper: bool):
    """b - A y for the full symmetric matrix, given in full (scipy) or (``upper``) as its upper triangle,
    without building a second matrix: the engine's own PARDISO check (engine.solvers.pardiso.SymmetricUpper,
    MKL's threaded symmetric product)."""
    if not upper:
        return b - A @ y
    from engine.solvers.pardiso import SymmetricUpper
    return SymmetricUpper(A, _threads()).residual(b, y)


def _pardiso_solver():
    """A pypardiso solver with the engine's PARDISO settings and thread count."""
    from engine.solvers.pardiso import configured_solver
    return configured_solver(_threads())


class FactorOnly:
    """PARDISO's numeric factorisation + solve of one fixed matrix (the cloth's system at (x, v)),
    the analysis done once at construction: the library's own cost per step, nothing around it.
    ``precision="mixed"``: f32 factorisation and back-substitution refined in f64 to ``tol`` (the
    engine's technique, engine.solvers.PardisoSolver), through the same binding."""

    def __init__(self, cloth, x, v, dt, precision: str = "double", tol: float = 1e-5, refinements: int = 6):
        reason = available("pardiso")
        if reason:
            raise RuntimeError(reason)
        from engine.solvers.pardiso import Pardiso
        self.A, self.b = cloth.implicit_system(x, v, dt, upper=True)
        self.mixed = precision == "mixed"
        self.tol, self.refinements = float(tol), int(refinements)
        self.S = Pardiso(self.A.indptr, self.A.indices, _threads(), single=self.mixed)
        self.S.analyse(self.A.data)
        from engine.solvers.pardiso import SymmetricUpper
        self._product = SymmetricUpper(self.A, _threads())   # the engine's check, made once per matrix as there
        self.y = None
        self.last = {}

    def run(self):
        if not self.S.factorize(self.A.data):
            raise RuntimeError("PARDISO: the matrix is not positive definite")
        y = self.S.solve(self.b)
        steps = 1
        if self.mixed:
            from engine.solvers.direct import norm
            nb = norm(self.b)
            while True:
                r = self._product.residual(self.b, y)
                residual = norm(r) / nb
                if residual <= self.tol:
                    break
                if steps > self.refinements:
                    raise RuntimeError(f"f32 PARDISO refined {self.refinements} times: residual {residual:.2e} "
                                       f"> tol {self.tol:.0e}")
                y = y + self.S.solve(r)
                steps += 1
            self.last = dict(residual=residual, iterations=steps)
        self.y = y
        return y
