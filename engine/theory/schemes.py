"""What each time integrator does to a linear system, mode by mode (numpy references).

A linear system f = -K (x - X) with lumped masses M separates into normal modes K phi = w^2 M phi;
every scheme then advances each mode's (q, dq/dt) by a 2x2 matrix per step (:func:`amplification`),
so its stability, damping and phase error follow from that matrix alone. :class:`ModalReference`
evolves an initial state of a rod mode by mode with those matrices and sums the modes again, an
independent check of the kernels. :func:`symplectic_euler_growth` and
:func:`backward_euler_damping_rate` are the per-step growth and the decay rate those matrices give;
:func:`scheme_frequency` the frequency a mode shows; :func:`backward_euler_damped_sequence` and
:func:`velocity_verlet_damped_rates` the two schemes' maps of a damped mode.
"""
from __future__ import annotations

import math

import numpy as np

from engine.errors import ParameterError
from engine.integrators.kernels import METHODS


def amplification(method: str, w2, dt: float) -> np.ndarray:
    """The per-step matrix of ``method`` for the mode equation q'' = -w^2 q, acting on (q, q').

    With a2 = (w dt)^2:
      forward Euler     [[1, dt], [-dt w^2, 1]]                   (det 1 + a2: grows)
      symplectic Euler  [[1 - a2, dt], [-dt w^2, 1]]              (det 1; stable iff a2 <= 4)
      velocity Verlet   [[1 - a2/2, dt], [-dt w^2 (1 - a2/4), 1 - a2/2]]   (det 1; same limit)
      backward Euler    [[1, dt], [-dt w^2, 1]] / (1 + a2)        (det 1/(1 + a2): damps)
    Symplectic Euler and velocity Verlet have the same trace 2 - a2, hence the same eigenvalues
    (phase per step theta with cos theta = 1 - a2/2): the same dispersion and stability limit.
    Backward Euler's eigenvalues are 1/(1 -+ i w dt): amplitude 1/sqrt(1 + a2), phase atan(w dt).
    Returns an array of shape w2.shape + (2, 2)."""
    w2 = np.asarray(w2, dtype=np.float64)
    a2 = w2 * dt * dt
    A = np.empty(w2.shape + (2, 2))
    if method == "forward-euler":
        A[..., 0, 0], A[..., 0, 1], A[..., 1, 0], A[..., 1, 1] = 1.0, dt, -dt * w2, 1.0
    elif method == "symplectic-euler":
        A[..., 0, 0], A[..., 0, 1], A[..., 1, 0], A[..., 1, 1] = 1.0 - a2, dt, -dt * w2, 1.0
    elif method == "velocity-verlet":
        A[..., 0, 0], A[..., 0, 1] = 1.0 - 0.5 * a2, dt
        A[..., 1, 0], A[..., 1, 1] = -dt * w2 * (1.0 - 0.25 * a2), 1.0 - 0.5 * a2
    elif method == "backward-euler":
        A[..., 0, 0], A[..., 0, 1], A[..., 1, 0], A[..., 1, 1] = 1.0, dt, -dt * w2, 1.0
        A /= (1.0 + a2)[..., None, None]
    else:
        raise ParameterError(f"integrator must be one of {', '.join(METHODS)} (got {method!r})")
    return A


class ModalReference:
    """What ``method`` at step ``dt`` does to a rod's initial state, computed mode by mode in
    numpy (a reference for lessons and tests, independent of the kernels).

    The initial displacement u0 and velocity v0 are projected on the normal modes
    (q = Phi^T M u), each mode's (q, q') is multiplied by ``amplification(method, w^2, dt)``
    to the power of the step count, and the modes are summed again (u = Phi q; pinned nodes 0).
    """

    def __init__(self, rod, u0, v0=None, dt: float = 1.0, method: str = "symplectic-euler"):
        w2, self.phi, self.free = rod.normal_modes()
        m = rod.mass[self.free]
        u0 = np.asarray(u0, dtype=np.float64)
        v0 = np.zeros(rod.n) if v0 is None else np.asarray(v0, dtype=np.float64)
        self.q0 = self.phi.T @ (m * u0[self.free])
        self.p0 = self.phi.T @ (m * v0[self.free])
        self.A = amplification(method, w2, float(dt))
        self.n, self.dt, self.method = rod.n, float(dt), method

    def modes(self, step: int):
        """Modal coordinates (q, q') after ``step`` steps."""
        P = np.linalg.matrix_power(self.A, int(step))
        return (P[:, 0, 0] * self.q0 + P[:, 0, 1] * self.p0, P[:, 1, 0] * self.q0 + P[:, 1, 1] * self.p0)

    def displacement(self, step: int) -> np.ndarray:
        """u = x - p at every node after ``step`` steps."""
        u = np.zeros(self.n)
        u[self.free] = self.phi @ self.modes(step)[0]
        return u

    def velocity(self, step: int) -> np.ndarray:
        v = np.zeros(self.n)
        v[self.free] = self.phi @ self.modes(step)[1]
        return v

    def displacements(self, steps) -> np.ndarray:
        """u after each of the non-decreasing ``steps`` (one row per step), advancing the modes from
        one step to the next and summing them with one matrix product (much faster than calling
        :meth:`displacement` for each)."""
        steps = [int(s) for s in steps]
        if any(b < a for a, b in zip(steps, steps[1:])) or (steps and steps[0] < 0):
            raise ValueError("steps must be non-negative and non-decreasing")
        q, p = self.q0, self.p0
        Q = np.empty((q.size, len(steps)))
        powers, prev = {}, 0
        for j, s in enumerate(steps):
            d = s - prev
            if d:
                P = powers.get(d)
                if P is None:
                    P = powers[d] = np.linalg.matrix_power(self.A, d)
                q, p = P[:, 0, 0] * q + P[:, 0, 1] * p, P[:, 1, 0] * q + P[:, 1, 1] * p
            Q[:, j] = q
            prev = s
        U = np.zeros((len(steps), self.n))
        U[:, self.free] = (self.phi @ Q).T
        return U


def scheme_frequency(method: str, w2: float, dt: float) -> float:
    """The angular frequency a mode of w^2 = ``w2`` shows under ``method`` at step dt: the phase per step
    of :func:`amplification`'s eigenvalues over dt; 2 asin(w dt/2)/dt for symplectic Euler and velocity
    Verlet, atan(w dt)/dt for forward and backward Euler. Started from rest, velocity Verlet's and
    backward Euler's q_n is |z|^n cos(n w dt) exactly (their matrices' diagonals are equal); symplectic
    Euler's carries a phase offset of order (w dt)^2 besides."""
    z = np.linalg.eigvals(amplification(method, w2, dt))
    return float(np.abs(np.angle(z)).max() / dt)


def symplectic_euler_growth(z: float) -> float:
    """Largest |eigenvalue| of symplectic Euler's step matrix for a mode with (w dt)^2 = z:
    x+ = (1 - z) x + dt v, v+ = v - w^2 dt x, so lambda^2 - (2 - z) lambda + 1 = 0 (stable, on the unit
    circle, for z <= 4)."""
    b = 2.0 - z
    disc = b * b - 4.0
    if disc <= 0.0:
        return 1.0  # complex pair on the unit circle: stable
    return (abs(b) + math.sqrt(disc)) / 2.0


def backward_euler_damping_rate(w: float, dt: float) -> float:
    """Backward Euler on an oscillator whose scheme frequency is w (phase arctan(W dt) = w dt per
    step, W the true frequency): amplitude factor 1/sqrt(1 + (W dt)^2) = cos(w dt) per step, i.e.
    the decay rate -ln(cos(w dt))/dt."""
    return -math.log(math.cos(w * dt)) / dt


# A damped mode q'' = -w^2 q - c q' (stiffness w2 = w^2 and damping c per unit mass, e.g. a proportionally
# damped lattice's Bloch branch, engine.waves.bloch_modes): the maps of the two schemes the lessons damp.

def backward_euler_damped_sequence(w2: float, c: float, dt: float, n: int) -> np.ndarray:
    """q_j / q_0, j = 0..n, of a damped mode started from rest under backward Euler, whose Newton
    system (M + dt C + dt^2 K) v+ = M v - dt K x is, mode by mode, v+ = (v - dt w2 q)/(1 + c dt + w2 dt^2),
    q+ = q + dt v+."""
    q, v, out = 1.0, 0.0, [1.0]
    for _ in range(int(n)):
        v = (v - dt * w2 * q) / (1.0 + c * dt + w2 * dt * dt)
        q = q + dt * v
        out.append(q)
    return np.asarray(out)


def velocity_verlet_damped_rates(w2: float, c: float, dt: float) -> tuple[float, float]:
    """(w, gamma) of a damped mode under the engine's velocity Verlet, which takes the damping force at
    the half-kicked velocity: v* = v + dt/2 a, q+ = q + dt v*, a+ = -w2 q+ - c v*, v+ = v* + dt/2 a+.
    From the step map's complex eigenvalue z: w = |arg z|/dt, gamma = -ln|z|/dt."""
    def step(s):
        q, v, a = s
        vh = v + 0.5 * dt * a
        q1 = q + dt * vh
        a1 = -w2 * q1 - c * vh
        return np.array([q1, vh + 0.5 * dt * a1, a1])
    lam = np.linalg.eigvals(np.column_stack([step(e) for e in np.eye(3)]))
    z = lam[np.argmax(np.abs(lam.imag))]
    return abs(math.atan2(z.imag, z.real)) / dt, -math.log(abs(z)) / dt
