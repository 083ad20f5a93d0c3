"""The mesh data structure: :class:`Mesh` and its topology (pure numpy, SI units).

Set-up code, not the hot loop: everything here is vectorised numpy (a 256 x 256 grid is
built, validated and analysed in a fraction of a second) and nothing imports Taichi.
The energies copy the arrays they need into ``ti.ndarray`` buffers.

A :class:`Mesh` holds rest positions ``vertices`` (n, dim) float64 in metres (dim 2 or 3)
and exactly one element array, all int64 vertex indices:

``segments`` (m, 2)   a 1D chain (the rod of the notes' first slides), vertices in 3D;
``triangles`` (t, 3)  a surface; in 2D every triangle is counter-clockwise;
``tets`` (t, 4)       a solid; every tet has positive signed volume
                      det(x1 - x0, x2 - x0, x3 - x0) / 6 > 0.

Topology and rest quantities are functions of the mesh and also cached properties of it
(the arrays are read-only so the caches stay true):

- ``edges``: unique undirected edges (m, 2), i < j, sorted lexicographically.
- ``csr_incidence``: per-vertex lists of incident edges, for a deterministic gather of
  edge forces (a gather sums in a fixed order, so it is reproducible, and on the CPU it is
  faster than parallel float atomics).
- ``hinges``: interior edges of a triangle mesh with their two wing vertices, for the
  dihedral bending energy (notes, "Dihedral angle bending"; Grinspun et al. 2003;
  Bridson et al. 2003). Columns ``[v0, v1, w0, w1]``: the shared edge is (v0, v1) with
  v0 < v1, triangle t0 = (v0, v1, w0) contains the directed edge v0 -> v1 and triangle
  t1 = (v1, v0, w1) contains v1 -> v0, both in the orientation of the mesh's triangles.
  Row k of ``hinges`` is the edge ``edges[hinge_edge_ids[k]]``.
- ``edge_measure`` A_ij: the area (volume) each edge spring stands for, notes' "area-scaled
  springs" W_ij = 1/2 E (l/L - 1)^2 A_ij with A_ij = (A1 + A2)/3: every triangle gives a
  third of its area to each of its 3 edges, every tet a sixth of its volume to each of its
  6 edges, so the measures sum to the total area (volume). For a rod, the segment length
  (the notes' 1D spring W = 1/2 E (l/h - 1)^2 h).
- ``lumped_masses``: rho * area/3 per triangle corner, rho * volume/4 per tet corner,
  rho * length/2 per segment end; they sum to rho times the total measure.
- ``hinge_heights``: heights h0, h1 of the wings over the shared edge, for the notes'
  A_e = |e| (h0 + h1) / 6 (= (A0 + A1)/3).

The rest quantities are computed by engine.mesh.measures; :func:`engine.mesh.validation.validate`
checks a mesh (every generator, engine.mesh.generators, validates its output).

:func:`incidence` is the one CSR builder: entries grouped by the vertex they belong to, in a
fixed order inside each group, so that every per-vertex gather sums in a deterministic order.
"""
from __future__ import annotations

import dataclasses
import functools
from typing import NamedTuple

import numpy as np

from engine.mesh.measures import edge_measure, hinge_heights, rest_lengths, tet_volumes, triangle_areas

__all__ = [
    "MeshError", "Mesh", "Incidence",
    "edges", "element_edges", "csr_incidence", "incidence", "edge_incidence", "hinges", "boundary_vertices",
    "boundary_edges", "tet_faces", "boundary_faces",
    "TRIANGLE_EDGES", "TET_EDGES", "TET_FACES",
]


class MeshError(ValueError):
    """A malformed mesh or a bad generator parameter; the message is one line and names the
    offending element (triangle/tet/vertex/edge index and its vertices) or parameter."""


# Local edge numbering of an element: element_edges[t, k] is the edge id of the pair
# (elem[t, a], elem[t, b]) for [a, b] = TRIANGLE_EDGES[k] (or TET_EDGES[k]).
TRIANGLE_EDGES = np.array([[0, 1], [1, 2], [2, 0]])
TET_EDGES = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]])
# Faces of a positively oriented tet, listed so that their normals (x1-x0)x(x2-x0) point
# out of the tet. Face k is opposite local vertex k.
TET_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])


class Incidence(NamedTuple):
    """Per-vertex edge incidence in CSR form (unpacks as ``offsets, edge_ids, others``).

    The entries of vertex i are ``offsets[i]:offsets[i+1]``, sorted by edge id;
    ``edge_ids[k]`` is an incident edge and ``others[k]`` its other endpoint.
    """

    offsets: np.ndarray  # (n+1,) int64
    edge_ids: np.ndarray  # (2m,) int64
    others: np.ndarray  # (2m,) int64


def _readonly(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


@dataclasses.dataclass(frozen=True, eq=False, repr=False)
class Mesh:
    """Rest geometry and topology. Fields are copied and made read-only on construction.

    vertices:  (n, dim) float64, rest positions in m (dim 2 or 3).
    triangles: (t, 3) int64 vertex indices, or None.
    tets:      (t, 4) int64 vertex indices, or None.
    segments:  (m, 2) int64 vertex indices (1D chain), or None.
    Exactly one element array is given. The constructor does not validate (so that
    :func:`validate` can be shown bad meshes); generators do.
    """

    vertices: np.ndarray
    triangles: np.ndarray | None = None
    tets: np.ndarray | None = None
    segments: np.ndarray | None = None

    def __post_init__(self):
        object.__setattr__(self, "vertices",
                           _readonly(np.array(self.vertices, dtype=np.float64)))
        for name in ("triangles", "tets", "segments"):
            a = getattr(self, name)
            if a is not None:
                a = np.array(a)
                if a.dtype.kind in "iu":
                    a = a.astype(np.int64)
                object.__setattr__(self, name, _readonly(a))

    def __repr__(self):
        e = self.elements
        shape = "?" if e is None else len(e)
        return (f"Mesh({self.kind}: {len(self.vertices)} vertices in {self.dim}D, "
                f"{shape} {self.kind})")

    # --- plain properties -------------------------------------------------------------
    @property
    def kind(self) -> str:
        """'triangles', 'tets' or 'segments' (whichever element array is set)."""
        for name in ("triangles", "tets", "segments"):
            if getattr(self, name) is not None:
                return name
        return "none"

    @property
    def elements(self) -> np.ndarray | None:
        """The element array, whichever kind it is."""
        return {"triangles": self.triangles, "tets": self.tets,
                "segments": self.segments}.get(self.kind)

    @property
    def dim(self) -> int:
        return int(self.vertices.shape[1]) if self.vertices.ndim == 2 else 0

    @property
    def n_vertices(self) -> int:
        return int(len(self.vertices))

    # --- cached topology and rest quantities -----------------------------------------
    @functools.cached_property
    def _edge_data(self):
        return _compute_edges(self)

    @property
    def edges(self) -> np.ndarray:
        """(m, 2) int64 unique undirected edges, i < j, lexicographic order."""
        return self._edge_data[0]

    @property
    def element_edges(self) -> np.ndarray:
        """(t, 3) or (t, 6) edge ids of each element's local edges (TRIANGLE_EDGES/TET_EDGES);
        for segments, (m, 1)."""
        return self._edge_data[1]

    @functools.cached_property
    def incidence(self) -> Incidence:
        return csr_incidence(self.n_vertices, self.edges)

    @functools.cached_property
    def _hinge_data(self):
        return compute_hinges(self)

    @property
    def hinges(self) -> np.ndarray:
        """(h, 4) int64 [v0, v1, w0, w1]; see the module docstring."""
        return self._hinge_data[0]

    @property
    def hinge_triangles(self) -> np.ndarray:
        """(h, 2) int64 triangle ids [t0, t1] of each hinge."""
        return self._hinge_data[1]

    @property
    def hinge_edge_ids(self) -> np.ndarray:
        """(h,) int64: hinge k is the edge edges[hinge_edge_ids[k]]."""
        return self._hinge_data[2]

    @functools.cached_property
    def rest_lengths(self) -> np.ndarray:
        """(m,) rest length of each edge, m."""
        return _readonly(rest_lengths(self.vertices, self.edges))

    @functools.cached_property
    def element_measures(self) -> np.ndarray:
        """(t,) triangle areas (m^2), tet volumes (m^3, positive for a valid mesh) or
        segment lengths (m)."""
        X, e = self.vertices, self.elements
        if self.kind == "triangles":
            return _readonly(triangle_areas(X, e))
        if self.kind == "tets":
            return _readonly(tet_volumes(X, e))
        return _readonly(rest_lengths(X, e))

    @functools.cached_property
    def edge_measure(self) -> np.ndarray:
        """(m,) A_ij per edge; see :func:`edge_measure`."""
        return _readonly(edge_measure(self))

    @functools.cached_property
    def hinge_heights(self) -> np.ndarray:
        """(h, 2) rest heights [h0, h1] of the wings w0, w1 over the hinge edge, m."""
        return _readonly(hinge_heights(self.vertices, self.hinges))

    @functools.cached_property
    def boundary_vertices(self) -> np.ndarray:
        """(n,) bool: vertex lies on the boundary (edge of one triangle, face of one tet,
        end of a chain)."""
        return _readonly(boundary_vertices(self))

    @property
    def total_measure(self) -> float:
        """Total area (m^2), volume (m^3) or length (m)."""
        return float(np.sum(np.abs(self.element_measures)))


# ======================================================================================
# Topology
# ======================================================================================

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


def _pair_keys(a: np.ndarray, b: np.ndarray, n: int) -> np.ndarray:
    lo, hi = np.minimum(a, b).astype(np.int64), np.maximum(a, b).astype(np.int64)
    return lo * max(n, 1) + hi


def _compute_edges(mesh: Mesh):
    n, E = mesh.n_vertices, mesh.elements
    local = {"triangles": TRIANGLE_EDGES, "tets": TET_EDGES,
             "segments": np.array([[0, 1]])}[mesh.kind]
    pairs = E[:, local]  # (t, k, 2)
    key = _pair_keys(pairs[..., 0], pairs[..., 1], n)
    uniq, inv = np.unique(key.ravel(), return_inverse=True)
    edge_arr = np.stack([uniq // max(n, 1), uniq % max(n, 1)], axis=1)
    return _readonly(edge_arr), _readonly(inv.reshape(key.shape).astype(np.int64))


def edges(mesh: Mesh) -> np.ndarray:
    """(m, 2) int64 unique undirected edges of the mesh's elements, i < j, sorted
    lexicographically (deterministic). Same as ``mesh.edges``."""
    return mesh.edges


def element_edges(mesh: Mesh) -> np.ndarray:
    """(t, 3) / (t, 6) edge ids of each triangle's / tet's local edges, in the order of
    TRIANGLE_EDGES / TET_EDGES. Same as ``mesh.element_edges``."""
    return mesh.element_edges


def csr_incidence(n_vertices: int, edges) -> Incidence:
    """Per-vertex edge incidence in CSR form.

    Returns ``Incidence(offsets (n+1,), edge_ids (2m,), others (2m,))``: the edges at
    vertex i are edge_ids[offsets[i]:offsets[i+1]], in increasing edge id, and others[k]
    is the endpoint of edge_ids[k] that is not i. Deterministic; int64.
    """
    E = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    m = len(E)
    if m and (E.min() < 0 or E.max() >= n_vertices):
        bad = int(np.flatnonzero(((E < 0) | (E >= n_vertices)).any(axis=1))[0])
        raise MeshError(f"edge {bad} ({E[bad, 0]}, {E[bad, 1]}) has an index outside the valid "
                        f"range 0..{n_vertices - 1}")
    offsets, eid, other = edge_incidence(n_vertices, E, by="edge")
    return Incidence(_readonly(offsets), _readonly(eid), _readonly(other))


def compute_hinges(mesh: Mesh):
    """(H, tris, edge ids) of a triangle mesh, read-only: what ``mesh.hinges``, ``mesh.hinge_triangles``
    and ``mesh.hinge_edge_ids`` cache (:func:`hinges`); raises MeshError as :func:`hinges` says."""
    if mesh.kind != "triangles":
        raise MeshError(f"hinges need a triangle mesh, got {mesh!r}")
    T, n = mesh.triangles, mesh.n_vertices
    # half-edge k of triangle t: T[t,k] -> T[t,k+1], opposite vertex T[t,k+2]
    src = T.ravel()
    dst = T[:, [1, 2, 0]].ravel()
    opp = T[:, [2, 0, 1]].ravel()
    tid = np.repeat(np.arange(len(T)), 3)
    key = _pair_keys(src, dst, n)
    order = np.argsort(key, kind="stable")
    ks = key[order]
    starts = np.flatnonzero(np.r_[True, ks[1:] != ks[:-1]])
    counts = np.diff(np.r_[starts, len(ks)])
    many = np.flatnonzero(counts > 2)
    if len(many):
        g = many[0]
        hs = order[starts[g]:starts[g] + counts[g]]
        lo, hi = sorted((int(src[hs[0]]), int(dst[hs[0]])))
        raise MeshError(f"edge ({lo}, {hi}) is shared by {counts[g]} triangles "
                        f"({', '.join(str(int(t)) for t in tid[hs])}); a hinge needs exactly "
                        "two (non-manifold edge)")
    pair = starts[counts == 2]
    ha, hb = order[pair], order[pair + 1]
    fwd_a, fwd_b = src[ha] < dst[ha], src[hb] < dst[hb]
    same = np.flatnonzero(fwd_a == fwd_b)
    if len(same):
        k = same[0]
        a, b = ha[k], hb[k]
        raise MeshError(f"triangles {tid[a]} ({', '.join(map(str, T[tid[a]]))}) and {tid[b]} "
                        f"({', '.join(map(str, T[tid[b]]))}) are inconsistently oriented: both "
                        f"contain the directed edge {src[a]} -> {dst[a]}")
    h0 = np.where(fwd_a, ha, hb)
    h1 = np.where(fwd_a, hb, ha)
    H = np.stack([src[h0], dst[h0], opp[h0], opp[h1]], axis=1).astype(np.int64)
    tris = np.stack([tid[h0], tid[h1]], axis=1).astype(np.int64)
    edge_keys = mesh.edges[:, 0] * max(n, 1) + mesh.edges[:, 1]
    eids = np.searchsorted(edge_keys, ks[pair]).astype(np.int64)
    return _readonly(H), _readonly(tris), _readonly(eids)


def hinges(mesh: Mesh) -> tuple[np.ndarray, np.ndarray]:
    """Interior edges of a triangle mesh, for dihedral bending.

    Returns ``(H, tris)``: H (h, 4) int64 with columns [v0, v1, w0, w1], the shared edge
    (v0, v1) with v0 < v1, triangle t0 = (v0, v1, w0) containing the directed edge v0 -> v1
    and t1 = (v1, v0, w1) containing v1 -> v0 (both as oriented in mesh.triangles); tris
    (h, 2) int64 the triangle ids [t0, t1]. Rows follow the order of ``edges(mesh)``
    (``mesh.hinge_edge_ids`` maps them). Boundary edges (one triangle) give no hinge.
    Raises MeshError for an edge of more than two triangles (non-manifold) or two
    neighbours that traverse their shared edge in the same direction (inconsistent
    orientation), naming the edge/triangles.
    """
    return mesh.hinges, mesh.hinge_triangles


def boundary_edges(mesh: Mesh) -> np.ndarray:
    """(b,) ids of the edges of a triangle mesh that belong to exactly one triangle."""
    if mesh.kind != "triangles":
        raise MeshError(f"boundary_edges needs a triangle mesh, got {mesh!r}")
    count = np.bincount(mesh.element_edges.ravel(), minlength=len(mesh.edges))
    return np.flatnonzero(count == 1)


def tet_faces(mesh: Mesh) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Faces of a tet mesh: ``(faces, count, tet_face)``.

    faces (f, 3) int64 unique faces, each as its sorted vertex triple, in lexicographic
    order; count (f,) how many tets share each face (2 inside, 1 on the boundary, more only
    for a broken mesh); tet_face (t, 4) the face id of each tet's local face TET_FACES[k]
    (opposite local vertex k).
    """
    if mesh.kind != "tets":
        raise MeshError(f"tet_faces needs a tet mesh, got {mesh!r}")
    F = np.sort(mesh.tets[:, TET_FACES], axis=2).reshape(-1, 3)
    n = mesh.n_vertices
    if n < 2 ** 21:
        key = (F[:, 0] * n + F[:, 1]) * n + F[:, 2]
        uniq, inv, count = np.unique(key, return_inverse=True, return_counts=True)
        faces = np.stack([uniq // (n * n), (uniq // n) % n, uniq % n], axis=1)
    else:
        faces, inv, count = np.unique(F, axis=0, return_inverse=True, return_counts=True)
    return faces.astype(np.int64), count, inv.reshape(-1, 4).astype(np.int64)


def boundary_faces(mesh: Mesh) -> np.ndarray:
    """(b, 3) int64 boundary triangles of a tet mesh (faces of exactly one tet), oriented
    with outward normals (x1-x0)x(x2-x0); e.g. to draw a solid as a surface."""
    faces, count, tet_face = tet_faces(mesh)
    once = count[tet_face] == 1  # (t, 4)
    return mesh.tets[:, TET_FACES][once].astype(np.int64)


def boundary_vertices(mesh: Mesh) -> np.ndarray:
    """(n,) bool: on an edge of only one triangle, a face of only one tet, or at a chain
    end (a vertex of degree 1). Vertices in no element count as boundary (never moved)."""
    n = mesh.n_vertices
    mask = np.zeros(n, dtype=bool)
    if mesh.kind == "triangles":
        mask[mesh.edges[boundary_edges(mesh)].ravel()] = True
    elif mesh.kind == "tets":
        faces, count, _ = tet_faces(mesh)
        mask[faces[count == 1].ravel()] = True
    else:
        mask[np.bincount(mesh.edges.ravel(), minlength=n) <= 1] = True
    used = np.zeros(n, dtype=bool)
    used[mesh.elements.ravel()] = True
    return mask | ~used
