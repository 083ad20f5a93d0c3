"""One CPU per thread of Taichi's CPU thread pool (engine.runtime.init does this by default).

Why: Taichi 1.7.4 runs a CPU parallel loop on its own pool of ``cpu_max_num_threads`` worker
threads, which sleep on a condition variable between launches; every launch wakes them all and
the launching thread waits. Left to the Linux scheduler, both workers of the 2-thread pool were
often woken onto the SAME CPU, and stayed there for launch after launch: the first takes the
loop's chunks one after the other and the second runs only once it is done (measured here: a
two-block loop of 0.8 ms of arithmetic per block took 0.8 ms on each worker in some launches and
1.6 ms on one worker and ~10 us on the other in the rest; the 128^2 cloth step with bending
1.1-1.2 ms or 2.2 ms per launch at random, for runs of consecutive launches). With each worker
bound to its own CPU, every launch of that loop ran its two blocks side by side.

How: the pool's threads are the threads that appear while Taichi starts and then do the work of
a parallel loop. :func:`pin_pool` runs a calibration loop of one busy chunk per worker (a few
times, until each worker has been seen working; a worker woken late finds its chunk done, so one
launch may not show both) and reads every new thread's CPU time from ``/proc/self/task``; the
threads that worked are the pool. Each is then bound (``os.sched_setaffinity``) to one of the
CPUs this process may use, in order. The launching (Python) thread stays free.

Nothing changes in what a kernel computes: only where its threads run. Pinning is skipped (and
the reason kept) on a system without ``/proc/self/task`` or ``sched_setaffinity``, with one
thread, when the threads are not as many as the CPUs this process may use (more threads: some
would share a CPU anyway; fewer: every process of the kind would be bound to the same first CPUs
while the others stay idle, e.g. the workers grading a class), or when the pool cannot be told
apart.
"""

import os

import taichi as ti

from engine.tickets import BLOCK_SLOTS   # a range-for's iterations per CPU thread (Taichi 1.7: >= 512)

BUSY_ITERATIONS = 40_000   # square roots per worker per calibration launch (~0.1-0.3 ms)
ATTEMPTS = 30        # calibration launches at most
WORKED_NS = 50_000   # CPU time that marks a thread as having run a busy chunk


def thread_ids() -> set[int] | None:
    """The ids of this process's threads, or None where /proc/self/task cannot be read."""
    try:
        return {int(t) for t in os.listdir("/proc/self/task")}
    except (OSError, ValueError):
        return None


def _cpu_ns(tid: int) -> int | None:
    try:
        with open(f"/proc/self/task/{tid}/schedstat") as f:
            return int(f.read().split()[0])
    except (OSError, ValueError, IndexError):
        return None


@ti.kernel
def _busy(n: ti.i32, out: ti.types.ndarray(dtype=ti.f64, ndim=1)):
    """One busy chunk per worker: iteration BLOCK_SLOTS*k of the loop does n dependent square roots."""
    for it in range(out.shape[0] * BLOCK_SLOTS):
        if it % BLOCK_SLOTS == 0:
            s = ti.cast(it, ti.f64)
            for _ in range(n):
                s = ti.sqrt(s + 1.0)
            out[it // BLOCK_SLOTS] = s


def pool_threads(before: set[int], threads: int) -> list[int] | None:
    """The ids of the pool's ``threads`` workers among the threads not in ``before`` (those that
    did busy chunks of :func:`_busy`), or None when exactly ``threads`` such threads were not found."""
    now = thread_ids()
    if now is None:
        return None
    candidates = sorted(now - before)
    out = ti.ndarray(ti.f64, threads)
    _busy(0, out)   # compiled (or loaded) before anything is timed: compiling may use other threads
    worked: set[int] = set()
    for _ in range(ATTEMPTS):
        start = {t: _cpu_ns(t) for t in candidates}
        _busy(BUSY_ITERATIONS, out)
        for t in candidates:
            t1 = _cpu_ns(t)
            if start[t] is not None and t1 is not None and t1 - start[t] >= WORKED_NS:
                worked.add(t)
        if len(worked) >= threads:
            break
    return sorted(worked) if len(worked) == threads else None


def pin_pool(before: set[int] | None, threads: int) -> tuple[tuple[int, ...] | None, str]:
    """Bind each of the pool's ``threads`` workers (new since ``before``) to its own CPU.
    Returns (the CPUs, in the workers' order, or None, and why not when None)."""
    if threads < 2:
        return None, "one thread"
    if before is None or not hasattr(os, "sched_setaffinity"):
        return None, "this system does not let a process bind its threads to CPUs"
    cpus = sorted(os.sched_getaffinity(0))
    if threads != len(cpus):
        # with more CPUs than threads, other processes of the same kind (grading workers, test
        # workers) would be bound to the same first CPUs while the rest stay idle
        return None, f"{threads} threads on {len(cpus)} usable CPUs (bound only when they are as many)"
    workers = pool_threads(before, threads)
    if workers is None:
        return None, "Taichi's pool threads could not be told apart"
    try:
        for tid, cpu in zip(workers, cpus):
            os.sched_setaffinity(tid, {cpu})
    except OSError as exc:
        for tid in workers:   # all or none
            try:
                os.sched_setaffinity(tid, set(cpus))
            except OSError:
                pass
        return None, f"binding a thread failed ({exc.strerror or exc})"
    return tuple(cpus), ""
