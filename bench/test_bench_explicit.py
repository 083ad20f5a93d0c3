"""Timed: the explicit (symplectic Euler) cloth step, engine against the numpy baseline, and the
kernels it is made of, with the force-kernel variants (parallel atomics, serialized scatter, the
engine's CSR gather).

Run the timings with ``python -m bench`` (or ``python -m pytest bench --benchmark-enable
--benchmark-only``); in the default test run (benchmarks disabled) each body runs once on a
tiny cloth as a smoke test.  What each body computes is checked in bench/test_correctness.py.
"""
import numpy as np
import pytest

from bench import config, traffic
from bench.baseline import NumpyCloth
from bench.timing import measure, sync
from bench.variants import bending_variant, spring_variant
from engine.energies.bending import gather_hinge_vectors_kernel, hinge_forces_kernel
from engine.integrators import get as integrator
from engine.integrators import kernels as step_kernels
from engine.fields import float_dtype, scratch_vec3, zero_vec3

SIZES = config.sizes("cloth")
DT = 1e-5  # below the stable dt of every cloth here (E = 1e3): timing only, the cost does not depend on dt
MODELS = {"springs+bending": True, "springs": False}


def _fb():
    return np.dtype(float_dtype()).itemsize


def _info(c, bending):
    return dict(side=int(round(np.sqrt(c.model.n))), n=c.model.n, m=c.springs.m,
                h=c.bending.n_hinges if (bending and c.bending is not None) else 0)


@pytest.mark.parametrize("impl", ["engine", "numpy"])
@pytest.mark.parametrize("model", list(MODELS))
@pytest.mark.parametrize("side", SIZES)
def test_explicit_step(benchmark, side, model, impl):
    """Engine and numpy baseline for the same cloth run back to back (adjacent in time, so that a
    shared machine's load changes little between the two)."""
    bending = MODELS[model]
    c = config.cloth_scene(side, bending)
    x0, v0 = config.cloth_start_state(c)
    info = _info(c, bending)
    if impl == "numpy":
        base = NumpyCloth(c.model, c.springs, c.bending if bending else None)
        x, v = x0.copy(), v0.copy()
        measure(benchmark, lambda: base.symplectic_euler(x, v, DT, 1), group="cloth-explicit-step", impl="numpy",
                model=model, kernel="explicit_step", **info)
        assert np.all(np.isfinite(x))
        return
    st = c.model.make_state(x0, v0)
    step = integrator("symplectic-euler")

    def run():
        step.step(c.model, st, DT, 1)
        sync()

    measure(benchmark, run, group="cloth-explicit-step", impl="engine", model=model, kernel="explicit_step",
            bytes=traffic.kernel_bytes("explicit_step", info["n"], info["m"], info["h"], _fb()), **info)
    assert np.all(np.isfinite(st.numpy().x))


@pytest.mark.parametrize("model", list(MODELS))
@pytest.mark.parametrize("side", SIZES)
def test_explicit_block(benchmark, side, model):
    """config.EXPLICIT_BLOCK steps per call, as a lesson takes them between two recorded frames: the
    engine takes them in one launch (cloth_steps) where it can; the peers are timed over the same
    block (test_peers_explicit.py, group "cloth-explicit-block")."""
    bending = MODELS[model]
    c = config.cloth_scene(side, bending)
    x0, v0 = config.cloth_start_state(c)
    info = _info(c, bending)
    st = c.model.make_state(x0, v0)
    step = integrator("symplectic-euler")
    k = config.EXPLICIT_BLOCK

    def run():
        step.step(c.model, st, DT, k)
        sync()

    measure(benchmark, run, group="cloth-explicit-block", steps=k, impl="engine", model=model, kernel="explicit_step",
            bytes=traffic.kernel_bytes("explicit_step", info["n"], info["m"], info["h"], _fb()), **info)
    assert np.all(np.isfinite(st.numpy().x))


KERNELS = ["zero", "spring_gather", "spring_atomic", "spring_serial", "hinge_pass1", "hinge_gather",
           "bending_gather", "bending_atomic", "bending_serial", "update"]


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("side", SIZES)
def test_force_kernels(benchmark, side, kernel):
    """One call of each kernel of the explicit step, and of the force-kernel variants."""
    c = config.cloth_scene(side, True)
    x0, v0 = config.cloth_start_state(c)
    st = c.model.make_state(x0, v0)
    m = c.model
    f = scratch_vec3(m, "bench_f")
    sp, be = c.springs, c.bending
    if kernel == "zero":
        call = lambda: zero_vec3(f)  # noqa: E731
    elif kernel.startswith("spring_"):
        add = spring_variant(kernel.split("_")[1])
        call = lambda: add(st.x, sp, f)  # noqa: E731
    elif kernel.startswith("bending_"):
        add = bending_variant(kernel.split("_")[1])
        call = lambda: add(st.x, be, f)  # noqa: E731
    elif kernel == "hinge_pass1":
        call = lambda: hinge_forces_kernel(st.x, *be.hinge_args(), be.per_hinge_vec)  # noqa: E731
    elif kernel == "hinge_gather":
        call = lambda: gather_hinge_vectors_kernel(be.per_hinge_vec, be.offsets, be.entries, f)  # noqa: E731
    else:  # update (dt = 0: the state stays put)
        zero_vec3(f)
        call = lambda: step_kernels.update_kernel(st.x, st.v, f, f, m.inv_mass_nd, m.gravity_vec, 0.0,  # noqa: E731
                                                  step_kernels.SYMPLECTIC_EULER, step_kernels.STEP)

    def run():
        call()
        sync()

    info = _info(c, True)
    measure(benchmark, run, group="cloth-force-kernels", impl="engine" if kernel in (
        "zero", "spring_gather", "hinge_pass1", "hinge_gather", "bending_gather", "update") else kernel.split("_")[1],
            kernel=kernel, bytes=traffic.kernel_bytes(kernel, info["n"], info["m"], info["h"], _fb()), **info)
