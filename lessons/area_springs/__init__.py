"""Lesson ``area-springs``: springs in 2D and 3D scaled by the area or volume they stand for.

The notes' multi-dimensional spring potential W_ij = 1/2 E (|x_i - x_j|/L_ij - 1)^2 A_ij, with
A_ij = engine.mesh.edge_measure (a third of each neighbouring triangle, a sixth of each
neighbouring tet), is the engine's SpringEnergy with c_e = E A_e. :mod:`.scene` builds the meshes,
runs one standing wave through the engine and draws it, and estimates each stage's time;
:mod:`.stages` runs the standing waves and a static stretch, measures speeds and moduli and
compares them with the long-wavelength theory of engine.waves (Cauchy-Born sum and Christoffel
equation); ``narrative.md`` narrates each stage.
"""
from __future__ import annotations

from dataclasses import dataclass

from engine.errors import ParameterError

from .._framework import Lesson, narrated_stages, param
from . import scene, stages


@dataclass
class AreaSpringsConfig:
    E: float = param(1.0, "Young's modulus E in W = 1/2 E (l/L-1)^2 A (sheets: N/m, the box: Pa; the lesson "
                     "scales with sqrt(E/rho), and this range keeps its speeds, steps and energies well inside f64)",
                     "N/m | Pa", ge=1e-6, le=1e12)
    rho: float = param(1.0, "density (sheets: kg/m^2 per area, the box: kg/m^3)", "kg/m^2 | kg/m^3", ge=1e-6, le=1e6)
    wavelength: int = param(48, "wavelength of the 2D standing waves, in lattice spacings", ge=16, le=160)
    box_cells: int = param(8, "cells along the coarsest 1 m tet box (stage 1 refines it x2 and x4)", ge=6, le=12)
    box_wavelength: int = param(20, "wavelength of the 3D waves of stage 4 on the coarse box, in cells", ge=8, le=24)
    jitter: float = param(0.25, "jitter amplitude of stage 3 (fraction of the local edge length)", gt=0, le=0.25)
    jitter_seeds: int = param(3, "jittered meshes (random seeds) in stage 3", ge=1, le=8)
    strain: float = param(1e-3, "peak strain of the waves and the stretch of stage 5 (at least 1e-6: the "
                          "displacements, strain x lengths up to a few hundred m, must stand well above the round-off "
                          "of positions that large, ~1e-13 m)", ge=1e-6, le=0.01)
    strip_cells: int = param(80, "length of the stage-5 strip in lattice spacings (width: a quarter)", ge=40, le=240)
    cfl: float = param(0.5, "time step as a fraction of the engine's Gershgorin CFL estimate", gt=0, le=1)


def _validate(cfg):
    if cfg.strain * cfg.strip_cells > 1.0:
        raise ParameterError(f"--strain {cfg.strain:g} stretches the {cfg.strip_cells}-spacing strip by more "
                             "than a spacing; use a smaller strain")
    scene.check_work(cfg)


LESSON = Lesson(
    id="area-springs",
    title="Area- and volume-scaled springs in 2D and 3D",
    summary="Springs weighted by the area/volume they represent: resolution-independent wave speeds, "
            "the Cauchy-Born stiffness of a spring network, P and S waves, anisotropy of mesh patterns, "
            "and a static stretch test of Young's modulus and Poisson's ratio.",
    config=AreaSpringsConfig,
    stages=narrated_stages(__name__, [
        ("one k for every spring versus volume-scaled springs", stages.stage_refinement),
        ("the equilateral sheet: P and S waves", stages.stage_equilateral),
        ("the pattern matters: grids, anisotropy, jitter", stages.stage_patterns),
        ("3D: waves in the tet box", stages.stage_tet_box),
        ("static stretch: Young's modulus and Poisson's ratio", stages.stage_stretch),
    ]),
    order=3,
    validate=_validate,
)

__all__ = ["LESSON", "AreaSpringsConfig"]
