"""One way to time a benchmark body with pytest-benchmark: warm up (compile) outside the clock,
end every timed call with ``ti.sync()``, choose rounds from a time budget, record what the
report needs in ``extra_info``."""
import math
import time

import taichi as ti

from bench import config


_warmed: set = set()
_PATH_KEYS = ("impl", "kernel", "model", "solver", "method", "level")


def sync():
    ti.sync()


def measure(benchmark, fn, *, group: str, steps: int = 1, setup=None, warmup: int = 1, **info):
    """Time ``fn()`` (which does ``steps`` steps or kernel calls and synchronises) with
    ``benchmark.pedantic``.  ``setup()`` (untimed) runs before every call (e.g. resets the
    state); without it, fast bodies are repeated ``iterations`` times per round.  Extra keyword
    arguments go to ``benchmark.extra_info`` (with ``steps_per_call``, ``config``, ``profile``).
    Returns fn's last result.  (Comparison rows, engine beside its peers, are timed interleaved by
    bench/interleave.py instead.)"""
    budget, max_rounds = config.budget()
    benchmark.group = group
    benchmark.extra_info.update(info, steps_per_call=int(steps), config=config.config_name(),
                                profile=config.profile())
    if budget <= 0.0:  # smoke (benchmarks disabled): the body runs once, no warm-up
        result = {}

        def once():
            result["out"] = fn()
        benchmark.pedantic(once, setup=setup, rounds=1, iterations=1, warmup_rounds=0)
        return result.get("out")
    # Warm up outside the clock: the first call of a code path in this process compiles its
    # kernels (or loads them from the cache); later sizes of the same path only fill per-model
    # caches, so one call is enough for them.
    key = (group, tuple(sorted((k, str(v)) for k, v in info.items() if k in _PATH_KEYS)))
    times = []
    n_warm = 0 if warmup <= 0 else (int(warmup) if key in _warmed else int(warmup) + 3)
    for _ in range(n_warm):
        if setup is not None:
            setup()
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
        if key in _warmed or (len(times) >= 2 and times[-1] > 0.7 * times[-2]):
            break  # the time has settled: nothing left to compile
    _warmed.add(key)
    if times:
        t_first = times[-1]
    else:
        if setup is not None:
            setup()
        t0 = time.perf_counter()
        fn()
        t_first = time.perf_counter() - t0
    iterations = 1 if setup is not None else max(1, math.ceil(2e-3 / max(t_first, 1e-7)))
    rounds = int(min(max_rounds, max(1, budget / max(t_first * iterations, 1e-9))))
    benchmark.extra_info.update(iterations=iterations, rounds=rounds)
    result = {}

    def body():
        result["out"] = fn()

    if setup is not None:
        benchmark.pedantic(body, setup=setup, rounds=rounds, iterations=1, warmup_rounds=0)
    else:
        benchmark.pedantic(body, rounds=rounds, iterations=iterations, warmup_rounds=0)
    return result.get("out")
