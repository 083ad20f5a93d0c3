"""Many explicit steps of a small spring network in ONE kernel launch.

Python-driven stepping (:mod:`engine.integrators.explicit`) launches several kernels per step,
each costing ~0.1 ms on a 2-core CPU: 10^5 steps of a 20-vertex chain would take tens of
seconds although the arithmetic is a few microseconds per step. For small spring-only models
(springs + gravity + pins; ``Model.from_springs``) :func:`run_fused` advances many steps in a
single launch: the outer step loop is serialized (``ti.loop_config(serialize=True)``, the
pattern of :func:`engine.rod.rod_run`) and every inner loop runs serially inside it.

The physics is the engine's, formula for formula:

  spring energy  W_e = 1/2 c_e (l_e/L_e - 1)^2          (engine.energies.springs, (S1))
  spring force   f_i = -sum_{e~i} (c_e/L_e)(1/L_e - 1/l_e)(x_i - x_j)   ((S2), CSR gather)
  gravity        W_g = -sum_{free i} m_i g . x_i,  a_i = f_i/m_i + g
  pins           inverse mass 0: never move, v = 0
  updates        forward Euler, symplectic Euler, velocity Verlet exactly as in
                 engine.integrators.explicit (same expressions, same order)

so one fused step equals one step of the explicit integrators to round-off (the tests check
this), and the energies it writes equal ``model.potential_energy`` + kinetic energy.

After every step the kinetic and potential energy are written to output arrays; the run
stops at the first step whose total energy is not finite or exceeds ``energy_bound`` and
:func:`run_fused` raises :class:`BlowUpError` naming that step.

Cost: one serial pass over the incidences and edges per step (~10 ns per edge); meant for
models of up to a few thousand vertices. Larger models want the parallel kernels.
"""

import math

import numpy as np
import taichi as ti

from engine.energies.springs import SpringEnergy, spring_gather
from engine.integrators.explicit import BlowUpError, _blowup_message, stable_dt_estimate
from engine.fields import edge_array, int_array, scalar_array, vec3_array
from engine.model import Model, State

FORWARD_EULER, SYMPLECTIC_EULER, VELOCITY_VERLET = 0, 1, 2
METHODS = {"forward-euler": FORWARD_EULER, "symplectic-euler": SYMPLECTIC_EULER,
           "velocity-verlet": VELOCITY_VERLET}


@ti.func
def _spring_forces(x: ti.template(), offsets: ti.template(), inc_other: ti.template(),
                   inc_inv_L: ti.template(), inc_c_over_L: ti.template(), f: ti.template()):
    # (S2) gathered per vertex, by the same ti.func as spring_add_forces_kernel
    for i in range(x.shape[0]):
        f[i] = spring_gather(x, i, offsets, inc_other, inc_inv_L, inc_c_over_L)


@ti.func
def _potential(x: ti.template(), edges: ti.template(), L: ti.template(), c: ti.template(), n_edges: int,
               mass: ti.template(), inv_mass: ti.template(), g: ti.math.vec3) -> float:
    # (S1) W = sum_e 1/2 c_e (l_e/L_e - 1)^2, plus W_g = -sum_{free i} m_i g . x_i
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


@ti.kernel
def fused_spring_run(x: vec3_array, v: vec3_array, f: vec3_array, a: vec3_array,
                     offsets: int_array, inc_other: int_array, inc_inv_L: scalar_array,
                     inc_c_over_L: scalar_array, edges: edge_array, L: scalar_array, c: scalar_array,
                     n_edges: ti.i32, mass: scalar_array, inv_mass: scalar_array, g: ti.math.vec3,
                     dt: float, n_steps: ti.i32, method: ti.i32, kin: scalar_array, pot: scalar_array,
                     bound: float) -> ti.i32:
    """Advance ``n_steps`` steps; kin[s], pot[s] = energies after step s. Returns the number of
    steps completed, or the index s of the first step with K + W > bound (or not finite)."""
    n = x.shape[0]
    done = n_steps
    ti.loop_config(serialize=True)
    for _ in range(1):
        if method == 2:  # velocity Verlet: a(x) of the starting state (explicit's begin())
            _spring_forces(x, offsets, inc_other, inc_inv_L, inc_c_over_L, f)
            for i in range(n):
                if inv_mass[i] > 0.0:
                    a[i] = inv_mass[i] * f[i] + g
                else:
                    a[i] = ti.math.vec3(0.0)
                    v[i] = ti.math.vec3(0.0)
    ti.loop_config(serialize=True)
    for s in range(n_steps):
        if method == 0:  # forward Euler: x+ = x + dt v ; v+ = v + dt (M^-1 f(x) + g)
            _spring_forces(x, offsets, inc_other, inc_inv_L, inc_c_over_L, f)
            for i in range(n):
                if inv_mass[i] > 0.0:
                    x[i] += dt * v[i]
                    v[i] += dt * (inv_mass[i] * f[i] + g)
                else:
                    v[i] = ti.math.vec3(0.0)
        elif method == 1:  # symplectic Euler: v+ = v + dt (M^-1 f(x) + g) ; x+ = x + dt v+
            _spring_forces(x, offsets, inc_other, inc_inv_L, inc_c_over_L, f)
            for i in range(n):
                if inv_mass[i] > 0.0:
                    v[i] += dt * (inv_mass[i] * f[i] + g)
                    x[i] += dt * v[i]
                else:
                    v[i] = ti.math.vec3(0.0)
        else:  # velocity Verlet: v* = v + dt/2 a ; x+ = x + dt v* ; a = a(x+) ; v+ = v* + dt/2 a
            for i in range(n):
                if inv_mass[i] > 0.0:
                    v[i] += 0.5 * dt * a[i]
                    x[i] += dt * v[i]
                else:
                    v[i] = ti.math.vec3(0.0)
            _spring_forces(x, offsets, inc_other, inc_inv_L, inc_c_over_L, f)
            half_dt = 0.5 * dt
            for i in range(n):
                if inv_mass[i] > 0.0:
                    a[i] = inv_mass[i] * f[i] + g
                    v[i] += half_dt * a[i]
                else:
                    a[i] = ti.math.vec3(0.0)
                    v[i] = ti.math.vec3(0.0)
        K = _kinetic(v, mass)
        W = _potential(x, edges, L, c, n_edges, mass, inv_mass, g)
        kin[s] = K
        pot[s] = W
        if not (K + W <= bound):
            done = s
            break
    return done


_buffers: dict[int, tuple] = {}


def _energy_buffers(n: int):
    """Reusable (kin, pot) ndarrays of at least n entries (chunked runs allocate nothing)."""
    size = 1
    while size < n:
        size *= 2
    buf = _buffers.get(size)
    if buf is None:
        buf = _buffers[size] = (ti.ndarray(dtype=float, shape=size), ti.ndarray(dtype=float, shape=size))
    return buf


def spring_energy_of(model: Model) -> SpringEnergy:
    """The model's only energy, which must be a SpringEnergy; ValueError (one line) otherwise."""
    springs = [e for e in model.energies if isinstance(e, SpringEnergy)]
    others = [e.name for e in model.energies if not isinstance(e, SpringEnergy)]
    if others or len(springs) != 1:
        raise ValueError(f"run_fused needs a spring-only model (exactly one spring energy, plus gravity and "
                         f"pins); this model has energies {[e.name for e in model.energies]}")
    return springs[0]


def run_fused(model: Model, state: State, dt: float, n_steps: int, method: str = "symplectic-euler",
              energy_bound: float | None = None, step_offset: int = 0):
    """Advance ``state`` by ``n_steps`` steps of ``method`` (forward-euler, symplectic-euler,
    velocity-verlet) in one kernel launch; returns (kinetic, potential) numpy arrays (J), one
    entry per step (the energies after that step).

    If the total energy after a step is not finite or exceeds ``energy_bound`` (J), the run
    stops there and :class:`BlowUpError` is raised with ``step`` = ``step_offset`` + index of
    that step (0-based) and the energies up to and including it in ``.kinetic``/``.potential``.
    ``state.t`` advances by the steps actually taken.
    """
    springs = spring_energy_of(model)
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; valid: {', '.join(METHODS)}")
    dt = float(dt)
    if not (math.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be > 0 and finite (got {dt!r})")
    n_steps = int(n_steps)
    if n_steps < 0 or n_steps >= 2 ** 31:
        raise ValueError(f"n_steps must be in 0..2^31-1 (got {n_steps})")
    if energy_bound is not None and math.isnan(float(energy_bound)):
        raise ValueError("energy_bound must be a number or None (got nan)")
    if state.n != model.n:
        raise ValueError(f"state has {state.n} vertices, model has {model.n}")
    if n_steps == 0:
        return np.zeros(0), np.zeros(0)
    kin, pot = _energy_buffers(n_steps)
    bound = math.inf if energy_bound is None else float(energy_bound)
    done = fused_spring_run(state.x, state.v, model.work_vec3("fused_f"), model.work_vec3("fused_a"),
                            springs.offsets, springs.inc_other, springs.inc_inv_L, springs.inc_c_over_L,
                            springs.edges, springs.L, springs.c, springs.m, model.mass_nd, model.inv_mass_nd,
                            model.gravity_vec, dt, n_steps, METHODS[method], kin, pot, bound)
    taken = min(done + 1, n_steps)
    K = kin.to_numpy()[:taken].astype(np.float64)
    W = pot.to_numpy()[:taken].astype(np.float64)
    state.t += dt * taken
    if done < n_steps:
        E = float(K[-1] + W[-1])
        dts = stable_dt_estimate(model)
        step = int(step_offset) + int(done)
        exc = BlowUpError(_blowup_message(method, step, state.t, E, energy_bound, dt, dts),
                          step=step, time=state.t, energy=E, dt=dt, dt_stable=dts, integrator=method)
        exc.kinetic, exc.potential = K, W
        raise exc
    return K, W


__all__ = ["run_fused", "fused_spring_run", "METHODS", "BlowUpError", "spring_energy_of"]
