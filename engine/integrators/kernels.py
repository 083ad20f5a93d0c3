"""The explicit updates, written once, and the per-vertex kernels that apply them.

Newton's second law for lumped masses, M dv/dt = f(x) = -dW/dx, with a = M^-1 f + g for free
vertices and a = 0, v = 0 for pinned ones (inverse mass 0):

  forward Euler      x+ = x + dt v ;          v+ = v + dt a(x)          (both from the old state)   (E1)
  symplectic Euler   v+ = v + dt a(x) ;       x+ = x + dt v+                                       (E2)
  velocity Verlet    v* = v + dt/2 a(x) ;     x+ = x + dt v* ;   v+ = v* + dt/2 a(x+)              (E3)
                     (kick-drift-kick; a(x+) is kept for the next step)

:func:`vertex_update` is the only place these formulas are written; every explicit kernel calls it
(directly or through :func:`update`, its in-place form):

* :func:`update_kernel` - one pass over the vertices with the forces already in ``f`` (the
  generic path: any energies, their own force kernels first);
* :func:`corner_update_kernel` - the gather of a "corner-gather" energy's per-element forces
  (membranes) fused with the update: with that energy's own force kernel, two bound launches per
  step (engine.integrators.explicit.corner_stepper);
* engine.integrators.cloth_kernels: :func:`cloth_step` and :func:`cloth_steps`, a symplectic-Euler
  or velocity-Verlet step (or many) of a springs [+ one hinge energy] model in ONE launch, over
  vertex blocks;
* engine.integrators.batched_steps: :func:`many_steps` and :func:`axial_steps`, many steps of a
  small spring-only model, or of the rod along its axis, in ONE launch.

Where a step is launched often, its arguments are bound once (engine.launch.BoundKernel).

Method codes: :data:`METHODS` is the one table of them.
"""
import taichi as ti

from engine.constants import INTEGRATOR_NAMES
from engine.energies.base import slot_gather
from engine.fields import int_array, scalar_array, vec3_array, vec3_array2

FORWARD_EULER, SYMPLECTIC_EULER, VELOCITY_VERLET, BACKWARD_EULER = 0, 1, 2, 3
METHODS = dict(zip(INTEGRATOR_NAMES, (FORWARD_EULER, SYMPLECTIC_EULER, VELOCITY_VERLET, BACKWARD_EULER)))

# phases of update(): which part of a step a loop performs
STEP = 0        # the whole per-vertex update of (E1) or (E2) (forces of the old state in f)
KICK = 1        # (E2) velocity only
DRIFT = 2       # (E2) position only
KICK_DRIFT = 3  # (E3) first half: v* = v + dt/2 a ; x+ = x + dt v*
ACCEL_KICK = 4  # (E3) a = M^-1 f + g ; v += h a  (h = dt/2; h = 0 only computes a)


@ti.func
def vertex_update(method: ti.template(), phase: ti.template(), xi, vi, ai, f_i, inv_m, g, dt, zero):
    """(E1), (E2) or a half of (E3) for one vertex, on values: returns the new (x_i, v_i, a_i).
    ``f_i`` is the force on the vertex, ``inv_m`` its inverse mass; a pinned vertex (inv_m = 0)
    keeps x and gets v = ``zero`` (a vec3 for the 3D models, a scalar for the rod along its axis)."""
    if ti.static(method == FORWARD_EULER):
        if inv_m > 0.0:
            xi = xi + dt * vi
            vi = vi + dt * (inv_m * f_i + g)
        else:
            vi = zero
    elif ti.static(method == SYMPLECTIC_EULER):
        if ti.static(phase == DRIFT):
            if inv_m > 0.0:
                xi = xi + dt * vi
        else:
            if inv_m > 0.0:
                vi = vi + dt * (inv_m * f_i + g)
                if ti.static(phase == STEP):
                    xi = xi + dt * vi
            else:
                vi = zero
    elif ti.static(phase == KICK_DRIFT):
        if inv_m > 0.0:
            vi = vi + 0.5 * dt * ai
            xi = xi + dt * vi
        else:
            vi = zero
    else:  # ACCEL_KICK, dt = the half step
        if inv_m > 0.0:
            ai = inv_m * f_i + g
            vi = vi + dt * ai
        else:
            ai = zero
            vi = zero
    return xi, vi, ai


@ti.func
def update(method: ti.template(), phase: ti.template(), i, x: ti.template(), v: ti.template(), f_i,
           a: ti.template(), inv_mass: ti.template(), g, dt, zero):
    """:func:`vertex_update` of vertex i in place: reads x[i], v[i] (and a[i]), writes back what the
    phase changes. Plain loads and stores (no atomics, whatever loop i comes from)."""
    ai = zero
    if ti.static(method == VELOCITY_VERLET and phase == KICK_DRIFT):
        ai = a[i]
    xi, vi, ai = vertex_update(method, phase, x[i], v[i], ai, f_i, inv_mass[i], g, dt, zero)
    if ti.static(method == FORWARD_EULER or phase in (STEP, DRIFT, KICK_DRIFT)):
        x[i] = xi
    if ti.static(method == FORWARD_EULER or phase != DRIFT):
        v[i] = vi
    if ti.static(method == VELOCITY_VERLET and phase == ACCEL_KICK):
        a[i] = ai


@ti.kernel
def update_kernel(x: vec3_array, v: vec3_array, f: vec3_array, a: vec3_array, inv_mass: scalar_array,
                  g: ti.math.vec3, dt: float, method: ti.template(), phase: ti.template()):
    for i in range(x.shape[0]):
        update(method, phase, i, x, v, f[i], a, inv_mass, g, dt, ti.math.vec3(0.0))


@ti.kernel
def corner_update_kernel(x: vec3_array, v: vec3_array, dt: float, a: vec3_array, vh: vec3_array2,
                         offsets: int_array, entries: int_array, inv_mass: scalar_array, gx: float, gy: float,
                         gz: float, k: ti.template(), method: ti.template(), phase: ti.template()):
    """:func:`update` of every vertex with the force gathered from a stencil energy's per-element
    corner forces ``vh`` over its incidence (entry = k*element + slot; KICK_DRIFT gathers nothing):
    the generic path's gather into a zeroed f and its update pass, in one loop and the same order
    (:func:`engine.integrators.explicit.corner_stepper`; g as three floats so that a BoundKernel
    can launch it)."""
    for i in range(x.shape[0]):
        f_i = ti.math.vec3(0.0)
        if ti.static(phase != KICK_DRIFT):
            f_i = f_i + slot_gather(vh, offsets, entries, i, k)
        update(method, phase, i, x, v, f_i, a, inv_mass, ti.math.vec3(gx, gy, gz), dt, ti.math.vec3(0.0))
