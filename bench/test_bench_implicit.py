"""Timed: one backward-Euler cloth step (Baraff-Witkin: one Newton iteration, no line search) at
dt = 1/60 s with the engine's PCG and Cholesky solvers, against the same step in numpy +
scipy.sparse (assembly + Jacobi-preconditioned CG at the same relative tolerance).

Every timed call starts from the same state (config.cloth_start_state, reset outside the clock).
The engine runs at tol 1e-5 in f64 (in f32, which cannot reach 1e-5, the first of 1e-4, 3e-4, 1e-3
that it reaches; recorded); the scipy baseline is f64 at 1e-5 and is timed in the 2-thread f64
process only.
"""
import numpy as np
import pytest

from bench import config, traffic
from bench.baseline import NumpyCloth
from bench.timing import measure, sync
from engine import runtime
from engine.fields import float_dtype

SIZES = config.sizes("implicit")
DT = config.IMPLICIT_DT
_scipy_seconds: dict = {}  # side -> seconds per baseline step, to extrapolate the next size


def _info(c):
    return dict(side=int(round(np.sqrt(c.model.n))), n=c.model.n, m=c.springs.m, h=c.bending.n_hinges,
                dt=DT, E=config.CLOTH_E, model="springs+bending")


@pytest.mark.parametrize("impl", ["pcg", "cholesky", "scipy"])
@pytest.mark.parametrize("side", SIZES)
def test_backward_euler_step(benchmark, side, impl):
    """The engine's two solvers and the scipy baseline for the same cloth run back to back (adjacent
    in time, so that a shared machine's load changes little between them)."""
    if impl == "scipy":
        return _scipy_step(benchmark, side)
    solver = impl
    c = config.cloth_scene(side, True)
    x0, v0 = config.cloth_start_state(c)
    st = c.model.make_state(x0, v0)
    iters = []

    def reset():
        st.assign(x0, v0, 0.0)
    reset.state = st
    be, tol, failed = config.backward_euler_for(c.model, reset, DT, solver, runtime.current().fp)
    if be is None:
        pytest.skip(f"{solver} reached none of the relative tolerances {failed} in f32")

    def run():
        be.advance(c.model, st, DT)
        sync()
        iters.append(be.last_info.linear_iterations[0])

    info = _info(c)
    measure(benchmark, run, setup=reset, group="cloth-implicit-step", impl="engine-" + solver, solver=solver,
            tol=tol, tol_failed=failed, **info)
    it = int(np.median(iters))
    benchmark.extra_info["linear_iterations"] = it
    if solver == "pcg":
        fb = np.dtype(float_dtype()).itemsize
        benchmark.extra_info["bytes"] = traffic.implicit_step_bytes(info["n"], info["m"], info["h"], it, fb)
        benchmark.extra_info["bytes_per_iteration"] = traffic.kernel_bytes("cg_iteration", info["n"], info["m"],
                                                                           info["h"], fb)
    assert np.all(np.isfinite(st.numpy().x))


def _scipy_step(benchmark, side):
    if config.config_name() != "t2-f64" and config.profile() != "smoke":
        pytest.skip("the numpy + scipy baseline is timed in the 2-thread f64 process only")
    if side > config.SCIPY_MAX_SIDE[config.profile()]:
        pytest.skip(f"scipy baseline not timed above {config.SCIPY_MAX_SIDE[config.profile()]}^2 in this profile")
    c = config.cloth_scene(side, True)
    base = NumpyCloth(c.model, c.springs, c.bending)
    x0, v0 = config.cloth_start_state(c)
    x, v = x0.copy(), v0.copy()
    split = []

    def reset():
        x[...] = x0
        v[...] = v0

    def run():
        base.backward_euler(x, v, DT, tol=config.IMPLICIT_TOL[64])
        split.append((base.last_assembly_s, base.last_solve_s, base.last_iterations))

    prev = max((k for k in _scipy_seconds if k < side), default=None)
    expect = None if prev is None else _scipy_seconds[prev] * (side / prev) ** 3  # iterations ~ side, work ~ side^2
    measure(benchmark, run, setup=reset, warmup=0, expect_s=expect, group="cloth-implicit-step", impl="scipy",
            solver="scipy-cg-jacobi", tol=config.IMPLICIT_TOL[64], **_info(c))
    _scipy_seconds[side] = float(np.median([a + b for a, b, _ in split]))
    a = np.median(np.asarray(split), axis=0)
    benchmark.extra_info.update(assembly_s=float(a[0]), solve_s=float(a[1]), linear_iterations=int(a[2]))
    assert np.all(np.isfinite(x))
