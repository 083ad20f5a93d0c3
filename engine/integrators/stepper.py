"""The one stepping path: :class:`Stepper` ``(model, integrator)``.

A stepper decides once, from the model's energies and the integrator, which kernels a step
launches, and it owns everything a step needs besides the state: the work arrays, the fast
step's plan and, for an implicit integrator, its own linear solver (:meth:`LinearSolver.fresh`:
the integrator's kind and options, with this stepper's pattern and symbolic analysis) and the
statistics of its steps (:attr:`Stepper.last_info`, :attr:`Stepper.stats`). The direction is one
way, as in Warp's ``integrator.simulate(model, state_in, state_out, dt)``: the stepper hands an
integrator a :class:`StepContext` (model, work arrays, dampers, solver) and the state, and the
integrator never reaches back; the fast paths are the stepper's own
(engine.integrators.explicit.FastStep, planned for one method). Integrators keep nothing between
steps: one instance may serve any number of steppers. Nothing is kept per model anywhere else.
Its ``path`` says what it planned:

- ``"scene"``: a scene with its own many-steps kernel (``scene.run``, e.g. engine.scenes.Rod), one
  launch per chunk; the integrator is then a method name the scene knows;
- ``"one-launch"``: springs [+ one hinge energy] under symplectic Euler or velocity Verlet, one
  launch per step (or one launch for many: engine.integrators.explicit.cloth_stepper);
- ``"two-pass"``: one membrane (a "corner-gather" energy) under symplectic Euler or velocity
  Verlet: its per-triangle force kernel, then gather + update, both launched bound
  (engine.integrators.explicit.corner_stepper);
- ``"generic"``: each energy's force kernels, then one update pass;
- ``"implicit"``: backward Euler's Newton step (engine.integrators.implicit) with the stepper's solver
  (and, for springs [+ one hinge energy], the model's forces in one launch:
  engine.integrators.explicit.cloth_forces).

A small spring-only model under an explicit method may also take ``"many-steps"`` chunks (every
step's energies in one launch, engine.integrators.explicit.many_steps) when a run samples the
energy after every step: :attr:`Stepper.many_steps` says whether it does.

``step(state, dt, n_steps)`` steps without watching; :meth:`advancer` gives the
``advance(chunk, done)`` that the run loop (:mod:`engine.integrators.loop`) drives, with the
energies and blow-up checks; :func:`run` is both for one call.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from engine import diagnostics
from engine.constants import MANY_STEPS_BELOW
from engine.fields import WorkArrays
from engine.integrators import loop
from engine.integrators.explicit import CLOTH_METHODS, cloth_forces, cloth_stepper, corner_stepper, many_steps, signature
from engine.integrators.monitor import Monitor
from engine.integrators.registry import EXPLICIT, get
from engine.solvers import SolverError


@dataclass(frozen=True)
class StepContext:
    """What an integrator is handed for a step: the model, the stepper's work arrays, whether the model
    has velocity-dependent forces, (implicit) the stepper's own linear solver, and ``forces(x, f)``, the
    model's forces as the stepper planned them (:meth:`engine.model.Model.forces`, or the same bits in
    one launch: engine.integrators.explicit.cloth_forces)."""
    model: object
    work: WorkArrays
    dampers: bool
    solver: object = None
    forces: object = None

    def __post_init__(self):
        if self.forces is None:
            object.__setattr__(self, "forces", self.model.forces)


@dataclass
class StepStats:
    """A stepper's implicit steps so far: steps, linear solves (refused exact-Hessian ones included)
    and their iterations."""
    steps: int = 0
    solves: int = 0
    linear_iterations: int = 0


class Stepper:
    """Steps one model (or scene) with one integrator; see the module docstring.

    ``integrator``: a registered name or an integrator object (for a scene with its own ``run``,
    a method name it knows). ``many_steps``: None (default) takes the many-steps kernel where it
    pays (a spring-only model under MANY_STEPS_BELOW vertices, explicit method, energies every
    step); True always for a spring-only model and an explicit method (ValueError otherwise);
    False never."""

    def __init__(self, model, integrator="symplectic-euler", many_steps: bool | None = None):
        self.model = model
        self.scene_run = getattr(model, "run", None)
        if self.scene_run is not None:
            self.integrator = integrator if isinstance(integrator, str) else integrator.name
            self.name = self.integrator
        else:
            self.integrator = get(integrator) if isinstance(integrator, str) else integrator
            self.name = self.integrator.name
        self.implicit = bool(getattr(self.integrator, "implicit", False))
        self.work = WorkArrays(model.n)
        self._fast_work: dict = {}  # the fast step's arrays (kept if the plan is made again)
        self._requested = many_steps
        self._key = None
        # an implicit integrator's solver kind and options, with this stepper's own set-up (pattern, analysis)
        self.solver = self.integrator.solver.fresh() if self.implicit and self.scene_run is None else None
        self.last_info = None         # what the last implicit step did (engine.integrators.implicit.StepInfo)
        self.stats = StepStats()
        self._plan()

    # -- the plan --------------------------------------------------------------------------------
    def _energies_key(self) -> tuple:
        # the energies and their coefficient arrays (SpringEnergy.set_coefficients replaces c_np)
        return tuple((id(e), id(getattr(e, "c_np", None))) for e in getattr(self.model, "energies", ()))

    def _plan(self) -> None:
        self._key = self._energies_key()
        self.fast = None  # the planned fast step (a FastStep of cloth_stepper or corner_stepper) or None
        self.many_steps = False
        self.dampers = bool(getattr(self.model, "dampers", ()))   # velocity-dependent forces: the generic path
        if self.scene_run is not None:
            self.path = "scene"
            self.context = None
            return
        if self.implicit:
            self.path = "implicit"
            self.context = StepContext(self.model, self.work, self.dampers, self.solver,
                                       cloth_forces(self.model, work=self._fast_work))
            return
        self.context = StepContext(self.model, self.work, self.dampers, self.solver)
        spring_only = signature(self.model) == ("springs",) and self.name in EXPLICIT
        if self._requested is True and not spring_only:
            raise ValueError(f"the many-steps kernel needs a spring-only model (exactly one spring energy, plus "
                             f"gravity and pins) and an explicit method ({', '.join(EXPLICIT)}); this is "
                             f"{self.name} on energies {[e.name for e in self.model.energies]}")
        self.many_steps = spring_only and (self._requested is True or
                                           (self._requested is None and self.model.n < MANY_STEPS_BELOW))
        self.path = "generic"
        if getattr(self.integrator, "fused", False) and self.name in CLOTH_METHODS and not self.dampers:
            for path, plan in (("one-launch", cloth_stepper), ("two-pass", corner_stepper)):
                self.fast = plan(self.model, self.name, work=self._fast_work)
                if self.fast is not None:
                    self.path = path
                    break

    def _check_plan(self) -> None:
        if self.scene_run is None and self._energies_key() != self._key:
            self._plan()  # the model's coefficients were replaced since: planned again

    # -- stepping --------------------------------------------------------------------------------
    def begin(self, state) -> None:
        """What the method prepares from the current state before its steps (Verlet's acceleration)."""
        self._check_plan()
        if self.fast is not None:
            self.fast.begin(state)
        else:
            self.integrator.begin(self.context, state)

    def advance(self, state, dt: float) -> None:
        """One step of ``dt`` (after :meth:`begin`); an implicit step's StepInfo is kept in
        :attr:`last_info` and counted in :attr:`stats`. The plan is checked first (~1 us): the fast
        step's plan and an implicit step's one-launch forces copy the springs' c/L."""
        self._check_plan()
        if self.fast is not None:
            self.fast.step(state, dt)
            state.t += dt
            return
        info = self.integrator.advance(self.context, state, dt)
        if info is not None:
            self.last_info = info
            self.stats.steps += 1
            self.stats.solves += info.solves
            self.stats.linear_iterations += info.all_linear_iterations

    def step(self, state, dt: float, n_steps: int = 1) -> None:
        """``n_steps`` steps of ``dt``, nothing watched: :meth:`begin`, then the steps (all in one
        launch of the cloth kernel on the one-launch path; ``state.t`` advances step by step
        either way, the same float sums)."""
        dt, n_steps = float(dt), int(n_steps)
        if self.scene_run is not None:
            self.scene_run(state, dt, n_steps, self.name)
            return
        self.begin(state)
        if self.fast is not None and n_steps > 0:
            self.fast.step(state, dt, n_steps)
            for _ in range(n_steps):
                state.t += dt
            return
        for _ in range(n_steps):
            self.advance(state, dt)

    def energies(self, state, dt: float, n_steps: int, energy_bound: float | None = None,
                 step_offset: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """``n_steps`` steps of ``dt``, returning (kinetic, potential) after every step (J): in one launch
        on the scene and many-steps paths, else step by step. A step whose total energy is not finite
        or exceeds ``energy_bound`` raises the monitor's BlowUpError naming that step (``step_offset`` +
        its index, counted from 1) with the energies up to it; the state stays at that step."""
        n_steps = int(n_steps)
        if n_steps < 0:
            raise ValueError(f"n_steps must be >= 0 (got {n_steps})")
        _, kin, pot = self.advancer(state, dt, n_steps, energy_bound)(n_steps, step_offset)   # one chunk: every step
        return kin, pot

    # -- stepping inside the run loop ------------------------------------------------------------
    def advancer(self, state, dt: float, n_total: int, energy_bound: float | None = None, energy_every: int = 1,
                 substeps: int = 1, check_interrupt=None):
        """``advance(chunk, done) -> (steps, kinetic, potential)`` for :func:`engine.integrators.loop.chunks`:
        ``chunk`` steps of ``dt`` (each made of ``substeps`` steps of dt/substeps), the energies after
        every ``energy_every``-th step and after step ``n_total``. A total energy that is not finite
        or above ``energy_bound`` (J) raises the monitor's BlowUpError at its step; so does a linear
        solve of an implicit step that fails (naming the solver). The scene and many-steps paths take
        one launch per chunk and sample every step."""
        dt, h = float(dt), float(dt) / substeps
        if self.scene_run is not None:
            def advance(chunk, done):
                K, W = self.scene_run(state, dt, chunk, self.name, energy_bound, step_offset=done)
                return np.arange(done + 1, done + chunk + 1), K, W
            return advance
        self._check_plan()
        monitor = Monitor(self.name, h, energy_bound, model=self.model)
        if self.many_steps and energy_every == 1 and substeps == 1:
            def advance(chunk, done):
                if check_interrupt is not None:
                    check_interrupt()
                K, W = many_steps(self.model, state, dt, chunk, self.name, monitor, self.work, done)
                return np.arange(done + 1, done + chunk + 1), K, W
            return advance

        begun = []
        model = self.model

        def advance(chunk, done):
            if not begun:
                begun.append(True)
                self.begin(state)
            steps, kin, pot = [], [], []
            for s in range(done + 1, done + chunk + 1):
                if check_interrupt is not None:
                    check_interrupt()
                try:
                    for _ in range(substeps):
                        self.advance(state, h)
                except SolverError as err:  # the integrator left the state at the last good step
                    E = diagnostics.total_energy(model, state)
                    exc = monitor.solver_failure(s - 1, state.t, E, err)
                    exc.steps, exc.kinetic, exc.potential = np.asarray(steps), np.asarray(kin), np.asarray(pot)
                    raise exc from None
                if s % energy_every == 0 or s == n_total:
                    K = diagnostics.kinetic_energy(model, state)
                    W = model.potential_energy(state.x)
                    steps.append(s)
                    kin.append(K)
                    pot.append(W)
                    if monitor.exceeded(K + W):
                        exc = monitor.blow_up(s - 1, state.t, K + W)
                        exc.steps, exc.kinetic, exc.potential = np.asarray(steps), np.asarray(kin), np.asarray(pot)
                        raise exc
            return np.asarray(steps, dtype=np.int64), np.asarray(kin), np.asarray(pot)
        return advance

    def __repr__(self) -> str:
        return f"<Stepper {self.name} path={self.path}{' many-steps' if self.many_steps else ''} n={self.model.n}>"


def run(model, state, dt: float, n_steps: int, integrator="symplectic-euler", energy_bound: float | None = None,
        check_every: int = 1) -> np.ndarray:
    """Advance ``n_steps`` steps, computing the total energy after every ``check_every``-th step
    (and after the last).  Raises the monitor's BlowUpError at the first check where the energy is
    not finite or exceeds ``energy_bound`` (J).  ``check_every=0`` disables checks.

    Returns the total energies at the checks (numpy, one per check)."""
    stepper = Stepper(model, integrator)
    n_steps = int(n_steps)
    if check_every <= 0:
        stepper.step(state, dt, n_steps)
        return np.zeros(0)
    advance = stepper.advancer(state, dt, n_steps, energy_bound, energy_every=int(check_every))
    _, kin, pot = loop.run(advance, n_steps, max(n_steps, 1))
    return kin + pot
