"""Rest quantities and geometric measures of meshes (pure numpy, SI units; set-up and reference
values, not the hot loop): lengths, areas, volumes, the edge measures A_ij of area-scaled springs,
lumped masses, and per hinge its rest geometry and dihedral angle. They take positions and index
arrays, or a Mesh (engine.mesh.core; its cached properties call these), and work for 2D or 3D
coordinates.

Hinge convention (engine.mesh.core): row [v0, v1, w0, w1]; edge e = x_v1 - x_v0, triangle
t0 = (v0, v1, w0) and t1 = (v1, v0, w1), both in the mesh's orientation; N0 = e x (x_w0 - x_v0),
N1 = (x_w1 - x_v0) x e.

    theta = atan2( e_hat . (N0 x N1), N0 . N1 )   in (-pi, pi]                            (A1)

(atan2 of the unnormalised sine and cosine parts: no acos, accurate near 0 and near +-pi);
theta = 0 for a flat hinge, > 0 where the surface is convex on the side its normals point to.

Wing heights over the edge h = 2 A / |e| (A the wing triangle's area); the notes' bending area
A_e = |e| (h0 + h1) / 6 = (A0 + A1) / 3.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from engine.errors import ModelError

if TYPE_CHECKING:
    from engine.mesh.core import Mesh

__all__ = ["as_points3", "rest_lengths", "triangle_areas", "signed_areas_2d", "tet_volumes", "total_measure",
           "edge_measure", "lumped_masses", "hinge_geometry", "hinge_heights", "dihedral_angles"]


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


def _cross_norm(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """|u x v| for rows of 2D or 3D vectors."""
    if u.shape[-1] == 2:
        return np.abs(u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0])
    return np.linalg.norm(np.cross(u, v), axis=-1)


def rest_lengths(X, edges) -> np.ndarray:
    """(m,) lengths |X[j] - X[i]| (m) of the edges (m, 2)."""
    X = np.asarray(X, dtype=np.float64)
    E = np.asarray(edges)
    return np.linalg.norm(X[E[:, 1]] - X[E[:, 0]], axis=1)


def triangle_areas(X, triangles) -> np.ndarray:
    """(t,) unsigned areas (m^2) 1/2 |(x1-x0) x (x2-x0)|, for 2D or 3D coordinates."""
    X = np.asarray(X, dtype=np.float64)
    T = np.asarray(triangles)
    x0 = X[T[:, 0]]
    return 0.5 * _cross_norm(X[T[:, 1]] - x0, X[T[:, 2]] - x0)


def signed_areas_2d(X, triangles) -> np.ndarray:
    """(t,) signed areas (m^2) of 2D triangles, positive when counter-clockwise."""
    X = np.asarray(X, dtype=np.float64)
    T = np.asarray(triangles)
    u = X[T[:, 1]] - X[T[:, 0]]
    v = X[T[:, 2]] - X[T[:, 0]]
    return 0.5 * (u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0])


def tet_volumes(X, tets) -> np.ndarray:
    """(t,) signed volumes (m^3) det(x1-x0, x2-x0, x3-x0)/6; positive = positively
    oriented."""
    X = np.asarray(X, dtype=np.float64)
    T = np.asarray(tets)
    x0 = X[T[:, 0]]
    a, b, c = X[T[:, 1]] - x0, X[T[:, 2]] - x0, X[T[:, 3]] - x0
    return np.einsum("ij,ij->i", a, np.cross(b, c)) / 6.0


def total_measure(mesh: Mesh) -> float:
    """Total area (m^2, triangles), volume (m^3, tets) or length (m, segments)."""
    return mesh.total_measure


def edge_measure(mesh: Mesh) -> np.ndarray:
    """(m,) A_ij per edge of ``edges(mesh)`` (notes, "area-scaled springs"):
    triangles: each triangle adds area/3 to each of its 3 edges (m^2), so an interior edge
    gets (A1 + A2)/3; tets: each tet adds |volume|/6 to each of its 6 edges (m^3);
    segments: the segment's length (m). Sums to the total area / volume / length."""
    share = {"triangles": 3, "tets": 6, "segments": 1}[mesh.kind]
    w = np.abs(mesh.element_measures) / share
    return np.bincount(mesh.element_edges.ravel(), weights=np.repeat(w, share),
                       minlength=len(mesh.edges))


def lumped_masses(mesh: Mesh, rho: float) -> np.ndarray:
    """(n,) lumped vertex masses (kg): rho*area/3 per triangle corner (rho areal density,
    kg/m^2), rho*volume/4 per tet corner (kg/m^3), rho*length/2 per segment end (linear
    density, kg/m). Sums to rho times the total measure; vertices in no element get 0."""
    k = mesh.elements.shape[1]
    w = float(rho) * np.abs(mesh.element_measures) / k
    return np.bincount(mesh.elements.ravel(), weights=np.repeat(w, k),
                       minlength=mesh.n_vertices)


def hinge_heights(X, hinges) -> np.ndarray:
    """(h, 2) heights [h0, h1] (m) of the wing vertices w0, w1 over the line of the hinge
    edge (v0, v1) (columns of ``hinges``), in 2D or 3D (:func:`hinge_geometry`). The
    notes' bending area is A_e = |e| (h0 + h1) / 6."""
    g = hinge_geometry(X, hinges)
    return np.stack([g["h0"], g["h1"]], axis=1)


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
    """(h,) signed dihedral angles theta (rad) at the hinges, (A1), float64: zero when flat; positive
    where the surface is convex on the side its normals point to (e.g. the outward-oriented
    engine.mesh.cylinder_wrap), negative where it is concave. 2D input gives zeros. The numpy
    reference for the kernel (engine.energies.hinge.dihedral_angle) and the rest angles of curved
    rest shapes."""
    X = as_points3(X)
    H = np.asarray(hinges, dtype=np.int64).reshape(-1, 4)
    xv0, xv1, xw0, xw1 = (X[H[:, k]] for k in range(4))
    e = xv1 - xv0
    N0 = np.cross(e, xw0 - xv0)
    N1 = np.cross(xw1 - xv0, e)
    sin_part = np.einsum("ij,ij->i", np.cross(N0, N1), e) / np.linalg.norm(e, axis=1)
    return np.arctan2(sin_part, np.einsum("ij,ij->i", N0, N1))
