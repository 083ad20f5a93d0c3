"""Spring energy, its derivatives, the Model and the diagnostics.

Every derivative is checked by central finite differences in f64 against the energy the code
evaluates (energy is the single source of truth), plus the invariances of a spring network:
zero force at rest, rigid-motion invariance, zero net force and torque.
"""
import numpy as np
import pytest
import scipy.linalg as sla

from engine import diagnostics
from engine.energies.springs import SpringEnergy, dense_hessian_from_blocks
from engine.stability import gershgorin_lambda_max, lambda_max_power, stable_dt_estimate
from engine.errors import ModelError
from engine.fields import vec3_ndarray
from engine.model import Model, State
import taichi as ti


# ------------------------------------------------------------------------------------------
# helpers
# ------------------------------------------------------------------------------------------

def random_network(seed, n=9, p=0.45):
    """Random 3D points and a random set of edges (every vertex has at least one edge)."""
    rng = np.random.default_rng(seed)
    X = rng.uniform(-1, 1, (n, 3))
    pairs = [(i, j) for i in range(n) for j in range(i + 1, n) if rng.random() < p]
    pairs += [(i, (i + 1) % n) for i in range(n)]
    edges = np.unique(np.sort(np.array(pairs), axis=1), axis=0)
    k = rng.uniform(0.5, 3.0, len(edges))
    mass = rng.uniform(0.5, 2.0, n)
    return X, edges, k, mass


def grid_network(N, h=0.1, diagonals=2):
    i, j = np.meshgrid(np.arange(N), np.arange(N), indexing="ij")
    X = np.stack([i.ravel() * h, j.ravel() * h, np.zeros(N * N)], 1)
    idx = i * N + j
    E = [np.stack([idx[:-1, :].ravel(), idx[1:, :].ravel()], 1), np.stack([idx[:, :-1].ravel(), idx[:, 1:].ravel()], 1)]
    if diagonals >= 1:
        E.append(np.stack([idx[:-1, :-1].ravel(), idx[1:, 1:].ravel()], 1))
    if diagonals >= 2:
        E.append(np.stack([idx[1:, :-1].ravel(), idx[:-1, 1:].ravel()], 1))
    return X, np.concatenate(E)


def nd(a):
    return vec3_ndarray(len(a), a)


def energy_np(x, edges, L, c):
    l = np.linalg.norm(x[edges[:, 0]] - x[edges[:, 1]], axis=1)
    return float(np.sum(0.5 * c * (l / L - 1.0) ** 2))


def forces_of(energy, x):
    f = vec3_ndarray(len(x))
    energy.add_forces(nd(x), f)
    return f.to_numpy()


def random_rotation(rng):
    Q, R = np.linalg.qr(rng.standard_normal((3, 3)))
    Q = Q @ np.diag(np.sign(np.diag(R)))
    if np.linalg.det(Q) < 0:
        Q[:, 0] *= -1
    return Q


def deformed(X, rng, scale=0.25):
    return X + scale * rng.standard_normal(X.shape)


# ------------------------------------------------------------------------------------------
# energy and its derivatives
# ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("seed", [0, 1, 2])
def test_energy_matches_notes_formula(seed):
    X, edges, k, _ = random_network(seed)
    sp = SpringEnergy.from_rest(X, edges, k=k)
    x = deformed(X, np.random.default_rng(seed + 10))
    L = np.linalg.norm(X[edges[:, 0]] - X[edges[:, 1]], axis=1)
    l = np.linalg.norm(x[edges[:, 0]] - x[edges[:, 1]], axis=1)
    notes = np.sum(0.5 * k * (l / L - 1) ** 2 * L)  # W = 1/2 k (l/L - 1)^2 L
    assert sp.energy(nd(x)) == pytest.approx(notes, rel=1e-13)
    assert sp.edge_energies(nd(x)).sum() == pytest.approx(notes, rel=1e-13)


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_gradient_central_differences(seed):
    X, edges, k, _ = random_network(seed)
    sp = SpringEnergy.from_rest(X, edges, k=k)
    x = deformed(X, np.random.default_rng(seed + 20))
    f = forces_of(sp, x)
    h = 1e-6
    g_fd = np.zeros(x.size)
    for a in range(x.size):
        xp, xm = x.copy(), x.copy()
        xp.reshape(-1)[a] += h
        xm.reshape(-1)[a] -= h
        g_fd[a] = (sp.energy(nd(xp)) - sp.energy(nd(xm))) / (2 * h)
    rel = np.linalg.norm(g_fd + f.reshape(-1)) / np.linalg.norm(g_fd)
    assert rel < 1e-6, rel


@pytest.mark.parametrize("seed", [0, 1])
def test_directional_derivative(seed):
    """D_q W(x) = grad W . q = -f . q for random directions q."""
    X, edges, k, _ = random_network(seed)
    sp = SpringEnergy.from_rest(X, edges, k=k)
    rng = np.random.default_rng(seed + 30)
    x = deformed(X, rng)
    f = forces_of(sp, x)
    h = 1e-6
    for _ in range(5):
        q = rng.standard_normal(x.shape)
        d_fd = (sp.energy(nd(x + h * q)) - sp.energy(nd(x - h * q))) / (2 * h)
        assert d_fd == pytest.approx(-np.sum(f * q), rel=1e-7, abs=1e-9)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_exact_hessian_central_differences(seed):
    X, edges, k, _ = random_network(seed)
    sp = SpringEnergy.from_rest(X, edges, k=k)
    x = deformed(X, np.random.default_rng(seed + 40))
    l = np.linalg.norm(x[edges[:, 0]] - x[edges[:, 1]], axis=1)
    assert (l < sp.L_np).any() and (l > sp.L_np).any()  # both compressed and stretched springs
    H = sp.dense_hessian(nd(x), psd=False)
    h = 1e-6
    H_fd = np.zeros_like(H)
    for a in range(x.size):
        xp, xm = x.copy(), x.copy()
        xp.reshape(-1)[a] += h
        xm.reshape(-1)[a] -= h
        H_fd[:, a] = -(forces_of(sp, xp) - forces_of(sp, xm)).reshape(-1) / (2 * h)
    rel = np.linalg.norm(H - H_fd) / np.linalg.norm(H_fd)
    assert rel < 1e-5, rel
    assert np.abs(H - H.T).max() < 1e-12 * np.abs(H).max()


def test_psd_hessian_equals_exact_when_stretched_and_is_psd_when_compressed():
    rng = np.random.default_rng(5)
    X, edges, k, _ = random_network(5)
    sp = SpringEnergy.from_rest(X, edges, k=k)
    # stretched: a uniform 20% expansion plus a small perturbation keeps every l > L
    x_s = 1.2 * X + 0.01 * rng.standard_normal(X.shape)
    l = np.linalg.norm(x_s[edges[:, 0]] - x_s[edges[:, 1]], axis=1)
    assert (l > sp.L_np).all()
    H_exact, H_psd = sp.dense_hessian(nd(x_s), psd=False), sp.dense_hessian(nd(x_s), psd=True)
    assert np.abs(H_psd - H_exact).max() <= 1e-14 * np.abs(H_exact).max()

    # compressed: the exact Hessian is indefinite, the projected one is PSD
    x_c = 0.7 * X + 0.01 * rng.standard_normal(X.shape)
    l = np.linalg.norm(x_c[edges[:, 0]] - x_c[edges[:, 1]], axis=1)
    assert (l < sp.L_np).all()
    ev_exact = np.linalg.eigvalsh(sp.dense_hessian(nd(x_c), psd=False))
    ev_psd = np.linalg.eigvalsh(sp.dense_hessian(nd(x_c), psd=True))
    scale = np.abs(ev_psd).max()
    assert ev_exact.min() < -0.05 * scale  # a measured, clearly negative eigenvalue
    assert ev_psd.min() >= -1e-12 * scale
    blocks = sp.hessian_blocks_numpy(nd(x_c), psd=True)
    assert np.linalg.eigvalsh(blocks).min() >= -1e-12 * np.abs(blocks).max()
    # longitudinal stiffness c/L^2 is kept: d^T K d = c/L^2 for every block
    d = x_c[edges[:, 0]] - x_c[edges[:, 1]]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    np.testing.assert_allclose(np.einsum("ea,eab,eb->e", d, blocks, d), sp.c_np / sp.L_np ** 2, rtol=1e-12)


@pytest.mark.parametrize("psd", [False, True])
def test_hessian_vector_products_match_assembled_hessian(psd):
    rng = np.random.default_rng(7)
    X, edges, k, _ = random_network(7)
    sp = SpringEnergy.from_rest(X, edges, k=k)
    x = deformed(X, rng)
    H = sp.dense_hessian(nd(x), psd=psd)
    dx = rng.standard_normal(X.shape)
    ref = H @ dx.reshape(-1)
    base = rng.standard_normal(X.shape)  # products accumulate: out += H dx
    out = nd(base)
    sp.add_hessian_product(nd(x), nd(dx), out, psd=psd)
    assert np.abs(out.to_numpy().reshape(-1) - base.reshape(-1) - ref).max() < 1e-12 * np.abs(ref).max()
    out2 = nd(base)
    sp.add_block_product(sp.hessian_blocks(nd(x), psd=psd), nd(dx), out2)
    assert np.abs(out2.to_numpy().reshape(-1) - base.reshape(-1) - ref).max() < 1e-12 * np.abs(ref).max()
    diag = ti.ndarray(dtype=ti.math.mat3, shape=len(X))
    diag.from_numpy(np.zeros((len(X), 3, 3)))
    sp.add_hessian_diagonal(nd(x), diag, psd=psd)
    ref_diag = np.array([H[3 * i:3 * i + 3, 3 * i:3 * i + 3] for i in range(len(X))])
    assert np.abs(diag.to_numpy() - ref_diag).max() < 1e-12 * np.abs(ref_diag).max()
    # the Energy base class's generic assembly (column by column) agrees with the block assembly
    from engine.energies.base import Energy
    H_generic = Energy.dense_hessian(sp, nd(x), psd)
    assert np.abs(H_generic - H).max() < 1e-12 * np.abs(H).max()


def test_stencil_blocks_and_force_args():
    """The stencil view (k = 2, elements = edges, block(a, b) = +-K from one stored K per edge)
    gives the same dense Hessian, and force_args() drives spring_gather like add_forces (bitwise)."""
    from engine.energies.springs import spring_gather, spring_pair_block
    from engine.fields import int_array, scalar_array, vec3_array

    @ti.kernel
    def pair_blocks(blocks: ti.types.ndarray(dtype=ti.math.mat3, ndim=1),
                    out: ti.types.ndarray(dtype=ti.math.mat3, ndim=2)):
        for e in range(blocks.shape[0]):
            for a in ti.static(range(2)):
                for b in ti.static(range(2)):
                    out[e, 2 * a + b] = spring_pair_block(blocks, e, a, b)

    @ti.kernel
    def gathered(x: vec3_array, offsets: int_array, inc_other: int_array, inc_inv_L: scalar_array,
                 inc_c_over_L: scalar_array, f: vec3_array):
        for i in range(x.shape[0]):
            f[i] += spring_gather(x, i, offsets, inc_other, inc_inv_L, inc_c_over_L)

    rng = np.random.default_rng(11)
    X, edges, k, _ = random_network(11)
    sp = SpringEnergy.from_rest(X, edges, k=k)
    assert sp.stencil_size == 2 and sp.n_elements == len(edges) and {"blocks", "pair-gather"} <= sp.products
    assert np.array_equal(sp.elements.to_numpy(), edges)
    x = nd(deformed(X, rng))
    out = ti.ndarray(dtype=ti.math.mat3, shape=(len(edges), 4))
    pair_blocks(sp.hessian_blocks(x, psd=False), out)
    B = out.to_numpy()
    H = np.zeros((3 * len(X), 3 * len(X)))
    for e, (i, j) in enumerate(edges):
        for a, va in enumerate((i, j)):
            for b, vb in enumerate((i, j)):
                H[3 * va:3 * va + 3, 3 * vb:3 * vb + 3] += B[e, 2 * a + b]
    assert np.array_equal(H, sp.dense_hessian(x, psd=False))
    f1, f2 = vec3_ndarray(len(X)), vec3_ndarray(len(X))
    sp.add_forces(x, f1)
    gathered(x, *sp.force_args(), f2)
    assert np.array_equal(f1.to_numpy(), f2.to_numpy()) and np.abs(f1.to_numpy()).max() > 0


def test_hessian_at_rest_is_longitudinal_only():
    X, edges, k, _ = random_network(3)
    sp = SpringEnergy.from_rest(X, edges, k=k)
    blocks = sp.hessian_blocks_numpy(nd(X), psd=False)
    d = X[edges[:, 0]] - X[edges[:, 1]]
    L = np.linalg.norm(d, axis=1)
    d /= L[:, None]
    ref = (sp.c_np / L ** 2)[:, None, None] * np.einsum("ea,eb->eab", d, d)  # (c/L^2) d d^T
    assert np.abs(blocks - ref).max() < 1e-13 * np.abs(ref).max()
    H = dense_hessian_from_blocks(len(X), edges, blocks)
    assert np.abs(H.sum(axis=1)).max() < 1e-12 * np.abs(H).max()  # translations are null vectors


# ------------------------------------------------------------------------------------------
# invariances
# ------------------------------------------------------------------------------------------

def test_zero_force_at_rest():
    X, edges, k, _ = random_network(4)
    sp = SpringEnergy.from_rest(X, edges, k=k)
    f = forces_of(sp, X)
    assert sp.energy(nd(X)) < 1e-28
    assert np.abs(f).max() < 1e-13 * (sp.c_np / sp.L_np).max()


def test_single_spring_force_along_the_spring_with_notes_magnitude():
    X = np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0]])
    k = 3.0
    sp = SpringEnergy.from_rest(X, np.array([[0, 1]]), k=k)
    rng = np.random.default_rng(8)
    for _ in range(5):
        x = rng.standard_normal((2, 3))
        f = forces_of(sp, x)
        d = x[0] - x[1]
        l = np.linalg.norm(d)
        # notes: f_ij = -k (|x_i - x_j|/L - 1) (x_i - x_j)/|x_i - x_j|
        np.testing.assert_allclose(f[0], -k * (l / 0.5 - 1) * d / l, rtol=1e-12, atol=1e-14)
        assert np.linalg.norm(np.cross(f[0], d)) < 1e-12 * np.linalg.norm(f[0]) * l  # parallel
        assert np.sign(f[0] @ d) == -np.sign(l - 0.5)  # pulls when stretched, pushes when compressed
        np.testing.assert_array_equal(f[1], -f[0])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_rigid_motion_invariance(seed):
    X, edges, k, _ = random_network(seed)
    sp = SpringEnergy.from_rest(X, edges, k=k)
    rng = np.random.default_rng(seed + 50)
    x = deformed(X, rng)
    W = sp.energy(nd(x))
    f = forces_of(sp, x)
    for _ in range(3):
        R, t = random_rotation(rng), rng.standard_normal(3)
        y = x @ R.T + t
        assert sp.energy(nd(y)) == pytest.approx(W, rel=1e-12)
        np.testing.assert_allclose(forces_of(sp, y), f @ R.T, atol=1e-12 * np.abs(f).max())


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_zero_net_force_and_torque(seed):
    X, edges, k, _ = random_network(seed)
    sp = SpringEnergy.from_rest(X, edges, k=k)
    x = deformed(X, np.random.default_rng(seed + 60)) + 3.0  # away from the origin
    f = forces_of(sp, x)
    scale = np.abs(f).max()
    assert np.abs(f.sum(axis=0)).max() < 1e-14 * len(x) * scale
    assert np.abs(np.cross(x, f).sum(axis=0)).max() < 1e-13 * len(x) * scale * np.abs(x).max()


def test_forces_are_deterministic():
    X, E = grid_network(20)
    sp = SpringEnergy.from_rest(X, E, k=1.0)
    x = deformed(X, np.random.default_rng(9), 0.01)
    f1, f2 = forces_of(sp, x), forces_of(sp, x)
    np.testing.assert_array_equal(f1, f2)


def test_area_springs_use_c_directly_and_set_coefficients():
    X, edges, k, _ = random_network(2)
    L = np.linalg.norm(X[edges[:, 0]] - X[edges[:, 1]], axis=1)
    x = deformed(X, np.random.default_rng(70))
    a = SpringEnergy.from_rest(X, edges, k=k)
    b = SpringEnergy.from_rest(X, edges, c=k * L)
    assert b.energy(nd(x)) == pytest.approx(a.energy(nd(x)), rel=1e-14)
    b.set_coefficients(2 * k * L)
    assert b.energy(nd(x)) == pytest.approx(2 * a.energy(nd(x)), rel=1e-14)
    np.testing.assert_allclose(forces_of(b, x), 2 * forces_of(a, x), rtol=1e-12, atol=1e-14)


# ------------------------------------------------------------------------------------------
# model: gravity, pins, potential, state
# ------------------------------------------------------------------------------------------

def test_model_forces_are_minus_gradient_of_potential_with_gravity_and_pins():
    X, edges, k, mass = random_network(1)
    g = np.array([0.0, -9.81, 0.0])
    model = Model.from_springs(X, edges, k=k, mass=mass, pinned=[0, 3], gravity=g)
    rng = np.random.default_rng(80)
    x = deformed(X, rng)
    f = vec3_ndarray(model.n)
    model.forces(nd(x), f)
    f = f.to_numpy()
    W_ref = energy_np(x, edges, model.springs.L_np, model.springs.c_np) - np.sum(mass[model.free] * (x[model.free] @ g))
    assert model.potential_energy(nd(x)) == pytest.approx(W_ref, rel=1e-13)
    h = 1e-6
    for i in range(model.n):
        for a in range(3):
            xp, xm = x.copy(), x.copy()
            xp[i, a] += h
            xm[i, a] -= h
            dW = (model.potential_energy(nd(xp)) - model.potential_energy(nd(xm))) / (2 * h)
            expected = 0.0 if model.pinned[i] else -dW
            assert f[i, a] == pytest.approx(expected, rel=1e-6, abs=1e-7)
    assert np.all(f[[0, 3]] == 0.0)


def test_state_roundtrip_and_pinned_velocity_zeroed():
    X, edges, k, mass = random_network(0)
    model = Model.from_springs(X, edges, k=k, mass=mass, pinned=np.arange(9) < 2)
    v = np.ones_like(X)
    s = model.make_state(v=v, t=1.5)
    arr = s.numpy()
    np.testing.assert_array_equal(arr.x, X)
    assert np.all(arr.v[:2] == 0) and np.all(arr.v[2:] == 1) and arr.t == 1.5
    c = s.copy()
    s.assign(x=X + 1)
    np.testing.assert_array_equal(c.numpy().x, X)
    assert isinstance(State.from_numpy(X), State)


def test_diagnostics_match_numpy():
    X, edges, k, mass = random_network(6)
    g = np.array([0.0, 0.0, -9.81])
    model = Model.from_springs(X, edges, k=k, mass=mass, gravity=g)
    rng = np.random.default_rng(90)
    x, v = deformed(X, rng), rng.standard_normal(X.shape)
    s = model.make_state(x, v)
    T = 0.5 * np.sum(mass * np.sum(v * v, axis=1))
    assert diagnostics.kinetic_energy(model, s) == pytest.approx(T, rel=1e-13)
    np.testing.assert_allclose(diagnostics.linear_momentum(model, s), (mass[:, None] * v).sum(0), rtol=1e-13)
    np.testing.assert_allclose(diagnostics.angular_momentum(model, s),
                               (mass[:, None] * np.cross(x, v)).sum(0), rtol=1e-12)
    e = diagnostics.energies(model, s)
    W = energy_np(x, edges, model.springs.L_np, model.springs.c_np) - np.sum(mass * (x @ g))
    assert e["total"] == pytest.approx(T + W, rel=1e-13)
    assert diagnostics.total_energy(model, s) == pytest.approx(T + W, rel=1e-13)


# ------------------------------------------------------------------------------------------
# validation: every error names the offending element, in one line
# ------------------------------------------------------------------------------------------

def _tet():
    X = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    E = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [2, 3], [1, 3]])
    return X, E


@pytest.mark.parametrize("case, expected", [
    ("zero_L", "edge 2 = (0, 3) has rest length 0.0"),
    ("negative_L", "edge 4 = (2, 3) has rest length -0.5"),
    ("coincident", "edge 4 joins vertices 2 and 3 at the same rest point"),
    ("k_negative", "edge 1 = (0, 2) has stiffness k=-2.0"),
    ("k_zero", "edge 0 = (0, 1) has stiffness k=0.0"),
    ("k_nan", "edge 5 = (1, 3) has stiffness k=nan"),
    ("c_inf", "edge 3 = (1, 2) has stiffness c=inf"),
    ("edge_out_of_range", "edge 5 = (1, 7) has a vertex index out of range 0..3"),
    ("edge_negative_index", "edge 0 = (-1, 1) has a vertex index out of range 0..3"),
    ("self_loop", "edge 1 joins vertex 2 to itself"),
    ("pin_out_of_range", "pin index 4 is out of range 0..3"),
    ("mass_zero_free", "vertex 2 is free but has mass 0.0"),
    ("mass_negative", "vertex 1 has invalid mass -1.0"),
    ("nonfinite_position", "vertex 3 has a non-finite rest position"),
])
def test_model_errors_name_the_element(case, expected):
    X, E = _tet()
    kw = dict(k=1.0)
    if case == "zero_L":
        kw["L"] = np.array([1, 1, 0.0, 1, 1, 1])
    elif case == "negative_L":
        kw["L"] = np.array([1, 1, 1, 1, -0.5, 1])
    elif case == "coincident":
        X = X.copy()
        X[3] = X[2]
    elif case.startswith("k_"):
        k = np.ones(6)
        k[{"k_negative": 1, "k_zero": 0, "k_nan": 5}[case]] = {"k_negative": -2.0, "k_zero": 0.0, "k_nan": np.nan}[case]
        kw["k"] = k
    elif case == "c_inf":
        c = np.ones(6)
        c[3] = np.inf
        kw = dict(c=c)
    elif case == "edge_out_of_range":
        E = E.copy()
        E[5] = (1, 7)
    elif case == "edge_negative_index":
        E = E.copy()
        E[0] = (-1, 1)
    elif case == "self_loop":
        E = E.copy()
        E[1] = (2, 2)
    elif case == "pin_out_of_range":
        kw["pinned"] = [0, 4]
    elif case == "mass_zero_free":
        kw["mass"] = np.array([0.0, 1, 0, 1])
        kw["pinned"] = [0]  # a pinned vertex may have zero mass; vertex 2 is free
    elif case == "mass_negative":
        kw["mass"] = np.array([1.0, -1, 1, 1])
    elif case == "nonfinite_position":
        X = X.copy()
        X[3, 1] = np.nan
    with pytest.raises(ModelError) as info:
        Model.from_springs(X, E, **kw)
    msg = str(info.value)
    assert expected in msg, msg
    assert "\n" not in msg
    assert isinstance(info.value, ValueError)


def test_model_requires_exactly_one_of_k_and_c():
    X, E = _tet()
    with pytest.raises(ModelError, match="exactly one of k"):
        Model.from_springs(X, E)
    with pytest.raises(ModelError, match="exactly one of k"):
        Model.from_springs(X, E, k=1.0, c=1.0)


# ------------------------------------------------------------------------------------------
# CFL estimates against numpy eigenvalues
# ------------------------------------------------------------------------------------------

def _true_lambda_max(model):
    H = model.dense_hessian(model.X_nd, psd=False)
    free = np.repeat(model.free, 3)
    M = np.repeat(model.mass, 3)[free]
    return sla.eigh(H[np.ix_(free, free)], np.diag(M), eigvals_only=True).max()


def _rod(N=40, h=0.05):
    X = np.zeros((N, 3))
    X[:, 0] = np.arange(N) * h
    return X, np.stack([np.arange(N - 1), np.arange(1, N)], 1)


@pytest.mark.parametrize("name", ["random0", "random1", "grid", "grid_pinned", "rod"])
def test_gershgorin_dt_is_conservative_and_power_iteration_is_accurate(name):
    if name.startswith("random"):
        X, E, k, mass = random_network(int(name[-1]) + 11, n=12)
        model = Model.from_springs(X, E, k=k, mass=mass)
    elif name.startswith("grid"):
        X, E = grid_network(5)
        mass = np.random.default_rng(1).uniform(0.5, 1.5, len(X))
        X = X + 0.01 * np.random.default_rng(2).standard_normal(X.shape)  # non-planar, irregular
        model = Model.from_springs(X, E, k=50.0, mass=mass, pinned=[0, 4] if name.endswith("pinned") else None)
    else:
        X, E = _rod()
        model = Model.from_springs(X, E, k=100.0, mass=0.2)
    lam = _true_lambda_max(model)
    lam_g = gershgorin_lambda_max(model)
    ratio = lam_g / lam
    assert 1.0 <= ratio < 4.0, ratio  # conservative, and not absurdly so
    if name == "rod":
        # free-free chain: lambda_max = 2k'/m (1 + cos(pi/N)) vs Gershgorin 4k'/m: nearly tight
        assert ratio < 1.01, ratio
    assert stable_dt_estimate(model) == pytest.approx(2 / np.sqrt(lam_g), rel=1e-12)
    # the brief's cruder bound 4 c/L^2 per incident edge is above ours
    sp = model.springs
    crude = np.zeros(model.n)
    np.add.at(crude, sp.edges_np.ravel(), np.repeat(4 * sp.c_np / sp.L_np ** 2, 2))
    assert lam_g <= (crude[model.free] / model.mass[model.free]).max() * (1 + 1e-12)
    lam_p = lambda_max_power(model, iters=5000, rtol=1e-12)
    assert lam_p <= lam * (1 + 1e-9)  # a Rayleigh quotient never exceeds lambda_max
    assert lam_p == pytest.approx(lam, rel=2e-3)
    # default settings (500 iterations, rtol 1e-8) give the true CFL dt within 0.1%
    dt_power = stable_dt_estimate(model, method="power")
    assert dt_power == pytest.approx(2 / np.sqrt(lam), rel=1e-3)
    print(f"{name}: gershgorin/true lambda {ratio:.3f}, power(5000)/true {lam_p / lam:.6f}, "
          f"dt power(500)/true {dt_power * np.sqrt(lam) / 2:.6f}")
