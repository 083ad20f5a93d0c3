"""Sparse assembly of the implicit system matrix for the direct solver (engine.linalg "cholesky").

The matrix is A' = a M + sum_terms scale H(x) (engine.linalg (L1) divided by c), written as
triplets into a ``ti.linalg.SparseMatrixBuilder`` (duplicates are summed), with the rows and
columns of pinned vertices replaced by the identity (engine.linalg (L2)).  Only the LOWER
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

import taichi as ti

from engine.energies.base import stencil_triplets
from engine.fields import int_array2, scalar_array

__all__ = ["assemble_mass", "assemble_energy", "element_assembler", "triplet_capacity"]


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


def assemble_energy(A, energy, blocks, inv_mass, scale: float) -> None:
    """A += scale H of ``energy`` from ``blocks`` = energy.hessian_blocks(x, psd) (lower triangle)."""
    if energy.n_elements:
        element_assembler(energy.stencil_size, type(energy).block)(A, energy.elements, blocks, inv_mass,
                                                                   float(scale))


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
