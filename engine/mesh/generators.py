"""Mesh generators: the rod, grids and lattices of triangles, boxes of tets, and the maps that
jitter, embed, rotate and roll them (pure numpy, SI units). Every generator validates its output
(engine.mesh.validation.validate) and raises MeshError naming a bad parameter."""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from engine.mesh.core import TET_FACES, TRIANGLE_EDGES, Mesh, MeshError
from engine.mesh.measures import tet_volumes, triangle_areas
from engine.mesh.validation import validate

__all__ = ["rod", "right_triangle_grid", "equilateral_lattice", "tet_box", "jitter", "embed_3d",
           "rotate_2d", "cylinder_wrap", "half_cylinder"]


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
