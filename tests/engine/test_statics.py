"""Static equilibrium (engine.statics): hanging chain against the exact nodal solution, pin
reactions, a cloth hanging from two corners, a stretched sheet, non-convergence reporting."""
import numpy as np
import pytest

from engine import mesh
from engine.energies.bending import BendingEnergy
from engine.energies.springs import SpringEnergy
from engine.solvers import SolverError
from engine.fields import vec3_ndarray
from engine.model import Model
from engine.statics import solve_static


def hanging_chain(n=20, L=2.0, rho=0.5, E=30.0, g=9.81):
    """n springs hanging down (-z) from a pin at the top; 1D springs W = 1/2 E (l/h - 1)^2 h
    (k = E, c = k h), lumped masses rho h (half at the ends)."""
    h = L / n
    X = np.zeros((n + 1, 3))
    X[:, 2] = -np.arange(n + 1) * h
    mass = np.full(n + 1, rho * h)
    mass[[0, -1]] = rho * h / 2
    edges = np.stack([np.arange(n), np.arange(1, n + 1)], 1)
    model = Model.from_springs(X, edges, k=E, mass=mass, pinned=[0], gravity=[0, 0, -g])
    return model, np.arange(n + 1) * h


@pytest.mark.parametrize("solver", ["cholesky", "pcg"])
def test_hanging_chain_matches_exact_nodal_solution(solver):
    L, rho, E, g = 2.0, 0.5, 30.0, 9.81
    model, p = hanging_chain(20, L, rho, E, g)
    res = solve_static(model, solver=solver)
    u = -(res.x[:, 2] - model.X[:, 2])                       # downward displacement
    exact = rho * g / E * (L * p - p ** 2 / 2)                # u(p) = (rho g/E)(L p - p^2/2)
    assert res.converged and res.residual <= 1e-10 and res.iterations <= 6, res
    assert np.abs(u - exact).max() <= 1e-8 * exact.max()
    assert np.abs(res.x[:, :2]).max() == 0.0                  # stays on its axis
    # the pin carries the whole weight (including its own lumped half-segment)
    weight = rho * L * g
    assert res.reactions[0] == pytest.approx([0.0, 0.0, weight], rel=1e-12, abs=1e-12 * weight)
    assert np.all(res.reactions[1:] == 0.0)
    assert res.history[0] == 1.0 and res.history[-1] == res.residual


def _cloth(N=8, E=1e3, B=1e-3):
    m3 = mesh.embed_3d(mesh.right_triangle_grid(N, N, 1.0, 1.0))
    X = m3.vertices
    model = Model(X, mass=mesh.lumped_masses(m3, 0.2), pinned=[0, N - 1], gravity=[0, 0, -9.81])
    model.add_energy(SpringEnergy.from_rest(X, m3.edges, c=E * mesh.edge_measure(m3)))
    model.add_energy(BendingEnergy.from_mesh(m3, B=B))
    return model


def test_cloth_pinned_at_two_corners_reactions_carry_the_weight():
    model = _cloth()
    res = solve_static(model, max_iter=150)
    weight = model.mass.sum() * 9.81
    assert res.converged and res.residual <= 1e-10
    total = res.reactions.sum(axis=0)
    assert total[2] == pytest.approx(weight, rel=1e-10)
    assert np.abs(total[:2]).max() <= 1e-10 * weight
    assert np.array_equal(res.x[model.pinned], model.X[model.pinned])
    assert res.x[model.free, 2].max() < 0.0 and res.x[:, 2].min() < -0.3   # it hangs
    # independent check of equilibrium with the model's own force kernel
    f = vec3_ndarray(model.n)
    model.forces(vec3_ndarray(model.n, res.x), f)
    net = f.to_numpy()[model.free]
    assert np.abs(net).max() <= 1e-10 * (model.mass.max() * 9.81) * 1.01


def test_stretched_sheet_without_gravity():
    """Left edge pinned at x = 0, right edge pinned and pulled to x = W (1 + eps): the pins' forces
    balance (no external load), and at small strain the pull is linear in eps."""
    N = 7
    m3 = mesh.embed_3d(mesh.right_triangle_grid(N, N, 1.0, 1.0))
    X = m3.vertices
    left = np.flatnonzero(X[:, 0] == 0.0)
    right = np.flatnonzero(X[:, 0] == 1.0)
    model = Model(X, mass=mesh.lumped_masses(m3, 0.2), pinned=np.concatenate([left, right]))
    model.add_energy(SpringEnergy.from_rest(X, m3.edges, c=1e3 * mesh.edge_measure(m3)))
    pulls = []
    for eps in (1e-4, 2e-4):
        x0 = X.copy()
        x0[right, 0] *= 1.0 + eps
        res = solve_static(model, x0=x0)
        R = res.reactions
        assert res.converged
        assert np.abs(R.sum(axis=0)).max() <= 1e-10 * np.abs(R).max()
        assert np.abs(res.x[:, 2]).max() == 0.0  # in-plane
        assert np.array_equal(res.x[right], x0[right])
        pulls.append(R[right, 0].sum())          # the sheet pulls back (-x): the pins hold it with +x
    assert pulls[0] > 0.0
    assert pulls[1] / pulls[0] == pytest.approx(2.0, rel=1e-3)


def test_nonconvergence_is_reported():
    model = _cloth(6)
    with pytest.raises(SolverError) as exc:
        solve_static(model, max_iter=2)
    msg = str(exc.value)
    assert "\n" not in msg and "did not converge" in msg and "tol 1.0e-10" in msg and "2 Newton iterations" in msg
    res = solve_static(model, max_iter=2, raise_on_failure=False)
    assert not res.converged and res.iterations == 2 and res.residual > 1e-10 and "max_iter" in res.message


def test_unloaded_model_is_already_in_equilibrium():
    model, _ = hanging_chain()
    free_model = Model.from_springs(model.X, model.springs.edges_np, k=30.0, mass=1.0, pinned=[0])
    res = solve_static(free_model)
    assert res.converged and res.iterations == 0 and res.residual == 0.0
    assert np.array_equal(res.x, free_model.X) and np.all(res.reactions == 0.0)
