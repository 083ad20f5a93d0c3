"""The area-springs lesson's exercise: the area (volume) each spring stands for, the A_e of the
area-scaled coefficient c_e = E A_e.

The student's function is set-up code (numpy): every mesh of the lesson gets its springs'
coefficients from it, and it is checked on its own first on a jittered triangle mesh and a tet box.
"""
import numpy as np

from engine import mesh as M
from engine.mesh import measures
from .._exercise import NUMPY, StudentError, Task, agreement, deviation, factor_text, first_bad, ratio, substitute


def _meshes():
    return {"triangles": M.jitter(M.right_triangle_grid(5, 4, 1.0, 0.8), 0.2, seed=1),
            "tets": M.jitter(M.tet_box(3, 2, 2, size=(0.3, 0.2, 0.2)), 0.15, seed=2)}


def _call(func, mesh) -> np.ndarray:
    X = np.array(mesh.vertices)
    if X.shape[1] == 2:   # a plane mesh: its vertices in 3D, z = 0
        X = np.column_stack([X, np.zeros(len(X))])
    try:
        out = func(X, np.array(mesh.edges), np.array(mesh.elements))
    except Exception as exc:  # noqa: BLE001 - the student's error, one line
        raise StudentError(f"edge_measure: raised {type(exc).__name__}: {' '.join(str(exc).split())[:200]}") from None
    try:
        out = np.asarray(out, dtype=float)
    except (TypeError, ValueError):
        raise StudentError(f"edge_measure: returns {type(out).__name__}, expected a numpy array of floats") from None
    if out.shape != (len(mesh.edges),):
        raise StudentError(f"edge_measure: returns shape {out.shape}, expected ({len(mesh.edges)},): one value per edge")
    return out


def check_edge_measure(func) -> list:
    exps = []
    for kind, mesh in _meshes().items():
        got = _call(func, mesh)
        ref = measures.edge_measure(mesh)
        dev = deviation(got, ref)
        tol = 1e-12
        unit, share, whole = ("m^2", "area/3", "area") if kind == "triangles" else ("m^3", "volume/6", "volume")
        reason = ""
        if not dev <= tol:
            i = first_bad(got, ref, tol)
            r = factor_text(ratio(got, ref))
            total = got.sum() / mesh.total_measure
            if not np.all(np.isfinite(got)):
                reason = f"edge_measure returns NaN or inf at edge {i}"
            elif r:
                reason = (f"edge_measure is {r} the right share: each element gives {share} to each of its edges, "
                          f"so the shares sum to the mesh's {whole}")
            elif abs(total - 1.0) > 1e-9:
                reason = f"edge_measure sums to {total:.4g} times the mesh's {whole}; the shares must add up to it"
            else:
                reason = (f"edge_measure gives edge {i} {got[i]:.6g} {unit} instead of {ref[i]:.6g} {unit}: "
                          f"is each element's {share} added to the right edges?")
        exps.append(agreement(f"edge_measure on a jittered {kind} mesh = {share} per element and edge (max rel. dev.)",
                              f"ex-edge-measure-{kind}", dev, tol, reason, unit))
    return exps


def install_edge_measure(func) -> None:
    engine_edge_measure = measures.edge_measure

    def edge_measure(mesh):   # a chain of segments (no area to share) keeps the engine's lengths
        return engine_edge_measure(mesh) if mesh.kind == "segments" else _call(func, mesh)
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
