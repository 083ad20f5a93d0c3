"""Backward Euler (engine.integrators.implicit): Baraff-Witkin step, Newton + line search,
damping of a mode, unconditional stability, first-order accuracy, pins, solver failures."""
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from engine import diagnostics, integrators, mesh
from engine.energies.bending import BendingEnergy
from engine.energies.springs import SpringEnergy
from engine.integrators import BackwardEuler, SolverError, make_integrator
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


def spring_net(N=5, pinned=(0, 4), gravity=(0, 0, -9.81), seed=0):
    X, E = grid_network(N)
    rng = np.random.default_rng(seed)
    model = Model.from_springs(X, E, k=20.0, mass=rng.uniform(0.05, 0.15, len(X)), pinned=list(pinned),
                               gravity=gravity)
    x0 = X + 0.02 * rng.standard_normal(X.shape)
    v0 = rng.standard_normal(X.shape)
    return model, x0, v0


def cloth(N=6, E=500.0, B=0.05):
    m3 = mesh.embed_3d(mesh.right_triangle_grid(N, N, 1.0, 1.0))
    X = m3.vertices
    model = Model(X, mass=mesh.lumped_masses(m3, 0.2), pinned=[0, N - 1], gravity=[0, 0, -9.81])
    model.add_energy(SpringEnergy.from_rest(X, m3.edges, c=E * mesh.edge_measure(m3)))
    model.add_energy(BendingEnergy.from_mesh(m3, B=B))
    return model


def dense_K(model, x):
    """-(PSD Hessian) as a dense matrix (df/dx of Baraff & Witkin, with the PSD projection)."""
    from engine.fields import vec3_ndarray
    return -model.dense_hessian(vec3_ndarray(model.n, x), psd=True)


def numpy_forces(model, x):
    """-grad W + M g on free vertices, zero on pinned (numpy, from the model's force kernel)."""
    from engine.fields import vec3_ndarray
    f = vec3_ndarray(model.n)
    model.forces(vec3_ndarray(model.n, x), f)
    return f.to_numpy().astype(np.float64)


# ------------------------------------------------------------------------------------------
# registry and options
# ------------------------------------------------------------------------------------------

def test_registry_and_make_integrator():
    be = integrators.get("backward-euler")
    assert isinstance(be, BackwardEuler) and be.implicit and be.name == "backward-euler"
    assert be.solver.name == "pcg" and be.newton_iterations == 1
    custom = make_integrator("backward-euler", solver="cholesky", tol=1e-6, newton_iterations=3, rayleigh_alpha=0.1)
    assert (custom.solver.name, custom.tol, custom.newton_iterations, custom.rayleigh_alpha) == \
        ("cholesky", 1e-6, 3, 0.1)
    assert make_integrator("symplectic-euler", solver="pcg", tol=1e-3) is integrators.get("symplectic-euler")
    with pytest.raises(ValueError, match="backward-euler"):
        make_integrator("crank-nicolson")
    with pytest.raises(ValueError, match="pcg, cholesky"):
        make_integrator("backward-euler", solver="gauss-seidel")


# ------------------------------------------------------------------------------------------
# the step itself
# ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("solver", ["pcg", "cholesky"])
def test_one_iteration_is_baraff_witkin_step(solver):
    """(M - dt^2 df/dx) dv = dt (f0 + dt df/dx v0), dense, equals one Newton iteration from x_n."""
    model, x0, v0 = spring_net()
    dt = 0.05
    be = make_integrator("backward-euler", solver=solver, tol=1e-12, line_search=False)
    st = model.make_state(x0, v0)
    Stepper(model, be).step(st, dt)
    free = np.repeat(model.free, 3)
    K = dense_K(model, x0)[np.ix_(free, free)]
    M = np.diag(np.repeat(model.mass, 3)[free])
    f0 = numpy_forces(model, x0).reshape(-1)[free]
    v0f = model.make_state(x0, v0).numpy().v.reshape(-1)[free]
    dv = np.linalg.solve(M - dt * dt * K, dt * (f0 + dt * K @ v0f))
    x1, v1, t1 = st.numpy()
    assert np.abs(v1.reshape(-1)[free] - (v0f + dv)).max() <= 1e-9 * np.abs(v0f + dv).max()
    assert np.allclose(x1, x0 + dt * v1, rtol=0, atol=1e-14)
    assert t1 == pytest.approx(dt)


@pytest.mark.parametrize("alpha,beta", [(0.0, 0.0), (0.5, 0.0), (0.0, 0.02), (0.3, 0.01)])
def test_newton_converges_to_backward_euler_with_monotone_objective(alpha, beta):
    """Converged Newton solves M (v+ - v)/dt = f(x+) + M g - (alpha M + beta H_n) v+ (H_n: PSD
    Hessian at x_n); the incremental potential decreases at every Newton step."""
    model = cloth(5)
    rng = np.random.default_rng(3)
    x0 = model.X + 0.05 * rng.standard_normal(model.X.shape)
    v0 = rng.standard_normal(model.X.shape)  # a strongly nonlinear step
    dt = 0.05
    be = BackwardEuler(solver="cholesky", tol=1e-12, newton_iterations=30, newton_tol=1e-10,
                       rayleigh_alpha=alpha, rayleigh_beta=beta)
    st = model.make_state(x0, v0)
    v0 = st.numpy().v
    stepper = Stepper(model, be)
    stepper.step(st, dt)
    info = stepper.last_info
    obj = np.asarray(info.objectives)
    assert len(obj) >= 3 and np.all(np.diff(obj) < 0), obj
    # converged (or stopped at round-off, where Phi no longer measurably decreases)
    assert info.newton_converged or info.line_search_failed
    assert info.gradient_norms[-1] <= 1e-8 * info.gradient_norms[0], info.gradient_norms
    x1, v1, _ = st.numpy()
    free = model.free
    Hn = -dense_K(model, x0)
    damping = (alpha * np.repeat(model.mass, 3) * v1.reshape(-1) + beta * Hn @ v1.reshape(-1)).reshape(-1, 3)
    residual = model.mass[:, None] * (v1 - v0) / dt - numpy_forces(model, x1) + damping
    # relative to |grad Phi(x_n)| = |M v_n/dt + f(x_n) + M g| (the Newton scale; ~130 N here)
    assert np.abs(residual[free]).max() <= 1e-8 * info.gradient_norms[0]


def test_line_search_backtracks_on_a_violent_step():
    """Far from linear (huge velocities, huge dt) the full Newton step would raise the incremental
    potential; the line search takes shorter steps and keeps the decrease monotone."""
    model = cloth(5, E=2000.0)
    rng = np.random.default_rng(5)
    st = model.make_state(model.X, 20.0 * rng.standard_normal(model.X.shape))
    be = BackwardEuler(solver="cholesky", newton_iterations=40, newton_tol=1e-9)
    short_steps = 0
    for _ in range(5):
        stepper = Stepper(model, be)
        stepper.step(st, 0.2)
        obj = np.asarray(stepper.last_info.objectives)
        assert np.all(np.diff(obj) < 0), obj
        short_steps += sum(s < 1.0 for s in stepper.last_info.step_sizes)
    assert short_steps >= 1


@pytest.mark.parametrize("solver", ["pcg", "cholesky"])
def test_pinned_vertices_never_move(solver):
    model = cloth(6)
    st = model.make_state()
    dt = 100 * stable_dt_estimate(model)
    be = make_integrator("backward-euler", solver=solver)
    stepper = Stepper(model, be)
    stepper.step(st, dt, 10)
    x, v, _ = st.numpy()
    assert np.array_equal(x[model.pinned], model.X[model.pinned])
    assert np.all(v[model.pinned] == 0.0)
    assert np.abs(x[model.free] - model.X[model.free]).max() > 0.05  # the cloth did fall
    assert max(stepper.last_info.linear_residuals) <= 1e-8


def test_nonconvergent_linear_solve_raises_and_keeps_state():
    model = cloth(6)
    st = model.make_state(model.X, np.random.default_rng(0).standard_normal(model.X.shape))
    before = st.numpy()
    be = BackwardEuler(solver="pcg", tol=1e-10, max_iter=2)
    with pytest.raises(SolverError) as exc:
        Stepper(model, be).step(st, 0.05)
    msg = str(exc.value)
    assert "\n" not in msg and "pcg" in msg and "tol 1.0e-10" in msg and "2 iterations" in msg, msg
    after = st.numpy()
    assert np.array_equal(after.x, before.x) and np.array_equal(after.v, before.v) and after.t == before.t


# ------------------------------------------------------------------------------------------
# energy behaviour and accuracy
# ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("solver", ["pcg", "cholesky"])
def test_stable_at_100x_explicit_dt(solver):
    """A spring network with pins and gravity at 100x the explicit CFL limit: the total energy never
    grows (backward Euler dissipates) and the motion settles."""
    model, x0, v0 = spring_net(N=6)
    dt_explicit = stable_dt_estimate(model, method="power")
    st = model.make_state(x0, v0)
    be = make_integrator("backward-euler", solver=solver)
    E = [diagnostics.total_energy(model, st)]
    for _ in range(30):
        Stepper(model, be).step(st, 100 * dt_explicit)
        E.append(diagnostics.total_energy(model, st))
    E = np.asarray(E)
    assert np.all(np.isfinite(E))
    assert E[-1] <= E[0]
    assert np.diff(E).max() <= 1e-12 * abs(E).max()  # monotone up to rounding
    assert diagnostics.kinetic_energy(model, st) < 1e-6 * (E[0] - E[-1])


@pytest.mark.parametrize("solver", ["pcg", "cholesky"])
def test_mode_energy_decays_by_one_over_one_plus_w2dt2(solver):
    """A chain of springs along x, pinned at both ends, moving along x: linear (W = 1/2 c/L^2
    (l - L)^2 exactly for l > 0), so each step multiplies a mode's energy by 1/(1 + w^2 dt^2)."""
    N, h, k, m = 9, 0.1, 50.0, 0.1
    X = np.zeros((N, 3))
    X[:, 0] = np.arange(N) * h
    model = Model.from_springs(X, np.stack([np.arange(N - 1), np.arange(1, N)], 1), k=k, mass=m, pinned=[0, N - 1])
    from engine.fields import vec3_ndarray
    H = model.dense_hessian(vec3_ndarray(N, X), psd=False)
    xdofs = 3 * np.flatnonzero(model.free)
    w2, V = np.linalg.eigh(H[np.ix_(xdofs, xdofs)] / m)
    dt_explicit = stable_dt_estimate(model)
    be = make_integrator("backward-euler", solver=solver, tol=1e-12)
    for mode in (0, 3):
        for dt in (0.5 * dt_explicit, 10 * dt_explicit):
            u = np.zeros((N, 3))
            u[model.free, 0] = 1e-3 * V[:, mode] / np.abs(V[:, mode]).max()
            st = model.make_state(X + u, 0.3 * u)  # velocity along the same mode
            E0 = diagnostics.total_energy(model, st)
            for _ in range(3):
                Stepper(model, be).step(st, dt)
                E1 = diagnostics.total_energy(model, st)
                assert E1 / E0 == pytest.approx(1.0 / (1.0 + w2[mode] * dt * dt), rel=1e-8)
                E0 = E1


def _pendulum():
    """A triangle of springs hanging from one pinned vertex, swinging and stretching (nonlinear)."""
    X = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 0.8, 0.3]])
    E = np.array([[0, 1], [1, 2], [0, 2]])
    model = Model.from_springs(X, E, k=40.0, mass=[1.0, 0.5, 0.7], pinned=[0], gravity=[0, 0, -9.81])
    v0 = np.array([[0.0, 0.0, 0.0], [0.0, 1.0, 0.5], [0.3, 0.0, 0.0]])
    return model, X, v0


def _reference_solution(model, X, v0, T):
    sp = model.springs
    e, L, c = sp.edges_np, sp.L_np, sp.c_np
    m = model.mass[:, None]
    free = model.free[:, None]

    def rhs(t, y):
        x, v = y[:9].reshape(3, 3), y[9:].reshape(3, 3)
        d = x[e[:, 0]] - x[e[:, 1]]
        l = np.linalg.norm(d, axis=1)
        fe = -(c / L * (l / L - 1) / l)[:, None] * d
        f = np.zeros_like(x)
        np.add.at(f, e[:, 0], fe)
        np.add.at(f, e[:, 1], -fe)
        a = np.where(free, f / m + model.gravity, 0.0)
        return np.concatenate([np.where(free, v, 0.0).ravel(), a.ravel()])

    sol = solve_ivp(rhs, (0, T), np.concatenate([X.ravel(), v0.ravel()]), method="DOP853", rtol=1e-12, atol=1e-12)
    return sol.y[:9, -1].reshape(3, 3)


def test_first_order_convergence_vs_verlet_second_order():
    model, X, v0 = _pendulum()
    T = 0.4
    ref = _reference_solution(model, X, v0, T)
    be = BackwardEuler(solver="cholesky", tol=1e-12, newton_iterations=8, newton_tol=1e-10)
    errors = {"backward-euler": [], "velocity-verlet": []}
    for n in (20, 40, 80):
        for name, integ in (("backward-euler", be), ("velocity-verlet", integrators.get("velocity-verlet"))):
            st = model.make_state(X, v0)
            Stepper(model, integ).step(st, T / n, n)
            errors[name].append(np.abs(st.numpy().x - ref).max())
    be_ratio = np.array(errors["backward-euler"][:-1]) / np.array(errors["backward-euler"][1:])
    vv_ratio = np.array(errors["velocity-verlet"][:-1]) / np.array(errors["velocity-verlet"][1:])
    assert np.all((1.8 <= be_ratio) & (be_ratio <= 2.2)), (be_ratio, errors)
    assert np.all((3.6 <= vv_ratio) & (vv_ratio <= 4.4)), (vv_ratio, errors)


def test_works_with_run_and_blowup_checks():
    """engine.integrators.run drives any integrator with begin/advance; backward Euler's energy never grows."""
    model, x0, v0 = spring_net()
    st = model.make_state(x0, v0)
    energies = run(model, st, 50 * stable_dt_estimate(model), 20, integrator="backward-euler",
                   energy_bound=diagnostics.total_energy(model, model.make_state(x0, v0)))
    assert len(energies) == 20 and np.all(np.diff(energies) <= 1e-12 * np.abs(energies).max())
    assert st.t == pytest.approx(20 * 50 * stable_dt_estimate(model))
    assert math.isfinite(energies[-1])
