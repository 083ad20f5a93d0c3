"""The engine's explicit cloth step written with Numba: ``numba.njit(parallel=True)`` kernels.

:class:`NumbaCloth` steps the cloth of :func:`engine.scenes.cloth` (any Model with springs and
optional notes-variant bending) by symplectic Euler, with the formulas of the engine
(engine/energies/springs.py, bending.py, integrators/kernels.py, cloth_kernels.py):

* springs, W_e = 1/2 c_e (l/L - 1)^2: per vertex i, f_i = sum_{e ~ i} -(c_e/L_e)(1/L_e - 1/l)(x_i - x_j);
* bending (the notes' energy), W_e = 1/2 k_e d^2 with d = theta - theta_bar wrapped into [-pi, pi):
  theta = atan2(e_hat . (N0 x N1), N0 . N1), N0 = e x a0, N1 = a1 x e (e = x_v1 - x_v0,
  a_i = x_wi - x_v0), gradient dtheta/dx_wi = -|e| N_i/|N_i|^2, dtheta/dx_v1 = -t0 g_w0 - t1 g_w1,
  dtheta/dx_v0 = -(g_v1 + g_w0 + g_w1); the hinge's force on slot a is -k_e d dtheta/dx_a;
* symplectic Euler: v += dt (f/m + g), x += dt v on free vertices, v = 0 on pinned ones.

One step is three ``prange`` loops inside one compiled function (all ``n_steps`` steps in one call):
per hinge, its four force vectors into an (h, 4, 3) buffer; per vertex, the spring gather and the
hinge gather over CSR incidences (built once in numpy, sorted by vertex) and the kick; per vertex,
the drift.  Each vertex sums its own terms in a fixed order, so the result does not depend on the
thread count and there are no atomics.

Kernels are ``numba.njit(parallel=True, fastmath=False, cache=True)`` (IEEE arithmetic, as the
engine's); the decorator is applied when the first peer is built, so that importing this module
does not import numba, to plain functions at module level, so that numba's on-disk cache (in
``__pycache__`` or ``NUMBA_CACHE_DIR``) finds them again in the next process.  A fresh environment
compiles for several seconds per precision; a cached one loads in well under a second.  The
per-element helpers are inlined into the ``prange`` loops at numba's IR level
(``inline="always"``): that doubles the compile time but runs the step 1.4-1.8x faster than
calling them as separate compiled functions (measured at sides 64 and 128, one thread).

Threads: ``numba.set_num_threads`` from ``ELASTIC_THREADS`` (default 2), set before each call.
Numba picks its threading layer itself (here "omp", GNU libgomp, whose idle threads spin before they
sleep).  On an oversubscribed machine (more runnable threads than cores) a spinning thread holds a
core that its partner needs to reach the next barrier, and the two-thread step becomes 3-30x slower
than the one-thread one; ``OMP_WAIT_POLICY=PASSIVE`` or ``NUMBA_THREADING_LAYER=workqueue`` avoid
that.  The peer leaves the choice to the environment and reports it (:attr:`NumbaCloth.layer`).
Precision: ``dtype`` float64 or float32; every constant is passed in that dtype so that float32 runs
in float32 (a float64 literal would promote the arithmetic).
"""
import math

import numpy as np

from bench import peers

# The kernels are plain functions here, compiled by _build() (numba is imported only then); they
# live at module level so that numba's on-disk cache finds them again in the next process.
prange = range          # numba.prange once _build() has run
hinge_vectors = vertex_force = None   # the compiled helpers, set by _build()
_kernels = None
_JIT = dict(fastmath=False, cache=True)


def _hinge_vectors(x, hinges, k, theta_bar, fh, h, cst):
    pi, two_pi = cst[2], cst[3]
    v0, v1, w0, w1 = hinges[h, 0], hinges[h, 1], hinges[h, 2], hinges[h, 3]
    ex, ey, ez = x[v1, 0] - x[v0, 0], x[v1, 1] - x[v0, 1], x[v1, 2] - x[v0, 2]
    ax, ay, az = x[w0, 0] - x[v0, 0], x[w0, 1] - x[v0, 1], x[w0, 2] - x[v0, 2]
    bx, by, bz = x[w1, 0] - x[v0, 0], x[w1, 1] - x[v0, 1], x[w1, 2] - x[v0, 2]
    # N0 = e x a0, N1 = a1 x e
    n0x, n0y, n0z = ey * az - ez * ay, ez * ax - ex * az, ex * ay - ey * ax
    n1x, n1y, n1z = by * ez - bz * ey, bz * ex - bx * ez, bx * ey - by * ex
    s = np.sqrt(ex * ex + ey * ey + ez * ez)
    # theta = atan2(e_hat . (N0 x N1), N0 . N1)
    cx, cy, cz = n0y * n1z - n0z * n1y, n0z * n1x - n0x * n1z, n0x * n1y - n0y * n1x
    theta = np.arctan2((cx * ex + cy * ey + cz * ez) / s, n0x * n1x + n0y * n1y + n0z * n1z)
    d = theta - theta_bar[h]
    if d >= pi:
        d -= two_pi
    elif d < -pi:
        d += two_pi
    W1 = k[h] * d
    q0 = -s / (n0x * n0x + n0y * n0y + n0z * n0z)
    q1 = -s / (n1x * n1x + n1y * n1y + n1z * n1z)
    gw0x, gw0y, gw0z = q0 * n0x, q0 * n0y, q0 * n0z
    gw1x, gw1y, gw1z = q1 * n1x, q1 * n1y, q1 * n1z
    s2 = s * s
    t0 = (ax * ex + ay * ey + az * ez) / s2
    t1 = (bx * ex + by * ey + bz * ez) / s2
    gv1x = -t0 * gw0x - t1 * gw1x
    gv1y = -t0 * gw0y - t1 * gw1y
    gv1z = -t0 * gw0z - t1 * gw1z
    gv0x = -(gv1x + gw0x + gw1x)
    gv0y = -(gv1y + gw0y + gw1y)
    gv0z = -(gv1z + gw0z + gw1z)
    m = -W1
    fh[h, 0, 0], fh[h, 0, 1], fh[h, 0, 2] = m * gv0x, m * gv0y, m * gv0z
    fh[h, 1, 0], fh[h, 1, 1], fh[h, 1, 2] = m * gv1x, m * gv1y, m * gv1z
    fh[h, 2, 0], fh[h, 2, 1], fh[h, 2, 2] = m * gw0x, m * gw0y, m * gw0z
    fh[h, 3, 0], fh[h, 3, 1], fh[h, 3, 2] = m * gw1x, m * gw1y, m * gw1z


def _vertex_force(x, i, offsets, inc_other, inc_inv_L, inc_c_over_L, fh, h_offsets, h_entries, with_hinges, cst):
    zero, one = cst[0], cst[1]
    # springs: sum_{e ~ i} -(c/L)(1/L - 1/l)(x_i - x_j)
    sx, sy, sz = zero, zero, zero
    xi0, xi1, xi2 = x[i, 0], x[i, 1], x[i, 2]
    for kk in range(offsets[i], offsets[i + 1]):
        j = inc_other[kk]
        dx, dy, dz = xi0 - x[j, 0], xi1 - x[j, 1], xi2 - x[j, 2]
        l = np.sqrt(dx * dx + dy * dy + dz * dz)
        if l > zero:
            a = inc_c_over_L[kk] * (inc_inv_L[kk] - one / l)
            sx -= a * dx
            sy -= a * dy
            sz -= a * dz
    fx, fy, fz = sx, sy, sz
    if with_hinges:
        hx, hy, hz = zero, zero, zero
        for kk in range(h_offsets[i], h_offsets[i + 1]):
            ent = h_entries[kk]
            hh, slot = ent // 4, ent % 4
            hx += fh[hh, slot, 0]
            hy += fh[hh, slot, 1]
            hz += fh[hh, slot, 2]
        fx += hx
        fy += hy
        fz += hz
    return fx, fy, fz


def _steps(x, v, inv_mass, g, dt, n_steps, offsets, inc_other, inc_inv_L, inc_c_over_L, hinges, k, theta_bar,
           fh, h_offsets, h_entries, with_hinges, cst):
    # n_steps of (hinge pass; gather + kick; drift), the engine's one-launch step
    n = x.shape[0]
    nh = hinges.shape[0]
    zero = cst[0]
    for _ in range(n_steps):
        if with_hinges:
            for h in prange(nh):
                hinge_vectors(x, hinges, k, theta_bar, fh, h, cst)
        for i in prange(n):   # gather + kick: v += dt (f/m + g)
            fx, fy, fz = vertex_force(x, i, offsets, inc_other, inc_inv_L, inc_c_over_L, fh, h_offsets,
                                      h_entries, with_hinges, cst)
            w = inv_mass[i]
            if w > zero:
                v[i, 0] += dt * (w * fx + g[0])
                v[i, 1] += dt * (w * fy + g[1])
                v[i, 2] += dt * (w * fz + g[2])
            else:
                v[i, 0], v[i, 1], v[i, 2] = zero, zero, zero
        for i in prange(n):   # drift: x += dt v
            if inv_mass[i] > zero:
                x[i, 0] += dt * v[i, 0]
                x[i, 1] += dt * v[i, 1]
                x[i, 2] += dt * v[i, 2]


def _forces(x, mass, inv_mass, g, offsets, inc_other, inc_inv_L, inc_c_over_L, hinges, k, theta_bar, fh,
            h_offsets, h_entries, with_hinges, cst, out):
    # out = -grad W + m g on free vertices, 0 on pinned ones (the engine's Model.forces)
    n = x.shape[0]
    zero = cst[0]
    if with_hinges:
        for h in prange(hinges.shape[0]):
            hinge_vectors(x, hinges, k, theta_bar, fh, h, cst)
    for i in prange(n):
        fx, fy, fz = vertex_force(x, i, offsets, inc_other, inc_inv_L, inc_c_over_L, fh, h_offsets,
                                  h_entries, with_hinges, cst)
        if inv_mass[i] > zero:
            out[i, 0], out[i, 1], out[i, 2] = fx + mass[i] * g[0], fy + mass[i] * g[1], fz + mass[i] * g[2]
        else:
            out[i, 0], out[i, 1], out[i, 2] = zero, zero, zero


def _build():
    """Compile (or load from numba's cache) the kernels; numba is imported here, not at module import."""
    global _kernels, prange, hinge_vectors, vertex_force
    if _kernels is not None:
        return _kernels
    numba = peers.require("numba")
    prange = numba.prange
    hinge_vectors = numba.njit(inline="always", **_JIT)(_hinge_vectors)
    vertex_force = numba.njit(inline="always", **_JIT)(_vertex_force)
    steps = numba.njit(parallel=True, **_JIT)(_steps)
    forces = numba.njit(parallel=True, **_JIT)(_forces)
    _kernels = dict(numba=numba, steps=steps, forces=forces)
    return _kernels


class NumbaCloth:
    """The cloth's explicit step in Numba (see the module docstring).

    ``model`` (engine.model.Model: ``mass``, ``pinned``, ``gravity``), ``springs`` (engine
    SpringEnergy: ``edges_np``, ``L_np``, ``c_np``), ``bending`` (engine BendingEnergy of the notes'
    variant, or None for springs only), ``dtype`` float64 or float32, ``threads`` (default:
    ``ELASTIC_THREADS``, else 2).  :meth:`step` works in place on numpy (n, 3) arrays; arrays that are
    not C-contiguous ``dtype`` are stepped in a copy that is written back."""

    def __init__(self, model, springs, bending=None, dtype=np.float64, threads: int | None = None):
        self.a = a = peers.cloth_arrays(model, springs, bending, dtype)
        kern = _build()
        numba = kern["numba"]
        upper = int(numba.config.NUMBA_NUM_THREADS)
        if threads is None:
            threads = peers.threads_from_env(upper)
        elif not 1 <= int(threads) <= upper:
            raise ValueError(f"threads must be an integer in 1..{upper} (got {threads!r})")
        self.threads = int(threads)
        self._numba = numba
        self._steps, self._forces = kern["steps"], kern["forces"]
        self.n, self.dtype, self.n_hinges = a["n"], a["dtype"], a["n_hinges"]
        self.cst = np.array([0.0, 1.0, math.pi, 2.0 * math.pi], dtype=self.dtype)
        self.fh = np.zeros((max(self.n_hinges, 1), 4, 3), dtype=self.dtype)
        self._gather = (a["offsets"], a["inc_other"], a["inc_inv_L"], a["inc_c_over_L"], a["hinges"], a["k"],
                        a["theta_bar"], self.fh, a["h_offsets"], a["h_entries"], a["with_hinges"], self.cst)

    @property
    def layer(self) -> str:
        """Numba's threading layer and OpenMP wait policy, e.g. "omp (OMP_WAIT_POLICY unset)" (after
        the first step or forces call; "not started" before)."""
        import os
        try:
            name = self._numba.threading_layer()
        except ValueError:
            return "not started"
        if name == "omp":
            name += f" (OMP_WAIT_POLICY {os.environ.get('OMP_WAIT_POLICY') or 'unset'})"
        return name

    def _threads(self):
        if self._numba.get_num_threads() != self.threads:
            self._numba.set_num_threads(self.threads)

    def forces(self, x) -> np.ndarray:
        """-grad W + M g on free vertices, 0 on pinned ones (what the engine's ``Model.forces`` and
        ``NumpyCloth.forces`` return), as a new (n, 3) array of ``dtype``."""
        if tuple(np.shape(x)) != (self.n, 3):
            raise ValueError(f"x must have shape ({self.n}, 3) (got {np.shape(x)})")
        x = np.ascontiguousarray(x, dtype=self.dtype)
        out = np.empty((self.n, 3), dtype=self.dtype)
        self._threads()
        self._forces(x, self.a["mass"], self.a["inv_mass"], self.a["g"], *self._gather, out)
        return out

    def step(self, x, v, dt: float, n_steps: int = 1):
        """``n_steps`` symplectic-Euler steps of ``dt`` seconds, in place (one compiled call); returns (x, v)."""
        dt, n_steps = peers.check_step_args(self.n, x, v, dt, n_steps)
        xs = x if _native(x, self.dtype) else np.ascontiguousarray(x, dtype=self.dtype)
        vs = v if _native(v, self.dtype) else np.ascontiguousarray(v, dtype=self.dtype)
        self._threads()
        self._steps(xs, vs, self.a["inv_mass"], self.a["g"], self.dtype.type(dt), n_steps, *self._gather)
        if xs is not x:
            x[...] = xs
        if vs is not v:
            v[...] = vs
        return x, v

    symplectic_euler = step  # the name NumpyCloth uses


def _native(a, dtype) -> bool:
    return isinstance(a, np.ndarray) and a.dtype == dtype and a.flags.c_contiguous and a.flags.writeable
