"""Command line: ``python -m lessons list``, ``python -m lessons run <id>|all`` (its parsers in
lessons.app.arguments, the run's plan checked in lessons.app.run_plan, its output paths' checks in
lessons.app.output_paths), ``exercise`` and ``check`` (lessons.app.exercises, lessons.app.grading).

``--stage`` takes stage numbers, lists and ranges (``3``, ``2-4``, ``1,3,5``, ``2-3,5``; repeatable);
``--pause`` waits for Enter between stages (``q`` stops there). Every other option may be given
once: a repeated one is refused (it would silently keep the last value).

Exit codes: 0 every experiment passed; 1 an experiment failed (or a simulation blew up
unexpectedly, or an output file could not be written); 2 bad input (one line on stderr,
nothing written); 128 + the signal for a signal: 130 interrupted (Ctrl-C, SIGINT), 143
terminated (SIGTERM), 129 hung up (SIGHUP); 141 the output pipe was closed (``| head``).

Output files (lessons.app.outfile): checked and created (as an empty temporary file) before the first
stage; written when the run ends, atomically. A run that does not complete (a signal, an
internal error, ``--pause`` stopped, a recording that could not be written) writes
``<stem>.partial.rrd`` / ``<stem>.partial.json``, marked partial inside, and leaves the files of
an earlier run under the final names alone (``--overwrite-partial``: the final names).
"""
from __future__ import annotations

import dataclasses
import importlib
import os
import re
import signal
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

from lessons.app.outfile import OutputWriteError

from . import registry
from .arguments import UsageError, main_parser
from .output_paths import output_targets, prepare_outputs, shown_path
from .results import encode as encode_results, results_document
from .run_plan import plan_run, RunRequest
from .._framework import Terminated, pending_signal, note_signal, run_lesson

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_INT, EXIT_TERM = 0, 1, 2, 130, 143
COMMANDS = {"exercise": (".exercises", "write_template"), "check": (".grading", "check"),   # command: (module,
            "grade": (".roster", "grade"), "view": (".view", "view"),                    # function(argv, out, err))
            "notebook": (".notebook", "write_notebooks")}
EXIT_HUP, EXIT_PIPE = 129, 141
HANDLED_SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name))


_CONTROL = re.compile("[\x00-\x1f\x7f-\x9f\u2028\u2029]")  # would break the one-line error message


def _list(out) -> int:
    for lesson in registry.all_lessons():
        print(f"{lesson.id:22s} {lesson.title}  [{len(lesson.stages)} stages: "
              + "; ".join(s.title for s in lesson.stages) + "]", file=out)
    return EXIT_OK


def _say(stream, text: str) -> None:
    """Print for the clean-up messages: never raises (a closed pipe must not stop the files)."""
    try:
        print(text, file=stream, flush=True)
    except (OSError, ValueError):
        pass


class _Signals:
    """The signals of this run: the first one raises (KeyboardInterrupt, Terminated) and stops
    the stages; any later one, and any one during clean-up, is only noted, so writing the files is
    never interrupted (and never prints a traceback). ``first`` decides the exit code."""

    def __init__(self):
        self.received: list[int] = []
        self.raised = False
        self.cleaning = False

    @property
    def first(self) -> int | None:
        return self.received[0] if self.received else None

    def handler(self, signum, frame):
        self.received.append(signum)
        if self.raised or self.cleaning:
            return
        self.raised = True
        note_signal(signum)  # acted on later if this raise lands in a __del__ and is swallowed
        raise KeyboardInterrupt() if signum == signal.SIGINT else Terminated(signum)


_SIGNAL_WORDS = {signal.SIGINT: "interrupted (SIGINT)", signal.SIGTERM: "terminated (SIGTERM)"}
if hasattr(signal, "SIGHUP"):
    _SIGNAL_WORDS[signal.SIGHUP] = "hung up (SIGHUP)"


def _outcome(exc: BaseException | None, stopped: bool, passed: bool) -> tuple[int, str]:
    """(exit code, exit reason) of a run that ended with ``exc`` (None: normally)."""
    from lessons.app.outfile import OutputWriteError
    if exc is None:
        code = EXIT_OK if passed else EXIT_FAILED
        if stopped:
            return code, "stopped at --pause"
        return code, "completed" if passed else "completed; an experiment failed"
    if isinstance(exc, KeyboardInterrupt):
        return EXIT_INT, _SIGNAL_WORDS[signal.SIGINT]
    if isinstance(exc, Terminated):
        return 128 + exc.signum, _SIGNAL_WORDS.get(exc.signum, f"signal {exc.signum}")
    if isinstance(exc, BrokenPipeError):
        return EXIT_PIPE, "the output pipe was closed"
    if isinstance(exc, OutputFailed):
        return EXIT_FAILED, str(exc)
    if isinstance(exc, OutputWriteError):
        return EXIT_FAILED, f"an output file could not be written ({exc.strerror or exc})"
    return EXIT_FAILED, f"internal error: {type(exc).__name__}: {exc}"


def _live_viewer(args, paths: dict, out) -> bool:
    """Whether ``--view`` can stream into a viewer here (a display on Linux); if not, say so in
    one line and record to the file only."""
    if not args.view:
        return False
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        where = " ".join(str(p) for p in paths.values() if p is not None)
        print("--view: cannot start the Rerun viewer: no display (DISPLAY is not set); "
              + (f"recording to the file only. Open it on a machine with a screen: rerun {where}" if where
                 else "nothing is recorded (--no-record)."), file=out)
        return False
    return True


def run(argv: list[str], out=None, err=None, stdin=None, signals: "_Signals | None" = None) -> int:
    """``python -m lessons run ARGV``: check the arguments, the lessons' parameters, the runtime and
    the output paths (bad input raises UsageError before anything runs or is written), then run the
    chosen lessons and write their files. Returns the exit code; a signal, a closed pipe, a file that
    could not be written or an internal error is raised after the files are written."""
    out = sys.stdout if out is None else out  # looked up per call (the streams may be redirected)
    err = sys.stderr if err is None else err
    stdin = sys.stdin if stdin is None else stdin
    plan = plan_run(argv, stdin, out)
    info = _start_runtime(plan.args, plan.chosen, plan.configs, err)
    outputs = _prepare_outputs(plan.args, plan.chosen)
    session = _Session(plan, info, outputs, signals if signals is not None else _Signals(), out, err)
    return session.execute()


def _start_runtime(args, chosen: list, configs: dict, err):
    """Start the Taichi runtime that ``--arch`` and ``--threads`` ask for (its warnings go to
    ``err``) and check that it can run each chosen lesson; returns the runtime's description. A
    runtime that cannot be had is a UsageError."""
    from engine import runtime
    try:
        runtime.init(arch=args.arch, threads=args.threads, warn=lambda line: _say(err, line))
        from .backends import check
        check(chosen, configs)  # f64 only, and the backends each lesson's physics holds on
    except runtime.RuntimeConfigError as exc:
        raise UsageError(str(exc)) from None
    return runtime.current()


def _prepare_outputs(args, chosen: list):
    """Every output path: checked (kinds, names, overlaps), then created as empty temporary files
    beside their targets, before the first stage; a bad one is bad input (exit 2, nothing left).
    Returns (the results target or None, the recording target by lesson id, every (option, target))."""
    results_target, record_targets = output_targets(args, chosen)
    targets = ([("--results", results_target)] if results_target is not None else []) + [
        ("--record", t) for t in record_targets.values() if t is not None]
    prepare_outputs(targets)
    return results_target, record_targets, targets


class _Session:
    """One ``run`` after its checks: runs the chosen lessons one after another, closes each one's
    recording (partial unless every stage asked ran), and at the end, however the run ended, writes
    the results, removes any temporary file left and prints the summary. It holds what the run has
    done so far: the stages asked and completed per lesson, the experiments' results, whether every
    one passed, whether ``--pause`` stopped the run, and the exception that ended it."""

    def __init__(self, plan: RunRequest, info, outputs, signals: _Signals, out, err):
        self.plan, self.info, self.signals, self.out, self.err = plan, info, signals, out, err
        self.results_target, self.record_targets, self.targets = outputs
        stages = plan.stages
        self.requested = {l.id: list(stages) if stages else list(range(1, len(l.stages) + 1)) for l in plan.chosen}
        self.completed: dict[str, list[int]] = {l.id: [] for l in plan.chosen}
        self.results: list[dict] = []
        self.started = time.time()
        self.version = _package_version()
        self.runtime = info.as_dict() if info is not None else None
        self.all_passed, self.stopped, self.failure = True, False, None
        self.unrecorded: list[str] = []  # lessons whose recording could not be written: the run is partial
        self.open_rec = None  # (recorder, lesson) of the lesson being run, until its recording is closed

    def execute(self) -> int:
        """Run the lessons and write the files; returns the exit code, or raises the exception
        that ended the run once the files are written."""
        live = _live_viewer(self.plan.args, {k: (t.path if t is not None else None)
                                             for k, t in self.record_targets.items()}, self.out)
        try:
            self._run_lessons(live)
        except BaseException as exc:
            self.failure = exc
        finally:
            self._finish()
        if self.failure is not None:
            raise self.failure
        if self.signals.first is not None:  # came during the clean-up of a finished run
            return 128 + self.signals.first
        return EXIT_OK if self.all_passed else EXIT_FAILED

    def _run_lessons(self, live: bool) -> None:
        """Say which runtime runs the lessons, then run them in turn until the last one, or until
        ``--pause`` stops the run (asked before each lesson after the first, and between stages)."""
        info, chosen, pause = self.info, self.plan.chosen, self.plan.pause
        _say(self.out, f"runtime: {info.describe()}" if info is not None else "runtime: not initialised")
        for number, l in enumerate(chosen, 1):
            if pause is not None and number > 1 and not pause.ask(
                    f"lesson {number}/{len(chosen)}: {l.id}, stage 1/{len(l.stages)}: {l.stages[0].title}"):
                self.stopped = True
                break
            if self._run_lesson(l, live):
                self.stopped = True
                break

    def _run_lesson(self, l, live: bool) -> bool:
        """Run the stages asked of lesson ``l`` into a new recorder, then close its recording;
        returns whether ``--pause`` stopped the run during the lesson. An exception from the lesson
        closes the recording (partial) and is raised again."""
        plan, pause = self.plan, self.plan.pause
        rec = make_recorder(l, self.record_targets[l.id], live)
        self.open_rec = (rec, l)
        # between= only with --pause (a runner stubbed in the tests may not take it)
        extra = {} if pause is None else {"between": pause.for_lesson(l)}
        try:
            ok = run_lesson(l, plan.configs[l.id], rec, plan.stages, out=self.out, err=self.err,
                            quiet=plan.args.quiet, results=self.results, stepping=plan.stepping, **extra)
        except BaseException as exc:
            self._close_unfinished(rec, l, exc)
            raise
        stop_here = pause is not None and pause.stopped
        self.completed[l.id] = self._stages_done(l.id) if stop_here else list(self.requested[l.id])
        self.all_passed &= ok
        self._close_recording(rec, l, None, stop_here, ok)
        return stop_here

    def _stages_done(self, lesson_id: str) -> list[int]:
        """The stages of the lesson that have results, in ascending order."""
        return sorted({r["stage"] for r in self.results if r.get("lesson") == lesson_id})

    def _close_unfinished(self, rec, l, exc: BaseException | None) -> None:
        """Close the recording of lesson ``l``, which did not finish (``exc``: why), with the
        stages that ran; from here on a signal is only noted. A recording that cannot be written is
        reported on one line and not raised: the run's own failure is the one that counts."""
        self.signals.cleaning = True
        self.completed[l.id] = self._stages_done(l.id)
        try:
            self._close_recording(rec, l, exc, False, False)
        except OutputFailed as e:
            _say(self.err, f"python -m lessons: error: {e}")

    def _close_recording(self, rec, l, exc: BaseException | None, stop_here: bool, passed: bool) -> None:
        """Write the lesson's recording (partial unless every stage asked ran) and say where. A
        signal that comes while the file is written is noted, and raised once it is written (unless
        the run was already cleaning up); a file that cannot be written raises OutputFailed."""
        self.open_rec = None
        target = self.record_targets.get(l.id)
        code, reason = _outcome(exc, stop_here, passed)
        complete = self.completed[l.id] == self.requested[l.id]
        status = self._recording_status(l, complete, code, reason)
        signals = self.signals
        was_cleaning = signals.cleaning
        signals.cleaning = True  # a signal now is noted; the file is finished first
        try:
            written = rec.close(status=status) if target is not None else rec.close()
        except OutputWriteError as e:
            self.unrecorded.append(l.id)
            raise OutputFailed(f"--record {shown_path(target.given)}: could not write the recording "
                               f"({e.strerror or e}); {_left_there(target)}") from None
        finally:
            signals.cleaning = was_cleaning
        self._report_recording(rec, l, target, written, complete, reason)
        if not was_cleaning and signals.received and not signals.raised:
            signals.raised = True  # a signal came while the file was written: stop now
            first = signals.first
            raise KeyboardInterrupt() if first == signal.SIGINT else Terminated(first)

    def _recording_status(self, l, complete: bool, code: int, reason: str) -> dict:
        """The status stored in lesson ``l``'s recording: whether it is complete, how and why the
        run ended, the stages asked and completed, the runtime, the version and the time now."""
        rt = self.runtime
        return dict(complete=complete, exit_reason=reason, exit_code=code, lesson=l.id,
                    stages_requested=self.requested[l.id], stages_completed=self.completed[l.id],
                    arch=rt["arch"] if rt else None, backend=rt["backend"] if rt else None,
                    precision=rt["precision"] if rt else None, threads=rt["threads"] if rt else None,
                    version=self.version, finished=_now())

    def _report_recording(self, rec, l, target, written, complete: bool, reason: str) -> None:
        """Say that the live viewer stopped receiving (if it did) and where the recording of lesson
        ``l`` was written (``written``; None: nowhere), with, for a partial one, the stages it
        holds and whether an earlier file under the final name is kept."""
        if getattr(rec, "live_error", None):
            _say(self.err, f"--view: the live viewer stopped receiving ({rec.live_error}); the recording file is "
                           f"complete")
        if written is None:
            return
        if complete:
            _say(self.out, f"\nrecording: {shown_path(str(written))}  (open with: rerun {shown_path(str(written))})")
        else:
            _say(self.out, f"\nrecording (PARTIAL: {reason}; stages {_stage_list(self.completed[l.id])} of "
                           f"{_stage_list(self.requested[l.id])}): {shown_path(str(written))}{_earlier(target)}")

    def _finish(self) -> None:
        """The end of the run, however it ended (signals from here on are only noted): close a
        recording still open, write the results, remove any temporary file still there (a recorder
        never made) and print how many experiments passed."""
        self.signals.cleaning = True
        if self.open_rec is not None:  # interrupted between the lesson's end and its recording's close
            rec, l = self.open_rec
            self._close_unfinished(rec, l, self.failure)
        code, reason = _outcome(self.failure, self.stopped, self.all_passed)
        complete = not self.unrecorded and all(self.completed[l.id] == self.requested[l.id] for l in self.plan.chosen)
        if self.results_target is not None:
            self._write_results(code, reason, complete)
        for _, t in self.targets:
            t.discard()
        n_fail = sum(not r["passed"] for r in self.results)
        _say(self.out, f"\n{len(self.results) - n_fail} of {len(self.results)} experiments passed"
                       + ("" if n_fail == 0 else f"; {n_fail} FAILED")
                       + ("" if complete else f" (the run did not complete: {reason})"))

    def _write_results(self, code: int, reason: str, complete: bool) -> None:
        """Write the ``--results`` file (partial unless the run completed) and say where; if it
        cannot be written, say so on one line and make that the run's failure when it has none."""
        target = self.results_target
        doc = self._results_document(code, reason, complete)
        try:
            target.write_bytes(encode_results(doc))
            where = target.commit(complete)
            if complete:
                _say(self.out, f"results: {shown_path(str(where))}")
            else:
                _say(self.out, f"results (PARTIAL: {reason}): {shown_path(str(where))}{_earlier(target)}")
        except OutputWriteError as e:
            _say(self.err, f"python -m lessons: error: --results {shown_path(target.given)}: could not write "
                           f"the results ({e.strerror or e}); {_left_there(target)}")
            if self.failure is None:
                self.failure = OutputFailed("the results could not be written")
                self.failure.reported = True

    def _results_document(self, code: int, reason: str, complete: bool) -> dict:
        """The results file's document: every experiment's result and how the run went (its
        lessons, stages, parameters, stepping, runtime, version, command line and times)."""
        plan = self.plan
        return results_document(
            self.results, complete=complete, exit_code=code, exit_reason=reason,
            lessons=[l.id for l in plan.chosen], stages_requested=self.requested, stages_completed=self.completed,
            parameters={l: dataclasses.asdict(c) for l, c in plan.configs.items()},
            stepping=dataclasses.asdict(plan.stepping), runtime=self.runtime, version=self.version,
            command=["python -m lessons", "run", *plan.argv], started=_now(self.started), finished=_now(),
            elapsed_s=round(time.time() - self.started, 3))


class OutputFailed(Exception):
    """An output file could not be written at the end of the run (exit 1; one line)."""

    reported = False


def _earlier(target) -> str:
    """What became of the file under the final name, said after where a partial output went."""
    if target.written != target.path:
        return f"; the earlier {shown_path(str(target.path))} is kept" if target.path.exists() else ""
    return f"; it replaced the earlier {shown_path(str(target.path))} (--overwrite-partial)" if target.replaced else ""


def _left_there(target) -> str:
    """What is left under an output's name after writing it failed (the temporary file is removed)."""
    if target.path.exists():
        return "the earlier file there is kept and the partial one removed"
    return "the partial file is removed and nothing is left there"


def _stage_list(stages: list[int]) -> str:
    return ",".join(str(s) for s in stages) if stages else "none"


def _now(t: float | None = None) -> str:
    return datetime.fromtimestamp(time.time() if t is None else t, timezone.utc).isoformat(timespec="seconds")


def _package_version() -> str:
    from .results import package_version
    return package_version()


def make_recorder(lesson, path, live: bool = False):
    """The lesson's recorder: the file at ``path`` (None: no file), streaming into a viewer that
    follows the stage being run when ``live``."""
    from lessons.app.recorder import Recorder
    from lessons.app.recorder_null import NullRecorder
    if path is None and not live:
        return NullRecorder()
    return Recorder(path, "elastic_lessons_" + lesson.id.replace("-", "_"), title=f"{lesson.id}: {lesson.title}",
                    camera=lesson.camera, live=live)


def main(argv: list[str] | None = None, restore_signals: bool = True) -> int:
    """``python -m lessons ARGV``; returns the exit code. The signal handlers it installs (SIGINT,
    SIGTERM, SIGHUP) are put back on return unless ``restore_signals`` is False (the program's
    own entry point keeps them until the process ends, so a late signal never kills it)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    signals = _Signals()
    pending_signal.clear()
    previous = {sig: signal.signal(sig, signals.handler) for sig in HANDLED_SIGNALS}
    try:
        try:
            from engine import runtime  # first: it prepares the environment Taichi's import needs
        except ValueError as exc:  # runtime.RuntimeConfigError: a bad TI_LOG_LEVEL
            raise UsageError(str(exc)) from None
        lessons_ = registry.all_lessons()
        ids = [l.id for l in lessons_]
        if not argv:
            raise UsageError("a command is required: list, run, exercise, check, grade, view or notebook (see "
                             "'python -m lessons --help')")
        if argv[0] in ("-h", "--help", "--version"):
            main_parser(ids).parse_args(argv[:1])
            return EXIT_OK
        command, rest = argv[0], argv[1:]
        if command == "list":
            if rest:
                raise UsageError(f"'list' takes no arguments (got {' '.join(rest)})")
            return _list(sys.stdout)
        if command == "run":
            return run(rest, signals=signals)
        if command in COMMANDS:   # the other commands' modules, loaded only when used
            module, name = COMMANDS[command]
            return getattr(importlib.import_module(module, __package__), name)(rest, sys.stdout, sys.stderr)
        raise UsageError(f"command must be 'list', 'run', 'exercise', 'check', 'grade', 'view' or 'notebook' (got "
                         f"{command!r}); see 'python -m lessons --help'")
    except SystemExit as exc:  # --help, --version
        return int(exc.code or 0)
    except UsageError as exc:  # one line, whatever the user typed (control characters escaped)
        message = _CONTROL.sub(lambda m: repr(m.group())[1:-1], str(exc))
        _say(sys.stderr, f"python -m lessons: error: {message}")
        return EXIT_USAGE
    except KeyboardInterrupt:
        _say(sys.stderr, "\ninterrupted (SIGINT): the output so far is written, marked partial")
        return EXIT_INT
    except Terminated as exc:
        _say(sys.stderr, f"\n{_SIGNAL_WORDS.get(exc.signum, f'signal {exc.signum}')}: the output so far is "
                         f"written, marked partial")
        return 128 + exc.signum
    except BrokenPipeError:  # '| head': stop quietly (the files are written, marked partial)
        _silence_stdout()
        return EXIT_PIPE
    except OutputFailed as exc:
        if not exc.reported:
            _say(sys.stderr, f"python -m lessons: error: {exc}")
        return EXIT_FAILED
    except Exception as exc:  # a bug, not bad input: one line, the work so far kept, exit 1
        if os.environ.get("ELASTIC_DEBUG"):
            raise
        where = exc.__traceback__
        while where is not None and where.tb_next is not None:
            where = where.tb_next
        loc = f" at {Path(where.tb_frame.f_code.co_filename).name}:{where.tb_lineno}" if where else ""
        _say(sys.stderr, f"python -m lessons: internal error{loc}: {type(exc).__name__}: {exc} (the output so "
                         f"far is written, marked partial; set ELASTIC_DEBUG=1 for the traceback, and please "
                         f"report it)")
        return EXIT_FAILED
    finally:
        pending_signal.clear()
        if restore_signals:
            for sig, handler in previous.items():
                signal.signal(sig, handler)
        else:
            signals.cleaning = True  # from here on a signal is only noted (see lessons/__main__.py)
            _after_main[:] = [signals, len(signals.received)]


_after_main: list = []  # [the _Signals of main(restore_signals=False), signals seen by its return]


def late_signal() -> int | None:
    """A signal that arrived after :func:`main` (restore_signals=False) returned, if any."""
    if not _after_main:
        return None
    signals, seen = _after_main
    return signals.received[seen] if len(signals.received) > seen else None


def _silence_stdout() -> None:
    """After a closed pipe: point stdout at /dev/null so that the interpreter's final flush does
    not complain."""
    try:
        fd = os.open(os.devnull, os.O_WRONLY)
        os.dup2(fd, sys.stdout.fileno())
        os.close(fd)
    except (OSError, ValueError, AttributeError):
        pass
