"""The explicit updates, written once, and the kernels generated from them.

Newton's second law for lumped masses, M dv/dt = f(x) = -dW/dx, with a = M^-1 f + g for free
vertices and a = 0, v = 0 for pinned ones (inverse mass 0):

  forward Euler      x+ = x + dt v ;          v+ = v + dt a(x)          (both from the old state)   (E1)
  symplectic Euler   v+ = v + dt a(x) ;       x+ = x + dt v+                                       (E2)
  velocity Verlet    v* = v + dt/2 a(x) ;     x+ = x + dt v* ;   v+ = v* + dt/2 a(x+)              (E3)
                     (kick-drift-kick; a(x+) is kept for the next step)

:func:`update` is the only place these formulas are written; every kernel below calls it:

* :func:`update_kernel` - one pass over the vertices with the forces already in ``f`` (the
  generic path: any energies, their own force kernels first);
* :func:`one_launch_step` - a symplectic-Euler step of a springs [+ one hinge energy] model as the
  consecutive loops of ONE kernel (per hinge: bending force vectors; per vertex: spring gather +
  hinge gather + kick; per vertex: drift). A CPU kernel launch costs ~0.1 ms, which dominates
  small meshes; the forces are summed in the same order as the generic path (springs, then
  bending), so the states are bitwise the same (tested);
* :func:`many_steps` - many steps of a spring-only model in ONE launch (the step loop
  serialised, every inner loop serial), writing each step's kinetic and potential energy and
  stopping at the first step whose total is not finite or above the bound. For small models
  (chains, frames) where launches would cost more than the arithmetic;
* :func:`axial_steps` - the same for the rod along its axis, one coordinate per node, backward
  Euler included (engine.solvers.thomas).

Method codes: :data:`METHODS` is the one table of them.
"""
import numpy as np
import taichi as ti

from engine.energies.axial import axial_force, axial_potential
from engine.energies.bending import hinge_force_vectors, hinge_gather
from engine.energies.springs import spring_gather
from engine.solvers.thomas import axial_backward_euler
from engine.fields import edge_array, int_array, scalar_array, vec3_array, vec3_array2
from engine.fields import int_array2 as hinge_array

FORWARD_EULER, SYMPLECTIC_EULER, VELOCITY_VERLET, BACKWARD_EULER = 0, 1, 2, 3
METHODS = {"forward-euler": FORWARD_EULER, "symplectic-euler": SYMPLECTIC_EULER,
           "velocity-verlet": VELOCITY_VERLET, "backward-euler": BACKWARD_EULER}
EXPLICIT = ("forward-euler", "symplectic-euler", "velocity-verlet")

# phases of update(): which part of a step a loop performs
STEP = 0        # the whole per-vertex update of (E1) or (E2) (forces of the old state in f)
KICK = 1        # (E2) velocity only
DRIFT = 2       # (E2) position only
KICK_DRIFT = 3  # (E3) first half: v* = v + dt/2 a ; x+ = x + dt v*
ACCEL_KICK = 4  # (E3) a = M^-1 f + g ; v += h a  (h = dt/2; h = 0 only computes a)


@ti.func
def update(method: ti.template(), phase: ti.template(), i, x: ti.template(), v: ti.template(), f_i,
           a: ti.template(), inv_mass: ti.template(), g, dt, zero):
    """The per-vertex update of vertex i: (E1), (E2) or a half of (E3) (see the phase codes).
    ``f_i`` is the force on vertex i; pinned vertices (inv_mass 0) keep x and get v = ``zero`` (a
    vec3 for the 3D models, a scalar for the rod along its axis)."""
    if ti.static(method == FORWARD_EULER):
        if inv_mass[i] > 0.0:
            x[i] += dt * v[i]
            v[i] += dt * (inv_mass[i] * f_i + g)
        else:
            v[i] = zero
    elif ti.static(method == SYMPLECTIC_EULER):
        if ti.static(phase == DRIFT):
            if inv_mass[i] > 0.0:
                x[i] += dt * v[i]
        else:
            if inv_mass[i] > 0.0:
                v[i] += dt * (inv_mass[i] * f_i + g)
                if ti.static(phase == STEP):
                    x[i] += dt * v[i]
            else:
                v[i] = zero
    elif ti.static(phase == KICK_DRIFT):
        if inv_mass[i] > 0.0:
            v[i] += 0.5 * dt * a[i]
            x[i] += dt * v[i]
        else:
            v[i] = zero
    else:  # ACCEL_KICK, dt = the half step
        if inv_mass[i] > 0.0:
            a[i] = inv_mass[i] * f_i + g
            v[i] += dt * a[i]
        else:
            a[i] = zero
            v[i] = zero


@ti.kernel
def update_kernel(x: vec3_array, v: vec3_array, f: vec3_array, a: vec3_array, inv_mass: scalar_array,
                  g: ti.math.vec3, dt: float, method: ti.template(), phase: ti.template()):
    for i in range(x.shape[0]):
        update(method, phase, i, x, v, f[i], a, inv_mass, g, dt, ti.math.vec3(0.0))


@ti.kernel
def one_launch_step(x: vec3_array, v: vec3_array, inv_mass: scalar_array, g: ti.math.vec3, dt: float,
                    offsets: int_array, inc_other: int_array, inc_inv_L: scalar_array, inc_c_over_L: scalar_array,
                    hinges: hinge_array, k: scalar_array, theta_bar: scalar_array, mode: ti.i32, fh: vec3_array2,
                    h_offsets: int_array, h_entries: int_array, with_hinges: ti.template()):
    # (E2) for springs [+ hinges]: forces summed as the generic path does (springs, then bending)
    if ti.static(with_hinges):
        for h in range(hinges.shape[0]):
            hinge_force_vectors(x, hinges, k, theta_bar, mode, fh, h)
    for i in range(x.shape[0]):
        f = ti.math.vec3(0.0)
        f += spring_gather(x, i, offsets, inc_other, inc_inv_L, inc_c_over_L)
        if ti.static(with_hinges):
            f += hinge_gather(fh, h_offsets, h_entries, i)
        update(SYMPLECTIC_EULER, KICK, i, x, v, f, v, inv_mass, g, dt, ti.math.vec3(0.0))
    for i in range(x.shape[0]):
        update(SYMPLECTIC_EULER, DRIFT, i, x, v, ti.math.vec3(0.0), v, inv_mass, g, dt, ti.math.vec3(0.0))


@ti.func
def _spring_forces(x: ti.template(), offsets: ti.template(), inc_other: ti.template(),
                   inc_inv_L: ti.template(), inc_c_over_L: ti.template(), f: ti.template()):
    for i in range(x.shape[0]):
        f[i] = spring_gather(x, i, offsets, inc_other, inc_inv_L, inc_c_over_L)


@ti.func
def _potential(x: ti.template(), edges: ti.template(), L: ti.template(), c: ti.template(), n_edges: int,
               mass: ti.template(), inv_mass: ti.template(), g: ti.math.vec3) -> float:
    # W = sum_e 1/2 c_e (l_e/L_e - 1)^2 (springs (S1)), plus W_g = -sum_{free i} m_i g . x_i; serial sums
    W = 0.0
    for e in range(n_edges):
        l = (x[edges[e][0]] - x[edges[e][1]]).norm()
        strain = l / L[e] - 1.0
        W += 0.5 * c[e] * strain * strain
    for i in range(x.shape[0]):
        if inv_mass[i] > 0.0:
            W -= mass[i] * g.dot(x[i])
    return W


@ti.func
def _kinetic(v: ti.template(), mass: ti.template()) -> float:
    T = 0.0
    for i in range(v.shape[0]):
        T += 0.5 * mass[i] * v[i].dot(v[i])
    return T


@ti.func
def _axial_kinetic(v: ti.template(), m: ti.template()) -> float:
    K = 0.0
    for i in range(v.shape[0]):
        K += 0.5 * m[i] * v[i] * v[i]
    return K


_buffers: dict[int, tuple] = {}


def energy_buffers(n: int):
    """Reusable (kin, pot) ndarrays of at least n entries for the many-steps kernels (chunked runs
    allocate nothing)."""
    size = 1
    while size < n:
        size *= 2
    buf = _buffers.get(size)
    if buf is None:
        buf = _buffers[size] = (ti.ndarray(dtype=float, shape=size), ti.ndarray(dtype=float, shape=size))
    return buf


def collect(kin, pot, done: int, n_steps: int, state, dt: float, monitor, step_offset: int = 0):
    """After a many-steps kernel returned ``done``: the (kinetic, potential) numpy arrays of the steps
    taken, ``state.t`` advanced by them, and the monitor's blow-up raised (with those energies) if the
    run stopped at step ``done``."""
    taken = min(int(done) + 1, n_steps)
    kinetic = kin.to_numpy()[:taken].astype(np.float64)
    potential = pot.to_numpy()[:taken].astype(np.float64)
    state.t += dt * taken
    if done < n_steps:
        raise monitor.blow_up(step_offset + int(done), state.t, float(kinetic[-1] + potential[-1]), kinetic, potential)
    return kinetic, potential


@ti.func
def _record(kin: ti.template(), pot: ti.template(), s, K, W, bound) -> ti.i32:
    """Write step s's energies; 1 when their total marks a blow-up (above the bound, nan or +-inf)."""
    kin[s] = K
    pot[s] = W
    E = K + W
    bad = 0
    if not (E <= bound) or E - E != 0.0:
        bad = 1
    return bad


@ti.kernel
def many_steps(x: vec3_array, v: vec3_array, f: vec3_array, a: vec3_array,
               offsets: int_array, inc_other: int_array, inc_inv_L: scalar_array,
               inc_c_over_L: scalar_array, edges: edge_array, L: scalar_array, c: scalar_array,
               n_edges: ti.i32, mass: scalar_array, inv_mass: scalar_array, g: ti.math.vec3,
               dt: float, n_steps: ti.i32, kin: scalar_array, pot: scalar_array, bound: float,
               method: ti.template()) -> ti.i32:
    """Advance ``n_steps`` steps of a spring-only model; kin[s], pot[s] = energies after step s.
    Returns n_steps, or the index s of the first step whose K + W is above ``bound`` or not finite."""
    n = x.shape[0]
    done = n_steps
    if ti.static(method == VELOCITY_VERLET):  # a(x) of the starting state
        ti.loop_config(serialize=True)
        for _ in range(1):
            _spring_forces(x, offsets, inc_other, inc_inv_L, inc_c_over_L, f)
            for i in range(n):
                update(VELOCITY_VERLET, ACCEL_KICK, i, x, v, f[i], a, inv_mass, g, 0.0, ti.math.vec3(0.0))
    ti.loop_config(serialize=True)
    for s in range(n_steps):
        if ti.static(method == VELOCITY_VERLET):
            for i in range(n):
                update(VELOCITY_VERLET, KICK_DRIFT, i, x, v, f[i], a, inv_mass, g, dt, ti.math.vec3(0.0))
            _spring_forces(x, offsets, inc_other, inc_inv_L, inc_c_over_L, f)
            for i in range(n):
                update(VELOCITY_VERLET, ACCEL_KICK, i, x, v, f[i], a, inv_mass, g, 0.5 * dt, ti.math.vec3(0.0))
        else:
            _spring_forces(x, offsets, inc_other, inc_inv_L, inc_c_over_L, f)
            for i in range(n):
                update(method, STEP, i, x, v, f[i], a, inv_mass, g, dt, ti.math.vec3(0.0))
        if _record(kin, pot, s, _kinetic(v, mass), _potential(x, edges, L, c, n_edges, mass, inv_mass, g), bound):
            done = s
            break
    return done


@ti.kernel
def axial_steps(x: scalar_array, v: scalar_array, a: scalar_array, h: scalar_array, E: scalar_array,
                m: scalar_array, inv_m: scalar_array, dt: float, n_steps: ti.i32, kin: scalar_array,
                pot: scalar_array, bound: float, Cp: scalar_array, Dp: scalar_array, method: ti.template()) -> ti.i32:
    """:func:`many_steps` for the rod along its axis (engine.energies.axial (R1), one coordinate per
    node, no gravity): the same updates, backward Euler by the scalar Thomas solve. Returns n_steps,
    or the index of the first step whose K + W is above ``bound`` or not finite."""
    n = x.shape[0]
    done = n_steps
    if ti.static(method == VELOCITY_VERLET):  # a(x) of the starting state
        ti.loop_config(serialize=True)
        for _ in range(1):
            for i in range(n):
                update(VELOCITY_VERLET, ACCEL_KICK, i, x, v, axial_force(x, h, E, i, n), a, inv_m, 0.0, 0.0, 0.0)
    ti.loop_config(serialize=True)
    for s in range(n_steps):
        if ti.static(method == VELOCITY_VERLET):
            for i in range(n):
                update(VELOCITY_VERLET, KICK_DRIFT, i, x, v, 0.0, a, inv_m, 0.0, dt, 0.0)
            for i in range(n):
                a[i] = axial_force(x, h, E, i, n)
            for i in range(n):
                update(VELOCITY_VERLET, ACCEL_KICK, i, x, v, a[i], a, inv_m, 0.0, 0.5 * dt, 0.0)
        elif ti.static(method == BACKWARD_EULER):
            axial_backward_euler(x, v, h, E, m, inv_m, dt, Cp, Dp)
        else:
            for i in range(n):
                Cp[i] = axial_force(x, h, E, i, n)
            for i in range(n):
                update(method, STEP, i, x, v, Cp[i], a, inv_m, 0.0, dt, 0.0)
        if _record(kin, pot, s, _axial_kinetic(v, m), axial_potential(x, h, E, n), bound):
            done = s
            break
    return done
