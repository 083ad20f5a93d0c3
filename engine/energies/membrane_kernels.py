"""The membrane energies' kernels over triangle arrays: energies, corner forces, Hessian blocks and
products, Baraff and Witkin's damping (M3), and the per-vertex gathers.

They sum the one-triangle math of engine/energies/triangle.py ((F1), (M1), (M2)) over a
membrane's triangles; :class:`engine.energies.membrane.MembraneEnergy` launches them (its module
docstring states the damping (M3)). Arguments after x: the triangles (m, 3), Dm^-1 per triangle
(m,) mat2, the rest areas and the two parameters per triangle, then the model code (a template).
Hessian block layout: ``blocks[t, 3*a + b]`` (mat3) is d2W_t/dx_a dx_b for corners a, b.

Kernels work per triangle (parallel, results per triangle) and gather per vertex over the
corner incidence (entry = 3 triangle + corner), deterministic, as the hinge energy does.
"""
import taichi as ti

from engine.energies.base import slot_gather
from engine.energies.triangle import (block_ab, condition_gradients, deformation_blocks, mat2, membrane_terms,
                                     triangle_frame)
from engine.fields import int_array, mat3_array2, scalar_array, vec3_array, vec3_array2
from engine.fields import int_array2 as triangle_array
from engine.launch import kernel as fast_kernel


@ti.func
def _triangle(x: ti.template(), tris: ti.template(), Dinv: ti.template(), area: ti.template(),
              p0: ti.template(), p1: ti.template(), model: ti.template(), t):
    """(w_u, w_v, [g_a], W, S, P_u, P_v) of triangle t: :func:`triangle_frame` and :func:`membrane_terms`."""
    wu, wv, g0, g1, g2 = triangle_frame(x, tris, Dinv, t)
    W, S, Pu, Pv = membrane_terms(model, wu, wv, area[t], p0[t], p1[t])
    return wu, wv, [g0, g1, g2], W, S, Pu, Pv


@ti.func
def membrane_block(blocks: ti.template(), t, a, b) -> ti.math.mat3:
    """Block (a, b) of triangle t in the layout of :meth:`MembraneEnergy.hessian_blocks` (a, b:
    compile-time or run-time slots)."""
    return blocks[t, 3 * a + b]


# --------------------------------------------------------------------------------------------
# Kernels (per triangle, then per vertex: no atomics)
# --------------------------------------------------------------------------------------------

@fast_kernel
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
def membrane_deformation_blocks_kernel(x: vec3_array, tris: triangle_array, Dinv: ti.types.ndarray(dtype=mat2, ndim=1),
                                       area: scalar_array, p0: scalar_array, p1: scalar_array, model: ti.template(),
                                       psd: ti.template(), out: mat3_array2):
    # out[t] = (A_uu, A_uv, A_vv) of triangle t (triangle.deformation_blocks)
    for t in range(tris.shape[0]):
        wu, wv, g, W, S, Pu, Pv = _triangle(x, tris, Dinv, area, p0, p1, model, t)
        Auu, Auv, Avv = deformation_blocks(model, psd, wu, wv, S, area[t], p0[t], p1[t])
        out[t, 0] = Auu
        out[t, 1] = Auv
        out[t, 2] = Avv


@ti.func
def deformation_corners(fblocks: ti.template(), Dinv: ti.template(), tris: ti.template(), z: ti.template(),
                        p: ti.template(), beta, t):
    """((H_t d)_0, (H_t d)_1, (H_t d)_2) for d = z + beta p at the triangle's corners, from its
    deformation blocks (triangle.deformation_blocks): dw_j = sum_b g_bj d_b, r_i = sum_j A_ij dw_j,
    (H d)_a = sum_i g_ai r_i."""
    D = Dinv[t]
    d0 = z[tris[t, 0]] + beta * p[tris[t, 0]]
    d1 = z[tris[t, 1]] + beta * p[tris[t, 1]] - d0
    d2 = z[tris[t, 2]] + beta * p[tris[t, 2]] - d0
    dwu = d1 * D[0, 0] + d2 * D[1, 0]          # g0 = -(g1 + g2): sum_b g_bj d_b = g1j (d1 - d0) + g2j (d2 - d0)
    dwv = d1 * D[0, 1] + d2 * D[1, 1]
    Auv = fblocks[t, 1]
    ru = fblocks[t, 0] @ dwu + Auv @ dwv
    rv = Auv.transpose() @ dwu + fblocks[t, 2] @ dwv
    y1 = D[0, 0] * ru + D[0, 1] * rv
    y2 = D[1, 0] * ru + D[1, 1] * rv
    return -(y1 + y2), y1, y2


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


# --------------------------------------------------------------------------------------------
# Baraff and Witkin's damping (M3): D(x) from the conditions' gradients
# --------------------------------------------------------------------------------------------

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
def negate_corners(yt: vec3_array2):
    for t, a in yt:
        yt[t, a] = -yt[t, a]
