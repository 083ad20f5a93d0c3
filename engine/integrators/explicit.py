"""Explicit time integrators: forward Euler, symplectic Euler, velocity Verlet.

The update formulas (E1)-(E3) are written once, in :mod:`engine.integrators.kernels`. Each
integrator has ``step(model, state, dt, n_steps=1)`` and ``begin``/``advance`` for
Python-driven runs (:mod:`engine.integrators.loop`). Which kernels a step launches is decided by a
planner from the model's energies (:func:`one_launch_plan`, :func:`many_steps_plan`): a springs
[+ one hinge energy] model takes one launch per symplectic-Euler step, a small spring-only model
many steps per launch; anything else the generic path (each energy's force kernels, then one
update pass). Each fast path is pinned bitwise to the generic path by tests.

The time-step limit is in :mod:`engine.stability`; blow-ups are reported by
:class:`engine.integrators.monitor.Monitor`.
"""
from __future__ import annotations

import math
import weakref

import numpy as np
import taichi as ti

from engine.constants import MANY_STEPS_BELOW
from engine.fields import scratch_vec3, zero_vec3
from engine.integrators import kernels as K
from engine.integrators.monitor import Monitor
from engine.model import Model, State


# --------------------------------------------------------------------------------------------
# The planner (its plans and dummy arrays are kept here, not on the model)
# --------------------------------------------------------------------------------------------

_work: "weakref.WeakKeyDictionary[Model, dict]" = weakref.WeakKeyDictionary()


def _dummies(model: Model) -> dict:
    d = _work.setdefault(model, {})
    if "dummy_h" not in d:
        d["dummy_h"] = ti.ndarray(dtype=ti.i32, shape=(1, 4))
        d["dummy_s"] = ti.ndarray(dtype=float, shape=1)
        d["dummy_i"] = ti.ndarray(dtype=ti.i32, shape=1)
        d["dummy_w"] = ti.ndarray(dtype=ti.math.vec3, shape=(1, 4))
    return d


_plans: "weakref.WeakKeyDictionary[Model, dict]" = weakref.WeakKeyDictionary()


def _plan(model: Model, what: str, build):
    key = tuple(id(e) for e in model.energies)
    d = _plans.setdefault(model, {})
    cached = d.get(what)
    if cached is None or cached[0] != key:
        cached = d[what] = (key, build(model))
    return cached[1]


def _signature(model: Model) -> tuple:
    """The model's energies as the forms the fast kernels know (each energy's ``force_form``, non-empty
    ones only): ("springs",) for one pair-gather energy, ("springs", "hinges") for one pair-gather
    energy followed by one slot-gather energy, () for anything else."""
    es = [e for e in model.energies if e.n_elements > 0]
    if len(es) != len(model.energies) or not es or es[0].force_form != "pair-gather":
        return ()
    if len(es) == 1:
        return ("springs",)
    if len(es) == 2 and es[1].force_form == "slot-gather" and es[1].n_vertices == model.n:
        return ("springs", "hinges")
    return ()


def _build_one_launch(model: Model):
    sig = _signature(model)
    if not sig:
        return None
    sargs = model.energies[0].force_args()
    if sig == ("springs", "hinges"):
        hargs = (*model.energies[1].force_args(), True)
    else:
        d = _dummies(model)
        hargs = (d["dummy_h"], d["dummy_s"], d["dummy_s"], 0, d["dummy_w"], d["dummy_i"], d["dummy_i"], False)

    def step(state, dt):
        K.one_launch_step(state.x, state.v, model.inv_mass_nd, model.gravity_vec, dt, *sargs, *hargs)
    return step


def one_launch_plan(model: Model):
    """``step(state, dt)``: one symplectic-Euler step in one launch, or None when the model's energies
    are not springs [+ one hinge energy] in that order."""
    return _plan(model, "one_launch", _build_one_launch)


def _build_many_steps(model: Model):
    if _signature(model) != ("springs",) or model.n >= MANY_STEPS_BELOW:
        return None
    s = model.energies[0]

    def steps(state, dt, n_steps, method, monitor: Monitor, step_offset: int):
        return _many_steps(model, s, state, dt, n_steps, method, monitor, step_offset)
    return steps


def many_steps_plan(model: Model, integrator):
    """``run(state, dt, n_steps, monitor, step_offset) -> (kinetic, potential)`` doing all steps of ``integrator`` in
    one launch, or None when the model is not a small spring-only model or the integrator is not explicit."""
    name = getattr(integrator, "name", integrator)
    fn = _plan(model, "many_steps", _build_many_steps) if name in K.EXPLICIT else None
    if fn is None:
        return None
    return lambda state, dt, n_steps, monitor, step_offset: fn(state, dt, n_steps, name, monitor, step_offset)


def _many_steps(model, springs, state, dt, n_steps, method, monitor, step_offset=0):
    dt = float(dt)
    if not (math.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be > 0 and finite (got {dt!r})")
    n_steps = int(n_steps)
    if n_steps < 0 or n_steps >= 2 ** 31:
        raise ValueError(f"n_steps must be in 0..2^31-1 (got {n_steps})")
    if state.n != model.n:
        raise ValueError(f"state has {state.n} vertices, model has {model.n}")
    if n_steps == 0:
        return np.zeros(0), np.zeros(0)
    kin, pot = K.energy_buffers(n_steps)
    done = K.many_steps(state.x, state.v, scratch_vec3(model, "explicit_f"), scratch_vec3(model, "explicit_a"),
                        *springs.force_args(), springs.edges, springs.L, springs.c, springs.m, model.mass_nd,
                        model.inv_mass_nd, model.gravity_vec, dt, n_steps, kin, pot, monitor.bound, K.METHODS[method])
    return K.collect(kin, pot, done, n_steps, state, dt, monitor, step_offset)


def run_many_steps(model: Model, state: State, dt: float, n_steps: int, method: str = "symplectic-euler",
                   energy_bound: float | None = None, step_offset: int = 0):
    """Advance ``state`` by ``n_steps`` steps of ``method`` (forward-euler, symplectic-euler,
    velocity-verlet) of a spring-only model in one kernel launch; returns (kinetic, potential)
    numpy arrays (J), one entry per step (the energies after that step).

    If the total energy after a step is not finite or exceeds ``energy_bound`` (J), the run stops
    there and the monitor's BlowUpError is raised with ``step`` = ``step_offset`` + the index of
    that step and the energies up to and including it in ``.kinetic``/``.potential``."""
    if method not in K.EXPLICIT:
        raise ValueError(f"unknown method {method!r}; valid: {', '.join(K.EXPLICIT)}")
    if _signature(model) != ("springs",):
        raise ValueError(f"run_many_steps needs a spring-only model (exactly one spring energy, plus gravity and "
                         f"pins); this model has energies {[e.name for e in model.energies]}")
    monitor = Monitor(method, dt, energy_bound, model=model)
    return _many_steps(model, model.energies[0], state, dt, n_steps, method, monitor, step_offset)


# --------------------------------------------------------------------------------------------
# Integrators
# --------------------------------------------------------------------------------------------

class ExplicitIntegrator:
    """Base: ``step(model, state, dt, n_steps)`` = ``begin`` once, then ``advance`` n_steps times
    (energies and blow-ups are watched by the run loop, engine.integrators.loop). Work arrays are allocated once per model (here, not on the model), so stepping allocates nothing."""

    name = "explicit"
    implicit = False

    def begin(self, model: Model, state: State) -> None:
        """Prepare caches that depend on the current state (nothing for one-stage methods)."""

    def advance(self, model: Model, state: State, dt: float) -> None:
        raise NotImplementedError

    def step(self, model: Model, state: State, dt: float, n_steps: int = 1) -> None:
        dt = float(dt)
        self.begin(model, state)
        for _ in range(int(n_steps)):
            self.advance(model, state, dt)

    def _elastic_forces(self, model: Model, state: State):
        f = scratch_vec3(model, "explicit_f")
        zero_vec3(f)
        model.add_elastic_forces(state.x, f)
        return f

    def __repr__(self) -> str:
        return f"<integrator {self.name}>"


class ForwardEuler(ExplicitIntegrator):
    name = "forward-euler"

    def advance(self, model, state, dt):
        f = self._elastic_forces(model, state)
        K.update_kernel(state.x, state.v, f, f, model.inv_mass_nd, model.gravity_vec, dt, K.FORWARD_EULER, K.STEP)
        state.t += dt


class SymplecticEuler(ExplicitIntegrator):
    """``fused`` (default): springs [+ one hinge energy] models take one kernel launch per step
    (:func:`one_launch_plan`, bitwise the same result); others the generic path."""

    name = "symplectic-euler"

    def __init__(self, fused: bool = True):
        self.fused = bool(fused)

    def advance(self, model, state, dt):
        if self.fused:
            one_launch = one_launch_plan(model)
            if one_launch is not None:
                one_launch(state, float(dt))
                state.t += dt
                return
        f = self._elastic_forces(model, state)
        K.update_kernel(state.x, state.v, f, f, model.inv_mass_nd, model.gravity_vec, dt, K.SYMPLECTIC_EULER,
                        K.STEP)
        state.t += dt


class VelocityVerlet(ExplicitIntegrator):
    """Kick-drift-kick.  The acceleration a(x) is computed in :meth:`begin` (one extra force
    evaluation per ``step`` call, not per step) and then carried from step to step."""

    name = "velocity-verlet"

    def begin(self, model, state):
        f = self._elastic_forces(model, state)
        K.update_kernel(state.x, state.v, f, scratch_vec3(model, "explicit_a"), model.inv_mass_nd, model.gravity_vec, 0.0,
                        K.VELOCITY_VERLET, K.ACCEL_KICK)

    def advance(self, model, state, dt):
        a = scratch_vec3(model, "explicit_a")
        K.update_kernel(state.x, state.v, a, a, model.inv_mass_nd, model.gravity_vec, dt, K.VELOCITY_VERLET,
                        K.KICK_DRIFT)
        f = self._elastic_forces(model, state)
        K.update_kernel(state.x, state.v, f, a, model.inv_mass_nd, model.gravity_vec, 0.5 * dt, K.VELOCITY_VERLET,
                        K.ACCEL_KICK)
        state.t += dt


def run(model: Model, state: State, dt: float, n_steps: int, integrator="symplectic-euler",
        energy_bound: float | None = None, check_every: int = 1) -> np.ndarray:
    """Advance ``n_steps`` steps, computing the total energy after every ``check_every``-th step
    (and after the last).  Raises the monitor's BlowUpError at the first check where the energy is
    not finite or exceeds ``energy_bound`` (J).  ``check_every=0`` disables checks.

    Returns the total energies at the checks (numpy, one per check)."""
    from engine.integrators import get
    from engine.integrators.loop import model_stepper, run as run_loop

    integ = get(integrator) if isinstance(integrator, str) else integrator
    dt = float(dt)
    n_steps = int(n_steps)
    if check_every <= 0:
        integ.step(model, state, dt, n_steps)
        return np.zeros(0)
    monitor = Monitor(integ.name, dt, energy_bound, model=model)
    advance = model_stepper(model, state, dt, integ, monitor, n_steps, energy_every=int(check_every))
    _, kin, pot = run_loop(advance, n_steps, max(n_steps, 1))
    return kin + pot
