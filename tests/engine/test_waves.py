"""engine.waves.bloch_modes: the plane waves of a periodic lattice read from a finite patch's Hessian,
checked against what is known in closed form (the one-way grid's equal masses and axis stencil; the
alternating grid's sublattice masses 4/3 and 2/3 of rho h^2; the continuum's speed as h -> 0, order 2),
and the damped per-mode maps of engine.theory.schemes against a direct run of the same recurrences."""
import math

import numpy as np
import pytest

from engine import mesh as M
from engine.energies.membrane import MembraneEnergy
from engine.model import Model
from engine.theory.schemes import backward_euler_damped_sequence, velocity_verlet_damped_rates
from engine.waves import bloch_modes

PERIODS = {"one-way": np.eye(2), "alternating": 2.0 * np.eye(2)}


def bw_modes(pattern, k, ks=1.0, kd=0.0, rho=1.0):
    m3 = M.embed_3d(M.right_triangle_grid(9, 9, 8.0, 8.0, pattern))
    params = dict(k_stretch=ks, k_shear=0.5 * ks)
    if kd:
        params.update(damping_stretch=kd, damping_shear=0.5 * kd)
    energy = MembraneEnergy.from_mesh(m3, "baraff-witkin", **params)
    model = Model(m3.vertices, mass=M.lumped_masses(m3, rho))
    model.add_energy(energy)
    X = m3.vertices
    damping = energy.dense_damping(X) if kd else None
    return bloch_modes(X, model.mass, PERIODS[pattern], [k, 0.0], energy.dense_hessian(X, psd=False), damping), X


def test_one_way_grid_has_equal_masses_and_the_axis_stencil():
    """One sublattice of mass rho h^2; the warp's P wave has w^2 = k_s (2 sin(k h/2))^2/(rho h^2)."""
    k = 2 * math.pi / 32
    modes, X = bw_modes("one-way", k)
    assert modes.mass == pytest.approx([1.0], rel=1e-14)
    b = modes.branch([1.0, 0.0])
    assert modes.w2[b] == pytest.approx((2 * math.sin(k / 2)) ** 2, rel=1e-12)
    assert np.allclose(modes.profile(X, b, [1.0, 0.0]), 1.0, atol=1e-12)   # every vertex moves alike


def test_alternating_grid_masses_move_its_mode_off_the_unit_mass_formula():
    """Vertices where four triangles meet weigh 2/3 rho h^2, where eight meet 4/3 (two of each in the
    2 x 2 block that repeats): the P wave is not the unit-mass one; its shape weights the two kinds differently."""
    k = 2 * math.pi / 32
    modes, X = bw_modes("alternating", k)
    assert sorted(np.round(modes.mass, 12)) == pytest.approx([2 / 3, 2 / 3, 4 / 3, 4 / 3], rel=1e-12)
    b = modes.branch([1.0, 0.0])
    unit = (2 * math.sin(k / 2)) ** 2
    assert abs(modes.w2[b] / unit - 1) > 1e-4          # the unit-mass prediction is off by more than this
    profile = modes.profile(X, b, [1.0, 0.0])
    mass = M.lumped_masses(M.embed_3d(M.right_triangle_grid(9, 9, 8.0, 8.0, "alternating")), 1.0)
    interior = (X[:, 0] > 0.5) & (X[:, 0] < 7.5) & (X[:, 1] > 0.5) & (X[:, 1] < 7.5)
    heavy = interior & (mass > 1.0)
    light = interior & (mass < 1.0)
    assert np.ptp(profile[heavy]) < 1e-12 and np.ptp(profile[light]) < 1e-12
    assert abs(profile[heavy][0] - profile[light][0]) > 1e-5   # the two kinds move differently
    assert (2 * profile[heavy][0] + profile[light][0]) / 3 == pytest.approx(1.0, rel=1e-12)   # mass-weighted mean


@pytest.mark.parametrize("pattern", ["one-way", "alternating"])
def test_the_lattice_speed_reaches_the_continuum_at_order_two(pattern):
    """w^2/(k_s k^2/rho) - 1 shrinks 4x each time the wavelength doubles (16 .. 128 spacings)."""
    errors = []
    for lam in (16, 32, 64, 128):
        k = 2 * math.pi / lam
        modes, _ = bw_modes(pattern, k)
        errors.append(abs(modes.w2[modes.branch([1.0, 0.0])] / k ** 2 - 1))
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert orders == pytest.approx(2.0, abs=0.01)


def test_the_damping_per_unit_mass_follows_the_stiffness():
    """Baraff-Witkin damping with k_d/k_s the same on stretch and shear is proportional: c = (k_d/k_s) w^2."""
    k = 2 * math.pi / 32
    modes, _ = bw_modes("alternating", k, ks=2.0, kd=0.3)
    b = modes.branch([1.0, 0.0])
    assert modes.c[b] == pytest.approx(0.15 * modes.w2[b], rel=1e-10)


def test_the_damped_maps_match_their_recurrences():
    w2, c, dt = 0.04, 0.01, 0.7
    seq = backward_euler_damped_sequence(w2, c, dt, 200)
    # backward Euler's map: q+ = q + dt v+, the eigenvalues of the 2x2 step; the sequence decays at their modulus
    A = np.array([[1 - dt * dt * w2 / (1 + c * dt + w2 * dt * dt), dt / (1 + c * dt + w2 * dt * dt)],
                  [-dt * w2 / (1 + c * dt + w2 * dt * dt), 1 / (1 + c * dt + w2 * dt * dt)]])
    q = np.array([1.0, 0.0])
    direct = [1.0]
    for _ in range(200):
        q = A @ q
        direct.append(q[0])
    assert np.allclose(seq, direct, rtol=0, atol=1e-14)
    w, gamma = velocity_verlet_damped_rates(w2, c, 1e-4)
    assert w == pytest.approx(math.sqrt(w2 - c * c / 4), rel=1e-6)   # small dt: the continuum's damped mode
    assert gamma == pytest.approx(c / 2, rel=1e-6)
