"""The area-springs exercise, solved: the reference the grader's tests run."""
import numpy as np


def edge_measure(vertices, edges, cells):
    X = np.asarray(vertices, float)
    cells = np.asarray(cells)
    P = X[cells]
    if cells.shape[1] == 3:   # triangles: area, shared by 3 edges
        size = 0.5 * np.linalg.norm(np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]), axis=1)
    else:                     # tets: |volume|, shared by 6 edges
        size = np.abs(np.einsum("ij,ij->i", P[:, 1] - P[:, 0], np.cross(P[:, 2] - P[:, 0], P[:, 3] - P[:, 0]))) / 6
    corners = cells.shape[1]
    pairs = [(a, b) for a in range(corners) for b in range(a + 1, corners)]
    n = len(X)
    edges = np.sort(np.asarray(edges), axis=1)
    index = {key: k for k, key in enumerate((edges[:, 0] * n + edges[:, 1]).tolist())}
    out = np.zeros(len(edges))
    for a, b in pairs:
        lo, hi = np.minimum(cells[:, a], cells[:, b]), np.maximum(cells[:, a], cells[:, b])
        rows = np.array([index[key] for key in (lo * n + hi).tolist()])
        np.add.at(out, rows, size / len(pairs))
    return out
