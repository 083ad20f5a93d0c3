"""Dihedral bending energy (engine/energies/bending.py): angle, derivatives, Hessians, physics.

Every test asserts a measured number against theory: the analytic dihedral angle, central
finite differences (f64), Bridson et al. 2003's u_1..u_4, rigid-motion invariance, the
force ratio (R1) 2 sin(theta/2)/theta, the cylinder curvature 1/(2R) and energy, and the
error messages.  Hinges are built by hand here (columns [v0, v1, w0, w1], t0 = (v0, v1, w0),
t1 = (v1, v0, w1)), independently of engine/mesh/.
"""
import math

import numpy as np
import pytest

from engine import mesh as meshes
from engine.energies import bending as bm
from engine.energies import bending_kernels as bk
from engine.energies.bending import BendingEnergy, BendingError, VARIANTS
from engine.energies.base import Energy
from engine.errors import ModelError
from engine.fields import vec3_ndarray
from lessons._measure import per_hinge_fd, random_rotation

# --------------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------------


def analytic_hinge(theta, L=1.3, p0=0.4, r0=0.9, p1=0.8, r1=0.7):
    """Edge along +x, wing w0 in the z = 0 plane (normal n0 = +z), wing w1 rotated about the
    edge so that the dihedral angle is theta by the module's sign convention."""
    return np.array([[0.0, 0.0, 0.0], [L, 0.0, 0.0], [p0, r0, 0.0],
                     [p1, -r1 * math.cos(theta), -r1 * math.sin(theta)]])


def stacked(hinge_points):
    """m independent hinges: vertices (4m, 3) and hinges [[4i, 4i+1, 4i+2, 4i+3]]."""
    X = np.concatenate(hinge_points, axis=0)
    H = np.arange(len(X)).reshape(-1, 4)
    return X, H


def random_hinges(rng, m, max_angle=2.4):
    """m random non-degenerate hinges (wing heights >= 0.3 |e|, |theta| <= max_angle),
    randomly placed and rotated."""
    out = []
    while len(out) < m:
        L = rng.uniform(0.6, 1.5)
        th = rng.uniform(-max_angle, max_angle)
        P = analytic_hinge(th, L=L, p0=rng.uniform(-0.3, 1.3) * L, r0=rng.uniform(0.3, 1.2) * L,
                           p1=rng.uniform(-0.3, 1.3) * L, r1=rng.uniform(0.3, 1.2) * L)
        out.append(P @ random_rotation(rng).T + rng.normal(size=3))
    return stacked(out)


def per_hinge_hessian_fd(fun, X, eps):
    """Central differences of per-hinge gradients fun(X) -> (m, 4, 3): (m, 12, 12)."""
    m = len(X) // 4
    Hs = np.zeros((m, 12, 12))
    for a in range(4):
        for c in range(3):
            Xp, Xm = X.copy(), X.copy()
            Xp[a::4, c] += eps
            Xm[a::4, c] -= eps
            Hs[:, :, 3 * a + c] = ((fun(Xp) - fun(Xm)) / (2 * eps)).reshape(m, 12)
    return Hs


def blocks_to_12(blocks):
    """(m, 16, 3, 3) -> (m, 12, 12)."""
    return blocks.reshape(-1, 4, 4, 3, 3).transpose(0, 1, 3, 2, 4).reshape(-1, 12, 12)


def rel(a, b):
    return np.linalg.norm(a - b) / np.linalg.norm(b)


def hinges_from_triangles(T):
    """[v0, v1, w0, w1] for every edge shared by two consistently oriented triangles."""
    half = {}
    for t in T:
        for k in range(3):
            half[(int(t[k]), int(t[(k + 1) % 3]))] = int(t[(k + 2) % 3])
    H = [[a, b, c, half[(b, a)]] for (a, b), c in half.items() if a < b and (b, a) in half]
    return np.array(sorted(H), dtype=np.int64)


def bumpy_grid(nx, ny, rng, amp=0.15):
    """Right-triangle grid on [0,1]^2, counter-clockwise, with a smooth random height field."""
    xs, ys = np.meshgrid(np.linspace(0, 1, nx), np.linspace(0, 1, ny), indexing="ij")
    X = np.stack([xs.ravel(), ys.ravel(), np.zeros(nx * ny)], axis=1)
    X[:, 2] = amp * np.sin(3 * X[:, 0] + rng.uniform(0, 3)) * np.cos(2 * X[:, 1])
    X[:, :2] += 0.01 * rng.normal(size=(nx * ny, 2))
    T = []
    for i in range(nx - 1):
        for j in range(ny - 1):
            a, b, c, d = i * ny + j, (i + 1) * ny + j, (i + 1) * ny + j + 1, i * ny + j + 1
            T += [(a, b, c), (a, c, d)]
    return X, np.array(T)


def cylinder(N, nx, R=1.0):
    """A closed strip of equilateral triangles around a cylinder of radius R (axis x):
    N generators (N even) at angles 2 pi j/N, nx vertices each, spaced a along x with odd
    generators shifted by a/2; the chord between generators 2R sin(pi/N) = a sqrt(3)/2, so
    every triangle is exactly equilateral.  Outward normals."""
    assert N % 2 == 0
    a = 4 * R * math.sin(math.pi / N) / math.sqrt(3)
    X = np.zeros((N * nx, 3))
    for j in range(N):
        phi = 2 * math.pi * j / N
        for i in range(nx):
            X[j * nx + i] = [(i + 0.5 * (j % 2)) * a, R * math.cos(phi), R * math.sin(phi)]
    T = []
    for j in range(N):
        jn = (j + 1) % N
        for i in range(nx - 1):
            if j % 2 == 0:
                tris = [(j * nx + i, j * nx + i + 1, jn * nx + i), (jn * nx + i, j * nx + i + 1, jn * nx + i + 1)]
            else:
                tris = [(jn * nx + i, jn * nx + i + 1, j * nx + i), (j * nx + i, jn * nx + i + 1, j * nx + i + 1)]
            for t in tris:
                p, q, r = X[list(t)]
                nrm = np.cross(q - p, r - p)
                c = (p + q + r) / 3
                radial = np.array([0.0, c[1], c[2]])
                T.append(t if nrm @ radial > 0 else (t[0], t[2], t[1]))
    T = np.array(T)
    areas = 0.5 * np.linalg.norm(np.cross(X[T[:, 1]] - X[T[:, 0]], X[T[:, 2]] - X[T[:, 0]]), axis=1)
    return X, T, a, areas.sum()


# --------------------------------------------------------------------------------------------
# angle
# --------------------------------------------------------------------------------------------

ANGLES = [-3.1, -3.0, -2.0, -math.pi / 2 - 1e-3, -math.pi / 2, -math.pi / 2 + 1e-3, -1.0, -0.5, -1e-7, 0.0,
          1e-7, 0.5, 1.0, math.pi / 2 - 1e-3, math.pi / 2, math.pi / 2 + 1e-3, 2.0, 3.0, 3.1, 3.14159]


def test_theta_matches_analytic_hinge_over_minus_pi_to_pi():
    rng = np.random.default_rng(1)
    pts = [analytic_hinge(t) @ random_rotation(rng).T + rng.normal(size=3) for t in ANGLES]
    X, H = stacked(pts)
    E = BendingEnergy(X, H, 1.0)  # rest = the bent hinges themselves; only angles() used
    theta = E.angles(X)
    err = np.abs(theta - np.array(ANGLES))
    assert err.max() < 1e-13, err.max()  # measured ~4e-16: atan2 keeps full precision near +-pi
    assert np.abs(theta - meshes.dihedral_angles(X, H)).max() < 1e-14


def test_theta_sign_convention():
    # theta > 0 where the hinge is convex on its normals' side; moving a wing along its own
    # normal (here w0 along n0 = +z) decreases theta.
    X = analytic_hinge(0.3)
    E = BendingEnergy(X, [[0, 1, 2, 3]], 1.0)
    t0 = E.angles(X)[0]
    Xp = X.copy()
    Xp[2, 2] += 1e-3
    assert t0 == pytest.approx(0.3, abs=1e-15)
    assert E.angles(Xp)[0] < t0
    # rotating w1 towards the normal side (-theta direction) folds it "up": theta < 0
    assert E.angles(analytic_hinge(-0.3))[0] == pytest.approx(-0.3, abs=1e-15)


# --------------------------------------------------------------------------------------------
# gradients
# --------------------------------------------------------------------------------------------

def test_theta_gradient_matches_finite_differences():
    rng = np.random.default_rng(2)
    X, H = random_hinges(rng, 40)
    E = BendingEnergy(X, H, 1.0)
    import taichi as ti
    buf = ti.ndarray(dtype=ti.math.vec3, shape=(len(H), 4))
    bm.theta_gradient_kernel(vec3_ndarray(len(X), X), E.hinges, buf)
    g = buf.to_numpy()
    fd = per_hinge_fd(E.angles, X, 1e-6)
    errs = np.linalg.norm((g - fd).reshape(len(H), -1), axis=1) / np.linalg.norm(fd.reshape(len(H), -1), axis=1)
    assert errs.max() < 1e-6, errs.max()  # measured ~2e-10
    # (G1): wing gradients are -n/h
    xv0, xv1, xw0 = X[H[:, 0]], X[H[:, 1]], X[H[:, 2]]
    N0 = np.cross(xv1 - xv0, xw0 - xv0)
    h0 = np.linalg.norm(N0, axis=1) / np.linalg.norm(xv1 - xv0, axis=1)
    assert np.abs(g[:, 2] + N0 / np.linalg.norm(N0, axis=1)[:, None] / h0[:, None]).max() < 1e-12
    assert np.abs(g.sum(axis=1)).max() < 1e-12


def test_bridson_u_vectors_equal_minus_theta_gradient():
    import taichi as ti
    rng = np.random.default_rng(3)
    X, H = random_hinges(rng, 40, max_angle=3.1)
    E = BendingEnergy(X, H, 1.0)
    xs = vec3_ndarray(len(X), X)
    g = ti.ndarray(dtype=ti.math.vec3, shape=(len(H), 4))
    u = ti.ndarray(dtype=ti.math.vec3, shape=(len(H), 4))
    bm.theta_gradient_kernel(xs, E.hinges, g)
    bm.bridson_u_kernel(xs, E.hinges, u)
    g, u = g.to_numpy(), u.to_numpy()
    errs = np.linalg.norm((u + g).reshape(len(H), -1), axis=1) / np.linalg.norm(g.reshape(len(H), -1), axis=1)
    assert errs.max() < 1e-12, errs.max()  # u_i = -dtheta/dx_i, measured ~4e-16


@pytest.mark.parametrize("variant", VARIANTS)
def test_energy_gradient_matches_finite_differences_with_curved_rest(variant):
    rng = np.random.default_rng(4)
    X, H = random_hinges(rng, 30, max_angle=2.0)
    theta_bar = rng.uniform(-1.0, 1.0, len(H))
    X_rest = X + 0.05 * rng.normal(size=X.shape)
    E = BendingEnergy(X_rest, H, 0.7, variant=variant, theta_bar=theta_bar)
    f = E.hinge_forces(X)
    fd = per_hinge_fd(E.hinge_energies, X, 1e-6)
    errs = np.linalg.norm((f + fd).reshape(len(H), -1), axis=1) / np.linalg.norm(fd.reshape(len(H), -1), axis=1)
    assert errs.max() < 1e-6, errs.max()
    # the total energy is the sum of the hinge energies, the gathered force the scatter sum
    assert E.energy(X) == pytest.approx(E.hinge_energies(X).sum(), rel=1e-13)
    assert np.abs(E.forces(X) - f.reshape(-1, 3)).max() == 0.0


@pytest.mark.parametrize("variant", VARIANTS)
def test_zero_force_and_energy_at_curved_rest(variant):
    rng = np.random.default_rng(5)
    X, H = random_hinges(rng, 20)
    E = BendingEnergy(X, H, 2.0, variant=variant, from_rest=True)
    assert np.abs(E.theta_bar).max() > 1.0  # genuinely curved rest shapes
    assert abs(E.energy(X)) < 1e-28
    assert np.abs(E.forces(X)).max() < 1e-13


# --------------------------------------------------------------------------------------------
# Hessians
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("variant", VARIANTS)
def test_exact_hessian_matches_finite_differences(variant):
    rng = np.random.default_rng(6)
    X, H = random_hinges(rng, 30, max_angle=2.0)
    E = BendingEnergy(X + 0.05 * rng.normal(size=X.shape), H, 1.3, variant=variant,
                      theta_bar=rng.uniform(-1, 1, len(H)))
    Hx = blocks_to_12(E.hessian_blocks_numpy(X, psd=False))
    Hfd = per_hinge_hessian_fd(lambda Y: -E.hinge_forces(Y), X, 1e-6)
    errs = np.array([rel(a, b) for a, b in zip(Hx, Hfd)])
    assert errs.max() < 1e-5, errs.max()  # measured ~2e-10
    assert np.abs(Hx - Hx.transpose(0, 2, 1)).max() < 1e-12 * np.abs(Hx).max()


def test_theta_hessian_matches_finite_differences():
    import taichi as ti
    rng = np.random.default_rng(7)
    X, H = random_hinges(rng, 30, max_angle=3.0)
    E = BendingEnergy(X, H, 1.0)

    def grad(Y):
        buf = ti.ndarray(dtype=ti.math.vec3, shape=(len(H), 4))
        bm.theta_gradient_kernel(vec3_ndarray(len(Y), Y), E.hinges, buf)
        return buf.to_numpy()

    Ht = blocks_to_12(E.theta_hessian_blocks_numpy(X))
    Hfd = per_hinge_hessian_fd(grad, X, 1e-6)
    errs = np.array([rel(a, b) for a, b in zip(Ht, Hfd)])
    assert errs.max() < 1e-5, errs.max()


@pytest.mark.parametrize("variant", VARIANTS)
def test_gauss_newton_hessian_is_psd_and_exact_at_rest_angle(variant):
    rng = np.random.default_rng(8)
    X, H = random_hinges(rng, 30, max_angle=2.5)
    E = BendingEnergy(X, H, 1.0, variant=variant, theta_bar=rng.uniform(-0.5, 0.5, len(H)))
    G = blocks_to_12(E.hessian_blocks_numpy(X, psd=True))
    assert np.abs(G - G.transpose(0, 2, 1)).max() < 1e-14 * np.abs(G).max()
    eig = np.linalg.eigvalsh(G)
    scale = np.abs(eig).max(axis=1)
    assert (eig.min(axis=1) >= -1e-10 * scale).all()
    # rank one: k' g g^T, its one non-zero eigenvalue is k' |g|^2
    assert (np.sort(np.abs(eig), axis=1)[:, -2] < 1e-10 * scale).all()
    # away from the rest angle the exact Hessian (W' Hess theta term) is indefinite
    Hx = blocks_to_12(E.hessian_blocks_numpy(X, psd=False))
    assert (np.linalg.eigvalsh(Hx).min(axis=1) < -1e-3 * scale).mean() > 0.5
    # at theta = theta_bar (W' = 0) the two coincide, for every variant
    E0 = BendingEnergy(X, H, 1.0, variant=variant, from_rest=True)
    G0 = E0.hessian_blocks_numpy(X, psd=True)
    H0 = E0.hessian_blocks_numpy(X, psd=False)
    assert np.abs(G0 - H0).max() < 1e-12 * np.abs(H0).max()


@pytest.mark.parametrize("variant", VARIANTS)
def test_gauss_newton_factors_are_the_rank_one_hessian(variant):
    """w[h, slot] = sqrt(max(W'', 0)) dtheta/dx_slot: w_h w_h^T is the Gauss-Newton block matrix,
    and the stencil block reader (``block``) and incidences describe the same hinges."""
    import taichi as ti
    rng = np.random.default_rng(18)
    X, H = random_hinges(rng, 30, max_angle=2.5)
    E = BendingEnergy(X, H, 1.0, variant=variant, theta_bar=rng.uniform(-0.5, 0.5, len(H)))
    assert E.stencil_size == 4 and E.n_elements == len(H) and "rank-one" in E.products
    assert np.array_equal(E.elements.to_numpy(), H) and E.elements is E.hinges
    w = ti.ndarray(dtype=ti.math.vec3, shape=(len(H), 4))
    E.gauss_newton_factors(X, w)
    wv = w.to_numpy().reshape(len(H), 12)
    G = blocks_to_12(E.hessian_blocks_numpy(X, psd=True))
    assert np.abs(np.einsum("hi,hj->hij", wv, wv) - G).max() < 1e-14 * np.abs(G).max()
    g = ti.ndarray(dtype=ti.math.vec3, shape=(len(H), 4))
    bm.theta_gradient_kernel(vec3_ndarray(len(X), X), E.hinges, g)
    # w is parallel to grad theta (the direction of the single non-zero eigenvector)
    gv = g.to_numpy().reshape(len(H), 12)
    cos = np.abs((wv * gv).sum(1)) / (np.linalg.norm(wv, axis=1) * np.linalg.norm(gv, axis=1))
    assert np.abs(cos - 1.0).max() < 1e-14
    off, ent = (a.to_numpy() for a in E.slot_incidence)
    assert np.array_equal(np.sort(H.reshape(-1)[ent]), np.sort(H.reshape(-1)))
    assert all((H.reshape(-1)[ent[off[v]:off[v + 1]]] == v).all() for v in range(len(X)))


def test_force_args_drive_the_force_funcs():
    """A kernel fusing hinge_force_vectors + hinge_gather with force_args() gives add_forces bitwise."""
    import taichi as ti
    from engine.fields import int_array, int_array2, scalar_array, vec3_array, vec3_array2

    @ti.kernel
    def fused_forces(x: vec3_array, hinges: int_array2, k: scalar_array, theta_bar: scalar_array, mode: ti.i32,
                     fh: vec3_array2, offsets: int_array, entries: int_array, f: vec3_array):
        for h in range(hinges.shape[0]):
            bk.hinge_force_vectors(x, hinges, k, theta_bar, mode, fh, h)
        for v in range(f.shape[0]):
            f[v] += bk.hinge_gather(fh, offsets, entries, v)

    rng = np.random.default_rng(19)
    X, T = bumpy_grid(6, 5, rng, amp=0.25)
    E = BendingEnergy(X, hinges_from_triangles(T), 1.0, variant="bridson")
    xs = vec3_ndarray(len(X), X + 0.05 * rng.normal(size=X.shape))
    f1, f2 = vec3_ndarray(len(X)), vec3_ndarray(len(X))
    E.add_forces(xs, f1)
    fused_forces(xs, *E.force_args(), f2)
    assert np.array_equal(f1.to_numpy(), f2.to_numpy()) and np.abs(f1.to_numpy()).max() > 0
    assert E.force_args()[:4] == E.hinge_args()


def test_hessian_products_diagonal_and_dense_assembly_agree_on_a_grid():
    rng = np.random.default_rng(9)
    X, T = bumpy_grid(5, 5, rng)
    H = hinges_from_triangles(T)
    Xr = X.copy()
    Xr[:, 2] = 0.0  # flat rest
    n = len(X)
    for variant in VARIANTS:
        E = BendingEnergy(Xr, H, 1.0, variant=variant)
        for psd in (True, False):
            D = E.dense_hessian(X, psd)                     # from blocks
            D2 = Energy.dense_hessian(E, vec3_ndarray(n, X), psd)  # from 3n Hessian-vector products
            assert np.abs(D - D2).max() < 1e-13 * np.abs(D).max()
            dx = rng.normal(size=(n, 3))
            out = np.ones((n, 3))
            E.add_hessian_product(X, dx, out, psd)
            assert np.abs(out - 1.0 - (D @ dx.ravel()).reshape(n, 3)).max() < 1e-13 * np.abs(D).max()
            import taichi as ti
            diag = ti.ndarray(dtype=ti.math.mat3, shape=n)
            diag.from_numpy(np.zeros((n, 3, 3)))
            E.add_hessian_diagonal(vec3_ndarray(n, X), diag, psd)
            Dd = np.array([D[3 * i:3 * i + 3, 3 * i:3 * i + 3] for i in range(n)])
            assert np.abs(diag.to_numpy() - Dd).max() < 1e-13 * np.abs(D).max()
        # global Hessian = finite differences of the gathered forces
        Dfd = np.zeros((3 * n, 3 * n))
        for col in range(3 * n):
            Xp, Xm = X.copy().ravel(), X.copy().ravel()
            Xp[col] += 1e-6
            Xm[col] -= 1e-6
            Dfd[:, col] = -(E.forces(Xp.reshape(n, 3)) - E.forces(Xm.reshape(n, 3))).ravel() / 2e-6
        assert rel(E.dense_hessian(X, psd=False), Dfd) < 1e-6


# --------------------------------------------------------------------------------------------
# invariances
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("variant", VARIANTS)
def test_zero_net_force_and_torque_per_hinge(variant):
    rng = np.random.default_rng(10)
    X, H = random_hinges(rng, 40, max_angle=3.0)
    E = BendingEnergy(X + 0.1 * rng.normal(size=X.shape), H, 1.0, variant=variant, from_rest=True)
    f = E.hinge_forces(X)
    xs = X[H]
    scale = (np.linalg.norm(f, axis=2) * np.linalg.norm(xs, axis=2)).sum(axis=1)
    net_f = np.linalg.norm(f.sum(axis=1), axis=1) / np.linalg.norm(f, axis=2).sum(axis=1)
    net_tau = np.linalg.norm(np.cross(xs, f).sum(axis=1), axis=1) / scale
    assert net_f.max() < 1e-14 and net_tau.max() < 1e-14, (net_f.max(), net_tau.max())


@pytest.mark.parametrize("variant", VARIANTS)
def test_rigid_motion_invariance(variant):
    rng = np.random.default_rng(11)
    X, T = bumpy_grid(6, 5, rng, amp=0.3)
    H = hinges_from_triangles(T)
    Xr = X + 0.02 * rng.normal(size=X.shape)
    E = BendingEnergy(Xr, H, 0.5, variant=variant, from_rest=True)
    W, th, f = E.energy(X), E.angles(X), E.forces(X)
    assert W > 0
    for _ in range(3):
        Q, t = random_rotation(rng), 10 * rng.normal(size=3)
        Y = X @ Q.T + t
        assert E.energy(Y) == pytest.approx(W, rel=1e-12)
        assert np.abs(E.angles(Y) - th).max() < 1e-12
        assert np.abs(E.forces(Y) - f @ Q.T).max() < 1e-11 * np.abs(f).max()


# --------------------------------------------------------------------------------------------
# physics
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("theta", [0.5, 1.0])
def test_bridson_force_ratio_to_notes_force(theta):
    rest = analytic_hinge(0.0)
    x = analytic_hinge(theta)
    H = [[0, 1, 2, 3]]
    fn = BendingEnergy(rest, H, 1.0, "notes").hinge_forces(x)[0]
    fb = BendingEnergy(rest, H, 1.0, "bridson").hinge_forces(x)[0]
    ratio = (fb * fn).sum() / (fn * fn).sum()
    assert np.abs(fb - ratio * fn).max() < 1e-15 * np.abs(fn).max()    # parallel forces
    assert ratio == pytest.approx(2 * math.sin(theta / 2) / theta, rel=1e-14)   # (R1)
    series = 1 - theta ** 2 / 24
    # identities once the ratio above holds (the Taylor series of 2 sin(theta/2)/theta), kept to show the
    # size of the small-angle form's error: the two-term series is short by theta^4/1920 (next term
    # -theta^6/322560)
    assert ratio - series == pytest.approx(theta ** 4 / 1920, rel=0.01)
    assert abs(ratio - series) < 5.3e-4  # 3.3e-5 at 0.5 rad, 5.2e-4 at 1 rad
    # discrete shells: same direction, 3x the notes' stiffness
    fd = BendingEnergy(rest, H, 1.0, "discrete-shells").hinge_forces(x)[0]
    assert np.abs(fd - 3 * fn).max() < 1e-14 * np.abs(fn).max()


def _bridson_literal(X, H, k):
    """Bridson et al. 2003's elastic bending force as written: F_i = k |E|^2/(|N1|+|N2|) sin(theta/2) u_i
    with |E|, |N1|, |N2|, theta and the u_i all of the current shape X (theta_bar = 0); (h, 4, 3) in
    slot order (v0, v1, w0, w1), the u_i from the engine's literal kernel."""
    import taichi as ti
    probe = BendingEnergy(X, H, 1.0)  # only for its hinge ndarray and angles
    u = ti.ndarray(dtype=ti.math.vec3, shape=(len(H), 4))
    bm.bridson_u_kernel(vec3_ndarray(len(X), X), probe.hinges, u)
    geo = meshes.hinge_geometry(X, np.asarray(H))
    coef = geo["edge_length"] ** 2 / (2 * (geo["A0"] + geo["A1"]))  # |E|^2/(|N1|+|N2|) now
    return k * (coef * np.sin(probe.angles(X) / 2))[:, None, None] * u.to_numpy(), coef


def test_bridson_variant_is_bridsons_formula_with_the_coefficient_of_the_rest_mesh():
    """Where the hinge keeps its rest |E| and wing areas (it only bends), the variant's force is
    Bridson's literal formula with his k = B/3: the frozen coefficient equals the current one.
    (This alone cannot tell the two apart: see the stretched hinge below.)"""
    rng = np.random.default_rng(12)
    X, H = random_hinges(rng, 20, max_angle=3.0)
    B = 0.9
    rest = X.copy()
    # a rest shape with the same edge and wing areas as X: w1 turned about the edge into the plane of w0
    e = X[1::4] - X[0::4]
    e_hat = e / np.linalg.norm(e, axis=1, keepdims=True)
    for i, (v0, w0, w1, eh) in enumerate(zip(X[0::4], X[2::4], X[3::4], e_hat)):
        a0, a1 = w0 - v0, w1 - v0
        perp0 = a0 - (a0 @ eh) * eh
        rest[4 * i + 3] = v0 + (a1 @ eh) * eh - perp0 / np.linalg.norm(perp0) * np.linalg.norm(a1 - (a1 @ eh) * eh)
    E = BendingEnergy(rest, H, B, "bridson")
    literal, coef = _bridson_literal(X, H, B / 3)
    geo = E.geometry
    assert np.allclose(coef, geo["edge_length"] ** 2 / (2 * (geo["A0"] + geo["A1"])), rtol=1e-12)
    f = E.hinge_forces(X)
    assert np.abs(f - literal).max() < 1e-12 * np.abs(f).max()


@pytest.mark.parametrize("heights,want", [(1 / 1.1, 1.21), (0.9, 1.1 / 0.9)], ids=["heights/1.1", "heights*0.9"])
def test_bridson_literal_coefficient_goes_with_edge_over_heights(heights, want):
    """The literal coefficient |E|^2/(|N1|+|N2|) = |E|/(h0+h1) over its rest value: an edge 10%
    longer with the heights divided by 1.1 gives 1.1^2 = 1.21; with the heights times 0.9 ("10%
    lower") it gives 1.1/0.9 = 1.2222, not 1.21."""
    kw = dict(L=1.0, p0=0.4, r0=0.8, p1=0.6, r1=0.7)
    rest = analytic_hinge(0.0, **kw)
    x = analytic_hinge(1.0, **kw)
    x[:, 0] *= 1.1
    x[:, 1:] *= heights
    H = np.arange(4).reshape(-1, 4)
    E = BendingEnergy(rest, H, 0.9, "bridson")
    _, coef = _bridson_literal(x, H, 0.3)
    geo = E.geometry
    ratio = coef / (geo["edge_length"] ** 2 / (2 * (geo["A0"] + geo["A1"])))
    assert ratio == pytest.approx(want, rel=1e-12)


def test_moving_the_wings_along_their_normals_lowers_theta():
    """The sign the bending lesson states: theta < 0 when the wings fold towards the side the
    normals point to, theta > 0 when they fold away (a ridge seen from the normal side)."""
    from engine.mesh.measures import dihedral_angles
    X = np.array([[0.0, 0, 0], [1.0, 0, 0], [0.5, 1.0, 0], [0.5, -1.0, 0]])
    H = np.array([[0, 1, 2, 3]])
    e, a0, a1 = X[1] - X[0], X[2] - X[0], X[3] - X[0]
    N0, N1 = np.cross(e, a0), np.cross(a1, e)
    assert np.allclose(N0 / np.linalg.norm(N0), N1 / np.linalg.norm(N1))   # flat: one normal side
    towards = X.copy()
    towards[2] += 0.1 * N0 / np.linalg.norm(N0)
    towards[3] += 0.1 * N1 / np.linalg.norm(N1)
    away = X.copy()
    away[2] -= 0.1 * N0 / np.linalg.norm(N0)
    away[3] -= 0.1 * N1 / np.linalg.norm(N1)
    assert dihedral_angles(towards, H)[0] < 0 < dihedral_angles(away, H)[0]


def test_bridson_variant_on_a_stretched_hinge_is_conservative_and_differs_from_the_literal_force():
    """On a hinge whose edge is 10% longer and whose wing heights are divided by 1.1, Bridson's
    coefficient |E|^2/(|N1|+|N2|) = |E|/(h0+h1) is 1.21 x its rest value. The variant keeps the
    rest value: its force is minus the gradient of 4 k_e (1 - cos(theta/2)) (central differences)
    and its Jacobian is symmetric; the literal force is 1.21 x larger and has no energy (its
    Jacobian is not symmetric)."""
    rng = np.random.default_rng(5)
    bent = []
    for _ in range(6):
        L = rng.uniform(0.8, 1.2)
        kw = dict(L=L, p0=rng.uniform(0.1, 0.9) * L, r0=rng.uniform(0.5, 1.0) * L, p1=rng.uniform(0.1, 0.9) * L,
                  r1=rng.uniform(0.5, 1.0) * L)
        rest = analytic_hinge(0.0, **kw)
        x = analytic_hinge(rng.uniform(0.6, 1.6), **kw)
        x[:, 0] *= 1.1          # the edge 10% longer
        x[:, 1:] /= 1.1         # the wing heights divided by 1.1
        Q, t = random_rotation(rng), rng.normal(size=3)
        bent.append((x @ Q.T + t, rest @ Q.T + t))
    X = np.concatenate([b[0] for b in bent])
    rest = np.concatenate([b[1] for b in bent])
    H = np.arange(len(X)).reshape(-1, 4)
    B = 0.9
    E = BendingEnergy(rest, H, B, "bridson")
    f = E.hinge_forces(X)
    # conservative: minus the gradient of the variant's own energy (W2) with k_e frozen at rest
    f_fd = -per_hinge_fd(E.hinge_energies, X)
    assert rel(f, f_fd) < 1e-7
    literal, coef = _bridson_literal(X, H, B / 3)
    geo = E.geometry
    ratio = coef / (geo["edge_length"] ** 2 / (2 * (geo["A0"] + geo["A1"])))
    assert np.allclose(ratio, 1.21, rtol=1e-12)
    assert np.abs(literal - ratio[:, None, None] * f).max() < 1e-12 * np.abs(literal).max()  # parallel, 1.21 x
    assert rel(f, literal) == pytest.approx(1 - 1 / 1.21, rel=1e-9)  # 17% of the literal force

    def jacobian(force, i):
        """12 x 12 central-difference Jacobian of hinge i's four forces."""
        J = np.zeros((12, 12))
        for a in range(4):
            for c in range(3):
                Xp, Xm = X.copy(), X.copy()
                Xp[4 * i + a, c] += 1e-6
                Xm[4 * i + a, c] -= 1e-6
                J[:, 3 * a + c] = (force(Xp)[i] - force(Xm)[i]).reshape(12) / 2e-6
        return J

    asym = lambda J: np.linalg.norm(J - J.T) / np.linalg.norm(J)
    for i in range(len(H)):
        assert asym(jacobian(E.hinge_forces, i)) < 1e-6      # a Hessian: symmetric
        assert asym(jacobian(lambda Y: _bridson_literal(Y, H, B / 3)[0], i)) > 0.1  # measured 0.48-0.62: no energy has it


def test_cylinder_curvature_estimate_converges_to_one_over_2R():
    R = 0.8
    errors = []
    for N in (12, 24):
        X, T, a, area = cylinder(N, 6, R)
        H = hinges_from_triangles(T)
        E = BendingEnergy(X, H, 1.0)
        theta = E.angles(X)
        h = E.geometry["h0"] + E.geometry["h1"]
        across = (H[:, 0] // 6) == (H[:, 1] // 6)  # edge along a generator: the bend runs across it
        assert across.sum() == N * 5
        assert np.abs(theta[~across]).max() < 1e-12       # other hinges are flat
        assert np.allclose(theta[across], 2 * math.pi / N, rtol=1e-12)  # convex, outward normals: > 0
        curv = theta[across] / h[across]
        err = abs(curv.mean() * 2 * R - 1)
        xN = math.pi / N
        assert err == pytest.approx(xN / math.sin(xN) - 1, rel=1e-9)  # (pi/N)/sin(pi/N) - 1 ~ (pi/N)^2/6
        errors.append(err)
    assert errors[1] < errors[0] / 3.9   # 0.0115 -> 0.00286: second order in the mesh size


def test_cylinder_energy_notes_one_third_discrete_shells_continuum():
    R, B = 1.2, 0.7
    ratios = {}
    for N in (16, 32):
        X, T, a, area = cylinder(N, 7, R)
        H = hinges_from_triangles(T)
        continuum = 0.5 * B * (1 / (2 * R)) ** 2 * area
        xN = math.pi / N
        for variant in VARIANTS:
            # rest |e|, h, A of the rolled strip equal the flat strip's (isometric); theta_bar = 0
            E = BendingEnergy(X, H, B, variant=variant)
            ratios[(variant, N)] = E.energy(X) / continuum
        assert ratios[("notes", N)] == pytest.approx((xN / math.sin(xN)) ** 2 / 3, rel=1e-10)
        assert ratios[("discrete-shells", N)] == pytest.approx((xN / math.sin(xN)) ** 2, rel=1e-10)
        # bridson: 8 k sin^2(theta/4) = 1/2 k theta^2 (1 - theta^2/48 + ...)
        th = 2 * xN
        assert ratios[("bridson", N)] == pytest.approx(
            (xN / math.sin(xN)) ** 2 / 3 * 16 * math.sin(th / 4) ** 2 / th ** 2, rel=1e-10)
    assert abs(ratios[("discrete-shells", 32)] - 1) < abs(ratios[("discrete-shells", 16)] - 1) / 3.9
    assert abs(ratios[("notes", 32)] - 1 / 3) < 1.1e-3


def test_energy_density_equals_energy_per_area_at_interior_vertices():
    X, T, a, area = cylinder(12, 8, 1.0)
    H = hinges_from_triangles(T)
    E = BendingEnergy(X, H, 1.0, variant="discrete-shells")  # theta_bar = 0
    rho = E.energy_density(X)
    # interior: in 12 hinges (6 as an edge end, 6 as a wing); 4 of them bend (2 + 2), all have
    # the same A_e, so rho = 4 W / (12 A_e) = W / (3 A_e) = total energy / total area
    memberships = np.bincount(H.ravel(), minlength=len(X))
    interior = memberships == 12
    assert interior.sum() == 12 * 5
    assert np.allclose(rho[interior], E.energy(X) / area, rtol=1e-12)
    assert rho.min() > 0


def test_rest_angle_wrap_keeps_energy_continuous_across_pi():
    rest = analytic_hinge(3.0)
    H = [[0, 1, 2, 3]]
    for variant in VARIANTS:
        E = BendingEnergy(rest, H, 1.0, variant=variant, from_rest=True)
        w_below = E.energy(analytic_hinge(math.pi - 1e-9))
        w_above = E.energy(analytic_hinge(-math.pi + 1e-9))  # crossed +pi: theta jumps to -pi
        assert w_above == pytest.approx(w_below, rel=1e-7)
        # d = theta - theta_bar wrapped into [-pi, pi): theta = -3 is 2 pi - 6 = 0.283 rad past theta_bar = 3
        assert E.energy(analytic_hinge(-3.0)) == pytest.approx(E.energy(analytic_hinge(3.0 - (2 * math.pi - 6.0))),
                                                               rel=1e-9)


# --------------------------------------------------------------------------------------------
# assembly and errors
# --------------------------------------------------------------------------------------------

def test_per_vertex_gather_equals_numpy_scatter_and_is_deterministic():
    import taichi as ti
    rng = np.random.default_rng(13)
    X, T = bumpy_grid(9, 7, rng, amp=0.25)
    H = hinges_from_triangles(T)
    E = BendingEnergy(X + 0.03 * rng.normal(size=X.shape), H, 1.0, variant="notes", from_rest=True)
    fh = E.hinge_forces(X)
    ref = np.zeros((len(X), 3))
    for h in range(len(H)):            # reference scatter, hinge by hinge
        for slot in range(4):
            ref[H[h, slot]] += fh[h, slot]
    f = vec3_ndarray(len(X))
    xs = vec3_ndarray(len(X), X)
    E.add_forces(xs, f)
    got = f.to_numpy()
    assert np.abs(got - ref).max() <= 1e-15 * np.abs(ref).max()
    assert np.array_equal(bk.scatter_hinge_vectors_numpy(len(X), H, fh), ref)
    f2 = vec3_ndarray(len(X))
    E.add_forces(xs, f2)
    assert np.array_equal(f2.to_numpy(), got)  # bitwise reproducible
    E.add_forces(xs, f2)                        # accumulates: f += -grad W
    assert np.abs(f2.to_numpy() - 2 * got).max() <= 1e-15 * np.abs(got).max()
    assert isinstance(f2, ti.Ndarray)


def _err(X, H, B=1.0, **kw):
    with pytest.raises(BendingError) as info:
        BendingEnergy(X, H, B, **kw)
    msg = str(info.value)
    assert "\n" not in msg
    return msg


def test_errors_name_the_element():
    rng = np.random.default_rng(14)
    X = rng.normal(size=(10, 3))
    good = [[0, 1, 2, 5], [1, 2, 3, 6], [2, 3, 4, 7], [3, 4, 5, 8], [0, 2, 1, 6], [5, 6, 7, 8], [4, 5, 6, 0]]
    Xd = X.copy()
    Xd[9] = X[3] + 2.5 * (X[4] - X[3])  # on the line of edge 3-4
    msg = _err(Xd, good + [[3, 4, 9, 5]])
    assert msg == "hinge 7 (edge 3-4): wing triangle (3, 4, 9) has zero area"
    msg = _err(Xd, good + [[3, 4, 5, 9]])
    assert msg == "hinge 7 (edge 3-4): wing triangle (4, 3, 9) has zero area"
    assert "hinge 2 [2, 3, 12, 7]: vertex index 12 out of range 0..9" == _err(X, good[:2] + [[2, 3, 12, 7]])
    assert "-1.0" in _err(X, good, B=-1.0) and "B" in _err(X, good, B=-1.0)
    assert "finite" in _err(X, good, B=float("inf"))
    Bs = np.ones(len(good))
    Bs[4] = np.nan
    assert _err(X, good, B=Bs).startswith("hinge 4 (edge 0-2): bending modulus B = nan")
    assert "four distinct" in _err(X, [[0, 1, 2, 1]])
    assert "unknown bending variant 'plates'" in _err(X, good, variant="plates")
    tb = np.zeros(len(good))
    tb[3] = np.inf
    assert _err(X, good, theta_bar=tb).startswith("hinge 3 (edge 3-4): rest angle")
    assert issubclass(BendingError, ValueError) and issubclass(BendingError, ModelError)
    # B = 0 is allowed (no bending)
    assert BendingEnergy(X, good, 0.0).energy(X + 0.1) == 0.0


def test_no_hinges_is_a_zero_energy():
    X = np.eye(3)
    E = BendingEnergy(X, np.zeros((0, 4), dtype=int), 1.0)
    f = np.zeros((3, 3))
    E.add_forces(X, f)
    assert E.energy(X) == 0.0 and not f.any() and E.angles(X).shape == (0,)
