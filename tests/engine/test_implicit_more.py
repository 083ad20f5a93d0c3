"""More checks of backward Euler and its linear solvers on the shared hanging-cloth scene
(engine/scenes.py), complementing tests/engine/test_implicit.py and tests/engine/test_solvers.py:

- stability at 100x the explicit limit on the cloth (springs + bending + gravity + pins);
- the damping factor 1/(1 + w^2 dt^2) of an in-plane cloth mode with one Newton iteration;
- convergence orders: backward Euler 1, symplectic Euler 1, velocity Verlet 2, and symplectic
  Euler started half a step earlier has exactly Verlet's positions;
- PCG, Cholesky and scipy's sparse direct solve agree on one backward-Euler system to the
  solver tolerance;
- the reported linear residual is the true one (recomputed densely) and below the tolerance;
- pinned vertices never move, with Newton, the exact Hessian and Rayleigh damping;
- Newton with line search lowers the incremental potential at every iteration, step after step;
- a linear solve that does not converge raises SolverError and leaves the state untouched.
"""
import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.integrate import solve_ivp

from engine import diagnostics
from engine.integrators import BackwardEuler, SolverError, Stepper, get, make_integrator
from engine.stability import lambda_max_power
from engine.solvers import make_solver
from engine.fields import vec3_ndarray
from engine.model import Model
from engine.scenes import cloth

SOLVERS = ["pcg", "cholesky"]


def explicit_limit(model, x=None):
    return 2.0 / np.sqrt(abs(lambda_max_power(model, x)))


def forces(model, x):
    f = vec3_ndarray(model.n)
    model.forces(vec3_ndarray(model.n, x), f)
    return f.to_numpy().astype(np.float64)


def dense_system(model, x, a):
    """a M + H_psd(x) on the free dofs (dense) and the free-dof mask."""
    H = model.dense_hessian(vec3_ndarray(model.n, x), psd=True)
    A = a * np.diag(np.repeat(model.mass, 3)) + H
    free = np.repeat(model.free, 3)
    return A[np.ix_(free, free)], free


@pytest.mark.parametrize("solver", SOLVERS)
def test_cloth_stable_at_100x_the_explicit_limit(solver):
    scene = cloth(8, E=1e3, rho=0.1, B=1e-4)
    model, X = scene.model, scene.model.X
    dt = 100.0 * explicit_limit(model)
    st = model.make_state()
    E0 = diagnostics.total_energy(model, st)
    be = make_integrator("backward-euler", solver=solver, tol=1e-8)
    energies, solves = [], 0
    for _ in range(20):
        stepper = Stepper(model, be)
        stepper.step(st, dt)
        energies.append(diagnostics.total_energy(model, st))
        # a step that starts converged (settled: |grad Phi| <= newton_tol |M g|) solves nothing
        assert all(r <= 1e-8 for r in stepper.last_info.linear_residuals)
        solves += len(stepper.last_info.linear_residuals)
    assert solves >= 10
    energies = np.asarray(energies)
    assert np.all(np.isfinite(energies)) and energies.max() <= E0
    x, v, _ = st.numpy()
    assert np.array_equal(x[model.pinned], X[model.pinned]) and np.all(v[model.pinned] == 0.0)
    # settled: what is left moving is a tiny fraction of the energy the fall released
    assert diagnostics.kinetic_energy(model, st) < 1e-6 * (E0 - energies[-1])


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize("wdt", [0.5, 5.0])
def test_in_plane_cloth_mode_energy_factor_with_one_newton_iteration(solver, wdt):
    """No gravity (the flat sheet is an equilibrium); a micrometre in-plane eigenmode: one
    Baraff-Witkin step multiplies its energy by 1/(1 + w^2 dt^2) up to O(amplitude)."""
    scene = cloth(6, E=1e3, rho=0.1, B=1e-4, gravity=0.0)
    model, X = scene.model, scene.model.X
    H = model.dense_hessian(vec3_ndarray(model.n, X), psd=False)
    free = np.flatnonzero(model.free)
    dofs = (3 * free[:, None] + np.array([0, 2])[None, :]).ravel()
    s = 1.0 / np.sqrt(np.repeat(model.mass[free], 2))
    w2, V = np.linalg.eigh(s[:, None] * H[np.ix_(dofs, dofs)] * s[None, :])
    k = len(w2) // 3
    u = np.zeros(3 * model.n)
    u[dofs] = s * V[:, k]
    u = 1e-6 * u.reshape(-1, 3) / np.abs(u).max()
    dt = wdt / np.sqrt(w2[k])
    st = model.make_state(X + u)
    E0 = diagnostics.total_energy(model, st)
    be = make_integrator("backward-euler", solver=solver, tol=1e-12, newton_iterations=1)
    for _ in range(2):
        Stepper(model, be).step(st, dt)
        E1 = diagnostics.total_energy(model, st)
        assert E1 / E0 == pytest.approx(1.0 / (1.0 + wdt * wdt), rel=1e-5)
        E0 = E1


def _pendulum():
    """A triangle of springs hanging from one pinned vertex: swings and stretches (nonlinear)."""
    X = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 0.8, 0.3]])
    E = np.array([[0, 1], [1, 2], [0, 2]])
    model = Model.from_springs(X, E, k=40.0, mass=[1.0, 0.5, 0.7], pinned=[0], gravity=[0, 0, -9.81])
    v0 = np.array([[0.0, 0.0, 0.0], [0.0, 1.0, 0.5], [0.3, 0.0, 0.0]])
    return model, X, v0


def _reference(model, X, v0, T):
    m = model.mass[:, None]
    free = model.free[:, None]
    x_nd, f_nd = vec3_ndarray(3), vec3_ndarray(3)

    def rhs(t, y):
        x, v = y[:9].reshape(3, 3), y[9:].reshape(3, 3)
        x_nd.from_numpy(x)
        model.forces(x_nd, f_nd)  # -grad W + m g on free vertices
        a = np.where(free, f_nd.to_numpy() / m, 0.0)
        return np.concatenate([np.where(free, v, 0.0).ravel(), a.ravel()])

    sol = solve_ivp(rhs, (0, T), np.concatenate([X.ravel(), v0.ravel()]), method="DOP853", rtol=1e-12,
                    atol=1e-12)
    return sol.y[:9, -1].reshape(3, 3)


def test_orders_and_symplectic_euler_half_step_start():
    model, X, v0 = _pendulum()
    T = 0.4
    ref = _reference(model, X, v0, T)
    a0 = np.where(model.free[:, None], forces(model, X) / model.mass[:, None], 0.0)
    assert np.abs(a0).max() > 1.0  # the start is not an equilibrium: symplectic Euler is first order
    be = BackwardEuler(solver="cholesky", tol=1e-12, newton_iterations=10, newton_tol=1e-11)
    errors = {"backward-euler": [], "symplectic-euler": [], "velocity-verlet": []}
    shifted = []
    for n in (40, 80, 160):
        dt = T / n
        finals = {}
        for name in errors:
            integ = be if name == "backward-euler" else get(name)
            st = model.make_state(X, v0)
            Stepper(model, integ).step(st, dt, n)
            finals[name] = st.numpy().x
            errors[name].append(np.abs(finals[name] - ref).max())
        st = model.make_state(X, v0 - 0.5 * dt * a0)  # the velocity half a step earlier
        Stepper(model, get("symplectic-euler")).step(st, dt, n)
        shifted.append(np.abs(st.numpy().x - finals["velocity-verlet"]).max() / errors["velocity-verlet"][-1])
    order = {k: np.log2(np.asarray(e[:-1]) / np.asarray(e[1:])) for k, e in errors.items()}
    assert np.all(np.abs(order["backward-euler"] - 1) < 0.1), (order, errors)
    assert np.all(np.abs(order["symplectic-euler"] - 1) < 0.1), (order, errors)
    assert np.all(np.abs(order["velocity-verlet"] - 2) < 0.1), (order, errors)
    assert max(shifted) < 1e-6, shifted


def test_pcg_cholesky_and_scipy_sparse_agree_on_a_backward_euler_system():
    """The system of a frame-sized step (dt = 1/60 s, ~50x the explicit limit) at a sagging state."""
    scene = cloth(7, E=1e3, rho=0.1, B=1e-4)
    model = scene.model
    st = model.make_state()
    Stepper(model, make_integrator("backward-euler", solver="cholesky")).step(st, 0.02, 3)
    x = st.numpy().x
    dt = 1.0 / 60.0
    a = 1.0 / dt ** 2
    A, free = dense_system(model, x, a)
    b = np.random.default_rng(3).standard_normal((model.n, 3))
    bf = b.reshape(-1)[free]
    y_ref = spla.spsolve(sp.csc_matrix(A), bf)
    cond = np.linalg.cond(A)
    tol = 1e-10
    ys = {}
    for name in SOLVERS:
        y = vec3_ndarray(model.n)
        info = make_solver(name, tol=tol, max_iter=20000).solve(model, vec3_ndarray(model.n, x),
                                                               vec3_ndarray(model.n, b), y, a)
        yy = y.to_numpy().reshape(-1)
        assert info.converged and info.residual <= tol
        assert np.all(yy[~free] == 0.0)
        ys[name] = yy[free]
        # the true residual of this solution is the reported one
        assert np.linalg.norm(A @ ys[name] - bf) / np.linalg.norm(bf) == pytest.approx(info.residual, rel=1e-2,
                                                                                       abs=1e-15)
    assert np.linalg.norm(A @ y_ref - bf) / np.linalg.norm(bf) <= tol
    # forward errors within cond(A) x tolerance of each other and of scipy
    for u, v in ((ys["pcg"], y_ref), (ys["cholesky"], y_ref), (ys["pcg"], ys["cholesky"])):
        assert np.linalg.norm(u - v) / np.linalg.norm(v) <= 2 * cond * tol


@pytest.mark.parametrize("solver", SOLVERS)
def test_reported_linear_residual_is_the_true_one_and_below_tol(solver):
    """One Baraff-Witkin step without line search: dx = x+ - x_n solves (M/dt^2 + H) dx = f + M g + M v_n/dt.
    The residual recomputed with the dense matrix equals the reported one and is below the (loose) tol."""
    scene = cloth(6, E=1e3, rho=0.1, B=1e-4)
    model, X = scene.model, scene.model.X
    rng = np.random.default_rng(2)
    st = model.make_state(X + 0.01 * rng.standard_normal(X.shape), 0.3 * rng.standard_normal(X.shape))
    x0, v0, _ = st.numpy()
    dt = 0.02
    tol = 1e-6
    be = BackwardEuler(solver=solver, tol=tol, newton_iterations=1, line_search=False)
    stepper = Stepper(model, be)
    stepper.step(st, dt)
    x1 = st.numpy().x
    A, free = dense_system(model, x0, 1.0 / dt ** 2)
    b = (forces(model, x0) + model.mass[:, None] * v0 / dt).reshape(-1)[free]
    dx = (x1 - x0).reshape(-1)[free]
    residual = np.linalg.norm(A @ dx - b) / np.linalg.norm(b)
    reported = stepper.last_info.linear_residuals
    assert len(reported) == 1 and reported[0] <= tol
    assert residual <= tol and residual == pytest.approx(reported[0], rel=1e-3, abs=1e-14)


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize("options", [dict(newton_iterations=1), dict(newton_iterations=8),
                                     dict(newton_iterations=8, rayleigh_alpha=0.5, rayleigh_beta=0.01)])
def test_pins_never_move(solver, options):
    scene = cloth(5, E=1e3, rho=0.1, B=1e-4)
    model, X = scene.model, scene.model.X
    st = model.make_state(X, np.random.default_rng(0).standard_normal(X.shape))
    be = make_integrator("backward-euler", solver=solver, **options)
    Stepper(model, be).step(st, 50.0 * explicit_limit(model), 4)
    x, v, _ = st.numpy()
    assert np.array_equal(x[model.pinned], X[model.pinned]) and np.all(v[model.pinned] == 0.0)
    assert np.abs(x[model.free] - X[model.free]).max() > 1e-3  # the rest did move


@pytest.mark.parametrize("solver", SOLVERS)
def test_newton_line_search_decreases_the_objective_every_iteration(solver):
    scene = cloth(6, E=1e3, rho=0.1, B=1e-3)
    model = scene.model
    st = model.make_state()
    be = BackwardEuler(solver=solver, newton_iterations=30, newton_tol=1e-9)
    dt = 100.0 * explicit_limit(model)
    weight = float(model.mass.sum()) * 9.81
    iterations = 0
    for _ in range(8):
        stepper = Stepper(model, be)
        stepper.step(st, dt)
        info = stepper.last_info
        obj = np.asarray(info.objectives)
        assert len(obj) == len(info.step_sizes) + 1 and np.all(np.diff(obj) < 0), obj
        # converged; once the cloth has settled the relative test asks for round-off, and Newton
        # stops (line search without a measurable decrease, or the iteration limit) with a net
        # force below a millionth of the cloth's weight
        assert info.newton_converged or info.gradient_norms[-1] < 1e-6 * weight
        iterations += info.newton_iterations
    assert iterations > 8  # more than one Newton iteration per step on average: the steps are nonlinear


def test_nonconvergent_solve_mid_run_raises_and_keeps_the_state():
    scene = cloth(6, E=1e4, rho=0.1, B=1e-4)
    model = scene.model
    st = model.make_state()
    Stepper(model, make_integrator("backward-euler")).step(st, 1.0 / 60.0, 3)  # fine with the defaults
    before = st.numpy()
    starved = BackwardEuler(solver="pcg", tol=1e-8, max_iter=3)
    with pytest.raises(SolverError) as exc:
        Stepper(model, starved).step(st, 1.0 / 60.0)
    msg = str(exc.value)
    assert "\n" not in msg and "pcg" in msg and "3 iterations" in msg and "t=0.05" in msg, msg
    after = st.numpy()
    assert np.array_equal(after.x, before.x) and np.array_equal(after.v, before.v) and after.t == before.t
    Stepper(model, make_integrator("backward-euler")).step(st, 1.0 / 60.0)  # and the run can go on
    assert st.t == pytest.approx(4.0 / 60.0)


def test_newton_on_a_settled_hanging_cloth_stops_at_once():
    """At equilibrium |grad Phi(x_n)| is round-off; the tolerance is relative to at least the
    weight |M g|, so Newton does not spend its iterations chasing round-off."""
    from engine.scenes import cloth
    from engine.statics import solve_static

    c = cloth(8, E=1e3, B=1e-4)
    model = c.model
    res = solve_static(model, model.X_nd.to_numpy(), tol=1e-9, max_iter=100)
    state = model.make_state(res.x)
    integ = make_integrator("backward-euler", solver="cholesky", newton_iterations=50)
    stepper = Stepper(model, integ)
    stepper.step(state, 1.0 / 60.0, 3)
    assert stepper.last_info.newton_converged
    assert len(stepper.last_info.gradient_norms) <= 2


@pytest.mark.parametrize("newton_iterations", [1, 3])
def test_serial_and_parallel_vertex_passes_give_the_same_steps(monkeypatch, newton_iterations):
    """The implicit step's per-vertex passes (the copy of x_n, the residual, the weight in the forces,
    the update, the velocities) run serialized below VERTEX_PASS_SERIAL_BELOW vertices and on the
    thread pool above: the same states either way (Newton with its line search included, whose
    residual norm is a sum taken in another order when parallel)."""
    from engine import constants
    from engine.fields import serial_pass
    from engine.solvers import pardiso_available

    assert serial_pass(64 * 64) and serial_pass(128 * 128) and not serial_pass(256 * 256)

    def steps(below):
        monkeypatch.setattr(constants, "VERTEX_PASS_SERIAL_BELOW", below)
        model = cloth(12, B=1e-3).model
        st = model.make_state(None, 0.02 * np.random.default_rng(5).standard_normal((model.n, 3)))
        stepper = Stepper(model, BackwardEuler("pardiso" if pardiso_available() else "cholesky", tol=1e-8,
                                               newton_iterations=newton_iterations, newton_tol=1e-10))
        stepper.step(st, 1 / 60, 4)
        return st.numpy(), stepper.last_info
    (a, ia), (b, ib) = steps(0), steps(1 << 40)   # every pass on the pool; every pass serialized
    assert ia.newton_iterations == ib.newton_iterations == newton_iterations
    assert np.array_equal(a.x, b.x) and np.array_equal(a.v, b.v)
    assert not np.array_equal(a.x, cloth(12, B=1e-3).model.X)   # it moved
    np.testing.assert_allclose(ia.gradient_norms, ib.gradient_norms, rtol=1e-12)
