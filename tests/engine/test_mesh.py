"""Tests of engine/mesh/: counts, conservation of area/volume/mass, hinge convention,
conformity, incidence, validation messages, and the geometric generators."""
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from engine import mesh as M
from engine.mesh import Mesh, MeshError

PATTERNS = ("one-way", "alternating", "crossed")
RHO = 0.37  # kg/m^2 or kg/m^3, any value


def _all_meshes():
    """(label, mesh, exact total measure) for every generator and pattern."""
    out = []
    for p in PATTERNS:
        g = M.right_triangle_grid(5, 4, 2.0, 0.75, p)
        out.append((f"grid-{p}", g, 1.5))
        out.append((f"grid-{p}-jitter", M.jitter(g, 0.25, seed=3), 1.5))
        out.append((f"grid-{p}-rotated", M.rotate_2d(g, 0.3, center=(1.0, 0.2)), 1.5))
        out.append((f"grid-{p}-xz", M.embed_3d(g, "xz", origin=(1, 2, 3)), 1.5))
    s = 0.1
    eq = M.equilateral_lattice(6, 5, s)
    eq_area = 2 * 5 * 4 * math.sqrt(3) / 4 * s * s
    out.append(("equilateral", eq, eq_area))
    out.append(("equilateral-jitter", M.jitter(eq, 0.25, seed=0), eq_area))
    box = M.tet_box(4, 3, 5, size=(0.6, 0.2, 0.8))
    out.append(("tet-box", box, 0.6 * 0.2 * 0.8))
    out.append(("tet-box-jitter", M.jitter(box, 0.25, seed=1), 0.6 * 0.2 * 0.8))
    out.append(("rod", M.rod(7, 2.5), 2.5))
    return out


ALL = _all_meshes()
IDS = [label for label, _, _ in ALL]


# ---------------------------------------------------------------- conservation ------

@pytest.mark.parametrize("label,mesh,total", ALL, ids=IDS)
def test_edge_measures_and_masses_sum_to_totals(label, mesh, total):
    assert mesh.total_measure == pytest.approx(total, rel=1e-12)
    A = M.edge_measure(mesh)
    assert A.shape == (len(mesh.edges),)
    assert (A > 0).all()
    assert A.sum() == pytest.approx(mesh.total_measure, rel=1e-12)
    m = M.lumped_masses(mesh, RHO)
    assert m.shape == (mesh.n_vertices,)
    assert (m > 0).all()
    assert m.sum() == pytest.approx(RHO * mesh.total_measure, rel=1e-12)


def test_edge_measure_is_a_third_of_adjacent_areas():
    g = M.right_triangle_grid(3, 3, 2.0, 2.0)  # unit cells, triangle area 1/2
    A = dict(zip(map(tuple, g.edges), g.edge_measure))
    assert A[(0, 1)] == pytest.approx(1 / 6)  # boundary edge: one triangle
    assert A[(1, 4)] == pytest.approx(1 / 3)  # interior edge: (A1 + A2)/3
    assert A[(0, 4)] == pytest.approx(1 / 3)  # diagonal
    box = M.tet_box(2, 2, 2, 1.0)  # 6 tets of volume 1/6; body diagonal is in all 6
    A = dict(zip(map(tuple, box.edges), box.edge_measure))
    assert A[(0, 7)] == pytest.approx(6 * (1 / 6) / 6)
    assert A[(0, 1)] == pytest.approx(2 / 36)  # cube edge x: in the 2 tets whose path starts +x
    r = M.rod(5, 1.0)
    np.testing.assert_allclose(M.lumped_masses(r, 2.0), [0.25, 0.5, 0.5, 0.5, 0.25])


@settings(max_examples=30, deadline=None)
@given(nx=st.integers(2, 9), ny=st.integers(2, 9), pattern=st.sampled_from(PATTERNS),
       w=st.floats(0.01, 10), h=st.floats(0.01, 10), seed=st.integers(0, 1000))
def test_grid_counts_and_conservation_any_size(nx, ny, pattern, w, h, seed):
    g = M.jitter(M.right_triangle_grid(nx, ny, w, h, pattern), 0.25, seed)
    C = (nx - 1) * (ny - 1)
    axis_edges = (nx - 1) * ny + nx * (ny - 1)
    per_cell = 4 if pattern == "crossed" else 2
    assert len(g.triangles) == per_cell * C
    assert len(g.edges) == axis_edges + (4 * C if pattern == "crossed" else C)
    assert len(g.hinges) == len(g.edges) - 2 * (nx - 1) - 2 * (ny - 1)
    assert g.edge_measure.sum() == pytest.approx(w * h, rel=1e-12)
    assert M.lumped_masses(g, RHO).sum() == pytest.approx(RHO * w * h, rel=1e-12)


# ---------------------------------------------------------------- counts ------------

@pytest.mark.parametrize("mesh,nv,nt,ne,nh", [
    # 3x3 grid: 4 cells; 6 horizontal + 6 vertical edges, 8 of them on the boundary
    (M.right_triangle_grid(3, 3), 9, 8, 16, 8),
    (M.right_triangle_grid(3, 3, diagonals="alternating"), 9, 8, 16, 8),
    (M.right_triangle_grid(3, 3, diagonals="crossed"), 13, 16, 28, 20),
    (M.right_triangle_grid(2, 2), 4, 2, 5, 1),
    (M.right_triangle_grid(2, 2, diagonals="crossed"), 5, 4, 8, 4),
    # 3 rows of 3: 6 row edges + 2 x 5 zig-zag edges; 8 on the boundary (V - E + F = 1)
    (M.equilateral_lattice(3, 3), 9, 8, 16, 8),
])
def test_small_triangle_counts(mesh, nv, nt, ne, nh):
    assert (mesh.n_vertices, len(mesh.triangles), len(mesh.edges), len(mesh.hinges)) == \
        (nv, nt, ne, nh)


@pytest.mark.parametrize("n,nt,ne,nf_boundary,nf_interior", [
    # one cube: 12 cube edges + 6 face diagonals + 1 body diagonal; 6 faces x 2 triangles
    ((2, 2, 2), 6, 19, 12, 6),
    # 2x2x2 cubes: 54 grid-line edges + 36 face diagonals + 8 body diagonals;
    # 4*48 = 2*72 + 48 face slots; Euler V - E + F - T = 27 - 98 + 120 - 48 = 1
    ((3, 3, 3), 48, 98, 48, 72),
])
def test_small_tet_counts(n, nt, ne, nf_boundary, nf_interior):
    box = M.tet_box(*n, size=1.0)
    faces, count, _ = M.tet_faces(box)
    assert len(box.tets) == nt and len(box.edges) == ne
    assert (count == 1).sum() == nf_boundary and (count == 2).sum() == nf_interior
    assert box.n_vertices - ne + len(faces) - nt == 1


def test_alternating_pattern_flips_the_diagonal():
    g = M.right_triangle_grid(3, 3, diagonals="alternating")
    E = set(map(tuple, g.edges))
    # cell (0,0): diagonal 0-4; cell (1,0): diagonal 2-4 (b-d); cell (0,1): 4-6; (1,1): 4-8
    assert {(0, 4), (2, 4), (4, 6), (4, 8)} <= E
    assert not {(1, 3), (1, 5), (3, 7), (5, 7)} & E


# ---------------------------------------------------------------- edges / CSR -------

@pytest.mark.parametrize("label,mesh,total", ALL, ids=IDS)
def test_edges_unique_sorted_and_csr_consistent(label, mesh, total):
    E = mesh.edges
    assert E.dtype == np.int64 and (E[:, 0] < E[:, 1]).all()
    keys = E[:, 0] * mesh.n_vertices + E[:, 1]
    assert (np.diff(keys) > 0).all()  # unique, lexicographic
    # element_edges point at the right vertex pairs
    local = {"triangles": M.TRIANGLE_EDGES, "tets": M.TET_EDGES,
             "segments": np.array([[0, 1]])}[mesh.kind]
    pairs = np.sort(mesh.elements[:, local], axis=2)
    np.testing.assert_array_equal(E[mesh.element_edges], pairs)
    off, eid, other = M.csr_incidence(mesh.n_vertices, E)
    assert off[0] == 0 and off[-1] == 2 * len(E) and (np.diff(off) >= 0).all()
    seen = np.zeros(len(E), dtype=int)
    for i in range(mesh.n_vertices):
        ids, oth = eid[off[i]:off[i + 1]], other[off[i]:off[i + 1]]
        assert (np.diff(ids) > 0).all()
        ends = E[ids]
        assert ((ends[:, 0] == i) | (ends[:, 1] == i)).all()
        np.testing.assert_array_equal(oth, ends.sum(axis=1) - i)
        seen[ids] += 1
    assert (seen == 2).all()
    assert mesh.incidence.offsets.tolist() == off.tolist()


def test_csr_by_hand():
    off, eid, other = M.csr_incidence(4, np.array([[0, 1], [1, 2], [0, 3], [2, 3]]))
    assert off.tolist() == [0, 2, 4, 6, 8]
    assert eid.tolist() == [0, 2, 0, 1, 1, 3, 2, 3]
    assert other.tolist() == [1, 3, 0, 2, 1, 3, 0, 2]


# ---------------------------------------------------------------- hinges ------------

def _check_hinge_convention(mesh):
    H, tris = M.hinges(mesh)
    T = mesh.triangles

    def has_directed(tri, a, b):
        return any(tri[k] == a and tri[(k + 1) % 3] == b for k in range(3))

    for (v0, v1, w0, w1), (t0, t1) in zip(H, tris):
        assert v0 < v1
        assert has_directed(T[t0], v0, v1) and has_directed(T[t0], v1, w0)
        assert has_directed(T[t1], v1, v0) and has_directed(T[t1], v0, w1)
    np.testing.assert_array_equal(mesh.edges[mesh.hinge_edge_ids], H[:, :2])
    return H


@pytest.mark.parametrize("label,mesh,total",
                         [a for a in ALL if a[1].kind == "triangles"],
                         ids=[a[0] for a in ALL if a[1].kind == "triangles"])
def test_hinge_orientation_and_boundary(label, mesh, total):
    H = _check_hinge_convention(mesh)
    boundary = set(M.boundary_edges(mesh).tolist())
    hinge_ids = set(mesh.hinge_edge_ids.tolist())
    assert not boundary & hinge_ids
    assert boundary | hinge_ids == set(range(len(mesh.edges)))
    # in 2D, t0 = (v0, v1, w0) is counter-clockwise: w0 is left of v0 -> v1
    if mesh.dim == 2:
        assert (M.signed_areas_2d(mesh.vertices, H[:, [0, 1, 2]]) > 0).all()
        assert (M.signed_areas_2d(mesh.vertices, H[:, [1, 0, 3]]) > 0).all()


def test_hinge_convention_with_scrambled_labels():
    g = M.right_triangle_grid(4, 4, diagonals="crossed")
    perm = np.random.default_rng(7).permutation(g.n_vertices)
    X = np.empty_like(g.vertices)
    X[perm] = g.vertices
    T = perm[g.triangles]
    T = np.roll(T, 1, axis=1)  # rotate the corner order too
    scrambled = M.validate(Mesh(X, triangles=T), need_hinges=True)
    H = _check_hinge_convention(scrambled)
    assert len(H) == len(g.hinges)


OCTAHEDRON = Mesh(
    [[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]],
    triangles=[[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4],
               [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
TETRAHEDRON = Mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]],
                   triangles=[[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])


@pytest.mark.parametrize("closed,ne", [(OCTAHEDRON, 12), (TETRAHEDRON, 6)])
def test_closed_surface_every_edge_is_a_hinge(closed, ne):
    M.validate(closed, need_hinges=True)
    H = _check_hinge_convention(closed)
    assert len(closed.edges) == ne and len(H) == ne
    assert len(M.boundary_edges(closed)) == 0
    assert not closed.boundary_vertices.any()
    # outward-oriented convex surface: every dihedral angle positive
    theta = M.dihedral_angles(closed.vertices, H)
    expected = math.pi - math.acos(-1 / 3) if ne == 12 else None
    assert (theta > 0).all()
    if expected is not None:  # octahedron: pi minus its interior dihedral angle
        np.testing.assert_allclose(theta, expected, rtol=1e-12)


def test_hinge_heights_and_bending_area():
    h = 0.5
    g = M.right_triangle_grid(5, 5, 2.0, 2.0)  # square cells of side h
    heights = g.hinge_heights
    diag = g.rest_lengths[g.hinge_edge_ids] > 1.1 * h
    np.testing.assert_allclose(heights[diag], h / math.sqrt(2), rtol=1e-12)
    np.testing.assert_allclose(heights[~diag], h, rtol=1e-12)
    # A_e = |e| (h0 + h1) / 6 = (A0 + A1) / 3, in 2D and embedded in 3D
    for mesh in (M.jitter(g, 0.2, seed=5), M.cylinder_wrap(M.jitter(g, 0.2, seed=5), 1.3)):
        lengths = mesh.rest_lengths[mesh.hinge_edge_ids]
        A_e = lengths * mesh.hinge_heights.sum(axis=1) / 6
        areas = mesh.element_measures[mesh.hinge_triangles].sum(axis=1) / 3
        np.testing.assert_allclose(A_e, areas, rtol=1e-12)


# ---------------------------------------------------------------- tets --------------

def test_tet_box_conforming_positive_and_closed():
    size = np.array([0.6, 0.2, 0.8])
    box = M.tet_box(4, 3, 5, size=size, origin=(1.0, -2.0, 0.5))
    vol = M.tet_volumes(box.vertices, box.tets)
    assert (vol > 0).all()
    assert vol.sum() == pytest.approx(size.prod(), rel=1e-12)
    faces, count, tet_face = M.tet_faces(box)
    assert set(count.tolist()) == {1, 2}
    P = box.vertices[faces] - np.array([1.0, -2.0, 0.5])  # (f, 3 corners, 3)
    on_box_side = np.zeros(len(faces), dtype=bool)
    for ax in range(3):
        for side in (0.0, size[ax]):
            on_box_side |= np.isclose(P[:, :, ax], side).all(axis=1)
    np.testing.assert_array_equal(on_box_side, count == 1)
    assert (count[tet_face] >= 1).all() and tet_face.shape == (len(box.tets), 4)
    # boundary faces point outward and form a closed, consistently oriented surface
    B = M.boundary_faces(box)
    X = box.vertices
    normal = np.cross(X[B[:, 1]] - X[B[:, 0]], X[B[:, 2]] - X[B[:, 0]])
    centre = X.mean(axis=0)
    assert (np.einsum("ij,ij->i", normal, X[B].mean(axis=1) - centre) > 0).all()
    surf = Mesh(X, triangles=B)
    M.validate(surf, need_hinges=True)
    assert len(surf.hinges) == len(surf.edges)
    assert M.triangle_areas(X, B).sum() == pytest.approx(
        2 * (0.6 * 0.2 + 0.2 * 0.8 + 0.6 * 0.8), rel=1e-12)


# ---------------------------------------------------------------- generators --------

def test_equilateral_lattice_edges_all_equal():
    s = 0.013
    for mesh in (M.equilateral_lattice(7, 6, s), M.rotate_2d(M.equilateral_lattice(4, 9, s), 1.1)):
        np.testing.assert_allclose(mesh.rest_lengths, s, rtol=1e-12)
        np.testing.assert_allclose(mesh.element_measures, math.sqrt(3) / 4 * s * s, rtol=1e-12)
    X = M.equilateral_lattice(3, 2, 1.0).vertices
    np.testing.assert_allclose(X[3], [0.5, math.sqrt(3) / 2])


@pytest.mark.parametrize("pattern", PATTERNS)
@pytest.mark.parametrize("axis", ["x", "y"])
def test_cylinder_wrap_lengths_and_radius(pattern, axis):
    R = 0.7
    flat = M.jitter(M.right_triangle_grid(7, 5, 1.5, 0.8, pattern), 0.2, seed=2)
    cyl = M.cylinder_wrap(flat, R, axis=axis)
    X = cyl.vertices
    off_axis = [1, 2] if axis == "x" else [0, 2]
    np.testing.assert_allclose(np.linalg.norm(X[:, off_axis], axis=1), R, rtol=1e-12)
    around, along = (1, 0) if axis == "x" else (0, 1)
    d = flat.vertices[flat.edges[:, 1]] - flat.vertices[flat.edges[:, 0]]
    chord = 2 * R * np.sin(np.abs(d[:, around]) / (2 * R))
    np.testing.assert_allclose(cyl.rest_lengths, np.hypot(chord, d[:, along]), rtol=1e-12)
    # lengths along the axis are unchanged
    d3 = X[cyl.edges[:, 1]] - X[cyl.edges[:, 0]]
    axis_index = 0 if axis == "x" else 1
    np.testing.assert_allclose(np.abs(d3[:, axis_index]), np.abs(d[:, along]), rtol=0, atol=1e-15)
    # outward normals
    T = cyl.triangles
    n = np.cross(X[T[:, 1]] - X[T[:, 0]], X[T[:, 2]] - X[T[:, 0]])
    radial = X[T].mean(axis=1)
    radial[:, along] = 0
    assert (np.einsum("ij,ij->i", n, radial) > 0).all()


def test_cylinder_wrap_preserves_axis_edges_exactly_and_bends_only_across():
    R, nx = 2.0, 9
    cyl = M.half_cylinder(nx, 5, radius=R, length=1.0)
    flat_len = math.pi * R / (nx - 1)
    E, L = cyl.edges, cyl.rest_lengths
    X = cyl.vertices
    along = np.isclose(X[E[:, 0], 0], X[E[:, 1], 0]) & np.isclose(X[E[:, 0], 2], X[E[:, 1], 2])
    np.testing.assert_allclose(L[along], 0.25, rtol=1e-12)  # unchanged by the wrap
    assert X[:, 2].min() == pytest.approx(0.0, abs=1e-15) and X[:, 2].max() == pytest.approx(R)
    # dihedral angles: dx/R on the axis-parallel interior edges, 0 on the others
    theta = M.dihedral_angles(X, cyl.hinges)
    on_axis_edges = along[cyl.hinge_edge_ids]
    np.testing.assert_allclose(theta[on_axis_edges], flat_len / R, rtol=1e-12)
    np.testing.assert_allclose(theta[~on_axis_edges], 0.0, atol=1e-12)
    assert on_axis_edges.sum() == (nx - 2) * (5 - 1)  # interior grid lines x cells along
    with pytest.raises(MeshError, match="less than 2 pi"):
        M.cylinder_wrap(M.right_triangle_grid(5, 3, 2 * math.pi, 1.0), 1.0)


@pytest.mark.parametrize("plane,normal", [("xy", [0, 0, 1]), ("xz", [0, -1, 0]),
                                          ("yz", [1, 0, 0])])
def test_embed_3d(plane, normal):
    g = M.right_triangle_grid(3, 4, 1.0, 2.0)
    m = M.embed_3d(g, plane, origin=(1.0, 2.0, 3.0))
    assert m.vertices.shape == (12, 3)
    X = m.vertices
    T = m.triangles
    n = np.cross(X[T[:, 1]] - X[T[:, 0]], X[T[:, 2]] - X[T[:, 0]])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    np.testing.assert_allclose(n, np.broadcast_to(normal, n.shape), atol=1e-15)
    np.testing.assert_allclose(m.rest_lengths, g.rest_lengths, rtol=1e-15)
    assert m.total_measure == pytest.approx(2.0, rel=1e-12)


def test_rotate_2d():
    g = M.right_triangle_grid(4, 3, 1.0, 0.5, "alternating")
    r = M.rotate_2d(g, math.pi / 2, center=(1.0, 0.0))
    np.testing.assert_allclose(r.vertices[0], [1.0, -1.0], atol=1e-15)
    np.testing.assert_array_equal(r.triangles, g.triangles)
    np.testing.assert_allclose(r.rest_lengths, g.rest_lengths, rtol=1e-12)
    np.testing.assert_allclose(r.element_measures, g.element_measures, rtol=1e-12)


@pytest.mark.parametrize("pattern", PATTERNS + ("equilateral", "tets"))
def test_jitter_moves_only_interior_within_amplitude(pattern):
    if pattern == "equilateral":
        base = M.equilateral_lattice(12, 10, 0.1)
    elif pattern == "tets":
        base = M.tet_box(5, 5, 5, 1.0)
    else:
        base = M.right_triangle_grid(12, 10, 1.0, 0.6, pattern)
    local = np.full(base.n_vertices, np.inf)
    np.minimum.at(local, base.edges.ravel(), np.repeat(base.rest_lengths, 2))
    amp = 0.25
    for seed in range(20):  # validate() inside jitter would raise on an inverted element
        j = M.jitter(base, amp, seed)
        d = np.linalg.norm(j.vertices - base.vertices, axis=1)
        b = base.boundary_vertices
        assert (d[b] == 0).all() and (d[~b] > 0).all()
        assert (d <= amp * local + 1e-15).all()
        assert d[~b].max() > 0.5 * amp * local[~b].min()  # really uses the amplitude
    np.testing.assert_array_equal(M.jitter(base, amp, 4).vertices, M.jitter(base, amp, 4).vertices)
    assert not np.array_equal(M.jitter(base, amp, 4).vertices, M.jitter(base, amp, 5).vertices)
    np.testing.assert_array_equal(M.jitter(base, 0.0, 4).vertices, base.vertices)


def test_element_widths_bound_the_jitter():
    # right triangle with legs h: width h/sqrt(2); Kuhn tet of a cube of side h: h/sqrt(3)
    # (distance between the opposite edges 000-110 and 100-111); regular tet: s/sqrt(2)
    w = M.generators._element_widths(M.right_triangle_grid(3, 3, 1.0, 1.0))
    np.testing.assert_allclose(w, 0.5 / math.sqrt(2), rtol=1e-12)
    w = M.generators._element_widths(M.tet_box(3, 3, 3, 1.0))
    np.testing.assert_allclose(w, 0.5 / math.sqrt(3), rtol=1e-12)
    reg = Mesh([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], tets=[[0, 2, 1, 3]])
    M.validate(reg)
    np.testing.assert_allclose(M.generators._element_widths(reg), 2 * math.sqrt(2) / math.sqrt(2))
    # stretched cells (aspect 50): the cap keeps amplitude 0.25 safe for every seed
    for pattern in PATTERNS:
        g = M.right_triangle_grid(6, 30, 5.0, 0.1, pattern)
        for seed in range(20):
            j = M.jitter(g, 0.25, seed)
            assert (M.signed_areas_2d(j.vertices, j.triangles) > 0).all()


def test_jitter_too_large_raises():
    g = M.right_triangle_grid(20, 20)
    with pytest.raises(MeshError, match=r"jitter\(amplitude=3.0, seed=0\).*triangle \d+"):
        M.jitter(g, 3.0, 0)
    with pytest.raises(MeshError, match="before embed_3d"):
        M.jitter(M.embed_3d(g), 0.1, 0)


def test_rod():
    r = M.rod(5, 2.0)
    assert r.vertices.shape == (5, 3)
    np.testing.assert_allclose(r.vertices[:, 0], [0, 0.5, 1, 1.5, 2])
    assert r.edges.tolist() == [[0, 1], [1, 2], [2, 3], [3, 4]]
    np.testing.assert_allclose(r.edge_measure, 0.5)
    assert r.boundary_vertices.tolist() == [True, False, False, False, True]


def test_mesh_arrays_are_read_only_and_int64():
    g = M.right_triangle_grid(3, 3)
    assert g.triangles.dtype == np.int64 and g.vertices.dtype == np.float64
    for a in (g.vertices, g.triangles, g.edges, g.hinges, g.edge_measure, g.incidence.offsets):
        with pytest.raises(ValueError):
            a[0] = 0


def test_large_grid_topology_is_complete():
    """The 256x256 benchmark grids build (speed is measured in bench/, not asserted here)."""
    for p in PATTERNS:
        g = M.right_triangle_grid(256, 256, 1.0, 1.0, p)
        g.incidence, g.hinge_heights
        assert M.lumped_masses(g, 1.0).sum() == pytest.approx(1.0, rel=1e-12)
        assert g.edge_measure.sum() == pytest.approx(1.0, rel=1e-12)


# ---------------------------------------------------------------- validation --------

SQUARE = [[0, 0], [1, 0], [1, 1], [0, 1]]


@pytest.mark.parametrize("mesh,need_hinges,message", [
    (Mesh(SQUARE + [[2, 0]], triangles=[[0, 1, 2], [0, 1, 4]]), False,
     r"^triangle 1 \(vertices 0, 1, 4\) has zero area$"),
    (Mesh(SQUARE + [[0.5, 1e-12]], triangles=[[0, 1, 2], [0, 1, 4]]), False,
     r"^triangle 1 \(vertices 0, 1, 4\) has near-zero area"),
    (Mesh(SQUARE, triangles=[[0, 1, 2], [0, 0, 3]]), False,
     r"^triangle 1 \(vertices 0, 0, 3\) has zero area$"),
    (Mesh(SQUARE, triangles=[[0, 1, 2], [0, 3, 2]]), False,
     r"^triangle 1 \(vertices 0, 3, 2\) is inverted"),
    (Mesh(SQUARE + [[1, 0]], triangles=[[0, 1, 2], [0, 2, 3]]), False,
     r"^vertices 1 and 4 are at the same position"),
    (Mesh(SQUARE, triangles=[[0, 1, 2], [0, 2, 7]]), False,
     r"^triangle 1 \(vertices 0, 2, 7\) has index 7 outside the valid range 0\.\.3$"),
    (Mesh(SQUARE, triangles=[[0, 1, 2], [-1, 2, 3]]), False,
     r"^triangle 1 \(vertices -1, 2, 3\) has index -1 outside the valid range 0\.\.3$"),
    (Mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1]],
          triangles=[[0, 1, 2], [1, 0, 3], [0, 1, 4]]), True,
     r"^edge \(0, 1\) is shared by 3 triangles \(0, 1, 2\)"),
    (Mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0]],
          triangles=[[0, 1, 2], [0, 1, 3]]), True,
     r"^triangles 0 \(0, 1, 2\) and 1 \(0, 1, 3\) are inconsistently oriented"),
    (Mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], tets=[[0, 1, 2, 3]]), False,
     r"^tet 0 \(vertices 0, 1, 2, 3\) is flat"),
    (Mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], tets=[[0, 2, 1, 3]]), False,
     r"^tet 0 \(vertices 0, 2, 1, 3\) is inverted"),
    (Mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], tets=[[0, 1, 2, 3]]), True,
     r"^hinges need a triangle mesh"),
    (Mesh([[0, 0], [1, 0], [np.nan, 1]], triangles=[[0, 1, 2]]), False,
     r"^vertex 2 has non-finite coordinates"),
    (Mesh([[0, 0], [1, 0], [0, np.inf]], triangles=[[0, 1, 2]]), False,
     r"^vertex 2 has non-finite coordinates"),
    (Mesh(np.zeros((3, 4)), triangles=[[0, 1, 2]]), False,
     r"^vertices must have shape \(n, 2\) or \(n, 3\) with n >= 1, got \(3, 4\)$"),
    (Mesh(SQUARE, triangles=[[0, 1, 2, 3]]), False,
     r"^triangles must have shape \(t, 3\), got \(1, 4\)$"),
    (Mesh(SQUARE, triangles=[0, 1, 2]), False, r"^triangles must have shape \(t, 3\)"),
    (Mesh(SQUARE, triangles=[[0.0, 1.0, 2.0]]), False,
     r"^triangles must hold integer vertex indices, got dtype float64$"),
    (Mesh(SQUARE, triangles=np.zeros((0, 3), dtype=int)), False, r"^the mesh has no triangles$"),
    (Mesh(SQUARE), False, r"^a mesh needs exactly one of triangles, tets, segments"),
    (Mesh(SQUARE, triangles=[[0, 1, 2]], tets=[[0, 1, 2, 3]]), False, r"exactly one of"),
    (Mesh(SQUARE, tets=[[0, 1, 2, 3]]), False, r"^tets need 3D vertices"),
    (Mesh([[0, 0, 0], [1, 0, 0], [1, 1e-13, 0]], segments=[[0, 1], [1, 2]]), False,
     r"^vertices 1 and 2 are at the same position"),
])
def test_validate_errors_name_the_element(mesh, need_hinges, message):
    with pytest.raises(MeshError, match=message) as info:
        M.validate(mesh, need_hinges=need_hinges)
    assert "\n" not in str(info.value)
    assert isinstance(info.value, ValueError)


def test_validate_accepts_good_meshes_and_returns_them():
    m = Mesh(SQUARE, triangles=[[0, 1, 2], [0, 2, 3]])
    assert M.validate(m, need_hinges=True) is m
    assert M.validate(OCTAHEDRON, need_hinges=True) is OCTAHEDRON


@pytest.mark.parametrize("call,message", [
    (lambda: M.right_triangle_grid(1, 3), r"^nx must be an integer >= 2, got 1$"),
    (lambda: M.right_triangle_grid(3, 3, diagonals="x"), r"^diagonals must be one of"),
    (lambda: M.right_triangle_grid(3, 3, width=0.0), r"^width must be a finite length > 0"),
    (lambda: M.equilateral_lattice(3, 3, spacing=-1), r"^spacing must be"),
    (lambda: M.tet_box(2, 2, 2, size=(1, 0, 1)), r"^size y must be"),
    (lambda: M.rod(1), r"^n_nodes must be an integer >= 2"),
    (lambda: M.embed_3d(M.right_triangle_grid(2, 2), "xw"), r"^plane must be one of"),
    (lambda: M.rotate_2d(M.tet_box(2, 2, 2), 0.1), r"^rotate_2d needs a 2D triangle mesh"),
    (lambda: M.cylinder_wrap(M.right_triangle_grid(2, 2), 1.0, axis="z"), r"^axis must be"),
    (lambda: M.hinges(M.rod(3)), r"^hinges need a triangle mesh"),
    (lambda: M.jitter(M.rod(3), 0.1, 0), r"^jitter needs a 2D triangle mesh or a tet mesh"),
])
def test_generator_parameter_errors(call, message):
    with pytest.raises(MeshError, match=message):
        call()
