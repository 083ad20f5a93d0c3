"""Conserved quantities and energies of a (model, state) pair.

    kinetic energy    T = 1/2 sum_i m_i |v_i|^2
    potential energy  W = sum of the model's energies - sum_i m_i g . x_i   (Model.potential_energy)
    total energy      E = T + W      (conserved by the exact flow; not by every integrator)
    linear momentum   p = sum_i m_i v_i            (conserved without gravity and pins)
    angular momentum  J = sum_i m_i x_i x v_i      (about the origin; conserved for central
                                                    forces such as springs, without gravity/pins)

Reductions are parallel ``+=`` in Taichi kernels: correct to rounding, not bitwise
reproducible across thread counts.
"""

import numpy as np
import taichi as ti

from engine.energies import masses
from engine.fields import scalar_array, vec3_array
from engine.model import Model, State


@ti.kernel
def kinetic_energy_kernel(v: vec3_array, mass: scalar_array) -> float:
    return masses.kinetic_energy(v, mass)


@ti.kernel
def linear_momentum_kernel(v: vec3_array, mass: scalar_array) -> ti.math.vec3:
    p = ti.math.vec3(0.0)
    for i in range(v.shape[0]):
        p += mass[i] * v[i]
    return p


@ti.kernel
def angular_momentum_kernel(x: vec3_array, v: vec3_array, mass: scalar_array) -> ti.math.vec3:
    J = ti.math.vec3(0.0)
    for i in range(v.shape[0]):
        J += mass[i] * x[i].cross(v[i])
    return J


def kinetic_energy(model: Model, state: State) -> float:
    return float(kinetic_energy_kernel(state.v, model.mass_nd))


def potential_energy(model: Model, state: State) -> float:
    return model.potential_energy(state.x)


def total_energy(model: Model, state: State) -> float:
    return kinetic_energy(model, state) + potential_energy(model, state)


def linear_momentum(model: Model, state: State) -> np.ndarray:
    return np.asarray(linear_momentum_kernel(state.v, model.mass_nd).to_numpy(), dtype=np.float64)


def angular_momentum(model: Model, state: State) -> np.ndarray:
    return np.asarray(angular_momentum_kernel(state.x, state.v, model.mass_nd).to_numpy(), dtype=np.float64)


def energies(model: Model, state: State) -> dict[str, float]:
    """{'kinetic', 'elastic', 'gravity', 'potential', 'total'} in joules."""
    T = kinetic_energy(model, state)
    We = model.elastic_energy(state.x)
    Wg = model.gravity_energy(state.x)
    return {"kinetic": T, "elastic": We, "gravity": Wg, "potential": We + Wg, "total": T + We + Wg}
