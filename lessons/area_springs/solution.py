"""The area-springs exercise, solved: the reference the grader's tests run."""
import itertools

import numpy as np


def edge_measure(vertices, edges, cells):
    X = np.asarray(vertices, float)
    index = {tuple(sorted(e)): k for k, e in enumerate(np.asarray(edges).tolist())}
    out = np.zeros(len(index))
    for cell in np.asarray(cells).tolist():
        P = X[cell]
        if len(cell) == 3:
            size = 0.5 * np.linalg.norm(np.cross(P[1] - P[0], P[2] - P[0]))
        else:
            size = abs(np.dot(P[1] - P[0], np.cross(P[2] - P[0], P[3] - P[0]))) / 6.0
        pairs = list(itertools.combinations(cell, 2))
        for a, b in pairs:
            out[index[tuple(sorted((a, b)))]] += size / len(pairs)
    return out
