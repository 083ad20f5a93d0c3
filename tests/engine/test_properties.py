"""Property-based checks (hypothesis) of the spring and bending energies on random meshes.

Every example is a jittered right-triangle grid of random size (2..5 x 2..5 vertices, any of the
three diagonal patterns, random cell shape), optionally curved out of plane as its rest shape
(bending then measures its rest angles on it), with random stiffness and a random deformation
(in-plane and out-of-plane noise plus a smooth bend). For the spring energy and every bending
variant (notes, bridson, discrete-shells) the checks every energy must pass:

- the energy and every per-element energy are >= 0, > 0 when deformed, ~0 at rest (also
  after a rigid motion of the rest shape), and the forces vanish at rest;
- a random rotation + translation leaves the energy unchanged to round-off and rotates the
  forces with the body;
- the forces are minus the central finite-difference gradient of the energy (f64);
- the Hessians of ``model.dense_hessian`` (exact and PSD-projected) are symmetric, the
  exact one matches finite differences of the forces, both agree with the Hessian-vector
  product the solvers use, and the projected one is positive semi-definite
  (smallest eigenvalue >= -1e-9 x largest).

Taichi kernels take ndarrays, so they compile once for all mesh sizes.
"""
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings, strategies as st

from engine import mesh as meshes
from engine.energies.bending import VARIANTS, BendingEnergy
from engine.fields import vec3_ndarray, zero_vec3
from engine.model import Model

ENERGIES = ("springs",) + VARIANTS
SETTINGS = dict(deadline=None, suppress_health_check=[HealthCheck.too_slow], print_blob=True)


# --------------------------------------------------------------------------------------------
# random scenes
# --------------------------------------------------------------------------------------------

class Scene:
    """A model with one energy (springs or one bending variant), its rest shape X, a deformed
    shape x, and the scales that make tolerances dimensionless."""

    def __init__(self, kind, X, mesh, x, coef, rng):
        self.kind, self.X, self.x, self.rng = kind, X, x, rng
        self.h = float(mesh.rest_lengths.min())  # shortest rest edge (m)
        if kind == "springs":
            c = coef * mesh.edge_measure
            self.model = Model.from_springs(X, mesh.edges, c=c)
            self.stiff = float(np.max(c / mesh.rest_lengths ** 2))  # largest c/L^2 (N/m)
            self.element_energies = self.model.springs.edge_energies
        else:
            curved = bool(np.ptp(X[:, 2]) > 0)
            bend = BendingEnergy(X, mesh.hinges, coef, variant=kind, from_rest=curved)
            self.model = Model(X, mass=1.0, energies=[bend])
            self.stiff = float(bend.k.max()) / self.h ** 2  # k_e/h^2 (N/m)
            self.element_energies = bend.hinge_energies
        self.energy = self.model.energies[0]
        self.n = len(X)

    def W(self, x):
        return self.model.elastic_energy(vec3_ndarray(self.n, x))

    def f(self, x):
        out = vec3_ndarray(self.n)
        zero_vec3(out)
        self.model.add_elastic_forces(vec3_ndarray(self.n, x), out)
        return out.to_numpy().astype(np.float64)

    def H(self, x, psd):
        return self.model.dense_hessian(vec3_ndarray(self.n, x), psd=psd)

    def Hv(self, x, v, psd):
        out = vec3_ndarray(self.n)
        zero_vec3(out)
        self.model.add_hessian_product(vec3_ndarray(self.n, x), vec3_ndarray(self.n, v), out, psd)
        return out.to_numpy().astype(np.float64).reshape(-1)


def random_rotation(rng) -> np.ndarray:
    Q, R = np.linalg.qr(rng.standard_normal((3, 3)))
    Q = Q * np.sign(np.diag(R))
    if np.linalg.det(Q) < 0:
        Q[:, 0] = -Q[:, 0]
    return Q


def _triangle_areas(x, T):
    return 0.5 * np.linalg.norm(np.cross(x[T[:, 1]] - x[T[:, 0]], x[T[:, 2]] - x[T[:, 0]]), axis=1)


@st.composite
def scenes(draw, kind):
    nx, ny = draw(st.integers(2, 5)), draw(st.integers(2, 5))
    diagonals = draw(st.sampled_from(["one-way", "alternating", "crossed"]))
    width, height = draw(st.floats(0.5, 2.0)), draw(st.floats(0.5, 2.0))
    amplitude = draw(st.floats(0.0, 0.25))
    seed = draw(st.integers(0, 2 ** 32 - 1))
    rest_bend = draw(st.sampled_from([0.0, 0.0, 0.15, 0.4]))  # rest shape: flat or curved
    noise = draw(st.floats(0.01, 0.2))        # deformation noise, fraction of the shortest edge
    bend = draw(st.floats(0.0, 0.5))          # smooth out-of-plane bend of the deformation (m)
    stretch = draw(st.floats(0.8, 1.25))      # uniform in-plane stretch/compression
    coef = 10.0 ** draw(st.floats(-2.0, 4.0))  # E (N/m) or B (N m)

    m2 = meshes.jitter(meshes.right_triangle_grid(nx, ny, width, height, diagonals), amplitude, seed)
    m3 = meshes.embed_3d(m2, "xy")
    rng = np.random.default_rng(seed)
    X = np.array(m3.vertices)
    X[:, 2] = rest_bend * np.sin(2.0 * X[:, 0] + 1.0) * np.cos(1.5 * X[:, 1])
    h = float(m3.rest_lengths.min())
    x = X.copy()
    x[:, :2] *= stretch
    x[:, 2] += bend * np.sin(3.0 * X[:, 0] + rng.uniform(0, 6)) * np.sin(2.0 * X[:, 1] + rng.uniform(0, 6))
    x += noise * h * rng.standard_normal(x.shape)
    # keep every triangle a proper triangle and every dihedral angle away from +-pi (where the
    # angle wraps): the energies are smooth only there
    T = m3.triangles
    assume(np.all(_triangle_areas(x, T) > 0.2 * _triangle_areas(X, T)))
    scene = Scene(kind, X, m3, x, coef, rng)
    if kind != "springs":
        assume(np.all(np.abs(scene.energy.angles(x)) < 2.5))
    return scene


# --------------------------------------------------------------------------------------------
# properties
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("kind", ENERGIES)
@settings(max_examples=12, **SETTINGS)
@given(data=st.data())
def test_energy_is_nonnegative_positive_when_deformed_and_zero_at_rest(kind, data):
    s = data.draw(scenes(kind))
    scale = s.stiff * s.h ** 2  # an energy scale (J): one element strained by 100%
    W = s.W(s.x)
    assert W > 0.0 and np.all(s.element_energies(vec3_ndarray(s.n, s.x)) >= 0.0)
    assert math.isclose(W, float(np.sum(s.element_energies(vec3_ndarray(s.n, s.x)))), rel_tol=1e-12)
    assert abs(s.W(s.X)) <= 1e-20 * scale
    assert np.all(s.element_energies(vec3_ndarray(s.n, s.X)) >= 0.0)
    assert np.abs(s.f(s.X)).max() <= 1e-10 * s.stiff * s.h
    # rest shape moved rigidly: still no energy, no force
    R, t = random_rotation(s.rng), 5.0 * s.rng.standard_normal(3)
    Xm = s.X @ R.T + t
    assert abs(s.W(Xm)) <= 1e-18 * scale
    assert np.abs(s.f(Xm)).max() <= 1e-8 * s.stiff * s.h


@pytest.mark.parametrize("kind", ENERGIES)
@settings(max_examples=12, **SETTINGS)
@given(data=st.data())
def test_rigid_motion_leaves_energy_unchanged_and_rotates_forces(kind, data):
    s = data.draw(scenes(kind))
    R = random_rotation(s.rng)
    t = data.draw(st.floats(0.0, 10.0)) * s.rng.standard_normal(3)
    xm = s.x @ R.T + t
    W, Wm = s.W(s.x), s.W(xm)
    assert abs(Wm - W) <= 1e-9 * W + 1e-14 * s.stiff * s.h ** 2
    f, fm = s.f(s.x), s.f(xm)
    assert np.abs(fm - f @ R.T).max() <= 1e-7 * np.abs(f).max() + 1e-12 * s.stiff * s.h
    # a rigid motion exerts no net force and no net torque
    assert np.abs(f.sum(axis=0)).max() <= 1e-9 * np.abs(f).max()
    torque = np.cross(s.x - s.x.mean(axis=0), f).sum(axis=0)
    assert np.abs(torque).max() <= 1e-9 * np.abs(f).max() * np.ptp(s.x, axis=0).max()


@pytest.mark.parametrize("kind", ENERGIES)
@settings(max_examples=10, **SETTINGS)
@given(data=st.data())
def test_forces_are_minus_the_finite_difference_gradient(kind, data):
    s = data.draw(scenes(kind))
    eps = 1e-6 * s.h
    x = s.x
    g = np.zeros_like(x)
    for i in range(s.n):
        for a in range(3):
            xp, xm = x.copy(), x.copy()
            xp[i, a] += eps
            xm[i, a] -= eps
            g[i, a] = (s.W(xp) - s.W(xm)) / (2 * eps)
    f = s.f(x)
    err = np.abs(f + g).max()
    assert err <= 1e-6 * np.abs(f).max() + 1e-9 * s.W(x) / s.h, (err, np.abs(f).max())


@pytest.mark.parametrize("kind", ENERGIES)
@settings(max_examples=10, **SETTINGS)
@given(data=st.data())
def test_hessians_are_symmetric_consistent_and_the_projected_one_is_psd(kind, data):
    s = data.draw(scenes(kind))
    x = s.x
    H = s.H(x, psd=False)
    Hp = s.H(x, psd=True)
    for M in (H, Hp):
        assert np.abs(M - M.T).max() <= 1e-12 * np.abs(M).max()
    # the projected Hessian is positive semi-definite
    lam = np.linalg.eigvalsh(0.5 * (Hp + Hp.T))
    assert lam[0] >= -1e-9 * lam[-1], (lam[0], lam[-1])
    # the exact Hessian is the derivative of minus the forces (central differences)
    eps = 1e-6 * s.h
    Hfd = np.zeros_like(H)
    for i in range(s.n):
        for a in range(3):
            xp, xm = x.copy(), x.copy()
            xp[i, a] += eps
            xm[i, a] -= eps
            Hfd[:, 3 * i + a] = -(s.f(xp) - s.f(xm)).reshape(-1) / (2 * eps)
    assert np.abs(Hfd - H).max() <= 1e-5 * np.abs(H).max()
    # the Hessian-vector products the solvers use agree with the assembled matrices
    v = s.rng.standard_normal(x.shape)
    for M, psd in ((H, False), (Hp, True)):
        assert np.abs(s.Hv(x, v, psd) - M @ v.reshape(-1)).max() <= 1e-10 * np.abs(M).max() * np.abs(v).max()
