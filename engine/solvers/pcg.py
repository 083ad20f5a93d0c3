"""``pcg``: block-Jacobi preconditioned conjugate gradient in Taichi kernels, matrix-free, with
Baraff-Witkin filtering of pinned vertices (the paths it takes are described in
:mod:`engine.solvers`)."""
import math

import taichi as ti

from engine import runtime, tickets
from engine.constants import SERIAL_BELOW
from engine.energies.base import slot_gather
from engine.fields import (free_dot, int_array, int_array2, mat2_array, mat3_array, mat3_array2,
                           scalar_array, vec3_array, vec3_array2, vec3_ndarray, zero_pinned, zero_vec3)
from engine.model import Model
from engine.solvers.operator import LinearSolver, LinearSolveInfo, apply_plan, hessian_plan, scaled_operator
from engine.solvers.pcg_whole import pcg_whole, step_vertex, whole_plan


# --------------------------------------------------------------------------------------------
# Kernels (pinned vertices: inv_mass == 0)
# --------------------------------------------------------------------------------------------

@ti.kernel
def _residual_norms(b: vec3_array, q: vec3_array, inv_mass: scalar_array, c: float) -> ti.math.vec2:
    # (|S(b - c q)|^2, |S b|^2)   (L3), q = A' y with A = c A'
    acc = ti.math.vec2(0.0)
    for i in range(b.shape[0]):
        if inv_mass[i] > 0.0:
            d = b[i] - c * q[i]
            acc += ti.math.vec2(d.dot(d), b[i].dot(b[i]))
    return acc


@ti.kernel
def _diag_init(mass: scalar_array, a: float, D: mat3_array):
    # D_i = a m_i I  (the energies add their 3x3 diagonal blocks H_ii)
    for i in range(mass.shape[0]):
        D[i] = a * mass[i] * ti.math.mat3(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)


@ti.kernel
def _diag_invert(D: mat3_array, inv_mass: scalar_array):
    # block Jacobi: D_i <- D_i^-1 (free, SPD block); scalar Jacobi if the block is singular; 0 if pinned
    for i in range(D.shape[0]):
        B = D[i]
        Binv = ti.math.mat3(0.0)
        if inv_mass[i] > 0.0:
            det = B.determinant()
            scale = ti.abs(B[0, 0]) + ti.abs(B[1, 1]) + ti.abs(B[2, 2])
            if det > 1e-12 * scale * scale * scale and scale > 0.0:
                Binv = B.inverse()
            else:
                for k in ti.static(range(3)):
                    if B[k, k] > 0.0:
                        Binv[k, k] = 1.0 / B[k, k]
        D[i] = Binv


@ti.kernel
def _pcg_restart(b: vec3_array, q: vec3_array, inv_mass: scalar_array, c: float, Pinv: mat3_array,
                 mass: scalar_array, a: float, r: vec3_array, z: vec3_array, p: vec3_array) -> ti.math.vec2:
    # on entry q = A' y:  r = S(b/c - q), z = P^-1 r, p = z, q = a' M p; returns (r.z, r.r)
    acc = ti.math.vec2(0.0)
    for i in range(b.shape[0]):
        ri = ti.math.vec3(0.0)
        if inv_mass[i] > 0.0:
            ri = b[i] / c - q[i]
        zi = Pinv[i] @ ri
        r[i] = ri
        z[i] = zi
        p[i] = zi
        q[i] = a * mass[i] * zi
        acc += ti.math.vec2(ri.dot(zi), ri.dot(ri))
    return acc


@ti.kernel
def _pcg_direction(beta: float, z: vec3_array, p: vec3_array, mass: scalar_array, a: float, q: vec3_array,
                   serial: ti.template()):
    # p = z + beta p ; q = a M p   (p, z are 0 on pinned vertices)
    ti.loop_config(serialize=serial)
    for i in range(p.shape[0]):
        pi = z[i] + beta * p[i]
        p[i] = pi
        q[i] = a * mass[i] * pi


@ti.func
def _rank_one_sum(i, b_off: ti.template(), b_ent: ti.template(), w: ti.template(), s: ti.template(),
                  k: ti.template()):
    # sum_{(e, slot) ~ i} s_e w_e,slot over the incidence (entry = k e + slot), from 0, in that order
    acc = ti.math.vec3(0.0)
    for j in range(b_off[i], b_off[i + 1]):
        ent = b_ent[j]
        acc += s[ent // k] * w[ent // k, ent % k]
    return acc


@ti.func
def _element_product(blocks: ti.template(), dinv: ti.template(), elements: ti.template(), z: ti.template(),
                     p: ti.template(), beta, yt: ti.template(), e, k: ti.template(), form: ti.template()):
    # yt[e, a] = sum_b H_e,ab (z + beta p)[element vertex b]: form 0, one element's stored blocks (layout
    # (m, k*k)); otherwise form is the energy's deformation_corners ti.func, blocks its deformation blocks
    # (m, 3) and dinv its rest frames ("deformation-blocks", engine/energies/base.py)
    if ti.static(form == 0):
        for a in ti.static(range(k)):
            acc = ti.math.vec3(0.0)
            for b in ti.static(range(k)):
                v = elements[e, b]
                acc += blocks[e, k * a + b] @ (z[v] + beta * p[v])
            yt[e, a] = acc
    else:
        ys = form(blocks, dinv, elements, z, p, beta, e)
        for a in ti.static(range(k)):
            yt[e, a] = ys[a]


@ti.kernel
def _element_products(blocks: mat3_array2, dinv: mat2_array, elements: int_array2, z: vec3_array, p: vec3_array,
                      beta: float, yt: vec3_array2, k: ti.template(), form: ti.template(), serial: ti.template()):
    # per element, its blocks times the new direction z + beta p (formed on the fly)
    ti.loop_config(serialize=serial)
    for e in range(elements.shape[0]):
        _element_product(blocks, dinv, elements, z, p, beta, yt, e, k, form)


@ti.kernel
def _pcg_step(alpha: float, p: vec3_array, q: vec3_array, inv_mass: scalar_array, Pinv: mat3_array,
              y: vec3_array, r: vec3_array, z: vec3_array, serial: ti.template()) -> ti.math.vec2:
    # y += alpha p ; r -= alpha S q ; z = P^-1 r ; returns (r.z, r.r)
    acc = ti.math.vec2(0.0)
    ti.loop_config(serialize=serial)
    for i in range(p.shape[0]):
        if inv_mass[i] > 0.0:
            acc += step_vertex(i, alpha, p, q, Pinv, y, r, z)
    return acc


@ti.kernel
def _rank_one_s(w: vec3_array2, elements: int_array2, z: vec3_array, p: vec3_array, beta: float, s: scalar_array,
                k: ti.template(), serial: ti.template()):
    # s_e = w_e . (z + beta p) over the element's k vertices (the new direction, formed on the fly)
    ti.loop_config(serialize=serial)
    for e in range(elements.shape[0]):
        acc = 0.0
        for a in ti.static(range(k)):
            v = elements[e, a]
            acc += w[e, a].dot(z[v] + beta * p[v])
        s[e] = acc


@ti.kernel
def _fused_direction_product(beta: float, z: vec3_array, p: vec3_array, p_new: vec3_array, q: vec3_array,
                             mass: scalar_array, inv_mass: scalar_array, a: float,
                             s_off: int_array, s_edge: int_array, s_other: int_array, s_blocks: mat3_array,
                             b_off: int_array, b_ent: int_array, w: vec3_array2, s: scalar_array,
                             c_off: int_array, c_ent: int_array, yt: vec3_array2,
                             k: ti.template(), kc: ti.template(), serial: ti.template()) -> float:
    # p_new = z + beta p ; q = a' M p_new + sum_{e ~ i} K_e (p_new_i - p_new_j) + sum_{(e, slot) ~ i} s_e w_e,slot
    # (pair-gather blocks, e.g. springs (S4); rank-one k-vertex elements, e.g. hinges) + sum of the element
    # products yt of a block energy (kc-vertex elements, e.g. membranes); returns p_new . q over free vertices.
    # p and p_new are different buffers, so the neighbours' new directions are formed from (z, p) without
    # a race.
    acc = 0.0
    ti.loop_config(serialize=serial)
    for i in range(z.shape[0]):
        pi = z[i] + beta * p[i]
        qi = a * mass[i] * pi
        for m in range(s_off[i], s_off[i + 1]):
            j = s_other[m]
            qi += s_blocks[s_edge[m]] @ (pi - (z[j] + beta * p[j]))
        qi = qi + _rank_one_sum(i, b_off, b_ent, w, s, k)
        qi = qi + slot_gather(yt, c_off, c_ent, i, kc)   # the generic path's q += gather(products)
        p_new[i] = pi
        q[i] = qi
        if inv_mass[i] > 0.0:
            acc += pi.dot(qi)
    return acc


class PCGSolver(LinearSolver):
    """Matrix-free block-Jacobi preconditioned CG with Baraff-Witkin filtering (module docstring).

    Fast paths (``fused=True``), used when the model's energies are at most one declaring the
    "pair-gather" product (springs), at most one declaring "rank-one" (bending) and at most one
    declaring "element-blocks" (a membrane: per-element H_e p, then gathered), nothing else,
    and psd=True: on one or two threads, or below SERIAL_BELOW vertices (or ``serial=True``), the whole
    CG loop is one kernel (:mod:`engine.solvers.pcg_whole`: serial below WHOLE_SPLIT_FROM vertices,
    else on the mesh's two halves shared by the threads; ``whole_threads=1`` runs the halves on one
    thread, the same result); otherwise
    three parallel launches per iteration (per-element s_e = w_e . p with the
    rank-one Gauss-Newton Hessian H_e = w_e w_e^T; per-vertex direction p = z + beta p,
    q = a' M p + sum_pairs K_e (p_i - p_j) + sum_elements s_e w_e,slot and p.q; step +
    preconditioner + r.z, r.r).  Otherwise (other energies, psd=False, an extra term,
    ``fused=False``) the generic path calls each energy's block or Hessian-vector product
    (4 + per-energy launches per iteration)."""

    name = "pcg"

    def __init__(self, tol: float = 1e-8, max_iter: int = 1000, fused: bool = True, serial: bool | None = None,
                 whole_threads: int | None = None):
        super().__init__(tol, max_iter)
        self.fused = bool(fused)
        self.serial = serial  # None: the whole-loop kernel on <= 2 threads, else below SERIAL_BELOW vertices
        self.whole_threads = whole_threads  # None: the whole-loop kernel's blocks shared by Taichi's threads; 1: one
        self.gave_up = 0      # whole-loop solves in which a worker gave up waiting (engine.tickets)

    def _work(self, model: Model) -> dict:
        entry = self._entry(model)
        if "r" not in entry:
            n = model.n
            # racc: the whole-loop kernel's rank-one sums (p2, free there, holds its block energy's, acc)
            entry.update(r=vec3_ndarray(n), z=vec3_ndarray(n), p=vec3_ndarray(n), p2=vec3_ndarray(n),
                         q=vec3_ndarray(n), racc=vec3_ndarray(n), pn=vec3_ndarray(n),
                         Pinv=ti.ndarray(dtype=ti.math.mat3, shape=n))
        return entry

    def _fused_setup(self, model: Model, entry: dict, x, psd: bool, blocks: dict):
        """Arguments of the fused kernels, or None if the fast path does not apply:
        (pair-gather energy's (offsets, inc_edge, inc_other, blocks), with the blocks the plan
        computed; the rank-one work dict: elements, n elements, k, incidence off/ent, factors w
        from gauss_newton_factors, scratch s).  A missing energy gets empty stand-ins (n = 0)."""
        if not (self.fused and psd):
            return None
        pairs = [e for e in model.energies if "pair-gather" in e.products]
        ranks = [e for e in model.energies if "rank-one" in e.products and "pair-gather" not in e.products]
        elems = [e for e in model.energies if "element-blocks" in e.products and e not in pairs + ranks]
        if len(pairs) + len(ranks) + len(elems) != len(model.energies) or max(len(pairs), len(ranks), len(elems)) > 1:
            return None
        if "no_pair" not in entry:
            off = ti.ndarray(dtype=ti.i32, shape=model.n + 1)  # zeros: no incidences
            i1 = ti.ndarray(dtype=ti.i32, shape=1)
            v11 = ti.ndarray(dtype=ti.math.vec3, shape=(1, 1))
            entry["no_pair"] = (off, i1, i1, ti.ndarray(dtype=ti.math.mat3, shape=1))
            entry["no_rank"] = dict(elements=ti.ndarray(dtype=ti.i32, shape=(1, 1)), n=0, k=1, off=off, ent=i1,
                                    w=v11, s=ti.ndarray(dtype=float, shape=1))
            entry["no_elem"] = dict(blocks=ti.ndarray(dtype=ti.math.mat3, shape=(1, 1)),
                                    dinv=ti.ndarray(dtype=ti.math.mat2, shape=1), form=0,
                                    elements=ti.ndarray(dtype=ti.i32, shape=(1, 1)), n=0, k=1, off=off, ent=i1,
                                    yt=v11)
        pair = entry["no_pair"]
        if pairs and pairs[0].n_elements:
            pair = (*pairs[0].pair_incidence, blocks[id(pairs[0])])
        rank = entry["no_rank"]
        if ranks and ranks[0].n_elements:
            e = ranks[0]
            key = ("rank-one", id(e))
            if key not in entry:
                m, k = e.n_elements, e.stencil_size
                off, ent = e.slot_incidence
                entry[key] = dict(elements=e.elements, n=m, k=k, off=off, ent=ent,
                                  w=ti.ndarray(dtype=ti.math.vec3, shape=(m, k)), s=ti.ndarray(dtype=float, shape=m))
            rank = entry[key]
            e.gauss_newton_factors(x, rank["w"])
        elem = entry["no_elem"]
        if elems and elems[0].n_elements:
            e = elems[0]
            key = ("element-blocks", id(e))
            if key not in entry:
                off, ent = e.slot_incidence
                entry[key] = dict(elements=e.elements, n=e.n_elements, k=e.stencil_size, off=off, ent=ent,
                                  yt=ti.ndarray(dtype=ti.math.vec3, shape=(e.n_elements, e.stencil_size)))
            if "deformation-blocks" in e.products:   # 27 numbers per triangle per iteration instead of 81
                elem = dict(entry[key], blocks=e.deformation_blocks(x, psd), dinv=e.Dinv, form=e.deformation_corners)
            else:
                elem = dict(entry[key], blocks=blocks[id(e)], dinv=entry["no_elem"]["dinv"], form=0)
        return pair, rank, elem

    def solve(self, model: Model, x, b, y, mass_coef: float, hess_coef: float = 1.0,
              psd: bool = True, extra=None) -> LinearSolveInfo:
        a, c = self._coefficients(mass_coef, hess_coef)
        w = self._work(model)
        r, z, q, Pinv = w["r"], w["z"], w["q"], w["Pinv"]
        p, p2 = w["p"], w["p2"]
        inv_mass, mass = model.inv_mass_nd, model.mass_nd
        a_s = a / c  # solve A' y = b / c with A' = a' M + H
        blocks = {}
        plan = hessian_plan(model, x, psd, scaled_operator(extra, c), blocks, w["work"])
        fused = None if scaled_operator(extra, c) is not None else self._fused_setup(model, w, x, psd, blocks)
        serial = self.serial if self.serial is not None else (model.n < SERIAL_BELOW or runtime.threads(2) <= 2)
        whole = fused is not None and serial  # the whole CG loop in one kernel (engine.solvers.pcg_whole)

        # block-Jacobi preconditioner P = blockdiag(a' m_i I + H_ii)
        _diag_init(mass, a_s, Pinv)
        for e in model.energies:
            try:
                e.add_hessian_diagonal(x, Pinv, psd)
            except NotImplementedError:
                pass  # that energy is left out of the preconditioner (still correct, slower)
        _diag_invert(Pinv, inv_mass)

        zero_vec3(y)
        zero_vec3(q)
        rz, rr = _pcg_restart(b, q, inv_mass, c, Pinv, mass, a_s, r, z, p)
        bb = rr  # |S b / c|^2
        if bb == 0.0:
            return self._info(0, 0.0)
        target2 = (0.5 * self.tol) ** 2 * bb  # the recurrence aims at tol/2 (margin for drift)
        it = 0
        message = ""
        while True:
            beta = 0.0  # after a (re)start: p = z
            if whole and it < self.max_iter and rr > target2:
                pair, rk, el = fused
                B, parts, out, sync, nb = whole_plan(model, w, rk, el)
                pn = p if nb == 1 else w["pn"]
                k_it, rr, bad, gave_up = pcg_whole(rz, target2, self.max_iter - it, z, p, pn, q, r, y, mass, inv_mass,
                                                    a_s, Pinv, *pair, rk["elements"], rk["w"], el["blocks"],
                                                    el["dinv"], el["elements"], p2, w["racc"], B, parts, out, sync,
                                                    tickets.SPIN_LIMIT, rk["k"], el["k"], el["form"], nb == 1,
                                                    nb == 1 or self.whole_threads == 1)
                it += int(k_it)
                self.gave_up += int(gave_up)   # a thread stopped for seconds: restarted from y below
                if bad:
                    message = "A is not positive definite on a search direction (p.Ap <= 0)"
            while not whole and it < self.max_iter and rr > target2:
                if fused is not None:
                    pair, rk, el = fused
                    if rk["n"]:
                        _rank_one_s(rk["w"], rk["elements"], z, p, beta, rk["s"], rk["k"], serial)
                    if el["n"]:
                        _element_products(el["blocks"], el["dinv"], el["elements"], z, p, beta, el["yt"], el["k"],
                                          el["form"], serial)
                    pq = _fused_direction_product(beta, z, p, p2, q, mass, inv_mass, a_s, *pair, rk["off"],
                                                  rk["ent"], rk["w"], rk["s"], el["off"], el["ent"], el["yt"],
                                                  rk["k"], el["k"], serial)
                    p, p2 = p2, p
                else:
                    _pcg_direction(beta, z, p, mass, a_s, q, serial)  # p = z + beta p ; q = a' M p
                    for add in plan:                          # q += H p
                        add(p, q)
                    pq = free_dot(p, q, inv_mass, serial)
                if not (pq > 0.0):
                    message = f"A is not positive definite on the search direction (p.Ap = {pq:.3e})"
                    break
                rz_new, rr = _pcg_step(rz / pq, p, q, inv_mass, Pinv, y, r, z, serial)
                it += 1
                beta = rz_new / rz
                rz = rz_new
            # true residual (L3); if the recurrence drifted above tol, restart from y
            apply_plan(model, plan, a_s, y, q)
            res2, _ = _residual_norms(b, q, inv_mass, c)
            residual = math.sqrt(res2 / (bb * c * c))
            if residual <= self.tol or it >= self.max_iter or message:
                break
            rz, rr = _pcg_restart(b, q, inv_mass, c, Pinv, mass, a_s, r, z, p)
        zero_pinned(y, inv_mass)
        return self._info(it, residual, message)
