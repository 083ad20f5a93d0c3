"""The bending energy's kernels over hinge arrays: hinge energies, forces (a per-hinge pass and a
per-vertex gather), Hessian blocks, products and Gauss-Newton factors, and numpy references of the
gather and of the block layout.

They sum the one-hinge math of engine/energies/hinge.py, (W1)/(W2) of engine/energies/bending.py,
over a bending energy's hinges; :class:`engine.energies.bending.BendingEnergy` launches them.
Arguments after x: the hinges (h, 4) [v0, v1, w0, w1], k_e and theta_bar per hinge, and the
hinge mode ((W1) or (W2)).

Hessian block layout: ``blocks[h, 4*a + b]`` (mat3) is d2W_h/dx_a dx_b for slots a, b in
[v0, v1, w0, w1] order.

Parallel assembly without float atomics: kernel 1 writes each hinge's four vectors into an
(h, 4) vec3 ndarray in parallel; kernel 2 gathers per vertex over a CSR incidence
(vertex -> entries 4*hinge + slot, in increasing hinge order), so results are
deterministic.  The energy total is a parallel reduction (not bitwise reproducible across
thread counts; the per-hinge values are).
"""
import numpy as np
import taichi as ti

from engine.energies.base import slot_gather
from engine.energies.hinge import (dihedral_angle, dihedral_angle_gradient, dihedral_angle_hessian_block,
                                   dihedral_angle_hessian_parts, hinge_energy, hinge_energy_terms, hinge_forces,
                                   hinge_hessian_block, hinge_hessian_parts, row_frame)
from engine.fields import int_array, mat3_array2, scalar_array, vec3_array, vec3_array2
from engine.fields import int_array2 as hinge_array
from engine.launch import kernel as fast_kernel


# --------------------------------------------------------------------------------------------
# Taichi functions
# --------------------------------------------------------------------------------------------

@ti.func
def _hinge_terms(x: ti.template(), hinges: ti.template(), k: ti.template(), theta_bar: ti.template(), mode, h):
    """Per-hinge set-up of the force and Hessian kernels: the frame (e, a0, a1), W' and W'' of
    (W1)/(W2) at theta (A1), and g = grad theta (G1)-(G3) over the slots (v0, v1, w0, w1)."""
    e, a0, a1 = row_frame(x, hinges, h)
    W, W1, W2 = hinge_energy_terms(dihedral_angle(e, a0, a1), k[h], theta_bar[h], mode)
    return e, a0, a1, W1, W2, dihedral_angle_gradient(e, a0, a1)


@ti.func
def hinge_block(blocks: ti.template(), h, a, b) -> ti.math.mat3:
    """Block (a, b) = d2W_h/dx_a dx_b of the layout of :meth:`BendingEnergy.hessian_blocks` (a, b:
    compile-time or run-time slots)."""
    return blocks[h, 4 * a + b]


# --------------------------------------------------------------------------------------------
# Kernels (per hinge, parallel; results per hinge, no atomics)
# --------------------------------------------------------------------------------------------

@ti.kernel
def hinge_energies_kernel(x: vec3_array, hinges: hinge_array, k: scalar_array, theta_bar: scalar_array,
                          mode: ti.i32, out: scalar_array):
    # (W1)/(W2) per hinge
    for h in range(hinges.shape[0]):
        e, a0, a1 = row_frame(x, hinges, h)
        out[h] = hinge_energy(e, a0, a1, k[h], theta_bar[h], mode)


@fast_kernel
def bending_energy_kernel(x: vec3_array, hinges: hinge_array, k: scalar_array, theta_bar: scalar_array,
                          mode: ti.i32) -> float:
    # sum_e W_e, (W1)/(W2); parallel reduction
    total = 0.0
    for h in range(hinges.shape[0]):
        e, a0, a1 = row_frame(x, hinges, h)
        total += hinge_energy(e, a0, a1, k[h], theta_bar[h], mode)
    return total


@ti.func
def hinge_force_vectors(x: ti.template(), hinges: ti.template(), k: ti.template(), theta_bar: ti.template(),
                        mode, fh: ti.template(), h):
    """Pass 1 for hinge h: fh[h, slot] = -dW_h/dx_slot = -W'(theta) dtheta/dx_slot (= W' u, Bridson's u)."""
    e, a0, a1 = row_frame(x, hinges, h)
    f = hinge_forces(e, a0, a1, k[h], theta_bar[h], mode)
    for a in ti.static(range(4)):
        fh[h, a] = f[a]


@ti.func
def hinge_gather(vh: ti.template(), offsets: ti.template(), entries: ti.template(), v):
    """Pass 2 for vertex v: the sum over its incidences (entry = 4*hinge + slot) of vh[hinge, slot]."""
    return slot_gather(vh, offsets, entries, v, 4)


@ti.kernel
def hinge_forces_kernel(x: vec3_array, hinges: hinge_array, k: scalar_array, theta_bar: scalar_array,
                        mode: ti.i32, fh: vec3_array2):
    for h in range(hinges.shape[0]):
        hinge_force_vectors(x, hinges, k, theta_bar, mode, fh, h)


@ti.kernel
def gather_hinge_vectors_kernel(vh: vec3_array2, offsets: int_array, entries: int_array, out: vec3_array):
    for v in range(offsets.shape[0] - 1):
        out[v] += hinge_gather(vh, offsets, entries, v)


@ti.kernel
def hinge_hessian_kernel(x: vec3_array, hinges: hinge_array, k: scalar_array, theta_bar: scalar_array,
                         mode: ti.i32, psd: ti.template(), diagonal: ti.template(), out: mat3_array2):
    # psd: max(W'', 0) g g^T;  exact: W'' g g^T + W' Hess(theta).
    # diagonal=False: out[h, 4a + b] = H_ab (h, 16);  diagonal=True (block-Jacobi pass 1): out[h, a] = H_aa (h, 4)
    for h in range(hinges.shape[0]):
        e, a0, a1, W1, W2, g = _hinge_terms(x, hinges, k, theta_bar, mode, h)
        parts = hinge_hessian_parts(psd, e, a0, a1)
        for i in ti.static(range(4)):
            for j in ti.static(range(4)):
                if ti.static(not diagonal):
                    out[h, 4 * i + j] = hinge_hessian_block(i, j, psd, W1, W2, g, parts)
                elif ti.static(i == j):
                    out[h, i] = hinge_hessian_block(i, i, psd, W1, W2, g, parts)


@fast_kernel
def hinge_gauss_newton_factors_kernel(x: vec3_array, hinges: hinge_array, k: scalar_array, theta_bar: scalar_array,
                                      mode: ti.i32, w: vec3_array2):
    # the Gauss-Newton hinge Hessian max(W'', 0) g g^T = w w^T:  w[h, slot] = sqrt(max(W'', 0)) dtheta/dx_slot
    for h in range(hinges.shape[0]):
        e, a0, a1, W1, W2, g = _hinge_terms(x, hinges, k, theta_bar, mode, h)
        c = ti.sqrt(ti.max(W2, 0.0))
        for a in ti.static(range(4)):
            w[h, a] = c * g[a]


@ti.kernel
def hinge_hessian_products_kernel(x: vec3_array, hinges: hinge_array, k: scalar_array, theta_bar: scalar_array,
                                  mode: ti.i32, psd: ti.template(), dx: vec3_array, yh: vec3_array2):
    # pass 1 of out += H dx: yh[h, a] = sum_b H_ab dx[hinge slot b], blocks recomputed from x
    for h in range(hinges.shape[0]):
        e, a0, a1, W1, W2, g = _hinge_terms(x, hinges, k, theta_bar, mode, h)
        d = [dx[hinges[h, 0]], dx[hinges[h, 1]], dx[hinges[h, 2]], dx[hinges[h, 3]]]
        gd = g[0].dot(d[0]) + g[1].dot(d[1]) + g[2].dot(d[2]) + g[3].dot(d[3])
        if ti.static(psd):
            c = ti.max(W2, 0.0) * gd
            for i in ti.static(range(4)):
                yh[h, i] = c * g[i]
        else:
            parts = dihedral_angle_hessian_parts(e, a0, a1)
            for i in ti.static(range(4)):
                y = (W2 * gd) * g[i]
                for j in ti.static(range(4)):
                    y += W1 * (dihedral_angle_hessian_block(i, j, *parts) @ d[j])
                yh[h, i] = y


# --------------------------------------------------------------------------------------------
# numpy references (tests, small meshes)
# --------------------------------------------------------------------------------------------

def scatter_hinge_vectors_numpy(n: int, hinges: np.ndarray, vh: np.ndarray) -> np.ndarray:
    """Reference scatter: out[v] = sum of vh[h, slot] over (h, slot) with hinges[h, slot] = v."""
    out = np.zeros((n, 3))
    np.add.at(out, np.asarray(hinges).reshape(-1), np.asarray(vh, dtype=np.float64).reshape(-1, 3))
    return out


def dense_hessian_from_hinge_blocks(n: int, hinges: np.ndarray, blocks: np.ndarray) -> np.ndarray:
    """Dense (3n, 3n) Hessian from blocks (h, 16, 3, 3), blocks[h, 4a+b] on slots (a, b)."""
    Hd = np.zeros((3 * n, 3 * n))
    blocks = np.asarray(blocks, dtype=np.float64).reshape(-1, 16, 3, 3)
    for h, row in enumerate(np.asarray(hinges)):
        for a in range(4):
            for b in range(4):
                i, j = 3 * int(row[a]), 3 * int(row[b])
                Hd[i:i + 3, j:j + 3] += blocks[h, 4 * a + b]
    return Hd
