"""Running an engine Model inside a lesson stage: chunked stepping, per-step energies,
geometry logging every k-th step, blow-up detection at the step, progress.

Lessons call :func:`simulate` instead of writing their own loops, so every scene is
recorded and checked the same way.
"""
from __future__ import annotations

import numpy as np

from engine.errors import BlowUpError
from engine.integrators.explicit import run_many_steps
from engine.integrators.monitor import Monitor
from engine.integrators.loop import Progress, model_stepper, run
from engine.stability import stable_dt_estimate, substeps_for

from ._framework import check_interrupt


def simulate(ctx, name: str, model, state, dt: float, n_steps: int, integrator="symplectic-euler",
             every: int | None = None, energy_bound: float | None = None, observe=None, log=None,
             energy_every: int = 1, fixed: bool = False, view=None, **integrator_options):
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
    way, naming the solver. Every ``every`` steps (and at step 0) ``observe(step, state)`` is called
    (for measurements); when recording, ``log(rec, state)`` draws the geometry at the frames the
    recorder asks for (about lessons.recorder.FRAMES_PER_RUN per run, whatever ``every``), and
    ``view`` (an lessons.recorder.RunView) says how the run is shown. Returns (steps, kinetic,
    potential) arrays at the energy samples.
    """
    every = int(every or getattr(ctx.cfg, "record_every", 20))
    integ = ctx.integrator(integrator, fixed=fixed, run=name, **integrator_options)
    substeps = 1
    if not fixed and ctx.stepping.overridden and not getattr(integ, "implicit", False):
        dts = stable_dt_estimate(model)
        substeps = substeps_for(dt, dts)
        if substeps > 1:
            ctx.progress(f"{name}: {integ.name} needs dt <= {dts:.3g} s (CFL estimate) but the scene steps "
                         f"{dt:.3g} s: taking {substeps} sub-steps per step")
    monitor = Monitor(integ.name, dt / substeps, energy_bound, model=model)
    advance = model_stepper(model, state, dt, integ, monitor, n_steps, energy_every, substeps, check_interrupt)
    return recorded_run(ctx, name, dt, n_steps, every, advance, state, log, observe, view)


def simulate_method(ctx, name: str, scene, state, dt: float, n_steps: int, method: str, every: int,
                    energy_bound: float | None = None, observe=None, log=None, fixed: bool = False,
                    label: str | None = None, view=None):
    """Like :func:`simulate` for a ``method`` (a name) the lesson has already chosen, run by a
    many-steps kernel: the engine's for a small spring-only Model, the scene's own ``run`` for the
    rod (engine.scenes.Rod): one launch per chunk of ``every`` steps, the energies of every step.
    The run is noted as ``label`` (default: the method) and ``fixed`` or not. Returns (steps,
    kinetic, potential)."""
    ctx.note_integrator(name, label or method, fixed)
    steps = getattr(scene, "run", None)
    if steps is None:
        def steps(st, h, chunk, meth, bound, step_offset):
            return run_many_steps(scene, st, h, chunk, meth, bound, step_offset=step_offset)

    def advance(chunk, done):
        K, W = steps(state, dt, chunk, method, energy_bound, step_offset=done)
        return np.arange(done + 1, done + chunk + 1), K, W
    return recorded_run(ctx, name, dt, n_steps, every, advance, state, log, observe, view)


def recorded_run(ctx, name: str, dt: float, n_steps: int, every: int, advance, state, log=None, observe=None,
                 view=None):
    """The one lesson run: the engine's run loop (engine.integrators.loop.run) in chunks of ``every``
    steps, ``observe(step, state)`` after every chunk (and at 0), the run's energies sent to the
    recorder as they come, the geometry drawn by ``log(rec, state)`` at the frames the recorder wants
    (the chunks are cut finer when it wants more frames than ``every`` gives; the measurements are
    taken at the same steps either way), a progress bar while it runs (on a terminal, for runs of more
    than a few seconds: :func:`progress_bar`), its steps and rate when it ends, and a blow-up drawn at
    its step, marked in the recording and re-raised."""
    rec = ctx.rec
    draw_every = _divisor_at_most(every, rec.frame_spacing(n_steps)) if log is not None and rec.enabled else None
    rec.run(name, view, n_steps=n_steps, dt=dt, draw_every=draw_every)

    def on_energies(steps, K, W):
        if not rec.enabled:
            return
        if len(steps) == steps[-1] - steps[0] + 1:  # every step: one column
            rec.energies(K, W, dt, first_step=int(steps[0]) - 1)
        else:  # sparse samples: one by one at their own steps
            for s, k, w in zip(steps, K, W):
                rec.energies([k], [w], dt, first_step=int(s) - 1)

    draw = None
    if draw_every is not None:
        def draw(step, last=False):
            if last or rec.wants_frame(step, step * dt):
                rec.set_time(step, step * dt)
                log(rec, state)
    on_frame = (lambda step: observe(step, state)) if observe is not None else None
    with ctx.timed(name, n_steps):
        try:
            return run(advance, n_steps, every, on_energies, on_frame, check_interrupt, draw, draw_every,
                       progress=progress_bar(ctx, name, n_steps))
        except BlowUpError as exc:
            rec.set_time(exc.step + 1, (exc.step + 1) * dt)
            rec.mark(str(exc), level="ERROR")
            raise


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
