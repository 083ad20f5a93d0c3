"""The cloth step: springs [+ one hinge energy], one parallel loop over vertex blocks per step.

:func:`cloth_step` - a symplectic-Euler or velocity-Verlet step of a springs [+ one hinge
energy] model in ONE launch with ONE parallel loop, over vertex blocks (one per thread): per
block, the springs reaching into it from below, its hinges, then a sweep over its vertices in
order that computes each spring once (its force goes to both ends), completes each vertex's
force and updates it (:func:`_cloth_block`). The terms of every vertex are summed in the order
of the generic path's gathers (springs by neighbour, then hinges by index), so the states are
bitwise the same for any number of blocks and threads (tested). Its arguments are bound once
(engine.launch.BoundKernel): a step costs ~30 us of launch instead of ~0.3 ms.
:func:`cloth_steps` takes many such steps in ONE launch. The updates are
engine.integrators.kernels.vertex_update's (E2) and (E3); engine.integrators.explicit.cloth_plan
builds the plan's arrays.

No kernel uses float atomics: in Taichi ``a[j] += ...`` in a parallel loop is an atomic add
unless j is the loop index, so the block kernels write ``a[j] = a[j] + ...``.
"""
import taichi as ti

from engine.energies.hinge import hinge_forces, hinge_frame
from engine.energies.masses import finish_force
from engine.energies.springs import spring_force
from engine.fields import int_array, scalar_array, vec3_array
from engine.integrators.kernels import ACCEL_KICK, KICK_DRIFT, STEP, SYMPLECTIC_EULER, VELOCITY_VERLET, vertex_update
from engine.tickets import BLOCK_SLOTS, SYNC_DONE, SYNC_STOP, SYNC_TICKET, start, wait_for_phase

# Layout of the plan's int array ``I`` (built by engine.integrators.explicit.cloth_plan): a header
# of section starts, then the sections. The float array ``F`` holds the per-entry coefficients.
(H_NB, H_N, H_VB, H_IN_OFF, H_IN_J, H_UP_OFF, H_UP_C, H_BFLAG, H_BND, H_NBND, H_HOFF, H_HV, H_F_IN, H_F_UP,
 H_F_H, H_F_G, H_MODE, H_BOFF, H_IN_V, H_IN_VOFF) = range(20)
HEADER = 20
# what one cloth_step launch does (CLOTH_FORCES: cloth_forces, the forces only)
CLOTH_SE, CLOTH_VV, CLOTH_VV_BEGIN, CLOTH_FORCES = 0, 1, 2, 3
# springs computed per iteration of a vertex's sweep over its upper springs: two independent square
# roots and divisions in flight, added in the same order (bitwise the same sums). Measured against one
# per iteration, springs only, 10 steps per call, interleaved with Numba: 64^2 48.6-50.0 -> 45.4-45.9
# us per step, 128^2 165 -> 159; four per iteration no faster than two
SPRINGS_PER_ITER = 2


@ti.func
def _hinge_entry(x: ti.template(), I: ti.template(), F: ti.template(), hv, f_h, q, mode):
    """The four forces of the block's hinge entry q (vertices I[hv + 4q ...], k and theta_bar in F):
    engine.energies.hinge.hinge_forces, as engine.energies.bending_kernels.hinge_force_vectors computes them."""
    e, a0, a1 = hinge_frame(x, I[hv + 4 * q], I[hv + 4 * q + 1], I[hv + 4 * q + 2], I[hv + 4 * q + 3])
    return hinge_forces(e, a0, a1, F[f_h + 2 * q], F[f_h + 2 * q + 1], mode)


@ti.func
def _spring_entry(x: ti.template(), I: ti.template(), F: ti.template(), xi, cols, f0, q):
    """The force on the vertex at xi of entry q of a spring list: neighbour I[cols + q], its two
    coefficients at F[f0 + 2q], F[f0 + 2q + 1] (engine.integrators.explicit.cloth_plan's layout)."""
    return spring_force(xi - x[I[cols + q]], F[f0 + 2 * q + 1], F[f0 + 2 * q])


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
    3. per vertex, ascending: the springs to neighbours above i (SPRINGS_PER_ITER at a time, added
       in order), each computed once: subtracted
       from i's sum and, if the neighbour is in the block, added to its w (it comes later, and
       its lower neighbours must come first: they do, since they are all below it); then i's
       forces are complete and i is updated. (E2): an interior vertex (read by no other block)
       drifts in place, a boundary vertex's new x goes to w[2n + i] (copied after the loop).
       (E3) ACCEL_KICK: a (in w[3n + i]) and v only. CLOTH_FORCES: i's elastic force goes to v[i]
       (v is then the force array; nothing else is written)."""
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
            acc += _spring_entry(x, I, F, xi, in_j, f_in, q)
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
        q = I[up_off + i]
        qe = I[up_off + i + 1]
        while q + SPRINGS_PER_ITER - 1 < qe:
            ts = [_spring_entry(x, I, F, xi, up_c, f_up, q + k) for k in ti.static(range(SPRINGS_PER_ITER))]
            for k in ti.static(range(SPRINGS_PER_ITER)):
                c = I[up_c + q + k]
                acc += ts[k]
                if c < hi:
                    w[c] = w[c] - ts[k]
            q += SPRINGS_PER_ITER
        while q < qe:
            c = I[up_c + q]
            t = _spring_entry(x, I, F, xi, up_c, f_up, q)
            acc += t
            if c < hi:
                w[c] = w[c] - t
            q += 1
        f = ti.math.vec3(0.0)
        f += acc
        w[i] = ti.math.vec3(0.0)
        if ti.static(with_hinges):
            f += w[n + i]
            w[n + i] = ti.math.vec3(0.0)
        if ti.static(what == CLOTH_FORCES):
            v[i] = f
        elif ti.static(what == CLOTH_SE):
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


@ti.kernel
def cloth_forces(x: vec3_array, f: vec3_array, w: vec3_array, I: int_array, F: scalar_array, mass: scalar_array,
                 with_hinges: ti.template(), serial: ti.template()):
    """f = the model's forces at x, as engine.model.Model.forces computes them (each vertex's springs,
    then its hinges, then m g; pinned vertices 0), bitwise: the blocks' loop of :func:`cloth_step`
    writing each vertex's elastic force (CLOTH_FORCES), then a per-vertex loop adding the weight
    (engine.energies.masses.finish_force). ``mass``: the model's masses (the plan's F holds inverse masses and g);
    w: the plan's work array (its sums are left zero)."""
    for it in range(I[H_NB] * BLOCK_SLOTS):   # see cloth_step's loop
        if it % BLOCK_SLOTS == 0:
            _cloth_block(it // BLOCK_SLOTS, x, f, w, I, F, 0.0, CLOTH_FORCES, with_hinges)
    g = ti.math.vec3(F[I[H_F_G]], F[I[H_F_G] + 1], F[I[H_F_G] + 2])
    ti.loop_config(serialize=serial)   # engine.fields.serial_pass
    for i in range(f.shape[0]):
        f[i] = finish_force(f[i], mass[i], F[i], g)


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
    two phases (see :func:`_cloth_phase`), each one task per block, handed out by tickets
    (engine.tickets): each task runs once and after all of the previous phase, so the state is the
    one of n_steps single-step launches (bitwise), whatever the threads do. Returns 0, or 1 when a
    wait for the tasks before a ticket exceeded ``spin_limit`` polls (the state is then part-way
    through a step)."""
    start(sync)
    for it in range(I[H_NB] * BLOCK_SLOTS):   # one worker per thread (see cloth_step's loop)
        if it % BLOCK_SLOTS == 0:
            nb = I[H_NB]
            last = 2 * n_steps * nb
            while True:
                t = ti.atomic_add(sync[SYNC_TICKET], 1)
                if t >= last or sync[SYNC_STOP] != 0:
                    break
                p = t // nb
                if wait_for_phase(sync, p, nb, spin_limit) == 0:
                    break
                _cloth_phase(p, t % nb, x, v, w, I, F, dt, what, with_hinges)
                ti.atomic_add(sync[SYNC_DONE], 1)
    return sync[SYNC_STOP]
