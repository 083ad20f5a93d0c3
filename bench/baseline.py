"""The baseline a user would otherwise write: the same steps in vectorised numpy and scipy.

Cloth (:class:`NumpyCloth`), the scene of :func:`engine.scenes.cloth`:

* Springs: W_e = 1/2 c_e (l/L - 1)^2, forces scattered with ``np.bincount``.
* Bending (notes' energy, W_e = 1/2 k_e (theta - theta_bar)^2): dtheta/dw_a = -n_a/h_a for the
  wing vertices, and the edge vertices take the barycentric combinations that make the four sum
  to zero (Bridson et al. 2003's u1..u4).
* Explicit: symplectic Euler with gravity and pins.
* Implicit (:meth:`NumpyCloth.backward_euler`): one Baraff-Witkin step, the same linear system as
  the engine's backward Euler with one Newton iteration (engine/integrators/implicit.py (N1)):

      (M/dt^2 + H_psd(x_n)) dx = f(x_n) + M g + M v_n/dt,     x+ = x_n + dx,  v+ = dx/dt

  with H_psd the PSD-projected spring blocks (S4) and the Gauss-Newton hinge blocks
  k_e g_a g_b^T (g = grad theta), assembled as a careful user would: the CSR pattern and the map
  from element blocks to it computed once (pinned degrees of freedom dropped), then one
  ``np.bincount`` per step and solved by ``scipy.sparse.linalg.cg`` with a (scalar) Jacobi
  preconditioner to the relative residual ``tol`` (||b - A dx|| <= tol ||b||, the engine's (L3)).

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


class NumpyCloth:
    """The cloth of :func:`engine.scenes.cloth` (any Model with springs and optional
    notes-variant bending), stepped in numpy (explicit) and numpy + scipy.sparse (implicit)."""

    def __init__(self, model, springs, bending=None):
        self.n = model.n
        self.inv_mass = np.where(model.pinned, 0.0, 1.0 / model.mass)
        self.free = (~model.pinned)[:, None]
        self.pinned = np.asarray(model.pinned, dtype=bool)
        self.mass = np.asarray(model.mass, dtype=np.float64)
        self.g = np.asarray(model.gravity, dtype=np.float64)
        self.i, self.j = springs.edges_np[:, 0], springs.edges_np[:, 1]
        self.L, self.c = springs.L_np, springs.c_np
        self.H = None
        if bending is not None:
            if bending.variant != "notes":
                raise ValueError("the numpy baseline implements the notes' bending energy only")
            self.H, self.k, self.theta_bar = bending.hinges_np, bending.k, bending.theta_bar
        # degree-of-freedom numbering with the pinned vertices eliminated (-1)
        free_dof = np.repeat(~self.pinned, 3)
        self.dof = np.full(3 * self.n, -1, dtype=np.int64)
        self.dof[free_dof] = np.arange(int(free_dof.sum()))
        self.n_free_dofs = int(free_dof.sum())
        self.last_assembly_s = self.last_solve_s = 0.0
        self._patterns = {}
        self.last_iterations = 0
        self.last_residual = 0.0

    def _scatter(self, idx, vec, out):
        for a in range(3):
            out[:, a] += np.bincount(idx, weights=vec[:, a], minlength=self.n)

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

    def forces(self, x, hinge_terms=None):
        """-grad W + M g on free vertices, 0 on pinned ones.  ``hinge_terms``: _hinge_terms(x)
        when already computed."""
        f = np.zeros((self.n, 3))
        d = x[self.j] - x[self.i]
        l = np.sqrt(np.einsum("ij,ij->i", d, d))
        # f_i = (c/L)(l/L - 1) d/l ;  f_j = -f_i
        fi = ((self.c / self.L) * (l / self.L - 1.0) / l)[:, None] * d
        self._scatter(self.i, fi, f)
        self._scatter(self.j, -fi, f)
        if self.H is not None and len(self.H):
            theta, grads = hinge_terms or self._hinge_terms(x)
            s = (-self.k * (theta - self.theta_bar))[:, None]  # -dW/dtheta
            for a, grad in enumerate(grads):
                self._scatter(self.H[:, a], s * grad, f)
        f += self.mass[:, None] * self.g
        return f * self.free

    def symplectic_euler(self, x, v, dt, n_steps=1):
        for _ in range(n_steps):
            v += dt * self.inv_mass[:, None] * self.forces(x)
            x += dt * v
        return x, v

    # -- implicit --------------------------------------------------------------------------------
    # The PSD element blocks, as values: each spring's K (9 values, placed +K at (i,i) and (j,j),
    # -K at (i,j) and (j,i)) and each hinge's k g_a g_b^T for the 10 slot pairs a <= b (9 values
    # each, placed at (a,b) and, transposed, at (b,a)).  A careful numpy user computes only these
    # values per step and sends them through a scatter map built once: a sparse matrix S with one
    # entry (+1 or -1) per placement kept, so that the CSR values are S @ values.
    _PAIRS = [(a, b) for a in range(4) for b in range(a, 4)]
    _PAIR_A = np.array([a for a, _ in _PAIRS])
    _PAIR_B = np.array([b for _, b in _PAIRS])

    def block_values(self, x, grads=None):
        """The per-step values (springs' K, then the hinges' 10 blocks), flat, written into one
        buffer kept between steps.  ``grads``: the hinge gradients at x when already computed."""
        m = len(self.i)
        h = 0 if self.H is None else len(self.H)
        if getattr(self, "_values", None) is None:
            self._values = np.empty(9 * m + 9 * len(self._PAIRS) * h)
        d = x[self.i] - x[self.j]
        l = np.sqrt(np.einsum("ij,ij->i", d, d))
        u = d / l[:, None]
        s = np.maximum(0.0, (l - self.L) / l)
        k = self.c / self.L ** 2
        K = self._values[:9 * m].reshape(m, 3, 3)
        np.einsum("ea,eb->eab", ((k * (1.0 - s))[:, None] * u), u, out=K)
        K[:, [0, 1, 2], [0, 1, 2]] += (k * s)[:, None]                         # k (uu^T + s (I - uu^T))
        if h:
            if grads is None:
                _, grads = self._hinge_terms(x)
            G = np.stack(grads, axis=1)                                           # (h, 4, 3)
            pa, pb = self._PAIR_A, self._PAIR_B
            Hb = self._values[9 * m:].reshape(h, len(self._PAIRS), 3, 3)
            np.einsum("hpi,hpj->hpij", self.k[:, None, None] * G[:, pa], G[:, pb], out=Hb)
        return self._values

    def _placements(self):
        """(value index, row vertex, column vertex, row component, column component, sign) of every
        placement of every value, the values numbered as ``block_values`` writes them."""
        m = len(self.i)
        comp_a, comp_b = np.divmod(np.arange(9), 3)
        vals, rows, cols, ca, cb, sign = [], [], [], [], [], []
        base = 9 * np.arange(m)[:, None] + np.arange(9)[None, :]                 # (m, 9) value index
        for rv, cv, sg in ((self.i, self.i, 1.0), (self.j, self.j, 1.0), (self.i, self.j, -1.0),
                           (self.j, self.i, -1.0)):
            vals.append(base.ravel())
            rows.append(np.repeat(rv, 9))
            cols.append(np.repeat(cv, 9))
            ca.append(np.tile(comp_a, m))
            cb.append(np.tile(comp_b, m))
            sign.append(np.full(9 * m, sg))
        if self.H is not None and len(self.H):
            h = len(self.H)
            off = 9 * m
            for p, (a, b) in enumerate(self._PAIRS):
                idx = off + (np.arange(h)[:, None] * len(self._PAIRS) + p) * 9 + np.arange(9)[None, :]
                for ra, rb, aa, bb in ((a, b, comp_a, comp_b),) + (((b, a, comp_b, comp_a),) if a != b else ()):
                    vals.append(idx.ravel())
                    rows.append(np.repeat(self.H[:, ra], 9))
                    cols.append(np.repeat(self.H[:, rb], 9))
                    ca.append(np.tile(aa, h))
                    cb.append(np.tile(bb, h))
                    sign.append(np.ones(9 * h))
        return tuple(np.concatenate(a) for a in (vals, rows, cols, ca, cb, sign))

    def _pattern(self, upper: bool):
        """The CSR pattern of the free-dof matrix (full, or its upper triangle), its diagonal
        positions, and the scatter matrix S (nnz x number of values) with CSR values = S @ values:
        computed once (the COO -> CSR sort a careful user does once, not every step)."""
        key = "upper" if upper else "full"
        if key not in self._patterns:
            val, rv, cv, ca, cb, sign = self._placements()
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
            n_values = 9 * len(self.i) + (9 * len(self._PAIRS) * len(self.H) if self.H is not None else 0)
            S = scipy.sparse.csr_matrix((sign[keep], (pos, val[keep])), shape=(len(uniq), n_values))
            S.sum_duplicates()
            self._patterns[key] = (S, indptr, cols, diag_pos)
        return self._patterns[key]

    def system_matrix(self, x, diag, upper: bool = False, grads=None):
        """H_psd(x) + diag(diag) over the free degrees of freedom as scipy CSR (the full matrix,
        or its upper triangle): the per-step block values scattered into the precomputed pattern by
        one sparse product with the scatter matrix."""
        S, indptr, indices, diag_pos = self._pattern(upper)
        data = S @ self.block_values(x, grads)
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
        terms = self._hinge_terms(x) if self.H is not None and len(self.H) else None  # once for both
        A = self.system_matrix(x, m3 / (dt * dt), upper, terms and terms[1])
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
