"""One-launch symplectic-Euler step (engine.integrators.kernels.one_launch_step): the same arithmetic as the
generic five-kernel path, so the states agree bit for bit."""
import numpy as np
import pytest

from engine.integrators.explicit import SymplecticEuler, one_launch_plan as fused_symplectic_step
from engine.stability import stable_dt_estimate
from engine.model import Model
from engine.scenes import cloth


def run(model, v0, dt, n, fused):
    st = model.make_state(None, v0)
    SymplecticEuler(fused).step(model, st, dt, n)
    s = st.numpy()
    return s.x, s.v, st.t


@pytest.mark.parametrize("B,variant", [(1e-3, "notes"), (1e-3, "discrete-shells"), (0.0, "notes")])
def test_fused_step_is_bitwise_the_generic_step(B, variant):
    c = cloth(12, B=B, variant=variant)
    model = c.model
    assert fused_symplectic_step(model) is not None
    v0 = 0.05 * np.random.default_rng(3).standard_normal((model.n, 3))
    dt = 0.5 * stable_dt_estimate(model)
    xa, va, ta = run(model, v0, dt, 150, True)
    xb, vb, tb = run(model, v0, dt, 150, False)
    assert np.array_equal(xa, xb) and np.array_equal(va, vb) and ta == tb
    assert np.abs(xa - model.X).max() > 1e-3  # it moved: the comparison is not vacuous
    pinned = model.pinned
    assert np.array_equal(xa[pinned], model.X[pinned]) and not va[pinned].any()


def test_models_without_springs_first_take_the_generic_path():
    c = cloth(6, B=1e-3)
    bending_only = Model(c.model.X, c.model.mass, c.model.pinned, c.model.gravity)
    bending_only.add_energy(c.bending)
    assert fused_symplectic_step(bending_only) is None
    v0 = 0.01 * np.ones((bending_only.n, 3))
    x, v, _ = run(bending_only, v0, 1e-4, 20, True)  # still steps, on the generic path:
    xg, vg, _ = run(bending_only, v0, 1e-4, 20, False)  # bitwise what the generic path gives
    assert np.array_equal(x, xg) and np.array_equal(v, vg)
    assert np.abs(x - bending_only.X).max() > 0
