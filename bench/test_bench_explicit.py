"""Timed: one explicit (symplectic Euler) cloth step, engine against the numpy baseline.

Run the timings with ``python -m pytest bench --benchmark-enable`` (or ``python -m bench``);
in the default test run (benchmarks disabled) each body runs once as a smoke test.
Sizes: ELASTIC_BENCH_SIZES (comma-separated vertices per side; default 32,64,128).
"""
import os

import numpy as np
import pytest
import taichi as ti

from bench.baseline import NumpyCloth
from engine.integrators import get as integrator
from engine.scenes import cloth

SIZES = [int(s) for s in os.environ.get("ELASTIC_BENCH_SIZES", "32,64,128").split(",")]


@pytest.fixture(scope="module", params=SIZES, ids=lambda n: f"{n}x{n}")
def scene(request):
    c = cloth(request.param, E=1e3, rho=0.1, B=1e-4)
    return c


def _dt(c):
    return 1e-5  # far below the stable dt of every size here: timing only


@pytest.mark.parametrize("bending", [True, False], ids=["springs+bending", "springs"])
def test_engine_symplectic_step(benchmark, scene, bending):
    c = scene if bending else cloth(int(round(np.sqrt(scene.model.n))), E=1e3, rho=0.1, B=0.0)
    st = c.model.make_state()
    step = integrator("symplectic-euler")
    dt = _dt(c)

    def run():
        step.step(c.model, st, dt, 1)
        ti.sync()

    run()  # compile and warm up outside the clock
    benchmark.extra_info.update(vertices=c.model.n, edges=c.springs.m, kind="engine")
    benchmark.pedantic(run, rounds=30, iterations=5, warmup_rounds=2)
    assert np.all(np.isfinite(st.numpy().x))


def test_numpy_symplectic_step(benchmark, scene):
    c = scene
    base = NumpyCloth(c.model, c.springs, c.bending)
    x, v = c.model.X.copy(), np.zeros((c.model.n, 3))
    benchmark.extra_info.update(vertices=c.model.n, edges=c.springs.m, kind="numpy")
    benchmark.pedantic(lambda: base.symplectic_euler(x, v, _dt(c), 1), rounds=10, iterations=2, warmup_rounds=1)
    assert np.all(np.isfinite(x))
