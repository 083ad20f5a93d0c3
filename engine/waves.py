"""Long-wavelength elasticity of spring networks and wave-speed measurement helpers.

Pure numpy (set-up and analysis; the dynamics run in the engine's kernels).

Cauchy-Born sum (lecture notes, "Multi-dimensional spring potential"; standard lattice
homogenisation). A spring e with rest vector L_e n_e and coefficient c_e stores
W_e = 1/2 c_e (l_e/L_e - 1)^2. Under a small uniform strain eps every spring's strain is
n_e . eps . n_e, so the network stores W = 1/2 sum_e c_e (n_e.eps.n_e)^2, which equals the
continuum 1/2 V C_ijkl eps_ij eps_kl when

    C_ijkl = (1/V) sum_e c_e n_i n_j n_k n_l                                      (CB)

(V: the area or volume the springs fill; c_e = E A_e for area/volume springs). C has the
full index symmetry of a fourth-order product of one vector, so pair springs always obey
the Cauchy relations (C_1122 = C_1212); for an isotropic network that forces lambda = mu,
i.e. Poisson's ratio 1/3 in 2D and 1/4 in 3D. (CB) is exact in the long-wavelength limit
when the uniform strain is an equilibrium of every vertex, e.g. when every vertex is a
centre of inversion of its springs (Bravais lattices, the grids here); otherwise the
vertices relax and (CB) is an upper bound.

Plane waves of direction n solve the Christoffel problem

    Gamma(n) p = rho c^2 p,    Gamma_ik = C_ijkl n_j n_l                           (Chr)

(rho: mass per area or volume). The largest root is the (quasi-)P wave.

Measurement: a standing plane wave u = A cos(k (X - X0).n) p started from rest oscillates
as cos(w t) with w = c k. :class:`ModeProbe` projects the displacement onto that shape over
a region far enough from the boundary that nothing reflected reaches it during the run,
and :func:`phase_frequency` fits w from the phase arccos(a(t)/a(0)). The time series must
be symmetric about t = 0 (velocity Verlet started from rest is; symplectic Euler started
from rest lags by half a step, an O(dt) error).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from engine.analysis import fit_slope

__all__ = ["cauchy_born_tensor", "christoffel", "wave_speeds", "max_speed", "voigt_2d", "young_poisson",
           "tensor_from_voigt_2d", "relaxed_stiffness_2d", "ModeProbe", "phase_frequency"]


def cauchy_born_tensor(X: np.ndarray, edges: np.ndarray, c: np.ndarray, measure: float) -> np.ndarray:
    """C_ijkl = (1/V) sum_e c_e n_i n_j n_k n_l over the given springs (CB); X in 2D or 3D
    (the dimension of C follows X), c_e in J, V = ``measure`` (m^2 or m^3)."""
    X = np.asarray(X, dtype=np.float64)
    E = np.asarray(edges)
    d = X[E[:, 1]] - X[E[:, 0]]
    n = d / np.linalg.norm(d, axis=1, keepdims=True)
    return np.einsum("e,ei,ej,ek,el->ijkl", np.asarray(c, dtype=np.float64), n, n, n, n) / float(measure)


def christoffel(C: np.ndarray, direction, rho: float):
    """Speeds (ascending, m/s) and polarisations (columns) of plane waves along ``direction``
    from (Chr)."""
    n = np.asarray(direction, dtype=np.float64)
    n = n / np.linalg.norm(n)
    G = np.einsum("ijkl,j,l->ik", C, n, n)
    w, v = np.linalg.eigh(G)
    return np.sqrt(np.maximum(w, 0.0) / rho), v


def wave_speeds(C: np.ndarray, direction, rho: float) -> np.ndarray:
    """Ascending plane-wave speeds along ``direction``; the last one is the (quasi-)P wave."""
    return christoffel(C, direction, rho)[0]


def max_speed(C: np.ndarray, rho: float, samples: int = 96) -> float:
    """Largest plane-wave speed over all directions (sampled; the fastest wave front any
    disturbance can have, since the largest group speed equals the largest phase speed)."""
    if C.shape[0] == 2:
        t = np.linspace(0.0, np.pi, samples, endpoint=False)
        dirs = np.stack([np.cos(t), np.sin(t)], axis=1)
    else:  # Fibonacci sphere (half of it: n and -n give the same speeds)
        i = np.arange(samples * samples // 8) + 0.5
        z = i / i.size
        phi = np.pi * (1 + 5 ** 0.5) * i
        r = np.sqrt(1 - z * z)
        dirs = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
    G = np.einsum("ijkl,dj,dl->dik", C, dirs, dirs)
    return float(np.sqrt(np.linalg.eigvalsh(G)[:, -1].max() / rho))


def voigt_2d(C: np.ndarray) -> np.ndarray:
    """3x3 Voigt matrix of a 2D stiffness tensor (order xx, yy, xy; engineering shear)."""
    idx = [(0, 0), (1, 1), (0, 1)]
    return np.array([[C[a + b] for b in idx] for a in idx])


def tensor_from_voigt_2d(V: np.ndarray) -> np.ndarray:
    """Inverse of :func:`voigt_2d`: the 2x2x2x2 tensor with full minor and major symmetry."""
    idx = [(0, 0), (1, 1), (0, 1)]
    C = np.zeros((2, 2, 2, 2))
    for a, (i, j) in enumerate(idx):
        for b, (k, l) in enumerate(idx):
            for p in {(i, j), (j, i)}:
                for q in {(k, l), (l, k)}:
                    C[p + q] = V[a, b]
    return C


def relaxed_stiffness_2d(mesh, blocks: np.ndarray, c: np.ndarray, window: np.ndarray):
    """Long-wavelength stiffness of a 2D spring network whose vertices are free to relax.

    Where vertices are not centres of symmetry (a jittered mesh), a uniform strain is not an
    equilibrium and (CB) over-estimates the stiffness. Here the boundary vertices of the 2D
    triangle ``mesh`` follow a unit uniform strain, the interior relaxes to the linear
    equilibrium K u = 0 (K assembled from the engine's rest Hessian blocks ``blocks`` (m, 2, 2)
    = c_e/L_e^2 n n^T, a reference solve with scipy), and the elastic energy density is
    averaged over the triangles in ``window`` (each spring's energy 1/2 c_e s_e^2,
    s_e = n.(u_j - u_i)/L_e, shared among its triangles in proportion to their area).
    Six strain states (xx, yy, xy and three sums) give the six Voigt constants.
    Returns (C_relaxed, C_affine) over the same window, 2x2x2x2 each.
    """
    import scipy.sparse as sps
    import scipy.sparse.linalg as spla

    V = np.asarray(mesh.vertices, dtype=np.float64)[:, :2]
    E = mesh.edges
    n_v = len(V)
    L = mesh.rest_lengths
    d = (V[E[:, 1]] - V[E[:, 0]]) / L[:, None]
    B = np.asarray(blocks, dtype=np.float64)[:, :2, :2]
    rows, cols, vals = [], [], []
    for a in range(2):
        for b in range(2):
            v = B[:, a, b]
            for I, J, sign in ((E[:, 0], E[:, 0], 1.0), (E[:, 1], E[:, 1], 1.0),
                               (E[:, 0], E[:, 1], -1.0), (E[:, 1], E[:, 0], -1.0)):
                rows.append(2 * I + a)
                cols.append(2 * J + b)
                vals.append(sign * v)
    K = sps.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                       shape=(2 * n_v, 2 * n_v))
    bd = np.repeat(np.asarray(mesh.boundary_vertices), 2)
    free, fixed = np.flatnonzero(~bd), np.flatnonzero(bd)
    lu = spla.splu(K[free][:, free].tocsc())
    K_fb = K[free][:, fixed]
    area = np.abs(mesh.element_measures)
    share = (area[window] / 3.0)[:, None] / mesh.edge_measure[mesh.element_edges[window]]  # (tw, 3)
    tw_edges = mesh.element_edges[window]
    total = float(area[window].sum())
    c = np.asarray(c, dtype=np.float64)

    def density(u):
        s = np.einsum("ei,ei->e", d, u[E[:, 1]] - u[E[:, 0]]) / L
        w = 0.5 * c * s * s
        return float(np.sum(share * w[tw_edges])) / total

    def two_w(eps):
        u = V @ eps.T
        affine = 2.0 * density(u)
        flat = u.reshape(-1).copy()
        flat[free] = lu.solve(-(K_fb @ flat[fixed]))
        return 2.0 * density(flat.reshape(-1, 2)), affine

    xx = np.array([[1.0, 0.0], [0.0, 0.0]])
    yy = np.array([[0.0, 0.0], [0.0, 1.0]])
    xy = np.array([[0.0, 0.5], [0.5, 0.0]])
    states = {"xx": xx, "yy": yy, "xy": xy, "xx+xy": xx + xy, "yy+xy": yy + xy, "xx+yy": xx + yy}
    relaxed, affine = {}, {}
    for name, eps in states.items():
        relaxed[name], affine[name] = two_w(eps)

    def voigt(w):
        C11, C22, C66 = w["xx"], w["yy"], w["xy"]
        C16 = 0.5 * (w["xx+xy"] - C11 - C66)
        C26 = 0.5 * (w["yy+xy"] - C22 - C66)
        C12 = 0.5 * (w["xx+yy"] - C11 - C22)
        return np.array([[C11, C12, C16], [C12, C22, C26], [C16, C26, C66]])

    return tensor_from_voigt_2d(voigt(relaxed)), tensor_from_voigt_2d(voigt(affine))


def young_poisson(C: np.ndarray, axis: int = 0) -> tuple[float, float]:
    """Young's modulus along ``axis`` and Poisson's ratio for a pull along it (contraction
    along the next axis) from the compliance S = C^-1 (2D: N/m for an areal C)."""
    if C.shape[0] == 2:
        S = np.linalg.inv(voigt_2d(C))
        other = 1 - axis
        return 1.0 / S[axis, axis], -S[other, axis] / S[axis, axis]
    idx = [(0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1)]
    V = np.array([[C[a + b] for b in idx] for a in idx])
    S = np.linalg.inv(V)
    other = (axis + 1) % 3
    return 1.0 / S[axis, axis], -S[other, axis] / S[axis, axis]


class ModeProbe:
    """Amplitude of the standing-wave shape phi_i = cos(k (X_i - X0).n) p over a region (times
    ``profile``_i, a lattice mode's amplitude at each vertex: BlochModes.profile).

    a(x) = sum_region m_i phi_i (x_i - X_i).p / sum_region m_i phi_i^2  (the mass-weighted
    least-squares amplitude of the shape), so a = A cos(w t) for the pure mode.
    """

    def __init__(self, X: np.ndarray, mass: np.ndarray, direction, polarization, k: float,
                 origin, region: np.ndarray, profile: np.ndarray | None = None):
        X = np.asarray(X, dtype=np.float64)
        dim = X.shape[1]
        n = np.zeros(dim)
        nd = np.asarray(direction, dtype=np.float64)
        n[:nd.size] = nd / np.linalg.norm(nd)
        p = np.zeros(dim)
        pd = np.asarray(polarization, dtype=np.float64)
        p[:pd.size] = pd / np.linalg.norm(pd)
        o = np.zeros(dim)
        od = np.asarray(origin, dtype=np.float64)
        o[:od.size] = od
        self.n, self.p, self.k, self.origin = n, p, float(k), o
        self.phi = np.cos(self.k * (X - o) @ n)
        if profile is not None:   # a lattice's own mode: its sublattices move by different amounts
            self.phi = self.phi * np.asarray(profile, dtype=np.float64)
        self.region = np.flatnonzero(region)
        if self.region.size == 0:
            raise ValueError("ModeProbe: the measurement region is empty")
        self.X = X
        w = np.asarray(mass, dtype=np.float64)[self.region] * self.phi[self.region]
        self._w = w
        self._norm = float(np.sum(w * self.phi[self.region]))

    def displacement(self, amplitude: float) -> np.ndarray:
        """(n, dim) initial displacement A phi_i p."""
        return amplitude * self.phi[:, None] * self.p[None, :]

    def amplitude(self, x: np.ndarray) -> float:
        r = self.region
        u = np.asarray(x, dtype=np.float64)[r, :self.X.shape[1]] - self.X[r]
        return float(np.sum(self._w * (u @ self.p)) / self._norm)


def phase_frequency(t: np.ndarray, a: np.ndarray, lo: float = -0.9, hi: float = 0.97) -> float:
    """Angular frequency w of a(t) = a(0) cos(w t): slope of arccos(a/a(0)) against t over
    the samples with lo < a/a(0) < hi, up to the first sample below ``lo`` (rad/s)."""
    t = np.asarray(t, dtype=np.float64)
    r = np.asarray(a, dtype=np.float64) / float(a[0])
    below = np.flatnonzero(r <= lo)
    end = below[0] if below.size else r.size
    t, r = t[:end], r[:end]
    keep = (r > lo) & (r < hi)
    if keep.sum() < 3:
        raise ValueError("phase_frequency: fewer than 3 usable samples (run longer or sample more often)")
    return fit_slope(t[keep], np.arccos(r[keep]))


def sublattice_keys(X: np.ndarray, periods) -> np.ndarray:
    """(n, 2) integer keys of each vertex's position modulo the lattice translations ``periods``
    (rows): vertices with equal keys are copies of one another (one sublattice)."""
    frac = np.linalg.solve(np.asarray(periods, dtype=np.float64).T, np.asarray(X, dtype=np.float64)[:, :2].T).T
    return np.round((frac - np.floor(frac + 1e-9)) * 1e6).astype(np.int64)


@dataclass
class BlochModes:
    """The plane-wave modes of a periodic lattice at one wavevector (:func:`bloch_modes`): per branch,
    ascending in w2, its w^2, its damping per unit mass c, and its mass-normalised amplitudes U
    (branch, sublattice, dims); the sublattices' masses and keys (:func:`sublattice_keys`)."""
    w2: np.ndarray
    c: np.ndarray
    U: np.ndarray
    mass: np.ndarray
    keys: np.ndarray
    periods: np.ndarray

    def branch(self, polarization) -> int:
        """The branch whose motion is closest to every sublattice moving along ``polarization`` alike
        (the wave a ModeProbe starts): the largest mass-weighted overlap."""
        p = np.asarray(polarization, dtype=np.float64)
        p = p / np.linalg.norm(p)
        U, m = self.U, self.mass
        overlap = np.abs(np.einsum("s,bsd,d->b", m, U, p)) ** 2 / np.einsum("s,bsd->b", m, np.abs(U) ** 2)
        return int(np.argmax(overlap))

    def profile(self, X: np.ndarray, branch: int, polarization) -> np.ndarray:
        """(n,) the branch's amplitude along ``polarization`` at each vertex of X (a larger piece of
        the same lattice), relative to its mass-weighted mean over the sublattices: the factor by
        which the mode's displacement differs from vertex to vertex (1 where all sublattices move
        alike)."""
        p = np.asarray(polarization, dtype=np.float64)
        a = self.U[branch] @ (p / np.linalg.norm(p))
        a = a * np.exp(-1j * np.angle(a[np.argmax(np.abs(a))]))
        if np.abs(a.imag).max() > 1e-9 * np.abs(a).max():
            raise ValueError("BlochModes.profile: the branch's sublattices are out of phase (not a standing wave)")
        a = a.real / (self.mass @ a.real / self.mass.sum())
        index = {tuple(key): s for s, key in enumerate(self.keys)}
        try:
            return np.array([a[index[tuple(key)]] for key in sublattice_keys(X, self.periods)])
        except KeyError:
            raise ValueError("BlochModes.profile: X is not a piece of the same lattice") from None


def bloch_modes(X: np.ndarray, mass: np.ndarray, periods, k, stiffness: np.ndarray,
                damping: np.ndarray | None = None, dims: int = 2) -> BlochModes:
    """The plane-wave modes of a periodic lattice at wavevector ``k``, read from a finite patch of it.

    X (n, >= 2) rest positions, mass (n,) lumped masses, periods (2, 2) the lattice's translation
    vectors (rows), ``stiffness`` and ``damping`` dense (3n, 3n) matrices of the patch at rest
    (e.g. Energy.dense_hessian, dense_damping). Vertices whose positions differ by a translation
    form one sublattice; one vertex of each, the nearest the patch's centre (so the patch must
    reach a stencil beyond it), gives its row of the Bloch matrix

        D(k)_{s s'} = sum_{j in s'} A[rep_s, j] exp(i k.(X_j - X_rep_s))         (in-plane dofs)

    and a displacement U_s exp(i k.X_j) on sublattice s is a mode when w^2 M U = D_K U. With unequal
    masses (the alternating grid's 4/3 and 2/3 of rho h^2) the wave is this mode, not the unit-mass
    one. A branch's damping per unit mass is c = U^H D_C U (U mass-normalised; exact when D_C
    commutes with the branch, e.g. proportional damping; 0 without ``damping``)."""
    X = np.asarray(X, dtype=np.float64)
    keys, label = np.unique(sublattice_keys(X, periods), axis=0, return_inverse=True)
    label = label.ravel()
    centre = X[:, :2].mean(axis=0)
    dist = np.linalg.norm(X[:, :2] - centre, axis=1)
    reps = [int(np.flatnonzero(label == s)[np.argmin(dist[label == s])]) for s in range(len(keys))]
    phase = np.exp(1j * (X[:, :2] @ np.asarray(k, dtype=np.float64)))
    ns = len(reps)

    def bloch(A):
        A = np.asarray(A).reshape(len(X), 3, len(X), 3)[:, :dims, :, :dims]
        D = np.zeros((ns * dims, ns * dims), dtype=np.complex128)
        for s, r in enumerate(reps):
            row = A[r] * (phase / phase[r])[None, :, None]       # (dims, n, dims)
            for t in range(ns):
                D[s * dims:(s + 1) * dims, t * dims:(t + 1) * dims] = row[:, label == t, :].sum(axis=1)
        return 0.5 * (D + D.conj().T)

    m_sub = np.asarray(mass, dtype=np.float64)[reps]
    m_half = np.repeat(np.sqrt(m_sub), dims)
    w2, V = np.linalg.eigh(bloch(stiffness) / np.outer(m_half, m_half))
    c = np.zeros_like(w2)
    if damping is not None:
        c = np.real(np.einsum("ib,ij,jb->b", V.conj(), bloch(damping) / np.outer(m_half, m_half), V))
    return BlochModes(w2, c, (V / m_half[:, None]).T.reshape(-1, ns, dims), m_sub, keys,
                      np.asarray(periods, dtype=np.float64))
