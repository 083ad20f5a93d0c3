"""Taichi's CPU pool threads bound one per CPU (engine.pinning, ELASTIC_PIN): the threads bound are
the ones that run a parallel loop (not Taichi's other threads, not the launching thread), each to
a CPU of its own; ELASTIC_PIN=off and threads not as many as the CPUs leave every thread free,
with the reason. Each case runs in a fresh process (the pool is made when Taichi starts)."""
import json
import os
import subprocess
import sys

import pytest

from tests.helpers import ROOT

SCRIPT = r"""
import json, os
import engine.runtime as R
from engine import pinning
info = R.init()
import taichi as ti
def cpu_ns():
    return {t: pinning._cpu_ns(t) for t in pinning.thread_ids()}
out = ti.ndarray(ti.f64, info.cpu_threads)
pinning._busy(0, out)
t0 = cpu_ns()
for _ in range(10):
    pinning._busy(pinning.BUSY_ITERATIONS, out)
t1 = cpu_ns()
worked = sorted(t for t in t1 if t in t0 and t1[t] - t0[t] >= pinning.WORKED_NS and t != os.getpid())
aff = {t: sorted(os.sched_getaffinity(t)) for t in pinning.thread_ids()}
print(json.dumps(dict(pinned=info.pinned, why=info.unpinned_why, describe=info.describe(), worked=worked,
                      affinity={str(t): a for t, a in aff.items()}, main=os.getpid(),
                      usable=sorted(os.sched_getaffinity(0)))))
"""

needs_two_cpus = pytest.mark.skipif(not hasattr(os, "sched_getaffinity") or len(os.sched_getaffinity(0)) < 2,
                                    reason="binding threads to CPUs needs Linux and two usable CPUs")


def _run(**env):
    e = dict(os.environ, PYTHONPATH=str(ROOT), ELASTIC_CACHE_DIR=str(ROOT / ".ti_cache"), ELASTIC_THREADS="2")
    e.pop("ELASTIC_PIN", None)
    e.update(env)
    r = subprocess.run([sys.executable, "-c", SCRIPT], env=e, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout.strip().splitlines()[-1])


@needs_two_cpus
def test_the_threads_that_run_a_parallel_loop_are_bound_one_per_cpu():
    d = _run()
    usable = d["usable"]
    assert d["pinned"] == usable[:2] and d["why"] == ""
    bound = {int(t): a for t, a in d["affinity"].items() if a != usable}
    # two threads bound, each to its own CPU, the CPUs reported; the launching thread is free
    assert sorted(a[0] for a in bound.values()) == usable[:2] and all(len(a) == 1 for a in bound.values())
    assert d["main"] not in bound
    # the bound threads are the pool: every thread that did a busy chunk in ten launches is one of them
    assert d["worked"] and set(d["worked"]) <= set(bound)
    assert d["describe"].startswith("cpu (") and f"2 CPU threads on CPUs {usable[0]}, {usable[1]}," in d["describe"]


@needs_two_cpus
def test_elastic_pin_off_leaves_every_thread_free():
    d = _run(ELASTIC_PIN="off")
    assert d["pinned"] is None and d["why"] == "ELASTIC_PIN=off"
    assert all(a == d["usable"] for a in d["affinity"].values())
    assert "2 CPU threads, kernel cache" in d["describe"]


@needs_two_cpus
def test_more_threads_than_cpus_are_not_bound_and_say_why():
    n = len(os.sched_getaffinity(0))
    d = _run(ELASTIC_THREADS=str(n + 1))
    assert d["pinned"] is None and d["why"] == f"{n + 1} threads on {n} usable CPUs (bound only when they are as many)"
    assert all(a == d["usable"] for a in d["affinity"].values())


def test_fewer_threads_than_cpus_are_not_bound(monkeypatch):
    """On a machine with more CPUs than threads, every process would bind its pool to the same first
    CPUs (a class graded by several workers, tests on several workers): auto leaves them free."""
    from engine import pinning
    monkeypatch.setattr(pinning.os, "sched_getaffinity", lambda pid: {0, 1, 2, 3}, raising=False)
    monkeypatch.setattr(pinning.os, "sched_setaffinity", lambda pid, cpus: pytest.fail("bound a thread"),
                        raising=False)
    assert pinning.pin_pool(set(), 2) == (None, "2 threads on 4 usable CPUs (bound only when they are as many)")


def test_one_thread_is_not_bound():
    d = _run(ELASTIC_THREADS="1")
    assert d["pinned"] is None and d["why"] == "one thread"
