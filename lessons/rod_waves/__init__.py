"""Lesson ``rod-waves``: the 1D elastic rod, its sound waves and the CFL limit.

Physics lives in the engine (the rod is :class:`engine.scenes.Rod`, a chain Model); :mod:`.stages` builds the scenes, runs them and measures,
and ``narrative.md`` narrates each stage.
"""
from __future__ import annotations

from dataclasses import dataclass

from engine.errors import ParameterError

from .._framework import Lesson, narrated_stages, param
from . import stages
from .stages import simulate  # the rod's chunked runner (tests/test_blowups.py drives it directly)


@dataclass
class RodWavesConfig:
    E: float = param(1.0, "Young's modulus of the rod (1D: force per unit strain)", "N", ge=1e-6, le=1e12)
    rho: float = param(1.0, "linear density of the rod", "kg/m", ge=1e-6, le=1e6)
    nodes: int = param(1001, "nodes on the rod of rest length 1 m (h = 1/(nodes-1))", ge=101, le=200001)
    cfl: float = param(0.5, "CFL number nu = c dt / h for runs that do not sweep it", gt=0, le=1000)
    width: float = param(10.0, "Gaussian pulse width sigma, in node spacings", ge=2, le=100)
    amplitude: float = param(1e-3, "pulse amplitude (displacement)", "m", gt=0, le=0.01)
    cfl_steps: int = param(10_000, "steps a run must survive to count as stable in stage 3", ge=100, le=10**7)
    record_every: int = param(20, "observe the scene runs every k-th step (the steps between "
                             "observations; the recording draws its own frames, about 200 per run, whatever k is)", ge=1)

    def validate(self):
        h = 1.0 / (self.nodes - 1)
        if self.width * h > 0.05:
            raise ParameterError(
                f"--width must be <= {0.05 / h:.3g} node spacings for --nodes {self.nodes} "
                f"(the pulse must be narrow next to the 1 m rod; got {self.width})")


LESSON = Lesson(
    id="rod-waves",
    title="1D rod: energy, sound waves, the CFL limit, impedance",
    summary="A rod of springs: forces from its energy, the speed of sound sqrt(E/rho), "
            "explicit stability (CFL) against implicit damping, and waves meeting changes of material.",
    config=RodWavesConfig,
    stages=narrated_stages(__name__, [
        ("energy and force", stages.stage_energy),
        ("sound waves", stages.stage_sound),
        ("the CFL limit", stages.stage_cfl),
        ("a heterogeneous rod", stages.stage_heterogeneous),
    ]),
    order=1,
)

__all__ = ["LESSON", "RodWavesConfig", "simulate"]
