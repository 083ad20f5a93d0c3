"""Many explicit steps in ONE launch, and the energies they record:

* :func:`many_steps` - many steps of a spring-only model in ONE launch (the step loop
  serialised, every inner loop serial), writing each step's kinetic and potential energy and
  stopping at the first step whose total is not finite or above the bound. For small models
  (chains, frames) where launches would cost more than the arithmetic;
* :func:`axial_steps` - the same for the rod along its axis, one coordinate per node, backward
  Euler included (engine.solvers.thomas).

The updates are engine.integrators.kernels.update's (E1)-(E3).
"""
import numpy as np
import taichi as ti

from engine.energies.axial import axial_force, axial_potential
from engine.energies.masses import add_gravity_potential, kinetic_energy
from engine.energies.springs import spring_energy, spring_gather
from engine.fields import edge_array, int_array, scalar_array, vec3_array
from engine.integrators.kernels import ACCEL_KICK, BACKWARD_EULER, KICK_DRIFT, STEP, VELOCITY_VERLET, update
from engine.solvers.thomas import axial_backward_euler


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
        W += spring_energy(x[edges[e][0]] - x[edges[e][1]], L[e], c[e])
    return add_gravity_potential(W, x, mass, inv_mass, g)


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
        if _record(kin, pot, s, kinetic_energy(v, mass), _potential(x, edges, L, c, n_edges, mass, inv_mass, g), bound):
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
        if _record(kin, pot, s, kinetic_energy(v, m), axial_potential(x, h, E, n), bound):
            done = s
            break
    return done
