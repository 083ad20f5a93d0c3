"""Lesson ``rod-waves``: the 1D elastic rod, its sound waves and the CFL limit.

Physics lives in the engine (the rod is :class:`engine.scenes.Rod`, a chain Model); :mod:`.scene` builds
the scenes, draws their runs and estimates each stage's cost, :mod:`.stages` runs them and measures, and
``narrative.md`` narrates each stage.
"""
from __future__ import annotations

from dataclasses import dataclass

from engine.errors import ParameterError

from .._framework import Lesson, narrated_stages, param
from . import scene, stages
from .scene import simulate  # the rod's chunked runner (tests/lessons/test_blowups.py drives it directly)


@dataclass
class RodWavesConfig:
    E: float = param(1.0, "Young's modulus of the rod (1D: force per unit strain)", "N", ge=1e-6, le=1e12)
    rho: float = param(1.0, "linear density of the rod", "kg/m", ge=1e-6, le=1e6)
    nodes: int = param(1001, "nodes on the rod of rest length 1 m (h = 1/(nodes-1))", ge=101, le=200001)
    cfl: float = param(0.5, "CFL number nu = c dt / h of stage 2's left-moving pulse and d'Alembert runs (the runs "
                       "that do not sweep it); at most 1, symplectic Euler's stability limit on the rod, which stage 3 "
                       "crosses on purpose", gt=0, le=1)
    width: float = param(None, "Gaussian pulse width sigma, in node spacings (default: 1 cm, i.e. 10 spacings at the "
                         "default 1001 nodes and more on finer grids, where a fixed count of spacings would disperse "
                         "over the more spacings it travels; at least 10 spacings on grids coarser than 1 mm; under "
                         "about 5 spacings the grid slows the pulse measurably and the speed claims fail, saying so)",
                         ge=2, le=100, optional=True)
    amplitude: float = param(1e-3, "pulse amplitude (displacement; at least 1e-9 m: positions are stored as "
                             "p + u, which resolves u only to about 1e-16 m on the 1 m rod)", "m", ge=1e-9, le=0.01)
    cfl_steps: int = param(10_000, "steps a run must survive to count as stable in stage 3", ge=100, le=10**7)
    record_every: int = param(20, "observe the scene runs every k-th step (the steps between "
                             "observations; the recording draws its own frames, about 200 per run, whatever k is; "
                             f"stage 2's speed fits need at least {scene.MIN_FIT_POINTS} observations while "
                             "the pulse crosses the middle of the rod)", ge=1)

    def validate(self):
        h = 1.0 / (self.nodes - 1)
        sigma = scene.pulse_width(self, h)
        if sigma > 0.05 and self.width is not None:
            raise ParameterError(
                f"--width must be <= {0.05 / h:.3g} node spacings for --nodes {self.nodes} "
                f"(the pulse must be narrow next to the 1 m rod; got {self.width})")
        if sigma > 0.05:
            raise ParameterError(
                f"--nodes {self.nodes}: the default pulse width, 10 node spacings = {sigma:g} m, is more than 0.05 m "
                f"(the pulse must be narrow next to the 1 m rod); use --nodes >= 201 or --width <= {0.05 / h:.3g}")
        scene.check_work(self)  # first: a tiny --cfl would make the fit windows below astronomically long
        fewest = scene.fewest_fit_points(self)
        if fewest < scene.MIN_FIT_POINTS:
            raise ParameterError(
                f"--record-every {self.record_every} leaves {fewest} observation(s) in a speed fit of stage 2 "
                f"(the pulse at nu = 1 crosses the middle of the rod in {scene.fit_window_steps(self)} steps at "
                f"--nodes {self.nodes}); a fit needs at least {scene.MIN_FIT_POINTS}: use --record-every <= "
                f"{scene.largest_record_every(self)}")


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
