"""Validation of a mesh: :func:`validate` checks a :class:`engine.mesh.core.Mesh` and returns it, or
raises :class:`engine.mesh.core.MeshError` with a one-line message naming the offending element
(pure numpy). Every generator (engine.mesh.generators) validates its output.
"""
from __future__ import annotations

import numpy as np

from engine.mesh.core import TET_EDGES, TRIANGLE_EDGES, Mesh, MeshError, compute_hinges
from engine.mesh.measures import signed_areas_2d, tet_volumes, triangle_areas

__all__ = ["validate"]

# Relative tolerances of validate(): an element is degenerate when its area (volume) is at
# most _DEGENERATE_TOL times its longest edge squared (cubed); two vertices coincide when
# they are closer than _DUPLICATE_TOL times the size of the mesh's bounding box.
_DEGENERATE_TOL = 1e-10
_DUPLICATE_TOL = 1e-12


def _fmt(row) -> str:
    return ", ".join(str(int(v)) for v in row)


def validate(mesh: Mesh, need_hinges: bool = False) -> Mesh:
    """Check a mesh and return it; raise MeshError naming the first offending item.

    Checks, in order: array shapes and dtypes; finite coordinates; exactly one element
    array, non-empty (tets need 3D vertices); indices in 0..n-1; no two vertices at the
    same position (closer than 1e-12 of the bounding box); no degenerate element (area <=
    1e-10 * longest edge^2, volume <= 1e-10 * longest edge^3, zero-length segments); 2D
    triangles counter-clockwise; tets positively oriented; with ``need_hinges``, a triangle
    mesh whose every edge has at most two triangles, consistently oriented.
    """
    V = mesh.vertices
    if V.ndim != 2 or V.shape[1] not in (2, 3) or len(V) == 0:
        raise MeshError(f"vertices must have shape (n, 2) or (n, 3) with n >= 1, got {V.shape}")
    finite = np.isfinite(V).all(axis=1)
    if not finite.all():
        i = int(np.flatnonzero(~finite)[0])
        raise MeshError(f"vertex {i} has non-finite coordinates {V[i].tolist()}")
    present = [k for k in ("triangles", "tets", "segments") if getattr(mesh, k) is not None]
    if len(present) != 1:
        raise MeshError("a mesh needs exactly one of triangles, tets, segments; "
                        f"got {present or 'none'}")
    kind = present[0]
    name, k = {"triangles": ("triangle", 3), "tets": ("tet", 4), "segments": ("segment", 2)}[kind]
    E = mesh.elements
    if E.ndim != 2 or E.shape[1] != k:
        raise MeshError(f"{kind} must have shape (t, {k}), got {E.shape}")
    if E.dtype.kind not in "iu":
        raise MeshError(f"{kind} must hold integer vertex indices, got dtype {E.dtype}")
    if len(E) == 0:
        raise MeshError(f"the mesh has no {kind}")
    if kind == "tets" and V.shape[1] != 3:
        raise MeshError(f"tets need 3D vertices, got shape {V.shape}")
    n = len(V)
    bad = (E < 0) | (E >= n)
    if bad.any():
        t = int(np.flatnonzero(bad.any(axis=1))[0])
        v = int(E[t][bad[t]][0])
        raise MeshError(f"{name} {t} (vertices {_fmt(E[t])}) has index {v} outside the valid "
                        f"range 0..{n - 1}")
    _check_duplicates(V)
    P = V[E]  # (t, k, dim)
    if kind == "segments":
        length = np.linalg.norm(P[:, 1] - P[:, 0], axis=1)
        scale = np.ptp(V, axis=0).max() if n > 1 else 0.0
        zero = length <= _DUPLICATE_TOL * scale
        if zero.any():
            t = int(np.flatnonzero(zero)[0])
            raise MeshError(f"segment {t} (vertices {_fmt(E[t])}) has zero length")
        return mesh
    local = TRIANGLE_EDGES if kind == "triangles" else TET_EDGES
    lmax = np.linalg.norm(P[:, local[:, 1]] - P[:, local[:, 0]], axis=2).max(axis=1)
    if kind == "triangles":
        if V.shape[1] == 2:
            measure = signed_areas_2d(V, E)
        else:
            measure = triangle_areas(V, E)
        small = np.abs(measure) <= _DEGENERATE_TOL * lmax ** 2
        if small.any():
            t = int(np.flatnonzero(small)[0])
            what = "zero area" if measure[t] == 0 else \
                f"near-zero area ({abs(measure[t]):.3g} m^2, longest edge {lmax[t]:.3g} m)"
            raise MeshError(f"triangle {t} (vertices {_fmt(E[t])}) has {what}")
        neg = measure < 0
        if neg.any():
            t = int(np.flatnonzero(neg)[0])
            raise MeshError(f"triangle {t} (vertices {_fmt(E[t])}) is inverted (clockwise, "
                            f"signed area {measure[t]:.3g} m^2); 2D triangles must be "
                            "counter-clockwise")
        if need_hinges:
            compute_hinges(mesh)
        return mesh
    vol = tet_volumes(V, E)
    flat = np.abs(vol) <= _DEGENERATE_TOL * lmax ** 3
    if flat.any():
        t = int(np.flatnonzero(flat)[0])
        raise MeshError(f"tet {t} (vertices {_fmt(E[t])}) is flat (volume {vol[t]:.3g} m^3, "
                        f"longest edge {lmax[t]:.3g} m)")
    neg = vol < 0
    if neg.any():
        t = int(np.flatnonzero(neg)[0])
        raise MeshError(f"tet {t} (vertices {_fmt(E[t])}) is inverted (signed volume "
                        f"{vol[t]:.3g} m^3); tets must be positively oriented")
    if need_hinges:
        raise MeshError(f"hinges need a triangle mesh, got {kind}")
    return mesh


def _check_duplicates(V: np.ndarray):
    if len(V) < 2:
        return
    lo = V.min(axis=0)
    scale = float(np.ptp(V, axis=0).max())
    if scale == 0.0:
        raise MeshError("vertices 0 and 1 are at the same position "
                        f"{V[0].tolist()}")
    Q = np.round((V - lo) / (_DUPLICATE_TOL * scale)).astype(np.int64)
    order = np.lexsort(Q.T[::-1])
    Qs = Q[order]
    same = np.flatnonzero((Qs[1:] == Qs[:-1]).all(axis=1))
    if len(same):
        i, j = sorted((int(order[same[0]]), int(order[same[0] + 1])))
        raise MeshError(f"vertices {i} and {j} are at the same position {V[i].tolist()}")
