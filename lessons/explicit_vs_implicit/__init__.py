"""Lesson ``explicit-vs-implicit``: the CFL limit of explicit time stepping, backward Euler's
unconditional stability, what it costs in accuracy and what it buys in speed.

The lecture notes remark that implicit methods pass information across the whole mesh in a
single step, so the CFL limit does not bind them. Physics lives in the engine (:mod:`engine.integrators.explicit`,
:mod:`engine.integrators.implicit`, :mod:`engine.solvers`, :mod:`engine.scenes`,
:mod:`engine.statics`); :mod:`.scene` builds the hanging cloth, draws it and estimates each
stage's time, :mod:`.stages` (stage 1, the CFL limit) and :mod:`.stages_tradeoffs` (stages 2
and 3, what implicit costs and buys) run it and measure, and ``narrative.md`` narrates each stage.
"""
from dataclasses import dataclass

from engine.errors import ParameterError

from .._framework import Lesson, narrated_stages, param
from . import scene, stages, stages_tradeoffs


@dataclass
class ExplicitImplicitConfig:
    n: int = param(16, "stage 1: vertices per side of the hanging cloth (1 m x 1 m, pinned at its two top "
                   "corners)", ge=6, le=40)
    E: float = param(1e3, "stages 1-2: stretching modulus of the cloth (Young's modulus x thickness)", "N/m",
                     gt=0, le=1e7)
    rho: float = param(0.1, "areal density of every cloth in the lesson", "kg/m^2", gt=0, le=100)
    B: float = param(1e-4, "bending modulus of every cloth in the lesson", "N m", ge=0, le=1)
    below: float = param(0.9, "stage 1: dt of the stable explicit run, as a fraction of the true limit", gt=0,
                         lt=1)
    above: float = param(1.1, "stage 1: dt of the unstable explicit run, as a multiple of the true limit", gt=1,
                         le=3)
    explicit_time: float = param(1.0, "stage 1: simulated time the explicit runs must survive", "s", gt=0, le=10)
    implicit_time: float = param(2.0, "stage 1: simulated time of the backward-Euler runs", "s", gt=0, le=20)
    big: float = param(10.0, "stage 1: dt of the first backward-Euler run / the explicit limit", ge=2, le=1000)
    huge: float = param(100.0, "stage 1: dt of the second backward-Euler run / the explicit limit", ge=2,
                        le=10000)
    seed_size: float = param(1e-9, "stage 1: random in-plane displacement that seeds the fastest modes (at least "
                             "1e-12 m: positions of about 1 m are stored to 1e-16 m, and a smaller seed is lost in "
                             "their round-off; at most 1e-4 m, a small linear perturbation of the cloth: a 1 mm seed "
                             "strains its springs by percents and the run at 0.9 x the limit goes unstable)", "m",
                             ge=1e-12, le=1e-4)
    seed: int = param(0, "random seed of that displacement", ge=0)
    mode_n: int = param(7, "stage 2: vertices per side of the small cloth whose modes are excited", ge=4, le=12)
    conv_n: int = param(9, "stage 2: vertices per side of the cloth of the convergence study", ge=4, le=16)
    conv_time: float = param(0.05, "stage 2: simulated time of the convergence runs (falling from rest)", "s",
                             gt=0, le=1)
    speed_n: int = param(32, "stage 3: vertices per side of the cloth of the timing runs", ge=8, le=96)
    E_soft: float = param(10.0, "stage 3: softest stretching modulus of the sweep (at least rho g / 0.1: the "
                          "cloth's weight may stretch it by 10% at most)", "N/m", gt=0, le=1e8)
    E_stiff: float = param(1e5, "stage 3: stiffest stretching modulus of the sweep", "N/m", gt=0, le=1e8)
    E_values: int = param(5, "stage 3: moduli in the sweep (log-spaced)", ge=3, le=9)
    frame_dt: float = param(1 / 60, "stage 3: backward Euler's time step (one video frame)", "s", gt=0, le=0.1)
    frames: int = param(8, "stage 3: frames (of --frame-dt) after the release that every timing run covers", ge=3,
                        le=600)
    record_every: int = param(10, "observe the scene runs every k-th step (the steps between "
                             "observations; the recording draws its own frames, about 200 per run, whatever k is)", ge=1)

    def validate(self):
        if self.huge <= self.big:
            raise ParameterError(f"--huge must be larger than --big (got {self.huge} <= {self.big})")
        if self.E_stiff <= self.E_soft:
            raise ParameterError(f"--E-stiff must be larger than --E-soft (got {self.E_stiff} <= {self.E_soft})")
        for option, E in (("--E", self.E), ("--E-soft", self.E_soft)):  # --E-soft: the sweep's softest cloth
            sag = self.rho * 9.81 / E  # the strain of the 1 m cloth's weight, rho g L / E
            if sag > scene.MAX_WEIGHT_STRAIN:
                raise ParameterError(
                    f"{option} {E:g} with --rho {self.rho:g}: the cloth's own weight would stretch it by rho g L / E = "
                    f"{sag:.2g}, over {scene.MAX_WEIGHT_STRAIN:g}; the lesson's limits and modes are taken about a "
                    f"hanging cloth that barely stretches: use {option} >= "
                    f"{self.rho * 9.81 / scene.MAX_WEIGHT_STRAIN:.3g} N/m")
        scene.check_work(self)


LESSON = Lesson(
    id="explicit-vs-implicit",
    title="Explicit vs implicit time stepping: the CFL limit, backward Euler's stability, damping and cost",
    summary="The hanging cloth under symplectic Euler just below and just above its CFL limit, and under "
            "backward Euler at 10x and 100x that limit; backward Euler's numerical damping 1/(1 + w^2 dt^2) "
            "and first-order accuracy against the explicit methods' orders; wall-clock per simulated second "
            "against stiffness and the crossover modulus.",
    config=ExplicitImplicitConfig,
    stages=narrated_stages(__name__, [
        ("the CFL limit, and stepping far over it", stages.stage_cfl),
        ("what implicit costs: numerical damping and first-order accuracy", stages_tradeoffs.stage_accuracy),
        ("what implicit buys: wall-clock per simulated second against stiffness", stages_tradeoffs.stage_speed),
    ]),
    order=5,
    camera="front",  # every run is a cloth hanging in the x-z plane
)

__all__ = ["LESSON", "ExplicitImplicitConfig"]
