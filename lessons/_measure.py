"""Measurement helpers shared by the lessons and their tests.

Finite differences (against which the engine's gradients are checked), random rigid motions,
peak tracking and the schemes' own modal predictions (against which a damped run is judged),
damped-frequency fits, and strains (for colouring and scale). numpy only; nothing here steps a
simulation or writes to the recording.
"""
from __future__ import annotations


import numpy as np

from engine.analysis import peak

from ._framework import Experiment

# ---------------------------------------------------------------------- finite differences


def central_difference(fun, x: np.ndarray, direction: np.ndarray, eps: float = 1e-6) -> float:
    """The directional derivative of ``fun`` at ``x`` along ``direction`` by central differences:
    (fun(x + eps d) - fun(x - eps d)) / (2 eps)."""
    return (fun(x + eps * direction) - fun(x - eps * direction)) / (2 * eps)


def central_gradient(fun, x: np.ndarray, eps: float = 1e-6, at=None) -> np.ndarray:
    """d fun / d x by central differences, one coordinate at a time (shaped like ``x``), or only
    at the flat coordinate indices ``at`` (a 1-D array, in that order)."""
    x = np.asarray(x)
    flat = range(x.size) if at is None else at
    out = np.empty(x.size if at is None else len(at))
    for k, i in enumerate(flat):
        xp, xm = x.copy(), x.copy()
        xp.reshape(-1)[i] += eps
        xm.reshape(-1)[i] -= eps
        out[k] = (fun(xp) - fun(xm)) / (2 * eps)
    return out.reshape(x.shape) if at is None else out


def per_hinge_fd(fun, X, eps=1e-6) -> np.ndarray:
    """Central differences of a per-hinge scalar for unconnected hinges (vertices 4i..4i+3 belong
    to hinge i, so one coordinate of every hinge can be perturbed at once): (m, 4, 3)."""
    m = len(X) // 4
    out = np.zeros((m, 4, 3))
    for a in range(4):
        for c in range(3):
            Xp, Xm = X.copy(), X.copy()
            Xp[a::4, c] += eps
            Xm[a::4, c] -= eps
            out[:, a, c] = (fun(Xp) - fun(Xm)) / (2 * eps)
    return out


# ------------------------------------------------------------------------- rigid motions

def random_rotation(rng, negate_all: bool = False) -> np.ndarray:
    """A random proper rotation: Q of the QR decomposition of a Gaussian 3x3 matrix, its column
    signs fixed by R's diagonal. If det Q = -1, Q is made proper by negating its first column,
    or with ``negate_all`` the whole matrix (the springs lesson's choice, kept so that its
    rigid-motion measurements stay bitwise what they were)."""
    q, r = np.linalg.qr(rng.standard_normal((3, 3)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        if negate_all:
            return -q
        q[:, 0] = -q[:, 0]
    return q


# --------------------------------------------------------------- waves: peaks and modes

def track_peaks(p: np.ndarray, regions):
    """(tracks, observe): ``observe(step, t, u)`` appends (t, position, value) of the peak of
    sign*u in each (lo, hi, sign) region of the node positions ``p`` (lo and hi may be functions
    of t) to that region's track."""
    tracks = [[] for _ in regions]

    def observe(step, t, u):
        for track, (lo, hi, sign) in zip(tracks, regions):
            lo_, hi_ = (lo(t), hi(t)) if callable(lo) else (lo, hi)
            track.append((t, *peak(p, u, lo_, hi_, sign)))
    return tracks, observe


def observation_steps(n_steps: int, every: int) -> list[int]:
    """The steps at which a chunked run observes: 0, every, 2 every, ..., n_steps."""
    return list(range(0, n_steps, every)) + [n_steps]


def modal_tracks(rod, u0, v0, dt: float, method: str, steps: list[int], regions=()):
    """What ``method`` itself predicts for a linear 1D rod (:class:`engine.theory.schemes.ModalReference`:
    each normal mode advanced with the scheme's exact 2x2 step matrix), measured like a run:
    the peaks of ``regions`` tracked at ``steps``. Returns (tracks, displacement at the last step)."""
    from engine.theory.schemes import ModalReference

    U = ModalReference(rod, u0, v0, dt, method).displacements(steps)
    tracks, observe = track_peaks(rod.p, regions)
    if regions:
        for s, u in zip(steps, U):
            observe(s, s * dt, u)
    return tracks, U[-1]


def expect(ctx, method: str, claim: str, undamped: float, measured: float, predicted, tol: float,
           compare: str = "rel", unit: str = "", *, id: str) -> Experiment:
    """A scene experiment: against the undamped theory when ``predicted`` is None (a symplectic
    method), else against the scheme's own prediction, the claim then naming the undamped value
    (the id is the same either way)."""
    if predicted is None:
        return Experiment(claim, undamped, measured, tol, compare, unit, id=id)
    ratio = f", ratio {predicted / undamped:.4f}" if undamped else ""
    ctx.progress(f"{claim}: {method} predicts {predicted:.6g} (undamped theory {undamped:.6g}{ratio}); "
                 f"measured {measured:.6g}")
    return Experiment(f"{claim}: {method}'s modal prediction (undamped theory {undamped:.4g})",
                      predicted, measured, tol, compare, unit, id=id)


# ------------------------------------------------------------------ damped oscillations

def damped_frequency(t: np.ndarray, a: np.ndarray) -> tuple[float, float]:
    """(w, gamma) of a(t) = a(0) exp(-gamma t) cos(w t), least squares over all samples (a run
    from rest stepped by backward Euler has exactly this form for each normal mode)."""
    from scipy.optimize import least_squares

    from engine.waves import phase_frequency

    r = a / a[0]
    w0 = phase_frequency(t, a)  # a start, biased by the decay

    def resid(p):
        return np.exp(-p[1] * t) * np.cos(p[0] * t) - r

    sol = least_squares(resid, [w0, 0.0], x_scale=[w0, w0], xtol=1e-14, ftol=1e-14, gtol=1e-14)
    return float(sol.x[0]), float(sol.x[1])


# ---------------------------------------------------------------------------- strains

def edge_strain(x: np.ndarray, edges: np.ndarray, rest_lengths: np.ndarray) -> np.ndarray:
    """(l/L - 1) per edge."""
    return np.linalg.norm(x[edges[:, 1]] - x[edges[:, 0]], axis=1) / rest_lengths - 1.0


def vertex_strain(n: int, edges: np.ndarray, strain: np.ndarray) -> np.ndarray:
    """Mean strain of the edges around each vertex, for vertex colours."""
    acc = np.bincount(edges.ravel(), weights=np.repeat(strain, 2), minlength=n)
    cnt = np.bincount(edges.ravel(), minlength=n)
    return acc / np.maximum(cnt, 1)


def rod_node_strain(x: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Strain dx/dp - 1 of a 1D chain at its nodes (ends: their segment; inside: the mean of the
    two segments), for colouring a rod."""
    s = np.diff(x) / np.diff(p) - 1.0
    return np.concatenate([[s[0]], 0.5 * (s[1:] + s[:-1]), [s[-1]]])


def middle_strains(X: np.ndarray, u: np.ndarray, x0: float, x1: float) -> tuple:
    """(eps_xx, eps_yy) fitted from the displacements ``u`` of the middle fifth of a strip reaching
    from x0 to x1 along x, where a strip pulled by its clamped ends is in uniaxial stress."""
    mid = np.abs(X[:, 0] - 0.5 * (x0 + x1)) <= 0.1 * (x1 - x0)
    A = np.stack([np.ones(mid.sum()), X[mid, 0], X[mid, 1]], axis=1)
    exx = np.linalg.lstsq(A, u[mid, 0], rcond=None)[0][1]
    eyy = np.linalg.lstsq(A, u[mid, 1], rcond=None)[0][2]
    return exx, eyy


def stretch_strip(m3, build, strain: float, end_width: float, tol: float) -> dict:
    """A static stretch test: clamp a strip's ends (the vertices within ``end_width`` of its smallest
    and largest x), pull them apart by ``strain``, and solve the statics of ``build(m3, pinned)`` to
    the residual ``tol``. Returns the solve (``res``), the displacements ``u``, the strains fitted in
    the middle fifth (``exx``, ``eyy``), the pull on the right end ``F`` (N) and the strip's ``width``."""
    from engine.statics import solve_static

    X = m3.vertices
    x0, x1 = X[:, 0].min(), X[:, 0].max()
    left, right = X[:, 0] <= x0 + end_width, X[:, 0] >= x1 - end_width
    model = build(m3, np.flatnonzero(left | right))
    start = X.copy()
    start[:, 0] = x0 + (X[:, 0] - x0) * (1 + strain)
    res = solve_static(model, x0=start, tol=tol, max_iter=60, raise_on_failure=False)
    u = res.x - X
    exx, eyy = middle_strains(X, u, x0, x1)
    return dict(res=res, u=u, exx=exx, eyy=eyy, F=res.reactions[right, 0].sum(), width=X[:, 1].max() - X[:, 1].min())
