"""The 1D rod engine: gradient, stencil, integrators' per-mode energy factors, CFL."""
import math

import numpy as np
import pytest

from engine.errors import BlowUpError, ParameterError
from engine.scenes import Rod


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
    x0 = st.positions()
    rod.run(st, 0.5 * rod.h[0], 200)
    rod.run(st, 5 * rod.h[0], 20, "backward-euler")
    x = st.positions()
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


# ------------------------------------------------------------------------------------------
# velocity Verlet and the per-mode theory of every scheme (engine.theory.schemes.amplification)
# ------------------------------------------------------------------------------------------

from engine.integrators import METHODS  # noqa: E402
from engine.theory.schemes import ModalReference, amplification  # noqa: E402


@pytest.mark.parametrize("method", list(METHODS))
@pytest.mark.parametrize("pinned", [(), (0,), (0, 25, 59)])
def test_kernel_equals_the_schemes_modal_theory(method, pinned):
    """Every integrator of the rod kernel is, mode by mode, its 2x2 amplification matrix."""
    rod, rng = random_rod(seed=8)
    rod = Rod(rod.p, rod.E, rod.rho, pinned)
    u0, v0 = 1e-3 * rng.standard_normal(rod.n), 1e-3 * rng.standard_normal(rod.n)
    u0[list(pinned)] = 0.0
    v0[list(pinned)] = 0.0
    dt = 0.8 * rod.stable_dt()
    st = rod.new_state(u0, v0)
    rod.run(st, dt, 40, method)
    rod.run(st, dt, 17, method)  # two launches: a chunked run is the same run
    ref = ModalReference(rod, u0, v0, dt, method)
    u, v = ref.displacement(57), ref.velocity(57)
    assert np.max(np.abs(st.displacement(rod) - u)) < 1e-11 * np.max(np.abs(u))
    assert np.max(np.abs(st.velocity() - v)) < 1e-11 * np.max(np.abs(v))
    np.testing.assert_allclose(ref.displacements([0, 20, 57, 57]), [u0, ref.displacement(20), u, u],
                               rtol=0, atol=1e-13 * np.max(np.abs(u)))


def test_amplification_determinants_and_traces():
    w2, dt = np.array([0.0, 0.3, 2.0, 3.9]), 1.0
    det = lambda m: np.linalg.det(amplification(m, w2, dt))
    tr = lambda m: np.trace(amplification(m, w2, dt), axis1=-2, axis2=-1)
    np.testing.assert_allclose(det("forward-euler"), 1 + w2, rtol=1e-14)
    np.testing.assert_allclose(det("backward-euler"), 1 / (1 + w2), rtol=1e-14)
    for m in ("symplectic-euler", "velocity-verlet"):  # area-preserving, same trace: same eigenvalues
        np.testing.assert_allclose(det(m), 1.0, rtol=1e-14)
        np.testing.assert_allclose(tr(m), 2 - w2, rtol=1e-14)
    with pytest.raises(ParameterError, match="integrator must be one of"):
        amplification("leapfrog", w2, dt)


def test_velocity_verlet_is_symplectic_euler_with_half_step_shifted_velocities():
    """Symplectic Euler started from v0 - dt/2 a(x0) visits exactly velocity Verlet's positions;
    its velocities are Verlet's half-step velocities, whose averages are Verlet's velocities."""
    rod, rng = random_rod(seed=9)
    u0, v0 = 1e-3 * rng.standard_normal(rod.n), 1e-3 * rng.standard_normal(rod.n)
    dt = 0.9 * rod.stable_dt()
    a0 = rod.forces(rod.p + u0) / rod.mass
    vv, se = rod.new_state(u0, v0), rod.new_state(u0, v0 - 0.5 * dt * a0)
    for _ in range(300):
        rod.run(vv, dt, 1, "velocity-verlet")
        rod.run(se, dt, 1, "symplectic-euler")
        # x = p + u is of order 1 m: round-off of x, not of u
        assert np.max(np.abs(vv.positions() - se.positions())) < 1e-13
    v_before = se.velocity()  # v_{n-1/2}
    rod.run(se, dt, 1, "symplectic-euler")  # v_{n+1/2}: Verlet's v_n is their mean
    np.testing.assert_allclose(vv.velocity(), 0.5 * (v_before + se.velocity()), rtol=0,
                               atol=1e-11 * np.max(np.abs(vv.velocity())))


@pytest.mark.parametrize("method,order", [("velocity-verlet", 2.0), ("symplectic-euler", 1.0)])
def test_time_convergence_order(method, order):
    """One mode of a pinned rod against the exact solution u0 cos(w t) of the semi-discrete rod:
    the largest error at ten common times in [0, T] falls like dt^order."""
    rod = Rod.uniform(101, pinned=(0, 100))
    h, j, T = rod.h[0], 3, 1.0
    w = 2 / h * np.sin(j * np.pi * h / 2)
    u0 = 1e-3 * np.sin(j * np.pi * rod.p)
    errs, dts = [], []
    for n in (400, 800, 1600, 3200):
        st = rod.new_state(u0)
        err = 0.0
        for k in range(1, 11):
            rod.run(st, T / n, n // 10, method)
            err = max(err, np.max(np.abs(st.displacement(rod) - u0 * np.cos(w * k * T / 10))) / 1e-3)
        errs.append(err)
        dts.append(T / n)
    slope = np.polyfit(np.log(dts), np.log(errs), 1)[0]
    assert abs(slope - order) < 0.05


def test_velocity_verlet_has_the_cfl_limit_and_forward_euler_no_dt_advice():
    rod = Rod.uniform(201)
    rng = np.random.default_rng(1)
    u0 = 1e-6 * rng.standard_normal(rod.n)
    E0 = rod.energy(rod.p + u0)
    st = rod.new_state(u0)
    K, W = rod.run(st, 0.99 * rod.h[0], 5000, "velocity-verlet", energy_bound=100 * E0)
    assert np.max(K + W) < 2 * E0
    with pytest.raises(BlowUpError) as info:
        rod.run(rod.new_state(u0), 1.01 * rod.h[0], 5000, "velocity-verlet", energy_bound=100 * E0)
    assert info.value.step < 300 and "CFL" in str(info.value) and "reduce dt below" in str(info.value)
    with pytest.raises(BlowUpError) as info:
        rod.run(rod.new_state(u0), 0.5 * rod.h[0], 5000, "forward-euler", energy_bound=100 * E0)
    assert ("forward Euler adds energy to every undamped oscillation at any dt" in str(info.value)
            and "reduce dt below" not in str(info.value))
