"""Timed: the hardware floor, a streaming copy of one f64 array into another (Taichi parallel
loop on this process' threads, and numpy), once larger than the last-level cache (DRAM) and
once cache-resident.  Bytes moved = 2 x 8 x elements (read + write)."""
import numpy as np
import pytest
import taichi as ti

from bench import config
from bench.timing import measure, sync
from bench.variants import stream_copy

SIZES = {"dram": 1 << 25, "cache": 1 << 19}  # elements: 256 MiB and 4 MiB per array


def _elements(level):
    return 1 << 14 if config.profile() == "smoke" else SIZES[level]


@pytest.mark.parametrize("level", list(SIZES))
@pytest.mark.parametrize("impl", ["taichi", "numpy"])
def test_stream_copy(benchmark, impl, level):
    n = _elements(level)
    src = np.arange(n, dtype=np.float64)
    if impl == "taichi":
        a = ti.ndarray(dtype=ti.f64, shape=n)
        b = ti.ndarray(dtype=ti.f64, shape=n)
        a.from_numpy(src)

        def run():
            stream_copy(a, b)
            sync()
    else:
        dst = np.empty_like(src)

        def run():
            np.copyto(dst, src)
    measure(benchmark, run, group="bandwidth", impl=impl, level=level, kernel="copy", n=n, bytes=2 * 8 * n,
            array_bytes=8 * n)
    if impl == "taichi":
        assert b.to_numpy()[-1] == src[-1]
