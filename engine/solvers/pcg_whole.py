"""The PCG solver's whole-loop kernel: the whole CG loop in one launch (engine.solvers.pcg's fast path
on one or two threads). Below WHOLE_SPLIT_FROM vertices it is serial; from there it works on the
mesh's two halves, two phases per iteration handed to the threads by tickets (engine.tickets), each
half making the products of its own vertices, the dot products summed from the halves' partial sums.
:func:`whole_plan` builds its per-model plan (numpy, once)."""
import numpy as np
import taichi as ti

from engine import tickets
from engine.constants import WHOLE_SPLIT_FROM
from engine.fields import (int_array, int_array2, int_ndarray, mat2_array, mat3_array, mat3_array2, scalar_array,
                           vec3_array, vec3_array2)

__all__ = ["pcg_whole", "step_vertex", "whole_plan"]


@ti.func
def step_vertex(i, alpha, p: ti.template(), q: ti.template(), Pinv: ti.template(), y: ti.template(),
                r: ti.template(), z: ti.template()):
    # free vertex i: y_i += alpha p_i ; r_i -= alpha q_i ; z_i = P_i^-1 r_i ; returns (r_i.z_i, r_i.r_i)
    # (y[i] = y[i] + ...: in a parallel loop whose index is not i, Taichi makes ``+=`` an atomic add)
    y[i] = y[i] + alpha * p[i]
    ri = r[i] - alpha * q[i]
    zi = Pinv[i] @ ri
    r[i] = ri
    z[i] = zi
    return ti.math.vec2(ri.dot(zi), ri.dot(ri))


# The whole-loop kernel's plan (int array B, built once per model by whole_plan): a header of
# section starts, then the sections, each a CSR (offsets per block, entries)
(W_NB, W_VB, W_R_OFF, W_R_ENT, W_C_OFF, W_C_ENT, W_IN_OFF, W_IN_V) = range(8)
W_HEADER = 8
W_DONE = 2   # sync[SYNC_STOP] when the loop ended (converged, max_iter or p.q <= 0)


@ti.func
def _part(kk, nb, blk, c):
    # where iteration kk's partial sum c (0: p.q, 1: r.z, 2: r.r) of block blk lives: a ring of three iterations
    return ((kk % 3) * nb + blk) * 3 + c


@ti.func
def _part_sum(parts: ti.template(), kk, nb, c):
    # iteration kk's sum c over the blocks, in block order
    s = parts[_part(kk, nb, 0, c)]
    for blk in range(1, nb):
        s += parts[_part(kk, nb, blk, c)]
    return s


@ti.func
def _whole_direction(v, lo, hi, z: ti.template(), p: ti.template(), pn: ti.template(), beta,
                     one_block: ti.template()):
    # the new direction at vertex v: the block's own from pn, another block's formed from (z, p) as its
    # own block forms it (bit for bit the same); one block: pn is p, already updated in place
    d = ti.math.vec3(0.0)
    if ti.static(one_block):
        d = pn[v]
    else:
        if lo <= v and v < hi:
            d = pn[v]
        else:
            d = z[v] + beta * p[v]
    return d


@ti.func
def _add_corners(ys: ti.template(), els: ti.template(), e, lo, hi, acc: ti.template(), kc: ti.template()):
    # acc[corner] += the element's product at that corner, for its corners in [lo, hi)
    for sl in ti.static(range(kc)):
        v = els[e, sl]
        if lo <= v and v < hi:
            acc[v] = acc[v] + ys[sl]


@ti.func
def _whole_products(blk, kk, beta, z: ti.template(), p: ti.template(), pn: ti.template(), q: ti.template(),
                    mass: ti.template(), inv_mass: ti.template(), a, s_off: ti.template(), s_edge: ti.template(),
                    s_other: ti.template(), s_blocks: ti.template(), elements: ti.template(), w: ti.template(),
                    c_blocks: ti.template(), c_dinv: ti.template(), c_elements: ti.template(), acc: ti.template(),
                    racc: ti.template(), B: ti.template(), parts: ti.template(), k: ti.template(),
                    kc: ti.template(), form: ti.template(), one_block: ti.template()):
    # on the block's vertices [lo, hi): pn = z + beta p, q = a' M pn + H pn, and the block's share of pn.q
    nb = B[W_NB]
    lo = B[B[W_VB] + blk]
    hi = B[B[W_VB] + blk + 1]
    for i in range(lo, hi):
        pi = z[i] + beta * p[i]
        pn[i] = pi
        q[i] = a * mass[i] * pi
        if kk == 0:   # later the sweep zeroes the sums after use
            acc[i] = ti.math.vec3(0.0)
            racc[i] = ti.math.vec3(0.0)
    # the rank-one elements touching the block (ascending), each product added to its corners in it
    r_ent = B[W_R_ENT]
    for m in range(B[B[W_R_OFF] + blk], B[B[W_R_OFF] + blk + 1]):
        e = B[r_ent + m]
        se = 0.0
        for sl in ti.static(range(k)):
            se += w[e, sl].dot(_whole_direction(elements[e, sl], lo, hi, z, p, pn, beta, one_block))
        for sl in ti.static(range(k)):
            v = elements[e, sl]
            if lo <= v and v < hi:
                racc[v] = racc[v] + se * w[e, sl]
    # the block energy's elements touching the block (ascending), the same way
    c_ent = B[W_C_ENT]
    for m in range(B[B[W_C_OFF] + blk], B[B[W_C_OFF] + blk + 1]):
        e = B[c_ent + m]
        if ti.static(form == 0):
            for sl in ti.static(range(kc)):
                v = c_elements[e, sl]
                if lo <= v and v < hi:
                    ya = ti.math.vec3(0.0)
                    for sb in ti.static(range(kc)):
                        d = _whole_direction(c_elements[e, sb], lo, hi, z, p, pn, beta, one_block)
                        ya += c_blocks[e, kc * sl + sb] @ (d + 0.0 * d)   # _element_product's arithmetic
                    acc[v] = acc[v] + ya
        elif ti.static(one_block):   # the products straight to the sums (not through yt: ~20% of this loop at 32^2)
            _add_corners(form(c_blocks, c_dinv, c_elements, pn, pn, 0.0, e), c_elements, e, lo, hi, acc, kc)
        else:   # the direction formed from (z, p) as the own blocks form it
            _add_corners(form(c_blocks, c_dinv, c_elements, z, p, beta, e), c_elements, e, lo, hi, acc, kc)
    # the block's vertices with pairs to vertices below the block: those terms first (ascending, as
    # the sweep would have made them); K_e (p_l - p_u) is what the lower end's sweep subtracts
    in_v = B[W_IN_V]
    for m in range(B[B[W_IN_OFF] + blk], B[B[W_IN_OFF] + blk + 1]):
        u = B[in_v + m]
        pu = pn[u]
        qu = q[u]
        for mm in range(s_off[u], s_off[u + 1]):
            lv = s_other[mm]
            if lv < lo:
                qu = qu - s_blocks[s_edge[mm]] @ (z[lv] + beta * p[lv] - pu)
        q[u] = qu
    pq = 0.0
    for i in range(lo, hi):
        pi = pn[i]
        qi = q[i]   # a' m_i p_i + K_e (p_i - p_j) of its pairs to lower j, added in ascending j
        for m in range(s_off[i], s_off[i + 1]):
            j = s_other[m]
            if j > i:   # each pair once: its term goes to both ends (K_e (p_j - p_i) is -t exactly)
                t = s_blocks[s_edge[m]] @ (pi - _whole_direction(j, lo, hi, z, p, pn, beta, one_block))
                qi += t
                if j < hi:   # a vertex above the block takes it in its own block's first pass
                    q[j] = q[j] - t
        qi = qi + racc[i]  # the fused path's rank-one sum
        qi = qi + acc[i]   # the fused path's q += gather(products)
        racc[i] = ti.math.vec3(0.0)
        acc[i] = ti.math.vec3(0.0)
        q[i] = qi
        if inv_mass[i] > 0.0:
            pq += pi.dot(qi)
    parts[_part(kk, nb, blk, 0)] = pq


@ti.kernel
def pcg_whole(rz0: float, target2: float, max_iter: ti.i32,
               z: vec3_array, p: vec3_array, pn: vec3_array, q: vec3_array, r: vec3_array, y: vec3_array,
               mass: scalar_array, inv_mass: scalar_array, a: float, Pinv: mat3_array,
               s_off: int_array, s_edge: int_array, s_other: int_array, s_blocks: mat3_array,
               elements: int_array2, w: vec3_array2, c_blocks: mat3_array2, c_dinv: mat2_array,
               c_elements: int_array2, acc: vec3_array, racc: vec3_array, B: int_array, parts: scalar_array,
               out: scalar_array, sync: int_array, spin_limit: ti.i32,
               k: ti.template(), kc: ti.template(), form: ti.template(), one_block: ti.template(),
               serialize: ti.template()) -> ti.math.vec4:
    # The whole CG loop in one launch (no launch or argument overhead per iteration), on the plan's
    # vertex blocks (one, or two halves whose tasks the threads share), its phases handed out by
    # tickets (engine.tickets). Starts from r, z, p set by _pcg_restart. Per iteration two phases of
    # one task per block: (0) pn = z + beta p, q = a' M pn + H pn and the block's pn.q (a neighbour in
    # another block's direction formed from (z, p) as that block forms it); (1) alpha = r.z / p.q,
    # y += alpha pn, r -= alpha q, z = P^-1 r, p = pn and the block's r.z, r.r. Every scalar is a sum of
    # the blocks' partial sums in block order (a ring of three iterations), which every task computes
    # alike, so the loop ends at the same phase for all, and the result is the same bit for bit however
    # many threads run it. Each element's product and each spring pair's term is made by the block of
    # the vertex it goes to, in the order of the slot and pair incidences (elements, neighbours
    # ascending per vertex), so every sum is the fused path's gather bit for bit. ``one_block`` (pn is
    # p, updated in place): the serial loop. ``serialize``: one thread does every task (a serial task,
    # the same arithmetic). Returns (iterations, r.r, 1 if p.q <= 0, 1 if a worker gave up).
    tickets.start(sync)
    nb = B[W_NB]
    ti.loop_config(serialize=serialize)   # a serial task: Taichi compiles it faster than a parallel one
    for it0 in range(nb * tickets.BLOCK_SLOTS):
        if it0 % tickets.BLOCK_SLOTS == 0:
            last = (2 * max_iter + 1) * nb
            while True:
                t = ti.atomic_add(sync[tickets.SYNC_TICKET], 1)
                if t >= last or sync[tickets.SYNC_STOP] != 0:
                    break
                ph = t // nb
                if tickets.wait_for_phase(sync, ph, nb, spin_limit) == 0:
                    break
                kk = ph // 2
                blk = t % nb
                done = 0
                if ph % 2 == 0:
                    beta = 0.0
                    if kk > 0:
                        rr = _part_sum(parts, kk - 1, nb, 2)
                        if rr <= target2 or kk >= max_iter:
                            out[0] = kk
                            out[1] = rr
                            out[2] = 0.0
                            done = 1
                        else:
                            rz_old = rz0
                            if kk > 1:
                                rz_old = _part_sum(parts, kk - 2, nb, 1)
                            beta = _part_sum(parts, kk - 1, nb, 1) / rz_old
                    if done == 0:
                        _whole_products(blk, kk, beta, z, p, pn, q, mass, inv_mass, a, s_off, s_edge, s_other,
                                        s_blocks, elements, w, c_blocks, c_dinv, c_elements, acc, racc, B, parts,
                                        k, kc, form, one_block)
                else:
                    pq = _part_sum(parts, kk, nb, 0)
                    rz = rz0
                    rr_prev = target2 + 1.0
                    if kk > 0:
                        rz = _part_sum(parts, kk - 1, nb, 1)
                        rr_prev = _part_sum(parts, kk - 1, nb, 2)
                    if pq <= 0.0:
                        out[0] = kk
                        out[1] = rr_prev
                        out[2] = 1.0
                        done = 1
                    else:
                        alpha = rz / pq
                        acc2 = ti.math.vec2(0.0)
                        for i in range(B[B[W_VB] + blk], B[B[W_VB] + blk + 1]):
                            if inv_mass[i] > 0.0:
                                acc2 += step_vertex(i, alpha, pn, q, Pinv, y, r, z)
                            if ti.static(not one_block):
                                p[i] = pn[i]
                        parts[_part(kk, nb, blk, 1)] = acc2[0]
                        parts[_part(kk, nb, blk, 2)] = acc2[1]
                if done == 1:
                    sync[tickets.SYNC_STOP] = W_DONE   # every task of this phase decides alike
                    break
                ti.atomic_add(sync[tickets.SYNC_DONE], 1)
    gave_up = 0.0
    if sync[tickets.SYNC_STOP] == tickets.GAVE_UP:   # part-way through an iteration: the caller restarts from y
        gave_up = 1.0
        out[0] = sync[tickets.SYNC_DONE] // (2 * nb)
        out[1] = target2 + 1.0
        out[2] = 0.0
    return ti.math.vec4(out[0], out[1], out[2], gave_up)


def whole_plan(model, entry: dict, rank: dict, elem: dict) -> tuple:
    """(B, parts, out, sync, nb) of the whole-loop kernel for this model and these energies: one vertex
    block below WHOLE_SPLIT_FROM vertices, else the two halves (the split depends on the mesh only,
    so the results do not depend on the number of threads); per block, the rank-one and block
    energy's elements with a corner in it and the vertices with a spring pair to a vertex below it
    (numpy set-up, once per model; kept in the solver's ``entry``)."""
    key = ("whole-plan", rank["n"], elem["n"])
    if key not in entry:
        n = model.n
        nb = 2 if n >= WHOLE_SPLIT_FROM else 1
        vb = np.array([0, n // 2, n] if nb == 2 else [0, n], dtype=np.int64)

        def touching(els_nd, m):
            if m == 0:
                return [np.zeros(0, np.int64)] * nb
            els = np.asarray(els_nd.to_numpy(), dtype=np.int64)[:m]
            return [np.flatnonzero(((els >= vb[b]) & (els < vb[b + 1])).any(axis=1)) for b in range(nb)]

        r_lists = touching(rank["elements"], rank["n"])
        c_lists = touching(elem["elements"], elem["n"])
        pairs = [e for e in model.energies if "pair-gather" in e.products]
        in_lists = [np.zeros(0, np.int64)] * nb
        if pairs and pairs[0].n_elements:
            off, _, other = (np.asarray(a.to_numpy(), dtype=np.int64) for a in pairs[0].pair_incidence)
            row = np.repeat(np.arange(n), np.diff(off[:n + 1]))
            block_of = np.searchsorted(vb, np.arange(n), side="right") - 1
            below = other < vb[block_of[row]]
            in_lists = [np.unique(row[below & (block_of[row] == b)]) for b in range(nb)]
        sections = [vb]
        for lists in (r_lists, c_lists, in_lists):
            sections.append(np.concatenate([[0], np.cumsum([len(x) for x in lists])]))
            sections.append(np.concatenate(lists) if sum(len(x) for x in lists) else np.zeros(1, np.int64))
        header = np.zeros(W_HEADER, dtype=np.int64)
        header[W_NB] = nb
        pos = W_HEADER
        for h, sec in zip((W_VB, W_R_OFF, W_R_ENT, W_C_OFF, W_C_ENT, W_IN_OFF, W_IN_V), sections):
            header[h] = pos
            pos += len(sec)
        B = np.concatenate([header] + sections)
        entry[key] = (int_ndarray(B), ti.ndarray(dtype=float, shape=9 * nb), ti.ndarray(dtype=float, shape=3),
                      int_ndarray(np.zeros(tickets.SYNC_SIZE, dtype=np.int64)), nb)
    return entry[key]
