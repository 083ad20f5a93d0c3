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

from engine.energies.bending import (BendingEnergy, _energy_terms, _frame, _theta, _theta_grad, hinge_array,
                                     int_array, vec3_array2)
from engine.energies.springs import SpringEnergy
from engine.model import scalar_array, vec3_array


@ti.func
def _spring_gather(x: ti.template(), i, offsets: ti.template(), inc_other: ti.template(),
                   inc_inv_L: ti.template(), inc_c_over_L: ti.template()):
    acc = ti.math.vec3(0.0)
    xi = x[i]
    for k in range(offsets[i], offsets[i + 1]):
        d = xi - x[inc_other[k]]
        l = d.norm()
        if l > 0.0:
            acc -= inc_c_over_L[k] * (inc_inv_L[k] - 1.0 / l) * d
    return acc


@ti.kernel
def se_step_springs(x: vec3_array, v: vec3_array, inv_mass: scalar_array, g: ti.math.vec3, dt: float,
                    offsets: int_array, inc_other: int_array, inc_inv_L: scalar_array, inc_c_over_L: scalar_array):
    for i in range(x.shape[0]):
        f = ti.math.vec3(0.0)
        f += _spring_gather(x, i, offsets, inc_other, inc_inv_L, inc_c_over_L)
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
        e, a0, a1 = _frame(x, hinges, h)
        W, W1, W2 = _energy_terms(_theta(e, a0, a1), k[h], theta_bar[h], mode)
        gr = _theta_grad(e, a0, a1)
        for a in ti.static(range(4)):
            fh[h, a] = -W1 * gr[a]
    for i in range(x.shape[0]):
        f = ti.math.vec3(0.0)
        f += _spring_gather(x, i, offsets, inc_other, inc_inv_L, inc_c_over_L)
        acc = ti.math.vec3(0.0)
        for j in range(h_offsets[i], h_offsets[i + 1]):
            ent = h_entries[j]
            acc += fh[ent // 4, ent % 4]
        f += acc
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
