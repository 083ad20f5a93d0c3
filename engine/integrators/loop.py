"""The one run loop: advance a state in chunks and hand each chunk's energies out as it comes.

:func:`chunks` drives any ``advance(chunk, done) -> (steps, kinetic, potential)`` (a
:meth:`engine.integrators.stepper.Stepper.advancer`, or a scene's own) and yields one
:class:`Chunk` after every chunk: the caller measures, draws and records from it; nothing in
here calls back up. Energies are sampled by ``advance`` (every step, or every k-th); a sample
that is not finite or above the monitor's bound makes ``advance`` raise the monitor's
:class:`engine.errors.BlowUpError` at that step, which ends the run with a last chunk that
carries it (and the energies up to the bad step). :func:`run` collects a whole run.
"""
from __future__ import annotations

import shutil
import sys
import time
from dataclasses import dataclass

import numpy as np

from engine.errors import BlowUpError


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


class Samples:
    """A run's energy samples, gathered chunk by chunk: :meth:`add` a chunk's, :meth:`arrays` for
    the whole run's (steps, kinetic, potential)."""

    def __init__(self):
        self.steps, self.kinetic, self.potential = [np.zeros(0, dtype=np.int64)], [np.zeros(0)], [np.zeros(0)]

    def add(self, steps, kinetic, potential) -> None:
        self.steps.append(np.asarray(steps, dtype=np.int64))
        self.kinetic.append(np.asarray(kinetic))
        self.potential.append(np.asarray(potential))

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return np.concatenate(self.steps), np.concatenate(self.kinetic), np.concatenate(self.potential)


@dataclass
class Chunk:
    """What one chunk of a run did. ``done``: steps done after it (0 for the first, empty chunk,
    which stands for the initial state); ``steps``/``kinetic``/``potential``: its energy samples;
    ``frame``: whether ``done`` is a multiple of ``every`` (or the last step), where a run measures
    its state; ``error``: the BlowUpError that ended the run in this chunk (``done`` is then the bad
    step, and the error carries the whole run's samples up to it), else None."""
    done: int
    steps: np.ndarray
    kinetic: np.ndarray
    potential: np.ndarray
    frame: bool
    error: BlowUpError | None = None


def chunks(advance, n_steps: int, every: int, draw_every: int | None = None, check_interrupt=None,
           progress: "Progress | str | None" = None):
    """Yield a :class:`Chunk` for step 0, then one after each chunk of ``draw_every`` steps
    (default ``every``; it must divide ``every``) until ``n_steps`` are done or a step blows up
    (then the last chunk carries the error, and the generator ends: the caller re-raises it).
    ``check_interrupt()`` is called before each chunk. ``progress``: the run's :class:`Progress`
    bar, or a label for one on stderr (None: no bar); it is closed when the run ends (use
    ``contextlib.closing`` where the caller may stop early, so that it is closed at once)."""
    bar = Progress(progress, n_steps) if isinstance(progress, str) else progress
    try:
        yield from _chunks(advance, int(n_steps), max(int(every), 1), draw_every, check_interrupt, bar)
    finally:
        if bar is not None:
            bar.close()


def _chunks(advance, n_steps, every, draw_every, check_interrupt, bar):
    chunk_len = every
    if draw_every is not None:
        chunk_len = max(int(draw_every), 1)
        if every % chunk_len:
            raise ValueError(f"draw_every ({chunk_len}) must divide every ({every})")
    empty = np.zeros(0)
    yield Chunk(0, np.zeros(0, dtype=np.int64), empty, empty, True)
    run = Samples()
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
            steps = np.asarray(steps, dtype=np.int64)
            run.add(steps, K, W)
            exc.steps, exc.kinetic, exc.potential = run.arrays()
            if bar is not None:
                bar.close()  # cleared before anything reports the blow-up
            yield Chunk(exc.step + 1, steps, K, W, True, exc)
            return
        steps, K, W = np.asarray(steps, dtype=np.int64), np.asarray(K), np.asarray(W)
        run.add(steps, K, W)
        done += chunk
        if bar is not None:
            bar.update(done)
        yield Chunk(done, steps, K, W, done % every == 0 or done == n_steps)


def run(advance, n_steps: int, every: int, check_interrupt=None, progress: "Progress | str | None" = None):
    """The whole run of :func:`chunks`: (steps, kinetic, potential) of all its energy samples; a
    blow-up is raised with the samples up to the bad step in ``steps``/``kinetic``/``potential``."""
    samples = Samples()
    for c in chunks(advance, n_steps, every, None, check_interrupt, progress):
        if c.error is not None:
            raise c.error
        samples.add(c.steps, c.kinetic, c.potential)
    return samples.arrays()
