"""The benchmarks compute what they claim: engine and numpy baseline agree on the same input.

Runs in CI (no timing); the timed benchmarks live in bench/test_bench_*.py.
"""
import numpy as np
import pytest

from bench.baseline import NumpyCloth
from engine.integrators import get as integrator
from engine.model import vec3_ndarray
from engine.scenes import cloth


@pytest.mark.parametrize("B", [0.0, 1e-3])
def test_numpy_forces_equal_engine_forces_on_deformed_cloth(B):
    c = cloth(12, E=1e3, rho=0.1, B=B)
    rng = np.random.default_rng(0)
    x = c.model.X + 0.01 * rng.standard_normal((c.model.n, 3))
    f = vec3_ndarray(c.model.n)
    c.model.forces(vec3_ndarray(c.model.n, x), f)
    ref = NumpyCloth(c.model, c.springs, c.bending).forces(x)
    assert np.max(np.abs(f.to_numpy() - ref)) <= 1e-10 * np.max(np.abs(ref))


def test_numpy_and_engine_symplectic_steps_agree():
    c = cloth(12, E=1e3, rho=0.1, B=1e-3)
    dt = 0.5 * 1e-3
    st = c.model.make_state()
    integrator("symplectic-euler").step(c.model, st, dt, 50)
    x, v = c.model.X.copy(), np.zeros((c.model.n, 3))
    NumpyCloth(c.model, c.springs, c.bending).symplectic_euler(x, v, dt, 50)
    got = st.numpy()
    assert np.max(np.abs(got.x - x)) <= 1e-10 * np.max(np.abs(x - c.model.X))
    assert np.max(np.abs(got.v - v)) <= 1e-9 * np.max(np.abs(v))
