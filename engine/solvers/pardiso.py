"""MKL PARDISO called through its C entry point, for one fixed CSR pattern (the optional ``fast``
extra: pypardiso + mkl, x86-64).

pypardiso loads MKL and declares ``pardiso``'s ctypes signature; this module calls that entry
point itself because pypardiso's own call (a) accepts only double precision values and (b) builds
the 1-based row and column index arrays again on every call (at 256^2, 4.6 million entries: two
copies of 18 MB per factorisation and per back-substitution).  Here the index arrays are made once
per pattern, and the values may be handed over in single precision (iparm(28) = 1): PARDISO then
factorises and back-substitutes in f32, about 1.5x faster on this mesh family (64^2 to 128^2, 2
threads), and the caller refines the solution in f64 against the f64 matrix
(:class:`engine.solvers.direct.PardisoSolver`).

:class:`Pardiso` is used by the engine's solver and, the same binding, by the benchmark's
"PARDISO alone" rows (bench/peers/sparse.py), so that the library's own cost is measured through
the same calls the engine makes.
"""
import ctypes
import os

import numpy as np

# PARDISO's settings (1-based iparm, value): user iparms, METIS nested dissection, no iterative
# refinement inside (the caller checks and refines), pivot perturbation 1e-8, no weighted matching,
# the default factorisation kernel, no matrix check, CSR (not transposed)
PARDISO_IPARMS = ((1, 1), (2, 2), (8, 0), (10, 8), (13, 0), (24, 0), (27, 0), (12, 0))
SINGLE_PRECISION_IPARM = 28   # iparm(28) = 1: the values, right-hand sides and solutions are f32
# iparm(24) = 0, the classic parallel factorisation, for the engine and the benchmark's PARDISO rows
# alike. The improved two-level one (iparm(24) = 10) factorises the cloth's f64 matrices 8-20%
# faster (2 threads, interleaved medians: 21.0 against 26.3 ms at 64^2, 136 against 157 at 128^2,
# 923 against 1005 at 256^2; in f32 no faster), but (a) it factorises an indefinite matrix without
# an error, where the classic one returns -4 and the engine reports "not positive definite"
# (tests/engine/test_solvers.py), and (b) its f64 back-substitution crashed the process
# (segmentation fault, reproduced) once Numba's GNU OpenMP threads had run in it, as they do in the
# benchmark's processes before the implicit rows.
# The values go in as CSR. PARDISO's 3x3 block format (BSR, iparm(37) = 3) factorises + solves the
# cloth's systems no faster (BSR / CSR, interleaved: 1.09 at 64^2 in f64 and f32, 1.02 / 1.07 at
# 128^2), and its variable-block conversion (iparm(37) = -80) is slower.
# iparm(25), the forward/backward solve's parallel modes, left at 0 (sequential): measured on the
# 64^2 / 128^2 cloth (Intel Xeon, 2 threads, 15 interleaved rounds of one factorisation and five
# solves), the f32 solve took 1.55 / 5.05 ms with 0, 1.68 / 7.93 with 1 and 1.45 / 4.81 with 2; f64
# 1.75 / 8.14, 2.11 / 15.9 and 1.72 / 8.26: mode 1 slower, mode 2 within the noise.
# iparm(2), the fill-in reducing ordering: METIS nested dissection (2), not MKL's minimum degree (0),
# whose factors have ~1% more entries but factorise faster at 64^2 only. Measured on the 64^2 / 128^2 /
# 256^2 cloth's systems (AMD EPYC, 2 threads, interleaved rounds of a factorisation and its solves:
# f64 factorisation + solve + check; f32 factorisation + two solves + two checks, as the engine's),
# per-round ratios minimum degree / METIS, median: f32 0.92 / 1.05 / 0.99, f64 0.94 / 1.02 / 0.98;
# the parallel METIS (3) factorised no faster than METIS (2).


MKL_BLOCKTIME_MS = "1"


def quiet_openmp() -> None:
    """MKL's OpenMP threads wait MKL_BLOCKTIME_MS = 1 ms after a parallel region before they sleep,
    instead of KMP_BLOCKTIME's default 200 ms: the Taichi kernels that follow a solve (the update, the
    next step's forces and assembly) need the same two cores. Not 0 either: each of a step's MKL calls
    after the factorisation (two back-substitutions, two threaded residual products) then woke the
    sleeping threads again. Measured on the 64^2 cloth (AMD EPYC, 2 threads, four processes each,
    30 interleaved rounds): the engine's back-substitutions and checks 2.6-3.3 ms with 0 against
    1.7-1.9 ms with 1 (2 and 5 alike), the whole step 14.3-15.0 ms against 14.8-16.2, PARDISO's f64
    factorisation + solve alone 16.5-17.4 against 16.5-18.1; at 128^2 no difference beyond the noise.
    (An earlier 200 ms against 0: one 64^2 solve 250-270 ms against 188-228.) Must be set before
    MKL's OpenMP runtime starts; a value the user set is kept. The benchmark's PARDISO peers run in
    the same processes with the same setting."""
    os.environ.setdefault("KMP_BLOCKTIME", MKL_BLOCKTIME_MS)


def pardiso_available() -> bool:
    """True when MKL PARDISO can be loaded (the optional ``fast`` extra: pypardiso + mkl)."""
    global _PARDISO_OK
    if _PARDISO_OK is None:
        quiet_openmp()
        try:
            import pypardiso
            pypardiso.PyPardisoSolver()
            _PARDISO_OK = True
        except Exception:
            _PARDISO_OK = False
    return _PARDISO_OK


_PARDISO_OK: bool | None = None


def configured_solver(threads: int):
    """A pypardiso solver (SPD, mtype 2) with the engine's settings (PARDISO_IPARMS) and MKL limited to
    ``threads`` threads: what :class:`Pardiso` calls through, and the benchmark's pypardiso.spsolve row."""
    quiet_openmp()
    import pypardiso
    solver = pypardiso.PyPardisoSolver(mtype=2)
    for i, v in PARDISO_IPARMS:
        solver.set_iparm(i, v)
    _limit_threads(solver.libmkl, threads)
    return solver


def _limit_threads(lib, threads: int) -> None:
    for name in ("MKL_Set_Num_Threads", "mkl_set_num_threads"):
        fn = getattr(lib, name, None)
        if fn is not None:
            fn(ctypes.c_int(int(threads)))
            break


def _mkl_library():
    """MKL's runtime library as pypardiso loaded it (once per process)."""
    global _MKL
    if _MKL is None:
        quiet_openmp()
        import pypardiso
        _MKL = pypardiso.PyPardisoSolver().libmkl
    return _MKL


_MKL = None


class _Descr(ctypes.Structure):
    """MKL's ``struct matrix_descr`` (mkl_spblas.h)."""
    _fields_ = [("type", ctypes.c_int), ("mode", ctypes.c_int), ("diag", ctypes.c_int)]


# mkl_spblas.h's enumerations
_NON_TRANSPOSE, _SYMMETRIC, _FILL_UPPER, _DIAG_NON_UNIT, _INDEX_ZERO = 10, 21, 41, 50, 0


class SymmetricUpper:
    """``residual(b, y) = b - A y`` for the symmetric A whose UPPER triangle is the f64 CSR matrix
    ``U`` (scipy, sorted, 0-based), by MKL's multi-threaded sparse product (``mkl_sparse_d_mv``,
    symmetric, upper fill) on U's own arrays: no copy, so values written into ``U.data`` in place
    are seen by the next product (the handle is deliberately not ``mkl_sparse_optimize``-d, which
    copies them).  One pass over U with MKL's threads, against scipy's two single-threaded ones
    (U y + U^T y - diag(U) y): at 128^2 about 0.5 ms against 1.1-2.5 ms.  Without MKL's
    inspector-executor entry points it falls back to scipy (:func:`engine.solvers.direct.upper_product`'s
    formula)."""

    def __init__(self, U, threads: int = 2):
        self.U = U
        self.n = U.shape[0]
        self._ia = np.ascontiguousarray(U.indptr, dtype=np.int32)
        self._ja = np.ascontiguousarray(U.indices, dtype=np.int32)
        if U.data.dtype != np.float64 or not U.data.flags.c_contiguous:
            raise ValueError("SymmetricUpper needs the f64 values of a CSR matrix, contiguous")
        self._handle = None
        lib = _mkl_library()
        _limit_threads(lib, threads)
        if not all(hasattr(lib, f) for f in ("mkl_sparse_d_create_csr", "mkl_sparse_d_mv", "mkl_sparse_destroy")):
            return
        i32 = ctypes.POINTER(ctypes.c_int32)
        handle = ctypes.c_void_p()
        status = lib.mkl_sparse_d_create_csr(ctypes.byref(handle), _INDEX_ZERO, self.n, self.n,
                                             self._ia.ctypes.data_as(i32), self._ia[1:].ctypes.data_as(i32),
                                             self._ja.ctypes.data_as(i32), U.data.ctypes.data_as(ctypes.c_void_p))
        if status != 0:
            return
        self._lib, self._handle, self._descr = lib, handle, _Descr(_SYMMETRIC, _FILL_UPPER, _DIAG_NON_UNIT)
        lib.mkl_sparse_d_mv.argtypes = [ctypes.c_int, ctypes.c_double, ctypes.c_void_p, _Descr, ctypes.c_void_p,
                                        ctypes.c_double, ctypes.c_void_p]

    @property
    def uses_mkl(self) -> bool:
        return self._handle is not None

    def residual(self, b: np.ndarray, y: np.ndarray) -> np.ndarray:
        """b - A y (f64, a new array)."""
        if self._handle is None:
            U = self.U
            return b - (U @ y + U.T @ y - U.diagonal() * y)
        out = np.array(b, dtype=np.float64)
        y = np.ascontiguousarray(y, dtype=np.float64)
        status = self._lib.mkl_sparse_d_mv(_NON_TRANSPOSE, -1.0, self._handle, self._descr, y.ctypes.data, 1.0,
                                           out.ctypes.data)
        if status != 0:
            raise PardisoError(f"MKL sparse product failed with status {status}")
        return out

    def __del__(self):
        try:
            if self._handle is not None:
                self._lib.mkl_sparse_destroy(self._handle)
        except Exception:
            pass


class PardisoError(RuntimeError):
    """PARDISO returned a non-zero error code (its number and phase in the message)."""


class Pardiso:
    """One PARDISO instance for the symmetric positive definite matrix whose UPPER triangle has
    the CSR pattern (``indptr``, ``indices``; 0-based, sorted, diagonal first in each row):
    ``analyse(values)`` (phase 11: ordering and symbolic factorisation, once per pattern),
    ``factorize(values) -> bool`` (phase 22; False when PARDISO reports a zero or negative pivot),
    ``solve(rhs) -> x`` (phase 33; f64 in and out whatever the precision).  ``single``: factorise
    and back-substitute in f32 (the values are copied to f32 at each factorisation).  Frees
    PARDISO's memory when dropped."""

    def __init__(self, indptr: np.ndarray, indices: np.ndarray, threads: int = 2, single: bool = False):
        self._lib = configured_solver(threads)   # loads MKL, holds pt, iparm and the entry point
        self.single = bool(single)
        self._lib.set_iparm(SINGLE_PRECISION_IPARM, 1 if self.single else 0)
        self.dtype = np.float32 if self.single else np.float64
        self.n = len(indptr) - 1
        self._ia = np.ascontiguousarray(np.asarray(indptr) + 1, dtype=np.int32)   # 1-based, once
        self._ja = np.ascontiguousarray(np.asarray(indices) + 1, dtype=np.int32)
        self._values = np.zeros(len(indices), dtype=self.dtype)
        self._b = np.zeros(self.n, dtype=self.dtype)
        self._x = np.zeros(self.n, dtype=self.dtype)
        self.analysed = False

    def _call(self, phase: int) -> int:
        error = ctypes.c_int32(0)
        i32 = ctypes.POINTER(ctypes.c_int32)
        lib = self._lib
        lib._mkl_pardiso(lib.pt.ctypes.data_as(ctypes.POINTER(lib._pt_type[0])),
                         ctypes.byref(ctypes.c_int32(1)), ctypes.byref(ctypes.c_int32(1)),   # maxfct, mnum
                         ctypes.byref(ctypes.c_int32(2)), ctypes.byref(ctypes.c_int32(phase)),   # mtype SPD
                         ctypes.byref(ctypes.c_int32(self.n)),
                         self._values.ctypes.data_as(ctypes.c_void_p), self._ia.ctypes.data_as(i32),
                         self._ja.ctypes.data_as(i32), lib.perm.ctypes.data_as(i32),
                         ctypes.byref(ctypes.c_int32(1)), lib.iparm.ctypes.data_as(i32),   # nrhs
                         ctypes.byref(ctypes.c_int32(0)),                                   # msglvl
                         self._b.ctypes.data_as(ctypes.c_void_p), self._x.ctypes.data_as(ctypes.c_void_p),
                         ctypes.byref(error))
        return int(error.value)

    def _set(self, values: np.ndarray) -> None:
        np.copyto(self._values, values, casting="same_kind")

    def analyse(self, values: np.ndarray) -> None:
        self._set(values)
        err = self._call(11)
        if err != 0:
            raise PardisoError(f"PARDISO analysis (phase 11) failed with error {err}")
        self.analysed = True

    def factorize(self, values: np.ndarray) -> bool:
        if not self.analysed:
            self.analyse(values)
        self._set(values)
        err = self._call(22)
        if err in (-4, -3):   # zero pivot / not positive definite (-4), reordering problem (-3)
            return False
        if err != 0:
            raise PardisoError(f"PARDISO factorisation (phase 22) failed with error {err}")
        return True

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        np.copyto(self._b, rhs, casting="same_kind")
        err = self._call(33)
        if err != 0:
            raise PardisoError(f"PARDISO back-substitution (phase 33) failed with error {err}")
        return self._x.astype(np.float64)

    def __del__(self):
        try:
            self._lib.free_memory(everything=True)
        except Exception:
            pass
