"""The 1D elastic rod of the notes' first slides, as a chain of 1D springs.

A rod of rest length L is parameterised by p; nodes sit at p_0 < p_1 < ... < p_{n-1}
(not necessarily evenly spaced) and move along the rod's axis, x_i(t). Segment j joins
nodes j and j+1, has rest length h_j = p_{j+1} - p_j, Young's modulus E_j (the notes'
E_{j+1/2}, units N: force per unit strain in 1D) and linear density rho_j (kg/m).

Energy (notes, "1D Continuum potential"):
    W = sum_j 1/2 E_j ((x_{j+1} - x_j)/h_j - 1)^2 h_j
Force (= -dW/dx_i), with strain s_j = (x_{j+1} - x_j)/h_j - 1:
    f_i = E_i s_i - E_{i-1} s_{i-1}
which, divided by the lumped mass m_i = (rho_{i-1} h_{i-1} + rho_i h_i)/2, is the
finite-difference stencil of (1/rho) d/dp (E (dx/dp - 1)) (notes, "From last class").

A rod is small, so a whole run of many steps is one serial kernel launch (a parallel
launch costs ~0.1 ms, more than a step of a 1000-node rod). Every step also records the
kinetic and potential energy and stops at the first step whose total energy leaves the
given bound or is not finite (blow-up detection at the step it happens).

Integrators: forward Euler, symplectic Euler and velocity Verlet (explicit, CFL-limited;
velocity Verlet is kick(dt/2)-drift(dt)-kick(dt/2)) and backward Euler, which for this linear
rod is exactly one tridiagonal solve per step ((M + dt^2 K) v' = M v + dt f(x); x' = x + dt v'),
done with the Thomas algorithm.

Reference theory of the schemes (numpy, for checks): the rod is linear, f = -K (x - p), so in
the normal modes of K phi = w^2 M phi every scheme is a 2x2 matrix acting on one mode's
(q, dq/dt) per step (:func:`amplification`); :class:`ModalReference` evolves an initial state
mode by mode with those matrices and sums the modes again.
"""

import numpy as np
import scipy.linalg as sla
import taichi as ti

from engine.errors import ParameterError
from engine.integrators.kernels import METHODS
from engine.integrators.monitor import Monitor
from engine.stability import lambda_max_from_rows
from engine.theory.schemes import ModalReference, amplification  # noqa: F401  (re-exported for the lessons)

F1 = ti.types.ndarray(dtype=float, ndim=1)


@ti.func
def _strain(x: ti.template(), h: ti.template(), j: int) -> float:
    return (x[j + 1] - x[j]) / h[j] - 1.0


@ti.func
def _force(x: ti.template(), h: ti.template(), E: ti.template(), i: int, n: int) -> float:
    # f_i = E_i s_i - E_{i-1} s_{i-1}  (minus the gradient of W)
    f = 0.0
    if i < n - 1:
        f += E[i] * _strain(x, h, i)
    if i > 0:
        f -= E[i - 1] * _strain(x, h, i - 1)
    return f


@ti.func
def _potential(x: ti.template(), h: ti.template(), E: ti.template(), n: int) -> float:
    W = 0.0
    for j in range(n - 1):
        s = _strain(x, h, j)
        W += 0.5 * E[j] * s * s * h[j]
    return W


@ti.func
def _kinetic(v: ti.template(), m: ti.template(), n: int) -> float:
    K = 0.0
    for i in range(n):
        K += 0.5 * m[i] * v[i] * v[i]
    return K


@ti.kernel
def rod_energy(x: F1, h: F1, E: F1) -> float:
    """W(x) for the rod (serial sum: deterministic)."""
    W = 0.0
    ti.loop_config(serialize=True)
    for _ in range(1):
        W = _potential(x, h, E, x.shape[0])
    return W


@ti.kernel
def rod_forces(x: F1, h: F1, E: F1, f: F1):
    """f = -dW/dx at every node."""
    n = x.shape[0]
    for i in range(n):
        f[i] = _force(x, h, E, i, n)


@ti.kernel
def rod_run(x: F1, v: F1, h: F1, E: F1, m: F1, inv_m: F1, work: F1, work2: F1,
            dt: float, n_steps: int, method: int, kin: F1, pot: F1, bound: float) -> int:
    """Advance ``n_steps`` steps in one launch; returns the number of steps completed.

    After each step the kinetic and potential energy are written to kin[s], pot[s]. If
    K + W exceeds ``bound`` or is not finite, the run stops and returns s (the index of
    the bad step), so the caller can report the step at which the blow-up happened.
    Pinned nodes have inv_m = 0 and keep v = 0.
    """
    n = x.shape[0]
    done = n_steps
    ti.loop_config(serialize=True)
    for s in range(n_steps):
        if method == 0:  # forward Euler: both updates from the old state
            for i in range(n):
                work[i] = _force(x, h, E, i, n)
            for i in range(n):
                x[i] += dt * v[i]
                v[i] += dt * work[i] * inv_m[i]
        elif method == 1:  # symplectic Euler: kick with f(x_n), drift with v_{n+1}
            for i in range(n):
                work[i] = _force(x, h, E, i, n)
            for i in range(n):
                v[i] += dt * work[i] * inv_m[i]
                x[i] += dt * v[i]
        elif method == 2:  # velocity Verlet: kick dt/2 with f(x_n), drift dt, kick dt/2 with f(x_{n+1})
            for i in range(n):
                work[i] = _force(x, h, E, i, n)
            for i in range(n):
                v[i] += 0.5 * dt * work[i] * inv_m[i]
                x[i] += dt * v[i]
            for i in range(n):
                work[i] = _force(x, h, E, i, n)
            for i in range(n):
                v[i] += 0.5 * dt * work[i] * inv_m[i]
        else:  # backward Euler: (M + dt^2 K) v' = M v + dt f(x); Thomas algorithm
            # row i: a_i v_{i-1} + b_i v_i + c_i v_{i+1} = d_i, with k_j = E_j / h_j.
            # work holds the modified upper diagonal c', work2 the modified rhs d'.
            dt2 = dt * dt
            for i in range(n):
                a = 0.0
                b = 1.0
                c = 0.0
                d = 0.0
                if inv_m[i] > 0.0:
                    b = m[i]
                    d = m[i] * v[i] + dt * _force(x, h, E, i, n)
                    if i > 0:
                        k = E[i - 1] / h[i - 1]
                        a = -dt2 * k
                        b += dt2 * k
                    if i < n - 1:
                        k = E[i] / h[i]
                        c = -dt2 * k
                        b += dt2 * k
                if i == 0:
                    work[i] = c / b
                    work2[i] = d / b
                else:
                    denom = b - a * work[i - 1]
                    work[i] = c / denom
                    work2[i] = (d - a * work2[i - 1]) / denom
            for k in range(n):
                i = n - 1 - k
                vi = work2[i]
                if i < n - 1:
                    vi -= work[i] * v[i + 1]
                v[i] = vi
            for i in range(n):
                x[i] += dt * v[i]
        K = _kinetic(v, m, n)
        W = _potential(x, h, E, n)
        kin[s] = K
        pot[s] = W
        total = K + W
        if not (total <= bound) or total - total != 0.0:  # above the bound, nan, or +-inf
            done = s
            break
    return done


class Rod:
    """Static description of a rod: rest node positions, segment E and rho, pins.

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
        self._h = _nd(h)
        self._E = _nd(E)
        self._m = _nd(self.mass)
        self._inv_m = _nd(inv_m)
        self._w1 = ti.ndarray(float, n)
        self._w2 = ti.ndarray(float, n)

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

    def omega_max_bound(self) -> float:
        """Upper bound on the highest angular frequency: Gershgorin (engine.stability (C1)) on M^-1 K.

        Row i of K has |diagonal| + |off-diagonal| = 2 (k_{i-1} + k_i), k_j = E_j/h_j.
        For a uniform free rod this is exact: w_max = 2c/h.
        """
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

    # --- kernels wrappers ------------------------------------------------------
    def energy(self, x) -> float:
        return rod_energy(_as_nd(x), self._h, self._E)

    def forces(self, x) -> np.ndarray:
        xn = _as_nd(x)
        f = ti.ndarray(float, self.n)
        rod_forces(xn, self._h, self._E, f)
        return f.to_numpy()

    def new_state(self, u0=None, v0=None) -> "RodState":
        """A state with displacement u0 (x = p + u0) and velocity v0 (zero by default)."""
        x = self.p + (0 if u0 is None else np.asarray(u0, dtype=np.float64))
        v = np.zeros(self.n) if v0 is None else np.asarray(v0, dtype=np.float64).copy()
        v[self.pinned] = 0.0
        return RodState(_nd(x), _nd(v))

    def kinetic(self, state: "RodState") -> float:
        v = state.v.to_numpy()
        return float(0.5 * np.sum(self.mass * v * v))

    def run(self, state: "RodState", dt: float, n_steps: int, method: str = "symplectic-euler",
            energy_bound: float | None = None, step_offset: int = 0):
        """Advance ``n_steps`` steps; returns (kinetic, potential) arrays, one entry per step.

        If ``energy_bound`` is given, a step whose total energy exceeds it (or is not
        finite) raises BlowUpError naming that step (``step_offset`` + index).
        """
        if not (np.isfinite(dt) and dt > 0):
            raise ParameterError(f"dt must be > 0 and finite (got {dt!r})")
        if method not in METHODS:
            raise ParameterError(f"integrator must be one of {', '.join(METHODS)} (got {method!r})")
        n_steps = int(n_steps)
        monitor = Monitor(method, dt, energy_bound, dt_stable=self.stable_dt, step_offset=step_offset)
        kin = ti.ndarray(float, max(n_steps, 1))
        pot = ti.ndarray(float, max(n_steps, 1))
        done = rod_run(state.x, state.v, self._h, self._E, self._m, self._inv_m, self._w1, self._w2,
                       float(dt), n_steps, METHODS[method], kin, pot, monitor.bound)
        K, W = kin.to_numpy()[:n_steps], pot.to_numpy()[:n_steps]
        state.t += dt * (done + (1 if done < n_steps else 0))
        if done < n_steps:  # energies up to the bad step travel with the error
            raise monitor.blow_up(done, state.t, K[done] + W[done], K[:done + 1], W[:done + 1])
        return K, W


class RodState:
    """Time-varying state of a rod: positions x and velocities v (Taichi ndarrays)."""

    def __init__(self, x, v, t: float = 0.0):
        self.x, self.v, self.t = x, v, t

    def displacement(self, rod: Rod) -> np.ndarray:
        return self.x.to_numpy() - rod.p

    def velocity(self) -> np.ndarray:
        return self.v.to_numpy()


def _nd(a: np.ndarray):
    a = np.ascontiguousarray(a, dtype=np.float64)
    nd = ti.ndarray(float, a.shape[0])
    nd.from_numpy(a)
    return nd


def _as_nd(x):
    return _nd(x) if isinstance(x, np.ndarray) else x
