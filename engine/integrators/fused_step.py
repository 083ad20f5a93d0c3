"""One kernel launch per symplectic-Euler step for the common models: springs, or springs
followed by one dihedral bending energy (the lessons' cloth).

The generic path launches five kernels per step (zero f, spring gather, per-hinge bending pass,
hinge gather, update); on a CPU each launch has a fixed cost of tens of microseconds, which
dominates small meshes. Here the same arithmetic runs as the consecutive top-level loops of
one kernel (Taichi runs them in order, so each loop sees the previous one's results):

  1. per hinge: the bending force vectors (as ``hinge_forces_kernel``)
  2. per vertex: f = spring gather + hinge gather; v+ = v + dt (M^-1 f + g)
  3. per vertex: x+ = x + dt v+

Every vertex's forces are summed in the same order as the generic path (springs, then
bending), so both give bitwise the same states; a test checks it.
"""

import taichi as ti

from engine.energies.bending import BendingEnergy, hinge_force_vectors, hinge_gather
from engine.energies.springs import SpringEnergy, spring_gather
from engine.fields import int_array, scalar_array, vec3_array, vec3_array2
from engine.fields import int_array2 as hinge_array


@ti.kernel
def se_step_springs(x: vec3_array, v: vec3_array, inv_mass: scalar_array, g: ti.math.vec3, dt: float,
                    offsets: int_array, inc_other: int_array, inc_inv_L: scalar_array, inc_c_over_L: scalar_array):
    for i in range(x.shape[0]):
        f = ti.math.vec3(0.0)
        f += spring_gather(x, i, offsets, inc_other, inc_inv_L, inc_c_over_L)
        if inv_mass[i] > 0.0:
            v[i] += dt * (inv_mass[i] * f + g)
        else:
            v[i] = ti.math.vec3(0.0)
    for i in range(x.shape[0]):
        if inv_mass[i] > 0.0:
            x[i] += dt * v[i]


@ti.kernel
def se_step_springs_bending(x: vec3_array, v: vec3_array, inv_mass: scalar_array, g: ti.math.vec3, dt: float,
                            offsets: int_array, inc_other: int_array, inc_inv_L: scalar_array,
                            inc_c_over_L: scalar_array, hinges: hinge_array, k: scalar_array,
                            theta_bar: scalar_array, mode: ti.i32, fh: vec3_array2, h_offsets: int_array,
                            h_entries: int_array):
    for h in range(hinges.shape[0]):
        hinge_force_vectors(x, hinges, k, theta_bar, mode, fh, h)
    for i in range(x.shape[0]):
        f = ti.math.vec3(0.0)
        f += spring_gather(x, i, offsets, inc_other, inc_inv_L, inc_c_over_L)
        f += hinge_gather(fh, h_offsets, h_entries, i)
        if inv_mass[i] > 0.0:
            v[i] += dt * (inv_mass[i] * f + g)
        else:
            v[i] = ti.math.vec3(0.0)
    for i in range(x.shape[0]):
        if inv_mass[i] > 0.0:
            x[i] += dt * v[i]


def fused_symplectic_step(model):
    """A function ``step(state, dt)`` doing one symplectic-Euler step in one launch, or None when
    the model's energies are not springs [+ one bending energy] in that order. Cached on the model
    (rebuilt if its energies change)."""
    key = tuple(id(e) for e in model.energies)
    cached = getattr(model, "_fused_se", None)
    if cached is not None and cached[0] == key:
        return cached[1]
    fn = None
    es = list(model.energies)
    if len(es) >= 1 and type(es[0]) is SpringEnergy and es[0].m > 0:
        s = es[0]
        sargs = (s.offsets, s.inc_other, s.inc_inv_L, s.inc_c_over_L)
        if len(es) == 1:
            def fn(state, dt):
                se_step_springs(state.x, state.v, model.inv_mass_nd, model.gravity_vec, dt, *sargs)
        elif len(es) == 2 and type(es[1]) is BendingEnergy and es[1].n_hinges > 0 \
                and es[1].n_vertices == model.n:
            b = es[1]
            bargs = (*b._args(), b._per_hinge_vec, b._offsets, b._entries)

            def fn(state, dt):
                se_step_springs_bending(state.x, state.v, model.inv_mass_nd, model.gravity_vec, dt, *sargs,
                                        *bargs)
    model._fused_se = (key, fn)
    return fn
