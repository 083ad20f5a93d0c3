"""The 1D rod engine: gradient, stencil, integrators' per-mode energy factors, CFL."""
import math

import numpy as np
import pytest

from engine.errors import BlowUpError, ParameterError
from engine.rod import Rod


def random_rod(n=60, seed=0):
    rng = np.random.default_rng(seed)
    h = rng.uniform(0.5, 1.5, n - 1)
    p = np.concatenate([[0.0], np.cumsum(h)])
    p /= p[-1]
    return Rod(p, rng.uniform(0.5, 2.0, n - 1), rng.uniform(0.5, 2.0, n - 1)), rng


def test_gradient_matches_central_differences_on_nonuniform_rod():
    rod, rng = random_rod()
    x = rod.p + 0.02 * rng.standard_normal(rod.n)
    f = rod.forces(x)
    eps = 1e-6
    fd = np.empty(rod.n)
    for i in range(rod.n):
        xp, xm = x.copy(), x.copy()
        xp[i] += eps
        xm[i] -= eps
        fd[i] = -(rod.energy(xp) - rod.energy(xm)) / (2 * eps)
    assert np.linalg.norm(fd - f) / np.linalg.norm(f) < 1e-6


def test_forces_are_minus_stiffness_times_displacement():
    """The rod is linear in x: f = -K (x - p) exactly."""
    rod, rng = random_rod(seed=3)
    u = 0.01 * rng.standard_normal(rod.n)
    f = rod.forces(rod.p + u)
    assert np.max(np.abs(f + rod.stiffness_matrix() @ u)) < 1e-12 * np.max(np.abs(f))


def test_energy_is_sum_of_segment_energies():
    rod, rng = random_rod(seed=4)
    x = rod.p + 0.01 * rng.standard_normal(rod.n)
    s = np.diff(x) / rod.h - 1
    assert rod.energy(x) == pytest.approx(np.sum(0.5 * rod.E * s * s * rod.h), rel=1e-13)


def test_lumped_masses_sum_to_total_mass():
    rod, _ = random_rod(seed=5)
    assert rod.mass.sum() == pytest.approx(np.sum(rod.rho * rod.h), rel=1e-14)


def test_stable_dt_bound_is_exact_for_uniform_free_rod_and_conservative_otherwise():
    rod = Rod.uniform(101, E=4.0, rho=1.0)
    assert rod.stable_dt() == pytest.approx(rod.h[0] / 2.0, rel=1e-12)  # h/c with c = 2
    het, _ = random_rod(seed=6)
    M = np.diag(het.mass)
    w2 = np.linalg.eigvals(np.linalg.solve(M, het.stiffness_matrix())).real.max()
    assert het.omega_max_bound() >= math.sqrt(w2) * (1 - 1e-12)


@pytest.mark.parametrize("method,factor", [
    ("forward-euler", lambda a: 1 + a * a),
    ("backward-euler", lambda a: 1 / (1 + a * a)),
])
def test_single_mode_energy_factor_per_step(method, factor):
    rod = Rod.uniform(201, pinned=(0, 200))
    h, j = rod.h[0], 5
    w = 2 / h * np.sin(j * np.pi * h / 2)
    for dt in (0.3 * h, 3 * h):
        st = rod.new_state(1e-3 * np.sin(j * np.pi * rod.p))
        E0 = rod.energy(st.x)
        K, W = rod.run(st, dt, 5, method)
        E = np.concatenate([[E0], K + W])
        assert np.allclose(E[1:] / E[:-1], factor(w * dt), rtol=1e-9, atol=0)


def test_symplectic_euler_blows_up_just_above_cfl_and_reports_the_step():
    rod = Rod.uniform(201)
    rng = np.random.default_rng(0)
    st = rod.new_state(1e-6 * rng.standard_normal(rod.n))
    E0 = rod.energy(st.x)
    with pytest.raises(BlowUpError) as info:
        rod.run(st, 1.01 * rod.h[0], 10_000, energy_bound=100 * E0)
    exc = info.value
    assert exc.step < 200
    assert exc.kinetic.size == exc.step + 1
    assert exc.kinetic[-1] + exc.potential[-1] > 100 * E0  # the reported step is the first bad one
    assert np.all(exc.kinetic[:-1] + exc.potential[:-1] <= 100 * E0)
    assert "CFL" in str(exc) and f"{rod.h[0]:.6g}" in str(exc)


def test_pinned_nodes_never_move():
    rod = Rod.uniform(51, pinned=(0, 50))
    st = rod.new_state(1e-3 * np.sin(np.pi * rod.p) + 1e-3)
    x0 = st.x.to_numpy()
    rod.run(st, 0.5 * rod.h[0], 200)
    rod.run(st, 5 * rod.h[0], 20, "backward-euler")
    x = st.x.to_numpy()
    assert x[0] == x0[0] and x[-1] == x0[-1]


@pytest.mark.parametrize("kwargs,needle", [
    (dict(p=[0.0, 1.0]), "nodes must be >= 3"),
    (dict(p=[0.0, 0.5, 0.5, 1.0]), "segment 1"),
    (dict(p=[0.0, 0.5, 1.0], E=-1.0), "E must be > 0"),
    (dict(p=[0.0, 0.5, 1.0], rho=0.0), "rho must be > 0"),
    (dict(p=[0.0, 0.5, 1.0], E=float("nan")), "E must be > 0"),
    (dict(p=[0.0, 0.5, 1.0], pinned=[3]), "pinned node indices must be in 0..2"),
])
def test_bad_rod_input_is_refused(kwargs, needle):
    with pytest.raises(ParameterError, match=needle):
        Rod(**kwargs)


@pytest.mark.parametrize("dt", [0.0, -1.0, float("nan")])
def test_bad_dt_is_refused(dt):
    rod = Rod.uniform(11)
    with pytest.raises(ParameterError, match="dt must be > 0"):
        rod.run(rod.new_state(), dt, 1)
