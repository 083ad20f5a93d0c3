"""Lesson ``bending``: dihedral-angle bending energy on triangle meshes.

The notes' discrete energy W = sum_e 1/2 B |e|^2/(36 A_e) theta_e^2 (A_e = |e|(h1+h2)/6, all
factors but theta from the rest mesh): the hinge and its derivatives, the curvature estimate
on a cylinder, the energy against the continuum (and why it lands on a third of it on regular
meshes), a hanging cloth that folds, and a curved shell that keeps its shape.

Physics lives in :mod:`engine.energies.bending`, :mod:`engine.mesh`, :mod:`engine.statics`
and the integrators; :mod:`.stages` builds the scenes, runs them and measures, and
``narrative.md`` narrates each stage.
"""
from dataclasses import dataclass

from engine.energies.bending import VARIANTS
from engine.errors import ParameterError

from .._framework import Lesson, narrated_stages, param
from . import stages


@dataclass
class BendingConfig:
    bending: str = param("notes", "bending energy: the notes' theta^2 weight |e|^2/(36 A_e), Bridson's "
                         "sin(theta/2) force with that weight, or Discrete Shells' weight 3|e|^2/(A1+A2) "
                         "(used by the cloth, the shell and the 1/R^2 scaling)", choices=VARIANTS)
    radius: float = param(1.0, "cylinder radius R for the curvature and energy measurements (sheets are 1 m wide)",
                          "m", ge=0.5, le=100.0)
    finest: int = param(129, "vertices per side of the finest sheet in the refinement studies "
                             "(levels finest, (finest+1)/2, (finest+3)/4)", ge=33, le=257)
    jitter: float = param(0.25, "random displacement of interior vertices for the irregular meshes, "
                                "in units of the local edge length", ge=0.1, le=0.25)
    seed: int = param(1, "random seed for the jittered meshes and the random hinges", ge=0)
    cloth_n: int = param(21, "cloth vertices per side (a 1 m x 1 m right-triangle grid)", ge=11, le=41)
    cloth_E: float = param(1e3, "cloth stretching modulus (Young's modulus times thickness)", "N/m", gt=0)
    cloth_rho: float = param(0.1, "cloth areal density", "kg/m^2", gt=0)
    cloth_B: float = param(3e-3, "middle bending modulus of the cloth sweep (B/10, B, 10 B)", "N m", gt=0)
    cloth_gap: float = param(0.5, "distance between the two hooks, as a fraction of the cloth width", ge=0.3, le=0.8)
    shell_E: float = param(1e4, "shell stretching modulus", "N/m", gt=0)
    shell_B: float = param(1.0, "shell bending modulus", "N m", gt=0)
    shell_rho: float = param(0.005, "shell areal density (its own weight is the small load)", "kg/m^2", gt=0)
    push: float = param(40.0, "the push: this many times the shell's own weight, then released", ge=2, le=100)
    static_tol: float = param(1e-5, "Newton residual for static equilibria (net force / largest vertex weight)",
                              gt=0, le=1e-3)
    dt: float = param(0.01, "time step of the backward-Euler runs", "s", gt=0, le=0.05)
    record_every: int = param(2, "observe the scene runs every k-th step (the steps between "
                             "observations; the recording draws its own frames, about 200 per run, whatever k is)", ge=1)

    def validate(self):
        if (self.finest - 1) % 4:
            raise ParameterError(f"--finest must be 4k + 1 so that the coarser levels nest (got {self.finest})")


LESSON = Lesson(
    id="bending",
    title="Dihedral bending: hinge, curvature, the one-third ratio, cloth folds, curved shells",
    summary="The notes' dihedral-angle bending energy: its gradient (Bridson's u vectors), the "
            "cylinder curvature estimate, why regular meshes get a third of the continuum energy "
            "(and Discrete Shells' fix), a hanging cloth that folds, and a curved shell that keeps its shape.",
    config=BendingConfig,
    stages=narrated_stages(__name__, [
        ("the hinge", stages.stage_hinge),
        ("curvature on a cylinder", stages.stage_curvature),
        ("energy against the continuum", stages.stage_continuum),
        ("a hanging cloth folds", stages.stage_cloth),
        ("a curved shell keeps its shape", stages.stage_shell),
    ]),
    order=4,
)

__all__ = ["LESSON", "BendingConfig"]
