"""The explicit updates, written once, and the kernels generated from them.

Newton's second law for lumped masses, M dv/dt = f(x) = -dW/dx, with a = M^-1 f + g for free
vertices and a = 0, v = 0 for pinned ones (inverse mass 0):

  forward Euler      x+ = x + dt v ;          v+ = v + dt a(x)          (both from the old state)   (E1)
  symplectic Euler   v+ = v + dt a(x) ;       x+ = x + dt v+                                       (E2)
  velocity Verlet    v* = v + dt/2 a(x) ;     x+ = x + dt v* ;   v+ = v* + dt/2 a(x+)              (E3)
                     (kick-drift-kick; a(x+) is kept for the next step)

:func:`vertex_update` is the only place these formulas are written; every kernel below calls it
(directly or through :func:`update`, its in-place form):

* :func:`update_kernel` - one pass over the vertices with the forces already in ``f`` (the
  generic path: any energies, their own force kernels first);
* :func:`cloth_step` - a symplectic-Euler or velocity-Verlet step of a springs [+ one hinge
  energy] model in ONE launch with ONE parallel loop, over vertex blocks (one per thread): per
  block, the springs reaching into it from below, its hinges, then a sweep over its vertices in
  order that computes each spring once (its force goes to both ends), completes each vertex's
  force and updates it (:func:`_cloth_block`). The terms of every vertex are summed in the order
  of the generic path's gathers (springs by neighbour, then hinges by index), so the states are
  bitwise the same for any number of blocks and threads (tested). Its arguments are bound once
  (:class:`BoundKernel`): a step costs ~30 us of launch instead of ~0.3 ms;
* :func:`corner_update_kernel` - the gather of a "corner-gather" energy's per-element forces
  (membranes) fused with the update: with that energy's own force kernel, two bound launches per
  step (engine.integrators.explicit.corner_stepper);
* :func:`many_steps` - many steps of a spring-only model in ONE launch (the step loop
  serialised, every inner loop serial), writing each step's kinetic and potential energy and
  stopping at the first step whose total is not finite or above the bound. For small models
  (chains, frames) where launches would cost more than the arithmetic;
* :func:`axial_steps` - the same for the rod along its axis, one coordinate per node, backward
  Euler included (engine.solvers.thomas).

No kernel uses float atomics: in Taichi ``a[j] += ...`` in a parallel loop is an atomic add
unless j is the loop index, so the block kernels write ``a[j] = a[j] + ...``.

Method codes: :data:`METHODS` is the one table of them.
"""
import numpy as np
import taichi as ti

from engine.constants import INTEGRATOR_NAMES
from engine.energies.axial import axial_force, axial_potential
from engine.energies.base import slot_gather
from engine.energies.hinge import hinge_forces, hinge_frame
from engine.energies.masses import add_gravity_potential, kinetic_energy
from engine.energies.springs import spring_energy, spring_force, spring_gather
from engine.solvers.thomas import axial_backward_euler
from engine.fields import edge_array, int_array, scalar_array, vec3_array, vec3_array2

FORWARD_EULER, SYMPLECTIC_EULER, VELOCITY_VERLET, BACKWARD_EULER = 0, 1, 2, 3
METHODS = dict(zip(INTEGRATOR_NAMES, (FORWARD_EULER, SYMPLECTIC_EULER, VELOCITY_VERLET, BACKWARD_EULER)))

# phases of update(): which part of a step a loop performs
STEP = 0        # the whole per-vertex update of (E1) or (E2) (forces of the old state in f)
KICK = 1        # (E2) velocity only
DRIFT = 2       # (E2) position only
KICK_DRIFT = 3  # (E3) first half: v* = v + dt/2 a ; x+ = x + dt v*
ACCEL_KICK = 4  # (E3) a = M^-1 f + g ; v += h a  (h = dt/2; h = 0 only computes a)


@ti.func
def vertex_update(method: ti.template(), phase: ti.template(), xi, vi, ai, f_i, inv_m, g, dt, zero):
    """(E1), (E2) or a half of (E3) for one vertex, on values: returns the new (x_i, v_i, a_i).
    ``f_i`` is the force on the vertex, ``inv_m`` its inverse mass; a pinned vertex (inv_m = 0)
    keeps x and gets v = ``zero`` (a vec3 for the 3D models, a scalar for the rod along its axis)."""
    if ti.static(method == FORWARD_EULER):
        if inv_m > 0.0:
            xi = xi + dt * vi
            vi = vi + dt * (inv_m * f_i + g)
        else:
            vi = zero
    elif ti.static(method == SYMPLECTIC_EULER):
        if ti.static(phase == DRIFT):
            if inv_m > 0.0:
                xi = xi + dt * vi
        else:
            if inv_m > 0.0:
                vi = vi + dt * (inv_m * f_i + g)
                if ti.static(phase == STEP):
                    xi = xi + dt * vi
            else:
                vi = zero
    elif ti.static(phase == KICK_DRIFT):
        if inv_m > 0.0:
            vi = vi + 0.5 * dt * ai
            xi = xi + dt * vi
        else:
            vi = zero
    else:  # ACCEL_KICK, dt = the half step
        if inv_m > 0.0:
            ai = inv_m * f_i + g
            vi = vi + dt * ai
        else:
            ai = zero
            vi = zero
    return xi, vi, ai


@ti.func
def update(method: ti.template(), phase: ti.template(), i, x: ti.template(), v: ti.template(), f_i,
           a: ti.template(), inv_mass: ti.template(), g, dt, zero):
    """:func:`vertex_update` of vertex i in place: reads x[i], v[i] (and a[i]), writes back what the
    phase changes. Plain loads and stores (no atomics, whatever loop i comes from)."""
    ai = zero
    if ti.static(method == VELOCITY_VERLET and phase == KICK_DRIFT):
        ai = a[i]
    xi, vi, ai = vertex_update(method, phase, x[i], v[i], ai, f_i, inv_mass[i], g, dt, zero)
    if ti.static(method == FORWARD_EULER or phase in (STEP, DRIFT, KICK_DRIFT)):
        x[i] = xi
    if ti.static(method == FORWARD_EULER or phase != DRIFT):
        v[i] = vi
    if ti.static(method == VELOCITY_VERLET and phase == ACCEL_KICK):
        a[i] = ai


@ti.kernel
def update_kernel(x: vec3_array, v: vec3_array, f: vec3_array, a: vec3_array, inv_mass: scalar_array,
                  g: ti.math.vec3, dt: float, method: ti.template(), phase: ti.template()):
    for i in range(x.shape[0]):
        update(method, phase, i, x, v, f[i], a, inv_mass, g, dt, ti.math.vec3(0.0))


@ti.kernel
def corner_update_kernel(x: vec3_array, v: vec3_array, dt: float, a: vec3_array, vh: vec3_array2,
                         offsets: int_array, entries: int_array, inv_mass: scalar_array, gx: float, gy: float,
                         gz: float, k: ti.template(), method: ti.template(), phase: ti.template()):
    """:func:`update` of every vertex with the force gathered from a stencil energy's per-element
    corner forces ``vh`` over its incidence (entry = k*element + slot; KICK_DRIFT gathers nothing):
    the generic path's gather into a zeroed f and its update pass, in one loop and the same order
    (:func:`engine.integrators.explicit.corner_stepper`; g as three floats so that a BoundKernel
    can launch it)."""
    for i in range(x.shape[0]):
        f_i = ti.math.vec3(0.0)
        if ti.static(phase != KICK_DRIFT):
            f_i = f_i + slot_gather(vh, offsets, entries, i, k)
        update(method, phase, i, x, v, f_i, a, inv_mass, ti.math.vec3(gx, gy, gz), dt, ti.math.vec3(0.0))


# --------------------------------------------------------------------------------------------
# Launching a kernel whose argument types never change
# --------------------------------------------------------------------------------------------

DIRECT_LAUNCH = True  # False: every BoundKernel call goes through Taichi's own kernel call


class BoundKernel:
    """A Taichi kernel called many times as ``bound(*head)`` = ``kernel(*head, *tail, *templates)``:
    ``tail`` (ndarrays, ints, floats) and ``templates`` are fixed when it is made, ``head`` changes
    from call to call (ndarrays of unchanging kinds, e.g. a state's x and v, and Python scalars).

    Taichi 1.7.4's kernel call spends Python time on every call mapping each argument's type to a
    compiled instance and checking it: about 5-20 us per ndarray argument, 0.1-0.3 ms for a kernel
    of 16 ndarrays, more than the arithmetic of a 64 x 64 cloth step. A BoundKernel looks the
    compiled instance up with Taichi's own lookup (which checks every argument against the
    kernel's annotations) whenever the head's ndarrays are other objects than at the last call, and
    otherwise fills the launch context itself, with the calls Taichi's call makes for these argument
    kinds (ndarray without gradient, int, float), and launches that compiled instance: the same
    machine code on the same arguments. With Taichi other than 1.7.4, or with DIRECT_LAUNCH False,
    every call is Taichi's own call. Kernels returning nothing or one i32 only."""

    def __init__(self, kernel, tail=(), templates=()):
        self.kernel = kernel
        self.tail = tuple(tail)
        self.templates = tuple(templates)
        self._prim = getattr(kernel, "_primal", None)
        self._direct = self._prim is not None and tuple(ti.__version__) == (1, 7, 4)
        self._head_arrays = None
        self._launch = None

    def public(self, *head):
        """The same launch through Taichi's own kernel call."""
        return self.kernel(*head, *self.tail, *self.templates)

    def __call__(self, *head):
        if not (DIRECT_LAUNCH and self._direct):
            return self.kernel(*head, *self.tail, *self.templates)
        arrays = self._head_arrays
        if arrays is None or len(head) != len(arrays) or any(
                h is not a for h, a in zip(head, arrays) if a is not None):
            self._bind(head)
        return self._launch(head)

    def _bind(self, head):
        from taichi.lang import impl
        prim = self._prim
        args = (*head, *self.tail)
        compiled = prim.compiled_kernels[prim.ensure_compiled(*args, *self.templates)]
        prog = impl.get_runtime().prog
        config, caps = prog.config(), prog.get_device_caps()
        kinds = []
        for a in args:
            if isinstance(a, ti.Ndarray):
                if a.grad is not None:
                    raise TypeError(f"{prim.func.__name__}: BoundKernel does not pass ndarrays with gradients")
                kinds.append(0)
            elif isinstance(a, (int, np.integer)) and not isinstance(a, (bool, np.bool_)):
                kinds.append(1)
            elif isinstance(a, (float, np.floating)):
                kinds.append(2)
            else:
                raise TypeError(f"{prim.func.__name__}: BoundKernel passes ndarrays, ints and floats, "
                                f"not {type(a).__name__}")
        ret = prim.return_type
        has_ret = ret is not None
        if has_ret and (len(ret) != 1 or ret[0] not in (ti.i32, int)):
            raise TypeError(f"{prim.func.__name__}: BoundKernel launches kernels returning nothing or one i32")
        nh = len(head)
        head_kinds = tuple(enumerate(kinds[:nh]))
        tail_arrays = tuple(((nh + j,), a.arr) for j, a in enumerate(self.tail) if kinds[nh + j] == 0)
        tail_ints = tuple(((nh + j,), int(a)) for j, a in enumerate(self.tail) if kinds[nh + j] == 1)
        tail_floats = tuple(((nh + j,), float(a)) for j, a in enumerate(self.tail) if kinds[nh + j] == 2)

        def launch(head):
            ctx = compiled.make_launch_context()
            for i, kind in head_kinds:
                if kind == 0:
                    ctx.set_arg_ndarray((i,), head[i].arr)
                elif kind == 1:
                    ctx.set_arg_int((i,), int(head[i]))
                else:
                    ctx.set_arg_float((i,), float(head[i]))
            for idx, arr in tail_arrays:
                ctx.set_arg_ndarray(idx, arr)
            for idx, val in tail_ints:
                ctx.set_arg_int(idx, val)
            for idx, val in tail_floats:
                ctx.set_arg_float(idx, val)
            prog.launch_kernel(prog.compile_kernel(config, caps, compiled), ctx)
            if has_ret:
                ti.sync()
                return ctx.get_struct_ret_int((0,))
            return None

        self._launch = launch
        self._head_arrays = tuple(h if isinstance(h, ti.Ndarray) else None for h in head)


# --------------------------------------------------------------------------------------------
# The cloth step: springs [+ one hinge energy], one parallel loop over vertex blocks per step
# --------------------------------------------------------------------------------------------
# Layout of the plan's int array ``I`` (built by engine.integrators.explicit.cloth_plan): a header
# of section starts, then the sections. The float array ``F`` holds the per-entry coefficients.
(H_NB, H_N, H_VB, H_IN_OFF, H_IN_J, H_UP_OFF, H_UP_C, H_BFLAG, H_BND, H_NBND, H_HOFF, H_HV, H_F_IN, H_F_UP,
 H_F_H, H_F_G, H_MODE, H_BOFF, H_IN_V, H_IN_VOFF) = range(20)
HEADER = 20
BLOCK_SLOTS = 512  # loop iterations per block (see cloth_step)
# what one cloth_step launch does
CLOTH_SE, CLOTH_VV, CLOTH_VV_BEGIN = 0, 1, 2


@ti.func
def _hinge_entry(x: ti.template(), I: ti.template(), F: ti.template(), hv, f_h, q, mode):
    """The four forces of the block's hinge entry q (vertices I[hv + 4q ...], k and theta_bar in F):
    engine.energies.hinge.hinge_forces, as engine.energies.bending_kernels.hinge_force_vectors computes them."""
    e, a0, a1 = hinge_frame(x, I[hv + 4 * q], I[hv + 4 * q + 1], I[hv + 4 * q + 2], I[hv + 4 * q + 3])
    return hinge_forces(e, a0, a1, F[f_h + 2 * q], F[f_h + 2 * q + 1], mode)


@ti.func
def _add_slots(w: ti.template(), I: ti.template(), hv, q, n, lo, hi, f: ti.template()):
    """Add hinge entry q's forces to the hinge sums w[n + v] of its slots v in the block [lo, hi)."""
    for a in ti.static(range(4)):
        s = I[hv + 4 * q + a]
        if lo <= s and s < hi:
            w[n + s] = w[n + s] + f[a]


@ti.func
def _cloth_block(b, x: ti.template(), v: ti.template(), w: ti.template(), I: ti.template(), F: ti.template(), dt,
                 what: ti.template(), with_hinges: ti.template()):
    """Forces and update of the vertices [lo, hi) of block b. Each vertex's forces are summed in the
    order of the generic path's gathers (springs by ascending neighbour index, then hinges by
    ascending hinge index), so the result is bitwise the generic path's for any partition. The
    vertex's spring sum is w[i], its hinge sum w[n + i]; both are 0 when a launch starts (the sweep
    zeroes them after use; a new work array is zero):

    1. per vertex with springs to neighbours below the block (listed): w[i] = their sum (ascending),
       computed here;
    2. per hinge touching the block (ascending): its four forces, added to the block's slots;
    3. per vertex, ascending: the springs to neighbours above i, each computed once: subtracted
       from i's sum and, if the neighbour is in the block, added to its w (it comes later, and
       its lower neighbours must come first: they do, since they are all below it); then i's
       forces are complete and i is updated. (E2): an interior vertex (read by no other block)
       drifts in place, a boundary vertex's new x goes to w[2n + i] (copied after the loop).
       (E3) ACCEL_KICK: a (in w[3n + i]) and v only."""
    n = I[H_N]
    g = ti.math.vec3(F[I[H_F_G]], F[I[H_F_G] + 1], F[I[H_F_G] + 2])
    mode = I[H_MODE]
    lo = I[I[H_VB] + b]
    hi = I[I[H_VB] + b + 1]
    in_v = I[H_IN_V]
    in_off = I[H_IN_OFF]
    in_j = I[H_IN_J]
    f_in = I[H_F_IN]
    for p in range(I[I[H_IN_VOFF] + b], I[I[H_IN_VOFF] + b + 1]):
        i = I[in_v + p]
        acc = ti.math.vec3(0.0)
        xi = x[i]
        for q in range(I[in_off + p], I[in_off + p + 1]):
            acc += spring_force(xi - x[I[in_j + q]], F[f_in + 2 * q + 1], F[f_in + 2 * q])
        w[i] = acc
    if ti.static(with_hinges):
        hv = I[H_HV]
        f_h = I[H_F_H]
        q0 = I[I[H_HOFF] + b]
        q1 = I[I[H_HOFF] + b + 1]
        # two hinges per iteration: their long dependency chains (geometry, angle, force) overlap;
        # the forces are still added in ascending hinge order
        for p in range((q1 - q0) // 2):
            qa = q0 + 2 * p
            fa = _hinge_entry(x, I, F, hv, f_h, qa, mode)
            fb = _hinge_entry(x, I, F, hv, f_h, qa + 1, mode)
            _add_slots(w, I, hv, qa, n, lo, hi, fa)
            _add_slots(w, I, hv, qa + 1, n, lo, hi, fb)
        if (q1 - q0) % 2 == 1:
            _add_slots(w, I, hv, q1 - 1, n, lo, hi, _hinge_entry(x, I, F, hv, f_h, q1 - 1, mode))
    up_off = I[H_UP_OFF]
    up_c = I[H_UP_C]
    f_up = I[H_F_UP]
    for i in range(lo, hi):
        acc = w[i]
        xi = x[i]
        for q in range(I[up_off + i], I[up_off + i + 1]):
            c = I[up_c + q]
            t = spring_force(xi - x[c], F[f_up + 2 * q + 1], F[f_up + 2 * q])
            acc += t
            if c < hi:
                w[c] = w[c] - t
        f = ti.math.vec3(0.0)
        f += acc
        w[i] = ti.math.vec3(0.0)
        if ti.static(with_hinges):
            f += w[n + i]
            w[n + i] = ti.math.vec3(0.0)
        if ti.static(what == CLOTH_SE):
            xn, vn, an = vertex_update(SYMPLECTIC_EULER, STEP, xi, v[i], xi, f, F[i], g, dt, ti.math.vec3(0.0))
            v[i] = vn
            if I[I[H_BFLAG] + i] != 0:
                w[2 * n + i] = xn
            else:
                x[i] = xn
        else:
            xn, vn, an = vertex_update(VELOCITY_VERLET, ACCEL_KICK, xi, v[i], xi, f, F[i], g, 0.5 * dt,
                                       ti.math.vec3(0.0))
            v[i] = vn
            w[3 * n + i] = an


@ti.kernel
def cloth_step(x: vec3_array, v: vec3_array, dt: float, w: vec3_array, I: int_array, F: scalar_array,
               what: ti.template(), with_hinges: ti.template(), fixup: ti.template()):
    """One step of symplectic Euler (what = CLOTH_SE) or velocity Verlet (CLOTH_VV; CLOTH_VV_BEGIN: the
    acceleration of the current state, the integrator's begin) for a springs [+ one hinge energy]
    model from its plan (I, F; engine.integrators.explicit.cloth_plan); w is the plan's work array
    of 4n vec3 (w[3n:] the Verlet acceleration, carried between steps). Loops: (E3) one per-vertex
    kick-drift (parallel), then one parallel loop over the blocks (:func:`_cloth_block`); (E2) with
    ``fixup`` (the plan has boundary vertices) a serial copy of the boundary vertices' new x."""
    if ti.static(what == CLOTH_VV):
        for i in range(x.shape[0]):
            xi, vi, ai = vertex_update(VELOCITY_VERLET, KICK_DRIFT, x[i], v[i], w[3 * x.shape[0] + i], x[i], F[i],
                                       x[i], dt, ti.math.vec3(0.0))
            x[i] = xi
            v[i] = vi
    # Taichi 1.7 runs a CPU range-for as one contiguous chunk of ceil(N / threads), but at least 512,
    # iterations per thread: a loop over a few blocks would run on one thread. So the loop runs
    # over BLOCK_SLOTS iterations per block and the first of each does the block: thread t gets
    # the blocks [t k, (t + 1) k) when there are k blocks per thread.
    for it in range(I[H_NB] * BLOCK_SLOTS):
        if it % BLOCK_SLOTS == 0:
            _cloth_block(it // BLOCK_SLOTS, x, v, w, I, F, dt, what, with_hinges)
    if ti.static(what == CLOTH_SE and fixup):
        ti.loop_config(serialize=True)
        for q in range(I[H_NBND]):
            j = I[I[H_BND] + q]
            x[j] = w[2 * I[H_N] + j]


# cloth_steps' counters, each on a cache line of its own inside a 64-entry i32 array (entries
# 16, 32, 48: no other allocation can share their lines), so that a thread polling one counter
# does not contend with the other thread's writes to another, or to a neighbouring array
SYNC_SIZE, SYNC_TICKET, SYNC_DONE, SYNC_STOP = 64, 16, 32, 48
SPIN_LIMIT = 1 << 27  # polls (~3-10 s) of one wait before cloth_steps gives up and reports it (its default)


@ti.func
def _cloth_phase(p, blk, x: ti.template(), v: ti.template(), w: ti.template(), I: ti.template(),
                 F: ti.template(), dt, what: ti.template(), with_hinges: ti.template()):
    """Phase p of cloth_steps for block blk. Phases per step: (E3) kick-drift, forces and update;
    (E2) forces and update, boundary copy."""
    n = I[H_N]
    if ti.static(what == CLOTH_VV):
        if p % 2 == 0:
            for i in range(I[I[H_VB] + blk], I[I[H_VB] + blk + 1]):
                xi, vi, ai = vertex_update(VELOCITY_VERLET, KICK_DRIFT, x[i], v[i], w[3 * n + i], x[i], F[i],
                                           x[i], dt, ti.math.vec3(0.0))
                x[i] = xi
                v[i] = vi
        else:
            _cloth_block(blk, x, v, w, I, F, dt, what, with_hinges)
    else:
        if p % 2 == 0:
            _cloth_block(blk, x, v, w, I, F, dt, what, with_hinges)
        else:
            for q in range(I[I[H_BOFF] + blk], I[I[H_BOFF] + blk + 1]):
                j = I[I[H_BND] + q]
                x[j] = w[2 * n + j]


@ti.kernel
def cloth_steps(x: vec3_array, v: vec3_array, dt: float, n_steps: ti.i32, w: vec3_array, I: int_array,
                F: scalar_array, sync: int_array, spin_limit: ti.i32, what: ti.template(),
                with_hinges: ti.template()) -> ti.i32:
    """``n_steps`` steps of :func:`cloth_step` (what = CLOTH_SE or CLOTH_VV) in ONE launch. A step is
    two phases (see :func:`_cloth_phase`), each one task per block; the tasks are numbered in order
    (phase p, block b: ticket p nb + b) and every thread of the launch takes the next ticket
    (sync[SYNC_TICKET], an integer atomic), waits until the tasks of the phases before it are done (sync[SYNC_DONE]
    counts them) and does it. Each task runs once and after all of the previous phase, so the
    state is the one of n_steps single-step launches (bitwise), whatever the threads do; a thread
    that starts late finds the others have done its share, and one thread alone does everything
    (nothing waits for a thread that is not running). A parallel loop costs a wake-up of the thread
    pool, 20-60 us here; a phase a few cache-line transfers. Returns 0, or 1 when a wait for the
    tasks before a ticket exceeded ``spin_limit`` polls (the state is then part-way through a step)."""
    sync[SYNC_TICKET] = 0
    sync[SYNC_DONE] = 0
    sync[SYNC_STOP] = 0
    for it in range(I[H_NB] * BLOCK_SLOTS):   # one worker per thread (see cloth_step's loop)
        if it % BLOCK_SLOTS == 0:
            nb = I[H_NB]
            last = 2 * n_steps * nb
            while True:
                t = ti.atomic_add(sync[SYNC_TICKET], 1)
                if t >= last or sync[SYNC_STOP] != 0:
                    break
                p = t // nb
                k = 0
                while ti.atomic_or(sync[SYNC_DONE], 0) < p * nb and sync[SYNC_STOP] == 0 and k < spin_limit:
                    k += 1
                if k >= spin_limit:
                    sync[SYNC_STOP] = 1
                if sync[SYNC_STOP] != 0:
                    break
                _cloth_phase(p, t % nb, x, v, w, I, F, dt, what, with_hinges)
                ti.atomic_add(sync[SYNC_DONE], 1)
    return sync[SYNC_STOP]


@ti.func
def _spring_forces(x: ti.template(), offsets: ti.template(), inc_other: ti.template(),
                   inc_inv_L: ti.template(), inc_c_over_L: ti.template(), f: ti.template()):
    for i in range(x.shape[0]):
        f[i] = spring_gather(x, i, offsets, inc_other, inc_inv_L, inc_c_over_L)


@ti.func
def _potential(x: ti.template(), edges: ti.template(), L: ti.template(), c: ti.template(), n_edges: int,
               mass: ti.template(), inv_mass: ti.template(), g: ti.math.vec3) -> float:
    # W = sum_e 1/2 c_e (l_e/L_e - 1)^2 (springs (S1)), plus W_g = -sum_{free i} m_i g . x_i; serial sums
    W = 0.0
    for e in range(n_edges):
        W += spring_energy(x[edges[e][0]] - x[edges[e][1]], L[e], c[e])
    return add_gravity_potential(W, x, mass, inv_mass, g)


_buffers: dict[int, tuple] = {}


def energy_buffers(n: int):
    """Reusable (kin, pot) ndarrays of at least n entries for the many-steps kernels (chunked runs
    allocate nothing)."""
    size = 1
    while size < n:
        size *= 2
    buf = _buffers.get(size)
    if buf is None:
        buf = _buffers[size] = (ti.ndarray(dtype=float, shape=size), ti.ndarray(dtype=float, shape=size))
    return buf


def collect(kin, pot, done: int, n_steps: int, state, dt: float, monitor, step_offset: int = 0):
    """After a many-steps kernel returned ``done``: the (kinetic, potential) numpy arrays of the steps
    taken, ``state.t`` advanced by them, and the monitor's blow-up raised (with those energies) if the
    run stopped at step ``done``."""
    taken = min(int(done) + 1, n_steps)
    kinetic = kin.to_numpy()[:taken].astype(np.float64)
    potential = pot.to_numpy()[:taken].astype(np.float64)
    state.t += dt * taken
    if done < n_steps:
        raise monitor.blow_up(step_offset + int(done), state.t, float(kinetic[-1] + potential[-1]), kinetic, potential)
    return kinetic, potential


@ti.func
def _record(kin: ti.template(), pot: ti.template(), s, K, W, bound) -> ti.i32:
    """Write step s's energies; 1 when their total marks a blow-up (above the bound, nan or +-inf)."""
    kin[s] = K
    pot[s] = W
    E = K + W
    bad = 0
    if not (E <= bound) or E - E != 0.0:
        bad = 1
    return bad


@ti.kernel
def many_steps(x: vec3_array, v: vec3_array, f: vec3_array, a: vec3_array,
               offsets: int_array, inc_other: int_array, inc_inv_L: scalar_array,
               inc_c_over_L: scalar_array, edges: edge_array, L: scalar_array, c: scalar_array,
               n_edges: ti.i32, mass: scalar_array, inv_mass: scalar_array, g: ti.math.vec3,
               dt: float, n_steps: ti.i32, kin: scalar_array, pot: scalar_array, bound: float,
               method: ti.template()) -> ti.i32:
    """Advance ``n_steps`` steps of a spring-only model; kin[s], pot[s] = energies after step s.
    Returns n_steps, or the index s of the first step whose K + W is above ``bound`` or not finite."""
    n = x.shape[0]
    done = n_steps
    if ti.static(method == VELOCITY_VERLET):  # a(x) of the starting state
        ti.loop_config(serialize=True)
        for _ in range(1):
            _spring_forces(x, offsets, inc_other, inc_inv_L, inc_c_over_L, f)
            for i in range(n):
                update(VELOCITY_VERLET, ACCEL_KICK, i, x, v, f[i], a, inv_mass, g, 0.0, ti.math.vec3(0.0))
    ti.loop_config(serialize=True)
    for s in range(n_steps):
        if ti.static(method == VELOCITY_VERLET):
            for i in range(n):
                update(VELOCITY_VERLET, KICK_DRIFT, i, x, v, f[i], a, inv_mass, g, dt, ti.math.vec3(0.0))
            _spring_forces(x, offsets, inc_other, inc_inv_L, inc_c_over_L, f)
            for i in range(n):
                update(VELOCITY_VERLET, ACCEL_KICK, i, x, v, f[i], a, inv_mass, g, 0.5 * dt, ti.math.vec3(0.0))
        else:
            _spring_forces(x, offsets, inc_other, inc_inv_L, inc_c_over_L, f)
            for i in range(n):
                update(method, STEP, i, x, v, f[i], a, inv_mass, g, dt, ti.math.vec3(0.0))
        if _record(kin, pot, s, kinetic_energy(v, mass), _potential(x, edges, L, c, n_edges, mass, inv_mass, g), bound):
            done = s
            break
    return done


@ti.kernel
def axial_steps(x: scalar_array, v: scalar_array, a: scalar_array, h: scalar_array, E: scalar_array,
                m: scalar_array, inv_m: scalar_array, dt: float, n_steps: ti.i32, kin: scalar_array,
                pot: scalar_array, bound: float, Cp: scalar_array, Dp: scalar_array, method: ti.template()) -> ti.i32:
    """:func:`many_steps` for the rod along its axis (engine.energies.axial (R1), one coordinate per
    node, no gravity): the same updates, backward Euler by the scalar Thomas solve. Returns n_steps,
    or the index of the first step whose K + W is above ``bound`` or not finite."""
    n = x.shape[0]
    done = n_steps
    if ti.static(method == VELOCITY_VERLET):  # a(x) of the starting state
        ti.loop_config(serialize=True)
        for _ in range(1):
            for i in range(n):
                update(VELOCITY_VERLET, ACCEL_KICK, i, x, v, axial_force(x, h, E, i, n), a, inv_m, 0.0, 0.0, 0.0)
    ti.loop_config(serialize=True)
    for s in range(n_steps):
        if ti.static(method == VELOCITY_VERLET):
            for i in range(n):
                update(VELOCITY_VERLET, KICK_DRIFT, i, x, v, 0.0, a, inv_m, 0.0, dt, 0.0)
            for i in range(n):
                a[i] = axial_force(x, h, E, i, n)
            for i in range(n):
                update(VELOCITY_VERLET, ACCEL_KICK, i, x, v, a[i], a, inv_m, 0.0, 0.5 * dt, 0.0)
        elif ti.static(method == BACKWARD_EULER):
            axial_backward_euler(x, v, h, E, m, inv_m, dt, Cp, Dp)
        else:
            for i in range(n):
                Cp[i] = axial_force(x, h, E, i, n)
            for i in range(n):
                update(method, STEP, i, x, v, Cp[i], a, inv_m, 0.0, dt, 0.0)
        if _record(kin, pot, s, kinetic_energy(v, m), axial_potential(x, h, E, n), bound):
            done = s
            break
    return done
