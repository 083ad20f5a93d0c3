"""Timed: the explicit (symplectic Euler) cloth step, engine against Numba, Warp and the numpy
baseline (bench/peers, bench/baseline.py) interleaved in rounds (bench/interleave.py), and the
kernels it is made of, with the force-kernel variants (parallel atomics, serialized scatter, the
engine's CSR gather).

Run the timings with ``python -m bench`` (or ``python -m pytest bench --benchmark-enable
--benchmark-only``); in the default test run (benchmarks disabled) each body runs once on a
tiny cloth as a smoke test.  What each body computes is checked in bench/test_correctness.py.
"""
import numpy as np
import pytest

from bench import config, peers, traffic
from bench.baseline import NumpyCloth
from bench.interleave import Contender, measure_row
from bench.timing import measure, sync
from bench.variants import bending_variant, spring_variant
from engine.energies.bending_kernels import gather_hinge_vectors_kernel, hinge_forces_kernel
from engine.integrators import Stepper
from engine.integrators import kernels as step_kernels
from engine.fields import float_dtype, vec3_ndarray, zero_vec3

SIZES = config.sizes("cloth")
DT = 1e-5  # below the stable dt of every cloth here (E = 1e3): timing only, the cost does not depend on dt
MODELS = {"springs+bending": True, "springs": False}


def _fb():
    return np.dtype(float_dtype()).itemsize


def _info(c, bending):
    return dict(side=int(round(np.sqrt(c.model.n))), n=c.model.n, m=c.springs.m,
                h=c.bending.n_hinges if (bending and c.bending is not None) else 0)


def _engine_contender(c, x0, v0, block):
    """(the engine's Contender stepping its own state from (x0, v0) ``block`` symplectic-Euler steps
    per call, that state)."""
    st = c.model.make_state(x0, v0)
    stepper = Stepper(c.model, "symplectic-euler")

    def engine():
        stepper.step(st, DT, block)
        sync()
    return Contender("engine", engine), st


def _warp_contender(p, x0, v0, dtype, block):
    """A Warp peer's Contender, loaded with (x0, v0) in ``dtype``, ``block`` steps per call."""
    p.load(x0.astype(dtype), v0.astype(dtype))
    return Contender("warp", lambda: p.advance(DT, block),     # CPU launches return when done
                     info=dict(peer_threads=1, peer_layer="warp cpu (serial)"))


def _contenders(c, bending, block):
    """The engine, Numba, Warp (and, one step per call, numpy) stepping their own copies of the
    bench's start state ``block`` steps per call in the engine's precision; (contenders, left out,
    the engine's state)."""
    x0, v0 = config.cloth_start_state(c)
    dtype = np.dtype(float_dtype())
    engine, st = _engine_contender(c, x0, v0, block)
    out = [engine]
    left = {}
    for name in ("numba", "warp"):
        why = peers.missing(name)
        if why:
            left[name] = why
            continue
        p = peers.explicit_peer(name, c, bending, dtype)
        if name == "numba":
            x, v = x0.astype(dtype), v0.astype(dtype)
            run = (lambda p=p, x=x, v=v: p.step(x, v, DT, block))
            info = dict(peer_threads=p.threads, peer_layer=p.layer)
            out.append(Contender(name, run, info=info))
        else:
            out.append(_warp_contender(p, x0, v0, dtype, block))
    if block == 1:
        base = NumpyCloth(c.model, c.springs, c.bending if bending else None)
        x, v = x0.copy(), v0.copy()
        out.append(Contender("numpy", lambda: base.symplectic_euler(x, v, DT, 1)))
    return out, left, st


@pytest.mark.parametrize("block", [1, config.EXPLICIT_BLOCK], ids=["1-step", f"{config.EXPLICIT_BLOCK}-steps"])
@pytest.mark.parametrize("model", list(MODELS))
@pytest.mark.parametrize("side", SIZES)
def test_explicit_row(benchmark, side, model, block):
    """``block`` symplectic-Euler steps per call (one: group "cloth-explicit-step"; config.EXPLICIT_BLOCK,
    as a lesson takes them between two recorded frames: group "cloth-explicit-block", the engine in
    one launch), engine and peers interleaved in rounds; the first calls (compilation or cache
    load) run before the clock."""
    bending = MODELS[model]
    c = config.cloth_scene(side, bending)
    info = _info(c, bending)
    contenders, left, st = _contenders(c, bending, block)
    row = measure_row(benchmark, contenders, group="cloth-explicit-step" if block == 1 else "cloth-explicit-block",
                      budget="explicit", steps=block, left_out=left, model=model, kernel="explicit_step",
                      bytes=traffic.kernel_bytes("explicit_step", info["n"], info["m"], info["h"], _fb()), **info)
    assert set(row) == {k.impl for k in contenders}
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
    f = vec3_ndarray(m.n)
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


MEMBRANE = config.MEMBRANE_MODEL


@pytest.mark.parametrize("block", [1, config.EXPLICIT_BLOCK], ids=["1-step", f"{config.EXPLICIT_BLOCK}-steps"])
@pytest.mark.parametrize("side", SIZES)
def test_membrane_row(benchmark, side, block):
    """The same cloth with a Baraff-Witkin membrane (engine/energies/membrane.py) instead of springs:
    ``block`` symplectic-Euler steps per call, the engine (its two-pass step: the triangle kernel,
    then gather + update) against the same energy written in Warp (bench/peers/warp_membrane.py),
    interleaved in rounds. Numba and numpy have no membrane."""
    c = config.membrane_scene(side)
    x0, v0 = config.cloth_start_state(c)
    dtype = np.dtype(float_dtype())
    engine, st = _engine_contender(c, x0, v0, block)
    contenders = [engine]
    left = {"numba": "the Numba peer writes springs and hinges only", "numpy": "the numpy baseline writes springs "
            "and hinges only"}
    why = peers.missing("warp")
    if why:
        left["warp"] = why
    else:
        from bench.peers.warp_membrane import WarpMembrane
        contenders.append(_warp_contender(WarpMembrane(c.model, c.membrane, dtype), x0, v0, dtype, block))
    n, m = c.model.n, c.membrane.n_elements
    row = measure_row(benchmark, contenders, group="cloth-explicit-step" if block == 1 else "cloth-explicit-block",
                      budget="explicit", steps=block, left_out=left, model=MEMBRANE, kernel="explicit_step",
                      side=int(round(np.sqrt(n))), n=n, m=m, h=0)
    assert set(row) == {k.impl for k in contenders}
    assert np.all(np.isfinite(st.numpy().x))
