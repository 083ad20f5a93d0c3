"""The implicit step as a user would write it with the sparse solvers pip installs.

Every contender takes one Baraff-Witkin step of the lessons' cloth (bench/baseline.py
``NumpyCloth.implicit_system``: A = M/dt^2 + H_psd(x_n), b = f(x_n) + M g + M v_n/dt over the
free degrees of freedom, assembled in numpy into a CSR pattern computed once), then solves
A dx = b:

``scipy-cg``       scipy.sparse.linalg.cg, Jacobi preconditioner, relative residual ``tol``;
``pyamg-cg``       pyamg smoothed aggregation (3x3 blocks, the three rigid translations as
                   near-null-space modes), rebuilt every step (the matrix changes), as the
                   preconditioner of CG to ``tol``;
``pardiso``        MKL PARDISO (pypardiso), SPD, nested dissection, the user's threads: the
                   symbolic analysis once, the numeric factorisation and solve every step (what
                   a careful user does: pypardiso.spsolve repeats the analysis on every call);
``pardiso-spsolve`` pypardiso.spsolve(A, b) as its README shows it (analysis every call);
``cholmod``        CHOLMOD through cholespy (the CHOLMOD wheel pip installs; scikit-sparse has no
                   wheel and needs SuiteSparse headers), factorised every step.

Direct solvers reach ~1e-13, so ``tol`` applies to the iterative ones only.  Each step records
its assembly, set-up (analysis, hierarchy or factorisation) and solve seconds and the true
relative residual ||b - A dx|| / ||b||.
"""
import ctypes
import os
import time

import numpy as np
import scipy.sparse
import scipy.sparse.linalg

PEERS = ("scipy-cg", "pyamg-cg", "pardiso", "pardiso-spsolve", "cholmod")
_MODULE = {"pyamg-cg": "pyamg", "pardiso": "pypardiso", "pardiso-spsolve": "pypardiso", "cholmod": "cholespy"}


def available(name: str) -> str | None:
    """None if peer ``name`` can run here, else the reason (a missing package)."""
    mod = _MODULE.get(name)
    if mod is None:
        return None
    _quiet_openmp()
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


def _quiet_openmp() -> None:
    """The engine's setting (engine.linalg): MKL's OpenMP threads sleep when a solve ends rather
    than spin, so both drive PARDISO under the same conditions."""
    os.environ.setdefault("KMP_BLOCKTIME", "0")


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
        self._pardiso = None
        if name.startswith("pardiso"):
            import pypardiso
            self._pardiso = pypardiso.PyPardisoSolver(mtype=2)
            lib = self._pardiso.libmkl
            fn = getattr(lib, "MKL_Set_Num_Threads", None) or getattr(lib, "mkl_set_num_threads", None)
            if fn is not None:
                fn(ctypes.c_int(_threads()))
        self._analysed = False

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
            ml = pyamg.smoothed_aggregation_solver(A.tobsr(blocksize=(3, 3)), B=B, symmetry="symmetric",
                                                   max_coarse=500)
            setup = time.perf_counter() - t0
            res = []
            y = ml.solve(b, tol=self.tol, accel="cg", maxiter=1000, residuals=res)
            return y, setup, max(len(res) - 1, 0)
        if self.name == "pardiso":
            S = self._pardiso
            bb = np.asfortranarray(b.reshape(-1, 1))
            t0 = time.perf_counter()
            if not self._analysed:
                S._check_A(A)
                S.set_iparm(1, 1)
                S.set_iparm(2, 2)
                S.set_iparm(8, 0)
                S.set_iparm(10, 8)
                S.set_phase(11)
                S._call_pardiso(A, bb)
                self._analysed = True
            S.set_phase(22)
            S._call_pardiso(A, bb)
            setup = time.perf_counter() - t0
            S.set_phase(33)
            return S._call_pardiso(A, bb).reshape(-1), setup, 1
        if self.name == "pardiso-spsolve":
            S = self._pardiso
            S.set_iparm(1, 1)
            S.set_iparm(2, 2)
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
        nb = float(np.linalg.norm(b))
        Af = self.full_matrix(A)
        self.last = dict(assembly_s=t1 - t0, setup_s=setup, solve_s=t2 - t1 - setup, iterations=int(iterations),
                         residual=float(np.linalg.norm(b - Af @ y) / nb) if nb > 0 else 0.0)
        return x, v
