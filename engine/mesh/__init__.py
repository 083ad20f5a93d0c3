"""Meshes for the lessons: generators, topology and rest quantities (pure numpy, SI units).

Set-up code, not the hot loop; nothing here imports Taichi. Four modules, every public name
re-exported here (``from engine.mesh import X``, ``engine.mesh.X``):

``core``        the data structure: :class:`Mesh` (rest positions and one element array, with
                its topology and rest quantities as cached properties), :class:`MeshError` and the
                topology functions (edges, hinges, CSR incidences, boundaries);
``validation``  :func:`validate`, the checks of a mesh;
``generators``  the rod, right-triangle grids, equilateral lattices, tet boxes, and jitter,
                embed_3d, rotate_2d, cylinder_wrap, half_cylinder;
``measures``    lengths, areas, volumes, edge measures, lumped masses, per-hinge rest geometry
                and dihedral angles.
"""
from engine.mesh.core import (TET_EDGES, TET_FACES, TRIANGLE_EDGES, Incidence, Mesh, MeshError, boundary_edges,
                              boundary_faces, boundary_vertices, csr_incidence, edge_incidence, edges, element_edges,
                              hinges, incidence, tet_faces)
from engine.mesh.generators import (cylinder_wrap, embed_3d, equilateral_lattice, half_cylinder, jitter,
                                    right_triangle_grid, rod, rotate_2d, tet_box)
from engine.mesh.measures import (as_points3, dihedral_angles, edge_measure, hinge_geometry, hinge_heights,
                                  lumped_masses, rest_lengths, signed_areas_2d, tet_volumes, total_measure,
                                  triangle_areas)
from engine.mesh.validation import validate

__all__ = [
    "MeshError", "Mesh", "Incidence",
    "rod", "right_triangle_grid", "equilateral_lattice", "tet_box", "jitter", "embed_3d",
    "rotate_2d", "cylinder_wrap", "half_cylinder",
    "edges", "element_edges", "csr_incidence", "incidence", "edge_incidence", "hinges", "boundary_vertices",
    "boundary_edges", "tet_faces", "boundary_faces",
    "as_points3", "rest_lengths", "triangle_areas", "signed_areas_2d", "tet_volumes", "total_measure",
    "edge_measure", "lumped_masses", "hinge_geometry", "hinge_heights", "dihedral_angles", "validate",
    "TRIANGLE_EDGES", "TET_EDGES", "TET_FACES",
]
