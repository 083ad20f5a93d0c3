"""The baseline a user would otherwise write: the same steps in vectorised numpy and scipy.

Cloth (:class:`NumpyCloth`), the scene of :func:`engine.scenes.cloth`:

* Springs: W_e = 1/2 c_e (l/L - 1)^2, forces scattered with ``np.bincount``.
* Bending (notes' energy, W_e = 1/2 k_e (theta - theta_bar)^2): dtheta/dw_a = -n_a/h_a for the
  wing vertices, and the edge vertices take the barycentric combinations that make the four sum
  to zero (Bridson et al. 2003's u1..u4).
* Explicit: symplectic Euler with gravity and pins.
* Implicit (:meth:`NumpyElastic.backward_euler`): one Baraff-Witkin step, the same linear system as
  the engine's backward Euler with one Newton iteration (engine/integrators/implicit.py (N1)):

      (M/dt^2 + H_psd(x_n)) dx = f(x_n) + M g + M v_n/dt,     x+ = x_n + dx,  v+ = dx/dt

  with H_psd the PSD-projected spring blocks (S4) and the Gauss-Newton hinge blocks
  k_e g_a g_b^T (g = grad theta), assembled as a careful user would: the CSR pattern and the map
  from element blocks to it computed once (pinned degrees of freedom dropped), then one
  ``np.bincount`` per step and solved by ``scipy.sparse.linalg.cg`` with a (scalar) Jacobi
  preconditioner to the relative residual ``tol`` (||b - A dx|| <= tol ||b||, the engine's (L3)).

Membrane (:class:`NumpyMembrane`), the same mesh with Baraff-Witkin's stretch and shear conditions
(engine/energies/triangle.py (M2)) instead of springs and hinges: its forces and its PSD blocks
per triangle (stretch clipped, shear Gauss-Newton), the same assembly, solvers and step.

Rod (:class:`NumpyRod`), the rod of :class:`engine.rod.Rod`: f_i = E_i s_i - E_{i-1} s_{i-1};
symplectic Euler vectorised, backward Euler (M + dt^2 K) v+ = M v + dt f(x) with
``scipy.linalg.solve_banded`` (what one writes for a tridiagonal system).

Used by the benchmarks (timed against the Taichi engine in the same run) and by their
correctness checks (the two must agree on the same input).
"""
import time

import numpy as np
import scipy.linalg
import scipy.sparse
import scipy.sparse.linalg

_COMP_A, _COMP_B = np.divmod(np.arange(9), 3)   # row and column component of each of a block's 9 values


def stencil_pairs(k: int) -> list:
    """The slot pairs (a, b), a <= b, of a stencil of ``k`` vertices: the blocks a symmetric
    element matrix is stored by (the (b, a) block is the transpose)."""
    return [(a, b) for a in range(k) for b in range(a, k)]


def stencil_placements(elements: np.ndarray, offset: int) -> list:
    """Where each value of a stencil energy's blocks goes: for elements (E, k), whose values are
    numbered offset + (e * P + p) * 9 + c (P = the k(k+1)/2 pairs of :func:`stencil_pairs`, c the
    block's row-major entry), the (value index, row vertex, column vertex, row component, column
    component, sign) arrays of block (a, b) and, for a != b, its transpose at (b, a)."""
    E, k = elements.shape
    pairs = stencil_pairs(k)
    out = []
    for p, (a, b) in enumerate(pairs):
        idx = offset + (np.arange(E)[:, None] * len(pairs) + p) * 9 + np.arange(9)[None, :]
        for ra, rb, aa, bb in ((a, b, _COMP_A, _COMP_B),) + (((b, a, _COMP_B, _COMP_A),) if a != b else ()):
            out.append((idx.ravel(), np.repeat(elements[:, ra], 9), np.repeat(elements[:, rb], 9),
                        np.tile(aa, E), np.tile(bb, E), np.ones(9 * E)))
    return out


class NumpyElastic:
    """What every numpy baseline shares: the model's masses, pins and gravity, symplectic Euler,
    and the implicit step's assembly (a CSR pattern and scatter matrix built once), system, solve
    and update.  A subclass gives ``terms(x)`` (what its forces and blocks share, computed once per
    step), ``forces(x, terms)``, ``block_values(x, terms)`` (the per-step values, flat) and
    ``placements()`` (where each value goes, :func:`stencil_placements`' arrays)."""

    def __init__(self, model):
        self.n = model.n
        self.inv_mass = np.where(model.pinned, 0.0, 1.0 / model.mass)
        self.free = (~model.pinned)[:, None]
        self.pinned = np.asarray(model.pinned, dtype=bool)
        self.mass = np.asarray(model.mass, dtype=np.float64)
        self.g = np.asarray(model.gravity, dtype=np.float64)
        # degree-of-freedom numbering with the pinned vertices eliminated (-1)
        free_dof = np.repeat(~self.pinned, 3)
        self.dof = np.full(3 * self.n, -1, dtype=np.int64)
        self.dof[free_dof] = np.arange(int(free_dof.sum()))
        self.n_free_dofs = int(free_dof.sum())
        self.last_assembly_s = self.last_solve_s = 0.0
        self._patterns = {}
        self._values = None
        self.last_iterations = 0
        self.last_residual = 0.0

    def _scatter(self, idx, vec, out):
        for a in range(3):
            out[:, a] += np.bincount(idx, weights=vec[:, a], minlength=self.n)

    def terms(self, x):
        return None

    def _finish_forces(self, f):
        f += self.mass[:, None] * self.g
        return f * self.free

    def symplectic_euler(self, x, v, dt, n_steps=1):
        for _ in range(n_steps):
            v += dt * self.inv_mass[:, None] * self.forces(x)
            x += dt * v
        return x, v

    # -- implicit --------------------------------------------------------------------------------
    # A careful numpy user computes only the block values per step and sends them through a
    # scatter map built once: a sparse matrix S with one entry (+1 or -1) per placement kept, so
    # that the CSR values are S @ values.
    def _value_buffer(self, size: int) -> np.ndarray:
        if self._values is None or len(self._values) != size:
            self._values = np.empty(size)
        return self._values

    def _pattern(self, upper: bool):
        """The CSR pattern of the free-dof matrix (full, or its upper triangle), its diagonal
        positions, and the scatter matrix S (nnz x number of values) with CSR values = S @ values:
        computed once (the COO -> CSR sort a careful user does once, not every step)."""
        key = "upper" if upper else "full"
        if key not in self._patterns:
            val, rv, cv, ca, cb, sign = (np.concatenate(a) for a in zip(*self.placements()))
            r = self.dof[3 * rv + ca]
            c = self.dof[3 * cv + cb]
            keep = (r >= 0) & (c >= 0) & ((c >= r) if upper else True)
            nf = self.n_free_dofs
            lin = r[keep].astype(np.int64) * nf + c[keep]
            uniq, pos = np.unique(lin, return_inverse=True)
            rows = uniq // nf
            indptr = np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=nf))]).astype(np.int32)
            cols = (uniq % nf).astype(np.int32)
            diag_pos = np.searchsorted(uniq, np.arange(nf, dtype=np.int64) * (nf + 1))
            if not np.array_equal(uniq[diag_pos], np.arange(nf, dtype=np.int64) * (nf + 1)):
                raise ValueError("a free vertex with no element: its diagonal is not in the pattern")
            S = scipy.sparse.csr_matrix((sign[keep], (pos, val[keep])), shape=(len(uniq), self.n_values))
            S.sum_duplicates()
            self._patterns[key] = (S, indptr, cols, diag_pos)
        return self._patterns[key]

    def system_matrix(self, x, diag, upper: bool = False, terms=None):
        """H_psd(x) + diag(diag) over the free degrees of freedom as scipy CSR (the full matrix,
        or its upper triangle): the per-step block values scattered into the precomputed pattern by
        one sparse product with the scatter matrix.  ``terms``: ``terms(x)`` when already computed."""
        S, indptr, indices, diag_pos = self._pattern(upper)
        data = S @ self.block_values(x, terms)
        data[diag_pos] += diag
        A = scipy.sparse.csr_matrix((data, indices, indptr), shape=(self.n_free_dofs,) * 2, copy=False)
        A.has_sorted_indices = True
        return A

    def hessian_psd(self, x):
        """The PSD Hessian H_psd(x) over the free degrees of freedom, as a scipy CSR matrix."""
        return self.system_matrix(x, 0.0)

    def implicit_system(self, x, v, dt, upper: bool = False):
        """(A, b) of one Baraff-Witkin step: A = M/dt^2 + H_psd(x), b = f(x) + M g + M v/dt (free dofs)."""
        free = ~self.pinned
        m3 = np.repeat(self.mass[free], 3)
        terms = self.terms(x)   # once for the forces and the blocks
        A = self.system_matrix(x, m3 / (dt * dt), upper, terms)
        b = (self.forces(x, terms) + self.mass[:, None] * v / dt)[free].reshape(-1)
        return A, b

    def apply_step(self, x, v, y, dt):
        """x += dx, v = dx/dt from the free-dof solution y (pinned: dx = 0, v = 0)."""
        free = ~self.pinned
        dx = np.zeros((self.n, 3))
        dx[free] = y.reshape(-1, 3)
        x += dx
        v[...] = dx / dt
        v[~free] = 0.0
        return x, v

    def backward_euler(self, x, v, dt, tol=1e-5, maxiter=100000):
        """One Baraff-Witkin step in place (x, v numpy (n, 3)); returns (x, v).  Records
        ``last_assembly_s``, ``last_solve_s``, ``last_iterations`` and ``last_residual``."""
        t0 = time.perf_counter()
        A, b = self.implicit_system(x, v, dt)
        Pinv = scipy.sparse.diags(1.0 / A.diagonal())
        t1 = time.perf_counter()
        count = [0]

        def cb(_):
            count[0] += 1
        y, info = scipy.sparse.linalg.cg(A, b, rtol=tol, atol=0.0, maxiter=maxiter, M=Pinv, callback=cb)
        t2 = time.perf_counter()
        if info != 0:
            raise RuntimeError(f"scipy cg did not converge (info={info}) after {count[0]} iterations")
        self.apply_step(x, v, y, dt)
        self.last_assembly_s, self.last_solve_s = t1 - t0, t2 - t1
        self.last_iterations = count[0]
        nb = np.linalg.norm(b)
        self.last_residual = float(np.linalg.norm(b - A @ y) / nb) if nb > 0 else 0.0
        return x, v


class NumpyCloth(NumpyElastic):
    """The cloth of :func:`engine.scenes.cloth` (any Model with springs and optional
    notes-variant bending), stepped in numpy (explicit) and numpy + scipy.sparse (implicit)."""

    def __init__(self, model, springs, bending=None):
        super().__init__(model)
        self.i, self.j = springs.edges_np[:, 0], springs.edges_np[:, 1]
        self.L, self.c = springs.L_np, springs.c_np
        self.H = None
        if bending is not None:
            if bending.variant != "notes":
                raise ValueError("the numpy baseline implements the notes' bending energy only")
            self.H, self.k, self.theta_bar = bending.hinges_np, bending.k, bending.theta_bar
        self._h = 0 if self.H is None else len(self.H)
        self.n_values = 9 * len(self.i) + 9 * len(stencil_pairs(4)) * self._h

    def _hinge_terms(self, x):
        """theta (h,) and the gradients dtheta/dx for the slots (v0, v1, w0, w1), each (h, 3)."""
        v0, v1, w0, w1 = (x[self.H[:, a]] for a in range(4))
        e = v1 - v0
        el2 = np.einsum("ij,ij->i", e, e)
        el = np.sqrt(el2)
        N0 = np.cross(e, w0 - v0)        # normal of (v0, v1, w0)
        N1 = np.cross(-e, w1 - v1)       # normal of (v1, v0, w1)
        A0 = np.linalg.norm(N0, axis=1)
        A1 = np.linalg.norm(N1, axis=1)
        n0, n1 = N0 / A0[:, None], N1 / A1[:, None]
        theta = np.arctan2(np.einsum("ij,ij->i", np.cross(n0, n1), e) / el, np.einsum("ij,ij->i", n0, n1))
        h0, h1 = A0 / el, A1 / el
        g0, g1 = -n0 / h0[:, None], -n1 / h1[:, None]
        t0 = (np.einsum("ij,ij->i", w0 - v0, e) / el2)[:, None]
        t1 = (np.einsum("ij,ij->i", w1 - v0, e) / el2)[:, None]
        gv0 = -(1 - t0) * g0 - (1 - t1) * g1
        gv1 = -t0 * g0 - t1 * g1
        return theta, (gv0, gv1, g0, g1)

    def terms(self, x):
        """The hinges' (theta, gradients) at x, shared by the forces and the blocks (None without hinges)."""
        return self._hinge_terms(x) if self._h else None

    def forces(self, x, terms=None):
        """-grad W + M g on free vertices, 0 on pinned ones.  ``terms``: ``terms(x)`` when already
        computed."""
        f = np.zeros((self.n, 3))
        d = x[self.j] - x[self.i]
        l = np.sqrt(np.einsum("ij,ij->i", d, d))
        # f_i = (c/L)(l/L - 1) d/l ;  f_j = -f_i
        fi = ((self.c / self.L) * (l / self.L - 1.0) / l)[:, None] * d
        self._scatter(self.i, fi, f)
        self._scatter(self.j, -fi, f)
        if self._h:
            theta, grads = terms or self._hinge_terms(x)
            s = (-self.k * (theta - self.theta_bar))[:, None]  # -dW/dtheta
            for a, grad in enumerate(grads):
                self._scatter(self.H[:, a], s * grad, f)
        return self._finish_forces(f)

    # The PSD element blocks, as values: each spring's K (9 values, placed +K at (i,i) and (j,j),
    # -K at (i,j) and (j,i)) and each hinge's k g_a g_b^T for the 10 slot pairs a <= b (9 values
    # each, placed at (a,b) and, transposed, at (b,a)).
    _PAIRS = stencil_pairs(4)
    _PAIR_A = np.array([a for a, _ in _PAIRS])
    _PAIR_B = np.array([b for _, b in _PAIRS])

    def block_values(self, x, terms=None):
        """The per-step values (springs' K, then the hinges' 10 blocks), flat, written into one
        buffer kept between steps.  ``terms``: ``terms(x)`` when already computed."""
        m, h = len(self.i), self._h
        values = self._value_buffer(self.n_values)
        d = x[self.i] - x[self.j]
        l = np.sqrt(np.einsum("ij,ij->i", d, d))
        u = d / l[:, None]
        s = np.maximum(0.0, (l - self.L) / l)
        k = self.c / self.L ** 2
        K = values[:9 * m].reshape(m, 3, 3)
        np.einsum("ea,eb->eab", ((k * (1.0 - s))[:, None] * u), u, out=K)
        K[:, [0, 1, 2], [0, 1, 2]] += (k * s)[:, None]                         # k (uu^T + s (I - uu^T))
        if h:
            _, grads = terms or self._hinge_terms(x)
            G = np.stack(grads, axis=1)                                           # (h, 4, 3)
            pa, pb = self._PAIR_A, self._PAIR_B
            Hb = values[9 * m:].reshape(h, len(self._PAIRS), 3, 3)
            np.einsum("hpi,hpj->hpij", self.k[:, None, None] * G[:, pa], G[:, pb], out=Hb)
        return values

    def placements(self) -> list:
        """Where each value of ``block_values`` goes: the springs' four placements, then the hinges'
        blocks (:func:`stencil_placements`)."""
        m = len(self.i)
        base = (9 * np.arange(m)[:, None] + np.arange(9)[None, :]).ravel()     # (m, 9) value index
        out = [(base, np.repeat(rv, 9), np.repeat(cv, 9), np.tile(_COMP_A, m), np.tile(_COMP_B, m),
                np.full(9 * m, sg))
               for rv, cv, sg in ((self.i, self.i, 1.0), (self.j, self.j, 1.0), (self.i, self.j, -1.0),
                                  (self.j, self.i, -1.0))]
        if self._h:
            out += stencil_placements(self.H, 9 * m)
        return out


class NumpyMembrane(NumpyElastic):
    """A Model whose only energy is a Baraff-Witkin membrane (engine/energies/triangle.py (M2),
    undamped; :func:`bench.config.membrane_scene`), stepped in numpy and numpy + scipy.sparse: per
    triangle w_u, w_v from the rest frames' gradient rows g_a, the forces
    -A [k_s ((|w_u| - 1) g_a0 n_u + (|w_v| - 1) g_a1 n_v) + k_h s (g_a0 w_v + g_a1 w_u)] and the PSD
    blocks A [k_s (g_a0 g_b0 K_u + g_a1 g_b1 K_v) + k_h q_a q_b^T] (K's transverse coefficient
    clipped at 0) for the 6 corner pairs a <= b."""

    _PAIRS = stencil_pairs(3)
    _PAIR_A = np.array([a for a, _ in _PAIRS])
    _PAIR_B = np.array([b for _, b in _PAIRS])

    def __init__(self, model, membrane):
        if membrane.model != "baraff-witkin" or membrane.has_damping:
            raise ValueError("the numpy membrane implements the undamped Baraff-Witkin model only")
        super().__init__(model)
        self.T = np.asarray(membrane.triangles_np, dtype=np.int64)
        D = np.asarray(membrane.Dinv_np, dtype=np.float64)
        g1, g2 = D[:, 0, :], D[:, 1, :]
        self.Dinv = D
        self.G = np.stack([-(g1 + g2), g1, g2], axis=1)                           # (m, 3 corners, 2)
        self.area = np.asarray(membrane.area_np, dtype=np.float64)
        self.ks, self.kh = float(membrane.k_stretch), float(membrane.k_shear)
        self.n_values = 9 * len(self._PAIRS) * len(self.T)

    def terms(self, x):
        """Per triangle: w_u, w_v, |w_u|, |w_v|, s = w_u . w_v (the deformation gradient's columns)."""
        x0 = x[self.T[:, 0]]
        d1, d2 = x[self.T[:, 1]] - x0, x[self.T[:, 2]] - x0
        D = self.Dinv
        wu = d1 * D[:, 0, 0, None] + d2 * D[:, 1, 0, None]
        wv = d1 * D[:, 0, 1, None] + d2 * D[:, 1, 1, None]
        lu = np.sqrt(np.einsum("ij,ij->i", wu, wu))
        lv = np.sqrt(np.einsum("ij,ij->i", wv, wv))
        return wu, wv, lu, lv, np.einsum("ij,ij->i", wu, wv)

    def forces(self, x, terms=None):
        """-grad W + M g on free vertices, 0 on pinned ones."""
        wu, wv, lu, lv, s = terms or self.terms(x)
        A, ks, kh = self.area, self.ks, self.kh
        P0 = (A * ks * (lu - 1.0) / lu)[:, None] * wu + (A * kh * s)[:, None] * wv     # dW/dw_u
        P1 = (A * ks * (lv - 1.0) / lv)[:, None] * wv + (A * kh * s)[:, None] * wu     # dW/dw_v
        grads = self.G[:, :, 0, None] * P0[:, None] + self.G[:, :, 1, None] * P1[:, None]   # (m, 3, 3)
        f = np.zeros((self.n, 3))
        self._scatter(self.T.reshape(-1), -grads.reshape(-1, 3), f)
        return self._finish_forces(f)

    def block_values(self, x, terms=None):
        """The 6 PSD blocks (a <= b) of every triangle, flat, into one buffer kept between steps."""
        wu, wv, lu, lv, _ = terms or self.terms(x)
        values = self._value_buffer(self.n_values)
        m, P = len(self.T), len(self._PAIRS)
        A, G, pa, pb = self.area, self.G, self._PAIR_A, self._PAIR_B
        eye = np.eye(3)

        def K(w, l):   # n n^T + max(1 - 1/l, 0) (I - n n^T)
            c = np.maximum(1.0 - 1.0 / l, 0.0)
            n = w / l[:, None]
            return np.einsum("mi,mj->mij", (1.0 - c)[:, None] * n, n) + c[:, None, None] * eye
        cu = (A * self.ks)[:, None] * G[:, pa, 0] * G[:, pb, 0]                     # (m, P)
        cv = (A * self.ks)[:, None] * G[:, pa, 1] * G[:, pb, 1]
        q = G[:, :, 0, None] * wv[:, None] + G[:, :, 1, None] * wu[:, None]        # (m, 3, 3): q_a
        Hb = values.reshape(m, P, 3, 3)
        np.einsum("mpi,mpj->mpij", (A * self.kh)[:, None, None] * q[:, pa], q[:, pb], out=Hb)
        Hb += cu[:, :, None, None] * K(wu, lu)[:, None] + cv[:, :, None, None] * K(wv, lv)[:, None]
        return values

    def placements(self) -> list:
        return stencil_placements(self.T, 0)


class NumpyRod:
    """The rod of :class:`engine.rod.Rod` (its h, E, masses and pins), stepped in numpy/scipy."""

    def __init__(self, rod):
        self.h, self.E, self.m = rod.h, rod.E, rod.mass
        self.pinned = rod.pinned
        self.inv_m = np.where(rod.pinned, 0.0, 1.0 / rod.mass)
        self.n = rod.n

    def forces(self, x):
        s = np.diff(x) / self.h - 1.0
        t = self.E * s            # segment tensions
        f = np.zeros(self.n)
        f[:-1] += t
        f[1:] -= t
        return f

    def symplectic_euler(self, x, v, dt, n_steps=1):
        for _ in range(n_steps):
            v += dt * self.inv_m * self.forces(x)
            x += dt * v
        return x, v

    def backward_euler(self, x, v, dt, n_steps=1):
        """(M + dt^2 K) v+ = M v + dt f(x) (pinned rows: v+ = 0), x+ = x + dt v+."""
        k = self.E / self.h
        dt2 = dt * dt
        diag = self.m.copy()
        diag[:-1] += dt2 * k
        diag[1:] += dt2 * k
        upper = np.zeros(self.n)
        lower = np.zeros(self.n)
        upper[1:] = -dt2 * k      # ab[0, j] = A[j-1, j]
        lower[:-1] = -dt2 * k     # ab[2, j] = A[j+1, j]
        p = self.pinned
        diag[p] = 1.0
        pi = np.flatnonzero(p)
        upper[pi[pi + 1 < self.n] + 1] = 0.0   # row i pinned: A[i, i+1] = 0
        lower[pi[pi > 0] - 1] = 0.0            # row i pinned: A[i, i-1] = 0
        ab = np.stack([upper, diag, lower])
        for _ in range(n_steps):
            rhs = self.m * v + dt * self.forces(x)
            rhs[p] = 0.0
            v[:] = scipy.linalg.solve_banded((1, 1), ab, rhs)
            x += dt * v
        return x, v
