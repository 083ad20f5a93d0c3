"""Explicit integrators: conservation laws, energy behaviour, pins, CFL blow-up, registry."""
import math

import numpy as np
import pytest
import scipy.linalg as sla

from engine import diagnostics, integrators
from engine.errors import BlowUpError
from engine.integrators.stepper import Stepper, run
from engine.stability import stable_dt_estimate
from engine.model import Model


def grid_network(N, h=0.1):
    i, j = np.meshgrid(np.arange(N), np.arange(N), indexing="ij")
    X = np.stack([i.ravel() * h, j.ravel() * h, np.zeros(N * N)], 1)
    idx = i * N + j
    E = np.concatenate([np.stack([idx[:-1, :].ravel(), idx[1:, :].ravel()], 1),
                        np.stack([idx[:, :-1].ravel(), idx[:, 1:].ravel()], 1),
                        np.stack([idx[:-1, :-1].ravel(), idx[1:, 1:].ravel()], 1),
                        np.stack([idx[1:, :-1].ravel(), idx[:-1, 1:].ravel()], 1)])
    return X, E


def wobbly_grid(seed=0, N=4, pinned=None, gravity=None):
    """A small 3D network, displaced from rest so that every mode carries energy."""
    X, E = grid_network(N)
    rng = np.random.default_rng(seed)
    model = Model.from_springs(X, E, k=20.0, mass=rng.uniform(0.05, 0.15, len(X)), pinned=pinned, gravity=gravity)
    x0 = X + 0.01 * rng.standard_normal(X.shape)
    return model, x0


def rod(N=20, h=0.05, k=100.0, m=0.2):
    X = np.zeros((N, 3))
    X[:, 0] = np.arange(N) * h
    return Model.from_springs(X, np.stack([np.arange(N - 1), np.arange(1, N)], 1), k=k, mass=m)


def true_stable_dt(model):
    H = model.dense_hessian(model.X_nd, psd=False)
    free = np.repeat(model.free, 3)
    lam = sla.eigh(H[np.ix_(free, free)], np.diag(np.repeat(model.mass, 3)[free]), eigvals_only=True).max()
    return 2.0 / math.sqrt(lam)


# ------------------------------------------------------------------------------------------
# registry
# ------------------------------------------------------------------------------------------

def test_registry_names_and_unknown_name():
    assert {"forward-euler", "symplectic-euler", "velocity-verlet"} <= set(integrators.INTEGRATORS)
    assert integrators.get("velocity-verlet").name == "velocity-verlet"
    with pytest.raises(ValueError) as info:
        integrators.get("leapfrog-ish")
    msg = str(info.value)
    assert "leapfrog-ish" in msg and "symplectic-euler" in msg and "forward-euler" in msg and "\n" not in msg


# ------------------------------------------------------------------------------------------
# conservation laws
# ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", ["symplectic-euler", "velocity-verlet"])
def test_momentum_conservation_without_gravity_and_pins(name):
    model, x0 = wobbly_grid(1)
    rng = np.random.default_rng(2)
    state = model.make_state(x0 + 1.0, 0.3 * rng.standard_normal(x0.shape))  # off the origin
    p0, J0 = diagnostics.linear_momentum(model, state), diagnostics.angular_momentum(model, state)
    dt = 0.3 * stable_dt_estimate(model)
    Stepper(model, integrators.get(name)).step(state, dt, 400)
    p, J = diagnostics.linear_momentum(model, state), diagnostics.angular_momentum(model, state)
    scale = np.sum(model.mass) * 0.3 * 3  # ~ sum m |v|
    assert np.abs(p - p0).max() < 1e-13 * scale, p - p0
    # both methods conserve angular momentum exactly for central forces (up to rounding)
    assert np.abs(J - J0).max() < 1e-12 * scale * 2, J - J0
    assert state.t == pytest.approx(400 * dt)


def _energy_history(name, dt_fraction=0.1, steps=3000, seed=0, check_every=1):
    model, x0 = wobbly_grid(seed)
    state = model.make_state(x0)
    dt = dt_fraction * stable_dt_estimate(model)
    E0 = diagnostics.total_energy(model, state)
    hist = run(model, state, dt, steps, integrator=name, check_every=check_every)
    return E0, hist


def test_symplectic_euler_energy_bounded_without_drift():
    E0, hist = _energy_history("symplectic-euler")
    dev = np.abs(hist - E0).max() / E0
    tenth = len(hist) // 10
    drift = abs(hist[-tenth:].mean() - hist[:tenth].mean()) / E0
    assert dev < 0.05, dev  # O(dt) oscillation of the measured energy
    assert drift < 0.01, drift  # no secular growth over 3000 steps


def test_velocity_verlet_energy_error_second_order_without_drift():
    E0, h1 = _energy_history("velocity-verlet", 0.1, steps=2000, check_every=2)
    _, h2 = _energy_history("velocity-verlet", 0.05, steps=4000, check_every=4)  # same times
    dev1, dev2 = np.abs(h1 - E0).max() / E0, np.abs(h2 - E0).max() / E0
    assert dev1 < 5e-3, dev1
    assert 3.0 < dev1 / dev2 < 5.5, dev1 / dev2  # halving dt divides the error by ~4
    tenth = len(h1) // 10
    assert abs(h1[-tenth:].mean() - h1[:tenth].mean()) / E0 < 5e-4


def test_forward_euler_energy_grows():
    E0, hist = _energy_history("forward-euler", 0.1, steps=1000)
    growth = hist[-1] / E0
    assert growth > 100.0, growth
    # monotone in trend: each later quarter holds more energy than the previous one
    q = np.array_split(hist, 4)
    assert all(q[i + 1].mean() > q[i].mean() for i in range(3))


def test_forward_euler_energy_growth_matches_modal_theory_on_a_rod():
    """A longitudinally displaced rod is an exactly linear system (l = x_j - x_i), so forward
    Euler multiplies each mode's energy by (1 + w_k^2 dt^2) every step."""
    model = rod()
    state = _rod_state(model)
    K = model.dense_hessian(model.X_nd, psd=False)
    M = np.repeat(model.mass, 3)
    w2, Phi = sla.eigh(K, np.diag(M))  # Phi^T M Phi = I
    u0 = (state.numpy().x - model.X).reshape(-1)
    q0 = Phi.T @ (M * u0)
    E_modes = 0.5 * np.clip(w2, 0, None) * q0 ** 2
    dt, n = 0.1 * true_stable_dt(model), 120
    predicted = np.sum(E_modes * (1 + np.clip(w2, 0, None) * dt * dt) ** n)
    Stepper(model, integrators.get("forward-euler")).step(state, dt, n)
    measured = diagnostics.total_energy(model, state)
    assert measured / E_modes.sum() > 10  # it grew a lot ...
    assert measured == pytest.approx(predicted, rel=1e-8)  # ... exactly as the theory says


# ------------------------------------------------------------------------------------------
# pins and gravity
# ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", ["forward-euler", "symplectic-euler", "velocity-verlet"])
def test_pinned_vertices_never_move(name):
    model, _ = wobbly_grid(3, N=4, pinned=[0, 3], gravity=[0.0, 0.0, -9.81])
    state = model.make_state()
    x0 = state.numpy().x
    dt = 0.2 * stable_dt_estimate(model)
    Stepper(model, integrators.get(name)).step(state, dt, 300)
    x, v, _ = state.numpy()
    np.testing.assert_array_equal(x[[0, 3]], x0[[0, 3]])
    np.testing.assert_array_equal(v[[0, 3]], 0.0)
    sag = x0[model.free, 2].mean() - x[model.free, 2].mean()
    assert sag > 0.01, sag  # the free part fell under gravity


def test_velocity_verlet_free_fall_is_exact():
    model = Model(np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 1.0]]), mass=[1.0, 2.0], gravity=[0.0, 0.0, -9.81])
    state = model.make_state(v=np.array([[1.0, 0.0, 2.0], [0.0, 0.5, 0.0]]))
    dt, n = 0.01, 100
    Stepper(model, integrators.get("velocity-verlet")).step(state, dt, n)
    t = n * dt
    ref = np.array([[1.0 * t, 0.0, 1.0 + 2.0 * t - 0.5 * 9.81 * t * t], [1.0, 0.5 * t, 1.0 - 0.5 * 9.81 * t * t]])
    assert np.abs(state.numpy().x - ref).max() < 1e-12


def test_symplectic_euler_free_fall_matches_discrete_formula():
    model = Model(np.zeros((1, 3)), gravity=[0.0, -9.81, 0.0])
    state = model.make_state()
    dt, n = 0.01, 50
    Stepper(model, integrators.get("symplectic-euler")).step(state, dt, n)
    # v_k = -g k dt, x_n = -g dt^2 n (n + 1) / 2
    assert state.numpy().x[0, 1] == pytest.approx(-9.81 * dt * dt * n * (n + 1) / 2, rel=1e-12)


# ------------------------------------------------------------------------------------------
# CFL limit and blow-up detection
# ------------------------------------------------------------------------------------------

def _rod_state(model, seed=4):
    x0 = model.X.copy()
    x0[:, 0] += 0.002 * np.random.default_rng(seed).standard_normal(model.n)  # longitudinal only
    return model.make_state(x0)


def test_symplectic_euler_blows_up_just_above_the_cfl_limit_and_reports_the_step():
    model = rod()
    dt_true = true_stable_dt(model)
    state = _rod_state(model)
    E0 = diagnostics.total_energy(model, state)
    # near the limit the measured energy T + W of the top mode oscillates by up to
    # (1 + w dt/2)/(1 - w dt/2) (symplectic Euler conserves T + W - dt/2 w^2 x v, not T + W):
    # use a bound far above that, so that only exponential growth reaches it
    bound = 1e4 * E0
    with pytest.raises(BlowUpError) as info:
        run(model, state, 1.05 * dt_true, 3000, integrator="symplectic-euler", energy_bound=bound)
    err = info.value
    msg = str(err)
    assert err.energy > bound and err.dt == pytest.approx(1.05 * dt_true)
    assert f"step {err.step}" in msg and "CFL" in msg and "reduce dt" in msg and "\n" not in msg
    assert err.dt_stable == pytest.approx(stable_dt_estimate(model))
    assert err.dt_stable <= dt_true
    # the reported step is the first one past the bound
    again = _rod_state(model)
    hist = run(model, again, 1.05 * dt_true, err.step + 1, integrator="symplectic-euler")
    assert hist[-1] > bound and hist[:-1].max() <= bound
    assert 5 < err.step < 500, err.step


def test_symplectic_euler_stable_just_below_the_cfl_limit():
    model = rod()
    state = _rod_state(model)
    E0 = diagnostics.total_energy(model, state)
    dt = 0.95 * true_stable_dt(model)
    hist = run(model, state, dt, 5000, integrator="symplectic-euler", energy_bound=1e4 * E0, check_every=10)
    # bounded: T + W oscillates, by at most (1 + w dt/2)/(1 - w dt/2) = 1.95/0.05 = 39 times its
    # starting value for a mode started at rest, but does not grow
    tenth = len(hist) // 10
    assert hist.max() / E0 < 39.0, hist.max() / E0
    assert hist[-tenth:].max() < 1.5 * hist[:tenth].max()
    assert len(hist) == 500


def test_rod_gershgorin_dt_is_h_over_c():
    """1D rod, c = k L per spring, m = rho h: the CFL limit dt = h / sqrt(E/rho) (the 1D wave equation's CFL limit)."""
    h, k, m = 0.05, 100.0, 0.2
    model = rod(h=h, k=k, m=m)
    E, rho = k, m / h  # c_e = k h = E A with A = 1, m = rho h
    assert stable_dt_estimate(model) == pytest.approx(h / math.sqrt(E / rho), rel=1e-12)


def test_forward_euler_blow_up_names_the_method():
    model, x0 = wobbly_grid(5)
    state = model.make_state(x0)
    E0 = diagnostics.total_energy(model, state)
    with pytest.raises(BlowUpError, match="forward Euler .* unstable") as info:
        run(model, state, 0.5 * stable_dt_estimate(model), 5000, integrator="forward-euler", energy_bound=100 * E0)
    assert info.value.integrator == "forward-euler" and info.value.step > 0


def test_non_finite_energy_is_caught_without_a_bound():
    model = rod()
    state = _rod_state(model)
    with pytest.raises(BlowUpError, match="is not finite") as info:
        run(model, state, 3.0 * true_stable_dt(model), 5000, integrator="symplectic-euler")
    assert info.value.step > 0 and not math.isfinite(info.value.energy)
