"""Every contender of a comparison row timed in the same rounds, one after the other, in one process.

A ratio of two medians taken minutes apart measures the machine as much as the code: on a shared
2-core machine the load, the CPU frequency and the state of other thread pools drift between
benchmarks.  So each row of the report (one cloth size, one model or tolerance) is one
pytest-benchmark test whose timed body is a *round*: every contender once (a batch of calls for a
fast one), in an order that rotates from round to round so that no contender always runs first or
right after the same neighbour.  The per-round seconds of each contender are kept in
``extra_info["interleaved"]``; the report takes each contender's median over the rounds
(bench/report/derive.py), and each ratio *per round* (engine / peer in the same round,
bench/report/ratios.py), giving the median ratio and its spread.

A contender is a :class:`Contender`: ``run()`` does ``steps`` steps and synchronises; ``setup()``
(untimed, before every call) resets its state where a call must start from the same state;
``after()`` (untimed, after every timed call) may return a dict of figures of that call (iterations,
the split of a step), whose per-key medians over the timed calls go into the contender's info.
"""
import math
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from bench import config

BATCH_S = 5e-3   # a contender without a setup repeats its call until a batch takes about this long
# an untimed pause before each contender's turn: on two cores a thread pool that spins after its
# work (OpenMP's default wait policy, MKL, OpenBLAS) takes a core from whatever runs next, and
# without the pause the contender after Numba paid for Numba's spinning (measured: the engine's
# 128^2 springs step 0.19-0.98 ms right after Numba against 0.25-0.36 with a 10 ms pause)
GAP_S = 0.01


@dataclass
class Contender:
    impl: str
    run: Callable[[], object]
    setup: Callable[[], object] | None = None
    after: Callable[[], dict | None] | None = None
    info: dict = field(default_factory=dict)


def spread(values) -> tuple:
    """(median, smallest, largest) of per-round figures.  The whole range, not a percentile band:
    between two runs the median of a launch-bound row moved by more than a 10-90 band of one run's
    rounds (measured: the engine's one-step 64^2 cloth against Numba 1.20 (0.93-1.66) in one full run,
    0.93 in the next)."""
    v = np.asarray(values, dtype=float)
    return float(np.median(v)), float(v.min()), float(v.max())


def _call(c: Contender, calls: int, warm: bool = False) -> float:
    """Seconds of one call (a batch of ``calls`` calls when c has no setup), after one untimed call
    when ``warm`` (with its own setup before each): the contender's threads are awake and its data
    in cache when its clock starts, as in a loop of steps."""
    if warm:
        if c.setup is not None:
            c.setup()
        c.run()
    if c.setup is not None:
        c.setup()
        t0 = time.perf_counter()
        c.run()
        return time.perf_counter() - t0
    t0 = time.perf_counter()
    for _ in range(calls):
        c.run()
    return (time.perf_counter() - t0) / calls


def measure_row(benchmark, contenders: list, *, group: str, budget: str, steps: int = 1, warmup: int = 2,
                left_out: dict | None = None, warm: bool = True, **info):
    """Time ``contenders`` interleaved in rounds with ``benchmark.pedantic`` (one round = one timed
    body).  ``warmup`` untimed calls of each first (compilation, caches, a solver's analysis), then
    one probe call each chooses the batch sizes and the number of rounds: the row's time budget
    (``config.row_budget(budget)``) divided by a round's time, within the fewest and most rounds it
    gives.  In a round, each contender's turn starts with an untimed pause (GAP_S) and, with
    ``warm``, one untimed call.  ``left_out``: contenders of this row that were not timed, with the
    reason.  Extra keyword arguments go to
    ``benchmark.extra_info`` (with ``steps_per_call``, ``config``, ``profile``)."""
    if not contenders:
        raise ValueError("measure_row needs at least one contender")
    smoke = config.profile() == "smoke"   # every body once, no pauses
    gap = 0.0 if smoke else GAP_S
    seconds, min_r, max_r = config.row_budget(budget)
    benchmark.group = group
    benchmark.extra_info.update(info, steps_per_call=int(steps), config=config.config_name(),
                                profile=config.profile(), left_out=dict(left_out or {}))
    for c in contenders:
        for _ in range(0 if smoke else warmup):
            _call(c, 1)
    if smoke:
        calls = {c.impl: 1 for c in contenders}
        rounds = 1
    else:
        probe = {c.impl: _call(c, 1) for c in contenders}
        calls = {c.impl: 1 if c.setup is not None else max(1, math.ceil(BATCH_S / max(probe[c.impl], 1e-7)))
                 for c in contenders}
        round_s = sum(probe[k] * (calls[k] + (1 if warm else 0)) + gap for k in probe)
        rounds = int(min(max_r, max(min_r, seconds / max(round_s, 1e-9))))
    times = {c.impl: [] for c in contenders}
    figures = {c.impl: [] for c in contenders}
    counter = [0]

    def one_round():
        k = counter[0]
        counter[0] += 1
        order = contenders[k % len(contenders):] + contenders[:k % len(contenders)]
        for c in order:
            time.sleep(gap)   # the last contender's thread pools stop spinning before this one starts
            times[c.impl].append(_call(c, calls[c.impl], warm=warm))
            if c.after:
                figures[c.impl].append(c.after() or {})

    benchmark.pedantic(one_round, rounds=rounds, iterations=1, warmup_rounds=0)
    out = {}
    for c in contenders:
        d = dict(c.info)
        for key in sorted({k for f in figures[c.impl] for k in f}):
            vals = [f[key] for f in figures[c.impl] if key in f and f[key] is not None]
            if vals:
                d[key] = float(np.median(vals)) if isinstance(vals[0], float) else int(np.median(vals))
        out[c.impl] = dict(round_s=times[c.impl], calls_per_round=calls[c.impl], info=d)
    benchmark.extra_info.update(interleaved=out, rounds=rounds)
    return out
