"""Measurement helpers shared by lessons and tests: pulse peaks, speeds, growth rates.

These run on small numpy copies of the state between kernel launches (analysis, not the
hot loop).
"""
from __future__ import annotations

import numpy as np


def peak(p: np.ndarray, u: np.ndarray, lo: float = -np.inf, hi: float = np.inf,
         sign: int = 0) -> tuple[float, float]:
    """Position and value of the largest |u| (or largest sign*u) with lo <= p <= hi.

    Sub-node accuracy: a parabola through log|u| at the three nodes around the maximum
    (exact for a Gaussian), falling back to a parabola through u itself.
    Returns (position, signed value).
    """
    mask = (p >= lo) & (p <= hi)
    idx = np.flatnonzero(mask)
    if idx.size == 0:
        raise ValueError("peak: empty search region")
    w = u[idx] if sign == 0 else sign * u[idx]
    k = idx[np.argmax(np.abs(w) if sign == 0 else w)]
    if k == 0 or k == len(u) - 1:
        return float(p[k]), float(u[k])
    y = u[k - 1:k + 2]
    x = p[k - 1:k + 2]
    if np.all(np.sign(y) == np.sign(y[1])) and np.all(y != 0):
        z = np.log(np.abs(y))
        s = np.sign(y[1])
        transform = lambda v: s * np.exp(v)
    else:
        z = y
        transform = lambda v: v
    coef = np.polyfit(x - x[1], z, 2)
    if coef[0] >= 0:  # not a maximum of the fitted parabola
        return float(p[k]), float(u[k])
    dx = -coef[1] / (2 * coef[0])
    dx = float(np.clip(dx, x[0] - x[1], x[2] - x[1]))
    return float(x[1] + dx), float(transform(np.polyval(coef, dx)))


def fit_slope(t: np.ndarray, y: np.ndarray) -> float:
    """Least-squares slope dy/dt."""
    t = np.asarray(t, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    return float(np.polyfit(t, y, 1)[0])


def geometric_growth(series: np.ndarray, last: int) -> float:
    """Mean per-step factor of a positive series over its last ``last`` steps."""
    s = np.asarray(series, dtype=np.float64)
    last = min(last, s.size - 1)
    return float((s[-1] / s[-1 - last]) ** (1.0 / last))


def convergence_order(h: np.ndarray, err: np.ndarray) -> float:
    """Least-squares slope of log(err) against log(h)."""
    return fit_slope(np.log(h), np.log(err))
