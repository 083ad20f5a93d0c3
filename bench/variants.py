"""Bench-only Taichi kernels: the force-kernel variants and the streaming-copy bandwidth probe.

Force-kernel variants, against the engine's data (engine/energies/springs.py, bending.py), the
engine's own formulas (its ti.funcs :func:`engine.energies.springs.spring_force` and
:func:`engine.energies.hinge.hinge_forces`):

  springs (S2)   f_i += -(c_e/L_e)(1/L_e - 1/l_e)(x_i - x_j),  f_j -= the same
  bending        f_slot += -W'(theta) dtheta/dx_slot   (W1/W2, (G1)-(G3))

* ``atomic``: one parallel loop over the elements, scattered with float atomics (on the CPU a
  compare-and-swap loop per component; results not bitwise reproducible with 2 threads).
* ``serial``: the same loop with ``ti.loop_config(serialize=True)`` (one thread, plain adds).
* the engine's own: springs gather per vertex over the CSR incidence
  (``spring_add_forces_kernel``); bending computes per-hinge vectors in parallel then gathers
  per vertex (``hinge_forces_kernel`` + ``gather_hinge_vectors_kernel``). Deterministic.

The bandwidth probe (:func:`stream_copy`) copies one f64 array into another in a parallel loop;
bytes moved = 2 x size (read + write; the write-allocate read of the destination is not counted,
as in STREAM's "copy").
"""
import taichi as ti

from engine.energies.hinge import hinge_forces, row_frame
from engine.energies.springs import edge_array, spring_force
from engine.fields import scalar_array, vec3_array

hinge_array = ti.types.ndarray(dtype=ti.i32, ndim=2)
f64_array = ti.types.ndarray(dtype=ti.f64, ndim=1)


@ti.func
def _spring_force(x: ti.template(), edges: ti.template(), L: ti.template(), c: ti.template(), e):
    # (S2): force on edges[e][0] (engine.energies.springs.spring_force)
    return spring_force(x[edges[e][0]] - x[edges[e][1]], 1.0 / L[e], c[e] / L[e])


@ti.kernel
def spring_forces_atomic(x: vec3_array, edges: edge_array, L: scalar_array, c: scalar_array, f: vec3_array):
    for e in range(edges.shape[0]):
        fe = _spring_force(x, edges, L, c, e)
        ti.atomic_add(f[edges[e][0]], fe)
        ti.atomic_sub(f[edges[e][1]], fe)


@ti.kernel
def spring_forces_serial(x: vec3_array, edges: edge_array, L: scalar_array, c: scalar_array, f: vec3_array):
    ti.loop_config(serialize=True)
    for e in range(edges.shape[0]):
        fe = _spring_force(x, edges, L, c, e)
        f[edges[e][0]] += fe
        f[edges[e][1]] -= fe


@ti.kernel
def hinge_forces_atomic(x: vec3_array, hinges: hinge_array, k: scalar_array, theta_bar: scalar_array,
                        mode: ti.i32, f: vec3_array):
    for h in range(hinges.shape[0]):
        e, a0, a1 = row_frame(x, hinges, h)
        fh = hinge_forces(e, a0, a1, k[h], theta_bar[h], mode)
        for a in ti.static(range(4)):
            ti.atomic_add(f[hinges[h, a]], fh[a])


@ti.kernel
def hinge_forces_serial(x: vec3_array, hinges: hinge_array, k: scalar_array, theta_bar: scalar_array,
                        mode: ti.i32, f: vec3_array):
    ti.loop_config(serialize=True)
    for h in range(hinges.shape[0]):
        e, a0, a1 = row_frame(x, hinges, h)
        fh = hinge_forces(e, a0, a1, k[h], theta_bar[h], mode)
        for a in ti.static(range(4)):
            f[hinges[h, a]] += fh[a]


@ti.kernel
def stream_copy(src: f64_array, dst: f64_array):
    for i in range(src.shape[0]):
        dst[i] = src[i]


def spring_variant(name: str):
    """``(x, springs, f) -> None`` adding the spring forces to f with the named variant."""
    if name == "atomic":
        return lambda x, sp, f: spring_forces_atomic(x, sp.edges, sp.L, sp.c, f)
    if name == "serial":
        return lambda x, sp, f: spring_forces_serial(x, sp.edges, sp.L, sp.c, f)
    if name == "gather":
        return lambda x, sp, f: sp.add_forces(x, f)
    raise ValueError(f"unknown spring variant {name!r}")


def bending_variant(name: str):
    """``(x, bending, f) -> None`` adding the bending forces to f with the named variant."""
    if name == "atomic":
        return lambda x, be, f: hinge_forces_atomic(x, *be.hinge_args(), f)
    if name == "serial":
        return lambda x, be, f: hinge_forces_serial(x, *be.hinge_args(), f)
    if name == "gather":
        return lambda x, be, f: be.add_forces(x, f)
    raise ValueError(f"unknown bending variant {name!r}")


VARIANTS = ("atomic", "serial", "gather")
