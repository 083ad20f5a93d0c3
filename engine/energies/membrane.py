"""Membrane energies on triangles (stencils of k = 3): a constant-strain continuum triangle
(St. Venant-Kirchhoff) and Baraff and Witkin's stretch and shear conditions.

Both read a triangle's deformation in its rest frame (u, v), an orthonormal frame of the rest
triangle's plane whose u axis is the projection of a chosen material direction (default: the x
axis; the warp of a cloth). With the rest coordinates of the corners in that frame,
Dm = [p1 - p0, p2 - p0] (2x2), the deformation gradient of the (linear) triangle is

    F = [x1 - x0, x2 - x0] Dm^-1 = sum_a x_a g_a^T,   g1, g2 = the rows of Dm^-1,  g0 = -(g1 + g2)  (F1)

(3x2; its columns w_u = dx/du and w_v = dx/dv are the images of the rest frame's axes), constant
over the triangle. A is the rest area.

Constant-strain triangle, St. Venant-Kirchhoff, with E = (F^T F - I)/2 (Green strain, 2x2):

    W = A [ mu E:E + lambda/2 tr(E)^2 ],   S = lambda tr(E) I + 2 mu E,   dW/dx_a = A F S g_a   (M1)
    H_ab = A [ (g_a . S g_b) I + lambda (F g_a)(F g_b)^T + mu (g_a . g_b) F F^T + mu (F g_b)(F g_a)^T ]

with the plane-stress Lame parameters of a sheet of 2D Young's modulus Y (N/m) and Poisson's
ratio nu:  mu = Y / (2 (1 + nu)),  lambda = Y nu / (1 - nu^2). Its small-strain limit is the
isotropic linear membrane, so a static stretch measures Y and nu as set, on any mesh. The PSD
variant keeps the positive part of S in the first term (the rest, lambda tr(M)^2 + 2 mu |sym M|^2
for M = F^T dF, is never negative).

Baraff and Witkin (1998), section 4.2: conditions on each triangle,

    stretch  C_u = sqrt(A) (|w_u| - 1),  C_v = sqrt(A) (|w_v| - 1);   shear  C_s = sqrt(A) w_u . w_v
    W = k_s/2 (C_u^2 + C_v^2) + k_h/2 C_s^2                                                     (M2)

(their C carries the area a itself, which makes W grow with a^2 and the stiffness depend on the
resolution; sqrt(A) makes W an integral over the rest area, k_s and k_h in N/m). For small strains
(M2) is an orthotropic membrane with Young's moduli k_s along u and v, Poisson's ratio 0 (the
stretch conditions do not couple u and v) and shear modulus k_h: isotropic only when
k_h = k_s / 2. With n_u = w_u/|w_u|:

    dW/dx_a = A [ k_s ((|w_u| - 1) g_a0 n_u + (|w_v| - 1) g_a1 n_v) + k_h s (g_a0 w_v + g_a1 w_u) ],  s = w_u . w_v
    H_ab = A [ k_s (g_a0 g_b0 K_u + g_a1 g_b1 K_v) + k_h ( q_a q_b^T + s (g_a0 g_b1 + g_a1 g_b0) I ) ]
           K_u = n_u n_u^T + (1 - 1/|w_u|) (I - n_u n_u^T),   q_a = g_a0 w_v + g_a1 w_u

The PSD variant clips K's transverse coefficient at 0 (a compressed direction, as for springs)
and drops the shear's s-term (Baraff and Witkin's own approximation: dC/dx^T dC/dx only).

Baraff and Witkin's damping (section 4.5) pulls against the rate of each condition,

    d = -k_d sum_c (dC_c/dx) dC_c/dt = -D(x) v,   D = k_d sum_c (dC_c/dx)(dC_c/dx)^T          (M3)

(k_d of the stretch conditions and of the shear, N s/m). D is symmetric and positive
semi-definite; the explicit steps add d to the forces, backward Euler takes D at the start of
the step, D_n, into its incremental potential as 1/(2 dt) (x - x_n)^T D_n (x - x_n): the force
-D_n v+ at the new velocity, and the Jacobian D_n/dt in its Newton matrix (their dd/dv; like
them, the dd/dx part is left out).

Kernels work per triangle (parallel, results per triangle) and gather per vertex over the
corner incidence (entry = 3 triangle + corner), deterministic, as the hinge energy does.
"""
import numpy as np
import taichi as ti

from engine.energies.base import Energy, gather_slot_blocks_kernel, slot_gather
from engine.errors import ModelError
from engine.fields import float_dtype, int_array, mat3_array2, scalar_array, vec3_argument, vec3_array, vec3_array2
from engine.fields import int_array2 as triangle_array
from engine.mesh import as_points3, incidence

STVK, BARAFF_WITKIN = 0, 1
MODELS = {"stvk": STVK, "baraff-witkin": BARAFF_WITKIN}
vec2 = ti.math.vec2
mat2 = ti.math.mat2


class MembraneError(ModelError):
    """Bad membrane input (parameters, triangles, degenerate rest triangles)."""


def lame(Y, nu) -> tuple:
    """(mu, lambda) (N/m) of a plane-stress sheet of 2D Young's modulus Y (N/m), Poisson's ratio nu."""
    return Y / (2.0 * (1.0 + nu)), Y * nu / (1.0 - nu * nu)


# --------------------------------------------------------------------------------------------
# One triangle
# --------------------------------------------------------------------------------------------

@ti.func
def deformation_gradient(d1, d2, D):
    """(w_u, w_v), the columns of F = [d1, d2] Dm^-1 (F1), for the deformed edges d1 = x1 - x0,
    d2 = x2 - x0 and D = Dm^-1 (the membranes exercise's first function)."""
    return d1 * D[0, 0] + d2 * D[1, 0], d1 * D[0, 1] + d2 * D[1, 1]


@ti.func
def triangle_frame(x: ti.template(), tris: ti.template(), Dinv: ti.template(), t):
    """(w_u, w_v, g0, g1, g2) of triangle t (F1): F's columns and the corners' gradient rows."""
    x0 = x[tris[t, 0]]
    D = Dinv[t]
    wu, wv = deformation_gradient(x[tris[t, 1]] - x0, x[tris[t, 2]] - x0, D)
    g1 = vec2(D[0, 0], D[0, 1])
    g2 = vec2(D[1, 0], D[1, 1])
    return wu, wv, -(g1 + g2), g1, g2


@ti.func
def baraff_witkin_stress(wu, wv, A, ks, kh):
    """(dW/dw_u, dW/dw_v) of Baraff and Witkin's energy (M2) of one triangle (the membranes
    exercise's second function)."""
    lu, lv, s = wu.norm(), wv.norm(), wu.dot(wv)
    return A * (ks * (lu - 1.0) / lu * wu + kh * s * wv), A * (ks * (lv - 1.0) / lv * wv + kh * s * wu)


@ti.func
def positive_part(S):
    """The positive part of a symmetric 2x2 matrix (its negative eigenvalues set to 0)."""
    a, b, d = S[0, 0], S[0, 1], S[1, 1]
    mean = 0.5 * (a + d)
    r = ti.sqrt(0.25 * (a - d) * (a - d) + b * b)
    hi, lo = mean + r, mean - r
    out = S
    if lo < 0.0:
        out = mat2(0.0)
        if hi > 0.0:
            v = vec2(1.0, 0.0)
            if b != 0.0:
                v = vec2(b, hi - a)
            elif d > a:
                v = vec2(0.0, 1.0)
            v = v / v.norm()
            out = hi * v.outer_product(v)
    return out


@ti.func
def membrane_terms(model: ti.template(), wu, wv, A, p0, p1):
    """(W, S, P_u, P_v) of one triangle: its energy, St. Venant-Kirchhoff's second Piola-Kirchhoff
    stress S (2x2; zero for Baraff-Witkin), and P_u = dW/dw_u, P_v = dW/dw_v, the derivatives by
    F's columns, so that dW/dx_a = g_a0 P_u + g_a1 P_v ((M1): P = A F S; (M2))."""
    W = 0.0
    S = mat2(0.0)
    Pu, Pv = ti.math.vec3(0.0), ti.math.vec3(0.0)
    if ti.static(model == STVK):
        mu, lam = p0, p1
        E00 = 0.5 * (wu.dot(wu) - 1.0)
        E11 = 0.5 * (wv.dot(wv) - 1.0)
        E01 = 0.5 * wu.dot(wv)
        tr = E00 + E11
        W = A * (mu * (E00 * E00 + E11 * E11 + 2.0 * E01 * E01) + 0.5 * lam * tr * tr)
        S = mat2([[lam * tr + 2.0 * mu * E00, 2.0 * mu * E01], [2.0 * mu * E01, lam * tr + 2.0 * mu * E11]])
        Pu = A * (S[0, 0] * wu + S[1, 0] * wv)
        Pv = A * (S[0, 1] * wu + S[1, 1] * wv)
    else:
        ks, kh = p0, p1
        lu, lv, s = wu.norm(), wv.norm(), wu.dot(wv)
        W = A * (0.5 * ks * ((lu - 1.0) ** 2 + (lv - 1.0) ** 2) + 0.5 * kh * s * s)
        Pu, Pv = baraff_witkin_stress(wu, wv, A, ks, kh)
    return W, S, Pu, Pv


@ti.func
def block_ab(model: ti.template(), psd: ti.template(), wu, wv, ga, gb, S, A, p0, p1):
    """H_ab = d2W/dx_a dx_b (3x3) of one triangle, (M1) or (M2), exact or PSD."""
    I3 = ti.math.eye(3)
    H = ti.math.mat3(0.0)
    if ti.static(model == STVK):
        mu, lam = p0, p1
        Sp = S
        if ti.static(psd):
            Sp = positive_part(S)
        Fa = ga[0] * wu + ga[1] * wv
        Fb = gb[0] * wu + gb[1] * wv
        FFt = wu.outer_product(wu) + wv.outer_product(wv)
        H = A * (ga.dot(Sp @ gb) * I3 + lam * Fa.outer_product(Fb) + mu * ga.dot(gb) * FFt
                 + mu * Fb.outer_product(Fa))
    else:
        ks, kh = p0, p1
        lu, lv, s = wu.norm(), wv.norm(), wu.dot(wv)
        nu_, nv_ = wu / lu, wv / lv
        cu, cv = 1.0 - 1.0 / lu, 1.0 - 1.0 / lv
        if ti.static(psd):
            cu, cv = ti.max(cu, 0.0), ti.max(cv, 0.0)
        Pu, Pv = nu_.outer_product(nu_), nv_.outer_product(nv_)
        Ku = Pu + cu * (I3 - Pu)
        Kv = Pv + cv * (I3 - Pv)
        qa = ga[0] * wv + ga[1] * wu
        qb = gb[0] * wv + gb[1] * wu
        H = ks * (ga[0] * gb[0] * Ku + ga[1] * gb[1] * Kv) + kh * qa.outer_product(qb)
        if ti.static(not psd):
            H += kh * s * (ga[0] * gb[1] + ga[1] * gb[0]) * I3
        H = A * H
    return H


@ti.func
def _triangle(x: ti.template(), tris: ti.template(), Dinv: ti.template(), area: ti.template(),
              p0: ti.template(), p1: ti.template(), model: ti.template(), t):
    """(w_u, w_v, [g_a], W, S, P_u, P_v) of triangle t: :func:`triangle_frame` and :func:`membrane_terms`."""
    wu, wv, g0, g1, g2 = triangle_frame(x, tris, Dinv, t)
    W, S, Pu, Pv = membrane_terms(model, wu, wv, area[t], p0[t], p1[t])
    return wu, wv, [g0, g1, g2], W, S, Pu, Pv


@ti.func
def membrane_block(blocks: ti.template(), t, a: ti.template(), b: ti.template()) -> ti.math.mat3:
    """Block (a, b) of triangle t in the layout of :meth:`MembraneEnergy.hessian_blocks`."""
    return blocks[t, 3 * a + b]


# --------------------------------------------------------------------------------------------
# Kernels (per triangle, then per vertex: no atomics)
# --------------------------------------------------------------------------------------------

@ti.kernel
def membrane_energy_kernel(x: vec3_array, tris: triangle_array, Dinv: ti.types.ndarray(dtype=mat2, ndim=1),
                           area: scalar_array, p0: scalar_array, p1: scalar_array, model: ti.template()) -> float:
    total = 0.0
    for t in range(tris.shape[0]):
        wu, wv, g, W, S, Pu, Pv = _triangle(x, tris, Dinv, area, p0, p1, model, t)
        total += W
    return total


@ti.kernel
def membrane_energies_kernel(x: vec3_array, tris: triangle_array, Dinv: ti.types.ndarray(dtype=mat2, ndim=1),
                             area: scalar_array, p0: scalar_array, p1: scalar_array, model: ti.template(),
                             out: scalar_array):
    for t in range(tris.shape[0]):
        wu, wv, g, W, S, Pu, Pv = _triangle(x, tris, Dinv, area, p0, p1, model, t)
        out[t] = W


@ti.kernel
def membrane_forces_kernel(x: vec3_array, tris: triangle_array, Dinv: ti.types.ndarray(dtype=mat2, ndim=1),
                           area: scalar_array, p0: scalar_array, p1: scalar_array, ft: vec3_array2,
                           model: ti.template()):
    # ft[t, a] = -dW_t/dx_a = -(g_a0 P_u + g_a1 P_v)  (the template last: a BoundKernel launches it)
    for t in range(tris.shape[0]):
        wu, wv, g0, g1, g2 = triangle_frame(x, tris, Dinv, t)
        W, S, Pu, Pv = membrane_terms(model, wu, wv, area[t], p0[t], p1[t])
        ft[t, 0] = -(g0[0] * Pu + g0[1] * Pv)
        ft[t, 1] = -(g1[0] * Pu + g1[1] * Pv)
        ft[t, 2] = -(g2[0] * Pu + g2[1] * Pv)


@ti.kernel
def membrane_hessian_kernel(x: vec3_array, tris: triangle_array, Dinv: ti.types.ndarray(dtype=mat2, ndim=1),
                            area: scalar_array, p0: scalar_array, p1: scalar_array, model: ti.template(),
                            psd: ti.template(), diagonal: ti.template(), out: mat3_array2):
    # diagonal=False: out[t, 3a + b] = H_ab;  diagonal=True: out[t, a] = H_aa
    for t in range(tris.shape[0]):
        wu, wv, g, W, S, Pu, Pv = _triangle(x, tris, Dinv, area, p0, p1, model, t)
        for a in ti.static(range(3)):
            for b in ti.static(range(3)):
                if ti.static(not diagonal):
                    out[t, 3 * a + b] = block_ab(model, psd, wu, wv, g[a], g[b], S, area[t], p0[t], p1[t])
                elif ti.static(a == b):
                    out[t, a] = block_ab(model, psd, wu, wv, g[a], g[a], S, area[t], p0[t], p1[t])


@ti.kernel
def membrane_products_kernel(x: vec3_array, tris: triangle_array, Dinv: ti.types.ndarray(dtype=mat2, ndim=1),
                             area: scalar_array, p0: scalar_array, p1: scalar_array, model: ti.template(),
                             psd: ti.template(), dx: vec3_array, yt: vec3_array2):
    # pass 1 of out += H dx: yt[t, a] = sum_b H_ab dx[corner b]
    for t in range(tris.shape[0]):
        wu, wv, g, W, S, Pu, Pv = _triangle(x, tris, Dinv, area, p0, p1, model, t)
        for a in ti.static(range(3)):
            y = ti.math.vec3(0.0)
            for b in ti.static(range(3)):
                y += block_ab(model, psd, wu, wv, g[a], g[b], S, area[t], p0[t], p1[t]) @ dx[tris[t, b]]
            yt[t, a] = y


@ti.kernel
def block_products_kernel(blocks: mat3_array2, tris: triangle_array, dx: vec3_array, yt: vec3_array2):
    for t in range(tris.shape[0]):
        for a in ti.static(range(3)):
            y = ti.math.vec3(0.0)
            for b in ti.static(range(3)):
                y += blocks[t, 3 * a + b] @ dx[tris[t, b]]
            yt[t, a] = y


@ti.kernel
def gather_corners_kernel(vt: vec3_array2, offsets: int_array, entries: int_array, out: vec3_array):
    for v in range(offsets.shape[0] - 1):
        out[v] += slot_gather(vt, offsets, entries, v, 3)


@ti.func
def condition_gradients(wu, wv, g, A):
    """dC/dx_a of Baraff-Witkin's three conditions for the corners a = 0, 1, 2: (stretch u,
    stretch v, shear) lists of vec3, (M2)."""
    r = ti.sqrt(A)
    nu_, nv_ = wu / wu.norm(), wv / wv.norm()
    gu = [r * g[a][0] * nu_ for a in ti.static(range(3))]
    gv = [r * g[a][1] * nv_ for a in ti.static(range(3))]
    gs = [r * (g[a][0] * wv + g[a][1] * wu) for a in ti.static(range(3))]
    return gu, gv, gs


@ti.kernel
def damping_products_kernel(x: vec3_array, tris: triangle_array, Dinv: ti.types.ndarray(dtype=mat2, ndim=1),
                            area: scalar_array, kd_s: scalar_array, kd_h: scalar_array, w: vec3_array,
                            yt: vec3_array2):
    # pass 1 of out += D(x) w (M3): yt[t, a] = sum_c kd_c dC_c/dx_a (sum_b dC_c/dx_b . w_b)
    for t in range(tris.shape[0]):
        wu, wv, g0, g1, g2 = triangle_frame(x, tris, Dinv, t)
        gu, gv, gs = condition_gradients(wu, wv, [g0, g1, g2], area[t])
        ru, rv, rs = 0.0, 0.0, 0.0
        for b in ti.static(range(3)):
            wb = w[tris[t, b]]
            ru += gu[b].dot(wb)
            rv += gv[b].dot(wb)
            rs += gs[b].dot(wb)
        for a in ti.static(range(3)):
            yt[t, a] = kd_s[t] * (ru * gu[a] + rv * gv[a]) + kd_h[t] * rs * gs[a]


@ti.kernel
def damping_blocks_kernel(x: vec3_array, tris: triangle_array, Dinv: ti.types.ndarray(dtype=mat2, ndim=1),
                          area: scalar_array, kd_s: scalar_array, kd_h: scalar_array, out: mat3_array2):
    # out[t, 3a + b] = D_ab = sum_c kd_c dC_c/dx_a (dC_c/dx_b)^T
    for t in range(tris.shape[0]):
        wu, wv, g0, g1, g2 = triangle_frame(x, tris, Dinv, t)
        gu, gv, gs = condition_gradients(wu, wv, [g0, g1, g2], area[t])
        for a in ti.static(range(3)):
            for b in ti.static(range(3)):
                out[t, 3 * a + b] = (kd_s[t] * (gu[a].outer_product(gu[b]) + gv[a].outer_product(gv[b]))
                                     + kd_h[t] * gs[a].outer_product(gs[b]))


@ti.kernel
def _negate_corners(yt: vec3_array2):
    for t, a in yt:
        yt[t, a] = -yt[t, a]


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
    """A membrane energy over triangles, (M1) "stvk" or (M2) "baraff-witkin" (module docstring).

    Parameters
      rest_positions  (n, 3) rest positions [m] ((n, 2) is embedded at z = 0)
      triangles       (m, 3) vertex indices
      model           "stvk": Y (2D Young's modulus, N/m, > 0) and nu (Poisson's ratio, in [0, 0.5));
                      "baraff-witkin": k_stretch and k_shear (N/m, >= 0)
      direction       the material direction the (u, v) frames' u axis follows (default x)

    As a stencil (engine/energies/base.py): k = 3, ``elements`` = the triangles, ``block`` reads
    :meth:`hessian_blocks`' (m, 9) layout, product "blocks"; force form "corner-gather"
    (:meth:`corner_force_launch`, ``per_corner``, ``slot_incidence``).
    """

    name = "membrane"
    stencil_size = 3
    block = staticmethod(membrane_block)
    products = frozenset({"blocks", "element-blocks"})
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
        _negate_corners(self.per_corner)
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
