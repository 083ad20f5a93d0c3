"""Dihedral-angle bending energy on hinges (pairs of triangles sharing an edge).

Sources
-------
* Lecture notes, slides "Bending energy" .. "Bending forces":
  W_bend = int 1/2 B kappa^2 ~ sum_e 1/2 B_e kappa_e^2 A_e with the edge curvature estimate
  1/(2R) ~ theta_e / (h0 + h1) and A_e = |e| (h0 + h1) / 6, so

      W_bend = sum_e 1/2 B_e |e|^2 / (36 A_e) theta_e^2                                  (N1)

  "Treat all terms except theta as constant (measured from initial mesh)".
* Grinspun, Hirani, Desbrun, Schroeder, "Discrete shells", SCA 2003, eq. (3):
  E_B = sum_e (theta_e - theta_bar_e)^2 |e| / h_e,  h_e = (h0 + h1)/6, i.e. weight
  3 |e|^2 / (A0 + A1).
* Bridson, Marino, Fedkiw, "Simulation of clothing with folds and wrinkles", SCA 2003,
  section 4 (bending): F_i = k |E|^2 / (|N1| + |N2|) sin(theta/2) u_i with the u_1..u_4
  vectors reproduced literally by :func:`engine.energies.hinge.bridson_u_kernel`.

Energy per hinge (the single source of truth: forces and Hessians below are its
derivatives), with d = theta - theta_bar wrapped into [-pi, pi):

    notes, discrete-shells:   W_e = 1/2 k_e d^2                                          (W1)
    bridson:                  W_e = 4 k_e (1 - cos(d/2)) = 8 k_e sin^2(d/4)              (W2)
                              dW/dtheta = 2 k_e sin(d/2),  d2W/dtheta2 = k_e cos(d/2)

Per-hinge stiffness k_e, all rest quantities (|e|, wing heights h0 h1, wing areas A0 A1
with A0 + A1 = |e| (h0 + h1) / 2):

    notes, bridson:    k_e = B |e|^2 / (36 A_e) = B |e| / (6 (h0 + h1))                   (K1)
    discrete-shells:   k_e = B |e|^2 / (4 (A0 + A1)) = B |e| / (2 (h0 + h1)) = 3 x (K1)  (K2)

(K2) is Discrete Shells' weight with its constant chosen so that B is the same bending
modulus. On a cylinder of radius R meshed by a right-triangle grid aligned with the axis (or
an equilateral lattice at any orientation) (K1) converges to one third of the continuum
1/2 B (1/(2R))^2 * area (only the edges across the bend carry curvature but A_e gives each
edge a third of its triangles' area) and (K2), being 3 x (K1) hinge by hinge, to the continuum.
On a grid turned by a against the axis both are off by the same factor: (K1) gives
(1 - sin 2a + sin^2 2a)/3 of the continuum and (K2) three times that (0.75 at 15 degrees, 3 at
-45 degrees); lessons/bending stage 3 measures both.

The "bridson" variant: (W2) has the force  -dW/dx = 2 k_e sin(d/2) u  with u = -grad theta
equal to Bridson's u_1..u_4.  With theta_bar = 0 and k_e from (K1) that is Bridson's elastic
bending force  k |E|^2/(|N1|+|N2|) sin(theta/2) u_i  with his k = B/3 (because
|N1| + |N2| = |e| (h0 + h1)) and the coefficient |E|^2/(|N1|+|N2|) frozen at its rest value
(the notes' rule: everything but theta measured on the rest mesh); so frozen, the force is
exactly -grad of (W2): conservative.  It is NOT Bridson et al.'s literal force, which takes
the coefficient from the current shape: the two agree while a hinge keeps its rest edge
length and wing areas and differ by the ratio of the coefficients otherwise (|e|/(h0+h1): 1.21
on a hinge 10% longer along its edge with its heights divided by 1.1; 1.222 with them times 0.9),
and the literal force is the gradient of
no energy (its Jacobian is not symmetric); tests/engine/test_bending_energy.py measures both.
For a rest angle we use sin((theta - theta_bar)/2) (Bridson writes sin(theta/2) -
sin(theta_bar/2); the two agree to first order in the deviation).  Compared with the
notes' force k_e theta u, the force ratio at theta_bar = 0 is

    2 sin(theta/2) / theta = 1 - theta^2/24 + theta^4/1920 - ...                          (R1)

(the same small-angle stiffness: d2W/dtheta2 = k_e at d = 0).

A variant is two choices, the two columns of :data:`VARIANT_AXES`: the shape of W(theta), (W1)
or (W2) (the ``mode`` of engine.energies.hinge), and the weight k_e of each hinge, (K1) or (K2):
notes = (W1, K1), bridson = (W2, K1), discrete-shells = (W1, K2).

Angle, gradient, Hessians
-------------------------
The single-hinge math, the dihedral angle theta (A1) with its sign convention, its gradient
(G1)-(G3) and Hessian, the energy terms W, W', W'' of (W1)/(W2) and a hinge's exact and
Gauss-Newton Hessian blocks, is engine/energies/hinge.py; the kernels of
engine/energies/bending_kernels.py sum it over the hinges (their block layout and their
deterministic gathers are described there).
The Gauss-Newton hinge Hessian max(W'', 0) g g^T (g = grad theta) is rank one, H = w w^T with
w = sqrt(max(W'', 0)) g (:meth:`BendingEnergy.gauss_newton_factors`).

Energy density for colouring (:meth:`BendingEnergy.energy_density`): per vertex
rho_v = sum_{e ni v} W_e / sum_{e ni v} A_e (J/m^2), the A_e-weighted mean over incident
hinges of the hinge densities W_e/A_e, A_e = |e| (h0 + h1) / 6 on the rest mesh.  On a
uniformly bent regular mesh it equals total energy / total area at interior vertices.
"""

import numpy as np
import taichi as ti

from engine.energies.base import Energy, gather_slot_blocks_kernel
from engine.energies.bending_kernels import (bending_energy_kernel, dense_hessian_from_hinge_blocks,
                                            gather_hinge_vectors_kernel, hinge_block, hinge_energies_kernel,
                                            hinge_forces_kernel, hinge_gauss_newton_factors_kernel,
                                            hinge_hessian_kernel, hinge_hessian_products_kernel)
from engine.energies.hinge import MODE_HALF_ANGLE, MODE_QUADRATIC
# the angle's kernels, also named here (__all__) for this module's readers
from engine.energies.hinge import bridson_u_kernel, hinge_angles_kernel, theta_gradient_kernel, theta_hessian_kernel
from engine.errors import ModelError
from engine.fields import float_dtype, vec3_argument
from engine.mesh import as_points3, dihedral_angles, hinge_geometry, incidence

__all__ = [
    "BendingError", "BendingEnergy", "VARIANTS",
    "hinge_angles_kernel", "theta_gradient_kernel", "bridson_u_kernel", "theta_hessian_kernel",
    "hinge_stiffness", "validate_hinges",
]

# variant: (shape of W(theta): the hinge mode, (W1) or (W2); weight k_e per hinge: (K1) or (K2))
VARIANT_AXES = {"notes": (MODE_QUADRATIC, "K1"), "bridson": (MODE_HALF_ANGLE, "K1"),
                "discrete-shells": (MODE_QUADRATIC, "K2")}
VARIANTS = tuple(VARIANT_AXES)


class BendingError(ModelError):
    """Invalid bending input (a ValueError); one line naming the offending hinge/parameter."""


# --------------------------------------------------------------------------------------------
# numpy set-up helpers (rest quantities, validation)
# --------------------------------------------------------------------------------------------

def hinge_stiffness(variant: str, B, geometry: dict) -> np.ndarray:
    """k_e per hinge: (K1) for "notes" and "bridson", (K2) for "discrete-shells"."""
    if variant not in VARIANTS:
        raise BendingError(f"unknown bending variant {variant!r}; choose one of {', '.join(VARIANTS)}")
    L, h0, h1 = geometry["edge_length"], geometry["h0"], geometry["h1"]
    if VARIANT_AXES[variant][1] == "K2":
        return B * L * L / (4.0 * (geometry["A0"] + geometry["A1"]))   # (K2) B|e|^2/(4(A0+A1))
    return B * L * L / (36.0 * (L * (h0 + h1) / 6.0))                    # (K1) B|e|^2/(36 A_e)


def _edge_name(H, i) -> str:
    return f"hinge {i} (edge {H[i, 0]}-{H[i, 1]})"


def validate_hinges(X, hinges, B=None, theta_bar=None, rel_tol: float = 1e-12) -> np.ndarray:
    """Check hinge input; return hinges as int64 (h, 4).  Raises BendingError naming the hinge.

    Checks: shape; indices in 0..n-1; four distinct vertices; finite rest positions of the
    hinge vertices; each wing triangle t0 = (v0, v1, w0), t1 = (v1, v0, w1) of non-zero area
    (2 * area > rel_tol * longest side^2); B finite and >= 0; theta_bar finite."""
    X = as_points3(X, BendingError)
    n = len(X)
    H = np.asarray(hinges)
    if H.size == 0:
        H = H.reshape(0, 4)
    if H.ndim != 2 or H.shape[1] != 4 or (H.size and not np.issubdtype(H.dtype, np.integer)):
        raise BendingError(f"hinges must be an integer array of shape (h, 4) [v0, v1, w0, w1], "
                           f"got {H.dtype} {H.shape}")
    H = H.astype(np.int64)
    bad = np.flatnonzero(((H < 0) | (H >= n)).any(axis=1))
    if bad.size:
        i = bad[0]
        v = H[i][(H[i] < 0) | (H[i] >= n)][0]
        raise BendingError(f"hinge {i} [{', '.join(map(str, H[i]))}]: vertex index {v} out of range 0..{n - 1}")
    srt = np.sort(H, axis=1)
    bad = np.flatnonzero((srt[:, 1:] == srt[:, :-1]).any(axis=1))
    if bad.size:
        i = bad[0]
        raise BendingError(f"{_edge_name(H, i)}: vertices [{', '.join(map(str, H[i]))}] are not four distinct vertices")
    bad = np.flatnonzero(~np.isfinite(X[H]).all(axis=(1, 2)))
    if bad.size:
        i = bad[0]
        raise BendingError(f"{_edge_name(H, i)}: a vertex has a non-finite rest position")
    if len(H):
        xv0, xv1, xw0, xw1 = (X[H[:, k]] for k in range(4))
        for tri, (p, q, r), cols in (("t0", (xv0, xv1, xw0), (0, 1, 2)), ("t1", (xv1, xv0, xw1), (1, 0, 3))):
            twice_area = np.linalg.norm(np.cross(q - p, r - p), axis=1)
            longest = np.max([np.linalg.norm(q - p, axis=1), np.linalg.norm(r - q, axis=1),
                              np.linalg.norm(p - r, axis=1)], axis=0)
            bad = np.flatnonzero(~(twice_area > rel_tol * longest * longest))
            if bad.size:
                i = bad[0]
                t = ", ".join(str(H[i, c]) for c in cols)
                raise BendingError(f"{_edge_name(H, i)}: wing triangle ({t}) has zero area")
    if B is not None:
        Bv = np.broadcast_to(np.asarray(B, dtype=np.float64), (len(H),)) if np.ndim(B) == 0 else np.asarray(B, float)
        if Bv.shape != (len(H),):
            raise BendingError(f"B must be a scalar or have shape ({len(H)},), got {Bv.shape}")
        bad = np.flatnonzero(~np.isfinite(Bv) | (Bv < 0))
        if bad.size:
            i = bad[0]
            if np.ndim(B) == 0:
                raise BendingError(f"bending modulus B = {float(B)!r} must be finite and >= 0")
            raise BendingError(f"{_edge_name(H, i)}: bending modulus B = {float(Bv[i])!r} must be finite and >= 0")
    if theta_bar is not None:
        tb = np.asarray(theta_bar, dtype=np.float64)
        if tb.shape != (len(H),):
            raise BendingError(f"theta_bar must have shape ({len(H)},), got {tb.shape}")
        bad = np.flatnonzero(~np.isfinite(tb))
        if bad.size:
            i = bad[0]
            raise BendingError(f"{_edge_name(H, i)}: rest angle theta_bar = {float(tb[i])!r} must be finite")
    return H


# --------------------------------------------------------------------------------------------
# Energy object
# --------------------------------------------------------------------------------------------

class BendingEnergy(Energy):
    """Sum over hinges of (W1)/(W2) with per-hinge k_e from the rest mesh (module docstring).

    Parameters
      rest_positions  (n, 3) rest positions [m] (numpy or vec3 ndarray; (n, 2) is embedded at z=0)
      hinges          (h, 4) int [v0, v1, w0, w1] (engine.mesh convention)
      B               bending modulus [J = N m], scalar or per hinge, finite and >= 0
      variant         "notes" | "bridson" | "discrete-shells"
      theta_bar       (h,) rest angles [rad]; or from_rest=True to measure them on the rest
                      mesh (curved rest shapes); default zeros (flat rest)

    Protocol (engine.model.Energy): x, f, dx, out are vec3 ndarrays with one entry per vertex
    (numpy (n, 3) arrays are also accepted; a numpy f/out is updated in place).
    Attributes (numpy, float64): ``hinges_np``, ``k`` (k_e), ``theta_bar``, ``geometry``
    (engine.mesh.hinge_geometry dict), ``A_e``.  Taichi ndarrays (size max(h, 1)):
    ``hinges`` (h, 4) i32, ``k_nd``, ``theta_bar_nd``, the incidence ``offsets`` (n+1,) and
    ``entries`` (4h,) (entry = 4 hinge + slot), the per-hinge vec3 buffer ``per_hinge_vec`` (h, 4).
    :meth:`hinge_args` and :meth:`force_args` are the argument tuples of its kernels and of the
    force ti.funcs :func:`engine.energies.bending_kernels.hinge_force_vectors` /
    :func:`engine.energies.bending_kernels.hinge_gather`.

    As a stencil (engine/energies/base.py): k = 4, ``elements`` = ``hinges``, ``block`` reads
    ``hessian_blocks``' (h, 16) layout, product "rank-one" (:meth:`gauss_newton_factors`,
    ``slot_incidence`` = (offsets, entries)).
    """

    name = "bending"
    stencil_size = 4
    block = staticmethod(hinge_block)
    products = frozenset({"rank-one"})
    force_form = "slot-gather"

    def __init__(self, rest_positions, hinges, B, variant: str = "notes", theta_bar=None,
                 from_rest: bool = False):
        if variant not in VARIANTS:
            raise BendingError(f"unknown bending variant {variant!r}; choose one of {', '.join(VARIANTS)}")
        X = as_points3(rest_positions, BendingError)
        H = validate_hinges(X, hinges, B=B, theta_bar=theta_bar)
        if from_rest and theta_bar is not None:
            raise BendingError("give either theta_bar or from_rest=True, not both")
        h = len(H)
        if h >= 2 ** 29 or len(X) >= 2 ** 31:
            raise BendingError(f"too many hinges/vertices for i32 indexing ({h}, {len(X)})")
        self.n_vertices = len(X)
        self.n_hinges = h
        self.variant = variant
        self.mode, self.weight = VARIANT_AXES[variant]  # the shape of W(theta) and the weight k_e
        self.hinges_np = H
        self.geometry = hinge_geometry(X, H)
        self.A_e = self.geometry["A_e"]
        self.B = np.broadcast_to(np.asarray(B, dtype=np.float64), (h,)).copy()
        self.k = hinge_stiffness(variant, self.B, self.geometry)
        if from_rest:
            tb = dihedral_angles(X, H)
        elif theta_bar is None:
            tb = np.zeros(h)
        else:
            tb = np.asarray(theta_bar, dtype=np.float64).copy()
        self.theta_bar = tb
        self.offsets_np, self.entries_np = incidence(self.n_vertices, H.reshape(-1))  # entry = 4 hinge + slot

        m = max(h, 1)  # ndarrays of size 0 are avoided; kernels are skipped when h == 0
        fdt = float_dtype()
        self.hinges = ti.ndarray(dtype=ti.i32, shape=(m, 4))
        self.k_nd = ti.ndarray(dtype=float, shape=m)
        self.theta_bar_nd = ti.ndarray(dtype=float, shape=m)
        self.offsets = ti.ndarray(dtype=ti.i32, shape=self.n_vertices + 1)
        self.entries = ti.ndarray(dtype=ti.i32, shape=max(4 * h, 1))
        if h:
            self.hinges.from_numpy(H.astype(np.int32))
            self.k_nd.from_numpy(self.k.astype(fdt))
            self.theta_bar_nd.from_numpy(tb.astype(fdt))
            self.entries.from_numpy(self.entries_np.astype(np.int32))
        self.offsets.from_numpy(self.offsets_np.astype(np.int32))
        self.per_hinge_vec = ti.ndarray(dtype=ti.math.vec3, shape=(m, 4))
        self.n_elements = h
        self.elements = self.hinges
        self.slot_incidence = (self.offsets, self.entries)
        self._scalars = ti.ndarray(dtype=float, shape=m)
        self._blocks = None
        self._diag = None
        self._scratch: dict[str, object] = {}

    @classmethod
    def from_mesh(cls, mesh, B, variant: str = "notes", **kwargs) -> "BendingEnergy":
        """From an engine.mesh.Mesh (uses ``mesh.vertices`` and ``mesh.hinges``)."""
        return cls(mesh.vertices, mesh.hinges, B, variant=variant, **kwargs)

    # -- argument handling ---------------------------------------------------------------------
    def _vec3(self, a, slot: str):
        """A vec3 ndarray view of a (numpy arrays are copied into a per-slot scratch buffer)."""
        if not isinstance(a, np.ndarray) and tuple(a.shape) != (self.n_vertices,):
            raise BendingError(f"{slot} has shape {tuple(a.shape)}, the bending energy has {self.n_vertices} vertices")
        return vec3_argument(a, self.n_vertices, self._scratch, slot, BendingError, "the bending energy")

    def hinge_args(self) -> tuple:
        """(hinges, k_nd, theta_bar_nd, mode): what every per-hinge kernel takes after x."""
        return self.hinges, self.k_nd, self.theta_bar_nd, self.mode

    _args = hinge_args  # old private name, kept until its readers switch

    def force_args(self) -> tuple:
        """(hinges, k_nd, theta_bar_nd, mode, per_hinge_vec, offsets, entries): the arguments of
        :func:`hinge_force_vectors` (after x; its output fh = per_hinge_vec) followed by those of
        :func:`hinge_gather` (after vh = per_hinge_vec), for kernels fusing the bending forces."""
        return (*self.hinge_args(), self.per_hinge_vec, self.offsets, self.entries)

    def _gather_into(self, out) -> None:
        if isinstance(out, np.ndarray):
            buf = self._vec3(out, "out")
            gather_hinge_vectors_kernel(self.per_hinge_vec, self.offsets, self.entries, buf)
            out[...] = buf.to_numpy().reshape(out.shape)
        else:
            self._vec3(out, "out")
            gather_hinge_vectors_kernel(self.per_hinge_vec, self.offsets, self.entries, out)

    # -- protocol ------------------------------------------------------------------------------
    def energy(self, x) -> float:
        """W(x) = sum_e W_e."""
        if self.n_hinges == 0:
            return 0.0
        return float(bending_energy_kernel(self._vec3(x, "x"), *self.hinge_args()))

    def hinge_energies(self, x) -> np.ndarray:
        """(h,) W_e."""
        if self.n_hinges == 0:
            return np.zeros(0)
        hinge_energies_kernel(self._vec3(x, "x"), *self.hinge_args(), self._scalars)
        return self._scalars.to_numpy()[: self.n_hinges].astype(np.float64)

    def angles(self, x) -> np.ndarray:
        """(h,) signed dihedral angles theta (A1), rad."""
        if self.n_hinges == 0:
            return np.zeros(0)
        hinge_angles_kernel(self._vec3(x, "x"), self.hinges, self._scalars)
        return self._scalars.to_numpy()[: self.n_hinges].astype(np.float64)

    def hinge_forces(self, x) -> np.ndarray:
        """(h, 4, 3) per-hinge forces -dW_e/dx_slot (pass 1 of :meth:`add_forces`)."""
        if self.n_hinges == 0:
            return np.zeros((0, 4, 3))
        hinge_forces_kernel(self._vec3(x, "x"), *self.hinge_args(), self.per_hinge_vec)
        return self.per_hinge_vec.to_numpy()[: self.n_hinges].astype(np.float64)

    def add_forces(self, x, f) -> None:
        """f += -dW/dx: per-hinge forces, then a per-vertex gather (deterministic)."""
        if self.n_hinges == 0:
            return
        hinge_forces_kernel(self._vec3(x, "x"), *self.hinge_args(), self.per_hinge_vec)
        self._gather_into(f)

    def forces(self, x) -> np.ndarray:
        """-dW/dx as a numpy (n, 3) array."""
        f = np.zeros((self.n_vertices, 3))
        self.add_forces(x, f)
        return f

    def add_hessian_product(self, x, dx, out, psd: bool = True) -> None:
        """out += H(x) dx, H exact or (psd) Gauss-Newton max(W'',0) g g^T."""
        if self.n_hinges == 0:
            return
        hinge_hessian_products_kernel(self._vec3(x, "x"), *self.hinge_args(), bool(psd), self._vec3(dx, "dx"),
                                      self.per_hinge_vec)
        self._gather_into(out)

    def hessian_blocks(self, x, psd: bool = True):
        """Per-hinge 12x12 Hessians as a mat3 ndarray (max(h,1), 16): blocks[h, 4a+b] =
        d2W_h/dx_a dx_b, slots a, b in [v0, v1, w0, w1] order.  The buffer is reused (overwritten
        by the next call)."""
        if self._blocks is None:
            self._blocks = ti.ndarray(dtype=ti.math.mat3, shape=(max(self.n_hinges, 1), 16))
        if self.n_hinges:
            hinge_hessian_kernel(self._vec3(x, "x"), *self.hinge_args(), bool(psd), False, self._blocks)
        return self._blocks

    def gauss_newton_factors(self, x, w) -> None:
        """w[h, slot] = sqrt(max(W''(theta_h), 0)) dtheta_h/dx_slot into the (max(h, 1), 4) vec3
        ndarray w: the Gauss-Newton hinge Hessian is H_h = w_h w_h^T."""
        if self.n_hinges:
            hinge_gauss_newton_factors_kernel(self._vec3(x, "x"), *self.hinge_args(), w)

    def hessian_blocks_numpy(self, x, psd: bool = True) -> np.ndarray:
        """(h, 16, 3, 3) float64 copy of :meth:`hessian_blocks`."""
        return self.hessian_blocks(x, psd).to_numpy()[: self.n_hinges].astype(np.float64)

    def theta_hessian_blocks_numpy(self, x) -> np.ndarray:
        """(h, 16, 3, 3): Hess(theta) per hinge, same layout."""
        blocks = ti.ndarray(dtype=ti.math.mat3, shape=(max(self.n_hinges, 1), 16))
        if self.n_hinges:
            theta_hessian_kernel(self._vec3(x, "x"), self.hinges, blocks)
        return blocks.to_numpy()[: self.n_hinges].astype(np.float64)

    def add_hessian_diagonal(self, x, diag, psd: bool = True) -> None:
        """diag[v] += H_vv (3x3 vertex blocks, a mat3 ndarray), for block-Jacobi."""
        if self.n_hinges == 0:
            return
        if self._diag is None:
            self._diag = ti.ndarray(dtype=ti.math.mat3, shape=(self.n_hinges, 4))
        hinge_hessian_kernel(self._vec3(x, "x"), *self.hinge_args(), bool(psd), True, self._diag)
        gather_slot_blocks_kernel(self._diag, self.offsets, self.entries, diag, 4)

    def dense_hessian(self, x, psd: bool = True) -> np.ndarray:
        """Dense (3n, 3n) Hessian assembled in numpy from the blocks (tests, small meshes)."""
        return dense_hessian_from_hinge_blocks(self.n_vertices, self.hinges_np, self.hessian_blocks_numpy(x, psd))

    def gershgorin_row_sums(self, x) -> np.ndarray:
        """(n, 3): sum_j |H_(v,a),j| of the exact Hessian at x, for a stable-time-step bound."""
        rows = np.zeros((self.n_vertices, 3))
        if self.n_hinges:
            absrow = np.abs(self.hessian_blocks_numpy(x, psd=False)).sum(axis=3)  # (h, 16, 3)
            per_slot = absrow.reshape(-1, 4, 4, 3).sum(axis=2)                     # (h, 4, 3)
            np.add.at(rows, self.hinges_np.reshape(-1), per_slot.reshape(-1, 3))
        return rows

    def energy_density(self, x) -> np.ndarray:
        """(n,) J/m^2 per vertex: sum of incident W_e / sum of incident rest A_e (0 where a
        vertex has no hinge).  See the module docstring."""
        W = self.hinge_energies(x)
        flat = self.hinges_np.reshape(-1)
        num = np.bincount(flat, weights=np.repeat(W, 4), minlength=self.n_vertices)
        den = np.bincount(flat, weights=np.repeat(self.A_e, 4), minlength=self.n_vertices)
        return np.divide(num, den, out=np.zeros(self.n_vertices), where=den > 0)

