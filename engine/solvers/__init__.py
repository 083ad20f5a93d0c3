"""Linear solvers for the implicit integrator and the static solver.

Every Newton step of backward Euler (Baraff & Witkin 1998, section 5; see
:mod:`engine.integrators.implicit`) and of the static solver (:mod:`engine.statics`) solves

    A y = b,        A = a M + c H(x) [+ s H(x2)]                                           (L1)

with M the lumped (diagonal) mass matrix, H(x) the PSD-projected Hessian of all the model's
energies (springs (S4), bending Gauss-Newton; engine/energies/*.py; ``psd=False`` gives the
exact, possibly indefinite, Hessian) and scalars a >= 0, c > 0 (backward Euler:
a = 1/dt^2 + alpha/dt, c = 1 + beta/dt; statics: a = Levenberg mu, c = 1).  The optional
term s H_psd(x2) is backward Euler's stiffness damping beta/dt H(x_n) during later Newton
iterations (``extra=(s, x2)``).

Pinned vertices are handled exactly, as in Baraff & Witkin's *filtered* conjugate gradient
(section 5.3, the filter S that zeroes the constrained components): the unknowns of a
pinned vertex are fixed at y_i = 0 and its equations are dropped, i.e. we solve

    S A S y = S b,      S = diag(1 free, 0 pinned)                                         (L2)

which is the same as eliminating the pinned rows/columns and putting 1 on their diagonal.
The reported residual is the true relative residual over the free rows,

    residual = ||S (b - A y)|| / ||S b||         (0 if S b = 0)                           (L3)

Four names share one interface (:func:`make_solver`):

``pcg``       preconditioned conjugate gradient in Taichi kernels, matrix-free.  3x3 block-
              Jacobi preconditioner from each energy's add_hessian_diagonal (plus a m_i I).
              The code path is chosen per solve from the products the energies declare
              (``Energy.products``, engine/energies/base.py):
              * whole-loop (at most one "pair-gather" energy, e.g. springs, at most one
                "rank-one" energy, e.g. bending, and at most one "element-blocks" energy,
                e.g. a membrane, nothing else; psd; on one or two threads, or below
                SERIAL_BELOW vertices): the entire
                CG loop is one kernel: pair blocks K_e (hessian_blocks, once per solve),
                each pair's term computed once in a sweep over the vertices and added to both
                ends, the rank-one energy as its Gauss-Newton factors w_e (H_e = w_e w_e^T,
                gauss_newton_factors, once per solve) and the element blocks' products each
                added to their corners' sums as they are made (in the order of the pair and
                slot incidences, so the sums are the fused path's gathers bit for bit), dot
                products, axpys and the preconditioner fused.  No launch per iteration.  Below
                WHOLE_SPLIT_FROM vertices it is serial; from there it works on the mesh's two
                halves, two phases per iteration handed to the threads by tickets
                (engine.tickets), each half making the products of its own vertices; the dot
                products are sums of the halves' partial sums, so the result is the same on
                one thread or two.
              * fused parallel (same energies, larger meshes on more threads): three or four launches per
                iteration (per-element s_e = w_e . p and/or H_e p; per-vertex direction +
                product + p.q; step + preconditioner + r.z, r.r).
              * generic (any energies, exact Hessian, extra term): each energy's
                add_block_product ("blocks" energies, blocks computed once per solve) or
                add_hessian_product, 4 + per-energy launches.
              When the recurrence says "converged" the true residual (L3) is computed and,
              if it drifted above the tolerance, CG restarts from the current y (residual
              replacement).
``cholesky``  direct sparse LL^T (Eigen, ``ti.linalg.SparseSolver``, f64) of A assembled from
              the per-element blocks by ``ti.linalg.SparseMatrixBuilder(dtype=ti.f64)``
              (:mod:`engine.solvers.assembly`: one kernel template for every stencil energy, reading
              the energy's blocks through its ``block`` ti.func; the builder's default is f32
              and it never checks its capacity, so the triplet capacity is computed exactly).
              Only the lower triangle is written (Eigen's LL^T reads nothing else):
              6k + 9k(k-1)/2 triplets per k-vertex element instead of 9k^2 (21 per spring,
              78 per hinge), 3 per vertex; twice the element part with an extra term.  That
              halves assembly (64x64 cloth: 65 -> ~35 ms).  The pattern is analysed once per
              model (cached on the solver), the numbers are factorised on every solve.  The
              residual (L3) is checked with a matrix-free product; up to two steps of
              iterative refinement are taken if it is above the tolerance.
``pardiso``   direct sparse LL^T with MKL PARDISO (supernodal, nested dissection, multi-threaded;
              the optional ``fast`` extra: pypardiso + mkl, x86-64), called through its C entry
              point with index arrays made once (:mod:`engine.solvers.pardiso`).  The UPPER triangle
              of A is written into a CSR pattern fixed per model
              (:class:`engine.solvers.assembly.CSRPattern`, numpy set-up once) by one gather kernel
              per energy (a parallel loop over block rows, each row written by one thread: no
              atomics, bitwise reproducible); the symbolic analysis (ordering, elimination tree) is
              done once per model and only the numeric factorisation per solve.  Mixed precision by
              default: PARDISO factorises and back-substitutes in f32 and the solution is refined in
              f64 against the f64 matrix until the residual (L3) is at or below the tolerance; when
              f32 cannot get there (its factorisation fails, refinement stalls: cond(A) near
              1/eps_f32) the same matrix is factorised in f64 (``precision="double"``: always).
``direct``    pardiso when it can be loaded, cholesky otherwise (the name the benchmark and the
              explicit-vs-implicit lesson use for "the fastest direct solve installed").

Both direct solvers share :class:`DirectSolver` (the residual check and iterative refinement)
and report ``last_timings`` (assembly, factorization, solve seconds of the last solve).

A solve that ends above the tolerance (or a failed factorisation, or p.Ap <= 0 in CG) is
reported (``LinearSolveInfo.converged`` False, ``message``) and callers raise
:class:`SolverError` (``info.check()``); it is never silently accepted.

Interface (``x``, ``b``, ``y`` are vec3 ndarrays with one entry per model vertex)::

    solver = make_solver("pcg" | "cholesky" | "pardiso" | "direct", tol=1e-8, max_iter=1000)
    info = solver.solve(model, x, b, y, mass_coef=a, hess_coef=c, psd=True, extra=None)
    info.iterations, info.residual, info.converged; info.check()     # raises SolverError

``y`` is overwritten (0 on pinned vertices); b on pinned vertices is ignored.
:func:`apply_system` computes S A p matrix-free (tests, residual checks).

Measured (2-core CPU, f64, 2 threads, 64x64 cloth: 4096 vertices, 12033 springs, 11781
hinges, dt = 1/60 s = 53x the explicit limit; shared machine, load ~3, medians): one
backward-Euler step (1 Newton iteration) with pcg tol 1e-8 ~260 ms (~710 CG iterations,
0.36 ms each), pcg tol 1e-5 ~240 ms (~540 iterations), cholesky ~230 ms (factorisation
~170-280 ms of it, assembly ~35 ms).  Block-Jacobi CG needs O(sqrt(1 + w_max^2 dt^2))
iterations, so it wins for small dt / loose tolerances and loses for large dt.
"""

from engine.constants import SOLVERS
from engine.solvers.assembly import triplet_capacity
from engine.solvers.direct import (PARDISO_IPARMS, CholeskySolver, DirectSolver, PardisoSolver, pardiso_available,
                                   upper_product)
from engine.solvers.operator import LinearSolveInfo, LinearSolver, SolverError, apply_system
from engine.solvers.pcg import PCGSolver

__all__ = ["SolverError", "LinearSolveInfo", "LinearSolver", "PCGSolver", "DirectSolver", "CholeskySolver",
           "PardisoSolver", "SOLVERS", "PARDISO_IPARMS", "pardiso_available", "make_solver", "apply_system",
           "triplet_capacity", "upper_product"]


def make_solver(name: str = "pcg", tol: float = 1e-8, max_iter: int = 1000) -> LinearSolver:
    """A linear solver by name: ``"pcg"`` (matrix-free, Taichi kernels), ``"cholesky"`` (sparse
    direct, Eigen LL^T), ``"pardiso"`` (sparse direct, MKL PARDISO; ValueError when it is not
    installed) or ``"direct"`` (pardiso if installed, else cholesky).  ``tol``: relative residual (L3); ``max_iter``: CG iteration
    limit (cholesky ignores it).  ValueError (one line) for an unknown name."""
    if isinstance(name, LinearSolver):
        return name
    if name == "pcg":
        return PCGSolver(tol, max_iter)
    if name == "cholesky":
        return CholeskySolver(tol, max_iter)
    if name == "pardiso":
        return PardisoSolver(tol, max_iter)
    if name == "direct":
        return PardisoSolver(tol, max_iter) if pardiso_available() else CholeskySolver(tol, max_iter)
    raise ValueError(f"unknown linear solver {name!r}; valid names: {', '.join(SOLVERS)}")
