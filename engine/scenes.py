"""Scenes shared by lessons and benchmarks, so a benchmark times exactly what a lesson runs.

``cloth``: a square sheet of ``n x n`` vertices (right-triangle grid, alternating diagonals by
default) hanging in the x-z plane, with area-scaled springs (c_e = E A_e, W = 1/2 E (l/L-1)^2 A_e),
dihedral bending (engine/energies/bending.py) and gravity, pinned at its two top corners.
Units: E is the 2D stretching modulus (N/m: Young's modulus times thickness), rho the areal
density (kg/m^2), B the bending modulus (N m).
"""
from dataclasses import dataclass

import numpy as np

from engine import mesh as meshes
from engine.constants import G
from engine.energies.bending import BendingEnergy
from engine.model import Model


@dataclass
class Cloth:
    mesh: meshes.Mesh
    model: Model
    springs: object
    bending: object | None


def cloth(n: int, size: float = 1.0, E: float = 1e3, rho: float = 0.1, B: float = 1e-4,
          variant: str = "notes", diagonals: str = "alternating", pins: str = "top-corners",
          gravity: float = G) -> Cloth:
    """Build the hanging-cloth scene; ``B = 0`` leaves the bending energy out."""
    m2 = meshes.right_triangle_grid(n, n, size, size, diagonals=diagonals)
    m3 = meshes.embed_3d(m2, plane="xz")
    X = np.asarray(m3.vertices, dtype=np.float64)
    if pins == "top-corners":
        top = np.flatnonzero(np.isclose(X[:, 2], X[:, 2].max()))
        pinned = [int(top[np.argmin(X[top, 0])]), int(top[np.argmax(X[top, 0])])]
    elif pins == "top-edge":
        pinned = np.flatnonzero(np.isclose(X[:, 2], X[:, 2].max())).tolist()
    elif pins == "none":
        pinned = []
    else:
        raise ValueError(f"pins must be top-corners, top-edge or none (got {pins!r})")
    model = Model.from_springs(X, m3.edges, c=E * m3.edge_measure, mass=meshes.lumped_masses(m3, rho),
                               pinned=pinned, gravity=[0.0, 0.0, -gravity])
    bending = None
    if B > 0:
        bending = model.add_energy(BendingEnergy.from_mesh(m3, B, variant))
    return Cloth(m3, model, model.springs, bending)
