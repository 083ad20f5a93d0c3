"""Running an engine Model (or a scene with its own kernel) inside a lesson stage: one
:class:`engine.integrators.stepper.Stepper`, the engine's run loop in chunks, per-step energies,
geometry drawn at the recorder's frames, blow-up detection at the step, progress.

Lessons call :func:`simulate` instead of writing their own loops, so every run is recorded and
checked the same way.
"""
from __future__ import annotations

import contextlib

from engine.integrators.loop import Progress, Samples, chunks
from engine.integrators.stepper import Stepper
from engine.stability import stable_dt_estimate, substeps_for

from ._framework import check_interrupt


def simulate(ctx, name: str, model, state, dt: float, n_steps: int, integrator="symplectic-euler",
             every: int | None = None, energy_bound: float | None = None, observe=None, log=None,
             energy_every: int = 1, fixed: bool = False, view=None, chosen: bool = False, label: str | None = None,
             **integrator_options):
    """The one lesson run: advance ``state`` by ``n_steps`` steps of ``integrator`` (a name, with
    backward-Euler ``integrator_options`` such as solver="cholesky", or an integrator object) on
    ``model`` (an engine Model, or a scene with its own many-steps kernel such as the rod).

    Unless ``fixed`` (the run is about that integrator) or ``chosen`` (the lesson has already
    applied the options), ``--integrator/--solver/--tol/--newton-iterations`` replace the run's
    choice; an explicit integrator chosen that way at a dt above CFL_SAFETY (engine.constants, 0.9)
    x the stable (Gershgorin) estimate takes enough sub-steps per step to stay below it, so the run
    covers the same simulated time with the same steps, observations and frames. ``chosen``: the
    integrator is a method name the lesson chose, noted as ``label`` (default the name), run by a
    many-steps kernel (one launch per chunk of ``every`` steps, the energies of every step): the
    scene's own, or the engine's for a spring-only Model.

    After every ``energy_every``-th step the kinetic and potential energy (J) are computed; a
    total above ``energy_bound`` or non-finite raises BlowUpError naming that step (after
    logging everything up to it and marking it in the recording), with the CFL limit for explicit
    integrators; a linear solve of backward Euler that does not converge is reported the same
    way, naming the solver. Every ``every`` steps (and at step 0) ``observe(step, state)`` is called
    (for measurements); when recording, ``log(rec, state)`` draws the geometry at the frames the
    recorder asks for (about lessons.app.recorder.FRAMES_PER_RUN per run, whatever ``every``), and
    ``view`` (a RunView) says how the run is shown. Returns (steps, kinetic, potential) arrays at
    the energy samples.
    """
    every = int(every or getattr(ctx.cfg, "record_every", 20))
    substeps = 1
    if chosen:
        ctx.note_integrator(name, label or integrator, fixed)
        stepper = Stepper(model, integrator, many_steps=True)
    else:
        integ = ctx.integrator(integrator, fixed=fixed, run=name, **integrator_options)
        if not fixed and ctx.stepping.overridden and not getattr(integ, "implicit", False):
            dts = stable_dt_estimate(model)
            substeps = substeps_for(dt, dts)
            if substeps > 1:
                ctx.progress(f"{name}: {integ.name} needs dt <= {dts:.3g} s (CFL estimate) but the scene steps "
                             f"{dt:.3g} s: taking {substeps} sub-steps per step")
        stepper = Stepper(model, integ)
    advance = stepper.advancer(state, dt, n_steps, energy_bound, energy_every, substeps, check_interrupt)
    return _recorded_run(ctx, name, dt, n_steps, every, advance, state, log, observe, view)


def _recorded_run(ctx, name: str, dt: float, n_steps: int, every: int, advance, state, log=None, observe=None,
                  view=None):
    """The engine's run loop (engine.integrators.loop.chunks) in chunks of ``every`` steps,
    ``observe(step, state)`` after every chunk (and at 0), the run's energies sent to the recorder as
    they come, the geometry drawn by ``log(rec, state)`` at the frames the recorder wants (the chunks
    are cut finer when it wants more frames than ``every`` gives; the measurements are taken at the
    same steps either way), a progress bar while it runs (on a terminal, for runs of more than a few
    seconds: :func:`progress_bar`), its steps and rate when it ends, and a blow-up drawn at its step,
    marked in the recording and re-raised. Returns (steps, kinetic, potential) of the whole run."""
    rec = ctx.rec
    draw_every = _divisor_at_most(every, rec.frame_spacing(n_steps)) if log is not None and rec.enabled else None
    rec.run(name, view, n_steps=n_steps, dt=dt, draw_every=draw_every)
    samples = Samples()
    run = chunks(advance, n_steps, every, draw_every, check_interrupt, progress=progress_bar(ctx, name, n_steps))
    with ctx.timed(name, n_steps), contextlib.closing(run):
        for c in run:
            if len(c.kinetic):
                samples.add(c.steps, c.kinetic, c.potential)
                if rec.enabled:
                    _record_energies(rec, c.steps, c.kinetic, c.potential, dt)
            if draw_every is not None and (c.error is not None or rec.wants_frame(c.done, c.done * dt)):
                rec.set_time(c.done, c.done * dt)
                log(rec, state)
            if observe is not None and c.frame:
                observe(c.done, state)
            if c.error is not None:
                rec.set_time(c.done, c.done * dt)
                rec.mark(str(c.error), level="ERROR")
                raise c.error
    return samples.arrays()


def _record_energies(rec, steps, K, W, dt: float) -> None:
    if len(steps) == steps[-1] - steps[0] + 1:  # every step: one column
        rec.energies(K, W, dt, first_step=int(steps[0]) - 1)
    else:  # sparse samples: one by one at their own steps
        for s, k, w in zip(steps, K, W):
            rec.energies([k], [w], dt, first_step=int(s) - 1)


def progress_bar(ctx, name: str, n_steps: int) -> Progress | None:
    """The run's progress bar on the stage's progress stream (a terminal only; none with --quiet):
    engine.integrators.loop.Progress, labelled like the stage's progress lines."""
    if getattr(ctx, "_quiet", True):
        return None
    return Progress(f"    {name}", n_steps, stream=getattr(ctx, "_stream", None))


def _divisor_at_most(n: int, limit: int) -> int:
    """The largest divisor of ``n`` that is at most ``limit`` (at least 1)."""
    n = max(int(n), 1)
    best = 1
    for d in range(1, int(n ** 0.5) + 1):
        if n % d == 0:
            for c in (d, n // d):
                if best < c <= limit:
                    best = c
    return best
