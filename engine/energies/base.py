"""The energy protocol: every elastic energy W(x) over a model's vertices.

Energy is the single source of truth: forces are ``-grad W`` and implicit integrators use the
Hessian of the same W. ``x``, ``dx``, ``f``, ``out`` are ``ti.ndarray`` of vec3 with one entry
per model vertex. Pins are handled by the model and the integrators, not by energies.

Stencils.  Most energies are sums over elements of k vertices each (springs: k = 2, hinges:
k = 4), W = sum_e W_e(x_e0, ..., x_e(k-1)), so the Hessian is a sum of k x k arrays of 3x3 blocks
H_e,ab = d2W_e / dx_a dx_b.  An energy says so by setting ``stencil_size`` k and ``elements``
(an (max(m, 1), k) i32 ndarray, the first ``n_elements`` rows valid) and by giving a ti.func
``block(blocks, e, a, b)`` (a, b ints, known at compile time or only at run time) that returns
H_e,ab from the array its :meth:`hessian_blocks` returns, in whatever compact layout it stores.
That is all the sparse assembly (:mod:`engine.solvers.assembly`) needs.  ``products`` names the
faster products an energy offers to the PCG solver (:mod:`engine.solvers`):

``"blocks"``       :meth:`add_block_product` (out += H dx from the stored blocks, computed once
                   per linear solve).
``"pair-gather"``  k = 2 with H_e = [[K, -K], [-K, K]]: ``pair_incidence`` is the CSR triple
                   (offsets (n+1,), inc_edge, inc_other) over which (H p)_i = sum_{e ~ i}
                   K_e (p_i - p_other) is gathered, K_e = hessian_blocks(x)[e].
``"rank-one"``     the PSD (Gauss-Newton) Hessian of each element is rank one, H_e = w_e w_e^T:
                   :meth:`gauss_newton_factors` writes w_e (k vec3 per element) and
                   ``slot_incidence`` is the CSR pair (offsets (n+1,), entries) listing, per
                   vertex, k*element + slot in increasing element order.
``"element-blocks"`` :meth:`hessian_blocks` is (m, k*k) mat3 with H_e,ab at [e, k a + b] (membranes):
                   the PCG's fused paths multiply each element's blocks by the direction and
                   gather the products per vertex over ``slot_incidence``.
``"deformation-blocks"`` (with "element-blocks", triangles): :meth:`deformation_blocks(x, psd)` is
                   (m, 3) mat3, the Hessian by the deformation gradient's columns, and the
                   ti.func ``deformation_corners(fblocks, Dinv, elements, z, p, beta, e)``
                   returns the k vectors (H_e (z + beta p))_a from them and the rest frames ``Dinv``
                   (the energy's): the PCG's fused paths use it instead of the stored blocks.
"""
import numpy as np
import taichi as ti

from engine.fields import float_dtype, int_array, mat3_array, mat3_array2, vec3_ndarray, zero_vec3


def stencil_triplets(k: int) -> int:
    """Nonzeros of the lower triangle of one element's 3k x 3k Hessian: k diagonal blocks x 6
    plus k(k-1)/2 vertex pairs x 9 (21 for a spring, k = 2; 78 for a hinge, k = 4)."""
    return 6 * k + 9 * k * (k - 1) // 2


class Energy:
    """Protocol for an elastic energy W(x) over the model's vertices.

    Energy is the single source of truth: forces are ``-grad W`` and implicit integrators
    use the Hessian of the same W.  Subclasses implement the first four methods with
    Taichi kernels; ``x``, ``dx``, ``f``, ``out`` are ``ti.ndarray`` of vec3 with one entry
    per model vertex.  Pins are handled by the model/integrators, not by energies.
    Stencil energies also set the attributes below (module docstring).
    """

    name = "energy"
    n_vertices: int = 0

    # -- stencil description (module docstring) -----------------------------------------------
    stencil_size: int = 0       # k vertices per element; 0: no per-element block layout
    n_elements: int = 0         # m
    elements = None             # (max(m, 1), k) i32 ndarray of element vertices
    block = None                # ti.func block(blocks, e, a, b) -> mat3 H_e,ab (slots a, b at compile or run time)
    products: frozenset = frozenset()  # of "blocks", "pair-gather", "rank-one", "element-blocks", "deformation-blocks"
    # How the explicit fast kernels can take its forces (engine.integrators.cloth_kernels): "pair-gather"
    # (spring_gather over force_args()), "slot-gather" (a per-element pass, then a per-vertex gather
    # over force_args(): hinge_force_vectors + hinge_gather), "corner-gather" (a kernel of its own,
    # corner_force_launch(), writes per-element corner forces into per_corner, which the step
    # gathers over slot_incidence: engine.integrators.explicit.corner_stepper), or None (only add_forces).
    force_form: str | None = None
    pair_incidence = None       # "pair-gather": (offsets, inc_edge, inc_other) i32 ndarrays
    slot_incidence = None       # "rank-one", "element-blocks", "corner-gather": (offsets, entries) i32 ndarrays,
    #                             entry = k*element + slot

    def energy(self, x) -> float:
        """W(x)."""
        raise NotImplementedError

    def add_forces(self, x, f) -> None:
        """f += -dW/dx (deterministic: no parallel float atomics)."""
        raise NotImplementedError

    def add_hessian_product(self, x, dx, out, psd: bool = True) -> None:
        """out += H(x) dx, with H the exact Hessian or (psd=True) its PSD projection."""
        raise NotImplementedError

    def hessian_blocks(self, x, psd: bool = True):
        """Per-element Hessian blocks (energy-specific layout, read through ``block``)."""
        raise NotImplementedError

    def add_block_product(self, blocks, dx, out) -> None:
        """out += H dx from blocks computed by :meth:`hessian_blocks` (``"blocks"`` in products)."""
        raise NotImplementedError(f"{type(self).__name__} has no block product")

    def gauss_newton_factors(self, x, w) -> None:
        """w[e, slot] (an (max(m, 1), k) vec3 ndarray) = the factor of the PSD element Hessian
        H_e = w_e w_e^T (``"rank-one"`` in products)."""
        raise NotImplementedError(f"{type(self).__name__} has no rank-one Gauss-Newton Hessian")

    def add_hessian_diagonal(self, x, diag, psd: bool = True) -> None:
        """diag[i] += H_ii (3x3 vertex diagonal blocks, a mat3 ndarray) for block-Jacobi."""
        raise NotImplementedError(f"{type(self).__name__} has no Hessian diagonal")

    def gershgorin_row_sums(self, x) -> np.ndarray:
        """(n, 3) numpy array: sum_j |H_(i,a),j| of the exact Hessian at x (for the CFL bound)."""
        raise NotImplementedError(f"{type(self).__name__} has no Gershgorin bound")

    def dense_hessian(self, x, psd: bool = True) -> np.ndarray:
        """Dense (3n, 3n) Hessian in numpy, for tests on small models.

        Default: one Hessian-vector product per unit vector (3n products)."""
        n = self.n_vertices
        H = np.zeros((3 * n, 3 * n))
        dx = vec3_ndarray(n)
        out = vec3_ndarray(n)
        for col in range(3 * n):
            e = np.zeros((n, 3))
            e.reshape(-1)[col] = 1.0
            dx.from_numpy(e.astype(float_dtype()))
            zero_vec3(out)
            self.add_hessian_product(x, dx, out, psd)
            H[:, col] = out.to_numpy().reshape(-1)
        return H


# --------------------------------------------------------------------------------------------
# The per-vertex pass of an element energy: gathering the per-element, per-slot results
# --------------------------------------------------------------------------------------------

@ti.func
def slot_gather(vh: ti.template(), offsets: ti.template(), entries: ti.template(), v, k: ti.template()):
    """For vertex v, the sum over its incidences (entry = k*element + slot, in the order of
    ``entries``) of vh[element, slot]: a stencil energy's per-element vectors (forces, Hessian
    products) gathered without atomics."""
    acc = ti.math.vec3(0.0)
    for j in range(offsets[v], offsets[v + 1]):
        ent = entries[j]
        acc += vh[ent // k, ent % k]
    return acc


@ti.kernel
def gather_slot_blocks_kernel(dh: mat3_array2, offsets: int_array, entries: int_array, diag: mat3_array,
                              k: ti.template()):
    """diag[v] += the sum over vertex v's incidences (entry = k*element + slot) of dh[element, slot]:
    the block-Jacobi diagonal from per-element diagonal blocks."""
    for v in range(offsets.shape[0] - 1):
        acc = ti.math.mat3(0.0)
        for j in range(offsets[v], offsets[v + 1]):
            ent = entries[j]
            acc += dh[ent // k, ent % k]
        diag[v] += acc
