"""Scenes shared by lessons and benchmarks, so a benchmark times exactly what a lesson runs.

``cloth``: a square sheet of ``n x n`` vertices (right-triangle grid, alternating diagonals by
default) hanging in the x-z plane, with area-scaled springs (c_e = E A_e, W = 1/2 E (l/L-1)^2 A_e),
dihedral bending (engine/energies/bending.py) and gravity, pinned at its two top corners.
Units: E is the 2D stretching modulus (N/m: Young's modulus times thickness), rho the areal
density (kg/m^2), B the bending modulus (N m).

``Rod``: the 1D elastic rod of the notes' first slides as a chain Model. Nodes at rest positions
p_0 < ... < p_{n-1} on the x axis (not necessarily evenly spaced) move along the axis; segment j
joins nodes j and j+1, has rest length h_j = p_{j+1} - p_j, Young's modulus E_j (the notes'
E_{j+1/2}; N, force per unit strain in 1D) and linear density rho_j (kg/m). Its springs have
c_j = E_j h_j, so the spring energy (S1) is the notes' "1D continuum potential"

    W = sum_j 1/2 E_j ((x_{j+1} - x_j)/h_j - 1)^2 h_j                                        (R1)

and the spring force (S2) along the axis is f_i = E_i s_i - E_{i-1} s_{i-1} (s_j the strain), which
divided by the lumped mass m_i = (rho_{i-1} h_{i-1} + rho_i h_i)/2 is the finite-difference stencil
of (1/rho) d/dp (E (dx/dp - 1)) (notes, "From last class"). The nodes move along the axis only, so
the rod is stepped in that one coordinate (engine.energies.axial): a run is one launch of
engine.integrators.batched_steps.axial_steps, the same explicit updates as every model, backward Euler by
the tridiagonal solve of engine.solvers.thomas. ``Rod.model`` is the same rod as a 3D chain Model
(for the general solvers). Theory of the schemes on the rod: engine.theory.schemes.
"""
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla

import taichi as ti

from engine import mesh as meshes
from engine.constants import G
from engine.energies.bending import BendingEnergy
from engine.errors import BlowUpError, ParameterError
from engine.energies.axial import axial_energy_kernel, axial_forces_kernel
from engine.fields import float_dtype, scalar_ndarray
from engine.runtime import RuntimeConfigError
from engine.model import Model
from engine.stability import lambda_max_from_rows


@dataclass
class Cloth:
    mesh: meshes.Mesh
    model: Model
    springs: object
    bending: object | None


def cloth(n: int, size: float = 1.0, E: float = 1e3, rho: float = 0.1, B: float = 1e-4,
          variant: str = "notes", diagonals: str = "alternating", pins: str = "top-corners",
          gravity: float = G) -> Cloth:
    """Build the hanging-cloth scene; ``B = 0`` leaves the bending energy out."""
    m2 = meshes.right_triangle_grid(n, n, size, size, diagonals=diagonals)
    m3 = meshes.embed_3d(m2, plane="xz")
    X = np.asarray(m3.vertices, dtype=np.float64)
    if pins == "top-corners":
        top = np.flatnonzero(np.isclose(X[:, 2], X[:, 2].max()))
        pinned = [int(top[np.argmin(X[top, 0])]), int(top[np.argmax(X[top, 0])])]
    elif pins == "top-edge":
        pinned = np.flatnonzero(np.isclose(X[:, 2], X[:, 2].max())).tolist()
    elif pins == "none":
        pinned = []
    else:
        raise ValueError(f"pins must be top-corners, top-edge or none (got {pins!r})")
    model = Model.from_springs(X, m3.edges, c=E * m3.edge_measure, mass=meshes.lumped_masses(m3, rho),
                               pinned=pinned, gravity=[0.0, 0.0, -gravity])
    bending = None
    if B > 0:
        bending = model.add_energy(BendingEnergy.from_mesh(m3, B, variant))
    return Cloth(m3, model, model.springs, bending)



# ------------------------------------------------------------------ the rod's launches

@ti.kernel
def _serial_count(n: ti.i32) -> ti.i32:
    """Counts n iterations of one serial loop (the probe of :func:`serial_loop_limit`)."""
    c = 0
    ti.loop_config(serialize=True)
    for _ in range(1):
        for i in range(n):
            c += 1
    return c


_PROBE = 1 << 22
_loop_limit: dict = {}


def backend_name() -> str:
    """The backend Taichi actually runs on: cpu, cuda or vulkan (TI_ARCH can override what
    engine.runtime.init was asked for)."""
    from taichi.lang import impl
    name = ti._lib.core.arch_name(impl.current_cfg().arch)
    return name if name in ("cuda", "vulkan") else "cpu"


def serial_loop_limit() -> int | None:
    """The most loop iterations one invocation of a kernel runs on this backend (None: no limit).

    Mesa's software Vulkan driver (lavapipe, llvmpipe) ends every loop of a shader once the
    shader has run 65535 loop iterations in all, a guard against endless shaders that raises no
    error: a serial kernel that loops longer stops part-way and returns what it has. The rod's
    many-steps kernel is such a loop (about 5 passes over the nodes per step), so there a run
    of 1001 nodes stopped after 16 steps of each launch and the pulses moved at 0.8 c. CPU
    backends have no such cut-off; the count of a 4M-iteration serial loop tells, once per
    process."""
    arch = backend_name()
    if arch == "cpu":
        return None
    if arch not in _loop_limit:
        count = int(_serial_count(_PROBE))
        _loop_limit[arch] = None if count >= _PROBE else count
    return _loop_limit[arch]


# Loop iterations of one step of engine.integrators.batched_steps.axial_steps, per node: velocity
# Verlet (kick-drift, forces, kick) and backward Euler (Thomas: set-up and elimination,
# substitution, drift) make three passes over the nodes, the others two; the energies of the
# step two more. Velocity Verlet also makes one pass before the first step.
_PASSES_PER_STEP = 5
_LIMIT_MARGIN = 0.9  # of the probed limit: the driver's count also includes loop entries


def rod_max_nodes() -> int | None:
    """The most nodes a :class:`Rod` can be stepped with on this backend (None: any number):
    one step, and velocity Verlet's first pass, must fit in :func:`serial_loop_limit`."""
    limit = serial_loop_limit()
    if limit is None:
        return None
    return int((_LIMIT_MARGIN * limit - 2) // (_PASSES_PER_STEP + 1))


def _largest_float() -> float:
    return float(np.finfo(float_dtype()).max)


class RodState:
    """A state of a :class:`Rod`: positions ``x`` and velocities ``v`` along the axis (scalar
    ndarrays), time ``t``."""

    def __init__(self, x, v, t: float = 0.0):
        self.x, self.v, self.t = x, v, float(t)

    def positions(self) -> np.ndarray:
        """x_i along the axis (m)."""
        return self.x.to_numpy().astype(np.float64)

    def displacement(self, rod: "Rod") -> np.ndarray:
        """u_i = x_i - p_i (m)."""
        return self.positions() - rod.p

    def velocity(self) -> np.ndarray:
        """dx_i/dt along the axis (m/s)."""
        return self.v.to_numpy().astype(np.float64)


class Rod:
    """The rod scene: rest node positions, segment E and rho, pins, and its chain ``model``.

    Parameters (SI): p: node rest positions (m), strictly increasing, at least 3 nodes;
    E: Young's modulus per segment (N) or a scalar; rho: linear density per segment
    (kg/m) or a scalar; pinned: node indices held fixed.
    """

    def __init__(self, p, E=1.0, rho=1.0, pinned=()):
        p = np.asarray(p, dtype=np.float64)
        if p.ndim != 1 or p.size < 3:
            raise ParameterError(f"nodes must be >= 3 (got {p.size})")
        if not np.all(np.isfinite(p)):
            raise ParameterError("node positions p must be finite")
        h = np.diff(p)
        if np.any(h <= 0):
            j = int(np.argmax(h <= 0))
            raise ParameterError(f"node positions must increase: segment {j} has length {h[j]:.6g} (must be > 0)")
        n = p.size
        E = np.broadcast_to(np.asarray(E, dtype=np.float64), (n - 1,)).copy()
        rho = np.broadcast_to(np.asarray(rho, dtype=np.float64), (n - 1,)).copy()
        for name, arr in (("E", E), ("rho", rho)):
            bad = ~(np.isfinite(arr) & (arr > 0))
            if np.any(bad):
                j = int(np.argmax(bad))
                raise ParameterError(f"{name} must be > 0 and finite (got {arr[j]!r} on segment {j})")
        pinned = np.asarray(pinned, dtype=np.int64).reshape(-1)
        if pinned.size and (pinned.min() < 0 or pinned.max() >= n):
            raise ParameterError(f"pinned node indices must be in 0..{n - 1} (got {pinned.tolist()})")
        self.p, self.h, self.E, self.rho = p, h, E, rho
        self.n = n
        seg_mass = rho * h
        self.mass = np.zeros(n)
        self.mass[:-1] += 0.5 * seg_mass  # lumped: half of each adjacent segment
        self.mass[1:] += 0.5 * seg_mass
        self.pinned = np.zeros(n, dtype=bool)
        self.pinned[pinned] = True
        inv_m = np.where(self.pinned, 0.0, 1.0 / self.mass)
        self._h, self._E, self._m, self._inv_m = (scalar_ndarray(a) for a in (h, E, self.mass, inv_m))
        self._work = tuple(scalar_ndarray(np.zeros(n)) for _ in range(3))  # a, Cp, Dp of axial_steps
        self._modes = None
        self._model = None

    @classmethod
    def uniform(cls, nodes: int, length: float = 1.0, E=1.0, rho=1.0, pinned=()):
        if int(nodes) < 3:
            raise ParameterError(f"nodes must be >= 3 (got {nodes})")
        return cls(np.linspace(0.0, length, int(nodes)), E, rho, pinned)

    # --- physics quantities -------------------------------------------------------
    def wave_speed(self) -> np.ndarray:
        """c = sqrt(E/rho) per segment (m/s)."""
        return np.sqrt(self.E / self.rho)

    def impedance(self) -> np.ndarray:
        """Z = sqrt(E rho) per segment (kg/s)."""
        return np.sqrt(self.E * self.rho)

    @property
    def model(self) -> Model:
        """The same rod as a chain Model in 3D (springs c = E h along x, the lumped masses and pins),
        for the general solvers and the energies' own checks."""
        if self._model is None:
            X = np.zeros((self.n, 3))
            X[:, 0] = self.p
            edges = np.stack([np.arange(self.n - 1), np.arange(1, self.n)], axis=1)
            self._model = Model.from_springs(X, edges, c=self.E * self.h, L=self.h, mass=self.mass,
                                             pinned=self.pinned)
        return self._model

    def omega_max_bound(self) -> float:
        """Upper bound on the highest angular frequency: the Gershgorin bound (engine.stability (C1))
        on M^-1 K; row i sums 2 (k_{i-1} + k_i), k_j = E_j/h_j (the chain model's row sums along
        the axis), exact for a uniform free rod: w_max = 2c/h."""
        k = self.E / self.h
        row = np.zeros(self.n)
        row[:-1] += 2 * k
        row[1:] += 2 * k
        return float(np.sqrt(lambda_max_from_rows(row, self.mass, ~self.pinned)))

    def stable_dt(self) -> float:
        """Largest dt with w_max dt <= 2 (symplectic Euler's and velocity Verlet's limit); conservative."""
        return 2.0 / self.omega_max_bound()

    def stiffness_matrix(self) -> np.ndarray:
        """Dense K (n x n) for reference checks in tests and lessons."""
        k = self.E / self.h
        K = np.zeros((self.n, self.n))
        idx = np.arange(self.n - 1)
        K[idx, idx] += k
        K[idx + 1, idx + 1] += k
        K[idx, idx + 1] -= k
        K[idx + 1, idx] -= k
        return K

    def normal_modes(self):
        """(w2, Phi, free): the eigenpairs K Phi = M Phi diag(w2) of the free nodes (numpy, for
        reference checks), Phi M-orthonormal (Phi^T M Phi = I), w2 ascending (rigid modes ~ 0,
        clipped at 0); ``free`` the indices of the unpinned nodes. Computed once per rod.

        K restricted to the free nodes is tridiagonal, so S = M^-1/2 K M^-1/2 is a symmetric
        tridiagonal matrix and LAPACK's tridiagonal eigensolver gives S = Y diag(w2) Y^T;
        Phi = M^-1/2 Y."""
        if getattr(self, "_modes", None) is None:
            free = np.flatnonzero(~self.pinned)
            k = self.E / self.h
            diag = np.zeros(self.n)
            diag[:-1] += k
            diag[1:] += k
            off = np.where(np.diff(free) == 1, -k[free[:-1]], 0.0)  # coupling of consecutive free nodes
            s = 1.0 / np.sqrt(self.mass[free])
            w2, Y = sla.eigh_tridiagonal(diag[free] * s * s, off * s[:-1] * s[1:])
            self._modes = (np.clip(w2, 0.0, None), s[:, None] * Y, free)
        return self._modes

    # --- kernels ---------------------------------------------------------------------
    def energy(self, x) -> float:
        """W(x) of (R1); x: positions along the axis (numpy) or a state's ``x``."""
        self._steps_per_launch()  # its serial sum must fit in the backend's loop limit, as a step must
        return float(axial_energy_kernel(self._nd(x), self._h, self._E))

    def forces(self, x) -> np.ndarray:
        """-dW/dx_i along the axis at every node (pinned ones included)."""
        f = scalar_ndarray(np.zeros(self.n))
        axial_forces_kernel(self._nd(x), self._h, self._E, f)
        return f.to_numpy().astype(np.float64)

    @staticmethod
    def _nd(x):
        return scalar_ndarray(x) if isinstance(x, np.ndarray) else x

    def new_state(self, u0=None, v0=None) -> RodState:
        """A state with displacement u0 (x = p + u0) and velocity v0 (zero by default)."""
        x = self.p + (0 if u0 is None else np.asarray(u0, dtype=np.float64))
        v = np.zeros(self.n) if v0 is None else np.asarray(v0, dtype=np.float64).copy()
        v[self.pinned] = 0.0
        return RodState(scalar_ndarray(x), scalar_ndarray(v))

    def kinetic(self, state: RodState) -> float:
        v = state.velocity()
        return float(0.5 * np.sum(self.mass * v * v))

    def run(self, state: RodState, dt: float, n_steps: int, method: str = "symplectic-euler",
            energy_bound: float | None = None, step_offset: int = 0):
        """Advance ``n_steps`` steps of ``method`` in one launch (engine.integrators.batched_steps.axial_steps);
        returns (kinetic, potential) arrays, one entry per step. A step whose total energy is not finite
        or exceeds ``energy_bound`` raises the monitor's BlowUpError naming that step (``step_offset`` +
        index), with the energies up to it. The state stays at that step.

        On a backend whose kernels stop loops after :func:`serial_loop_limit` iterations (software
        Vulkan) the steps are split over as many launches as keep each one below it (the same
        steps: velocity Verlet's a(x) at a launch's start is the one its last step computed); a rod
        too long for one step there is refused (RuntimeConfigError)."""
        from engine.integrators import batched_steps, kernels
        from engine.integrators.monitor import Monitor

        if not (np.isfinite(dt) and dt > 0):
            raise ParameterError(f"dt must be > 0 and finite (got {dt!r})")
        if method not in kernels.METHODS:
            raise ParameterError(f"integrator must be one of {', '.join(kernels.METHODS)} (got {method!r})")
        n_steps = int(n_steps)
        if n_steps <= 0:
            return np.zeros(0), np.zeros(0)
        per_launch = self._steps_per_launch()
        monitor = Monitor(method, dt, energy_bound, dt_stable=self.stable_dt)
        # The kernel stops at the first step whose K + W is not <= bound. Without a bound (inf) an
        # energy that has overflowed to +inf passes that test (inf <= inf), and the kernel's NaN test
        # does not catch it either; the rod is linear, so its positions stay finite while K or W
        # overflow, and a run at nu = 1.0001 ran all its steps to displacements of 1e236 m. The
        # largest finite number of the precision as the bound makes every non-finite total a blow-up.
        bound = min(monitor.bound, _largest_float())
        a, Cp, Dp = self._work
        parts, done = [], 0
        while done < n_steps:
            k = min(n_steps - done, per_launch)
            kin, pot = batched_steps.energy_buffers(k)
            stop = batched_steps.axial_steps(state.x, state.v, a, self._h, self._E, self._m, self._inv_m, float(dt), k,
                                             kin, pot, bound, Cp, Dp, kernels.METHODS[method])
            try:
                with np.errstate(over="ignore"):  # K + W of a blown-up step may overflow
                    parts.append(batched_steps.collect(kin, pot, stop, k, state, float(dt), monitor,
                                                       step_offset + done))
            except BlowUpError as exc:
                if parts:  # the energies of the earlier launches too, up to the bad step
                    exc.kinetic = np.concatenate([p[0] for p in parts] + [exc.kinetic])
                    exc.potential = np.concatenate([p[1] for p in parts] + [exc.potential])
                raise
            done += k
        if len(parts) == 1:
            return parts[0]
        return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])

    def _steps_per_launch(self) -> int:
        """Steps one launch of the many-steps kernel may take on this backend (see run)."""
        limit = serial_loop_limit()
        if limit is None:
            return 1 << 62
        most = rod_max_nodes()
        if self.n > most:
            raise RuntimeConfigError(
                f"a rod of {self.n} nodes cannot be stepped on this {backend_name()} device: it stops every kernel "
                f"loop after {limit} iterations and one step needs about {_PASSES_PER_STEP * self.n}; use at most "
                f"{most} nodes or --arch cpu")
        return max(1, int((_LIMIT_MARGIN * limit - self.n) // (_PASSES_PER_STEP * self.n + 2)))
