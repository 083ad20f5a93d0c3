"""Static model description (topology, rest state, masses, pins, energies) and time-varying state.

Following the Model/State split of Warp: a :class:`Model` is built once from numpy arrays,
validated, and turned into Taichi ndarrays; a :class:`State` holds what changes in time
(positions ``x``, velocities ``v``, time ``t``).  Integrators only ever talk to
``model.energies`` through the :class:`Energy` protocol and never know which energies exist.

Potential energy (lecture notes, "Potential energy" slides): the total is the sum of the
elastic energies plus the gravity potential ``W_g = -sum_i m_i g . x_i`` over free vertices,
and every force is its negative gradient, ``f = -dW/dx``.

Pins: a pinned vertex has inverse mass 0, never gets a force and never moves.

Nothing here touches Taichi at import time; call :func:`engine.runtime.init` first.
"""

from typing import NamedTuple, Sequence

import numpy as np
import taichi as ti

from engine.energies.base import Energy
from engine.energies.masses import add_gravity_potential, finish_force
from engine.energies.springs import SpringEnergy
from engine.errors import ModelError
from engine.fields import (copy_vec3, float_dtype, per_item, scalar_array, scalar_ndarray, vec3_array, vec3_ndarray,
                           zero_vec3)


# --------------------------------------------------------------------------------------------
# Kernels of the model's own terms (gravity, pins)
# --------------------------------------------------------------------------------------------

@ti.kernel
def gravity_energy_kernel(x: vec3_array, mass: scalar_array, inv_mass: scalar_array,
                          g: ti.math.vec3) -> float:
    # W_g = -sum_{free i} m_i g . x_i (engine.energies.masses)
    return add_gravity_potential(0.0, x, mass, inv_mass, g)


@ti.kernel
def finish_forces_kernel(f: vec3_array, mass: scalar_array, inv_mass: scalar_array, g: ti.math.vec3):
    # f_i += m_i g for free vertices (gravity = -dW_g/dx_i); pinned vertices get zero force
    for i in range(f.shape[0]):
        f[i] = finish_force(f[i], mass[i], inv_mass[i], g)


# --------------------------------------------------------------------------------------------
# State
# --------------------------------------------------------------------------------------------

class StateArrays(NamedTuple):
    """numpy copies of a :class:`State`."""
    x: np.ndarray
    v: np.ndarray
    t: float


class State:
    """Time-varying state: positions ``x`` (m), velocities ``v`` (m/s), time ``t`` (s)."""

    def __init__(self, x, v, t: float = 0.0):
        self.x = x
        self.v = v
        self.t = float(t)

    @property
    def n(self) -> int:
        return self.x.shape[0]

    @classmethod
    def from_numpy(cls, x: np.ndarray, v: np.ndarray | None = None, t: float = 0.0) -> "State":
        x = np.asarray(x, dtype=float)
        if x.ndim != 2 or x.shape[1] != 3:
            raise ModelError(f"state positions must have shape (n, 3), got {x.shape}")
        if v is None:
            v = np.zeros_like(x)
        v = np.asarray(v, dtype=float)
        if v.shape != x.shape:
            raise ModelError(f"state velocities must have shape {x.shape}, got {v.shape}")
        return cls(vec3_ndarray(len(x), x), vec3_ndarray(len(x), v), t)

    def numpy(self) -> StateArrays:
        return StateArrays(self.x.to_numpy().astype(np.float64), self.v.to_numpy().astype(np.float64), self.t)

    def assign(self, x: np.ndarray | None = None, v: np.ndarray | None = None, t: float | None = None) -> None:
        """Overwrite positions and/or velocities from numpy arrays (n, 3)."""
        if x is not None:
            self.x.from_numpy(np.ascontiguousarray(x, dtype=float_dtype()).reshape(-1, 3))
        if v is not None:
            self.v.from_numpy(np.ascontiguousarray(v, dtype=float_dtype()).reshape(-1, 3))
        if t is not None:
            self.t = float(t)

    def copy(self) -> "State":
        s = State(vec3_ndarray(self.n), vec3_ndarray(self.n), self.t)
        copy_vec3(self.x, s.x)
        copy_vec3(self.v, s.v)
        return s


# --------------------------------------------------------------------------------------------
# Model
# --------------------------------------------------------------------------------------------

class Model:
    """Static description of a particle system: rest positions, lumped masses, pins, gravity
    and a list of :class:`Energy` objects.

    Parameters (SI units):
      X        (n, 3) rest positions [m]
      mass     scalar or (n,) lumped masses [kg]; must be > 0 for free vertices
      pinned   boolean mask (n,) or list of vertex indices that never move
      gravity  (3,) acceleration [m/s^2], default zero
      energies energy objects (see :class:`Energy`), more via :meth:`add_energy`
    """

    def __init__(self, X: np.ndarray, mass=1.0, pinned=None, gravity=None,
                 energies: Sequence[Energy] = ()):
        X, m, pinned_mask, g = self.check_inputs(X, mass, pinned, gravity)
        n = len(X)
        self.n = n
        self.X = X.copy()
        self.X.setflags(write=False)
        self.mass = m
        self.pinned = pinned_mask
        self.free = ~pinned_mask
        self.gravity = g
        self.gravity_vec = ti.math.vec3(*g)  # kernel argument, built once
        m_free = m[~pinned_mask]
        self.weight_norm = float(np.sqrt(np.sum(m_free * m_free)) * np.linalg.norm(g))  # |M g| over free vertices (N)
        inv = np.where(pinned_mask, 0.0, 1.0 / np.where(m > 0, m, 1.0))
        # Taichi arrays
        self.mass_nd = scalar_ndarray(m)
        self.inv_mass_nd = scalar_ndarray(inv)
        self.X_nd = vec3_ndarray(n, X)
        self.energies: tuple[Energy, ...] = ()
        self._frozen = False
        for e in energies:
            self.add_energy(e)

    @staticmethod
    def check_inputs(X, mass=1.0, pinned=None, gravity=None):
        """Validate in numpy (before any kernel runs); returns (X, mass, pinned_mask, gravity).
        Raises ModelError with a one-line message naming the offending vertex/pin."""
        X = np.asarray(X, dtype=np.float64)
        if X.ndim != 2 or X.shape[1] != 3:
            raise ModelError(f"rest positions X must have shape (n, 3), got {X.shape}")
        n = len(X)
        if n == 0:
            raise ModelError("model has no vertices")
        bad = np.flatnonzero(~np.isfinite(X).all(axis=1))
        if bad.size:
            raise ModelError(f"vertex {bad[0]} has a non-finite rest position {X[bad[0]].tolist()}")

        pinned_mask = np.zeros(n, dtype=bool)
        if pinned is not None:
            p = np.asarray(pinned)
            if p.dtype == bool:
                if p.shape != (n,):
                    raise ModelError(f"pinned mask must have shape ({n},), got {p.shape}")
                pinned_mask = p.copy()
            else:
                p = p.reshape(-1)
                if p.size and not np.issubdtype(p.dtype, np.integer):
                    raise ModelError(f"pinned must be a boolean mask or integer vertex indices, got dtype {p.dtype}")
                out = np.flatnonzero((p < 0) | (p >= n))
                if out.size:
                    raise ModelError(f"pin index {int(p[out[0]])} is out of range 0..{n - 1}")
                pinned_mask[p.astype(np.int64)] = True

        m = per_item("mass", mass, n)
        bad = np.flatnonzero(~np.isfinite(m) | (m < 0))
        if bad.size:
            raise ModelError(f"vertex {bad[0]} has invalid mass {float(m[bad[0]])!r} (must be finite and >= 0)")
        bad = np.flatnonzero(~pinned_mask & (m <= 0))
        if bad.size:
            raise ModelError(f"vertex {bad[0]} is free but has mass {float(m[bad[0]])!r} (must be > 0; pin it or give it mass)")

        g = np.zeros(3) if gravity is None else np.asarray(gravity, dtype=np.float64).reshape(-1)
        if g.shape != (3,) or not np.isfinite(g).all():
            raise ModelError(f"gravity must be 3 finite numbers, got {gravity!r}")
        return X, m, pinned_mask, g

    # -- construction helpers ----------------------------------------------------------------
    @classmethod
    def from_springs(cls, X: np.ndarray, edges: np.ndarray, k=None, c=None, L=None, mass=1.0,
                     pinned=None, gravity=None) -> "Model":
        """A spring network.  Give exactly one of
          k  spring constant(s) of the notes' 1D spring W = 1/2 k (l/L - 1)^2 L  -> c = k L
          c  per-edge coefficient(s) directly, e.g. c = E A_e for area/volume springs.
        L: rest lengths (m,), default |X_i - X_j|."""
        X = cls.check_inputs(X, mass, pinned, gravity)[0]
        edges, L, c, name = SpringEnergy.prepare(X, edges, k=k, c=c, L=L)  # numpy checks before any kernel
        model = cls(X, mass=mass, pinned=pinned, gravity=gravity)
        model.add_energy(SpringEnergy(model.n, edges, L, c, X=X, coef_name=name))
        return model

    def add_energy(self, energy: Energy) -> Energy:
        if getattr(energy, "n_vertices", self.n) != self.n:
            raise ModelError(f"{energy.name} energy is defined on {energy.n_vertices} vertices, model has {self.n}")
        if self._frozen:
            raise ModelError(f"cannot add the {energy.name} energy: the model is frozen once a state has been made "
                             f"from it (add every energy before make_state)")
        object.__setattr__(self, "energies", self.energies + (energy,))
        return energy

    def __setattr__(self, name, value):
        if getattr(self, "_frozen", False):
            raise AttributeError(f"a Model does not change once a state has been made from it (setting {name!r}); "
                                 f"keep per-run data with the solver, or build a new Model")
        object.__setattr__(self, name, value)

    @property
    def springs(self):
        """The first spring energy, or None."""
        return next((e for e in self.energies if isinstance(e, SpringEnergy)), None)

    # -- state and work arrays ---------------------------------------------------------------
    def make_state(self, x: np.ndarray | None = None, v: np.ndarray | None = None, t: float = 0.0) -> State:
        """A State at positions x (default: rest X) with velocities v (default 0; pinned forced 0)."""
        x = self.X if x is None else np.asarray(x, dtype=np.float64)
        v = np.zeros((self.n, 3)) if v is None else np.array(v, dtype=np.float64)
        if x.shape != (self.n, 3) or v.shape != (self.n, 3):
            raise ModelError(f"state arrays must have shape ({self.n}, 3), got x {x.shape}, v {v.shape}")
        for what, a in (("positions", x), ("velocities", v)):
            bad = np.flatnonzero(~np.isfinite(a).all(axis=1))
            if bad.size:  # a simulation started from it would only blow up at its first step
                raise ModelError(f"initial {what}: vertex {bad[0]} is not finite ({a[bad[0]].tolist()})")
        v[self.pinned] = 0.0
        object.__setattr__(self, "_frozen", True)  # built: energies, masses and pins are fixed from here on
        return State.from_numpy(x, v, t)

    # -- energies and forces -----------------------------------------------------------------
    def elastic_energy(self, x) -> float:
        return float(sum(e.energy(x) for e in self.energies))

    def gravity_energy(self, x) -> float:
        if not self.gravity.any():
            return 0.0
        return float(gravity_energy_kernel(x, self.mass_nd, self.inv_mass_nd, self.gravity_vec))

    def potential_energy(self, x) -> float:
        """All energies plus the gravity potential -sum m g . x (free vertices)."""
        return self.elastic_energy(x) + self.gravity_energy(x)

    def add_elastic_forces(self, x, f) -> None:
        """f += -grad of every energy (no gravity, no pin handling)."""
        for e in self.energies:
            e.add_forces(x, f)

    @property
    def dampers(self) -> list:
        """The energies that also damp (Baraff-Witkin's damping of a membrane's conditions, (M3) of
        engine.energies.membrane): a force -D(x) v that depends on the velocity."""
        return [e for e in self.energies if getattr(e, "has_damping", False)]

    def add_damping_forces(self, x, v, f) -> None:
        """f += -D(x) v summed over the dampers (no pin handling)."""
        for e in self.dampers:
            e.add_damping_forces(x, v, f)

    def add_damping_product(self, x, w, out) -> None:
        """out += D(x) w summed over the dampers (no pin handling)."""
        for e in self.dampers:
            e.add_damping_product(x, w, out)

    def forces(self, x, f) -> None:
        """f = -grad(potential): zero f, add all energies, add m g; pinned vertices get zero."""
        zero_vec3(f)
        self.add_elastic_forces(x, f)
        finish_forces_kernel(f, self.mass_nd, self.inv_mass_nd, self.gravity_vec)

    def add_hessian_product(self, x, dx, out, psd: bool = True) -> None:
        """out += H dx summed over all energies (gravity is linear: no Hessian). No pin handling."""
        for e in self.energies:
            e.add_hessian_product(x, dx, out, psd)

    def dense_hessian(self, x, psd: bool = True) -> np.ndarray:
        """Dense (3n, 3n) Hessian of the potential (tests, small models only)."""
        H = np.zeros((3 * self.n, 3 * self.n))
        for e in self.energies:
            H += e.dense_hessian(x, psd)
        return H
