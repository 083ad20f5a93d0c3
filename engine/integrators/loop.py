"""The one run loop: advance a state in chunks, watch its energy, hand energies and frames out.

:func:`run` drives any ``advance(chunk, done) -> (steps, kinetic, potential)``; :func:`model_stepper`
makes one for a :class:`engine.model.Model` and an integrator, choosing the fastest path the model's
energies allow (:func:`engine.integrators.explicit.many_steps_plan`: many steps per kernel launch for
small spring-only models), and the rod scene has its own many-steps kernel with the same contract.
Energies are sampled after every ``energy_every``-th step (and the last); a sample that is not
finite or above the monitor's bound stops the run at that step with the monitor's
:class:`engine.errors.BlowUpError`, which carries the energies up to the bad step.
"""
from __future__ import annotations

import shutil
import sys
import time

import numpy as np

from engine import diagnostics
from engine.errors import BlowUpError
from engine.integrators.monitor import Monitor


def model_stepper(model, state, dt: float, integrator, monitor: Monitor, n_total: int, energy_every: int = 1,
                  substeps: int = 1, check_interrupt=None):
    """``advance(chunk, done)`` for ``integrator`` on ``model``: ``chunk`` steps of size dt (each made of
    ``substeps`` steps of dt/substeps), energies after every ``energy_every``-th step and after step
    ``n_total``; a linear-solver failure of an implicit step is reported as the monitor's blow-up."""
    from engine.integrators.explicit import many_steps_plan
    from engine.linalg import SolverError

    h = dt / substeps
    many = None
    if energy_every == 1 and substeps == 1:
        many = many_steps_plan(model, integrator)
    if many is not None:
        def advance(chunk, done):
            if check_interrupt is not None:
                check_interrupt()
            K, W = many(state, dt, chunk, monitor, done)
            return np.arange(done + 1, done + chunk + 1), K, W
        return advance

    begun = []

    def advance(chunk, done):
        if not begun:
            begun.append(True)
            integrator.begin(model, state)
        steps, kin, pot = [], [], []
        for s in range(done + 1, done + chunk + 1):
            if check_interrupt is not None:
                check_interrupt()
            try:
                for _ in range(substeps):
                    integrator.advance(model, state, h)
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


PROGRESS_AFTER_S = 0.5    # a bar is considered once a run has taken this long ...
PROGRESS_EXPECTED_S = 3.0  # ... and is expected to take at least this long in all
PROGRESS_INTERVAL_S = 0.25  # the bar is redrawn at most this often


class Progress:
    """A progress bar on stderr (tqdm: steps done, rate, estimated time left) for one run of the
    loop, shown only when stderr is a terminal and the run, judged from its rate so far, is
    expected to take more than PROGRESS_EXPECTED_S; redrawn at most every PROGRESS_INTERVAL_S and
    cleared when the run ends (also on a blow-up or an interrupt), before anything reports it.
    It only watches the loop: the steps, their order and every result are the same with or
    without it."""

    def __init__(self, label: str, n_steps: int, stream=None):
        self.label, self.n_steps = label, int(n_steps)
        self.stream = sys.stderr if stream is None else stream
        try:
            self.enabled = bool(self.stream.isatty())
        except (AttributeError, ValueError, OSError):  # no stream, or a closed one
            self.enabled = False
        self.t0 = time.perf_counter()
        self.bar = None

    def update(self, done: int) -> None:
        if not self.enabled or done >= self.n_steps:
            return
        if self.bar is None:
            elapsed = time.perf_counter() - self.t0
            if elapsed < PROGRESS_AFTER_S or done <= 0 or elapsed * self.n_steps / done < PROGRESS_EXPECTED_S:
                return
            import tqdm as _tqdm
            _tqdm.tqdm.monitor_interval = 0  # no monitor thread: the bar is redrawn from update() only
            tqdm = _tqdm.tqdm
            size = shutil.get_terminal_size()  # (80, 24) where the terminal does not say (a 0 x 0 pty)
            self.bar = tqdm(total=self.n_steps, initial=0, desc=self.label, unit=" steps", unit_scale=True,
                            file=self.stream, leave=False, ncols=size.columns, nrows=size.lines,
                            mininterval=PROGRESS_INTERVAL_S, miniters=1, smoothing=0.1, delay=1e-9)
            # the rate and the time left count from the run's start (tqdm's clock is time.time)
            self.bar.start_t = self.bar.last_print_t = time.time() - (time.perf_counter() - self.t0)
        self.bar.update(done - self.bar.n)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()  # leave=False: the line is cleared
            self.bar = None


def run(advance, n_steps: int, every: int, on_energies=None, on_frame=None, check_interrupt=None,
        on_draw=None, draw_every: int | None = None, progress: str | None = None):
    """Advance ``n_steps`` steps in chunks of ``every`` (the last may be shorter).

    ``on_frame(step)`` is called at step 0 and after every chunk (to measure the state);
    ``on_energies(steps, kinetic, potential)`` after every chunk with its energy samples. With
    ``on_draw``, the chunks are ``draw_every`` steps (a divisor of ``every``) and ``on_draw(step)``
    is called at step 0 and after each of them (to draw the state more often than it is measured;
    ``on_frame`` still comes at the same steps). On a blow-up the samples up to the bad step are
    handed out, ``on_frame`` and ``on_draw(step, True)`` are called at the bad step (the True: the
    state there must be drawn whatever the frame spacing), and the error is re-raised
    with ``steps``/``kinetic``/``potential`` of the whole run so far. Returns (steps, kinetic,
    potential) of the whole run.

    ``progress``: the run's :class:`Progress` bar, or a label for one on stderr (None: no bar)."""
    bar = Progress(progress, n_steps) if isinstance(progress, str) else progress
    try:
        return _run(advance, n_steps, every, on_energies, on_frame, check_interrupt, on_draw, draw_every, bar)
    finally:
        if bar is not None:
            bar.close()


def _run(advance, n_steps, every, on_energies, on_frame, check_interrupt, on_draw, draw_every, bar):
    all_s, all_k, all_w = [], [], []
    n_steps = int(n_steps)
    every = max(int(every), 1)
    chunk_len = every
    if on_draw is not None and draw_every is not None:
        chunk_len = max(int(draw_every), 1)
        if every % chunk_len:
            raise ValueError(f"draw_every ({chunk_len}) must divide every ({every})")
    if on_draw is not None:
        on_draw(0)
    if on_frame is not None:
        on_frame(0)
    done = 0
    while done < n_steps:
        if check_interrupt is not None:
            check_interrupt()
        chunk = min(chunk_len, n_steps - done)
        try:
            steps, K, W = advance(chunk, done)
        except BlowUpError as exc:
            steps = getattr(exc, "steps", None)
            K = np.asarray(exc.kinetic if exc.kinetic is not None else [])
            W = np.asarray(exc.potential if exc.potential is not None else [])
            if steps is None:
                steps = np.arange(done + 1, done + 1 + len(K))
            if on_energies is not None and len(K):
                on_energies(np.asarray(steps), K, W)
            if on_draw is not None:
                on_draw(exc.step + 1, True)
            if on_frame is not None:
                on_frame(exc.step + 1)
            exc.steps = np.concatenate(all_s + [np.asarray(steps, dtype=np.int64)])
            exc.kinetic = np.concatenate(all_k + [K])
            exc.potential = np.concatenate(all_w + [W])
            raise
        all_s.append(np.asarray(steps, dtype=np.int64))
        all_k.append(np.asarray(K))
        all_w.append(np.asarray(W))
        if on_energies is not None and len(K):
            on_energies(np.asarray(steps), np.asarray(K), np.asarray(W))
        done += chunk
        if bar is not None:
            bar.update(done)
        if on_draw is not None:
            on_draw(done)
        if on_frame is not None and (done % every == 0 or done == n_steps):
            on_frame(done)
    if not all_s:
        return np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros(0)
    return np.concatenate(all_s), np.concatenate(all_k), np.concatenate(all_w)
