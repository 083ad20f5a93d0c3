"""The baseline a user would otherwise write: the same cloth step in vectorised numpy.

Springs: W_e = 1/2 c_e (l/L - 1)^2, forces scattered with ``np.bincount``.
Bending (notes' energy, W_e = 1/2 k_e (theta - theta_bar)^2): dtheta/dw_a = -n_a/h_a for the wing
vertices, and the edge vertices take the barycentric combinations that make the four sum to
zero (Bridson et al. 2003's u1..u4). Symplectic Euler with gravity and pins.

Used by the benchmarks (timed against the Taichi engine in the same run) and by their
correctness checks (the two must agree on the same input).
"""
import numpy as np


class NumpyCloth:
    """The cloth of :func:`engine.scenes.cloth` (any Model with springs and optional
    notes-variant bending), stepped in numpy."""

    def __init__(self, model, springs, bending=None):
        self.n = model.n
        self.inv_mass = np.where(model.pinned, 0.0, 1.0 / model.mass)
        self.free = (~model.pinned)[:, None]
        self.mass = np.asarray(model.mass, dtype=np.float64)
        self.g = np.asarray(model.gravity, dtype=np.float64)
        self.i, self.j = springs.edges_np[:, 0], springs.edges_np[:, 1]
        self.L, self.c = springs.L_np, springs.c_np
        self.H = None
        if bending is not None:
            if bending.variant != "notes":
                raise ValueError("the numpy baseline implements the notes' bending energy only")
            self.H, self.k, self.theta_bar = bending.hinges_np, bending.k, bending.theta_bar
    def _scatter(self, idx, vec, out):
        for a in range(3):
            out[:, a] += np.bincount(idx, weights=vec[:, a], minlength=self.n)

    def forces(self, x):
        f = np.zeros((self.n, 3))
        d = x[self.j] - x[self.i]
        l = np.sqrt(np.einsum("ij,ij->i", d, d))
        # f_i = (c/L)(l/L - 1) d/l ;  f_j = -f_i
        fi = ((self.c / self.L) * (l / self.L - 1.0) / l)[:, None] * d
        self._scatter(self.i, fi, f)
        self._scatter(self.j, -fi, f)
        if self.H is not None and len(self.H):
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
            s = (-self.k * (theta - self.theta_bar))[:, None]  # -dW/dtheta
            for a, grad in enumerate((gv0, gv1, g0, g1)):
                self._scatter(self.H[:, a], s * grad, f)
        f += self.mass[:, None] * self.g
        return f * self.free

    def symplectic_euler(self, x, v, dt, n_steps=1):
        for _ in range(n_steps):
            v += dt * self.inv_mass[:, None] * self.forces(x)
            x += dt * v
        return x, v
