"""Explicit time integrators: forward Euler, symplectic Euler, velocity Verlet, and the plans of
their fast kernels.

The update formulas (E1)-(E3) are written once, in :mod:`engine.integrators.kernels`. An integrator
here is the method only; :class:`engine.integrators.stepper.Stepper` decides once, from the model's
energies, which kernels a step launches and keeps the plan and the work arrays: a springs [+ one
hinge energy] model takes one launch per symplectic-Euler or velocity-Verlet step
(:func:`cloth_stepper`, its arrays laid out by :func:`cloth_plan`), a membrane two bound launches
(:func:`corner_stepper`), a small spring-only model run
by the run loop many steps per launch (:func:`many_steps`); anything else the generic path (each
energy's force kernels, then one update pass). Each fast path is pinned bitwise to the generic
path by tests.

The time-step limit is in :mod:`engine.stability`; blow-ups are reported by
:class:`engine.integrators.monitor.Monitor`.
"""
from __future__ import annotations

import math

import numpy as np

from engine import tickets
from engine.fields import int_ndarray, scalar_ndarray, serial_pass, vec3_ndarray, zero_vec3
from engine.integrators import batched_steps as B
from engine.integrators import cloth_kernels as C
from engine.integrators import kernels as K
from engine.launch import BoundKernel
from engine.integrators.monitor import Monitor
from engine.model import Model, State


# --------------------------------------------------------------------------------------------
# Plans (a Stepper, engine.integrators.stepper, makes them once and keeps them with its work arrays)
# --------------------------------------------------------------------------------------------

def signature(model: Model) -> tuple:
    """The model's energies as the forms the fast kernels know (each energy's ``force_form``, non-empty
    ones only): ("springs",) for one pair-gather energy, ("springs", "hinges") for one pair-gather
    energy followed by one slot-gather energy, ("corners",) for one corner-gather energy (a
    membrane), () for anything else."""
    es = [e for e in model.energies if e.n_elements > 0]
    if len(es) == 1 and len(model.energies) == 1 and es[0].force_form == "corner-gather" \
            and es[0].n_vertices == model.n:
        return ("corners",)
    if len(es) != len(model.energies) or not es or es[0].force_form != "pair-gather":
        return ()
    if len(es) == 1:
        return ("springs",)
    if len(es) == 2 and es[1].force_form == "slot-gather" and es[1].n_vertices == model.n:
        return ("springs", "hinges")
    return ()


def cloth_blocks(n: int) -> int:
    """How many vertex blocks the cloth step splits a model of n vertices into: one per thread
    (Taichi gives each CPU thread one contiguous share of a parallel loop, so more blocks would only
    recompute more boundary terms), one below CLOTH_BLOCK_MIN vertices per thread. Any number of
    blocks gives bitwise the same result."""
    return int(max(1, min(_threads(), n // CLOTH_BLOCK_MIN)))


CLOTH_BLOCK_MIN = 256  # vertices per block at least: below it a second thread costs more than it gains


def cloth_plan(model: Model, n_blocks: int):
    """The arrays of :func:`engine.integrators.cloth_kernels.cloth_step` for a springs [+ one hinge energy]
    model split into ``n_blocks`` contiguous vertex blocks: (I, F, boundary count), or None when the
    springs' incidence is not ordered by neighbour index (then no block order reproduces the
    generic path's sums; the generic path is taken).

    Per vertex i, the generic path sums its springs in the incidence order (ascending neighbour j)
    and its hinges in ascending hinge index. The block kernel splits i's springs into those to j
    below i's block (``in``: computed by i's block before its sweep), to j in the block below i
    (computed once, by j, when the sweep passes j) and to j above i (``up``: computed by i); the
    three come in ascending j, so the sum is the same, term for term and in the same order."""
    springs = model.energies[0]
    bending = model.energies[1] if len(model.energies) > 1 else None
    n = model.n
    nb = int(max(1, min(n_blocks, n)))
    vb = np.linspace(0, n, nb + 1).round().astype(np.int64)
    blk = np.repeat(np.arange(nb), np.diff(vb))
    lo_v, hi_v = vb[blk], vb[blk + 1]

    off, other, eid = springs.offsets_np, springs.inc_other_np, springs.inc_edge_np
    owner = np.repeat(np.arange(n), np.diff(off))
    cat = np.where(other < lo_v[owner], 0, np.where(other < owner, 1, 2))  # in, in-block below, up
    if len(cat) > 1 and np.any((cat[1:] < cat[:-1]) & (owner[1:] == owner[:-1])):
        return None
    up = cat == 2
    inc = cat == 0
    # the in-block-below terms reach i in the order the sweep computes them (j ascending, then j's
    # up order): it must be i's incidence order, also for repeated edges between the same two vertices
    up_rank = np.full(len(eid), -1, dtype=np.int64)
    up_rank[up] = np.arange(int(up.sum()))
    by_edge = np.argsort(eid, kind="stable")
    mate = np.empty(len(eid), dtype=np.int64)
    mate[by_edge[0::2]], mate[by_edge[1::2]] = by_edge[1::2], by_edge[0::2]
    below = np.flatnonzero(cat == 1)
    r = up_rank[mate[below]]
    if np.any(r < 0) or np.any((r[1:] <= r[:-1]) & (owner[below][1:] == owner[below][:-1])):
        return None

    cl, il = springs.c_np / springs.L_np, 1.0 / springs.L_np
    bnd = np.zeros(n, dtype=bool)
    bnd[other[inc]] = True
    bnd[other[up & (other >= hi_v[owner])]] = True
    if bending is not None and bending.n_hinges:
        H = bending.hinges_np
        hb = blk[H]
        pairs = np.unique(np.stack([hb.reshape(-1), np.repeat(np.arange(len(H)), 4)], axis=1), axis=0)
        h_list = pairs[:, 1]
        h_off = np.searchsorted(pairs[:, 0], np.arange(nb + 1))
        crossing = (hb != hb[:, :1]).any(axis=1)
        bnd[H[crossing].reshape(-1)] = True
        hv, hf = H[h_list].reshape(-1), np.stack([bending.k[h_list], bending.theta_bar[h_list]], 1).reshape(-1)
    else:
        h_off, hv, hf = np.zeros(nb + 1, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0)

    def csr(mask):
        return np.concatenate([[0], np.cumsum(np.bincount(owner[mask], minlength=n))])

    in_count = np.bincount(owner[inc], minlength=n)
    in_v = np.flatnonzero(in_count)   # the vertices with springs from below their block, ascending
    bnd_list = np.flatnonzero(bnd)
    sections = [vb, np.concatenate([[0], np.cumsum(in_count[in_v])]), other[inc], csr(up), other[up],
                bnd.astype(np.int64), bnd_list, None, h_off, hv, np.searchsorted(bnd_list, vb), in_v,
                np.searchsorted(in_v, vb)]
    header = np.zeros(C.HEADER, dtype=np.int64)
    header[C.H_NB], header[C.H_N] = nb, n
    parts, pos = [header], C.HEADER
    slots = (C.H_VB, C.H_IN_OFF, C.H_IN_J, C.H_UP_OFF, C.H_UP_C, C.H_BFLAG, C.H_BND, C.H_NBND, C.H_HOFF, C.H_HV,
             C.H_BOFF, C.H_IN_V, C.H_IN_VOFF)
    for slot, arr in zip(slots, sections):
        if arr is None:
            header[slot] = int(bnd.sum())
            continue
        header[slot] = pos
        parts.append(arr)
        pos += len(arr)
    inv_mass = model.inv_mass_nd.to_numpy().astype(np.float64)[:n]
    fparts = [inv_mass, np.stack([cl[eid[inc]], il[eid[inc]]], 1).reshape(-1),
              np.stack([cl[eid[up]], il[eid[up]]], 1).reshape(-1), hf, np.asarray(model.gravity, dtype=np.float64)]
    fpos = np.cumsum([0] + [len(a) for a in fparts])
    header[C.H_F_IN], header[C.H_F_UP], header[C.H_F_H], header[C.H_F_G] = fpos[1], fpos[2], fpos[3], fpos[4]
    header[C.H_MODE] = int(bending.mode) if bending is not None else 0
    I = np.concatenate(parts)
    if I.max(initial=0) >= 2 ** 31 or fpos[-1] >= 2 ** 31:
        return None
    return int_ndarray(I), scalar_ndarray(np.concatenate(fparts)), int(bnd.sum())


class FastStep:
    """A fast step planned for one model and one method: :meth:`begin` once before the steps (velocity
    Verlet's acceleration for the current state), then :meth:`step` (``n_steps`` steps of dt; ``state.t``
    is the caller's to advance). Made by :func:`cloth_stepper` or :func:`corner_stepper`, which choose the
    kernels for the method when they plan, not at every call."""

    def __init__(self, n: int, begin, steps):
        self.n, self._begin, self._steps = n, begin, steps

    def _check(self, state) -> None:
        if state.x.shape[0] != self.n:
            raise ValueError(f"state has {state.x.shape[0]} vertices, model has {self.n}")

    def begin(self, state) -> None:
        self._check(state)
        if self._begin is not None:
            self._begin(state)

    def step(self, state, dt: float, n_steps: int = 1) -> None:
        self._check(state)
        self._steps(state, float(dt), int(n_steps))


def _cloth_parts(model: Model, n_blocks: int | None, work: dict | None):
    """What the cloth kernels take for a springs [+ one hinge energy] model: (I, F, boundary count, work
    array w, with hinges, the work dict), or None for another model or one whose incidence has no
    block order (:func:`cloth_plan`). ``n_blocks`` default :func:`cloth_blocks`; ``work``: the dict that
    keeps w (a Stepper's: the Verlet acceleration in it outlives a plan made again; default a new one)."""
    if n_blocks is None:
        n_blocks = cloth_blocks(model.n)
    sig = signature(model)
    if sig not in (("springs",), ("springs", "hinges")):
        return None
    plan = cloth_plan(model, n_blocks)
    if plan is None:
        return None
    I, F, n_boundary = plan
    d = {} if work is None else work
    w = d.get("cloth_w")
    if w is None:  # per work dict (a stepper's), not per plan: the Verlet acceleration outlives a new plan
        w = d["cloth_w"] = vec3_ndarray(4 * model.n)  # spring sums, hinge sums, boundary x, Verlet acceleration
    return I, F, n_boundary, w, sig == ("springs", "hinges"), d


def cloth_forces(model: Model, n_blocks: int | None = None, work: dict | None = None):
    """``forces(x, f)``: f = the model's forces at x (:meth:`engine.model.Model.forces`, bitwise) in ONE
    launch of :func:`engine.integrators.cloth_kernels.cloth_forces` (bound), for a springs [+ one hinge
    energy] model; None for any other (then Model.forces: a zeroing, each energy's force kernels and
    the weight, four or five launches). What an implicit stepper evaluates its Newton residual with."""
    parts = _cloth_parts(model, n_blocks, work)
    if parts is None:
        return None
    I, F, _, w, with_h, _ = parts
    launch = BoundKernel(C.cloth_forces, (w, I, F, model.mass_nd), (with_h, serial_pass(model.n)))

    def forces(x, f):
        if f.shape[0] != model.n or x.shape[0] != model.n:
            raise ValueError(f"x and f must have the model's {model.n} vertices (got {x.shape[0]} and {f.shape[0]})")
        launch(x, f)
    return forces


def cloth_stepper(model: Model, method: str = "symplectic-euler", n_blocks: int | None = None,
                  work: dict | None = None) -> FastStep | None:
    """The :class:`FastStep` of ``method`` ("symplectic-euler" or "velocity-verlet": kick-drift, then
    force-kick, the acceleration carried in the work array) for springs [+ one hinge energy]: one
    launch of :func:`engine.integrators.cloth_kernels.cloth_step` per step, or all steps in one launch
    of :func:`engine.integrators.cloth_kernels.cloth_steps` when every block has a thread; None when the
    model's energies are not springs [+ one hinge energy] in that order (or their incidence has no
    block order: :func:`cloth_plan`).

    ``n_blocks``: vertex blocks (default :func:`cloth_blocks`, one per thread); ``work``: the dict
    that keeps the kernel's work arrays (a Stepper's, so that the Verlet acceleration in them
    outlives a plan made again; default a new one)."""
    parts = _cloth_parts(model, n_blocks, work)
    if parts is None:
        return None
    I, F, n_boundary, w, with_h, d = parts
    n = model.n
    sync = d.get("cloth_sync")
    if sync is None:
        sync = d["cloth_sync"] = int_ndarray(np.zeros(tickets.SYNC_SIZE))
    what = CLOTH_METHODS[method]
    launch = BoundKernel(C.cloth_step, (w, I, F), (what, with_h, n_boundary > 0))
    begin = None
    if method == "velocity-verlet":   # the acceleration for the current state (dt = 0)
        first = BoundKernel(C.cloth_step, (w, I, F), (C.CLOTH_VV_BEGIN, with_h, n_boundary > 0))
        begin = lambda state: first(state.x, state.v, 0.0)   # noqa: E731
    # many steps per launch with a thread per block and a core per thread (cloth_steps' threads
    # spin while they wait for each other: on a shared core that would cost a time slice)
    nb = int(I.to_numpy()[C.H_NB])
    multi = BoundKernel(C.cloth_steps, (w, I, F, sync, tickets.SPIN_LIMIT), (what, with_h)) \
        if nb <= _threads() <= _cores() else None

    def steps(state, dt, left):
        if left > 1 and multi is not None:
            while left > 0:
                k = min(left, MULTI_STEP_CHUNK)
                if multi(state.x, state.v, dt, k):
                    zero_vec3(w)  # the sums a block left in it (a launch starts from zero sums)
                    raise RuntimeError(f"the many-steps cloth kernel gave up: a thread waited more than {tickets.SPIN_LIMIT} "
                                       f"polls for the tasks before its own (the state is part-way through a step); "
                                       f"is every CPU thread of the runtime really running? ELASTIC_THREADS=1 avoids it")
                left -= k
            return
        for _ in range(left):
            launch(state.x, state.v, dt)
    return FastStep(n, begin, steps)


CLOTH_METHODS = {"symplectic-euler": C.CLOTH_SE, "velocity-verlet": C.CLOTH_VV}   # the methods the fast steps know


def corner_stepper(model: Model, method: str = "symplectic-euler", work: dict | None = None) -> FastStep | None:
    """The :class:`FastStep` of ``method`` for a model whose one energy has the "corner-gather" force
    form (a membrane); None for any other model. Each step launches the energy's per-element force kernel and
    :func:`engine.integrators.kernels.corner_update_kernel` (gather + update), both bound
    (:class:`engine.launch.BoundKernel`): symplectic Euler = forces, gather + update;
    velocity Verlet = kick-drift, forces, gather + kick (begin: forces, gather + acceleration). The
    generic path launches the same force kernel, then a zeroing, a gather and an update through
    Taichi's own call; the states are bitwise the same (tested). ``work``: the dict
    that keeps the Verlet acceleration (a Stepper's)."""
    if signature(model) != ("corners",):
        return None
    e = model.energies[0]
    n = model.n
    d = {} if work is None else work
    a = d.get("corner_a")
    if a is None or a.shape[0] != n:
        a = d["corner_a"] = vec3_ndarray(n)
    kernel, tail, templates = e.corner_force_launch()
    forces = BoundKernel(kernel, tail, templates)
    offsets, entries = e.slot_incidence
    g = [float(c) for c in np.asarray(model.gravity, dtype=np.float64).reshape(3)]
    tail = (a, e.per_corner, offsets, entries, model.inv_mass_nd, *g)

    def update(method, phase):
        return BoundKernel(K.corner_update_kernel, tail, (e.stencil_size, method, phase))
    se = update(K.SYMPLECTIC_EULER, K.STEP)
    kick_drift = update(K.VELOCITY_VERLET, K.KICK_DRIFT)
    accel_kick = update(K.VELOCITY_VERLET, K.ACCEL_KICK)

    if method not in CLOTH_METHODS:
        raise ValueError(f"method must be one of {', '.join(CLOTH_METHODS)} (got {method!r})")

    def symplectic_euler(state, dt, n_steps):
        x, v = state.x, state.v
        for _ in range(n_steps):
            forces(x)
            se(x, v, dt)

    def velocity_verlet(state, dt, n_steps):
        x, v = state.x, state.v
        for _ in range(n_steps):
            kick_drift(x, v, dt)
            forces(x)
            accel_kick(x, v, 0.5 * dt)

    def acceleration(state):
        forces(state.x)
        accel_kick(state.x, state.v, 0.0)
    if method == "symplectic-euler":
        return FastStep(n, None, symplectic_euler)
    return FastStep(n, acceleration, velocity_verlet)


MULTI_STEP_CHUNK = 1 << 20  # steps per cloth_steps launch at most (its barrier counter stays far below 2^31)


def _threads() -> int:
    from engine import runtime
    return runtime.threads(1)


def _cores() -> int:
    import os
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def many_steps(model: Model, state: State, dt: float, n_steps: int, method: str, monitor: Monitor, work,
               step_offset: int = 0):
    """``n_steps`` steps of ``method`` of a spring-only model in one launch of
    :func:`engine.integrators.batched_steps.many_steps`, with ``work``'s arrays (an
    :class:`engine.fields.WorkArrays`); returns (kinetic, potential) after every step (J), and
    raises the monitor's BlowUpError at the first step whose energy is not finite or above its
    bound (:meth:`engine.integrators.stepper.Stepper.energies` on the many-steps path)."""
    springs = model.energies[0]
    dt = float(dt)
    if not (math.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be > 0 and finite (got {dt!r})")
    n_steps = int(n_steps)
    if n_steps < 0 or n_steps >= 2 ** 31:
        raise ValueError(f"n_steps must be in 0..2^31-1 (got {n_steps})")
    if state.n != model.n:
        raise ValueError(f"state has {state.n} vertices, model has {model.n}")
    if n_steps == 0:
        return np.zeros(0), np.zeros(0)
    kin, pot = B.energy_buffers(n_steps)
    done = B.many_steps(state.x, state.v, work.vec3("f"), work.vec3("a"),
                        *springs.force_args(), springs.edges, springs.L, springs.c, springs.m, model.mass_nd,
                        model.inv_mass_nd, model.gravity_vec, dt, n_steps, kin, pot, monitor.bound, K.METHODS[method])
    return B.collect(kin, pot, done, n_steps, state, dt, monitor, step_offset)


# --------------------------------------------------------------------------------------------
# Integrators
# --------------------------------------------------------------------------------------------

class ExplicitIntegrator:
    """Base: the update formula of one explicit method, with no state of its own. A
    :class:`engine.integrators.stepper.Stepper` drives it on its generic path (the fast paths are the
    stepper's own :class:`FastStep`): ``begin(ctx, state)`` once, then ``advance(ctx, state, dt)`` per
    step, handed a :class:`engine.integrators.stepper.StepContext` (the model, the stepper's work
    arrays, whether the model has dampers) and never reaching back. Energies and blow-ups are
    watched by the run loop (engine.integrators.loop)."""

    name = "explicit"
    implicit = False
    fused = False  # whether a Stepper may plan a fast step (FastStep) for it

    def begin(self, ctx, state: State) -> None:
        """Prepare what depends on the current state (nothing for one-stage methods)."""

    def advance(self, ctx, state: State, dt: float) -> None:
        raise NotImplementedError

    @staticmethod
    def _elastic_forces(ctx, state: State):
        """The elastic forces at the state's x, plus the dampers' -D(x) v at its v (velocity Verlet's
        second half kick takes them at the half-kicked velocity)."""
        f = ctx.work.vec3("f")
        zero_vec3(f)
        ctx.model.add_elastic_forces(state.x, f)
        if ctx.dampers:
            ctx.model.add_damping_forces(state.x, state.v, f)
        return f

    def __repr__(self) -> str:
        return f"<integrator {self.name}>"


class ForwardEuler(ExplicitIntegrator):
    name = "forward-euler"

    def advance(self, ctx, state, dt):
        model = ctx.model
        f = self._elastic_forces(ctx, state)
        K.update_kernel(state.x, state.v, f, f, model.inv_mass_nd, model.gravity_vec, dt, K.FORWARD_EULER, K.STEP)
        state.t += dt


class FusableIntegrator(ExplicitIntegrator):
    """A method the fast steps know. ``fused`` (default): a stepper may plan the fast step for it (the
    one-launch cloth step for springs [+ one hinge energy], the two-pass step for a membrane: bitwise
    the same result)."""

    def __init__(self, fused: bool = True):
        self.fused = bool(fused)


class SymplecticEuler(FusableIntegrator):
    name = "symplectic-euler"

    def advance(self, ctx, state, dt):
        model = ctx.model
        f = self._elastic_forces(ctx, state)
        K.update_kernel(state.x, state.v, f, f, model.inv_mass_nd, model.gravity_vec, dt, K.SYMPLECTIC_EULER,
                        K.STEP)
        state.t += dt


class VelocityVerlet(FusableIntegrator):
    """Kick-drift-kick.  The acceleration a(x) is computed in :meth:`begin` (one extra force
    evaluation per run, not per step) and then carried from step to step in the stepper's work
    arrays (or the fast step's)."""

    name = "velocity-verlet"

    def begin(self, ctx, state):
        model = ctx.model
        f = self._elastic_forces(ctx, state)
        K.update_kernel(state.x, state.v, f, ctx.work.vec3("a"), model.inv_mass_nd, model.gravity_vec, 0.0,
                        K.VELOCITY_VERLET, K.ACCEL_KICK)

    def advance(self, ctx, state, dt):
        model = ctx.model
        a = ctx.work.vec3("a")
        K.update_kernel(state.x, state.v, a, a, model.inv_mass_nd, model.gravity_vec, dt, K.VELOCITY_VERLET,
                        K.KICK_DRIFT)
        f = self._elastic_forces(ctx, state)
        K.update_kernel(state.x, state.v, f, a, model.inv_mass_nd, model.gravity_vec, 0.5 * dt, K.VELOCITY_VERLET,
                        K.ACCEL_KICK)
        state.t += dt
