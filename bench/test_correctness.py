"""The benchmarks compute what they claim (runs in CI, no timing; the timed benchmarks live in
bench/test_bench_*.py):

* the benchmark scenes are the lessons' scenes (engine.scenes.cloth, engine.rod.Rod) and have the
  lessons' physics (no force at rest, mass and area-spring stiffness sums, the rod's CFL limit);
* the numpy baseline and the engine agree on forces and on explicit steps;
* the force-kernel variants (atomics, serialized scatter) agree with the engine's gathers;
* the numpy + scipy backward-Euler step agrees with the engine's (PCG and Cholesky) on the same
  input, and its assembled matrix with the engine's PSD Hessian (the precomputed-pattern assembly
  with a fresh COO one); every sparse peer (bench/peers/sparse.py) solves the engine's system;
  the same for the Baraff-Witkin membrane's numpy model (NumpyMembrane);
* the rod baselines agree with engine.rod, and the rod-as-Model backward Euler with the rod's;
* the headline's accuracy-matched dt and crossover helpers, the traffic model, and the streaming
  copy kernel do what they say.
"""
import math

import numpy as np
import pytest

from bench import config, headline, traffic
from bench.baseline import NumpyCloth, NumpyMembrane, NumpyRod
from bench.variants import VARIANTS, bending_variant, spring_variant, stream_copy
from engine.constants import CFL_SAFETY, G
from engine.integrators import BackwardEuler, Stepper
from engine.integrators import get as integrator
from engine.fields import vec3_ndarray
from engine.scenes import cloth
from engine.solvers import upper_product   # scipy, independent of the MKL product the peers use


def _deformed(c, seed=0, amp=0.01):
    rng = np.random.default_rng(seed)
    return c.model.X + amp * rng.standard_normal((c.model.n, 3))


# -- scenes ----------------------------------------------------------------------------------

def test_bench_cloth_is_the_lessons_scene_with_its_physics():
    c = config.cloth_scene(12, True)
    ref = cloth(12, E=config.CLOTH_E, rho=config.CLOTH_RHO, B=config.CLOTH_B)
    assert np.array_equal(c.model.X, ref.model.X)
    assert np.array_equal(c.springs.edges_np, ref.springs.edges_np)
    assert np.allclose(c.springs.c_np, ref.springs.c_np) and np.array_equal(c.model.pinned, ref.model.pinned)
    assert c.bending.variant == "notes" and np.allclose(c.bending.k, ref.bending.k)
    # lumped masses sum to rho x area; area springs: each triangle gives a third of its area to each
    # edge, so sum_e c_e = E x area
    assert math.isclose(float(np.sum(c.model.mass)), config.CLOTH_RHO * 1.0, rel_tol=1e-12)
    assert math.isclose(float(np.sum(c.springs.c_np)), config.CLOTH_E * 1.0, rel_tol=1e-12)
    # at rest the only force on a free vertex is its weight; pinned vertices get none
    f = vec3_ndarray(c.model.n)
    c.model.forces(c.model.X_nd, f)
    weight = c.model.mass[:, None] * np.array([0.0, 0.0, -G])
    got = f.to_numpy()
    assert np.allclose(got[c.model.free], weight[c.model.free], rtol=0, atol=1e-12)
    assert np.all(got[c.model.pinned] == 0.0)


def test_bench_start_state_keeps_pins_and_is_deterministic():
    c = config.cloth_scene(12, True)
    x0, v0 = config.cloth_start_state(c)
    x1, v1 = config.cloth_start_state(c)
    assert np.array_equal(x0, x1) and np.array_equal(v0, v1)
    p = c.model.pinned
    assert np.array_equal(x0[p], c.model.X[p]) and np.all(v0[p] == 0.0)
    assert 0.0 < np.abs(x0 - c.model.X).max() <= 0.06 and np.abs(v0).max() == pytest.approx(0.2)


def test_bench_rod_is_engine_rod_with_cfl_limit_h_over_c():
    rod, u0 = config.rod_scene(101)
    h = 1.0 / 100
    c = math.sqrt(config.ROD_E / config.ROD_RHO)
    assert np.allclose(rod.h, h) and rod.pinned[0] and not rod.pinned[1:].any()
    # symplectic Euler on the rod is stable iff dt <= h/c (the CFL limit of the 1D wave equation;
    # a pinned end allows slightly more)
    assert rod.stable_dt() >= h / c * (1 - 1e-12)
    assert abs(u0.max() - 1e-3) < 1e-4


# -- explicit: forces and steps ----------------------------------------------------------------

@pytest.mark.parametrize("B", [0.0, 1e-3])
def test_numpy_forces_equal_engine_forces_on_deformed_cloth(B):
    c = cloth(12, E=1e3, rho=0.1, B=B)
    x = _deformed(c)
    f = vec3_ndarray(c.model.n)
    c.model.forces(vec3_ndarray(c.model.n, x), f)
    ref = NumpyCloth(c.model, c.springs, c.bending).forces(x)
    assert np.max(np.abs(f.to_numpy() - ref)) <= 1e-10 * np.max(np.abs(ref))


def test_numpy_and_engine_symplectic_steps_agree():
    c = cloth(12, E=1e3, rho=0.1, B=1e-3)
    dt = 0.5 * 1e-3
    st = c.model.make_state()
    Stepper(c.model, integrator("symplectic-euler")).step(st, dt, 50)
    x, v = c.model.X.copy(), np.zeros((c.model.n, 3))
    NumpyCloth(c.model, c.springs, c.bending).symplectic_euler(x, v, dt, 50)
    got = st.numpy()
    assert np.max(np.abs(got.x - x)) <= 1e-10 * np.max(np.abs(x - c.model.X))
    assert np.max(np.abs(got.v - v)) <= 1e-9 * np.max(np.abs(v))


@pytest.mark.parametrize("variant", VARIANTS)
def test_force_kernel_variants_equal_engine_forces(variant):
    c = cloth(10, E=1e3, rho=0.1, B=1e-3)
    x = vec3_ndarray(c.model.n, _deformed(c, seed=1))
    ref_s = vec3_ndarray(c.model.n)
    c.springs.add_forces(x, ref_s)
    ref_b = vec3_ndarray(c.model.n)
    c.bending.add_forces(x, ref_b)
    for add, ref, obj in ((spring_variant(variant), ref_s, c.springs), (bending_variant(variant), ref_b, c.bending)):
        f = vec3_ndarray(c.model.n)
        add(x, obj, f)
        r = ref.to_numpy()
        assert np.max(np.abs(f.to_numpy() - r)) <= 1e-12 * np.max(np.abs(r)), (variant, type(obj).__name__)


def test_stream_copy_copies():
    import taichi as ti
    src = np.random.default_rng(0).standard_normal(1000)
    a, b = ti.ndarray(dtype=ti.f64, shape=1000), ti.ndarray(dtype=ti.f64, shape=1000)
    a.from_numpy(src)
    stream_copy(a, b)
    assert np.array_equal(b.to_numpy(), src)


# -- implicit: the scipy baseline against the engine ---------------------------------------------

def test_scipy_assembly_equals_engine_psd_hessian():
    c = cloth(8, E=1e3, rho=0.1, B=1e-3)
    x = _deformed(c, seed=2, amp=0.02)
    base = NumpyCloth(c.model, c.springs, c.bending)
    H = base.hessian_psd(x).toarray()
    ref = c.model.dense_hessian(vec3_ndarray(c.model.n, x), psd=True)
    free = np.repeat(c.model.free, 3)
    ref = ref[np.ix_(free, free)]
    assert np.max(np.abs(H - ref)) <= 1e-10 * np.max(np.abs(ref))


def test_scatter_assembly_equals_the_engines_matrix_on_two_states():
    """The baseline's assembly (per-step block values through a scatter matrix built once) is the
    engine's dense PSD Hessian on two different states (the pattern does not depend on x), in full
    and as the upper triangle PARDISO reads, and the peers' residual from the upper
    triangle (MKL's symmetric product) equals the full matrix's."""
    from bench.peers import sparse as peers
    c = cloth(8, E=1e3, rho=0.1, B=1e-3)
    base = NumpyCloth(c.model, c.springs, c.bending)
    free = np.repeat(c.model.free, 3)
    nf = base.n_free_dofs
    d = np.linspace(1.0, 2.0, nf)
    for seed in (1, 2):
        x = _deformed(c, seed=seed, amp=0.02)
        ref = c.model.dense_hessian(vec3_ndarray(c.model.n, x), psd=True)[np.ix_(free, free)]
        assert np.max(np.abs(base.hessian_psd(x).toarray() - ref)) <= 1e-12 * np.abs(ref).max()
        U = base.system_matrix(x, d, upper=True)
        assert np.max(np.abs(U.toarray() - np.triu(ref + np.diag(d)))) <= 1e-12 * np.abs(ref).max()
        y = np.random.default_rng(seed).standard_normal(nf)
        b = np.random.default_rng(seed + 10).standard_normal(nf)
        assert np.max(np.abs(peers.residual_of(U, b, y, upper=True) - (b - (ref + np.diag(d)) @ y))) <= \
            1e-12 * np.abs(ref).max() * nf


def _sparse_peer_case(name):
    """(bench.peers.sparse, a 10^2 cloth, its start state, dt, its NumpyCloth); skips when the peer
    ``name`` is not installed."""
    from bench.peers import sparse as peers
    reason = peers.available(name)
    if reason:
        pytest.skip(reason)
    c = cloth(10, E=1e3, rho=0.1, B=1e-3)
    x0, v0 = config.cloth_start_state(c)
    return peers, c, x0, v0, 1.0 / 60.0, NumpyCloth(c.model, c.springs, c.bending)


def test_pardiso_factorisation_alone_solves_the_peers_system():
    """bench/peers/sparse.FactorOnly (the library row) solves the system the PARDISO peer solves
    in its step: its solution is that step's displacement."""
    peers, c, x0, v0, dt, base = _sparse_peer_case("pardiso")
    f = peers.FactorOnly(base, x0, v0, dt)
    y = f.run()
    x, v = x0.copy(), v0.copy()
    peers.SparsePeer("pardiso", base).step(x, v, dt)
    dx = (x - x0)[c.model.free].reshape(-1)
    assert np.max(np.abs(dx)) > 1e-3
    assert np.max(np.abs(y - dx)) <= 1e-12 * np.max(np.abs(dx))
    A, b = base.implicit_system(x0, v0, dt, upper=True)
    assert np.linalg.norm(b - upper_product(A, y)) <= 1e-10 * np.linalg.norm(b)


@pytest.mark.parametrize("tol", [1e-5, 1e-10])
def test_pardiso_mixed_alone_reaches_the_tolerance_of_the_same_system(tol):
    """The library row of the engine's own technique (f32 factorisation, f64 refinement) solves the
    same f64 system to ``tol``: its true residual is at or below it, at 1e-10 only after refinement
    (an f32 solve alone is ~1e-6..1e-4 off), and it agrees with the f64 solve to cond x tol."""
    peers, c, x0, v0, dt, base = _sparse_peer_case("pardiso")
    exact = peers.FactorOnly(base, x0, v0, dt).run()
    f = peers.FactorOnly(base, x0, v0, dt, precision="mixed", tol=tol)
    y = f.run()
    A, b = base.implicit_system(x0, v0, dt, upper=True)
    residual = np.linalg.norm(b - upper_product(A, y)) / np.linalg.norm(b)
    assert residual <= tol and f.last["residual"] == pytest.approx(residual, rel=1e-6, abs=1e-15)
    assert f.last["iterations"] >= (2 if tol < 1e-7 else 1)
    assert np.linalg.norm(y - exact) <= 1e4 * tol * np.linalg.norm(exact)


@pytest.mark.parametrize("name", ["scipy-cg", "pyamg-cg", "pardiso", "pardiso-spsolve", "cholmod"])
def test_sparse_peers_solve_the_engines_system(name):
    """Each implicit contender (bench/peers/sparse.py) solves the engine's backward-Euler system:
    its matrix times random vectors equals engine.solvers.apply_system (relative 1e-12), and its
    step equals the engine's direct step to the tolerance it was given."""
    from engine.solvers import apply_system
    peers, c, x0, v0, dt, base = _sparse_peer_case(name)
    tol = 1e-10
    peer = peers.SparsePeer(name, base, tol=tol)
    A, _ = peer.system(x0, v0, dt)
    A = peer.full_matrix(A)
    free = np.repeat(c.model.free, 3)
    rng = np.random.default_rng(5)
    for _ in range(2):
        p = rng.standard_normal((c.model.n, 3)) * c.model.free[:, None]
        q = vec3_ndarray(c.model.n)
        apply_system(c.model, vec3_ndarray(c.model.n, x0), vec3_ndarray(c.model.n, p), q, 1.0 / dt ** 2)
        ref = q.to_numpy().reshape(-1)[free]
        assert np.max(np.abs(A @ p.reshape(-1)[free] - ref)) <= 1e-12 * np.abs(ref).max()
    x, v = x0.copy(), v0.copy()
    peer.step(x, v, dt)
    assert peer.last["residual"] <= tol
    st = c.model.make_state(x0, v0)
    Stepper(c.model, BackwardEuler(solver="cholesky", tol=1e-12, newton_iterations=1, line_search=False)).step(st, dt)
    moved = np.max(np.abs(st.numpy().x - x0))
    assert moved > 1e-3
    assert np.max(np.abs(x - st.numpy().x)) <= 1e-6 * moved


@pytest.mark.parametrize("solver", ["pcg", "cholesky"])
def test_scipy_and_engine_backward_euler_steps_agree(solver):
    c = cloth(10, E=1e3, rho=0.1, B=1e-3)
    x0, v0 = config.cloth_start_state(c)
    dt = 1.0 / 60.0
    tol = 1e-10
    st = c.model.make_state(x0, v0)
    be = BackwardEuler(solver=solver, tol=tol, newton_iterations=1, line_search=False, max_iter=100000)
    Stepper(c.model, be).step(st, dt)
    base = NumpyCloth(c.model, c.springs, c.bending)
    x, v = x0.copy(), v0.copy()
    base.backward_euler(x, v, dt, tol=tol)
    got = st.numpy()
    moved = np.max(np.abs(x - x0))
    assert moved > 1e-3  # the step does something
    assert np.max(np.abs(got.x - x)) <= 1e-7 * moved
    assert np.max(np.abs(got.v - v)) <= 1e-7 * np.max(np.abs(v))
    assert base.last_residual <= tol and base.last_iterations > 0


def test_scipy_step_reaches_the_benchmark_tolerance():
    c = config.cloth_scene(12, True)
    x0, v0 = config.cloth_start_state(c)
    base = NumpyCloth(c.model, c.springs, c.bending)
    x, v = x0.copy(), v0.copy()
    base.backward_euler(x, v, config.IMPLICIT_DT, tol=config.IMPLICIT_TOL[64])
    assert base.last_residual <= config.IMPLICIT_TOL[64]
    assert base.last_assembly_s > 0 and base.last_solve_s > 0


# -- implicit: the membrane's numpy model against the engine ----------------------------------------

def test_numpy_membrane_forces_and_matrix_equal_the_engines():
    """NumpyMembrane (the membrane rows' peers' model): its forces are the engine's (membrane +
    gravity, pins zero) and its scattered PSD blocks the engine's dense PSD Hessian over the free
    degrees of freedom, on two states (full and upper triangle)."""
    c = config.membrane_scene(10)
    base = NumpyMembrane(c.model, c.membrane)
    free = np.repeat(c.model.free, 3)
    for seed in (1, 2):
        x = _deformed(c, seed=seed, amp=0.02)
        ref = (c.membrane.forces(x) + c.model.mass[:, None] * c.model.gravity) * c.model.free[:, None]
        assert np.max(np.abs(base.forces(x) - ref)) <= 1e-12 * np.abs(ref).max()
        H = c.model.dense_hessian(vec3_ndarray(c.model.n, x), psd=True)[np.ix_(free, free)]
        assert np.max(np.abs(base.hessian_psd(x).toarray() - H)) <= 1e-12 * np.abs(H).max()
        U = base.system_matrix(x, 1.0, upper=True).toarray()
        assert np.max(np.abs(U - np.triu(H + np.eye(len(H))))) <= 1e-12 * np.abs(H).max()


@pytest.mark.parametrize("name", ["scipy-cg", "pardiso"])
def test_membrane_peers_step_as_the_engine(name):
    """A membrane row's peer steps the membrane as the engine's backward Euler does (Eigen LL^T at
    tol 1e-12): the same x+ to 1e-7 of the displacement."""
    from bench.peers import sparse as peers
    if peers.available(name):
        pytest.skip(peers.available(name))
    c = config.membrane_scene(10)
    x0, v0 = config.cloth_start_state(c)
    dt = 1.0 / 60.0
    peer = peers.SparsePeer(name, NumpyMembrane(c.model, c.membrane), tol=1e-11)
    x, v = x0.copy(), v0.copy()
    peer.step(x, v, dt)
    st = c.model.make_state(x0, v0)
    Stepper(c.model, BackwardEuler(solver="cholesky", tol=1e-12, newton_iterations=1, line_search=False)).step(st, dt)
    moved = np.max(np.abs(st.numpy().x - x0))
    assert moved > 1e-3
    assert np.max(np.abs(x - st.numpy().x)) <= 1e-7 * moved
    assert peer.last["residual"] <= 1e-11


# -- rod ---------------------------------------------------------------------------------------

@pytest.mark.parametrize("method", ["symplectic-euler", "backward-euler"])
def test_numpy_rod_steps_equal_engine_rod(method):
    rod, u0 = config.rod_scene(201)
    dt = CFL_SAFETY * rod.stable_dt() if method == "symplectic-euler" else 10 * float(rod.h[0])
    st = rod.new_state(u0)
    rod.run(st, dt, 30, method)
    base = NumpyRod(rod)
    x, v = rod.p + u0, np.zeros(rod.n)
    (base.symplectic_euler if method == "symplectic-euler" else base.backward_euler)(x, v, dt, 30)
    assert np.max(np.abs(st.positions() - x)) <= 1e-10 * np.max(np.abs(u0))
    assert np.max(np.abs(st.velocity() - v)) <= 1e-9 * max(np.max(np.abs(v)), 1e-30)


@pytest.mark.parametrize("solver", ["pcg", "cholesky"])
def test_rod_model_backward_euler_equals_rod_thomas(solver):
    rod, u0 = config.rod_scene(201)
    dt = 10 * float(rod.h[0])
    st = rod.new_state(u0)
    rod.run(st, dt, 3, "backward-euler")
    model = rod.model
    x0 = np.asarray(model.X, dtype=np.float64).copy()
    x0[:, 0] += u0
    ms = model.make_state(x0)
    Stepper(model, BackwardEuler(solver=solver, tol=1e-12, newton_iterations=1, line_search=False,
                                 max_iter=100000)).step(ms, dt, 3)
    got = ms.numpy()
    assert np.max(np.abs(got.x[:, 0] - st.positions())) <= 1e-8 * np.max(np.abs(u0))
    assert np.max(np.abs(got.x[:, 1:])) == 0.0


# -- headline helpers, traffic model -------------------------------------------------------------

def test_accuracy_matched_dt_loses_the_stated_energy():
    w = headline.pendulum_omega(1.0)
    assert math.isclose(w, math.sqrt(1.5 * G), rel_tol=1e-12)
    dt = headline.accuracy_matched_dt(w, 0.10)
    assert math.isclose(headline.energy_kept_per_second(w, dt), 0.90, rel_tol=1e-9)
    assert headline.energy_kept_per_second(w, 1.05 * dt) < 0.90 < headline.energy_kept_per_second(w, 0.95 * dt)
    # small-dt form: -ln(0.9) ~ w^2 dt
    assert math.isclose(dt, -math.log(0.9) / w ** 2, rel_tol=0.01)


def test_backward_euler_damps_a_mode_as_the_accuracy_model_says():
    """The model behind the accuracy-matched dt, checked on the engine: one free mass on a spring
    (w = sqrt(k/m)) keeps (1 + w^2 dt^2)^-1 of its energy per backward-Euler step."""
    from engine.model import Model
    X = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    model = Model.from_springs(X, np.array([[0, 1]]), k=4.0, mass=[1.0, 1.0], pinned=[0])
    w = math.sqrt(4.0 / 1.0)  # c = k L, axial stiffness c/L^2 = 4
    dt = 0.05
    st = model.make_state(X + np.array([[0, 0, 0], [1e-6, 0, 0]]))
    e0 = 0.5 * 4.0 * 1e-12
    be = BackwardEuler(solver="cholesky", tol=1e-12, newton_iterations=1, line_search=False)
    n = 20
    Stepper(model, be).step(st, dt, n)
    s = st.numpy()
    e = 0.5 * 1.0 * s.v[1, 0] ** 2 + 0.5 * 4.0 * (s.x[1, 0] - 1.0) ** 2
    assert math.isclose(e / e0, (1 + (w * dt) ** 2) ** (-n), rel_tol=1e-4)


def test_crossover_interpolates_the_sign_change():
    E = [1.0, 10.0, 100.0]
    E_c, note = headline.crossover(E, [1.0, 10.0, 100.0], [10.0, 10.0 * 10 ** 0.5, 10.0])
    assert note.startswith("explicit") and 10.0 < E_c < 100.0
    assert headline.crossover(E, [1, 1, 1], [2, 2, 2])[0] is None


def test_traffic_model_scales_with_the_mesh():
    c = config.cloth_scene(12, True)
    n, m, h = c.model.n, c.springs.m, c.bending.n_hinges
    for k in traffic.KERNELS:
        b1, b2 = traffic.kernel_bytes(k, n, m, h), traffic.kernel_bytes(k, 4 * n, 4 * m, 4 * h)
        assert b1 > 0 and 3.5 < b2 / b1 < 4.5
        assert traffic.kernel_bytes(k, n, m, h, fb=4) < b1
    assert traffic.kernel_bytes("zero", n) == 24 * n
    assert traffic.implicit_step_bytes(n, m, h, 10) > 10 * traffic.kernel_bytes("cg_iteration", n, m, h)
