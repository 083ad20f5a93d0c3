"""The area-springs lesson's exercise: the area (volume) each spring stands for, the A_e of the
area-scaled coefficient c_e = E A_e.

The student's function is set-up code (numpy): every mesh of the lesson gets its springs'
coefficients from it, and it is checked on its own first on a jittered triangle mesh and a tet box.
"""
import math

import numpy as np

from engine import mesh as M
from engine.mesh import measures
from .._exercise import NUMPY, LocalFunction, Sampler, StudentError, Task, agreement, deviation, direct, \
    factor_text, first_bad, matches, ratio, substitute


def _meshes():
    """The meshes the check runs on: a jittered triangle sheet lifted off the plane into a bumpy 3D
    surface, and a jittered tet box; in each, every other element listed with the other orientation
    (a solution may not assume positive elements, nor a flat sheet)."""
    tri = M.jitter(M.right_triangle_grid(6, 5, 1.0, 0.8), 0.2, seed=1)
    X = np.array(tri.vertices, float)
    z = 0.3 * np.sin(2.0 * X[:, 0]) * np.cos(3.0 * X[:, 1]) + 0.05 * Sampler(3).uniform(len(X), -1.0, 1.0)
    tri_cells = np.array(tri.elements)
    tri_cells[::2] = tri_cells[::2][:, [0, 2, 1]]
    tet = M.jitter(M.tet_box(3, 3, 2, size=(0.3, 0.25, 0.2)), 0.15, seed=2)
    tet_cells = np.array(tet.elements)
    tet_cells[1::2] = tet_cells[1::2][:, [0, 1, 3, 2]]
    return {"triangles": (np.column_stack([X, z]), np.array(tri.edges), tri_cells),
            "tets": (np.array(tet.vertices, float), np.array(tet.edges), tet_cells)}


def _sizes(X, cells, signed=False, flat=False, right_angle=False) -> np.ndarray:
    """Each element's area (triangles) or volume (tets); ``signed``/``flat``/``right_angle``: the
    mistakes named."""
    P = X[cells]
    if right_angle and cells.shape[1] == 3:
        return 0.5 * np.linalg.norm(P[:, 1] - P[:, 0], axis=1) * np.linalg.norm(P[:, 2] - P[:, 0], axis=1)
    if flat:
        P = P.copy()
        P[..., 2] = 0.0
    if cells.shape[1] == 3:
        n = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
        return 0.5 * (n[:, 2] if signed else np.linalg.norm(n, axis=1))
    v = np.einsum("ij,ij->i", P[:, 1] - P[:, 0], np.cross(P[:, 2] - P[:, 0], P[:, 3] - P[:, 0])) / 6.0
    return v if signed else np.abs(v)


def _shares(X, edges, cells, **mistake) -> np.ndarray:
    """A_e in the order of ``edges`` (either way round): each element's size over its edge count."""
    size = _sizes(X, cells, **mistake)
    corners = cells.shape[1]
    pairs = [(a, b) for a in range(corners) for b in range(a + 1, corners)]
    row = {(min(i, j), max(i, j)): k for k, (i, j) in enumerate(np.asarray(edges).tolist())}
    out = np.zeros(len(edges))
    for a, b in pairs:
        for e, (i, j) in enumerate(zip(cells[:, a].tolist(), cells[:, b].tolist())):
            out[row[(min(i, j), max(i, j))]] += size[e] / len(pairs)
    return out


def _call(student, X, edges, cells) -> np.ndarray:
    out = student.via(direct)(X, np.array(edges), np.array(cells))
    if out.shape != (len(edges),):
        raise StudentError(f"edge_measure: returns shape {out.shape}, expected ({len(edges)},): one value per edge")
    return out


def check_edge_measure(student) -> list:
    exps = []
    for kind, (X, edges, cells) in _meshes().items():
        got = _call(student, X, edges, cells)
        ref = _shares(X, edges, cells)
        exps.append(_verdict(kind, got, ref, X, edges, cells, f"ex-edge-measure-{kind}",
                             f"edge_measure on a jittered {'bumpy 3D triangle' if kind == 'triangles' else 'tet'} "
                             f"mesh, elements of both orientations"))
    # the same meshes with their edge rows shuffled and every third one reversed (j, i)
    for kind, (X, edges, cells) in _meshes().items():
        order = Sampler(5).rng.permutation(len(edges))
        shuffled = edges[order].copy()
        shuffled[::3] = shuffled[::3, ::-1]
        what = f"edge_measure on the {kind} mesh with its edges shuffled and some given as (j, i)"
        try:
            got = _call(student, X, shuffled, cells)
        except StudentError as exc:
            exps.append(_failed(f"ex-edge-measure-order-{kind}", what,
                                f"{exc} (only with the edges shuffled and some given as (j, i): an edge may come "
                                f"either way round, in any order)"))
            continue
        exps.append(_verdict(kind, got, _shares(X, shuffled, cells), X, shuffled, cells,
                             f"ex-edge-measure-order-{kind}", what))
    return exps


def _failed(id: str, claim: str, reason: str):
    return agreement(f"{claim} (max rel. dev.)", id, math.inf, 1e-12, reason)


def _verdict(kind, got, ref, X, edges, cells, id, claim):
    dev = deviation(got, ref)
    tol = 1e-12
    unit, share, whole = ("m^2", "area/3", "area") if kind == "triangles" else ("m^3", "volume/6", "volume")
    reason = ""
    if not dev <= tol:
        i = first_bad(got, ref, tol)
        r = factor_text(ratio(got, ref))
        total = got.sum() / ref.sum()
        if not np.all(np.isfinite(got)):
            reason = f"edge_measure returns NaN or inf at edge {i}"
        elif matches(got, _shares(X, edges, cells, signed=True)):
            reason = (f"edge_measure takes each element's signed {whole}: an element listed with the other "
                      f"orientation counts negative; use its absolute {whole}")
        elif kind == "triangles" and matches(got, _shares(X, edges, cells, flat=True)):
            reason = ("edge_measure's triangle areas ignore z: the sheet is not flat; the area is |(x1 - x0) x "
                      "(x2 - x0)|/2 in 3D")
        elif kind == "triangles" and matches(got, _shares(X, edges, cells, signed=True, flat=True)):
            reason = "edge_measure's triangle areas are the signed areas in the x-y plane: use |(x1 - x0) x (x2 - x0)|/2 in 3D"
        elif kind == "triangles" and matches(got, _shares(X, edges, cells, right_angle=True)):
            reason = ("edge_measure takes a triangle's area as |x1 - x0| |x2 - x0|/2, true only for a right angle at "
                      "corner 0: use |(x1 - x0) x (x2 - x0)|/2")
        elif np.allclose(np.sort(got), np.sort(ref), rtol=1e-12, atol=0):
            reason = ("edge_measure returns the right values in another order than the rows of `edges`: the "
                      "result must follow the edges as given (any order, either way round)")
        elif r:
            reason = (f"edge_measure is {r} the right share: each element gives {share} to each of its edges, "
                      f"so the shares sum to the mesh's {whole}")
        elif abs(total - 1.0) > 1e-9:
            reason = (f"edge_measure sums to {total:.4g} times the mesh's {whole}; the shares must add up to it"
                      + ("; out[rows] += v adds a repeated row once: np.add.at adds every one" if total < 1 else ""))
        else:
            reason = (f"edge_measure gives edge {i} {got[i]:.6g} {unit} instead of {ref[i]:.6g} {unit}: "
                      f"is each element's {share} added to the right edges?")
    return agreement(f"{claim} = {share} per element and edge (max rel. dev.)", id, dev, tol, reason, unit)


def install_edge_measure(func) -> None:
    engine_edge_measure = measures.edge_measure

    def edge_measure(mesh):   # a chain of segments (no area to share) keeps the engine's lengths
        if mesh.kind == "segments":
            return engine_edge_measure(mesh)
        X = np.array(mesh.vertices, float)
        if X.shape[1] == 2:   # a plane mesh: its vertices in 3D, z = 0
            X = np.column_stack([X, np.zeros(len(X))])
        return _call(LocalFunction("edge_measure", func), X, mesh.edges, mesh.elements)
    substitute(measures.edge_measure, edge_measure)


TASKS = [
    Task("edge_measure", NUMPY, "vertices, edges, cells", """\
The area (triangles) or volume (tets) each spring stands for, A_e, so that an area-scaled spring
gets the coefficient c_e = E A_e; in m^2 or m^3, one value per edge.

vertices: (n, 3) positions (m); edges: (m, 2) vertex indices of the springs, in the order the
result must follow; cells: (k, 3) triangles or (k, 4) tetrahedra (vertex indices).
Every element shares its area (volume) equally among its edges: a triangle has 3 edges, a
tetrahedron 6. An edge's A_e is the sum of the shares it gets from the elements around it, so
the A_e of all edges add up to the mesh's whole area (volume).""", install_edge_measure,
         check_edge_measure, (), "numpy array (m,)"),
]
