"""The engine's explicit step of a Baraff-Witkin membrane (engine/energies/triangle.py, (M2): the
stretch and shear conditions of each triangle in its rest (u, v) frame) written with NVIDIA Warp on
``device="cpu"``, as :mod:`bench.peers.warp_cloth` writes the springs and hinges.

Warp itself no longer ships a cloth model: its ``warp.sim`` (whose triangle FEM was a different,
neo-Hookean-like energy) left Warp for the separate Newton project, and ``warp.fem`` is a general
finite-element toolkit, not a cloth energy. So the peer is the same energy written in Warp's own
style: per step three launches, (1) per triangle its three force vectors into an (m, 3) array,
(2) per vertex the gather over its corners (entry = 3 triangle + corner, each vertex's terms in a
fixed order: no atomics, deterministic) and the kick v += dt (f/m + g), (3) per vertex the drift.
The launches are recorded once and replayed. Warp's CPU backend runs each launch on one thread.
"""
import numpy as np

from bench import peers
from bench.peers.warp_cloth import WarpStepper, import_warp
from bench.peers.warp_cloth import build_kernels as _build_cloth

_kernels: dict = {}


def build_kernels(dtype):
    key = np.dtype(dtype).name
    if key in _kernels:
        return _kernels[key]
    wp = import_warp()
    scalar = wp.float64 if key == "float64" else wp.float32
    vec = wp.vec3d if key == "float64" else wp.vec3
    opts = dict(enable_backward=False, module=f"bench_peers_warp_membrane_{key}")

    @wp.kernel(**opts)
    def triangle_kernel(x: wp.array(dtype=vec), tris: wp.array2d(dtype=wp.int32), di: wp.array2d(dtype=scalar),
                        area: wp.array(dtype=scalar), ks: scalar, kh: scalar, ft: wp.array2d(dtype=vec)):
        # (M2): -dW/dx_a = -A [ks ((|wu| - 1) g_a0 n_u + (|wv| - 1) g_a1 n_v) + kh s (g_a0 wv + g_a1 wu)]
        t = wp.tid()
        x0 = x[tris[t, 0]]
        d1 = x[tris[t, 1]] - x0
        d2 = x[tris[t, 2]] - x0
        wu = d1 * di[t, 0] + d2 * di[t, 2]
        wv = d1 * di[t, 1] + d2 * di[t, 3]
        lu = wp.length(wu)
        lv = wp.length(wv)
        s = wp.dot(wu, wv)
        a = area[t]
        su = ks * (lu - scalar(1.0)) / lu
        sv = ks * (lv - scalar(1.0)) / lv
        # corners 1 and 2: g1 = (di00, di01), g2 = (di10, di11); corner 0: g0 = -(g1 + g2)
        f1 = -a * (su * di[t, 0] * wu + sv * di[t, 1] * wv + kh * s * (di[t, 0] * wv + di[t, 1] * wu))
        f2 = -a * (su * di[t, 2] * wu + sv * di[t, 3] * wv + kh * s * (di[t, 2] * wv + di[t, 3] * wu))
        ft[t, 1] = f1
        ft[t, 2] = f2
        ft[t, 0] = -(f1 + f2)

    @wp.func
    def corner_sum(offsets: wp.array(dtype=wp.int32), entries: wp.array(dtype=wp.int32),
                   ft: wp.array2d(dtype=vec), i: int):
        # vertex i's corner forces, in the order of its incidence (entry = 3 triangle + corner)
        f = vec()
        for kk in range(offsets[i], offsets[i + 1]):
            ent = entries[kk]
            f = f + ft[ent // 3, ent % 3]
        return f

    @wp.kernel(**opts)
    def kick_kernel(v: wp.array(dtype=vec), inv_mass: wp.array(dtype=scalar), g: vec, dt: scalar,
                    offsets: wp.array(dtype=wp.int32), entries: wp.array(dtype=wp.int32), ft: wp.array2d(dtype=vec)):
        i = wp.tid()
        f = corner_sum(offsets, entries, ft, i)
        w = inv_mass[i]
        if w > scalar(0.0):
            v[i] = v[i] + dt * (w * f + g)
        else:
            v[i] = vec()

    @wp.kernel(**opts)
    def gather_kernel(offsets: wp.array(dtype=wp.int32), entries: wp.array(dtype=wp.int32),
                      ft: wp.array2d(dtype=vec), out: wp.array(dtype=vec)):
        i = wp.tid()
        out[i] = corner_sum(offsets, entries, ft, i)

    # the drift is the cloth peer's (x += dt v on free vertices)
    _kernels[key] = dict(wp=wp, scalar=scalar, vec=vec, triangle=triangle_kernel, kick=kick_kernel,
                         drift=_build_cloth(dtype)["drift"], gather=gather_kernel)
    return _kernels[key]


class WarpMembrane(WarpStepper):
    """Symplectic Euler of a model whose one energy is a Baraff-Witkin MembraneEnergy, in Warp on the
    CPU (module docstring; single-threaded). ``load``/``numpy``/``advance``/``step`` are
    :class:`bench.peers.warp_cloth.WarpStepper`'s; :meth:`elastic_forces` is -grad W alone."""

    def __init__(self, model, membrane, dtype=np.float64):
        if membrane.model != "baraff-witkin" or membrane.has_damping:
            raise ValueError("the Warp membrane peer writes Baraff-Witkin's undamped conditions only")
        dtype = np.dtype(dtype)
        kern = build_kernels(dtype)
        wp = self._wp = kern["wp"]
        self._k = kern
        self.n, self.dtype = int(model.n), dtype
        scalar, vec = kern["scalar"], kern["vec"]
        dev = self.device = "cpu"
        T = np.ascontiguousarray(membrane.triangles_np, dtype=np.int32)
        self.m = len(T)
        pinned = np.asarray(model.pinned, dtype=bool)
        mass = np.asarray(model.mass, dtype=np.float64)
        inv_mass = np.where(pinned, 0.0, 1.0 / np.where(mass > 0, mass, 1.0))
        offsets, entries = peers.csr(self.n, T.reshape(-1).astype(np.int64), np.arange(3 * self.m, dtype=np.int64))
        self.tris = wp.array(T, dtype=wp.int32, device=dev)
        self.di = wp.array(membrane.Dinv_np.reshape(-1, 4).astype(dtype), dtype=scalar, device=dev)
        self.area = wp.array(membrane.area_np.astype(dtype), dtype=scalar, device=dev)
        self.ks, self.kh = scalar(membrane.k_stretch), scalar(membrane.k_shear)
        self.inv_mass = wp.array(inv_mass.astype(dtype), dtype=scalar, device=dev)
        self.g = vec(*[float(t) for t in model.gravity])
        self.offsets = wp.array(offsets, dtype=wp.int32, device=dev)
        self.entries = wp.array(entries.astype(np.int32), dtype=wp.int32, device=dev)
        self.ft = wp.zeros((self.m, 3), dtype=vec, device=dev)
        self.x = wp.zeros(self.n, dtype=vec, device=dev)
        self.v = wp.zeros(self.n, dtype=vec, device=dev)
        self._cmds, self._dt = None, None

    def _record(self, dt: float):
        wp, k, s = self._wp, self._k, self._k["scalar"]
        self._cmds = [
            wp.launch(k["triangle"], dim=self.m, inputs=[self.x, self.tris, self.di, self.area, self.ks, self.kh,
                                                         self.ft], device=self.device, record_cmd=True),
            wp.launch(k["kick"], dim=self.n, inputs=[self.v, self.inv_mass, self.g, s(dt), self.offsets, self.entries,
                                                     self.ft], device=self.device, record_cmd=True),
            wp.launch(k["drift"], dim=self.n, inputs=[self.x, self.v, self.inv_mass, s(dt)], device=self.device,
                      record_cmd=True)]
        self._dt = dt

    def elastic_forces(self, x) -> np.ndarray:
        """-grad W at numpy positions x, as a new (n, 3) array (the state is not touched)."""
        wp, k = self._wp, self._k
        xa = wp.array(np.asarray(x, dtype=self.dtype), dtype=k["vec"], device=self.device)
        out = wp.zeros(self.n, dtype=k["vec"], device=self.device)
        wp.launch(k["triangle"], dim=self.m, inputs=[xa, self.tris, self.di, self.area, self.ks, self.kh, self.ft],
                  device=self.device)
        wp.launch(k["gather"], dim=self.n, inputs=[self.offsets, self.entries, self.ft, out], device=self.device)
        return out.numpy().astype(np.float64)
