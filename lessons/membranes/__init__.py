"""Lesson ``membranes``: Baraff and Witkin's triangle conditions and a continuum constant-strain
triangle against area-scaled springs.

The energies are engine.energies.membrane's stencils (k = 3): the St. Venant-Kirchhoff triangle
(Young's modulus and Poisson's ratio as parameters) and Baraff and Witkin's stretch and shear
conditions. :mod:`.scene` builds the strips, sheets and the hanging cloth and estimates each
stage's time; :mod:`.stages` checks the energies' derivatives, measures the moduli by a static
stretch and the wave speeds by direction, and hangs a cloth with backward Euler at large steps;
``narrative.md`` narrates each stage.
"""
from __future__ import annotations

from dataclasses import dataclass

from engine.errors import ParameterError

from .._framework import Lesson, narrated_stages, param
from . import scene, stages


@dataclass
class MembranesConfig:
    Y: float = param(1.0, "the membrane's 2D Young's modulus (St. Venant-Kirchhoff; also Baraff-Witkin's k_stretch "
                     "in stages 1-2, with k_shear = Y/2)", "N/m", ge=1e-6, le=1e12)
    nu: float = param(0.3, "Poisson's ratio of the St. Venant-Kirchhoff membrane (stage 2 also measures 0 and "
                      "0.45)", ge=0.0, le=0.45)
    rho: float = param(1.0, "areal density of the strips and sheets", "kg/m^2", ge=1e-6, le=1e6)
    strain: float = param(1e-3, "the stretch of stage 2 and the peak strain of stage 3's waves", ge=1e-6, le=0.01)
    strip_cells: int = param(40, "length of stage 2's strips in lattice spacings (width: a quarter)", ge=24, le=160)
    wavelength: int = param(32, "wavelength of stage 3's standing waves, in lattice spacings", ge=16, le=96)
    cfl: float = param(0.5, "stage 3's time step as a fraction of the engine's Gershgorin CFL estimate", gt=0, le=1)
    cloth_n: int = param(16, "vertices along each side of stage 4's cloth", ge=4, le=64)
    cloth_size: float = param(1.0, "side of stage 4's square cloth", "m", ge=0.1, le=10.0)
    cloth_rho: float = param(0.1, "areal density of stage 4's cloth", "kg/m^2", ge=1e-3, le=10.0)
    k_stretch: float = param(100.0, "stage 4's Baraff-Witkin stretch stiffness", "N/m", ge=1.0, le=1e6)
    k_shear: float = param(10.0, "stage 4's Baraff-Witkin shear stiffness", "N/m", ge=0.1, le=1e6)
    large_step: int = param(10, "stage 4's large step, in 1/60 s", ge=2, le=60)
    settle_time: float = param(3.0, "how long stage 4's cloth hangs", "s", ge=0.5, le=60.0)
    damping_ratio: float = param(0.05, "stage 5's Baraff-Witkin damping, as the damping ratio it gives its wave "
                                 "(k_d = 2 ratio sqrt(k_s rho) / k)", ge=0.01, le=0.5)


def _validate(cfg):
    if cfg.strain * cfg.strip_cells > 1.0:
        raise ParameterError(f"--strain {cfg.strain:g} stretches the {cfg.strip_cells}-spacing strip by more than a "
                             "spacing; use a smaller strain")
    if cfg.large_step / 60.0 > cfg.settle_time:
        raise ParameterError(f"--large-step {cfg.large_step} (x 1/60 s) is longer than --settle-time "
                             f"{cfg.settle_time:g} s; use a longer --settle-time")
    scene.check_work(cfg)


LESSON = Lesson(
    id="membranes",
    title="Membranes: Baraff-Witkin's triangles and a continuum triangle against springs",
    summary="Energies on triangles instead of edges: their derivatives and the patch test, Young's modulus and "
            "Poisson's ratio as set on any mesh (springs fix Poisson's ratio), wave speeds whose dependence on "
            "direction vanishes as the mesh is refined, a Baraff-Witkin cloth under backward Euler at large steps "
            "and the decay of a damped wave.",
    config=MembranesConfig,
    stages=narrated_stages(__name__, [
        ("energies on triangles: derivatives and the patch test", stages.stage_triangles),
        ("static stretch: any Poisson's ratio, on any mesh", stages.stage_stretch),
        ("wave speeds and direction: isotropic as the mesh is refined, unlike springs", stages.stage_waves),
        ("a Baraff-Witkin cloth under backward Euler", stages.stage_hanging),
        ("Baraff-Witkin damping: the decay of a mode", stages.stage_damping),
    ]),
    order=6,
    camera="top",
    validate=_validate,
)

__all__ = ["LESSON", "MembranesConfig"]
