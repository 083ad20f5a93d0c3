"""The explicit time-step limit (CFL), in one place.

Linearising about a state, each mode oscillates with w^2 an eigenvalue of M^-1 H (H the Hessian of
the potential, M the lumped masses, pinned vertices removed). Symplectic Euler and velocity Verlet
are stable iff w_max dt <= 2 (lecture notes, "Courant-Friedrichs-Lewy (CFL) condition"); forward
Euler multiplies each mode's energy by about 1 + w^2 dt^2 per step, so it is unstable at every dt
without damping.

:func:`gershgorin_lambda_max` bounds lambda_max = w_max^2 by Gershgorin's theorem on M^-1 H:

    lambda_max <= max over free vertices i and axes a of (1/m_i) sum_cols |H_(i,a),col|        (C1)

(each energy supplies its row sums; for springs at rest a row gets 2 (c_e/L_e^2) |d_a| |d|_1 from
every incident edge, d the unit edge direction). Every eigenvalue lies in a Gershgorin disc, so
dt = 2/sqrt(bound) is conservative (never above the true limit); for a straight 1D rod it is exact
(dt = h/c). :func:`lambda_max_power` estimates lambda_max by power iteration with Hessian-vector
products (a Rayleigh quotient: a lower bound of lambda_max, hence a dt estimate from above; use it
with a safety factor, :data:`engine.constants.CFL_SAFETY`).
"""

import math

import numpy as np
import taichi as ti

from engine.constants import CFL_SAFETY
from engine.fields import (float_dtype, free_dot, mass_dot, scalar_array, scale_vec3, vec3_array, vec3_ndarray,
                           zero_vec3)


def lambda_max_from_rows(rows: np.ndarray, mass: np.ndarray, free: np.ndarray) -> float:
    """(C1) from Gershgorin row sums ``rows`` ((n,) or (n, d) per dof), lumped masses and the free mask."""
    if not free.any():
        return 0.0
    r = rows[free]
    if r.ndim > 1:
        r = r.max(axis=1)
    return float((r / mass[free]).max())


def dt_from_lambda(lam: float) -> float:
    """2 / sqrt(lambda_max): the largest stable dt of symplectic Euler and velocity Verlet (inf if 0)."""
    return 2.0 / math.sqrt(lam) if lam > 0 else math.inf


def gershgorin_lambda_max(model, x=None) -> float:
    """(C1) for the exact Hessian at x (default: the rest state). Every energy must implement
    gershgorin_row_sums."""
    x = model.X_nd if x is None else x
    rows = np.zeros((model.n, 3))
    for e in model.energies:
        rows += e.gershgorin_row_sums(x)
    return lambda_max_from_rows(rows, model.mass, model.free)


@ti.kernel
def _minv_scale(y: vec3_array, u: vec3_array, inv_mass: scalar_array, scale: float):
    # u = scale M^-1 y on free vertices, 0 on pinned
    for i in range(y.shape[0]):
        u[i] = scale * inv_mass[i] * y[i]


def lambda_max_power(model, x=None, psd: bool = False, iters: int = 500, rtol: float = 1e-8,
                     seed: int = 0) -> float:
    """Largest-magnitude eigenvalue of M^-1 H restricted to free vertices, by power iteration
    with Hessian-vector products: u <- M^-1 H u, lambda = (u.H u)/(u.M u) (Rayleigh quotient of
    the symmetric pencil (H, M)).  x defaults to the rest state."""
    x = model.X_nd if x is None else x
    if not model.free.any():
        return 0.0
    u, y = vec3_ndarray(model.n), vec3_ndarray(model.n)  # this estimate's own work arrays
    rng = np.random.default_rng(seed)
    u0 = rng.standard_normal((model.n, 3))
    u0[model.pinned] = 0.0
    u.from_numpy(u0.astype(float_dtype()))
    scale_vec3(u, 1.0 / math.sqrt(mass_dot(u, u, model.mass_nd, model.inv_mass_nd)))
    lam_old = math.inf
    lam = 0.0
    for _ in range(int(iters)):
        zero_vec3(y)
        model.add_hessian_product(x, u, y, psd)
        lam = free_dot(u, y, model.inv_mass_nd, False)  # u.H u with u.M u = 1
        _minv_scale(y, u, model.inv_mass_nd, 1.0)
        norm2 = mass_dot(u, u, model.mass_nd, model.inv_mass_nd)
        if norm2 == 0.0:
            return 0.0
        scale_vec3(u, 1.0 / math.sqrt(norm2))
        if abs(lam - lam_old) <= rtol * abs(lam):
            break
        lam_old = lam
    return float(lam)


def stable_dt_estimate(model, method: str = "gershgorin", x=None) -> float:
    """Largest stable dt for symplectic Euler / velocity Verlet: 2 / sqrt(lambda_max(M^-1 H)).

    method="gershgorin" (default): conservative bound (C1) at the rest state (or x); an energy
    without row sums falls back to power iteration only when asked (``method="power"``).
    method="power": power-iteration estimate (close to the true limit, not conservative).
    Returns inf when nothing is stiff."""
    if method not in ("gershgorin", "power"):
        raise ValueError(f"method must be 'gershgorin' or 'power' (got {method!r})")
    lam = gershgorin_lambda_max(model, x) if method == "gershgorin" else abs(lambda_max_power(model, x))
    return dt_from_lambda(lam)


def best_stable_dt(model) -> float:
    """The Gershgorin limit, or the power-iteration one for models with an energy that has no
    Gershgorin row sums."""
    try:
        return stable_dt_estimate(model)
    except NotImplementedError:
        return stable_dt_estimate(model, method="power")


def substeps_for(dt: float, dt_stable: float, safety: float = CFL_SAFETY) -> int:
    """Sub-steps per step that keep an explicit integrator at or below ``safety`` x its stable dt."""
    if not (math.isfinite(dt_stable) and dt_stable > 0) or dt <= safety * dt_stable:
        return 1
    return int(math.ceil(dt / (safety * dt_stable)))
