"""Meshes for the lessons: generators, topology and rest quantities (pure numpy, SI units).

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

:func:`validate` raises :class:`MeshError` with a one-line message naming the offending
element; every generator validates its output.
"""
from __future__ import annotations

import dataclasses
import functools
import math
from typing import NamedTuple

import numpy as np

from engine import geometry

__all__ = [
    "MeshError", "Mesh", "Incidence",
    "rod", "right_triangle_grid", "equilateral_lattice", "tet_box", "jitter", "embed_3d",
    "rotate_2d", "cylinder_wrap", "half_cylinder",
    "edges", "element_edges", "csr_incidence", "hinges", "boundary_vertices",
    "boundary_edges", "tet_faces", "boundary_faces",
    "rest_lengths", "triangle_areas", "signed_areas_2d", "tet_volumes", "total_measure",
    "edge_measure", "lumped_masses", "hinge_heights", "dihedral_angles", "validate",
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

# Relative tolerances of validate(): an element is degenerate when its area (volume) is at
# most _DEGENERATE_TOL times its longest edge squared (cubed); two vertices coincide when
# they are closer than _DUPLICATE_TOL times the size of the mesh's bounding box.
_DEGENERATE_TOL = 1e-10
_DUPLICATE_TOL = 1e-12


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
        return _compute_hinges(self)

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
# Generators
# ======================================================================================

def _check_count(name: str, value, minimum: int = 2) -> int:
    if int(value) != value or value < minimum:
        raise MeshError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def _check_positive(name: str, value) -> float:
    value = float(value)
    if not (math.isfinite(value) and value > 0):
        raise MeshError(f"{name} must be a finite length > 0 m, got {value!r}")
    return value


def rod(n_nodes: int, length: float = 1.0) -> Mesh:
    """A 1D chain of ``n_nodes`` evenly spaced nodes on the x axis, from x = 0 to x =
    ``length`` (m), as a 3D polyline: vertices (n, 3), segments (n-1, 2) = (i, i+1)."""
    n = _check_count("n_nodes", n_nodes)
    length = _check_positive("length", length)
    X = np.zeros((n, 3))
    X[:, 0] = np.linspace(0.0, length, n)
    i = np.arange(n - 1)
    mesh = Mesh(X, segments=np.stack([i, i + 1], axis=1))
    validate(mesh)
    return mesh


_DIAGONALS = ("one-way", "alternating", "crossed")


def right_triangle_grid(nx: int, ny: int, width: float = 1.0, height: float = 1.0,
                        diagonals: str = "one-way") -> Mesh:
    """A rectangle [0, width] x [0, height] (m) in 2D, triangulated on an nx x ny grid.

    Grid vertex (i, j), 0 <= i < nx, 0 <= j < ny, sits at (i*width/(nx-1), j*height/(ny-1))
    and has index i + nx*j. Each of the (nx-1)(ny-1) cells with corners a=(i,j), b=(i+1,j),
    c=(i+1,j+1), d=(i,j+1) is split by ``diagonals``:

    "one-way":     2 right triangles (a, b, c), (a, c, d); every diagonal runs a -> c.
    "alternating": as "one-way" where i + j is even, else (a, b, d), (b, c, d): the
                   diagonal direction flips in a checkerboard.
    "crossed":     4 triangles (a,b,e), (b,c,e), (c,d,e), (d,a,e) around an added vertex e
                   at the cell centre, so the mesh has nx*ny + (nx-1)(ny-1) vertices; the
                   centre of cell (i, j) has index nx*ny + i + (nx-1)*j.

    All triangles are counter-clockwise. Counts: one-way/alternating have 2C triangles and
    (nx-1)ny + nx(ny-1) + C edges, crossed has 4C triangles and (nx-1)ny + nx(ny-1) + 4C
    edges, with C = (nx-1)(ny-1).
    """
    nx, ny = _check_count("nx", nx), _check_count("ny", ny)
    width, height = _check_positive("width", width), _check_positive("height", height)
    if diagonals not in _DIAGONALS:
        raise MeshError(f"diagonals must be one of {', '.join(_DIAGONALS)}, got {diagonals!r}")
    x = np.linspace(0.0, width, nx)
    y = np.linspace(0.0, height, ny)
    gx, gy = np.meshgrid(x, y)  # (ny, nx): index i + nx*j after ravel
    X = np.stack([gx.ravel(), gy.ravel()], axis=1)
    ci, cj = np.meshgrid(np.arange(nx - 1), np.arange(ny - 1))
    ci, cj = ci.ravel(), cj.ravel()
    a = ci + nx * cj
    b, c, d = a + 1, a + 1 + nx, a + nx
    if diagonals == "crossed":
        e = nx * ny + np.arange(len(a))
        centres = np.stack([(x[ci] + x[ci + 1]) / 2, (y[cj] + y[cj + 1]) / 2], axis=1)
        X = np.concatenate([X, centres])
        T = np.stack([np.stack(t, axis=1) for t in
                      ((a, b, e), (b, c, e), (c, d, e), (d, a, e))], axis=1).reshape(-1, 3)
    else:
        t0 = np.stack([a, b, c], axis=1)
        t1 = np.stack([a, c, d], axis=1)
        if diagonals == "alternating":
            odd = (ci + cj) % 2 == 1
            t0[odd] = np.stack([a, b, d], axis=1)[odd]
            t1[odd] = np.stack([b, c, d], axis=1)[odd]
        T = np.stack([t0, t1], axis=1).reshape(-1, 3)
    mesh = Mesh(X, triangles=T)
    validate(mesh, need_hinges=True)
    return mesh


def equilateral_lattice(nx: int, ny: int, spacing: float = 1.0) -> Mesh:
    """A 2D lattice of equilateral triangles with edge ``spacing`` (m).

    ny rows of nx vertices; vertex (i, j) has index i + nx*j and sits at
    (i*spacing + (j % 2)*spacing/2, j*spacing*sqrt(3)/2): odd rows are offset by half a
    spacing. Between two rows there are 2(nx-1) triangles, 2(nx-1)(ny-1) in all, all
    counter-clockwise and equilateral; the outline is a rectangle with zig-zag left and
    right sides. Every edge has length ``spacing``.
    """
    nx, ny = _check_count("nx", nx), _check_count("ny", ny)
    spacing = _check_positive("spacing", spacing)
    gi, gj = np.meshgrid(np.arange(nx), np.arange(ny))
    gi, gj = gi.ravel(), gj.ravel()
    X = np.stack([(gi + 0.5 * (gj % 2)) * spacing, gj * spacing * math.sqrt(3) / 2], axis=1)
    ci, cj = np.meshgrid(np.arange(nx - 1), np.arange(ny - 1))
    ci, cj = ci.ravel(), cj.ravel()
    p = ci + nx * cj  # (i, j)
    q, r, s = p + 1, p + nx, p + nx + 1  # (i+1, j), (i, j+1), (i+1, j+1)
    even = (cj % 2 == 0)[:, None]
    # even row j: row j+1 is shifted right; odd row j: row j is shifted right.
    t0 = np.where(even, np.stack([p, q, r], 1), np.stack([p, s, r], 1))
    t1 = np.where(even, np.stack([r, q, s], 1), np.stack([p, q, s], 1))
    T = np.stack([t0, t1], axis=1).reshape(-1, 3)
    mesh = Mesh(X, triangles=T)
    validate(mesh, need_hinges=True)
    return mesh


def tet_box(nx: int, ny: int, nz: int, size=1.0, origin=(0.0, 0.0, 0.0)) -> Mesh:
    """A box of nx x ny x nz grid vertices filled with tetrahedra.

    ``size`` is the box's extent in m, a scalar (a cube) or (sx, sy, sz); the box spans
    origin + [0, sx] x [0, sy] x [0, sz] and each of the (nx-1)(ny-1)(nz-1) cells (a cube
    when the spacings agree) is split into 6 tets by the Kuhn (Freudenthal) split along its
    main diagonal from corner (0,0,0) to (1,1,1): one tet per path 000 -> e_a -> e_a+e_b ->
    111 through the cube's corners. Every cell uses the same split, so each cell face is cut
    by the same diagonal from both sides and the mesh is conforming.

    Grid vertex (i, j, k) has index i + nx*(j + ny*k). All tets have positive signed volume.
    Counts: 6C tets and, with cells (cx, cy, cz) = (nx-1, ny-1, nz-1), C = cx*cy*cz edges
    cx*ny*nz + nx*cy*nz + nx*ny*cz (grid lines) + cx*cy*nz + cx*ny*cz + nx*cy*cz (face
    diagonals) + C (body diagonals).
    """
    nx, ny, nz = (_check_count(n, v) for n, v in (("nx", nx), ("ny", ny), ("nz", nz)))
    sizes = np.broadcast_to(np.asarray(size, dtype=np.float64), (3,))
    for name, s in zip(("size x", "size y", "size z"), sizes):
        _check_positive(name, s)
    origin = np.asarray(origin, dtype=np.float64).reshape(3)
    axes = [np.linspace(0.0, s, n) for s, n in zip(sizes, (nx, ny, nz))]
    gz, gy, gx = np.meshgrid(axes[2], axes[1], axes[0], indexing="ij")  # index i + nx(j + ny k)
    X = np.stack([gx.ravel(), gy.ravel(), gz.ravel()], axis=1) + origin
    ck, cj, ci = np.meshgrid(np.arange(nz - 1), np.arange(ny - 1), np.arange(nx - 1),
                             indexing="ij")
    base = (ci + nx * (cj + ny * ck)).ravel()
    stride = np.array([1, nx, nx * ny])
    tets = []
    for perm in ((0, 1, 2), (1, 2, 0), (2, 0, 1), (0, 2, 1), (2, 1, 0), (1, 0, 2)):
        c1 = stride[perm[0]]
        c2 = c1 + stride[perm[1]]
        c3 = stride.sum()
        # signed volume of (000, e_a, e_a+e_b, 111) is the sign of the permutation
        even = perm in ((0, 1, 2), (1, 2, 0), (2, 0, 1))
        cols = (base, base + c1, base + c2, base + c3) if even else \
            (base, base + c1, base + c3, base + c2)
        tets.append(np.stack(cols, axis=1))
    T = np.stack(tets, axis=1).reshape(-1, 4)
    mesh = Mesh(X, tets=T)
    validate(mesh)
    return mesh


def jitter(mesh: Mesh, amplitude: float, seed: int) -> Mesh:
    """Perturb interior vertices of a 2D triangle mesh or a tet mesh at random.

    Each interior vertex moves by an offset drawn uniformly from the disc (ball) of radius
    ``amplitude`` (dimensionless, e.g. 0.25) times its local length: the shortest incident
    rest edge, capped at twice the smallest width of the incident elements (the width of a
    triangle is its smallest altitude; of a tet, the smaller of its smallest altitude and
    its shortest distance between opposite edges). The cap changes nothing for the
    generators' meshes with roughly square cells and only bites on stretched elements.
    Boundary vertices stay put, so the outline is unchanged. The draw uses
    ``numpy.random.default_rng(seed)``, one offset per vertex (boundary ones discarded), so
    a given (mesh, amplitude, seed) always gives the same result.

    amplitude <= 0.25 cannot invert or flatten any element: every vertex of an element of
    width w then moves less than w/2, and for the element to pass through a flat state all
    its vertices would have to come within w/2 of a common line (plane), i.e. the element
    would fit in a strip (slab) narrower than its width. The result is validated anyway;
    for a larger amplitude an inverted or degenerate element raises MeshError naming it.
    """
    amplitude = float(amplitude)
    if not (math.isfinite(amplitude) and amplitude >= 0):
        raise MeshError(f"amplitude must be a finite number >= 0, got {amplitude!r}")
    if mesh.kind == "segments" or (mesh.kind == "triangles" and mesh.dim != 2):
        raise MeshError(f"jitter needs a 2D triangle mesh or a tet mesh, got {mesh!r}; "
                        "jitter before embed_3d/cylinder_wrap")
    E = mesh.edges
    lengths = mesh.rest_lengths
    local = np.full(mesh.n_vertices, np.inf)
    np.minimum.at(local, E[:, 0], lengths)
    np.minimum.at(local, E[:, 1], lengths)
    width = _element_widths(mesh)
    k = mesh.elements.shape[1]
    np.minimum.at(local, mesh.elements.ravel(), np.repeat(2.0 * width, k))
    rng = np.random.default_rng(seed)
    n, dim = mesh.vertices.shape
    direction = rng.standard_normal((n, dim))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    radius = amplitude * np.where(np.isfinite(local), local, 0.0) * rng.random(n) ** (1 / dim)
    radius[mesh.boundary_vertices] = 0.0
    X = mesh.vertices + direction * radius[:, None]
    out = dataclasses.replace(mesh, vertices=X)
    try:
        validate(out, need_hinges=mesh.kind == "triangles")
    except MeshError as err:
        raise MeshError(f"jitter(amplitude={amplitude}, seed={seed}) gives a bad mesh: "
                        f"{err}") from None
    return out


_PLANES = {"xy": (0, 1), "xz": (0, 2), "yz": (1, 2)}


def embed_3d(mesh2d: Mesh, plane: str = "xy", origin=(0.0, 0.0, 0.0)) -> Mesh:
    """Place a 2D triangle mesh in 3D (for cloth): (x, y) -> origin + (x, y, 0) for "xy",
    origin + (x, 0, y) for "xz" (a hanging curtain with z up), origin + (0, x, y) for "yz".
    Coordinates in m. Triangle orientation is kept; counter-clockwise 2D triangles get
    normals +z ("xy"), -y ("xz") or +x ("yz")."""
    _need_2d_triangles(mesh2d, "embed_3d")
    if plane not in _PLANES:
        raise MeshError(f"plane must be one of {', '.join(_PLANES)}, got {plane!r}")
    X = np.zeros((mesh2d.n_vertices, 3))
    X[:, list(_PLANES[plane])] = mesh2d.vertices
    X += np.asarray(origin, dtype=np.float64).reshape(3)
    out = Mesh(X, triangles=mesh2d.triangles)
    validate(out, need_hinges=True)
    return out


def rotate_2d(mesh: Mesh, angle: float, center=(0.0, 0.0)) -> Mesh:
    """Rotate a 2D triangle mesh counter-clockwise by ``angle`` (radians) about ``center``
    (m). Used to measure orientation dependence of a grid pattern; topology unchanged."""
    _need_2d_triangles(mesh, "rotate_2d")
    c, s = math.cos(angle), math.sin(angle)
    R = np.array([[c, -s], [s, c]])
    center = np.asarray(center, dtype=np.float64).reshape(2)
    out = Mesh((mesh.vertices - center) @ R.T + center, triangles=mesh.triangles)
    validate(out, need_hinges=True)
    return out


def cylinder_wrap(mesh2d: Mesh, radius: float, axis: str = "y") -> Mesh:
    """Roll a flat 2D triangle mesh onto a cylinder of radius ``radius`` (m) whose axis is
    the 3D y axis (``axis="y"``) or x axis (``axis="x"``).

    axis "y": (x, y) -> (R sin(x/R), y, R cos(x/R)); the arc length x becomes the angle
    x/R, so lengths along the axis are kept exactly and an edge spanning dx around the
    cylinder becomes the chord 2R sin(dx/(2R)). axis "x": (x, y) -> (x, R sin(y/R),
    R cos(y/R)). Every vertex ends at distance R from the axis, the line x = 0 (y = 0)
    lands on z = R, and counter-clockwise triangles get outward normals. The angular extent
    must stay below 2 pi (no seam is closed).
    """
    _need_2d_triangles(mesh2d, "cylinder_wrap")
    R = _check_positive("radius", radius)
    if axis not in ("x", "y"):
        raise MeshError(f"axis must be 'x' or 'y', got {axis!r}")
    around, along = (0, 1) if axis == "y" else (1, 0)
    u = mesh2d.vertices[:, around]
    extent = (u.max() - u.min()) / R
    if extent >= 2 * math.pi * (1 - 1e-12):
        raise MeshError(f"cylinder_wrap: the mesh spans {extent:.6g} rad around a cylinder of "
                        f"radius {R} m; it must span less than 2 pi")
    X = np.empty((mesh2d.n_vertices, 3))
    X[:, 0 if axis == "y" else 1] = R * np.sin(u / R)
    X[:, 1 if axis == "y" else 0] = mesh2d.vertices[:, along]
    X[:, 2] = R * np.cos(u / R)
    out = Mesh(X, triangles=mesh2d.triangles)
    validate(out, need_hinges=True)
    return out


def half_cylinder(n_around: int, n_along: int, radius: float = 1.0, length: float = 1.0,
                  diagonals: str = "one-way", axis: str = "y") -> Mesh:
    """A half cylinder (an arch) of radius ``radius`` and length ``length`` (m): a
    right-triangle grid of width pi*R (n_around vertices) by ``length`` (n_along vertices),
    centred on x = 0 (y = 0 for axis "x") and rolled by :func:`cylinder_wrap`. The angle runs
    from -pi/2 to pi/2, so the arch rises from z = 0 to its crest at z = R."""
    R = _check_positive("radius", radius)
    w = math.pi * R
    if axis == "y":
        flat = right_triangle_grid(n_around, n_along, w, length, diagonals)
        shift = np.array([w / 2, 0.0])
    else:
        flat = right_triangle_grid(n_along, n_around, length, w, diagonals)
        shift = np.array([0.0, w / 2])
    flat = Mesh(flat.vertices - shift, triangles=flat.triangles)
    return cylinder_wrap(flat, R, axis)


def _element_widths(mesh: Mesh) -> np.ndarray:
    """(t,) minimal width (m) of each triangle (smallest altitude, 2A / longest edge) or tet
    (min of the vertex-face distances 3V / face area and the opposite-edge distances
    6V / |e1 x e2|, which together attain the width of a tetrahedron)."""
    X, T = mesh.vertices, mesh.elements
    if mesh.kind == "triangles":
        P = X[T]
        longest = np.linalg.norm(P[:, TRIANGLE_EDGES[:, 1]] - P[:, TRIANGLE_EDGES[:, 0]],
                                 axis=2).max(axis=1)
        return 2.0 * triangle_areas(X, T) / longest
    vol6 = np.abs(tet_volumes(X, T)) * 6.0
    face_area = np.stack([triangle_areas(X, T[:, f]) for f in TET_FACES], axis=1)
    d = X[T]
    cross = [np.linalg.norm(np.cross(d[:, b] - d[:, a], d[:, q] - d[:, p]), axis=1)
             for (a, b), (p, q) in (((0, 1), (2, 3)), ((0, 2), (1, 3)), ((0, 3), (1, 2)))]
    return np.minimum(vol6 / 2.0 / face_area.max(axis=1),
                      vol6 / np.stack(cross, axis=1).max(axis=1))


def _need_2d_triangles(mesh: Mesh, what: str):
    if mesh.kind != "triangles" or mesh.dim != 2:
        raise MeshError(f"{what} needs a 2D triangle mesh, got {mesh!r}")


# ======================================================================================
# Topology
# ======================================================================================

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
    offsets, eid, other = geometry.edge_incidence(n_vertices, E, by="edge")
    return Incidence(_readonly(offsets), _readonly(eid), _readonly(other))


def _compute_hinges(mesh: Mesh):
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


# ======================================================================================
# Rest quantities (work for 2D or 3D coordinates)
# ======================================================================================

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
    edge (v0, v1) (columns of ``hinges``), in 2D or 3D (engine.geometry.hinge_geometry). The
    notes' bending area is A_e = |e| (h0 + h1) / 6."""
    g = geometry.hinge_geometry(X, hinges)
    return np.stack([g["h0"], g["h1"]], axis=1)


def dihedral_angles(X, hinges) -> np.ndarray:
    """(h,) signed dihedral angles theta (rad) at the hinges (engine.geometry.dihedral_angles):
    zero when flat; positive where the surface is convex on the side its normals point to (e.g.
    the outward-oriented :func:`cylinder_wrap`), negative where it is concave. 2D input gives
    zeros. A numpy reference for rest angles of curved rest shapes."""
    return geometry.dihedral_angles(X, hinges)


# ======================================================================================
# Validation
# ======================================================================================

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
            _compute_hinges(mesh)
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
