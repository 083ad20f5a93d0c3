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
              * whole-loop (at most one "pair-gather" energy, e.g. springs, and at most one
                "rank-one" energy, e.g. bending, nothing else; psd; below SERIAL_BELOW
                vertices): the entire CG loop is one serial kernel: pair blocks K_e
                (hessian_blocks, once per solve) gathered per vertex over the energy's
                pair_incidence, the rank-one energy as its Gauss-Newton factors w_e
                (H_e = w_e w_e^T, gauss_newton_factors, once per solve) gathered over its
                slot_incidence, dot products, axpys and the preconditioner fused.  No launch
                per iteration.
              * fused parallel (same energies, larger meshes): three launches per iteration
                (per-element s_e = w_e . p; per-vertex direction + product + p.q; step +
                preconditioner + r.z, r.r).
              * generic (any energies, exact Hessian, extra term): each energy's
                add_block_product ("blocks" energies, blocks computed once per solve) or
                add_hessian_product, 4 + per-energy launches.
              When the recurrence says "converged" the true residual (L3) is computed and,
              if it drifted above the tolerance, CG restarts from the current y (residual
              replacement).
``cholesky``  direct sparse LL^T (Eigen, ``ti.linalg.SparseSolver``, f64) of A assembled from
              the per-element blocks by ``ti.linalg.SparseMatrixBuilder(dtype=ti.f64)``
              (:mod:`engine.assembly`: one kernel template for every stencil energy, reading
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
              the optional ``fast`` extra: pypardiso + mkl, x86-64).  The UPPER triangle of A is
              written into a CSR pattern fixed per model (:class:`engine.assembly.CSRPattern`,
              numpy set-up once) by one gather kernel per energy (a parallel loop over block
              rows, each row written by one thread: no atomics, bitwise reproducible); the
              symbolic analysis (ordering, elimination tree) is done once per model and only
              the numeric factorisation per solve.  Residual check and refinement as cholesky.
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

import math
import time
import weakref
from typing import NamedTuple

import numpy as np
import taichi as ti

from engine.assembly import CSRPattern, assemble_energy, assemble_mass, assemble_rows, init_rows, triplet_capacity
from engine.constants import SERIAL_BELOW
from engine.fields import (axpy_inplace, float_dtype, free_dot, int_array, int_array2, mat3_array, scalar_array,
                           scratch_vec3, vec3_array, vec3_array2, vec3_ndarray, zero_pinned, zero_vec3)
from engine.model import Model

__all__ = ["SolverError", "LinearSolveInfo", "LinearSolver", "PCGSolver", "DirectSolver", "CholeskySolver", "PardisoSolver", "SOLVERS",
           "pardiso_available",
           "make_solver", "apply_system", "triplet_capacity"]

SOLVERS = ("pcg", "cholesky", "pardiso", "direct")


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
# Kernels: matrix-free operator pieces and PCG (pinned vertices: inv_mass == 0)
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


@ti.kernel
def _residual_norms(b: vec3_array, q: vec3_array, inv_mass: scalar_array, c: float) -> ti.math.vec2:
    # (|S(b - c q)|^2, |S b|^2)   (L3), q = A' y with A = c A'
    acc = ti.math.vec2(0.0)
    for i in range(b.shape[0]):
        if inv_mass[i] > 0.0:
            d = b[i] - c * q[i]
            acc += ti.math.vec2(d.dot(d), b[i].dot(b[i]))
    return acc


@ti.kernel
def _diag_init(mass: scalar_array, a: float, D: mat3_array):
    # D_i = a m_i I  (the energies add their 3x3 diagonal blocks H_ii)
    for i in range(mass.shape[0]):
        D[i] = a * mass[i] * ti.math.mat3(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)


@ti.kernel
def _diag_invert(D: mat3_array, inv_mass: scalar_array):
    # block Jacobi: D_i <- D_i^-1 (free, SPD block); scalar Jacobi if the block is singular; 0 if pinned
    for i in range(D.shape[0]):
        B = D[i]
        Binv = ti.math.mat3(0.0)
        if inv_mass[i] > 0.0:
            det = B.determinant()
            scale = ti.abs(B[0, 0]) + ti.abs(B[1, 1]) + ti.abs(B[2, 2])
            if det > 1e-12 * scale * scale * scale and scale > 0.0:
                Binv = B.inverse()
            else:
                for k in ti.static(range(3)):
                    if B[k, k] > 0.0:
                        Binv[k, k] = 1.0 / B[k, k]
        D[i] = Binv


@ti.kernel
def _pcg_restart(b: vec3_array, q: vec3_array, inv_mass: scalar_array, c: float, Pinv: mat3_array,
                 mass: scalar_array, a: float, r: vec3_array, z: vec3_array, p: vec3_array) -> ti.math.vec2:
    # on entry q = A' y:  r = S(b/c - q), z = P^-1 r, p = z, q = a' M p; returns (r.z, r.r)
    acc = ti.math.vec2(0.0)
    for i in range(b.shape[0]):
        ri = ti.math.vec3(0.0)
        if inv_mass[i] > 0.0:
            ri = b[i] / c - q[i]
        zi = Pinv[i] @ ri
        r[i] = ri
        z[i] = zi
        p[i] = zi
        q[i] = a * mass[i] * zi
        acc += ti.math.vec2(ri.dot(zi), ri.dot(ri))
    return acc


@ti.kernel
def _pcg_direction(beta: float, z: vec3_array, p: vec3_array, mass: scalar_array, a: float, q: vec3_array,
                   serial: ti.template()):
    # p = z + beta p ; q = a M p   (p, z are 0 on pinned vertices)
    ti.loop_config(serialize=serial)
    for i in range(p.shape[0]):
        pi = z[i] + beta * p[i]
        p[i] = pi
        q[i] = a * mass[i] * pi


@ti.func
def _step_vertex(i, alpha, p: ti.template(), q: ti.template(), Pinv: ti.template(), y: ti.template(),
                 r: ti.template(), z: ti.template()):
    # free vertex i: y_i += alpha p_i ; r_i -= alpha q_i ; z_i = P_i^-1 r_i ; returns (r_i.z_i, r_i.r_i)
    y[i] += alpha * p[i]
    ri = r[i] - alpha * q[i]
    zi = Pinv[i] @ ri
    r[i] = ri
    z[i] = zi
    return ti.math.vec2(ri.dot(zi), ri.dot(ri))


@ti.func
def _add_rank_one(qi, i, b_off: ti.template(), b_ent: ti.template(), w: ti.template(), s: ti.template(),
                  k: ti.template()):
    # qi + sum_{(e, slot) ~ i} s_e w_e,slot over the incidence (entry = k e + slot), summed in that order
    for j in range(b_off[i], b_off[i + 1]):
        ent = b_ent[j]
        qi += s[ent // k] * w[ent // k, ent % k]
    return qi


@ti.kernel
def _pcg_step(alpha: float, p: vec3_array, q: vec3_array, inv_mass: scalar_array, Pinv: mat3_array,
              y: vec3_array, r: vec3_array, z: vec3_array, serial: ti.template()) -> ti.math.vec2:
    # y += alpha p ; r -= alpha S q ; z = P^-1 r ; returns (r.z, r.r)
    acc = ti.math.vec2(0.0)
    ti.loop_config(serialize=serial)
    for i in range(p.shape[0]):
        if inv_mass[i] > 0.0:
            acc += _step_vertex(i, alpha, p, q, Pinv, y, r, z)
    return acc


@ti.kernel
def _rank_one_s(w: vec3_array2, elements: int_array2, z: vec3_array, p: vec3_array, beta: float, s: scalar_array,
                k: ti.template(), serial: ti.template()):
    # s_e = w_e . (z + beta p) over the element's k vertices (the new direction, formed on the fly)
    ti.loop_config(serialize=serial)
    for e in range(elements.shape[0]):
        acc = 0.0
        for a in ti.static(range(k)):
            v = elements[e, a]
            acc += w[e, a].dot(z[v] + beta * p[v])
        s[e] = acc


@ti.kernel
def _fused_direction_product(beta: float, z: vec3_array, p: vec3_array, p_new: vec3_array, q: vec3_array,
                             mass: scalar_array, inv_mass: scalar_array, a: float,
                             s_off: int_array, s_edge: int_array, s_other: int_array, s_blocks: mat3_array,
                             b_off: int_array, b_ent: int_array, w: vec3_array2, s: scalar_array,
                             k: ti.template(), serial: ti.template()) -> float:
    # p_new = z + beta p ; q = a' M p_new + sum_{e ~ i} K_e (p_new_i - p_new_j) + sum_{(e, slot) ~ i} s_e w_e,slot
    # (pair-gather blocks, e.g. springs (S4); rank-one k-vertex elements, e.g. hinges); returns p_new . q over
    # free vertices.  p and p_new are different buffers, so the neighbours' new directions are formed
    # from (z, p) without a race.
    acc = 0.0
    ti.loop_config(serialize=serial)
    for i in range(z.shape[0]):
        pi = z[i] + beta * p[i]
        qi = a * mass[i] * pi
        for m in range(s_off[i], s_off[i + 1]):
            j = s_other[m]
            qi += s_blocks[s_edge[m]] @ (pi - (z[j] + beta * p[j]))
        qi = _add_rank_one(qi, i, b_off, b_ent, w, s, k)
        p_new[i] = pi
        q[i] = qi
        if inv_mass[i] > 0.0:
            acc += pi.dot(qi)
    return acc


@ti.kernel
def _pcg_whole_serial(beta0: float, rz0: float, target2: float, max_iter: ti.i32,
                      z: vec3_array, p: vec3_array, q: vec3_array, r: vec3_array, y: vec3_array,
                      mass: scalar_array, inv_mass: scalar_array, a: float, Pinv: mat3_array,
                      s_off: int_array, s_edge: int_array, s_other: int_array, s_blocks: mat3_array,
                      elements: int_array2, n_elements: ti.i32, b_off: int_array, b_ent: int_array,
                      w: vec3_array2, s: scalar_array, k: ti.template()) -> ti.math.vec3:
    # The whole CG loop in one serial kernel (small problems: no launch or argument overhead per
    # iteration).  Starts from r, z, p set by _pcg_restart (beta0 = 0).  Same arithmetic as the
    # fused path: p = z + beta p ; q = A' p ; alpha = r.z / p.q ; y += alpha p ; r -= alpha q ;
    # z = P^-1 r.  Returns (iterations, r.r, 1 if p.q <= 0 else 0).
    n = z.shape[0]
    rz = rz0
    beta = beta0
    rr = target2 + 1.0
    it = 0
    bad = 0
    ti.loop_config(serialize=True)
    for _ in range(max_iter):
        for i in range(n):
            p[i] = z[i] + beta * p[i]
        for e in range(n_elements):
            acc = 0.0
            for sl in ti.static(range(k)):
                acc += w[e, sl].dot(p[elements[e, sl]])
            s[e] = acc
        pq = 0.0
        for i in range(n):
            pi = p[i]
            qi = a * mass[i] * pi
            for m in range(s_off[i], s_off[i + 1]):
                qi += s_blocks[s_edge[m]] @ (pi - p[s_other[m]])
            qi = _add_rank_one(qi, i, b_off, b_ent, w, s, k)
            q[i] = qi
            if inv_mass[i] > 0.0:
                pq += pi.dot(qi)
        if pq <= 0.0:
            bad = 1
            break
        alpha = rz / pq
        acc2 = ti.math.vec2(0.0)
        for i in range(n):
            if inv_mass[i] > 0.0:
                acc2 += _step_vertex(i, alpha, p, q, Pinv, y, r, z)
        rz_new = acc2[0]
        rr = acc2[1]
        it += 1
        if rr <= target2:
            break
        beta = rz_new / rz
        rz = rz_new
    return ti.math.vec3(it, rr, bad)


# --------------------------------------------------------------------------------------------
# Operator helpers
# --------------------------------------------------------------------------------------------

def _hessian_plan(model: Model, x, psd: bool = True, extra=None, blocks: dict | None = None):
    """One callable per energy, ``add(p, q)``: q += H_e(x) p with the PSD (or exact) Hessian.
    Energies offering the "blocks" product (springs) compute their blocks here, once per solve
    (and put them in ``blocks[id(energy)]`` if a dict is given); the others use
    add_hessian_product.  ``extra`` = (s, x2) appends q += s H_psd(x2) p (matrix-free, through a
    scratch array)."""
    plan = []
    if extra is not None and extra[0] != 0.0:
        s, x2 = float(extra[0]), extra[1]
        t = scratch_vec3(model, "linalg_extra")

        def add_extra(p, q):
            zero_vec3(t)
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


def _scaled(extra, c: float):
    """extra = (s, x2) of A = a M + c H(x) + s H(x2), as seen in A' = A / c; None if absent."""
    if extra is None or float(extra[0]) == 0.0:
        return None
    return float(extra[0]) / c, extra[1]


def _apply_plan(model: Model, plan, a: float, p, q) -> None:
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
    _apply_plan(model, _hessian_plan(model, x, psd, _scaled(extra, c)), float(mass_coef) / c, p, q)
    _filtered_scale(q, model.inv_mass_nd, c)


# --------------------------------------------------------------------------------------------
# Solvers
# --------------------------------------------------------------------------------------------

class LinearSolver:
    """Base class: ``solve(model, x, b, y, mass_coef, hess_coef=1.0) -> LinearSolveInfo`` solves
    (L1)-(L2) for y (overwritten; 0 on pinned vertices).  ``tol`` is the relative residual (L3)
    to reach, ``max_iter`` the iteration limit.  Work arrays are cached per model."""

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
        self._cache: "weakref.WeakKeyDictionary[Model, dict]" = weakref.WeakKeyDictionary()
        self.last_info: LinearSolveInfo | None = None

    def solve(self, model: Model, x, b, y, mass_coef: float, hess_coef: float = 1.0,
              psd: bool = True, extra=None) -> LinearSolveInfo:
        raise NotImplementedError

    def _entry(self, model: Model) -> dict:
        """Per-model cache, rebuilt if the model's energy list changed."""
        key = tuple((id(e), e.n_elements) for e in model.energies)
        entry = self._cache.get(model)
        if entry is None or entry["key"] != key:
            entry = {"key": key}
            self._cache[model] = entry
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


class PCGSolver(LinearSolver):
    """Matrix-free block-Jacobi preconditioned CG with Baraff-Witkin filtering (module docstring).

    Fast paths (``fused=True``), used when the model's energies are at most one declaring the
    "pair-gather" product (springs) and at most one declaring "rank-one" (bending), nothing else,
    and psd=True: below SERIAL_BELOW vertices (or ``serial=True``) the whole CG loop is one serial
    kernel; otherwise three parallel launches per iteration (per-element s_e = w_e . p with the
    rank-one Gauss-Newton Hessian H_e = w_e w_e^T; per-vertex direction p = z + beta p,
    q = a' M p + sum_pairs K_e (p_i - p_j) + sum_elements s_e w_e,slot and p.q; step +
    preconditioner + r.z, r.r).  Otherwise (other energies, psd=False, an extra term,
    ``fused=False``) the generic path calls each energy's block or Hessian-vector product
    (4 + per-energy launches per iteration)."""

    name = "pcg"

    def __init__(self, tol: float = 1e-8, max_iter: int = 1000, fused: bool = True, serial: bool | None = None):
        super().__init__(tol, max_iter)
        self.fused = bool(fused)
        self.serial = serial  # None: serial loops below SERIAL_BELOW vertices

    def _work(self, model: Model) -> dict:
        entry = self._entry(model)
        if "r" not in entry:
            n = model.n
            entry.update(r=vec3_ndarray(n), z=vec3_ndarray(n), p=vec3_ndarray(n), p2=vec3_ndarray(n),
                         q=vec3_ndarray(n), Pinv=ti.ndarray(dtype=ti.math.mat3, shape=n))
        return entry

    def _fused_setup(self, model: Model, entry: dict, x, psd: bool, blocks: dict):
        """Arguments of the fused kernels, or None if the fast path does not apply:
        (pair-gather energy's (offsets, inc_edge, inc_other, blocks), with the blocks the plan
        computed; the rank-one work dict: elements, n elements, k, incidence off/ent, factors w
        from gauss_newton_factors, scratch s).  A missing energy gets empty stand-ins (n = 0)."""
        if not (self.fused and psd):
            return None
        pairs = [e for e in model.energies if "pair-gather" in e.products]
        ranks = [e for e in model.energies if "rank-one" in e.products and "pair-gather" not in e.products]
        if len(pairs) + len(ranks) != len(model.energies) or len(pairs) > 1 or len(ranks) > 1:
            return None
        if "no_pair" not in entry:
            off = ti.ndarray(dtype=ti.i32, shape=model.n + 1)  # zeros: no incidences
            i1 = ti.ndarray(dtype=ti.i32, shape=1)
            entry["no_pair"] = (off, i1, i1, ti.ndarray(dtype=ti.math.mat3, shape=1))
            entry["no_rank"] = dict(elements=ti.ndarray(dtype=ti.i32, shape=(1, 1)), n=0, k=1, off=off, ent=i1,
                                    w=ti.ndarray(dtype=ti.math.vec3, shape=(1, 1)), s=ti.ndarray(dtype=float, shape=1))
        pair = entry["no_pair"]
        if pairs and pairs[0].n_elements:
            pair = (*pairs[0].pair_incidence, blocks[id(pairs[0])])
        rank = entry["no_rank"]
        if ranks and ranks[0].n_elements:
            e = ranks[0]
            key = ("rank-one", id(e))
            if key not in entry:
                m, k = e.n_elements, e.stencil_size
                off, ent = e.slot_incidence
                entry[key] = dict(elements=e.elements, n=m, k=k, off=off, ent=ent,
                                  w=ti.ndarray(dtype=ti.math.vec3, shape=(m, k)), s=ti.ndarray(dtype=float, shape=m))
            rank = entry[key]
            e.gauss_newton_factors(x, rank["w"])
        return pair, rank

    def solve(self, model: Model, x, b, y, mass_coef: float, hess_coef: float = 1.0,
              psd: bool = True, extra=None) -> LinearSolveInfo:
        a, c = self._coefficients(mass_coef, hess_coef)
        w = self._work(model)
        r, z, q, Pinv = w["r"], w["z"], w["q"], w["Pinv"]
        p, p2 = w["p"], w["p2"]
        inv_mass, mass = model.inv_mass_nd, model.mass_nd
        a_s = a / c  # solve A' y = b / c with A' = a' M + H
        blocks = {}
        plan = _hessian_plan(model, x, psd, _scaled(extra, c), blocks)
        fused = None if _scaled(extra, c) is not None else self._fused_setup(model, w, x, psd, blocks)
        serial = self.serial if self.serial is not None else model.n < SERIAL_BELOW
        whole = fused is not None and serial  # the whole CG loop in one serial kernel

        # block-Jacobi preconditioner P = blockdiag(a' m_i I + H_ii)
        _diag_init(mass, a_s, Pinv)
        for e in model.energies:
            try:
                e.add_hessian_diagonal(x, Pinv, psd)
            except NotImplementedError:
                pass  # that energy is left out of the preconditioner (still correct, slower)
        _diag_invert(Pinv, inv_mass)

        zero_vec3(y)
        zero_vec3(q)
        rz, rr = _pcg_restart(b, q, inv_mass, c, Pinv, mass, a_s, r, z, p)
        bb = rr  # |S b / c|^2
        if bb == 0.0:
            return self._info(0, 0.0)
        target2 = (0.5 * self.tol) ** 2 * bb  # the recurrence aims at tol/2 (margin for drift)
        it = 0
        message = ""
        while True:
            beta = 0.0  # after a (re)start: p = z
            if whole and it < self.max_iter and rr > target2:
                pair, rk = fused
                k_it, rr, bad = _pcg_whole_serial(0.0, rz, target2, self.max_iter - it, z, p, q, r, y, mass,
                                                  inv_mass, a_s, Pinv, *pair, rk["elements"], rk["n"], rk["off"],
                                                  rk["ent"], rk["w"], rk["s"], rk["k"])
                it += int(k_it)
                if bad:
                    message = "A is not positive definite on a search direction (p.Ap <= 0)"
            while not whole and it < self.max_iter and rr > target2:
                if fused is not None:
                    pair, rk = fused
                    if rk["n"]:
                        _rank_one_s(rk["w"], rk["elements"], z, p, beta, rk["s"], rk["k"], serial)
                    pq = _fused_direction_product(beta, z, p, p2, q, mass, inv_mass, a_s, *pair, rk["off"],
                                                  rk["ent"], rk["w"], rk["s"], rk["k"], serial)
                    p, p2 = p2, p
                else:
                    _pcg_direction(beta, z, p, mass, a_s, q, serial)  # p = z + beta p ; q = a' M p
                    for add in plan:                          # q += H p
                        add(p, q)
                    pq = free_dot(p, q, inv_mass, serial)
                if not (pq > 0.0):
                    message = f"A is not positive definite on the search direction (p.Ap = {pq:.3e})"
                    break
                rz_new, rr = _pcg_step(rz / pq, p, q, inv_mass, Pinv, y, r, z, serial)
                it += 1
                beta = rz_new / rz
                rz = rz_new
            # true residual (L3); if the recurrence drifted above tol, restart from y
            _apply_plan(model, plan, a_s, y, q)
            res2, _ = _residual_norms(b, q, inv_mass, c)
            residual = math.sqrt(res2 / (bb * c * c))
            if residual <= self.tol or it >= self.max_iter or message:
                break
            rz, rr = _pcg_restart(b, q, inv_mass, c, Pinv, mass, a_s, r, z, p)
        zero_pinned(y, inv_mass)
        return self._info(it, residual, message)


def upper_product(U, y: np.ndarray, diag: np.ndarray | None = None) -> np.ndarray:
    """A y for the symmetric A stored as its upper triangle U (scipy CSR), without building A:
    U y + U^T y - diag(U) y.  ``diag``: U's diagonal when already at hand."""
    return U @ y + U.T @ y - (U.diagonal() if diag is None else diag) * y


def _norm(a: np.ndarray) -> float:
    """|a| without BLAS: numpy's threaded ddot leaves an OpenBLAS thread spinning on the second
    core for ~0.1 s (unless OPENBLAS_THREAD_TIMEOUT was set before numpy loaded, see
    engine/__init__.py), which slowed the factorisation that follows by ~1.7x."""
    return math.sqrt(float(np.square(a).sum()))


class DirectSolver(LinearSolver):
    """A sparse direct solve of (L1)-(L2), shared by the backends: assemble A' = A/c, factorise,
    back-substitute, then check the residual (L3) with the matrix-free product and take up to
    ``refinements`` steps of iterative refinement while it is above the tolerance.  A subclass
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

    def _product(self, model: Model, entry: dict, x, a_s: float, psd: bool, extra):
        """``product(sol, y) -> A' sol`` (numpy, 3n) for the residual check; ``y`` holds sol as a
        vec3 ndarray.  Here the matrix-free operator (L1) in Taichi kernels."""
        plan = _hessian_plan(model, x, psd, extra)
        q = entry["q"]

        def product(sol, y):
            _apply_plan(model, plan, a_s, y, q)
            return q.to_numpy().astype(np.float64).reshape(-1)
        return product

    def solve(self, model: Model, x, b, y, mass_coef: float, hess_coef: float = 1.0,
              psd: bool = True, extra=None) -> LinearSolveInfo:
        a, c = self._coefficients(mass_coef, hess_coef)
        entry = self._setup(model)
        t0 = time.perf_counter()
        ok = self._factorize(model, entry, x, a / c, psd, _scaled(extra, c))
        t1 = time.perf_counter()
        self.last_timings = {"assembly": entry.pop("_assembly_s", 0.0), "factorization": t1 - t0, "solve": 0.0}
        self.last_timings["factorization"] -= self.last_timings["assembly"]
        if not ok:
            zero_vec3(y)
            return self._info(1, math.inf, f"{self.name} factorization failed (matrix not positive definite)")
        free = entry["free_dofs"]
        rhs = np.asarray(b.to_numpy(), dtype=np.float64).reshape(-1) / c
        rhs[~free] = 0.0
        bnorm = _norm(rhs)
        if bnorm == 0.0:
            zero_vec3(y)
            return self._info(0, 0.0)
        sol = np.asarray(self._backsolve(entry, rhs), dtype=np.float64).reshape(-1)
        y.from_numpy(sol.reshape(-1, 3).astype(float_dtype()))
        product = self._product(model, entry, x, a / c, psd, _scaled(extra, c))
        it = 1
        while True:
            res = rhs - product(sol, y)  # rhs - A' sol
            res[~free] = 0.0
            residual = _norm(res) / bnorm
            if residual <= self.tol or it > self.refinements or not np.isfinite(residual):
                break
            sol = sol + np.asarray(self._backsolve(entry, res), dtype=np.float64).reshape(-1)  # refinement
            y.from_numpy(sol.reshape(-1, 3).astype(float_dtype()))
            it += 1
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
        extra = _scaled(extra, c)
        if extra is None:
            B = entry["builder"]
        else:  # the same pattern with every element block written twice
            if "builder2" not in entry:
                N = 3 * model.n
                entry["builder2"] = ti.linalg.SparseMatrixBuilder(
                    N, N, max_num_triplets=2 * entry["capacity"] - 3 * model.n, dtype=ti.f64)
            B = entry["builder2"]
        assemble_mass(B, model.mass_nd, model.inv_mass_nd, a_s)
        terms = [(1.0, x, psd)] if extra is None else [(extra[0], extra[1], True), (1.0, x, psd)]
        for scale, xx, ps in terms:
            for e in model.energies:
                if e.n_elements:
                    assemble_energy(B, e, e.hessian_blocks(xx, ps), model.inv_mass_nd, scale)
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


# PARDISO's settings (1-based iparm, value): user iparms, METIS nested dissection, no iterative
# refinement inside (the caller checks and refines), pivot perturbation 1e-8, no weighted matching,
# the default factorisation kernel, no matrix check, CSR (not transposed)
PARDISO_IPARMS = ((1, 1), (2, 2), (8, 0), (10, 8), (13, 0), (24, 0), (27, 0), (12, 0))


class _Pardiso:
    """One MKL PARDISO instance (through pypardiso's ctypes binding) for a fixed CSR pattern:
    real symmetric positive definite (mtype 2), nested-dissection ordering; the symbolic
    analysis (phase 11) once, the numeric factorisation (phase 22) per solve, back-substitution
    (phase 33).  Frees its memory when dropped."""

    def __init__(self, matrix, threads: int):
        import ctypes
        _quiet_openmp()
        import pypardiso
        self.S = pypardiso.PyPardisoSolver(mtype=2)
        for i, v in PARDISO_IPARMS:
            self.S.set_iparm(i, v)
        for name in ("MKL_Set_Num_Threads", "mkl_set_num_threads"):
            fn = getattr(self.S.libmkl, name, None)
            if fn is not None:
                fn(ctypes.c_int(int(threads)))
                break
        self.A = matrix
        self._zero = np.zeros((matrix.shape[0], 1))
        self._call(11)

    def _call(self, phase: int, b=None):
        self.S.set_phase(phase)
        return self.S._call_pardiso(self.A, self._zero if b is None else np.asfortranarray(b.reshape(-1, 1)))

    def factorize(self) -> bool:
        import pypardiso
        try:
            self._call(22)
        except pypardiso.pardiso_wrapper.PyPardisoError:
            return False
        return True

    def solve(self, rhs):
        return self._call(33, rhs).reshape(-1)

    def __del__(self):
        try:
            self.S.free_memory(everything=True)
        except Exception:
            pass


def _quiet_openmp() -> None:
    """MKL's OpenMP threads sleep as soon as a factorisation ends instead of spinning for 200 ms
    (KMP_BLOCKTIME's default): the Taichi kernels that follow (assembly, the residual check) need
    the same two cores.  Measured on the 64^2 cloth, one solve: 188-228 ms against 250-270 ms.
    Must be set before MKL's OpenMP runtime starts; a value the user set is kept."""
    import os
    os.environ.setdefault("KMP_BLOCKTIME", "0")


def pardiso_available() -> bool:
    """True when MKL PARDISO can be loaded (the optional ``fast`` extra: pypardiso + mkl)."""
    global _PARDISO_OK
    if _PARDISO_OK is None:
        _quiet_openmp()
        try:
            import pypardiso
            pypardiso.PyPardisoSolver()
            _PARDISO_OK = True
        except Exception:
            _PARDISO_OK = False
    return _PARDISO_OK


_PARDISO_OK: bool | None = None


class PardisoSolver(DirectSolver):
    """Sparse LL^T with MKL PARDISO (supernodal, multi-threaded).  The upper triangle of A' is
    assembled into a CSR pattern fixed per model (:class:`engine.assembly.CSRPattern`: one gather
    kernel per energy, a parallel loop over block rows, no atomics, bitwise reproducible), the
    symbolic analysis is done once per model and only the numeric factorisation per solve."""

    name = "pardiso"

    def __init__(self, tol: float = 1e-8, max_iter: int = 1000, refinements: int = 2):
        if not pardiso_available():
            raise ValueError("solver 'pardiso' needs MKL PARDISO, which is not installed: "
                             "pip install 'elastic-lessons[fast]' (x86-64), or use solver 'direct' or 'cholesky'")
        super().__init__(tol, max_iter, refinements)

    def _setup(self, model: Model) -> dict:
        entry = super()._setup(model)
        if "pattern" not in entry:
            import scipy.sparse
            from engine.runtime import current
            pattern = CSRPattern(model)
            values = np.zeros(pattern.nnz, dtype=np.float64)
            N = 3 * model.n
            A = scipy.sparse.csr_matrix((values, pattern.indices, pattern.indptr), shape=(N, N), copy=False)
            A.has_sorted_indices = True
            entry["pattern"], entry["matrix"] = pattern, A
            info = current()
            entry["_pardiso_threads"] = info.threads if info is not None else 2
        return entry

    def assemble_values(self, model: Model, entry: dict, x, a_s: float, psd: bool, extra) -> np.ndarray:
        """Write the values of A' (P1) at x into the pattern's CSR values; returns them (numpy)."""
        pattern, A = entry["pattern"], entry["matrix"]
        values = A.data  # the kernels write the CSR values in place (a numpy array: no copy on the CPU)
        init_rows(values, pattern.indptr_nd, model.mass_nd, model.inv_mass_nd, a_s)
        terms = [(1.0, x, psd)] if extra is None else [(extra[0], extra[1], True), (1.0, x, psd)]
        for scale, xx, ps in terms:
            for e in model.energies:
                if e.n_elements:
                    assemble_rows(pattern, values, e, e.hessian_blocks(xx, ps), scale)
        ti.sync()
        return values

    def _factorize(self, model, entry, x, a_s, psd, extra) -> bool:
        t0 = time.perf_counter()
        self.assemble_values(model, entry, x, a_s, psd, extra)
        entry["_assembly_s"] = time.perf_counter() - t0
        if "pardiso" not in entry:
            entry["pardiso"] = _Pardiso(entry["matrix"], entry["_pardiso_threads"])  # analysis, once
        return entry["pardiso"].factorize()

    def _backsolve(self, entry, rhs):
        return entry["pardiso"].solve(rhs)

    def _product(self, model, entry, x, a_s, psd, extra):
        """A' sol from the upper triangle U just factorised (U sol + U^T sol - diag(U) sol): the same
        matrix, no second pass over the elements (at 128^2 about 4 ms less than the matrix-free
        product and its copies)."""
        U = entry["matrix"]
        if "diag_pos" not in entry:
            pos = U.indptr[:-1]   # each row of the sorted upper triangle starts at its diagonal
            if not np.array_equal(U.indices[pos], np.arange(U.shape[0])):
                raise RuntimeError("the PARDISO pattern lacks a diagonal entry at the start of a row")
            entry["diag_pos"] = pos
        d = U.data[entry["diag_pos"]]
        return lambda sol, y: upper_product(U, sol, d)


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
