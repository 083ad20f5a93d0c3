"""Phases handed out by tickets inside one launch: how a kernel runs a sequence of phases, each
split into one task per block, on all the launch's threads without a launch per phase.

A kernel's parallel loop runs one worker per block (:data:`BLOCK_SLOTS` iterations each, the first
of which works: Taichi 1.7 gives a CPU thread at least 512 consecutive iterations, so a loop over
a few items would run on one thread). The tasks are numbered in order (phase p, block b: ticket
p nb + b); every worker takes the next ticket (an integer atomic on ``sync[SYNC_TICKET]``), waits
until every task of the phases before it is done (``sync[SYNC_DONE]`` counts them:
:func:`wait_for_phase`), does it and counts it done. Each task runs once and after all of the
previous phase, so the result does not depend on how many threads run or when they start: a
worker that starts late finds its share done, and one thread alone does everything (nothing waits
for a thread that is not running). A phase costs a few cache-line transfers instead of a parallel
loop's wake-up of the thread pool (20-60 us on the 2-core CPU).

``sync`` is an i32 array of SYNC_SIZE entries whose counters sit on cache lines of their own
(entries 16, 32, 48: no other allocation shares their lines), so a thread polling one does not
contend with writes to another. A worker that waited more than ``spin_limit`` polls (a thread
stopped for seconds) sets ``sync[SYNC_STOP]`` to GAVE_UP and every worker leaves; a kernel may
set it to another non-zero value to end the work early (every worker then leaves too).

Used by engine.integrators.cloth_kernels (many explicit steps in one launch) and
engine.solvers.pcg (the whole CG loop in one launch).
"""
import taichi as ti

SYNC_SIZE, SYNC_TICKET, SYNC_DONE, SYNC_STOP = 64, 16, 32, 48
SPIN_LIMIT = 1 << 27  # polls (~3-10 s) of one wait before a worker gives up and reports it (the default)
BLOCK_SLOTS = 512     # loop iterations per worker (see the module docstring)
GAVE_UP = 1           # sync[SYNC_STOP] after a wait exceeded spin_limit


@ti.func
def start(sync: ti.template()):
    """Reset the counters (at the top of the kernel, before its parallel loop)."""
    sync[SYNC_TICKET] = 0
    sync[SYNC_DONE] = 0
    sync[SYNC_STOP] = 0


@ti.func
def wait_for_phase(sync: ti.template(), p, nb, spin_limit) -> ti.i32:
    """Wait until the tasks of the phases before p (nb tasks each) are done; 1 to go on, 0 when the
    work was stopped (by another worker, or by this wait exceeding ``spin_limit`` polls)."""
    k = 0
    while ti.atomic_or(sync[SYNC_DONE], 0) < p * nb and sync[SYNC_STOP] == 0 and k < spin_limit:
        k += 1
    if k >= spin_limit:
        sync[SYNC_STOP] = GAVE_UP
    go = 1
    if sync[SYNC_STOP] != 0:
        go = 0
    return go
