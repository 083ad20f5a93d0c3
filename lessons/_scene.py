"""Running an engine Model inside a lesson stage: chunked stepping, per-step energies,
geometry logging every k-th step, blow-up detection at the step, progress.

Lessons call :func:`simulate` instead of writing their own loops, so every scene is
recorded and checked the same way.
"""
from __future__ import annotations

import math

import numpy as np

from engine import diagnostics
from engine.constants import CFL_SAFETY
from engine.linalg import SolverError
from engine import errors
from engine.integrators.explicit import BlowUpError, _blowup_message, stable_dt_estimate

from ._framework import check_interrupt


def simulate(ctx, name: str, model, state, dt: float, n_steps: int, integrator="symplectic-euler",
             every: int | None = None, energy_bound: float | None = None, observe=None, log=None,
             energy_every: int = 1, fixed: bool = False, **integrator_options):
    """Advance ``state`` by ``n_steps`` steps of ``integrator`` (a name, with backward-Euler
    ``integrator_options`` such as solver="cholesky", or an integrator object).

    Unless ``fixed`` (the run is about that integrator), ``--integrator/--solver/--tol/
    --newton-iterations`` replace the run's choice; an explicit integrator chosen that way at a dt
    above CFL_SAFETY (engine.constants, 0.9) x the stable (Gershgorin) estimate takes enough
    sub-steps per step to stay below it, so the run covers the same simulated time with the same
    steps, observations and frames.

    After every ``energy_every``-th step the kinetic and potential energy (J) are computed; a
    total above ``energy_bound`` or non-finite raises BlowUpError naming that step (after
    logging everything up to it and marking it in the recording), with the CFL limit for explicit
    integrators; a linear solve of backward Euler that does not converge is reported the same
    way, naming the solver. Every ``every`` steps (and at step 0) ``log(rec, state)`` draws the
    geometry (if recording) and ``observe(step, state)`` is called (for measurements). Returns
    (steps, kinetic, potential) arrays at the energy samples.
    """
    rec = ctx.rec
    every = int(every or getattr(ctx.cfg, "record_every", 20))
    integ = ctx.integrator(integrator, fixed=fixed, run=name, **integrator_options)
    substeps = 1
    if not fixed and ctx.stepping.overridden and not getattr(integ, "implicit", False):
        dts = stable_dt_estimate(model)
        if dt > CFL_SAFETY * dts:
            substeps = int(math.ceil(dt / (CFL_SAFETY * dts)))
            ctx.progress(f"{name}: {integ.name} needs dt <= {dts:.3g} s (CFL estimate) but the scene steps "
                         f"{dt:.3g} s: taking {substeps} sub-steps per step")
    h = dt / substeps
    rec.run(name)
    steps, kin, pot = [], [], []

    draw = step_drawer(rec, dt, state, log, observe)

    def flush_energies(first):
        if rec.enabled and kin[first:]:
            k = np.asarray(kin[first:])
            w = np.asarray(pot[first:])
            if energy_every == 1:
                rec.energies(k, w, dt, first_step=steps[first] - 1)
            else:  # sparse samples: log them one by one at their own steps
                for s, ks, ws in zip(steps[first:], k, w):
                    rec.energies([ks], [ws], dt, first_step=s - 1)

    def fail(s, E, exc_cls_message):
        flush_energies(flushed)
        draw(s)
        rec.set_time(s, s * dt)
        rec.mark(str(exc_cls_message), level="ERROR")
        raise exc_cls_message

    draw(0)
    flushed = 0
    begin = getattr(integ, "begin", None)
    if begin is not None:
        begin(model, state)
    with ctx.timed(name, n_steps):
        for s in range(1, n_steps + 1):
            check_interrupt()
            try:
                for _ in range(substeps):
                    if hasattr(integ, "advance"):
                        integ.advance(model, state, h)
                    else:
                        integ.step(model, state, h, 1)
            except SolverError as err:  # the integrator left the state at the last good step
                E = diagnostics.kinetic_energy(model, state) + model.potential_energy(state.x)
                fail(s, E, BlowUpError(
                    f"{integ.name} failed at step {s - 1} (t={state.t:.4g} s, total energy {E:.4g} J at the last "
                    f"good step): {err}; likely cause: the linear solver did not converge (raise --tol, allow more "
                    f"iterations, or use --solver cholesky)",
                    step=s - 1, time=state.t, energy=E, dt=dt, dt_stable=math.inf, integrator=integ.name))
            if s % energy_every == 0 or s == n_steps:
                K = diagnostics.kinetic_energy(model, state)
                W = model.potential_energy(state.x)
                steps.append(s)
                kin.append(K)
                pot.append(W)
                E = K + W
                if not math.isfinite(E) or (energy_bound is not None and E > energy_bound):
                    dts = stable_dt_estimate(model)
                    fail(s, E, BlowUpError(_blowup_message(integ.name, s - 1, state.t, E, energy_bound, h, dts),
                                           step=s - 1, time=state.t, energy=E, dt=h, dt_stable=dts,
                                           integrator=integ.name))
            if s % every == 0 or s == n_steps:
                flush_energies(flushed)
                flushed = len(kin)
                draw(s)
    return np.asarray(steps), np.asarray(kin), np.asarray(pot)


def step_drawer(rec, dt: float, state, log=None, observe=None):
    """``draw(step)`` for a run: at simulation step ``step`` (time step * dt) ``log(rec, state)``
    draws the geometry when recording, and ``observe(step, state)`` measures."""
    def draw(step):
        if log is not None and rec.enabled:
            rec.set_time(step, step * dt)
            log(rec, state)
        if observe is not None:
            observe(step, state)
    return draw


def run_chunked(ctx, name: str, dt: float, n_steps: int, every: int, advance, draw):
    """The loop shared by runners that advance many steps per kernel launch.

    ``advance(chunk, done)`` runs ``chunk`` steps and returns per-step (kinetic, potential);
    on a blow-up it raises an engine BlowUpError carrying ``kinetic``/``potential`` up to the
    bad step. ``draw(step)`` logs/observes the state after ``step`` steps (and at 0). The
    energies of every step go to the recorder; a blow-up is recorded up to its step, marked,
    its energies extended to the whole run, and re-raised. Returns (kinetic, potential).
    """
    rec = ctx.rec
    kin, pot = [], []
    draw(0)
    done = 0
    with ctx.timed(name, n_steps):
        while done < n_steps:
            check_interrupt()
            chunk = min(every, n_steps - done)
            try:
                K, W = advance(chunk, done)
            except errors.BlowUpError as exc:  # any engine blow-up: keep energies up to the bad step, mark, re-raise
                rec.energies(exc.kinetic, exc.potential, dt, first_step=done)
                exc.kinetic = np.concatenate(kin + [exc.kinetic])
                exc.potential = np.concatenate(pot + [exc.potential])
                draw(exc.step + 1)
                rec.mark(str(exc), level="ERROR")
                raise
            kin.append(K)
            pot.append(W)
            rec.energies(K, W, dt, first_step=done)
            done += chunk
            draw(done)
    return np.concatenate(kin), np.concatenate(pot)
