"""Lesson ``springs``: forces from potential energy, the variational derivative, energy
conservation, stiffness from the speed of sound, a hanging rod.

Physics lives in the engine (:mod:`engine.energies.springs`, :mod:`engine.model`,
:mod:`engine.integrators`, :class:`engine.scenes.Rod`, :mod:`engine.statics`); :mod:`.scene`
builds the scenes, draws them and estimates each stage's cost, :mod:`.stages` (the stages that
do not step in time: 1, 3 and 5) and :mod:`.stages_dynamics` (those that do: 2 and 4) run them
and measure, and ``narrative.md`` narrates each stage.
"""
from __future__ import annotations

from dataclasses import dataclass

from .._framework import Lesson, narrated_stages, param
from . import scene, stages, stages_dynamics


@dataclass
class SpringsConfig:
    k: float = param(50.0, "stage 1: the notes' spring constant k in W = 1/2 k (l/L - 1)^2 L "
                     "(force per unit strain)", "N", ge=1e-6, le=1e9)
    chain_nodes: int = param(12, "stage 2: nodes of the swinging chain (1 m long, top node pinned)", ge=3, le=200)
    chain_k: float = param(1000.0, "stage 2: spring constant k of every chain link", "N", ge=1e-6, le=1e9)
    frame_k: float = param(100.0, "stage 2: spring constant k of every edge of the tetrahedral frame", "N",
                           ge=1e-6, le=1e9)
    steps: int = param(100_000, "stage 2: steps of each energy-conservation run", ge=1000, le=10**7)
    dt_fraction: float = param(0.1, "stage 2: time step as a fraction of the engine's CFL estimate (at most 0.5: "
                               "the estimate is the rest state's, the swinging chain's tension stiffens it and at "
                               "1.0 it blows up, and the wobble orders are asymptotic claims that need a small dt)",
                               gt=0, le=0.5)
    wave_segments: int = param(1500, "stage 4: 1/h, h the shortest segment of the 1 m chains", ge=1000,
                                le=20000)
    E: float = param(100.0, "stages 4-5: Young's modulus of the rod/chain (1D: force per unit strain)", "N",
                     ge=1e-6, le=1e9)
    rho: float = param(1.0, "stages 4-5: linear density", "kg/m", ge=1e-6, le=1e6)
    hang_nodes: int = param(41, "stage 5: nodes of the hanging rod (1 m)", ge=3, le=5000)
    record_every: int = param(1000, "stage 2: steps per kernel launch of the conservation runs (and between the "
                              "frame's momentum checks)", ge=1)

    def validate(self):
        scene.check_work(self)


LESSON = Lesson(
    id="springs",
    title="Springs: forces from energy, the variational derivative, energy conservation",
    summary="The notes' spring energy and its gradient, energy and momentum conservation under "
            "symplectic time stepping, discretising the energy instead of the PDE, choosing spring "
            "stiffness from the speed of sound, and a rod hanging under its own weight.",
    config=SpringsConfig,
    stages=narrated_stages(__name__, [
        ("one spring: force = -dW/dx", stages.stage_one_spring),
        ("energy conservation", stages_dynamics.stage_conservation),
        ("discretise the energy, not the PDE", stages.stage_variational),
        ("stiffness from the speed of sound", stages_dynamics.stage_sound),
        ("a hanging rod", stages.stage_hanging),
    ]),
    order=2,
)

__all__ = ["LESSON", "SpringsConfig"]
