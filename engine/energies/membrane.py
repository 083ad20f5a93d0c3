"""Membrane energies on triangles (stencils of k = 3): a constant-strain continuum triangle
(St. Venant-Kirchhoff) and Baraff and Witkin's stretch and shear conditions, and Baraff and
Witkin's damping of those conditions: the rest frames of the triangles and :class:`MembraneEnergy`.

One triangle's math, the deformation gradient (F1) in the triangle's rest frame, the energies (M1)
(St. Venant-Kirchhoff, with the plane-stress Lame parameters of :func:`lame`) and (M2) (Baraff and
Witkin), their exact and PSD Hessian blocks and the conditions' gradients, is
engine/energies/triangle.py; the kernels that sum it over the triangles are
engine/energies/membrane_kernels.py.

Baraff and Witkin's damping (section 4.5) pulls against the rate of each condition,

    d = -k_d sum_c (dC_c/dx) dC_c/dt = -D(x) v,   D = k_d sum_c (dC_c/dx)(dC_c/dx)^T          (M3)

(k_d of the stretch conditions and of the shear, N s/m). D is symmetric and positive
semi-definite; the explicit steps add d to the forces, backward Euler takes D at the start of
the step, D_n, into its incremental potential as 1/(2 dt) (x - x_n)^T D_n (x - x_n): the force
-D_n v+ at the new velocity, and the Jacobian D_n/dt in its Newton matrix (their dd/dv; like
them, the dd/dx part is left out).
"""
import numpy as np
import taichi as ti

from engine.energies.base import Energy, gather_slot_blocks_kernel
from engine.energies.membrane_kernels import (block_products_kernel, damping_blocks_kernel, damping_products_kernel,
                                             deformation_corners, gather_corners_kernel, membrane_block,
                                             membrane_deformation_blocks_kernel, membrane_energies_kernel,
                                             membrane_energy_kernel, membrane_forces_kernel, membrane_hessian_kernel,
                                             membrane_products_kernel, negate_corners)
from engine.energies.triangle import MODELS, mat2
from engine.errors import ModelError
from engine.fields import float_dtype, vec3_argument
from engine.mesh import as_points3, incidence


class MembraneError(ModelError):
    """Bad membrane input (parameters, triangles, degenerate rest triangles)."""


def lame(Y, nu) -> tuple:
    """(mu, lambda) (N/m) of a plane-stress sheet of 2D Young's modulus Y (N/m), Poisson's ratio nu."""
    return Y / (2.0 * (1.0 + nu)), Y * nu / (1.0 - nu * nu)


# --------------------------------------------------------------------------------------------
# Set-up (numpy) and the class
# --------------------------------------------------------------------------------------------

def rest_frames(X: np.ndarray, tris: np.ndarray, direction=(1.0, 0.0, 0.0)) -> tuple:
    """(Dm^-1 (m, 2, 2), rest areas (m,)) of each triangle in its (u, v) frame, u the projection of
    ``direction`` onto the triangle's plane (the y axis where ``direction`` is nearly normal to it)."""
    P0, P1, P2 = X[tris[:, 0]], X[tris[:, 1]], X[tris[:, 2]]
    e1, e2 = P1 - P0, P2 - P0
    n = np.cross(e1, e2)
    twice = np.linalg.norm(n, axis=1)
    if np.any(~(twice > 1e-300)):
        bad = int(np.flatnonzero(~(twice > 1e-300))[0])
        raise MembraneError(f"triangle {bad} {tris[bad].tolist()} has zero rest area")
    n = n / twice[:, None]
    d = np.asarray(direction, dtype=np.float64).reshape(3)
    u = d[None, :] - (n @ d)[:, None] * n
    weak = np.linalg.norm(u, axis=1) < 1e-6
    if np.any(weak):
        alt = np.array([0.0, 1.0, 0.0])
        u[weak] = alt - (n[weak] @ alt)[:, None] * n[weak]
    u /= np.linalg.norm(u, axis=1)[:, None]
    v = np.cross(n, u)
    Dm = np.stack([np.stack([np.einsum("ij,ij->i", e1, u), np.einsum("ij,ij->i", e2, u)], axis=1),
                   np.stack([np.einsum("ij,ij->i", e1, v), np.einsum("ij,ij->i", e2, v)], axis=1)], axis=1)
    return np.linalg.inv(Dm), 0.5 * twice


class MembraneEnergy(Energy):
    """A membrane energy over triangles, (M1) "stvk" or (M2) "baraff-witkin" (engine/energies/triangle.py).

    Parameters
      rest_positions  (n, 3) rest positions [m] ((n, 2) is embedded at z = 0)
      triangles       (m, 3) vertex indices
      model           "stvk": Y (2D Young's modulus, N/m, > 0) and nu (Poisson's ratio, in [0, 0.5));
                      "baraff-witkin": k_stretch and k_shear (N/m, >= 0)
      direction       the material direction the (u, v) frames' u axis follows (default x)

    As a stencil (engine/energies/base.py): k = 3, ``elements`` = the triangles, ``block`` reads
    :meth:`hessian_blocks`' (m, 9) layout, product "blocks"; force form "corner-gather"
    (:meth:`corner_force_launch`, ``per_corner``, ``slot_incidence``); product "deformation-blocks":
    :meth:`deformation_blocks` (27 numbers per triangle) and ``deformation_corners``, the product
    the PCG's fused paths take per iteration instead of the nine stored blocks (81 numbers).
    """

    name = "membrane"
    stencil_size = 3
    block = staticmethod(membrane_block)
    products = frozenset({"blocks", "element-blocks", "deformation-blocks"})
    deformation_corners = staticmethod(deformation_corners)
    force_form = "corner-gather"

    def __init__(self, rest_positions, triangles, model: str = "stvk", Y=None, nu=None, k_stretch=None,
                 k_shear=None, direction=(1.0, 0.0, 0.0), damping_stretch: float = 0.0, damping_shear: float = 0.0):
        if model not in MODELS:
            raise MembraneError(f"model must be one of {', '.join(MODELS)} (got {model!r})")
        X = as_points3(rest_positions, MembraneError)
        T = np.asarray(triangles, dtype=np.int64)
        if T.ndim != 2 or T.shape[1] != 3 or len(T) == 0:
            raise MembraneError(f"triangles must have shape (m, 3) with m >= 1, got {T.shape}")
        if T.min() < 0 or T.max() >= len(X):
            raise MembraneError(f"triangle vertex index out of range 0..{len(X) - 1}")
        if model == "stvk":
            if Y is None or nu is None or not (np.isfinite(Y) and Y > 0):
                raise MembraneError(f"stvk needs Y > 0 (N/m) and nu in [0, 0.5) (got Y={Y!r}, nu={nu!r})")
            if not (0.0 <= nu < 0.5):
                raise MembraneError(f"nu must be in [0, 0.5) (got {nu!r})")
            p0, p1 = lame(float(Y), float(nu))
        else:
            if k_stretch is None or k_shear is None or not (np.isfinite(k_stretch) and k_stretch >= 0
                                                            and np.isfinite(k_shear) and k_shear >= 0):
                raise MembraneError(f"baraff-witkin needs k_stretch >= 0 and k_shear >= 0 (N/m) (got "
                                    f"{k_stretch!r}, {k_shear!r})")
            p0, p1 = float(k_stretch), float(k_shear)
        for label, value in (("damping_stretch", damping_stretch), ("damping_shear", damping_shear)):
            if not (np.isfinite(value) and value >= 0):
                raise MembraneError(f"{label} must be finite and >= 0 (N s/m) (got {value!r})")
        if model != "baraff-witkin" and (damping_stretch or damping_shear):
            raise MembraneError("damping_stretch and damping_shear are Baraff-Witkin's damping of its conditions; "
                                "use model='baraff-witkin'")
        self.damping = (float(damping_stretch), float(damping_shear))
        self.has_damping = any(self.damping)
        self.model, self.model_code = model, MODELS[model]
        self.Y, self.nu, self.k_stretch, self.k_shear = Y, nu, k_stretch, k_shear
        self.n_vertices = len(X)
        self.triangles_np = T
        self.Dinv_np, self.area_np = rest_frames(X, T, direction)
        m = len(T)
        fdt = float_dtype()
        self.tris = ti.ndarray(dtype=ti.i32, shape=(m, 3))
        self.tris.from_numpy(T.astype(np.int32))
        self.Dinv = ti.ndarray(dtype=mat2, shape=m)
        self.Dinv.from_numpy(self.Dinv_np.astype(fdt))
        self.area = ti.ndarray(dtype=float, shape=m)
        self.area.from_numpy(self.area_np.astype(fdt))
        self.p0, self.p1 = ti.ndarray(dtype=float, shape=m), ti.ndarray(dtype=float, shape=m)
        self.p0.from_numpy(np.full(m, p0, dtype=fdt))
        self.p1.from_numpy(np.full(m, p1, dtype=fdt))
        self.kd_s, self.kd_h = ti.ndarray(dtype=float, shape=m), ti.ndarray(dtype=float, shape=m)
        self.kd_s.from_numpy(np.full(m, self.damping[0], dtype=fdt))
        self.kd_h.from_numpy(np.full(m, self.damping[1], dtype=fdt))
        offsets, entries = incidence(self.n_vertices, T.reshape(-1))
        self.offsets = ti.ndarray(dtype=ti.i32, shape=self.n_vertices + 1)
        self.offsets.from_numpy(offsets.astype(np.int32))
        self.entries = ti.ndarray(dtype=ti.i32, shape=3 * m)
        self.entries.from_numpy(entries.astype(np.int32))
        self.slot_incidence = (self.offsets, self.entries)
        self.n_elements = m
        self.elements = self.tris
        self.per_corner = ti.ndarray(dtype=ti.math.vec3, shape=(m, 3))
        self._scalars = ti.ndarray(dtype=float, shape=m)
        self._blocks = None
        self._fblocks = None
        self._damping_blocks = None
        self._diag = None
        self._scratch: dict = {}

    @classmethod
    def from_mesh(cls, mesh, model: str = "stvk", **kwargs) -> "MembraneEnergy":
        return cls(mesh.vertices, mesh.triangles, model, **kwargs)

    def _vec3(self, a, slot: str):
        return vec3_argument(a, self.n_vertices, self._scratch, slot, MembraneError, "the membrane")

    def corner_force_launch(self) -> tuple:
        """(kernel, tail, templates): ``kernel(x, *tail, *templates)`` writes every triangle's corner
        forces -dW_t/dx_a into ``per_corner`` (m, 3), which ``slot_incidence`` gathers per vertex
        (the "corner-gather" force form: engine.integrators.explicit.corner_stepper launches it
        bound)."""
        return membrane_forces_kernel, (*self.args()[:5], self.per_corner), (self.model_code,)

    def args(self) -> tuple:
        return self.tris, self.Dinv, self.area, self.p0, self.p1, self.model_code

    def _gather_into(self, out) -> None:
        if isinstance(out, np.ndarray):
            buf = self._vec3(np.zeros_like(out), "gathered")
            gather_corners_kernel(self.per_corner, self.offsets, self.entries, buf)
            out += buf.to_numpy().reshape(out.shape)
        else:
            gather_corners_kernel(self.per_corner, self.offsets, self.entries, out)

    def energy(self, x) -> float:
        return float(membrane_energy_kernel(self._vec3(x, "x"), *self.args()))

    def triangle_energies(self, x) -> np.ndarray:
        membrane_energies_kernel(self._vec3(x, "x"), *self.args(), self._scalars)
        return self._scalars.to_numpy().astype(np.float64)

    def add_forces(self, x, f) -> None:
        kernel, tail, templates = self.corner_force_launch()
        kernel(self._vec3(x, "x"), *tail, *templates)
        self._gather_into(f)

    def forces(self, x) -> np.ndarray:
        f = np.zeros((self.n_vertices, 3))
        self.add_forces(x, f)
        return f

    def add_hessian_product(self, x, dx, out, psd: bool = True) -> None:
        membrane_products_kernel(self._vec3(x, "x"), *self.args(), bool(psd), self._vec3(dx, "dx"), self.per_corner)
        self._gather_into(out)

    def hessian_blocks(self, x, psd: bool = True):
        """(m, 9) mat3 ndarray: blocks[t, 3a + b] = d2W_t/dx_a dx_b (reused by the next call)."""
        if self._blocks is None:
            self._blocks = ti.ndarray(dtype=ti.math.mat3, shape=(self.n_elements, 9))
        membrane_hessian_kernel(self._vec3(x, "x"), *self.args(), bool(psd), False, self._blocks)
        return self._blocks

    def deformation_blocks(self, x, psd: bool = True):
        """(m, 3) mat3 ndarray: (A_uu, A_uv, A_vv) of every triangle, its Hessian by F's columns
        (engine/energies/triangle.py, deformation_blocks); ``deformation_corners`` multiplies with
        them. Reused by the next call."""
        if self._fblocks is None:
            self._fblocks = ti.ndarray(dtype=ti.math.mat3, shape=(self.n_elements, 3))
        membrane_deformation_blocks_kernel(self._vec3(x, "x"), *self.args(), bool(psd), self._fblocks)
        return self._fblocks

    def add_block_product(self, blocks, dx, out) -> None:
        block_products_kernel(blocks, self.tris, self._vec3(dx, "dx"), self.per_corner)
        self._gather_into(out)

    def add_hessian_diagonal(self, x, diag, psd: bool = True) -> None:
        if self._diag is None:
            self._diag = ti.ndarray(dtype=ti.math.mat3, shape=(self.n_elements, 3))
        membrane_hessian_kernel(self._vec3(x, "x"), *self.args(), bool(psd), True, self._diag)
        gather_slot_blocks_kernel(self._diag, self.offsets, self.entries, diag, 3)

    def hessian_blocks_numpy(self, x, psd: bool = True) -> np.ndarray:
        return self.hessian_blocks(x, psd).to_numpy().astype(np.float64)

    def dense_hessian(self, x, psd: bool = True) -> np.ndarray:
        return self._dense(self.hessian_blocks_numpy(x, psd))

    def _dense(self, blocks: np.ndarray) -> np.ndarray:
        """Dense (3n, 3n) matrix from per-triangle blocks (m, 9, 3, 3) (tests, small meshes)."""
        n, T = self.n_vertices, self.triangles_np
        B = blocks.reshape(-1, 3, 3, 3, 3)
        H = np.zeros((3 * n, 3 * n))
        for a in range(3):
            for b in range(3):
                ia = (3 * T[:, a])[:, None] + np.arange(3)
                ib = (3 * T[:, b])[:, None] + np.arange(3)
                np.add.at(H, (ia[:, :, None], ib[:, None, :]), B[:, a, b])
        return H

    def gershgorin_row_sums(self, x) -> np.ndarray:
        return self._abs_row_sums(self.hessian_blocks_numpy(x, psd=False))

    def _abs_row_sums(self, blocks: np.ndarray) -> np.ndarray:
        """(n, 3): sum_j |M_(v,a),j| of the matrix whose per-triangle blocks (m, 9, 3, 3) are given."""
        rows = np.zeros((self.n_vertices, 3))
        absrow = np.abs(blocks).sum(axis=3)                                      # (m, 9, 3)
        per_corner = absrow.reshape(-1, 3, 3, 3).sum(axis=2)                     # (m, 3, 3)
        np.add.at(rows, self.triangles_np.reshape(-1), per_corner.reshape(-1, 3))
        return rows

    # -- Baraff-Witkin damping (M3) ------------------------------------------------------------
    def _damping_args(self) -> tuple:
        return self.tris, self.Dinv, self.area, self.kd_s, self.kd_h

    def add_damping_product(self, x, w, out) -> None:
        """out += D(x) w (M3)."""
        damping_products_kernel(self._vec3(x, "x"), *self._damping_args(), self._vec3(w, "w"), self.per_corner)
        self._gather_into(out)

    def add_damping_forces(self, x, v, f) -> None:
        """f += d = -D(x) v (M3)."""
        damping_products_kernel(self._vec3(x, "x"), *self._damping_args(), self._vec3(v, "v"), self.per_corner)
        negate_corners(self.per_corner)
        self._gather_into(f)

    def damping_blocks(self, x):
        """(m, 9) mat3 ndarray of D's blocks, the layout of :meth:`hessian_blocks` (reused)."""
        if self._damping_blocks is None:
            self._damping_blocks = ti.ndarray(dtype=ti.math.mat3, shape=(self.n_elements, 9))
        damping_blocks_kernel(self._vec3(x, "x"), *self._damping_args(), self._damping_blocks)
        return self._damping_blocks

    def dense_damping(self, x) -> np.ndarray:
        """Dense (3n, 3n) D(x) (tests, small meshes)."""
        return self._dense(self.damping_blocks(x).to_numpy().astype(np.float64))

    def damping_row_sums(self, x) -> np.ndarray:
        """(n, 3): sum_j |D_(v,a),j| at x, the Gershgorin bound of D's rows: an explicit step must keep
        dt D/m below 2 as well as under the stiffness' limit."""
        return self._abs_row_sums(self.damping_blocks(x).to_numpy().astype(np.float64))
