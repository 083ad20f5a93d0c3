"""The engine's explicit cloth step written with NVIDIA Warp, on ``device="cpu"``.

:class:`WarpCloth` computes what :class:`bench.peers.numba_cloth.NumbaCloth` computes (the engine's
springs, the notes' dihedral bending and symplectic Euler; formulas in that module's docstring and in
engine/energies/springs.py, bending.py), written the way Warp is meant to be used: one thread per
element (``wp.tid()``), ``wp.vec3d`` / ``wp.vec3`` arrays for float64 / float32, and per step three
launches:

1. per hinge: its four force vectors into an (h, 4) array (skipped for springs only);
2. per vertex: the spring gather and the hinge gather over CSR incidences, then the kick
   v += dt (f/m + g) (v = 0 on pinned vertices);
3. per vertex: the drift x += dt v.

Each vertex sums its own terms in a fixed order (no atomics), so the result is deterministic.  The
launches are recorded once (``wp.launch(..., record_cmd=True)``) and replayed, which keeps Warp's
per-launch Python cost to a minimum; CUDA graphs (``wp.ScopedCapture``) do not exist on the CPU.

Warp's CPU backend runs each launch on ONE thread (the calling thread loops over the launch's
elements), so this peer is single-threaded whatever ``ELASTIC_THREADS`` says.  Kernels are compiled
without backward passes (``enable_backward=False``); the first use in a fresh environment compiles
them with Warp's bundled compiler (seconds), later processes load them from Warp's kernel cache.
"""
import math

import numpy as np

from bench import peers

_kernels: dict = {}
_wp = None


def import_warp():
    """Import and initialise warp (once); ImportError with a one-line reason when it is missing."""
    global _wp
    if _wp is None:
        wp = peers.require("warp")
        wp.config.quiet = True                       # no banner at init
        if hasattr(wp, "LOG_WARNING"):
            wp.config.log_level = wp.LOG_WARNING     # no line per module load
        wp.init()
        _wp = wp
    return _wp


def build_kernels(dtype):
    """The kernels for one precision (float64: wp.float64 / wp.vec3d; float32: wp.float32 / wp.vec3)."""
    key = np.dtype(dtype).name
    if key in _kernels:
        return _kernels[key]
    wp = import_warp()
    scalar = wp.float64 if key == "float64" else wp.float32
    vec = wp.vec3d if key == "float64" else wp.vec3
    # one Warp module per precision: its kernels compile together, once
    opts = dict(enable_backward=False, module=f"bench_peers_warp_cloth_{key}")

    @wp.func
    def vertex_force(x: wp.array(dtype=vec), i: int, offsets: wp.array(dtype=wp.int32),
                     inc_other: wp.array(dtype=wp.int32), inc_inv_L: wp.array(dtype=scalar),
                     inc_c_over_L: wp.array(dtype=scalar), fh: wp.array2d(dtype=vec),
                     h_offsets: wp.array(dtype=wp.int32), h_entries: wp.array(dtype=wp.int32), with_hinges: int):
        # springs: sum_{e ~ i} -(c/L)(1/L - 1/l)(x_i - x_j); then the hinges' vectors for vertex i
        acc = vec()
        xi = x[i]
        for kk in range(offsets[i], offsets[i + 1]):
            d = xi - x[inc_other[kk]]
            l = wp.length(d)
            if l > scalar(0.0):
                acc = acc - (inc_c_over_L[kk] * (inc_inv_L[kk] - scalar(1.0) / l)) * d
        f = acc
        if with_hinges != 0:
            hacc = vec()
            for kk in range(h_offsets[i], h_offsets[i + 1]):
                ent = h_entries[kk]
                hacc = hacc + fh[ent // 4, ent % 4]
            f = f + hacc
        return f

    @wp.kernel(**opts)
    def hinge_kernel(x: wp.array(dtype=vec), hinges: wp.array2d(dtype=wp.int32), k: wp.array(dtype=scalar),
                     theta_bar: wp.array(dtype=scalar), fh: wp.array2d(dtype=vec)):
        h = wp.tid()
        xv0 = x[hinges[h, 0]]
        e = x[hinges[h, 1]] - xv0
        a0 = x[hinges[h, 2]] - xv0
        a1 = x[hinges[h, 3]] - xv0
        N0 = wp.cross(e, a0)
        N1 = wp.cross(a1, e)
        s = wp.length(e)
        theta = wp.atan2(wp.dot(wp.cross(N0, N1), e) / s, wp.dot(N0, N1))
        d = theta - theta_bar[h]
        if d >= scalar(math.pi):
            d = d - scalar(2.0 * math.pi)
        elif d < -scalar(math.pi):
            d = d + scalar(2.0 * math.pi)
        W1 = k[h] * d
        g_w0 = (-s / wp.dot(N0, N0)) * N0
        g_w1 = (-s / wp.dot(N1, N1)) * N1
        t0 = wp.dot(a0, e) / (s * s)
        t1 = wp.dot(a1, e) / (s * s)
        g_v1 = -t0 * g_w0 - t1 * g_w1
        g_v0 = -(g_v1 + g_w0 + g_w1)
        fh[h, 0] = -W1 * g_v0
        fh[h, 1] = -W1 * g_v1
        fh[h, 2] = -W1 * g_w0
        fh[h, 3] = -W1 * g_w1

    @wp.kernel(**opts)
    def kick_kernel(x: wp.array(dtype=vec), v: wp.array(dtype=vec), inv_mass: wp.array(dtype=scalar), g: vec,
                    dt: scalar, offsets: wp.array(dtype=wp.int32), inc_other: wp.array(dtype=wp.int32),
                    inc_inv_L: wp.array(dtype=scalar), inc_c_over_L: wp.array(dtype=scalar),
                    fh: wp.array2d(dtype=vec), h_offsets: wp.array(dtype=wp.int32),
                    h_entries: wp.array(dtype=wp.int32), with_hinges: int):
        i = wp.tid()
        f = vertex_force(x, i, offsets, inc_other, inc_inv_L, inc_c_over_L, fh, h_offsets, h_entries, with_hinges)
        w = inv_mass[i]
        if w > scalar(0.0):
            v[i] = v[i] + dt * (w * f + g)
        else:
            v[i] = vec()

    @wp.kernel(**opts)
    def drift_kernel(x: wp.array(dtype=vec), v: wp.array(dtype=vec), inv_mass: wp.array(dtype=scalar), dt: scalar):
        i = wp.tid()
        if inv_mass[i] > scalar(0.0):
            x[i] = x[i] + dt * v[i]

    @wp.kernel(**opts)
    def forces_kernel(x: wp.array(dtype=vec), mass: wp.array(dtype=scalar), inv_mass: wp.array(dtype=scalar),
                      g: vec, offsets: wp.array(dtype=wp.int32), inc_other: wp.array(dtype=wp.int32),
                      inc_inv_L: wp.array(dtype=scalar), inc_c_over_L: wp.array(dtype=scalar),
                      fh: wp.array2d(dtype=vec), h_offsets: wp.array(dtype=wp.int32),
                      h_entries: wp.array(dtype=wp.int32), with_hinges: int, out: wp.array(dtype=vec)):
        # out = -grad W + m g on free vertices, 0 on pinned ones (the engine's Model.forces)
        i = wp.tid()
        f = vertex_force(x, i, offsets, inc_other, inc_inv_L, inc_c_over_L, fh, h_offsets, h_entries, with_hinges)
        if inv_mass[i] > scalar(0.0):
            out[i] = f + mass[i] * g
        else:
            out[i] = vec()

    _kernels[key] = dict(wp=wp, scalar=scalar, vec=vec, hinge=hinge_kernel, kick=kick_kernel, drift=drift_kernel,
                         forces=forces_kernel)
    return _kernels[key]


class WarpStepper:
    """What both Warp peers share (this module's cloth, bench.peers.warp_membrane's membrane): the
    state ``x``, ``v`` in Warp arrays of ``n`` entries and ``dtype``, copied in and out, and a step's
    launches, recorded once per dt by the subclass's ``_record(dt)`` (into ``_cmds``) and replayed."""

    def load(self, x, v=None) -> None:
        """Copy numpy (n, 3) positions (and velocities) into the Warp state."""
        for name, src, dst in (("x", x, self.x), ("v", v, self.v)):
            if src is None:
                continue
            if tuple(np.shape(src)) != (self.n, 3):
                raise ValueError(f"{name} must have shape ({self.n}, 3) (got {np.shape(src)})")
            dst.numpy()[...] = np.asarray(src, dtype=self.dtype)   # a CPU array's numpy() is a view

    def numpy(self):
        """(x, v) as new numpy (n, 3) arrays of ``dtype``."""
        return self.x.numpy().copy(), self.v.numpy().copy()

    def advance(self, dt: float, n_steps: int = 1) -> None:
        """``n_steps`` symplectic-Euler steps of the Warp state (3 launches each; CPU launches return
        when done)."""
        if not (math.isfinite(dt) and dt > 0.0):
            raise ValueError(f"dt must be finite and > 0 (got {dt!r})")
        if self._cmds is None or dt != self._dt:
            self._record(dt)
        for _ in range(n_steps):
            for cmd in self._cmds:
                cmd.launch()

    def step(self, x, v, dt: float, n_steps: int = 1):
        """``n_steps`` symplectic-Euler steps of numpy (n, 3) arrays, in place; returns (x, v)."""
        dt, n_steps = peers.check_step_args(self.n, x, v, dt, n_steps)
        self.load(x, v)
        self.advance(dt, n_steps)
        x[...] = self.x.numpy()
        v[...] = self.v.numpy()
        return x, v

    symplectic_euler = step  # the name NumpyCloth uses


class WarpCloth(WarpStepper):
    """The cloth's explicit step in Warp on the CPU (see the module docstring; single-threaded).

    Arguments as :class:`bench.peers.numba_cloth.NumbaCloth` (``model``, ``springs``, ``bending`` or
    None, ``dtype`` float64 or float32).  The state lives in Warp arrays ``x``, ``v`` ((n,) vec3 on the
    CPU); :meth:`load` and :meth:`numpy` copy it in and out, :meth:`advance` steps it, and
    :meth:`step` does the three for numpy arrays (in place, like ``NumpyCloth.symplectic_euler``)."""

    def __init__(self, model, springs, bending=None, dtype=np.float64):
        a = peers.cloth_arrays(model, springs, bending, dtype)
        kern = build_kernels(a["dtype"])
        wp = self._wp = kern["wp"]
        self._k = kern
        self.n, self.dtype, self.n_hinges = a["n"], a["dtype"], a["n_hinges"]
        self.with_hinges = bool(a["with_hinges"])
        dev = self.device = "cpu"
        vec, scalar = kern["vec"], kern["scalar"]

        def arr(name, dt=None):
            return wp.array(a[name], dtype=dt or (wp.int32 if a[name].dtype == np.int32 else scalar), device=dev)
        self.mass, self.inv_mass = arr("mass"), arr("inv_mass")
        self.g = vec(*[float(t) for t in a["g"]])
        self.offsets, self.inc_other = arr("offsets"), arr("inc_other")
        self.inc_inv_L, self.inc_c_over_L = arr("inc_inv_L"), arr("inc_c_over_L")
        self.hinges = wp.array(a["hinges"] if self.n_hinges else np.zeros((1, 4), np.int32), dtype=wp.int32, device=dev)
        self.k = wp.array(a["k"] if self.n_hinges else np.zeros(1, a["dtype"]), dtype=scalar, device=dev)
        self.theta_bar = wp.array(a["theta_bar"] if self.n_hinges else np.zeros(1, a["dtype"]), dtype=scalar,
                                  device=dev)
        self.h_offsets = arr("h_offsets")
        self.h_entries = wp.array(a["h_entries"] if self.n_hinges else np.zeros(1, np.int32), dtype=wp.int32,
                                  device=dev)
        self.fh = wp.zeros((max(self.n_hinges, 1), 4), dtype=vec, device=dev)
        self.x = wp.zeros(self.n, dtype=vec, device=dev)
        self.v = wp.zeros(self.n, dtype=vec, device=dev)
        self._out = wp.zeros(self.n, dtype=vec, device=dev)
        self._gather = [self.offsets, self.inc_other, self.inc_inv_L, self.inc_c_over_L, self.fh, self.h_offsets,
                        self.h_entries, int(self.with_hinges)]
        self._dt = None
        self._cmds = None

    def _record(self, dt: float):
        """The three launches of a step, recorded once per dt and replayed by :meth:`advance`."""
        wp, k, s = self._wp, self._k, self._k["scalar"]
        cmds = []
        if self.with_hinges:
            cmds.append(wp.launch(k["hinge"], dim=self.n_hinges, inputs=[self.x, self.hinges, self.k, self.theta_bar,
                                                                         self.fh], device=self.device, record_cmd=True))
        cmds.append(wp.launch(k["kick"], dim=self.n, inputs=[self.x, self.v, self.inv_mass, self.g, s(dt),
                                                              *self._gather], device=self.device, record_cmd=True))
        cmds.append(wp.launch(k["drift"], dim=self.n, inputs=[self.x, self.v, self.inv_mass, s(dt)],
                              device=self.device, record_cmd=True))
        self._cmds, self._dt = cmds, dt

    def forces(self, x) -> np.ndarray:
        """-grad W + M g on free vertices, 0 on pinned ones (as the engine's ``Model.forces``), as a new
        (n, 3) numpy array of ``dtype``.  Uses its own position buffer: the state is not touched."""
        wp, k = self._wp, self._k
        if tuple(np.shape(x)) != (self.n, 3):
            raise ValueError(f"x must have shape ({self.n}, 3) (got {np.shape(x)})")
        xw = wp.array(np.asarray(x, dtype=self.dtype), dtype=k["vec"], device=self.device)
        if self.with_hinges:
            wp.launch(k["hinge"], dim=self.n_hinges, inputs=[xw, self.hinges, self.k, self.theta_bar, self.fh],
                      device=self.device)
        wp.launch(k["forces"], dim=self.n, inputs=[xw, self.mass, self.inv_mass, self.g, *self._gather, self._out],
                  device=self.device)
        return self._out.numpy().copy()
