"""The membrane energies (engine/energies/membrane.py): forces and Hessians against finite
differences for both models over random shapes, the PSD variant, the products and diagonals the
solvers use against the dense Hessian, the patch test, invariances, and bad input."""
import numpy as np
import pytest
import taichi as ti
from hypothesis import given, settings, strategies as st

from engine import mesh as M
from engine.energies.membrane import MembraneEnergy, MembraneError, lame
from engine.model import Model

MODELS = {"stvk": dict(Y=3.0, nu=0.35), "baraff-witkin": dict(k_stretch=3.0, k_shear=0.7)}


def patch(seed=0):
    return M.embed_3d(M.jitter(M.right_triangle_grid(3, 3, 0.4, 0.3, "alternating"), 0.2, seed=seed))


def fd_forces(energy, x, eps=1e-7):
    g = np.zeros_like(x)
    for i in range(len(x)):
        for j in range(3):
            xp, xm = x.copy(), x.copy()
            xp[i, j] += eps
            xm[i, j] -= eps
            g[i, j] = (energy.energy(xp) - energy.energy(xm)) / (2 * eps)
    return -g


def fd_hessian(energy, x, eps=1e-7):
    n = x.size
    H = np.zeros((n, n))
    for c in range(n):
        xp, xm = x.reshape(-1).copy(), x.reshape(-1).copy()
        xp[c] += eps
        xm[c] -= eps
        H[:, c] = -(energy.forces(xp.reshape(-1, 3)) - energy.forces(xm.reshape(-1, 3))).reshape(-1) / (2 * eps)
    return H


@settings(max_examples=12, deadline=None)
@given(seed=st.integers(0, 10_000), scale=st.floats(0.01, 0.3), model=st.sampled_from(sorted(MODELS)))
def test_forces_and_hessians_are_the_energys_derivatives(seed, scale, model):
    m3 = patch(seed % 5)
    e = MembraneEnergy.from_mesh(m3, model, **MODELS[model])
    x = m3.vertices + scale * np.random.default_rng(seed).standard_normal(m3.vertices.shape)
    f_fd = fd_forces(e, x)
    assert np.abs(e.forces(x) - f_fd).max() <= 1e-6 * np.abs(f_fd).max()
    H, H_fd = e.dense_hessian(x, psd=False), fd_hessian(e, x)
    assert np.abs(H - H_fd).max() <= 1e-6 * np.abs(H_fd).max()
    assert np.abs(H - H.T).max() <= 1e-12 * np.abs(H).max()
    Hp = e.dense_hessian(x, psd=True)
    assert np.linalg.eigvalsh(Hp).min() >= -1e-12 * np.abs(Hp).max()


@pytest.mark.parametrize("model", sorted(MODELS))
def test_the_products_and_diagonals_the_solvers_use_match_the_dense_hessian(model):
    m3 = patch(2)
    e = MembraneEnergy.from_mesh(m3, model, **MODELS[model])
    rng = np.random.default_rng(3)
    x = m3.vertices + 0.1 * rng.standard_normal(m3.vertices.shape)
    dx = rng.standard_normal(x.shape)
    for psd in (False, True):
        H = e.dense_hessian(x, psd)
        out = np.zeros_like(x)
        e.add_hessian_product(x, dx, out, psd)
        assert np.abs(out.reshape(-1) - H @ dx.reshape(-1)).max() <= 1e-12 * np.abs(H).max() * np.abs(dx).max() * 10
        blocks = e.hessian_blocks(x, psd)
        out2 = np.zeros_like(x)
        e.add_block_product(blocks, dx, out2)
        assert np.array_equal(out, out2)
        diag = ti.ndarray(dtype=ti.math.mat3, shape=len(x))
        diag.fill(0.0)
        e.add_hessian_diagonal(x, diag, psd)
        D = diag.to_numpy()
        for v in range(len(x)):
            assert np.allclose(D[v], H[3 * v:3 * v + 3, 3 * v:3 * v + 3], rtol=0, atol=1e-12 * np.abs(H).max())


_vec3s = ti.types.ndarray(dtype=ti.math.vec3, ndim=1)


@ti.kernel
def _deformation_products(energy: ti.template(), fblocks: ti.types.ndarray(dtype=ti.math.mat3, ndim=2),
                          dinv: ti.types.ndarray(dtype=ti.math.mat2, ndim=1),
                          tris: ti.types.ndarray(dtype=ti.i32, ndim=2), z: _vec3s, p: _vec3s, beta: float,
                          yt: ti.types.ndarray(dtype=ti.math.vec3, ndim=2)):
    for t in range(tris.shape[0]):
        ys = energy.deformation_corners(fblocks, dinv, tris, z, p, beta, t)
        for a in ti.static(range(3)):
            yt[t, a] = ys[a]


@pytest.mark.parametrize("model", sorted(MODELS))
@pytest.mark.parametrize("strain", [0.8, 1.0, 1.3])
def test_the_deformation_form_product_is_the_hessians(model, strain):
    """The PCG's per-iteration membrane product from 27 numbers per triangle (the Hessian by F's columns,
    MembraneEnergy.deformation_blocks) equals the dense Hessian's product, exact and PSD, on a crumpled
    patch squeezed (0.8: compressed triangles, where the PSD variants clip), as is and stretched, with the
    direction formed as z + beta p as the CG forms it."""
    from engine.fields import vec3_ndarray
    m3 = patch(4)
    e = MembraneEnergy.from_mesh(m3, model, **MODELS[model])
    rng = np.random.default_rng(5)
    x = strain * m3.vertices + 0.08 * rng.standard_normal(m3.vertices.shape)
    z, p = rng.standard_normal(x.shape), rng.standard_normal(x.shape)
    beta = 0.37
    d = (z + beta * p).reshape(-1)
    yt = ti.ndarray(dtype=ti.math.vec3, shape=(e.n_elements, 3))
    clipped = 0
    for psd in (False, True):
        H = e.dense_hessian(x, psd)
        _deformation_products(e, e.deformation_blocks(x, psd), e.Dinv, e.tris, vec3_ndarray(len(x), z),
                              vec3_ndarray(len(x), p), beta, yt)
        out = np.zeros_like(x)
        np.add.at(out, e.triangles_np.reshape(-1), yt.to_numpy().reshape(-1, 3))
        assert np.abs(out.reshape(-1) - H @ d).max() <= 1e-12 * np.abs(H).max() * np.abs(d).max() * 10
        clipped += int(not np.allclose(H, e.dense_hessian(x, not psd)))
    assert clipped == 2    # exact and PSD differ here: both variants were checked


@pytest.mark.parametrize("model", sorted(MODELS))
def test_an_affine_deformation_stores_area_times_the_density_and_rest_is_zero(model):
    m3 = patch(4)
    p = MODELS[model]
    e = MembraneEnergy.from_mesh(m3, model, **p)
    assert e.energy(m3.vertices) == pytest.approx(0.0, abs=1e-28)
    F = np.array([[1.1, 0.2], [-0.1, 0.9], [0.3, 0.05]])
    W = e.energy(m3.vertices[:, :2] @ F.T + np.array([0.3, -1.0, 2.0]))
    if model == "stvk":
        mu, lam = lame(p["Y"], p["nu"])
        E = 0.5 * (F.T @ F - np.eye(2))
        psi = mu * np.sum(E * E) + 0.5 * lam * np.trace(E) ** 2
    else:
        lu, lv, s = np.linalg.norm(F[:, 0]), np.linalg.norm(F[:, 1]), F[:, 0] @ F[:, 1]
        psi = 0.5 * p["k_stretch"] * ((lu - 1) ** 2 + (lv - 1) ** 2) + 0.5 * p["k_shear"] * s * s
    assert W == pytest.approx(m3.total_measure * psi, rel=1e-12)


def test_the_rest_frame_follows_the_material_direction():
    """Baraff-Witkin's warp u follows ``direction``: stretching along x costs k_stretch there and
    along the diagonal it costs stretch and shear."""
    m3 = patch(1)
    X = m3.vertices
    along_x = X * np.array([1.01, 1.0, 1.0])
    e_x = MembraneEnergy.from_mesh(m3, "baraff-witkin", k_stretch=2.0, k_shear=0.0)
    assert e_x.energy(along_x) == pytest.approx(m3.total_measure * 0.5 * 2.0 * 0.01 ** 2, rel=1e-9)
    e_d = MembraneEnergy.from_mesh(m3, "baraff-witkin", k_stretch=2.0, k_shear=0.0, direction=(1.0, 1.0, 0.0))
    assert e_d.energy(along_x) < 0.6 * e_x.energy(along_x)


def test_backward_euler_steps_a_membrane_model_with_every_solver_alike():
    from engine.integrators.implicit import BackwardEuler
    from engine.integrators.stepper import Stepper
    m3 = M.embed_3d(M.right_triangle_grid(6, 6, 1.0, 1.0, "alternating"), plane="xz")
    top = np.flatnonzero(m3.vertices[:, 2] >= 1.0 - 1e-9)
    finals = []
    for solver in ("cholesky", "pcg"):
        model = Model(m3.vertices, mass=M.lumped_masses(m3, 0.1), pinned=top, gravity=(0.0, 0.0, -9.81))
        model.add_energy(MembraneEnergy.from_mesh(m3, "baraff-witkin", k_stretch=100.0, k_shear=10.0))
        state = model.make_state()
        Stepper(model, BackwardEuler(solver=solver, tol=1e-12)).step(state, 1 / 60, 10)
        finals.append(state.numpy().x)
    assert np.abs(finals[0] - finals[1]).max() <= 1e-9
    assert finals[0][:, 2].min() < -1e-4 + m3.vertices[:, 2].min()   # it fell


@pytest.mark.parametrize("kwargs,needle", [
    (dict(model="shell"), "model must be one of stvk, baraff-witkin"),
    (dict(model="stvk", Y=1.0, nu=0.5), "nu must be in [0, 0.5)"),
    (dict(model="stvk", Y=-1.0, nu=0.3), "stvk needs Y > 0"),
    (dict(model="baraff-witkin", k_stretch=1.0, k_shear=-1.0), "baraff-witkin needs k_stretch >= 0 and k_shear >= 0"),
])
def test_bad_parameters_are_one_clear_error(kwargs, needle):
    m3 = patch(0)
    with pytest.raises(MembraneError) as info:
        MembraneEnergy(m3.vertices, m3.triangles, **kwargs)
    assert needle in str(info.value) and "\n" not in str(info.value)


def test_a_degenerate_rest_triangle_is_named():
    X = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0]], float)
    with pytest.raises(MembraneError, match=r"triangle 0 \[0, 1, 2\] has zero rest area"):
        MembraneEnergy(X, [[0, 1, 2], [0, 1, 3]], "stvk", Y=1.0, nu=0.3)


# -------------------------------------------------------------------- Baraff-Witkin damping (M3)

def _conditions(e, x):
    """(m, 3) [C_u, C_v, C_s] per triangle, written out in numpy from the rest frames."""
    T = e.triangles_np
    d1, d2 = x[T[:, 1]] - x[T[:, 0]], x[T[:, 2]] - x[T[:, 0]]
    Di = e.Dinv_np
    wu = d1 * Di[:, 0, 0, None] + d2 * Di[:, 1, 0, None]
    wv = d1 * Di[:, 0, 1, None] + d2 * Di[:, 1, 1, None]
    r = np.sqrt(e.area_np)
    return np.stack([r * (np.linalg.norm(wu, axis=1) - 1), r * (np.linalg.norm(wv, axis=1) - 1),
                     r * np.einsum("ij,ij->i", wu, wv)], axis=1)


def test_damping_is_minus_d_v_with_d_the_conditions_rates_squared():
    """v^T D v = sum k_d (dC/dt)^2, dC/dt by central differences of the conditions along v; the
    force is -D v; D is symmetric PSD and its blocks, products and dense form agree."""
    m3 = patch(1)
    kd = (0.7, 0.2)
    e = MembraneEnergy.from_mesh(m3, "baraff-witkin", k_stretch=3.0, k_shear=1.0, damping_stretch=kd[0],
                                 damping_shear=kd[1])
    rng = np.random.default_rng(5)
    x = m3.vertices + 0.1 * rng.standard_normal(m3.vertices.shape)
    v = rng.standard_normal(x.shape)
    eps = 1e-6
    rates = (_conditions(e, x + eps * v) - _conditions(e, x - eps * v)) / (2 * eps)
    dissipation = kd[0] * np.sum(rates[:, :2] ** 2) + kd[1] * np.sum(rates[:, 2] ** 2)
    D = e.dense_damping(x)
    assert v.reshape(-1) @ D @ v.reshape(-1) == pytest.approx(dissipation, rel=1e-8)
    f = np.zeros_like(x)
    e.add_damping_forces(x, v, f)
    assert np.abs(f.reshape(-1) + D @ v.reshape(-1)).max() <= 1e-13 * np.abs(D).max() * np.abs(v).max() * 10
    out = np.zeros_like(x)
    e.add_damping_product(x, v, out)
    assert np.array_equal(out, -f)
    assert np.abs(D - D.T).max() == 0.0 and np.linalg.eigvalsh(D).min() >= -1e-14 * np.abs(D).max()


def _damped_cloth(solver_seed=0):
    m3 = M.embed_3d(M.right_triangle_grid(5, 5, 1.0, 1.0, "alternating"), plane="xz")
    top = np.flatnonzero(m3.vertices[:, 2] >= 1.0 - 1e-9)
    model = Model(m3.vertices, mass=M.lumped_masses(m3, 0.1), pinned=top, gravity=(0.0, 0.0, -9.81))
    energy = MembraneEnergy.from_mesh(m3, "baraff-witkin", k_stretch=50.0, k_shear=5.0, damping_stretch=2.0,
                                      damping_shear=0.5)
    model.add_energy(energy)
    v0 = 0.3 * np.random.default_rng(solver_seed).standard_normal(m3.vertices.shape) * model.free[:, None]
    return model, energy, v0


@pytest.mark.parametrize("solver", ["cholesky", "pcg"])
def test_a_damped_backward_euler_step_solves_its_equations(solver):
    """M (v+ - v_n) = dt (f(x+) + M g - D(x_n) v+), x+ = x_n + dt v+, to the Newton tolerance."""
    from engine.integrators.implicit import BackwardEuler
    from engine.integrators.stepper import Stepper
    model, energy, v0 = _damped_cloth()
    state = model.make_state(model.X, v0)
    dt = 0.05
    Stepper(model, BackwardEuler(solver=solver, tol=1e-12, newton_iterations=30, newton_tol=1e-12)).step(state, dt, 1)
    x1, v1 = state.numpy().x, state.numpy().v
    f = np.zeros_like(x1)
    energy.add_forces(x1, f)
    d = np.zeros_like(x1)
    energy.add_damping_forces(model.X, v1, d)
    r = model.mass[:, None] * (v1 - v0) - dt * (f + model.mass[:, None] * np.array([0.0, 0.0, -9.81]) + d)
    r[~model.free] = 0.0
    assert np.abs(r).max() <= 1e-9 * dt * 9.81 * model.mass.max()
    assert np.abs(x1 - (model.X + dt * v1))[model.free].max() <= 1e-14


def test_damping_drains_energy_at_the_rate_v_d_v_under_an_explicit_step():
    from engine.integrators.stepper import Stepper
    from engine import diagnostics
    model, energy, v0 = _damped_cloth(1)
    state = model.make_state(model.X, v0)
    E0 = diagnostics.total_energy(model, state)
    rate = v0.reshape(-1) @ energy.dense_damping(model.X) @ v0.reshape(-1)
    dt = 1e-7
    Stepper(model, "symplectic-euler").step(state, dt, 1)
    assert (diagnostics.total_energy(model, state) - E0) / dt == pytest.approx(-rate, rel=1e-3)


def test_damping_is_refused_where_it_is_not_defined():
    m3 = patch(0)
    with pytest.raises(MembraneError, match="use model='baraff-witkin'"):
        MembraneEnergy.from_mesh(m3, "stvk", Y=1.0, nu=0.3, damping_stretch=1.0)
    with pytest.raises(MembraneError, match="damping_shear must be finite and >= 0"):
        MembraneEnergy.from_mesh(m3, "baraff-witkin", k_stretch=1.0, k_shear=1.0, damping_shear=-1.0)
