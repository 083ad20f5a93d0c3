"""Sparse assembly of the implicit system matrix for the direct solver (engine.solvers "cholesky").

The matrix is A' = a M + sum_terms scale H(x) (engine.solvers (L1) divided by c), written as
triplets into a ``ti.linalg.SparseMatrixBuilder`` (duplicates are summed), with the rows and
columns of pinned vertices replaced by the identity (engine.solvers (L2)).  Only the LOWER
triangle is written (row >= col): Eigen's LL^T reads nothing else, and it halves the triplets.

Every energy is assembled by the same template.  An energy that is a sum over elements of
k vertices (engine/energies/base.py: ``stencil_size`` k, ``elements`` (m, k), ``block``) has
per element the k x k array of 3x3 blocks H_e,ab, a, b over its slots; with va, vb the
slots' vertices, the template writes block (va, vb) for va > vb in full and the diagonal
blocks (va = vb) for r >= s only, so an element with all vertices free writes

    6 k + 9 k (k - 1) / 2 triplets   (21 for a spring, k = 2; 78 for a hinge, k = 4)          (T1)

(:func:`engine.energies.base.stencil_triplets`), a vertex 3 (its mass, or 1 if pinned).
``block`` is a ti.func reading the energy's own compact storage (springs keep one K per edge:
H_e = [[K, -K], [-K, K]]), so no energy expands its blocks in memory; one kernel per
(k, block) pair is generated from the template and cached.

Triplets are appended in a serialized loop, element by element in index order, so the duplicates
of every matrix entry are summed in a fixed order and the factorisation is bitwise reproducible
run to run (within an element every triplet goes to a different entry: its vertices are
distinct).  The builder never checks its capacity, so :func:`triplet_capacity` is exact.
"""

import numpy as np
import taichi as ti

from engine.energies.base import stencil_triplets
from engine.fields import int_array, int_array2, int_ndarray, scalar_array
from engine.launch import FastKernel

__all__ = ["assemble_mass", "assemble_energy", "element_assembler", "triplet_capacity", "CSRPattern", "init_rows",
           "row_assembler", "assemble_rows", "pair_assembler", "assemble_system"]


@ti.kernel
def assemble_mass(A: ti.types.sparse_matrix_builder(), mass: scalar_array, inv_mass: scalar_array, a: float):
    """a m_i on the diagonal of free vertices, 1 for pinned (eliminated) ones: 3 triplets per vertex."""
    ti.loop_config(serialize=True)  # triplets in a fixed order: the factorisation is bitwise reproducible
    for i in range(mass.shape[0]):
        val = a * mass[i]
        if inv_mass[i] == 0.0:
            val = 1.0
        for d in ti.static(range(3)):
            A[3 * i + d, 3 * i + d] += val


_ASSEMBLERS: dict = {}


def element_assembler(k: int, block):
    """The kernel ``assemble(A, elements, blocks, inv_mass, scale)`` adding scale H_e for every
    element of a k-vertex stencil whose blocks ``block(blocks, e, a, b)`` reads (lower triangle,
    pinned rows/columns dropped); generated once per (k, block)."""
    key = (int(k), block)
    kernel = _ASSEMBLERS.get(key)
    if kernel is not None:
        return kernel

    @ti.kernel
    def assemble(A: ti.types.sparse_matrix_builder(), elements: int_array2, blocks: ti.types.ndarray(),
                 inv_mass: scalar_array, scale: float):
        ti.loop_config(serialize=True)  # triplets in a fixed order: the factorisation is bitwise reproducible
        for e in range(elements.shape[0]):
            for a in ti.static(range(k)):
                for b in ti.static(range(k)):
                    va = elements[e, a]
                    vb = elements[e, b]
                    if inv_mass[va] > 0.0 and inv_mass[vb] > 0.0 and va >= vb:
                        K = scale * block(blocks, e, a, b)
                        for r in ti.static(range(3)):
                            for s in ti.static(range(3)):
                                if va > vb or r >= s:
                                    A[3 * va + r, 3 * vb + s] += K[r, s]

    _ASSEMBLERS[key] = assemble
    return assemble


def _block_source(energy, blocks) -> tuple:
    """(ti.func block, its data) of an element term: the energy's stored blocks, or the rank-one
    factors of :class:`engine.solvers.operator.RankOneFactors`."""
    from engine.solvers.operator import RankOneFactors, rank_one_block
    if isinstance(blocks, RankOneFactors):
        return rank_one_block, blocks.w
    return type(energy).block, blocks


def assemble_energy(A, energy, blocks, inv_mass, scale: float) -> None:
    """A += scale H of ``energy`` from ``blocks`` = energy.hessian_blocks(x, psd) or its rank-one
    factors (lower triangle)."""
    if energy.n_elements:
        block, data = _block_source(energy, blocks)
        element_assembler(energy.stencil_size, block)(A, energy.elements, data, inv_mass, float(scale))


def triplet_capacity(model) -> int:
    """Exact number of triplets the assembly may write for the lower triangle of ``model``'s
    matrix: 3 per vertex plus (T1) per element.  An upper bound where pins drop entries; never
    exceeded.  NotImplementedError (one line) for an energy without a stencil layout."""
    cap = 3 * model.n
    for e in model.energies:
        if not e.stencil_size or e.block is None:
            raise NotImplementedError(
                f"cholesky cannot assemble the {getattr(e, 'name', type(e).__name__)} energy "
                f"({type(e).__name__}): no per-element block layout is known; use solver='pcg'")
        cap += stencil_triplets(e.stencil_size) * e.n_elements
    return cap


# --------------------------------------------------------------------------------------------
# Fixed-pattern assembly into CSR values (the PARDISO direct solver, engine.solvers "pardiso")
# --------------------------------------------------------------------------------------------
#
# The pattern of A' depends only on the model's elements and pins, so it is computed once per
# model (numpy, set-up) and every solve only writes the values.  Stored: the UPPER triangle
# (row <= column) in CSR, zero-based, columns sorted within each row (what a symmetric
# positive-definite PARDISO factorisation reads), vertex by vertex:
#
#   row 3i+r:  the diagonal block's entries (3i+r, 3i+s), s >= r, then for each neighbour
#              j > i of vertex i (increasing j) the three entries (3i+r, 3j+s), s = 0, 1, 2   (P1)
#
# A pinned vertex keeps only its diagonal block (the identity); pairs with a pinned vertex are
# not stored (its rows and columns are eliminated, (L2) of engine.solvers).
#
# The values are written by a gather per vertex (a parallel loop over block rows; vertex i's
# thread alone writes rows 3i..3i+2, no atomics): for every element e incident to i, at slot a,
# and every slot b whose vertex vb >= i, block H_e,ab is added at (i, vb).  Contributions are
# listed per row in increasing (element, b) order, so the sums are bitwise reproducible.

class CSRPattern:
    """The fixed upper-triangle CSR pattern (P1) of a model's system matrix and, per stencil
    energy, the per-row contribution lists the gather kernels read.  Numpy set-up, once per
    model; ``indptr``/``indices`` are int32 numpy arrays (``nnz`` entries)."""

    def __init__(self, model):
        n = int(model.n)
        free = np.asarray(model.free, dtype=bool)
        lo_all, hi_all = [], []
        element_sets = []
        for e in model.energies:
            if not e.n_elements:
                continue
            if not e.stencil_size or e.block is None:
                raise NotImplementedError(
                    f"pardiso cannot assemble the {getattr(e, 'name', type(e).__name__)} energy "
                    f"({type(e).__name__}): no per-element block layout is known; use solver='pcg'")
            els = np.asarray(e.elements.to_numpy(), dtype=np.int64)[:e.n_elements]
            element_sets.append((e, els))
            k = els.shape[1]
            for a in range(k):
                for b in range(a + 1, k):
                    va, vb = els[:, a], els[:, b]
                    keep = free[va] & free[vb]
                    lo_all.append(np.minimum(va, vb)[keep])
                    hi_all.append(np.maximum(va, vb)[keep])
        keys = np.unique(np.concatenate(lo_all) * n + np.concatenate(hi_all)) if lo_all else np.zeros(0, np.int64)
        self.n = n
        self.keys = keys                                    # sorted: row vertex, then column vertex
        rows_v, cols_v = keys // n, keys % n
        nb = np.bincount(rows_v, minlength=n)               # neighbours j > i of each vertex
        self.block_ptr = np.concatenate([[0], np.cumsum(nb)]).astype(np.int64)
        r = np.tile(np.arange(3), n)
        lengths = (3 - r) + 3 * np.repeat(nb, 3)
        indptr = np.concatenate([[0], np.cumsum(lengths)])
        if indptr[-1] >= 2 ** 31:
            raise ValueError(f"the system matrix has {indptr[-1]} nonzeros: too many for 32-bit indices")
        self.indptr = indptr.astype(np.int32)
        self.nnz = int(indptr[-1])
        indices = np.empty(self.nnz, dtype=np.int64)
        row = np.arange(3 * n)
        vert = row // 3
        # diagonal-block entries: row 3i+r holds columns 3i+r .. 3i+2
        for s in range(3):
            has = r <= s
            indices[indptr[:-1][has] + (s - r[has])] = 3 * vert[has] + s
        # neighbour blocks: entry k of row vertex i at offset (3 - r) + 3 k + s of row 3i+r
        if len(keys):
            kk = np.arange(len(keys)) - self.block_ptr[rows_v]       # index among i's neighbours
            for rr in range(3):
                start = indptr[3 * rows_v + rr] + (3 - rr) + 3 * kk
                for s in range(3):
                    indices[start + s] = 3 * cols_v + s
        self.indices = indices.astype(np.int32)
        self.indptr_nd = int_ndarray(self.indptr)
        self.contributions = {}
        for e, els in element_sets:
            self.contributions[id(e)] = self._contributions(els, free)

    def _contributions(self, els: np.ndarray, free: np.ndarray) -> tuple:
        """(c_ptr (n+1,), c_elem, c_code = a k + b, c_pos: -1 for the diagonal block, else the
        index of vb among row va's neighbours), i32 ndarrays, sorted by (va, element, b)."""
        m, k = els.shape
        e_idx = np.repeat(np.arange(m), k * k)
        a_idx = np.tile(np.repeat(np.arange(k), k), m)
        b_idx = np.tile(np.arange(k), m * k)
        va = els[e_idx, a_idx]
        vb = els[e_idx, b_idx]
        keep = free[va] & free[vb] & (vb >= va) & ((vb > va) | (a_idx == b_idx))
        e_idx, a_idx, b_idx, va, vb = e_idx[keep], a_idx[keep], b_idx[keep], va[keep], vb[keep]
        order = np.lexsort((b_idx, e_idx, va))
        e_idx, a_idx, b_idx, va, vb = e_idx[order], a_idx[order], b_idx[order], va[order], vb[order]
        pos = np.full(len(va), -1, dtype=np.int64)
        off = vb > va
        if off.any():
            where = np.searchsorted(self.keys, va[off] * self.n + vb[off])
            pos[off] = where - self.block_ptr[va[off]]
        c_ptr = np.concatenate([[0], np.cumsum(np.bincount(va, minlength=self.n))])
        return tuple(int_ndarray(arr) for arr in (c_ptr, e_idx, a_idx * k + b_idx, pos))


@ti.func
def _init_row(i, values: ti.template(), indptr: ti.template(), mass: ti.template(), inv_mass: ti.template(), a):
    """Block row i of (P1): a m_i on the diagonal of a free vertex, 1 on a pinned one, 0 elsewhere."""
    for idx in range(indptr[3 * i], indptr[3 * i + 3]):
        values[idx] = 0.0
    d = a * mass[i]
    if inv_mass[i] == 0.0:
        d = 1.0
    for r in ti.static(range(3)):
        values[indptr[3 * i + r]] = d


@ti.func
def _add_row(i, values: ti.template(), indptr: ti.template(), c_ptr: ti.template(), c_elem: ti.template(),
             c_code: ti.template(), c_pos: ti.template(), blocks: ti.template(), scale, k: ti.template(),
             block: ti.template()):
    """Block row i += scale H_e,ab of every contribution to it of a k-vertex stencil energy (P1), in
    the listed order; i's rows have one writer (no atomics)."""
    for c in range(c_ptr[i], c_ptr[i + 1]):
        e = c_elem[c]
        code = c_code[c]
        pos = c_pos[c]
        K = scale * block(blocks, e, code // k, code % k)   # the slots at run time: no k^2-way branch
        if pos < 0:
            for r in ti.static(range(3)):
                base = indptr[3 * i + r] - r
                for s in ti.static(range(r, 3)):
                    values[base + s] = values[base + s] + K[r, s]
        else:
            for r in ti.static(range(3)):
                base = indptr[3 * i + r] + 3 - r + 3 * pos
                for s in ti.static(range(3)):
                    values[base + s] = values[base + s] + K[r, s]


@ti.kernel
def init_rows(values: scalar_array, indptr: ti.types.ndarray(dtype=ti.i32, ndim=1), mass: scalar_array,
              inv_mass: scalar_array, a: float):
    """values = a M on the diagonal of free vertices, 1 on pinned ones, 0 elsewhere (P1)."""
    for i in range(mass.shape[0]):
        _init_row(i, values, indptr, mass, inv_mass, a)


_ROW_ASSEMBLERS: dict = {}


def row_assembler(k: int, block):
    """The kernel ``assemble(values, indptr, c_ptr, c_elem, c_code, c_pos, blocks, scale)`` adding
    scale H_e,ab of every contribution of a k-vertex stencil energy into the CSR values (P1), one
    block row per thread; generated once per (k, block)."""
    key = (int(k), block)
    kernel = _ROW_ASSEMBLERS.get(key)
    if kernel is not None:
        return kernel

    @ti.kernel
    def assemble(values: scalar_array, indptr: ti.types.ndarray(dtype=ti.i32, ndim=1), c_ptr: int_array,
                 c_elem: int_array, c_code: int_array, c_pos: int_array, blocks: ti.types.ndarray(), scale: float):
        for i in range(c_ptr.shape[0] - 1):
            _add_row(i, values, indptr, c_ptr, c_elem, c_code, c_pos, blocks, scale, k, block)

    _ROW_ASSEMBLERS[key] = assemble
    return assemble


def assemble_rows(pattern: CSRPattern, values, energy, blocks, scale: float) -> None:
    """values += scale H of ``energy`` from ``blocks`` = energy.hessian_blocks(x, psd) or its
    rank-one factors (P1)."""
    if energy.n_elements:
        c_ptr, c_elem, c_code, c_pos = pattern.contributions[id(energy)]
        block, data = _block_source(energy, blocks)
        row_assembler(energy.stencil_size, block)(values, pattern.indptr_nd, c_ptr, c_elem, c_code, c_pos, data,
                                                  float(scale))


_PAIR_ASSEMBLERS: dict = {}


def pair_assembler(k1: int, block1, k2: int, block2):
    """The kernel writing all of A' = a M + s1 H_1 + s2 H_2 (P1) for two stencil energies in ONE
    pass over the block rows: per row, :func:`init_rows`' values, then the first energy's
    contributions, then the second's, so every entry is summed in the order of init_rows followed
    by two :func:`assemble_rows` (the same bits) with one launch instead of three and the row's
    values still in cache; generated once per (k1, block1, k2, block2)."""
    key = (int(k1), block1, int(k2), block2)
    kernel = _PAIR_ASSEMBLERS.get(key)
    if kernel is not None:
        return kernel

    @ti.kernel
    def assemble(values: scalar_array, indptr: ti.types.ndarray(dtype=ti.i32, ndim=1), mass: scalar_array,
                 inv_mass: scalar_array, a: float,
                 p1: int_array, e1: int_array, c1: int_array, q1: int_array, b1: ti.types.ndarray(), s1: float,
                 p2: int_array, e2: int_array, c2: int_array, q2: int_array, b2: ti.types.ndarray(), s2: float):
        for i in range(mass.shape[0]):
            _init_row(i, values, indptr, mass, inv_mass, a)
            _add_row(i, values, indptr, p1, e1, c1, q1, b1, s1, k1, block1)
            _add_row(i, values, indptr, p2, e2, c2, q2, b2, s2, k2, block2)

    _PAIR_ASSEMBLERS[key] = assemble = FastKernel(assemble)
    return assemble


def assemble_system(pattern: CSRPattern, values, model, a: float, terms, once_each: bool = False) -> None:
    """values = a M + sum of ``terms`` (P1): ``terms`` yields (scale, energy, blocks) as
    engine.solvers.operator.element_terms does, one at a time. With ``once_each`` (the caller knows
    each energy comes once: no extra term) and two energies with elements (a cloth's springs and
    hinges), one :func:`pair_assembler` launch; otherwise :func:`init_rows` and one
    :func:`assemble_rows` per term, each assembled before the next is asked for (an energy may reuse
    its blocks buffer for its next term)."""
    args = (values, pattern.indptr_nd, model.mass_nd, model.inv_mass_nd, float(a))
    active = [e for e in model.energies if e.n_elements]
    if once_each and len(active) == 2 and active[0] is not active[1]:
        terms = list(terms)   # two energies, one term each: their buffers are distinct
        if [t[1] for t in terms] == active:
            parts = []
            for scale, e, blocks in terms:
                block, data = _block_source(e, blocks)
                parts.append((e.stencil_size, block, pattern.contributions[id(e)], data, float(scale)))
            (k1, bl1, con1, d1, s1), (k2, bl2, con2, d2, s2) = parts
            pair_assembler(k1, bl1, k2, bl2)(*args, *con1, d1, s1, *con2, d2, s2)
            return
    init_rows(*args)
    for scale, e, blocks in terms:
        assemble_rows(pattern, values, e, blocks, scale)
