"""The shared Taichi engine: rod, meshes, energies, integrators, solvers (physics only: no rerun, no output files, no lesson code)."""
import os as _os

# Keep Taichi quiet on import (before any engine module imports taichi).
_os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "0")
_os.environ.setdefault("TI_SKIP_VERSION_CHECK", "ON")

# BLAS worker threads sleep as soon as a call ends (OpenBLAS, numpy's and scipy's BLAS, otherwise
# busy-waits 2^28 cycles, about 0.1 s, after each threaded call). With as many threads as cores, the
# spinning thread takes a core from the Taichi kernels or the PARDISO factorisation that follow:
# a 128^2 cloth's factorisation took 120-140 ms right after np.linalg.norm of its 49k-entry
# right-hand side against 70-75 ms without the spin. Read once, when OpenBLAS loads (numpy's
# import): the lessons' and the bench's packages import this module first; a value the user set is
# kept.
_os.environ.setdefault("OPENBLAS_THREAD_TIMEOUT", "4")
