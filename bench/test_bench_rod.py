"""Timed: the 1D rod (engine.rod.Rod: many steps in one serial kernel) with symplectic Euler at
engine.constants.CFL_SAFETY of its stable dt and backward Euler (Thomas algorithm) at
dt = 10 h/c; the same rod as a spring-chain Model stepped by the general backward Euler (PCG,
Cholesky); and the numpy (symplectic Euler) and scipy (``solve_banded`` backward Euler)
baselines."""
import numpy as np
import pytest

from bench import config, traffic
from bench.baseline import NumpyRod
from bench.timing import measure, sync
from engine import runtime
from engine.constants import CFL_SAFETY
from engine.fields import float_dtype
from engine.integrators import Stepper

SIZES = config.sizes("rod")


def _steps(nodes):
    return int(max(5, min(200, 2_000_000 // nodes)))


def _dts(rod):
    h = float(rod.h[0])
    c = float(np.sqrt(rod.E[0] / rod.rho[0]))
    return CFL_SAFETY * rod.stable_dt(), config.ROD_IMPLICIT_NU * h / c


def _fb():
    return np.dtype(float_dtype()).itemsize


@pytest.mark.parametrize("method", ["symplectic-euler", "backward-euler"])
@pytest.mark.parametrize("nodes", SIZES)
def test_engine_rod_steps(benchmark, nodes, method):
    rod, u0 = config.rod_scene(nodes)
    st = rod.new_state(u0)
    dt = _dts(rod)[0 if method == "symplectic-euler" else 1]
    k = _steps(nodes)

    def run():
        rod.run(st, dt, k, method)
        sync()

    kind = "rod_explicit_step" if method == "symplectic-euler" else "rod_implicit_step"
    measure(benchmark, run, steps=k, group="rod-step", impl="engine-rod" if method == "symplectic-euler" else
            "engine-rod-thomas", method=method, n=nodes, dt=dt, bytes=traffic.kernel_bytes(kind, nodes, fb=_fb()))
    assert np.all(np.isfinite(st.x.to_numpy()))


@pytest.mark.parametrize("solver", ["pcg", "cholesky"])
@pytest.mark.parametrize("nodes", SIZES)
def test_engine_rod_model_backward_euler(benchmark, nodes, solver):
    rod, u0 = config.rod_scene(nodes)
    model = rod.model
    x0 = np.asarray(model.X, dtype=np.float64).copy()
    x0[:, 0] += u0
    st = model.make_state(x0)
    dt = _dts(rod)[1]
    iters = []

    def reset():
        st.assign(x0, np.zeros_like(x0), 0.0)
    reset.state = st
    be, tol, failed = config.backward_euler_for(model, reset, dt, solver, runtime.current().fp)
    if be is None:
        pytest.skip(f"{solver} reached none of the relative tolerances {failed} in f32")

    stepper = Stepper(model, be)

    def run():
        stepper.advance(st, dt)
        sync()
        iters.append(stepper.last_info.linear_iterations[0])

    measure(benchmark, run, setup=reset, group="rod-step", impl="engine-model-" + solver, method="backward-euler",
            n=nodes, dt=dt, solver=solver, tol=tol, tol_failed=failed)
    it = int(np.median(iters))
    benchmark.extra_info["linear_iterations"] = it
    if solver == "pcg":
        benchmark.extra_info["bytes"] = traffic.implicit_step_bytes(nodes, nodes - 1, 0, it, _fb())


@pytest.mark.parametrize("method", ["symplectic-euler", "backward-euler"])
@pytest.mark.parametrize("nodes", SIZES)
def test_numpy_rod_steps(benchmark, nodes, method):
    if config.config_name() != "t2-f64" and config.profile() != "smoke":
        pytest.skip("the numpy/scipy baselines are timed in the 2-thread f64 process only")
    rod, u0 = config.rod_scene(nodes)
    base = NumpyRod(rod)
    x, v = rod.p + u0, np.zeros(rod.n)
    dt = _dts(rod)[0 if method == "symplectic-euler" else 1]
    k = _steps(nodes)
    fn = base.symplectic_euler if method == "symplectic-euler" else base.backward_euler
    measure(benchmark, lambda: fn(x, v, dt, k), steps=k, warmup=1, group="rod-step",
            impl="numpy" if method == "symplectic-euler" else "scipy-banded", method=method, n=nodes, dt=dt)
    assert np.all(np.isfinite(x))
