"""Lesson ``bending``: dihedral-angle bending energy on triangle meshes.

The notes' discrete energy W = sum_e 1/2 B |e|^2/(36 A_e) theta_e^2 (A_e = |e|(h1+h2)/6, all
factors but theta from the rest mesh): the hinge and its derivatives, the curvature estimate
on a cylinder, the energy against the continuum (and why it lands on a third of it on aligned
regular meshes, and elsewhere on a closed form of the mesh's orientation that Discrete Shells'
weight only multiplies by three), a hanging cloth that folds, and a curved shell that keeps its
shape.

Physics lives in :mod:`engine.energies.bending`, :mod:`engine.mesh`, :mod:`engine.statics`
and the integrators; :mod:`.scene` builds the hinges, sheets and shell and draws them,
:mod:`.stages` (the energy itself: stages 1-3) and :mod:`.stages_structures` (the cloth and the
shell: stages 4 and 5) run them and measure, and ``narrative.md`` narrates each stage.
"""
from dataclasses import dataclass

from engine.energies.bending import VARIANTS
from engine.constants import G
from engine.errors import ParameterError

from .._framework import Lesson, narrated_stages, param
from . import scene, stages, stages_structures


@dataclass
class BendingConfig:
    bending: str = param("notes", "bending energy: the notes' theta^2 weight |e|^2/(36 A_e); 'bridson': the "
                         "energy 4k(1 - cos(theta/2)) with that weight, whose force is Bridson et al.'s "
                         "sin(theta/2) force with its coefficient frozen at the rest mesh (theirs takes it from "
                         "the current shape); or Discrete Shells' weight 3|e|^2/(A1+A2), 3x the notes' "
                         "(used by the cloth, the shell and the 1/R^2 scaling)", choices=VARIANTS)
    radius: float = param(1.0, "cylinder radius R for the curvature and energy measurements (sheets are 1 m wide; "
                               "up to 30 m: beyond, round-off, about 1e-16 (R/h)^2, swamps the chord heights' error "
                               "(h/(2R))^2/6 on the finest sheet and their order-2 fit fails)", "m", ge=0.5, le=30.0)
    finest: int = param(129, "vertices per side of the finest sheet in the refinement studies "
                             "(levels finest, (finest+1)/2, (finest+3)/4)", ge=33, le=257)
    jitter: float = param(0.25, "random displacement of interior vertices for the irregular meshes, "
                                "in units of the local edge length", ge=0.1, le=0.25)
    seed: int = param(1, "random seed for the jittered meshes and the random hinges", ge=0)
    cloth_n: int = param(21, "cloth vertices per side (a 1 m x 1 m right-triangle grid)", ge=11, le=41)
    cloth_E: float = param(1e3, "cloth stretching modulus (Young's modulus times thickness); with --cloth-rho, "
                                "E/(rho g L) must be in [300, 1.02e5] (L = 1 m): a softer cloth buckles in the fall "
                                "until backward Euler's system is indefinite, a stiffer one's statics need ever more "
                                "Newton steps", "N/m", ge=30, le=1e5)
    cloth_rho: float = param(0.1, "cloth areal density", "kg/m^2", ge=0.01, le=1.0)
    cloth_B: float = param(3e-3, "middle bending modulus of the cloth sweep (B/10, B, 10 B); with --cloth-rho, "
                                 "its bending length (B/(rho g))^(1/3) must be in [0.1, 0.31] m, where the sweep's "
                                 "fold order was measured (shorter: the softest cloth folds at the mesh spacing)",
                           "N m",
                           ge=1e-4, le=0.3)
    cloth_gap: float = param(0.5, "distance between the two hooks, as a fraction of the cloth width", ge=0.3, le=0.8)
    shell_E: float = param(1e4, "shell stretching modulus; with --shell-B, E R^2/B must be in [25, 2.5e5] (R = 0.5 m; "
                                "outside it the solves' linear systems lose their accuracy)", "N/m", ge=1.0, le=1e7)
    shell_B: float = param(1.0, "shell bending modulus; with --shell-rho, the weight against the bending "
                                "stiffness rho g R^3/B must be in [0.1, 2] x the default's (heavier: the sag is no "
                                "longer linear; lighter: no push deforms it visibly)", "N m", ge=1e-3, le=1e3)
    shell_rho: float = param(0.005, "shell areal density (its own weight is the small load)", "kg/m^2",
                             ge=1e-4, le=1.0)
    push: float = param(40.0, "the push: this many times the shell's own weight, then released; push x rho g "
                              "R^3/B must be in [10, 40] x the default's rho g R^3/B (weaker: it deforms the shell "
                              "by less than 0.01 R; stronger: the arch snaps through and does not return)",
                        ge=2, le=100)
    static_tol: float = param(1e-5, "Newton residual for static equilibria (net force / largest vertex weight); "
                                    "from 1e-8: the forces of the stiffest allowed cloth carry round-off of about "
                                    "4e-10 of a vertex weight (1e-16 m x E/(rho g h))", ge=1e-8, le=1e-3)
    dt: float = param(0.01, "time step of the backward-Euler runs (from 5 ms: below it backward Euler's damping, "
                            "1/(1 + w^2 dt^2) per step, leaves the softest allowed shell 1.5e-5 R from rest after "
                            "2 s at 2 ms instead of the claimed 1e-6 R)", "s", ge=5e-3, le=0.05)
    record_every: int = param(2, "observe the scene runs every k-th step (the steps between "
                             "observations; the recording draws its own frames, about 200 per run, whatever k is)", ge=1)

    def validate(self):
        if (self.finest - 1) % 4:
            raise ParameterError(f"--finest must be 4k + 1 so that the coarser levels nest (got {self.finest})")
        self._validate_cloth()
        self._validate_shell()

    # The validity box of stages 4 and 5. Their claims depend on the parameters through dimensionless
    # groups; each group's range is one whose ends (and the corners of the box) were run and passed.
    # Outside it a claim fails for a physical reason, named in the message.

    def _validate_cloth(self):
        """Stage 4: stiffness against weight E/(rho g L) in [300, 1.02e5] (L = 1 m: the stretch of the
        cloth under its own weight between 1e-5 and 3e-3) and the middle bending length
        (B/(rho g))^(1/3) in [0.1, 0.31] m (the sweep's B/10 .. 10 B then spans 4.6 cm .. 67 cm)."""
        stiff = self.cloth_E / (self.cloth_rho * G)
        if not CLOTH_STIFFNESS[0] <= stiff <= CLOTH_STIFFNESS[1]:
            why = ("a softer cloth stretches and buckles under the fall's squeeze until backward Euler's Newton "
                   "system is indefinite (measured at E/(rho g L) = 100)" if stiff < CLOTH_STIFFNESS[0] else
                   "a stiffer cloth's static solve needs ever more Newton steps (786 at 1.02e5) and nears its "
                   "round-off floor")
            raise ParameterError(
                f"--cloth-E {self.cloth_E:g} with --cloth-rho {self.cloth_rho:g}: E/(rho g L) = {stiff:.4g} must be "
                f"in [{CLOTH_STIFFNESS[0]:g}, {CLOTH_STIFFNESS[1]:g}]: {why}")
        length = (self.cloth_B / (self.cloth_rho * G)) ** (1.0 / 3.0)
        if not CLOTH_BENDING_LENGTH[0] <= length <= CLOTH_BENDING_LENGTH[1]:
            why = ("the softest cloth of the sweep then folds at the mesh spacing, and the fold order is no longer "
                   "the bending's (measured to fail at 0.065 m)" if length < CLOTH_BENDING_LENGTH[0] else
                   "the stiffest cloth of the sweep then bends over more than twice the 1 m cloth and the sweep "
                   "leaves the range where its fold order was measured")
            raise ParameterError(
                f"--cloth-B {self.cloth_B:g} with --cloth-rho {self.cloth_rho:g}: the bending length "
                f"(B/(rho g))^(1/3) = {length:.3g} m must be in [{CLOTH_BENDING_LENGTH[0]:g}, "
                f"{CLOTH_BENDING_LENGTH[1]:g}] m: {why}")

    def _validate_shell(self):
        """Stage 5: the static problems depend only on the load against the bending stiffness,
        rho g R^3/B (times push for the push), and on the stretching against the bending, E R^2/B."""
        R = scene.SHELL_RADIUS
        membrane = self.shell_E * R * R / self.shell_B
        if not SHELL_MEMBRANE[0] <= membrane <= SHELL_MEMBRANE[1]:
            raise ParameterError(
                f"--shell-E {self.shell_E:g} with --shell-B {self.shell_B:g}: E R^2/B = {membrane:.4g} must be in "
                f"[{SHELL_MEMBRANE[0]:g}, {SHELL_MEMBRANE[1]:g}]: outside it the stretching and bending "
                f"stiffnesses differ so much that the solves' linear systems lose their accuracy (the Cholesky "
                f"residual check fails at 2.5e-5)")
        load = self.shell_rho * G * R ** 3 / self.shell_B
        ref = SHELL_DEFAULT_LOAD
        if not SHELL_LOAD[0] * ref <= load <= SHELL_LOAD[1] * ref:
            raise ParameterError(
                f"--shell-rho {self.shell_rho:g} with --shell-B {self.shell_B:g}: the weight against the bending "
                f"stiffness rho g R^3/B = {load:.4g} must be in [{SHELL_LOAD[0] * ref:.3g}, {SHELL_LOAD[1] * ref:.3g}] "
                f"({SHELL_LOAD[0]:g} to {SHELL_LOAD[1]:g} x the default's): "
                + ("a heavier or softer shell sags nonlinearly: twice the weight no longer gives twice the "
                   "displacement within 3% (2.07 at 3.3x), and the push snaps it through"
                   if load > SHELL_LOAD[1] * ref else "no push up to 100 x its weight then deforms it by 1% of R"))
        pushed = self.push * load / ref
        if not SHELL_PUSH[0] <= pushed <= SHELL_PUSH[1]:
            raise ParameterError(
                f"--push {self.push:g} with --shell-rho {self.shell_rho:g} and --shell-B {self.shell_B:g}: push x rho "
                f"g R^3/B = {pushed:.3g} x the default's weight load must be in [{SHELL_PUSH[0]:g}, {SHELL_PUSH[1]:g}]: "
                + ("a weaker push deforms the shell by less than 1% of R (5.4e-3 R at 5)" if pushed < SHELL_PUSH[0]
                   else "a stronger push snaps the arch through to another equilibrium, from which it does not "
                        "return (measured from 80 at the softest allowed membrane, 100 at the default)"))


CLOTH_STIFFNESS = (300.0, 1.02e5)     # E / (rho g L), L = 1 m (--cloth-E 1e5 at the default rho: 1.019e5)
CLOTH_BENDING_LENGTH = (0.1, 0.31)    # (B_mid / (rho g))^(1/3), m
SHELL_MEMBRANE = (25.0, 2.5e5)        # E R^2 / B
SHELL_LOAD = (0.1, 2.0)               # rho g R^3 / B over the default's
SHELL_PUSH = (10.0, 40.0)             # push x rho g R^3 / B over the default's
SHELL_DEFAULT_LOAD = 0.005 * G * scene.SHELL_RADIUS ** 3 / 1.0


LESSON = Lesson(
    id="bending",
    title="Dihedral bending: hinge, curvature, the one-third ratio, cloth folds, curved shells",
    summary="The notes' dihedral-angle bending energy: its gradient (Bridson's u vectors), the "
            "cylinder curvature estimate, why aligned regular meshes get a third of the continuum energy "
            "(and Discrete Shells' 3x weight, which restores it only where that third holds), a hanging cloth that "
            "folds, and a curved shell that keeps its shape.",
    config=BendingConfig,
    stages=narrated_stages(__name__, [
        ("the hinge", stages.stage_hinge),
        ("curvature on a cylinder", stages.stage_curvature),
        ("energy against the continuum", stages.stage_continuum),
        ("a hanging cloth folds", stages_structures.stage_cloth),
        ("a curved shell keeps its shape", stages_structures.stage_shell),
    ]),
    order=4,
)

__all__ = ["LESSON", "BendingConfig"]
