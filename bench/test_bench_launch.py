"""Timed: what one call costs before any work, the engine's Taichi kernel launch against a Numba
call and a Warp launch, interleaved in rounds (bench/interleave.py).

Each contender calls a kernel of the explicit step's shape (three (n, 3) arrays of the 64^2 cloth
and a scalar) whose parallel loop has one iteration: what is timed is the call itself (Taichi:
argument handling in Python, the launch and ti.sync; Numba: the dispatcher's type check and the
parallel region; Warp: wp.launch on the CPU).  At 64^2 the explicit step's whole work is
~50-100 us, so this fixed cost is what the engine's one-step-per-call rows pay that Numba's do not.

The engine is timed three ways, to say where its cost lies: ``engine``, Taichi's own kernel call;
``engine-bound``, the same kernel launched as the explicit steps launch theirs
(engine.launch.BoundKernel: the compiled instance looked up once, the launch context
filled directly); ``engine-serial``, bound too, with the loop serialized. Taichi's CPU parallel
loop hands its work to a thread pool and waits for it (the launching thread does none of it), so
engine-bound minus engine-serial is that hand-over, which no change to the engine's kernels removes.
"""
import numpy as np
import taichi as ti

from bench import peers
from bench.interleave import Contender, measure_row
from bench.timing import sync
from engine.fields import float_dtype, vec3_array, vec3_ndarray
from engine.launch import BoundKernel

SIDE = 64


@ti.kernel
def _one_item(x: vec3_array, v: vec3_array, f: vec3_array, dt: float):
    for i in range(1):
        f[i] = x[i] + dt * v[i]


@ti.kernel
def _one_item_serial(x: vec3_array, v: vec3_array, f: vec3_array, dt: float):
    ti.loop_config(serialize=True)   # run by the launching thread: no thread pool
    for i in range(1):
        f[i] = x[i] + dt * v[i]


def _numba_call(dtype):
    numba = peers.require("numba")

    @numba.njit(parallel=True, cache=False)
    def one_item(x, v, f, dt):
        for i in numba.prange(1):
            for d in range(3):
                f[i, d] = x[i, d] + dt * v[i, d]
    return one_item


def _warp_call(dtype):
    from bench.peers.warp_cloth import import_warp
    wp = import_warp()
    vec = wp.vec3d if np.dtype(dtype) == np.float64 else wp.vec3
    scalar = wp.float64 if np.dtype(dtype) == np.float64 else wp.float32

    @wp.kernel(module="bench_launch_" + np.dtype(dtype).name, enable_backward=False)
    def one_item(x: wp.array(dtype=vec), v: wp.array(dtype=vec), f: wp.array(dtype=vec), dt: scalar):
        i = wp.tid()
        f[i] = x[i] + dt * v[i]
    return wp, one_item


def test_launch_cost(benchmark):
    """One call of a one-item kernel: engine (Taichi), Numba, Warp, interleaved."""
    n = SIDE * SIDE
    dtype = np.dtype(float_dtype())
    x, v, f = (vec3_ndarray(n) for _ in range(3))

    def engine():
        _one_item(x, v, f, 1e-3)
        sync()
    bound, serial = BoundKernel(_one_item), BoundKernel(_one_item_serial)

    def engine_bound():
        bound(x, v, f, 1e-3)
        sync()

    def engine_serial():
        serial(x, v, f, 1e-3)
        sync()
    contenders, left = [Contender("engine", engine), Contender("engine-bound", engine_bound),
                        Contender("engine-serial", engine_serial)], {}
    X, V, F = (np.zeros((n, 3), dtype=dtype) for _ in range(3))
    for name in ("numba", "warp"):
        why = peers.missing(name)
        if why:
            left[name] = why
        elif name == "numba":
            call = _numba_call(dtype)
            contenders.append(Contender("numba", lambda: call(X, V, F, dtype.type(1e-3))))
        else:
            wp, kernel = _warp_call(dtype)
            arrays = [wp.array(a, dtype=kernel.adj.args[0].type.dtype, device="cpu") for a in (X, V, F)]
            contenders.append(Contender("warp", lambda: wp.launch(kernel, dim=1, inputs=[*arrays, dtype.type(1e-3)],
                                                                  device="cpu")))
    row = measure_row(benchmark, contenders, group="launch-cost", budget="explicit", left_out=left,
                      side=SIDE, n=n)
    assert set(row) == {k.impl for k in contenders}
    assert np.allclose(f.to_numpy()[0], 0.0)
