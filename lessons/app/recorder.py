"""Rerun recordings of lesson runs.

One :class:`Recorder` per lesson run writes one ``.rrd`` file through its own
``rr.RecordingStream`` (never the global stream). The recording is collected in memory and
written by :meth:`Recorder.close` into a temporary file beside the target (created when the
recorder is made, as the proof that the file can be written there), which is then renamed onto
the target (:mod:`lessons.app.outfile`): a crash, a kill or a full disk never leaves a truncated file
under the final name, and never destroys the earlier one. A run that did not complete is written
to ``<stem>.partial.rrd`` and says so in the file (the ``run`` recording property).

The recorder also plans what a student sees when the file is opened: the layout is made by
:mod:`lessons.app.blueprint`, the geometry and the energy plots are drawn by
:mod:`lessons.app.recorder_geometry` and :mod:`lessons.app.recorder_energies` (parts of
:class:`Recorder`).

Timelines:
    ``progress``  per mille of the run's span (its planned duration unless the stage gives one):
                  every run of every stage plays over 0..1000, so any tab shows its own runs at
                  the same point of their runs and none has to be found on a long timeline;
    ``sim_time``  simulated seconds since the start of the run (runs overlap);
    ``step``      the time step of the run.

Entity layout (``S`` = ``stage<N>``, ``R`` = run name inside the stage):
    /S/narrative, /S/results, /S/<doc>   markdown TextDocuments, static
    /S/R/...                             the run's geometry (rod, springs, mesh, labels)
    /S/R/energy/{kinetic,potential,total}   Scalars (J), at most ENERGY_SAMPLES per run: the
                                         lowest and highest sample of each bin of steps, so a
                                         curve that oscillates faster than a bin is drawn as
                                         its envelope, not aliased
    /S/R/energy_change/relative          (E - E_1)/|E_1| of the total, for runs about
                                         conservation (``energy="drift"``)
    /S/R/events                          TextLog (blow-ups)

:class:`NullRecorder` (lessons.app.recorder_null) has the same methods and does nothing;
``enabled`` is False so callers can skip building colours and arrays altogether. A recording is
read back by :func:`summarize` and :func:`run_status` (lessons.app.recorder_read).
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from ..views import CAMERAS, RunView
from .blueprint import ENERGY_KEY, PROGRESS_TICKS, RunPlan, StagePlan, lesson_blueprint
from .outfile import OutputFile, OutputWriteError
from .recorder_energies import RecorderEnergies
from .recorder_geometry import RecorderGeometry
from .recorder_null import NullRecorder
from .recorder_read import run_status, summarize

__all__ = ["Recorder", "NullRecorder", "check_writable", "summarize", "run_status", "OutputWriteError",
           "FRAMES_PER_RUN"]

FRAMES_PER_RUN = 200        # geometry frames a run draws at most (tens per period of a wave)
MIN_FRAMES_PER_RUN = 20     # ... and at least, when its span allows
RUN_GEOMETRY_BYTES = 900_000  # a run's geometry budget (bytes of arrays logged), which sets its frames
LIVE_PORT = 9876            # the port of the viewer a live recorder spawns (Rerun's default)
KEYS_DOC = "colour_keys"    # the stage's document listing every run's colour scale


def check_writable(path: str | os.PathLike) -> Path:
    """Return the resolved path if a file can be created there; raise OSError otherwise.

    Creates missing parent directories (that is what a user asking for
    ``--record out/run.rrd`` wants) but writes nothing else. The checks are those of
    :meth:`lessons.app.outfile.OutputFile.check` (a regular file or a new name; a name that fits).
    """
    out = OutputFile(path)
    out.check()
    _, missing = out._existing_ancestor()
    try:
        for d in reversed(missing):
            os.mkdir(d)
    except OSError:
        for d in missing:
            try:
                d.rmdir()
            except OSError:
                pass
        raise
    return out.path


# ------------------------------------------------------------------------------ recorders

class Recorder(RecorderGeometry, RecorderEnergies, NullRecorder):
    """Writes one lesson's recording to ``path`` (atomically, on :meth:`close`).

    ``title`` names the recording in the viewer; ``camera`` is the default camera of the lesson's
    runs; ``live`` also streams to a Rerun viewer (spawned, or the one at ``live`` if it is a
    ``rerun+http://`` address) that follows the stage being run. ``path`` None with ``live``
    streams only."""

    enabled = True

    def __init__(self, path: str | os.PathLike | None, application_id: str, title: str = "",
                 camera: str = "outside", live: bool | str = False, strict: bool = False):
        super().__init__()
        if camera not in CAMERAS:
            raise ValueError(f"camera must be one of {CAMERAS} (got {camera!r})")
        if path is None:
            self.output = None
        else:
            self.output = path if isinstance(path, OutputFile) else OutputFile(path)
            if self.output.tmp is None:
                self.output.prepare()  # the temporary file beside the target, created now
        self.path = self.output.path if self.output is not None else None
        self.written: Path | None = None  # where close() put the file
        self._rec = rr.RecordingStream(application_id)
        if strict:
            rr.set_strict_mode(True)
        # The file's bytes are collected in memory (a recording is a few MB: its frames and energy
        # samples are bounded per run) and written by close() itself, so that a write error (a
        # full disk) is an OSError here, not a message from the SDK's writer thread, and the
        # earlier file under the final name is kept.
        self._stream = self._rec.binary_stream() if self.output is not None else None
        sinks = [self._stream] if self._stream is not None else []
        self.live = bool(live)
        self.live_error = None  # why streaming to the viewer failed, if it did
        if live:
            url = live if isinstance(live, str) else None
            if url is None:  # a viewer of our own, the one installed beside this Python if there is one
                exe = Path(sys.executable).with_name("rerun")
                rr.spawn(port=LIVE_PORT, connect=False, hide_welcome_screen=True,
                         executable_path=str(exe) if exe.exists() else None)
                url = f"rerun+http://127.0.0.1:{LIVE_PORT}/proxy"
            sinks.append(rr.GrpcSink(url))
        if not sinks:
            raise ValueError("a Recorder needs a path or live=True")
        self._rec.set_sinks(*sinks)
        self.title = title
        if title:
            self._rec.send_recording_name(title)
        self.default_camera = camera
        self.stages: list[StagePlan] = []
        self._prefix = ""
        self._stage = ""
        self._closed = False
        self._static_done: set[str] = set()
        self._frame_bytes = 0         # bytes logged in the current frame
        self._outbox: dict = {}       # entity -> kept energy samples not yet sent
        self._reset_run()

    def _reset_run(self) -> None:
        """The state of the current run, empty: between runs and before the first."""
        self._run = None
        self._frame_tick = -1         # progress tick of the run's last set_time (-1: none yet)
        self._next_target = None      # the progress tick the run's next frame is meant for
        self._chunk_ticks = 0.0       # progress ticks between the moments the run can draw
        self._pending: list = []      # energy samples not yet binned: (step, K, W)
        self._pending_count = 0
        self._energy_width = None     # steps per energy bin, fixed once the run has run long
        self._energy_dt = 0.0
        self._energy_first_total = None
        self._energy_factor = None    # J per unit of the run's energy plot (energy_unit), fixed at its first samples

    # --- structure --------------------------------------------------------------
    def stage(self, index: int, title: str, narrative: str) -> None:
        """Start stage ``index``; its narrative goes to /stage<index>/narrative."""
        self._end_stage()
        self._stage = f"stage{index}"
        self._prefix = self._stage
        self.stages.append(StagePlan(index, title))
        self.markdown("narrative", f"# {index}. {title}\n\n{narrative}")
        if self.live:
            self._send_live_layout()

    def run(self, name: str, view: RunView | None = None, n_steps: int | None = None,
            dt: float | None = None, draw_every: int | None = None) -> str:
        """Start a run inside the current stage; returns its entity prefix. ``n_steps`` and ``dt``
        (planned) set its span on the progress timeline unless ``view.span`` does; ``draw_every``:
        the steps between the moments the run can draw (its chunks), so the frames it is asked
        for are the chunk ends nearest to evenly spaced ones."""
        self._end_run()
        view = view or RunView()
        safe = "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in name)
        self._prefix = f"{self._stage}/{safe}" if self._stage else safe
        span = view.span
        if span is None and n_steps and dt:
            span = n_steps * dt
        self._run = RunPlan(name=name, entity=f"/{self._prefix}", label=view.label or name,
                            camera=view.camera or self.default_camera, energy=view.energy, plot=view.plot,
                            span=span if span and span > 0 else None, n_steps=n_steps,
                            duration=n_steps * dt if n_steps and dt else None)
        self._energy_dt = float(dt or 0.0)
        self._chunk_ticks = (PROGRESS_TICKS * draw_every * dt / self._run.span
                             if draw_every and dt and self._run.span else 0.0)
        if self.stages:
            self.stages[-1].runs.append(self._run)
        if self.live:  # show the runs so far, on this stage's tab
            self._send_live_layout()
        return self._prefix

    def _send_live_layout(self) -> None:
        if self.stages:
            self._rec.send_blueprint(self.blueprint(active=self.stages[-1].index), make_active=True,
                                     make_default=False)

    def _end_run(self) -> None:
        if self._run is not None:
            self._flush_energies(final=True)
            self._close_frame()
        self._reset_run()

    def _end_stage(self) -> None:
        """Finish the current run and write the stage's colour keys, one line per run with any."""
        self._end_run()
        runs = self.stages[-1].runs if self.stages else []
        keyed = [r for r in runs if r.keys and r.has_geometry]
        split = any(r.has_geometry and r.has_energy and r.energy == "split" and not (r.plot and r.has_series)
                    for r in runs)
        if keyed or split:
            self.markdown(KEYS_DOC, "Colours, each on a scale fixed for the whole run:\n\n" + "\n".join(
                [f"- **{r.label}**: " + "; ".join(r.keys.values()) for r in keyed]
                + ([f"- {ENERGY_KEY}"] if split else [])))

    def _tick(self, sim_time: float, step: int) -> int:
        run = self._run
        if run is None or run.span is None:
            return int(step)
        return int(round(PROGRESS_TICKS * float(sim_time) / run.span))

    def _allowed_frames(self) -> int:
        run = self._run
        if run is None or run.frame_bytes <= 0:
            return FRAMES_PER_RUN
        return int(min(FRAMES_PER_RUN, max(MIN_FRAMES_PER_RUN, RUN_GEOMETRY_BYTES // run.frame_bytes)))

    def wants_frame(self, step: int, sim_time: float) -> bool:
        """Whether a run stepping through ``step`` should draw its geometry now: the first frame,
        then about FRAMES_PER_RUN evenly spaced on the progress timeline (fewer when a frame is
        large: RUN_GEOMETRY_BYTES per run), and the run's last step."""
        run = self._run
        if run is None or run.span is None or self._frame_tick < 0:
            return True
        if run.n_steps is not None and step >= run.n_steps:
            return True
        spacing = PROGRESS_TICKS / self._allowed_frames()
        # the frames are meant for the moments k * spacing; a run draws at the chunk end nearest
        # to the next of them (at most half a chunk early), and skips those it has passed
        reach = self._tick(sim_time, step) + 0.5 * self._chunk_ticks + 1e-9
        if self._next_target is None:
            self._next_target = spacing
        if reach < self._next_target:
            return False
        while self._next_target <= reach:
            self._next_target += spacing
        return True

    def frame_spacing(self, n_steps: int) -> int:
        """The step spacing a run of ``n_steps`` needs to offer FRAMES_PER_RUN frames."""
        return max(1, n_steps // FRAMES_PER_RUN)

    def _path(self, entity: str) -> str:
        return f"/{self._prefix}/{entity}" if self._prefix else f"/{entity}"

    def set_time(self, step: int, sim_time: float) -> None:
        """Set the timelines for the geometry drawn next: ``step`` = steps done in this run."""
        self._close_frame()
        tick = self._tick(sim_time, step)
        self._frame_tick = tick
        self._rec.set_time("progress", sequence=tick)
        self._rec.set_time("sim_time", duration=float(sim_time))
        self._rec.set_time("step", sequence=int(step))

    def _close_frame(self) -> None:
        if self._run is not None and self._frame_bytes:
            if self._run.frames == 0:
                self._run.frame_bytes = self._frame_bytes
                if self._run.lo is not None:
                    self._run.box0 = (self._run.lo.copy(), self._run.hi.copy())
            self._run.frames += 1
            if self.live and self._run.frames == 1:  # its view can be shown now
                self._send_live_layout()
        self._frame_bytes = 0

    def _drew(self, points: np.ndarray, *arrays, frame: bool = True) -> None:
        """Note drawn geometry: its bounding box and (``frame``: it is per-frame data) its bytes in
        this frame."""
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if frame:
            self._frame_bytes += pts.size * 4 + sum(np.asarray(a).nbytes for a in arrays if a is not None) + 1
        run = self._run
        if run is None or pts.size == 0:
            return
        finite = pts[np.all(np.isfinite(pts), axis=1)]
        if finite.size == 0:
            return
        if run.frames == 0:  # the first frame sets the box
            lo, hi = finite.min(axis=0), finite.max(axis=0)
            run.lo = lo if run.lo is None else np.minimum(run.lo, lo)
            run.hi = hi if run.hi is None else np.maximum(run.hi, hi)
            return
        # later frames widen it by what stays within two body sizes of it (a body that moves
        # or sags stays framed; the far-flung nodes of a blow-up do not pull the camera away)
        lo0, hi0 = run.box0 if run.box0 is not None else (run.lo, run.hi)
        c0, size = 0.5 * (lo0 + hi0), float(np.max(hi0 - lo0))
        near = finite[np.all(np.abs(finite - c0) <= 0.5 * (hi0 - lo0) + 2.0 * size, axis=1)]
        if near.size:
            run.lo = np.minimum(run.lo, near.min(axis=0))
            run.hi = np.maximum(run.hi, near.max(axis=0))

    # --- text ---------------------------------------------------------------------
    def markdown(self, entity: str, text: str, static: bool = True) -> None:
        """A markdown TextDocument under the current stage (not the current run)."""
        path = f"/{self._stage}/{entity}" if self._stage else f"/{entity}"
        self._rec.log(path, rr.TextDocument(text, media_type=rr.MediaType.MARKDOWN), static=static)
        if self.stages:
            st = self.stages[-1]
            if entity == "results":
                st.has_results = True
            elif entity != "narrative" and entity not in st.docs:
                st.docs.append(entity)

    def mark(self, text: str, level: str = "WARN") -> None:
        """A time-stamped event at the current run (e.g. 'blew up here')."""
        self._rec.log(self._path("events"), rr.TextLog(text, level=level))
        if self._run is not None:
            self._run.has_events = True
        if self.stages:
            self.stages[-1].events = True

    # --- layout and lifetime --------------------------------------------------------
    def blueprint(self, active: int | None = None) -> rrb.Blueprint:
        """The viewer layout for what has been recorded so far (see :func:`lesson_blueprint`)."""
        return lesson_blueprint(self.stages, active)

    def close(self, keep: bool = True, active: int | None = None, status: dict | None = None) -> Path | None:
        """Send the layout, flush, and write the file: onto its final name, or (``status`` given
        with ``complete`` False, a run that did not finish) onto ``<stem>.partial.rrd`` unless the
        output was made with ``overwrite_partial``. ``status`` (complete, exit_reason, stages
        asked and completed, ...) is written into the file as the recording property ``run``
        (:func:`run_status` reads it back); a partial recording also says so in its name and in
        a "run status" document in its last stage. ``keep`` False deletes the file instead.
        Returns where the file went (None if nowhere). A write error raises OutputWriteError
        after removing the temporary file: the earlier file is untouched."""
        if self._closed:
            return self.written if keep else None
        self._closed = True
        data = None
        try:
            if status is not None:
                self._send_status(status)
            self._end_stage()
            if self.stages:
                self._rec.send_blueprint(self.blueprint(active), make_active=True, make_default=True)
            try:
                self._rec.flush()
            except RuntimeError as exc:  # the live viewer went away: the file is still finished
                if not self.live:
                    raise
                self.live_error = str(exc)
            self._rec.disconnect()
        finally:
            if self._stream is not None:
                try:
                    data = self._stream.read(flush=False)
                except Exception:  # nothing readable: no file is written (an earlier one is kept)
                    data = None
            if self.output is not None:
                if keep and data is not None:
                    self.output.write_bytes(data)  # raises OutputWriteError (temporary file removed)
                    complete = True if status is None else bool(status.get("complete"))
                    self.written = self.output.commit(complete)
                else:
                    self.output.discard()
        return self.written if keep else None

    def _send_status(self, status: dict) -> None:
        """The run's completeness, as the recording property ``run`` (and, for a run that did not
        complete, in the recording's name and a document in the last stage's tab)."""
        values = {}
        for key, value in status.items():
            if isinstance(value, (list, tuple)):
                value = [str(v) for v in value] if any(not isinstance(v, (int, float)) for v in value) else list(value)
                if not value:
                    continue
            elif value is None:
                continue
            elif not isinstance(value, (bool, int, float, str)):
                value = str(value)
            values[key] = value
        self._rec.send_property("run", rr.AnyValues(**values))
        if not status.get("complete", True):
            done = ", ".join(str(s) for s in status.get("stages_completed") or []) or "none"
            reason = status.get("exit_reason", "did not complete")
            if self.title:
                self._rec.send_recording_name(f"{self.title} (PARTIAL: {reason})")
            if self.stages:
                self.markdown("run_status", f"**This recording is partial**: {reason}. Stages completed: {done} "
                                            f"(asked: {', '.join(str(s) for s in status.get('stages_requested') or [])}).")
