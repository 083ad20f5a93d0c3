"""Spring energy, forces and Hessians for spring networks in 3D.

Source: the lecture notes, slide "Spring potential":

    W_ij = 1/2 k_ij (|x_i - x_j| / L_ij - 1)^2 L_ij
    f_ij = -dW_ij/dx_i = -k_ij (|x_i - x_j| / L_ij - 1) (x_i - x_j) / |x_i - x_j|

and slide "Multi-dimensional spring potential", where the length scale L_ij multiplying
the energy becomes the area/volume A_ij represented by the spring:

    W_ij = 1/2 E (|x_i - x_j| / L_ij - 1)^2 A_ij.

One form covers both: with a per-edge coefficient c_e,

    W_e = 1/2 c_e (l_e / L_e - 1)^2,    l_e = |x_i - x_j|                              (S1)

with c_e = k_e L_e for the 1D spring and c_e = E A_e for area/volume-scaled springs.
The coefficient array is the only difference between the two.

Force on i (on j it is the opposite):

    f_i = -(c_e / L_e) (l_e / L_e - 1) (x_i - x_j) / l_e                                 (S2)

Hessian: writing W_e = 1/2 (c/L^2) (l - L)^2 and d = (x_i - x_j)/l, grad_i W = (c/L^2)(l - L) d
and d(d)/dx_i = (I - d d^T)/l, so H_e = [[K, -K], [-K, K]] with the 3x3 block

    K = (c/L^2) [ d d^T + ((l - L)/l) (I - d d^T) ]                                        (S3)

Under compression (l < L) the transverse coefficient (l - L)/l is negative and K is
indefinite; the PSD variant clamps it at zero (Baraff & Witkin 1998 / Choi & Ko 2002):

    K+ = (c/L^2) [ d d^T + max(0, (l - L)/l) (I - d d^T) ]                                 (S4)

Forces and Hessian products are per-vertex gathers over a CSR incidence (for vertex i,
loop over incident edges): deterministic, no float atomics.  The CSR arrays store, per
incidence, the other endpoint, the edge id and copies of 1/L_e and c_e/L_e so that the
gather streams through memory.

(S1) and (S2) of one spring are written once, as the ti.funcs :func:`spring_energy` and
:func:`spring_force`; the kernels here, the fused steps (engine.integrators.cloth_kernels and
engine.integrators.batched_steps) and the benchmark's variants (bench/variants.py) call them.
"""

import numpy as np
import taichi as ti

from engine.energies.base import Energy
from engine.errors import ModelError
from engine.fields import (edge_array, float_dtype, int_array, int_ndarray, mat3_array, per_item, scalar_array,
                           scalar_ndarray, vec3_array)
from engine.launch import kernel as fast_kernel
from engine.mesh import edge_incidence


# --------------------------------------------------------------------------------------------
# Taichi functions and kernels
# --------------------------------------------------------------------------------------------

@ti.func
def spring_energy(d, L, c):
    """(S1) W_e = 1/2 c (l/L - 1)^2 (J) of one spring with edge vector d = x_i - x_j (m, l = |d|),
    rest length L (m) and coefficient c (J: c = k L for the 1D spring, E A for an area-scaled one)."""
    l = d.norm()
    strain = l / L - 1.0
    return 0.5 * c * strain * strain


@ti.func
def spring_force(d, inv_L, c_over_L):
    """(S2) the force (N) on the end i of one spring with edge vector d = x_i - x_j (m), given 1/L
    (1/m) and c/L (N): -(c/L)(l/L - 1) d/l, written as -(c/L)(1/L - 1/l) d (one division); the
    force on j is its negative. Zero for l = 0. Every kernel that needs a spring force calls this."""
    t = ti.math.vec3(0.0)
    l = d.norm()
    if l > 0.0:
        t = c_over_L * (inv_L - 1.0 / l) * d
    return -t


@ti.func
def spring_block(d: ti.math.vec3, inv_L: float, c_over_L: float, psd: ti.i32) -> ti.math.mat3:
    """K of (S3) (psd=0) or (S4) (psd=1) for the edge vector d = x_i - x_j, given 1/L and c/L;
    zero if l = 0."""
    K = ti.math.mat3(0.0)
    l = d.norm()
    if l > 0.0:
        n = d / l
        nnT = n.outer_product(n)
        s = 1.0 - 1.0 / (l * inv_L)  # transverse coefficient (l - L)/l
        if psd != 0 and s < 0.0:
            s = 0.0
        K = (c_over_L * inv_L) * (nnT + s * (ti.math.eye(3) - nnT))  # (c/L^2)[...]
    return K


@ti.func
def spring_pair_block(blocks: ti.template(), e, a, b) -> ti.math.mat3:
    """Block (a, b) of H_e = [[K, -K], [-K, K]] from the compact per-edge K = blocks[e] (S3)/(S4)
    (a, b: compile-time or run-time slots)."""
    K = blocks[e]
    if a != b:
        K = -K
    return K


@fast_kernel
def spring_energy_kernel(x: vec3_array, edges: edge_array, L: scalar_array, c: scalar_array) -> float:
    # (S1) W = sum_e 1/2 c_e (l_e/L_e - 1)^2
    W = 0.0
    for e in range(edges.shape[0]):
        W += spring_energy(x[edges[e][0]] - x[edges[e][1]], L[e], c[e])
    return W


@ti.kernel
def spring_edge_energies_kernel(x: vec3_array, edges: edge_array, L: scalar_array, c: scalar_array,
                                out: scalar_array):
    # (S1) per edge, e.g. for colouring springs by stored energy
    for e in range(edges.shape[0]):
        out[e] = spring_energy(x[edges[e][0]] - x[edges[e][1]], L[e], c[e])


@ti.func
def spring_gather(x: ti.template(), i, offsets: ti.template(), inc_other: ti.template(),
                  inc_inv_L: ti.template(), inc_c_over_L: ti.template()):
    """(S2) gathered for vertex i: sum_{e ~ i} of :func:`spring_force`, by ascending neighbour."""
    acc = ti.math.vec3(0.0)
    xi = x[i]
    for k in range(offsets[i], offsets[i + 1]):
        acc += spring_force(xi - x[inc_other[k]], inc_inv_L[k], inc_c_over_L[k])
    return acc


@ti.kernel
def spring_add_forces_kernel(x: vec3_array, offsets: int_array, inc_other: int_array,
                             inc_inv_L: scalar_array, inc_c_over_L: scalar_array, f: vec3_array):
    for i in range(x.shape[0]):
        f[i] += spring_gather(x, i, offsets, inc_other, inc_inv_L, inc_c_over_L)


@fast_kernel
def spring_hessian_blocks_kernel(x: vec3_array, edges: edge_array, L: scalar_array, c: scalar_array,
                                 psd: ti.i32, blocks: mat3_array):
    # (S3)/(S4) per edge
    for e in range(edges.shape[0]):
        blocks[e] = spring_block(x[edges[e][0]] - x[edges[e][1]], 1.0 / L[e], c[e] / L[e], psd)


@ti.kernel
def spring_add_hessian_product_kernel(x: vec3_array, dx: vec3_array, offsets: int_array,
                                      inc_other: int_array, inc_inv_L: scalar_array,
                                      inc_c_over_L: scalar_array, psd: ti.i32, out: vec3_array):
    # out_i += sum_{e ~ i} K_e (dx_i - dx_j), K_e of (S3)/(S4) applied matrix-free:
    # K q = (c/L^2) [ (n.q) n + s (q - (n.q) n) ],  s = (l - L)/l (clamped at 0 if psd)
    for i in range(x.shape[0]):
        acc = ti.math.vec3(0.0)
        xi = x[i]
        dxi = dx[i]
        for k in range(offsets[i], offsets[i + 1]):
            j = inc_other[k]
            d = xi - x[j]
            l = d.norm()
            if l > 0.0:
                n = d / l
                q = dxi - dx[j]
                s = 1.0 - 1.0 / (l * inc_inv_L[k])
                if psd != 0 and s < 0.0:
                    s = 0.0
                a = n.dot(q)
                acc += (inc_c_over_L[k] * inc_inv_L[k]) * ((1.0 - s) * a * n + s * q)
        out[i] += acc


@ti.kernel
def spring_add_block_product_kernel(blocks: mat3_array, dx: vec3_array, offsets: int_array,
                                    inc_edge: int_array, inc_other: int_array, out: vec3_array):
    # out_i += sum_{e ~ i} K_e (dx_i - dx_j) with precomputed blocks (one Newton step, many CG products)
    for i in range(dx.shape[0]):
        acc = ti.math.vec3(0.0)
        for k in range(offsets[i], offsets[i + 1]):
            acc += blocks[inc_edge[k]] @ (dx[i] - dx[inc_other[k]])
        out[i] += acc


@ti.kernel
def spring_add_hessian_diagonal_kernel(x: vec3_array, offsets: int_array, inc_other: int_array,
                                       inc_inv_L: scalar_array, inc_c_over_L: scalar_array, psd: ti.i32,
                                       diag: mat3_array):
    # H_ii = sum_{e ~ i} K_e
    for i in range(x.shape[0]):
        acc = ti.math.mat3(0.0)
        for k in range(offsets[i], offsets[i + 1]):
            acc += spring_block(x[i] - x[inc_other[k]], inc_inv_L[k], inc_c_over_L[k], psd)
        diag[i] += acc


# --------------------------------------------------------------------------------------------
# numpy helpers (setup and tests)
# --------------------------------------------------------------------------------------------

def validate_springs(X: np.ndarray, edges: np.ndarray, c: np.ndarray, L: np.ndarray,
                     coef_name: str = "c") -> None:
    """Raise ModelError (one line, naming the edge) for invalid spring input; pure numpy."""
    n = len(X)
    m = len(edges)
    out = np.flatnonzero(((edges < 0) | (edges >= n)).any(axis=1))
    if out.size:
        e = out[0]
        raise ModelError(f"edge {e} = ({edges[e, 0]}, {edges[e, 1]}) has a vertex index out of range 0..{n - 1}")
    loops = np.flatnonzero(edges[:, 0] == edges[:, 1])
    if loops.size:
        e = loops[0]
        raise ModelError(f"edge {e} joins vertex {edges[e, 0]} to itself")
    if m:
        rest = np.linalg.norm(X[edges[:, 0]] - X[edges[:, 1]], axis=1)
        same = np.flatnonzero(rest == 0.0)
        if same.size:
            e = same[0]
            i, j = edges[e]
            raise ModelError(f"edge {e} joins vertices {i} and {j} at the same rest point {X[i].tolist()}")
    bad = np.flatnonzero(~np.isfinite(L) | (L <= 0))
    if bad.size:
        e = bad[0]
        raise ModelError(f"edge {e} = ({edges[e, 0]}, {edges[e, 1]}) has rest length {float(L[e])!r} (must be finite and > 0)")
    bad = np.flatnonzero(~np.isfinite(c) | (c <= 0))
    if bad.size:
        e = bad[0]
        raise ModelError(f"edge {e} = ({edges[e, 0]}, {edges[e, 1]}) has stiffness {coef_name}={float(c[e])!r} "
                         f"(must be finite and > 0)")


def dense_hessian_from_blocks(n: int, edges: np.ndarray, blocks: np.ndarray) -> np.ndarray:
    """Assemble the dense (3n, 3n) Hessian from per-edge blocks K (m, 3, 3): H_e = [[K,-K],[-K,K]]."""
    H = np.zeros((3 * n, 3 * n))
    for (i, j), K in zip(edges, blocks):
        si, sj = slice(3 * i, 3 * i + 3), slice(3 * j, 3 * j + 3)
        H[si, si] += K
        H[sj, sj] += K
        H[si, sj] -= K
        H[sj, si] -= K
    return H


# --------------------------------------------------------------------------------------------
# Energy object
# --------------------------------------------------------------------------------------------

class SpringEnergy(Energy):
    """Sum of springs W = sum_e 1/2 c_e (l_e/L_e - 1)^2 on n vertices (see module docstring).

    Holds Taichi ndarrays: ``edges`` (ivec2, m), ``L``, ``c`` (m,), the CSR incidence
    ``offsets`` (n+1,), ``inc_edge``, ``inc_other``, ``inc_inv_L``, ``inc_c_over_L`` (2m,), and a reusable
    ``blocks`` (mat3, m) buffer returned by :meth:`hessian_blocks`.
    Numpy copies: ``edges_np``, ``L_np``, ``c_np``.

    As a stencil (engine/energies/base.py): k = 2, ``elements`` the edges as an (m, 2) i32
    ndarray, one K per edge (``block``: H_e,aa = K, H_e,ab = -K), products "blocks" and
    "pair-gather" over ``pair_incidence`` = (offsets, inc_edge, inc_other).
    :meth:`force_args` is what :func:`spring_gather` takes after (x, i).
    """

    name = "springs"
    stencil_size = 2
    block = staticmethod(spring_pair_block)
    products = frozenset({"blocks", "pair-gather"})
    force_form = "pair-gather"

    def __init__(self, n_vertices: int, edges: np.ndarray, L: np.ndarray, c: np.ndarray,
                 X: np.ndarray | None = None, coef_name: str = "c"):
        edges = np.asarray(edges)
        if edges.ndim != 2 or edges.shape[1] != 2 or (edges.size and not np.issubdtype(edges.dtype, np.integer)):
            raise ModelError(f"edges must be an integer array of shape (m, 2), got {edges.dtype} {edges.shape}")
        edges = edges.astype(np.int64)
        m = len(edges)
        L = per_item("rest lengths L", L, m)
        c = per_item(coef_name, c, m)
        if X is None:
            X = np.zeros((n_vertices, 3))
            X[:, 0] = np.arange(n_vertices)  # distinct dummy points: rest-point check not applicable
        validate_springs(np.asarray(X, dtype=np.float64), edges, c, L, coef_name)

        self.n_vertices = int(n_vertices)
        self.m = m
        self.edges_np = edges
        self.L_np = L
        self.c_np = c
        offsets, inc_edge, inc_other = edge_incidence(self.n_vertices, edges, by="other")
        self.offsets_np, self.inc_edge_np, self.inc_other_np = offsets, inc_edge, inc_other
        if m >= 2 ** 30:
            raise ModelError(f"too many edges for i32 indexing ({m})")

        e_nd = ti.ndarray(dtype=ti.math.ivec2, shape=max(m, 1))
        if m:
            e_nd.from_numpy(edges.astype(np.int32))
        self.edges = e_nd
        self.n_elements = m
        self.elements = int_ndarray(edges.reshape(-1, 2))
        self.offsets = int_ndarray(offsets)
        self.inc_edge = int_ndarray(inc_edge)
        self.inc_other = int_ndarray(inc_other)
        self.L = scalar_ndarray(L)
        self.c = scalar_ndarray(c)
        self.inc_inv_L = scalar_ndarray(1.0 / L[inc_edge])
        self.inc_c_over_L = scalar_ndarray((c / L)[inc_edge])
        self.blocks = ti.ndarray(dtype=ti.math.mat3, shape=max(m, 1))
        self.pair_incidence = (self.offsets, self.inc_edge, self.inc_other)
        self._edge_energy = None

    def force_args(self) -> tuple:
        """The ndarrays :func:`spring_gather` takes after (x, i): (offsets, inc_other, inc_inv_L,
        inc_c_over_L), for kernels that fuse the spring forces into their own loops."""
        return self.offsets, self.inc_other, self.inc_inv_L, self.inc_c_over_L

    @staticmethod
    def prepare(X: np.ndarray, edges: np.ndarray, k=None, c=None, L=None):
        """numpy-only validation and defaults: returns (edges, L, c, coef_name) for __init__.
        Exactly one of k (c = k L, the notes' 1D spring) or c (e.g. c = E A_e); L defaults to
        the rest lengths |X_i - X_j|."""
        X = np.asarray(X, dtype=np.float64)
        edges = np.asarray(edges)
        if (k is None) == (c is None):
            raise ModelError("give exactly one of k (spring constant, c = k L) or c (coefficient, e.g. E A)")
        if edges.ndim != 2 or edges.shape[1] != 2 or (edges.size and not np.issubdtype(edges.dtype, np.integer)):
            raise ModelError(f"edges must be an integer array of shape (m, 2), got {edges.dtype} {edges.shape}")
        edges = edges.astype(np.int64)
        m = len(edges)
        n = len(X)
        out = np.flatnonzero(((edges < 0) | (edges >= n)).any(axis=1))
        if out.size:  # before indexing X with edges
            e = out[0]
            raise ModelError(f"edge {e} = ({edges[e, 0]}, {edges[e, 1]}) has a vertex index out of range 0..{n - 1}")
        if L is None:
            L = np.linalg.norm(X[edges[:, 0]] - X[edges[:, 1]], axis=1) if m else np.zeros(0)
        L = per_item("rest lengths L", L, m)
        if k is not None:
            kk = per_item("k", k, m)
            # validate k itself so that the message names k; then c = k L
            bad = np.flatnonzero(~np.isfinite(kk) | (kk <= 0))
            if bad.size:
                e = bad[0]
                raise ModelError(f"edge {e} = ({edges[e, 0]}, {edges[e, 1]}) has stiffness k={float(kk[e])!r} "
                                 f"(must be finite and > 0)")
            c, name = kk * L, "c=k*L"
        else:
            c, name = per_item("c", c, m), "c"
        validate_springs(X, edges, c, L, name)
        return edges, L, c, name

    @classmethod
    def from_rest(cls, X: np.ndarray, edges: np.ndarray, k=None, c=None, L=None) -> "SpringEnergy":
        """From rest positions X (n, 3); arguments as in :meth:`prepare`."""
        X = np.asarray(X, dtype=np.float64)
        edges, L, c, name = cls.prepare(X, edges, k=k, c=c, L=L)
        return cls(len(X), edges, L, c, X=X, coef_name=name)

    def set_coefficients(self, c) -> None:
        """Replace the per-edge coefficients c_e (e.g. another Young's modulus) without rebuilding."""
        c = per_item("c", c, self.m)
        bad = np.flatnonzero(~np.isfinite(c) | (c <= 0))
        if bad.size:
            e = bad[0]
            raise ModelError(f"edge {e} = ({self.edges_np[e, 0]}, {self.edges_np[e, 1]}) has stiffness c={float(c[e])!r} "
                             f"(must be finite and > 0)")
        self.c_np = c
        self.c.from_numpy(c.astype(float_dtype()))
        self.inc_c_over_L.from_numpy((c / self.L_np)[self.inc_edge_np].astype(float_dtype()))

    # -- protocol ------------------------------------------------------------------------------
    def energy(self, x) -> float:
        if self.m == 0:
            return 0.0
        return float(spring_energy_kernel(x, self.edges, self.L, self.c))

    def edge_energies(self, x) -> np.ndarray:
        """Per-edge energies (m,) as numpy."""
        if self._edge_energy is None:
            self._edge_energy = ti.ndarray(dtype=float, shape=max(self.m, 1))
        spring_edge_energies_kernel(x, self.edges, self.L, self.c, self._edge_energy)
        return self._edge_energy.to_numpy()[: self.m].astype(np.float64)

    def add_forces(self, x, f) -> None:
        spring_add_forces_kernel(x, *self.force_args(), f)

    def add_hessian_product(self, x, dx, out, psd: bool = True) -> None:
        spring_add_hessian_product_kernel(x, dx, *self.force_args(), int(bool(psd)), out)

    def hessian_blocks(self, x, psd: bool = True):
        """Per-edge 3x3 blocks K_e (S3/S4) into the reusable mat3 ndarray ``self.blocks`` (m,),
        which is returned (overwritten by the next call).  H_e = [[K, -K], [-K, K]] on (i, j)."""
        if self.m:
            spring_hessian_blocks_kernel(x, self.edges, self.L, self.c, int(bool(psd)), self.blocks)
        return self.blocks

    def add_block_product(self, blocks, dx, out) -> None:
        """out += H dx from blocks computed by :meth:`hessian_blocks`."""
        spring_add_block_product_kernel(blocks, dx, self.offsets, self.inc_edge, self.inc_other, out)

    def add_hessian_diagonal(self, x, diag, psd: bool = True) -> None:
        spring_add_hessian_diagonal_kernel(x, *self.force_args(), int(bool(psd)), diag)

    def hessian_blocks_numpy(self, x, psd: bool = True) -> np.ndarray:
        return self.hessian_blocks(x, psd).to_numpy()[: self.m].astype(np.float64)

    def dense_hessian(self, x, psd: bool = True) -> np.ndarray:
        return dense_hessian_from_blocks(self.n_vertices, self.edges_np, self.hessian_blocks_numpy(x, psd))

    def gershgorin_row_sums(self, x) -> np.ndarray:
        """(n, 3): for each dof row (i, a), sum over columns of |H| for the exact Hessian at x:
        each incident edge contributes 2 sum_b |K_ab| (the diagonal block K and the -K block)."""
        rows = np.zeros((self.n_vertices, 3))
        if self.m:
            absrow = 2.0 * np.abs(self.hessian_blocks_numpy(x, psd=False)).sum(axis=2)  # (m, 3)
            np.add.at(rows, self.edges_np[:, 0], absrow)
            np.add.at(rows, self.edges_np[:, 1], absrow)
        return rows
