"""Geometry shared by meshes and energies, in numpy (set-up and reference values, not the hot loop).

Hinge convention (engine/mesh.py): row [v0, v1, w0, w1]; edge e = x_v1 - x_v0, triangle
t0 = (v0, v1, w0) and t1 = (v1, v0, w1), both in the mesh's orientation; N0 = e x (x_w0 - x_v0),
N1 = (x_w1 - x_v0) x e.

    theta = atan2( e_hat . (N0 x N1), N0 . N1 )   in (-pi, pi]                            (A1)

(atan2 of the unnormalised sine and cosine parts: no acos, accurate near 0 and near +-pi);
theta = 0 for a flat hinge, > 0 where the surface is convex on the side its normals point to.

Wing heights over the edge h = 2 A / |e| (A the wing triangle's area); the notes' bending area
A_e = |e| (h0 + h1) / 6 = (A0 + A1) / 3.

:func:`incidence` is the one CSR builder: entries grouped by the vertex they belong to, in a
fixed order inside each group, so that every per-vertex gather sums in a deterministic order.
"""
from __future__ import annotations

import numpy as np

from engine.errors import ModelError


def as_points3(X, error: type = ModelError) -> np.ndarray:
    """(n, 3) float64 positions from numpy or a vec3 ndarray; (n, 2) input is embedded at z = 0."""
    if hasattr(X, "to_numpy") and not isinstance(X, np.ndarray):
        X = X.to_numpy()
    X = np.asarray(X, dtype=np.float64)
    if X.ndim == 2 and X.shape[1] == 2:
        X = np.concatenate([X, np.zeros((len(X), 1))], axis=1)
    if X.ndim != 2 or X.shape[1] != 3:
        raise error(f"rest positions must have shape (n, 3), got {X.shape}")
    return X


def incidence(n: int, owners: np.ndarray, order_key: np.ndarray | None = None):
    """CSR grouping of entries by owner vertex: returns ``(offsets, perm)``, int64, with the entries
    of vertex v at ``perm[offsets[v]:offsets[v + 1]]``, sorted inside each group by ``order_key``
    (ties, and no key, in increasing entry index)."""
    owners = np.asarray(owners, dtype=np.int64).reshape(-1)
    idx = np.arange(owners.size)
    key = idx if order_key is None else np.asarray(order_key).reshape(-1)
    perm = np.lexsort((idx, key, owners))
    offsets = np.zeros(int(n) + 1, dtype=np.int64)
    np.cumsum(np.bincount(owners, minlength=int(n)), out=offsets[1:])
    return offsets, perm


def edge_incidence(n: int, edges: np.ndarray, by: str = "edge"):
    """Vertex -> incident edges: ``(offsets (n+1,), edge ids (2m,), other endpoints (2m,))``, int64,
    ordered inside each vertex by edge id (``by="edge"``) or by the other endpoint (``by="other"``,
    the springs' order: neighbours in memory order)."""
    E = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    m = len(E)
    owner = np.concatenate([E[:, 0], E[:, 1]])
    other = np.concatenate([E[:, 1], E[:, 0]])
    eid = np.concatenate([np.arange(m), np.arange(m)])
    offsets, perm = incidence(n, owner, eid if by == "edge" else other)
    return offsets, eid[perm], other[perm]


def hinge_geometry(X, hinges) -> dict:
    """Rest quantities per hinge (float64): ``edge_length`` |e|, ``h0``, ``h1`` (wing heights over the
    edge), ``A0``, ``A1`` (wing areas), ``A_e`` = |e|(h0+h1)/6."""
    X = as_points3(X)
    H = np.asarray(hinges, dtype=np.int64).reshape(-1, 4)
    xv0, xv1, xw0, xw1 = (X[H[:, k]] for k in range(4))
    e = xv1 - xv0
    L = np.linalg.norm(e, axis=1)
    A0 = 0.5 * np.linalg.norm(np.cross(e, xw0 - xv0), axis=1)
    A1 = 0.5 * np.linalg.norm(np.cross(xv0 - xv1, xw1 - xv1), axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        h0 = 2.0 * A0 / L
        h1 = 2.0 * A1 / L
    return dict(edge_length=L, h0=h0, h1=h1, A0=A0, A1=A1, A_e=L * (h0 + h1) / 6.0)


def dihedral_angles(X, hinges) -> np.ndarray:
    """(A1) per hinge (float64): the reference for the kernel and the rest angles of curved shapes."""
    X = as_points3(X)
    H = np.asarray(hinges, dtype=np.int64).reshape(-1, 4)
    xv0, xv1, xw0, xw1 = (X[H[:, k]] for k in range(4))
    e = xv1 - xv0
    N0 = np.cross(e, xw0 - xv0)
    N1 = np.cross(xw1 - xv0, e)
    sin_part = np.einsum("ij,ij->i", np.cross(N0, N1), e) / np.linalg.norm(e, axis=1)
    return np.arctan2(sin_part, np.einsum("ij,ij->i", N0, N1))
