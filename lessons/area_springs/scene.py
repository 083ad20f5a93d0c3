"""The scene of ``area-springs``: the meshes and the area/volume-scaled spring models built on
them, how the stretched strips are drawn, and the estimates of each stage's time with the budget
they are checked against. The standing-wave run every wave stage measures with, and its drawers,
are lessons._waves' (shared with membranes)."""
from __future__ import annotations

import math

import numpy as np

from engine import mesh as M
from engine.model import Model
from lessons.views import RunView
from engine.waves import cauchy_born_tensor

from .._budget import StageCost, announce as announce_budget, check_stages
from .._measure import edge_strain, vertex_strain
from .._waves import square_domain_cells


# ------------------------------------------------------- builders: meshes and models

def area_model(mesh3: M.Mesh, E: float, rho: float, pinned=None) -> tuple[Model, np.ndarray, np.ndarray]:
    """Area/volume-scaled springs on a 3D-embedded mesh: (model, c_e = E A_e, lumped masses)."""
    c = E * M.edge_measure(mesh3)
    mass = M.lumped_masses(mesh3, rho)
    return Model.from_springs(mesh3.vertices, mesh3.edges, c=c, mass=mass, pinned=pinned), c, mass


def bulk_tensor(mesh: M.Mesh, c: np.ndarray, h: float) -> np.ndarray:
    """Cauchy-Born C of the infinite lattice from the springs of 3 x 3 x 3 interior cells of a
    tet box (midpoints in a window offset by h/4, so every spring class is counted once per
    cell), for any coefficients c (also the constant-k springs)."""
    X, e = mesh.vertices, mesh.edges
    mid = 0.5 * (X[e[:, 0]] + X[e[:, 1]])
    lo = X.min(axis=0) + 1.25 * h
    inside = np.all((mid >= lo) & (mid < lo + 3 * h), axis=1)
    return cauchy_born_tensor(X, e[inside], c[inside], 27 * h ** 3)


def eq_sheet(cfg, half_cells: float, spacing: float = 1.0) -> M.Mesh:
    """An equilateral lattice about 2*half_cells spacings on a side."""
    nx = square_domain_cells(half_cells * spacing, spacing) + 1
    ny = square_domain_cells(half_cells * spacing, spacing * math.sqrt(3) / 2) + 1
    return M.equilateral_lattice(nx, ny, spacing)


STRIPS = {"equilateral_strip": "equilateral strip", "alternating_strip": "alternating right-triangle strip"}


def draw_strip(rec, name, m3, x, u, strain):
    """The stretched strip (one frame) and its springs, coloured by strain on the scale of the
    nominal strain, the displacements magnified so that the end moves a quarter of the strip's
    length (the narrowing in the middle, Poisson's ratio, then shows)."""
    X = m3.vertices
    gain = 0.25 / strain
    rec.run(name, RunView(label=f"{STRIPS[name]} stretched by {100 * strain:.2g}%, clamped ends, "
                                f"displacement x{gain:.0f}", camera="top", energy=None))
    rec.set_time(0, 0.0)
    s = edge_strain(x, m3.edges, m3.rest_lengths)
    xd = X + gain * u
    rec.mesh(xd, m3.triangles, vertex_colors=rec.colors(vertex_strain(len(X), m3.edges, s), "signed", "strain",
                                                        strain))
    rec.springs(xd, m3.edges, s, scale=strain)


# -------------------------------------------------------- estimates and budget: the parameters' limits

# seconds of each stage at the defaults on the reference 2-thread CPU (velocity Verlet), and how they scale:
# the steps go as 1/cfl and as the wave's length in cells, the vertices as its square (sheets) or cube (boxes)
STAGE_SECONDS = {1: 6.7, 2: 0.6, 3: 3.0, 4: 3.2, 5: 0.2}


def stage_seconds(cfg, stage: int) -> float:
    """An estimate of stage ``stage``'s time on the reference CPU, scaled from its time at the defaults."""
    d = type(cfg)()
    slower = d.cfl / cfg.cfl
    if stage == 1:  # three boxes of nc, 2 nc, 4 nc cells: vertices ~ nc^3, steps ~ nc
        return STAGE_SECONDS[1] * (cfg.box_cells / d.box_cells) ** 4 * slower
    if stage == 2:
        return STAGE_SECONDS[2] * (cfg.wavelength / d.wavelength) ** 3 * slower
    if stage == 3:  # 12 pattern runs and 2 per jittered mesh (jitter_seeds strong + 1 mild)
        runs = (12 + 2 * (cfg.jitter_seeds + 1)) / (12 + 2 * (d.jitter_seeds + 1))
        return STAGE_SECONDS[3] * (cfg.wavelength / d.wavelength) ** 3 * runs * slower
    if stage == 4:  # boxes of a few wavelengths: vertices ~ box_wavelength^3, steps ~ box_wavelength
        return STAGE_SECONDS[4] * (cfg.box_wavelength / d.box_wavelength) ** 4 * slower
    return STAGE_SECONDS[5] * (cfg.strip_cells / d.strip_cells) ** 3


BUDGET = {stage: StageCost(flags=flags, advice="use a larger --cfl or smaller sizes")
          for stage, flags in ((1, "--box-cells, --cfl"), (2, "--wavelength, --cfl"),
                               (3, "--wavelength, --jitter-seeds, --cfl"), (4, "--box-wavelength, --cfl"),
                               (5, "--strip-cells"))}


def check_work(cfg) -> None:
    """Refuse a configuration any of whose stages would take more than the lessons' budget."""
    check_stages(cfg, stage_seconds, BUDGET)


def announce(ctx, stage: int) -> None:
    announce_budget(ctx, stage_seconds(ctx.cfg, stage))
