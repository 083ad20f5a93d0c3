"""Command line: ``python -m lessons list`` and ``python -m lessons run <id>|all`` (its parsers in
lessons.app.arguments, its output paths' checks in lessons.app.output_paths).

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
import errno
import os
import re
import signal
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

from lessons.app.outfile import OutputWriteError

from . import registry
from .arguments import UsageError, _lesson_token, _main_parser, _run_parser, parse_stages
from .output_paths import _outputs, _prepare, _shown
from .results import encode as encode_results, results_document
from .._framework import Stepping, Terminated, _pending_signal, note_signal, run_lesson, validate_config

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_INT, EXIT_TERM = 0, 1, 2, 130, 143
EXIT_HUP, EXIT_PIPE = 129, 141
HANDLED_SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name))


_CONTROL = re.compile("[\x00-\x1f\x7f-\x9f\u2028\u2029]")  # would break the one-line error message


def _stdin_is_tty(stream) -> bool:
    try:
        return stream is not None and stream.isatty()
    except (AttributeError, ValueError, OSError):  # no stream, or a closed one
        return False


class _Pause:
    """``--pause``: between two stages (and, with 'all', two lessons) wait for Enter on ``stdin``;
    'q' (or 'quit', or end of input) stops the run there. ``stopped`` tells the caller."""

    def __init__(self, stdin, out):
        self.stdin, self.out, self.stopped = stdin, out, False

    def ask(self, what: str) -> bool:
        print(f"\npress Enter for {what}, or q + Enter to stop: ", end="", file=self.out, flush=True)
        line = self.stdin.readline()
        if not line:  # end of input (Ctrl-D)
            print(file=self.out)
        if not line or line.strip().lower() in ("q", "quit"):
            self.stopped = True
            print(f"stopped before {what}: the rest of the run is skipped", file=self.out, flush=True)
            return False
        return True

    def for_lesson(self, lesson):
        n = len(lesson.stages)
        return lambda index, title: self.ask(f"stage {index}/{n}: {title}")


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
    out = sys.stdout if out is None else out  # looked up per call (the streams may be redirected)
    err = sys.stderr if err is None else err
    stdin = sys.stdin if stdin is None else stdin
    lessons_ = registry.all_lessons()
    ids = [l.id for l in lessons_]
    by_id = {l.id: l for l in lessons_}
    lesson_arg = _lesson_token(argv, lessons_)
    lesson = by_id.get(lesson_arg)
    parser = _run_parser(ids, lesson)
    if lesson_arg is None and not any(a in ("-h", "--help") for a in argv):
        raise UsageError("LESSON is required: one of " + ", ".join(ids) + ", or all")
    if lesson_arg is not None and lesson is None and lesson_arg != "all":
        raise UsageError(f"LESSON must be one of {', '.join(ids)}, or all (got {lesson_arg!r})")
    args = parser.parse_args(argv)

    chosen = lessons_ if args.lesson == "all" else [lesson]
    overrides = {f.name: getattr(args, f.name) for f in dataclasses.fields(lesson.config)
                 if getattr(args, f.name, None) is not None} if lesson else {}
    stepping = Stepping(**{f.name: getattr(args, f.name) for f in dataclasses.fields(Stepping)
                           if getattr(args, f.name, None) is not None})
    stages = None
    if args.stage is not None:
        if len(chosen) != 1:
            raise UsageError("--stage needs a single lesson, not 'all'")
        stages = parse_stages(args.stage, len(lesson.stages), lesson.id)
    if args.pause and not _stdin_is_tty(stdin):
        raise UsageError("--pause needs an interactive terminal (stdin is not a tty); run without --pause, "
                         "or with --stage N to run one stage")
    pause = _Pause(stdin, out) if args.pause else None

    # Validate everything before any kernel runs or any file is written.
    configs = {}
    try:
        validate_config(stepping)
        for l in chosen:
            cfg = l.config(**overrides) if l is lesson else l.config()
            validate_config(cfg)
            if l.validate is not None:
                l.validate(cfg)
            configs[l.id] = cfg
    except ValueError as exc:  # ParameterError, mesh/model errors: bad input, not a crash
        raise UsageError(str(exc)) from None
    from engine import runtime
    try:
        runtime.init(arch=args.arch, threads=args.threads, warn=lambda line: _say(err, line))
        from .backends import check
        check(chosen, configs)  # f64 only, and the backends each lesson's physics holds on
    except runtime.RuntimeConfigError as exc:
        raise UsageError(str(exc)) from None

    info = runtime.current()

    # Every output path: checked (kinds, names, overlaps), then created as empty temporary files
    # beside their targets, before the first stage; a bad one is bad input (exit 2, nothing left).
    results_target, record_targets = _outputs(args, chosen)
    targets = ([("--results", results_target)] if results_target is not None else []) + [
        ("--record", t) for t in record_targets.values() if t is not None]
    _prepare(targets)

    signals = signals if signals is not None else _Signals()
    requested = {l.id: list(stages) if stages else list(range(1, len(l.stages) + 1)) for l in chosen}
    completed: dict[str, list[int]] = {l.id: [] for l in chosen}
    results: list[dict] = []
    started = time.time()
    common = dict(version=_package_version(), runtime=info.as_dict() if info is not None else None)
    all_passed, stopped, failure = True, False, None
    open_rec = None  # (recorder, lesson) of the lesson being run, until its recording is closed

    def stages_done(lesson_id: str) -> list[int]:
        return sorted({r["stage"] for r in results if r.get("lesson") == lesson_id})

    def close_recording(rec, l, exc, stop_here: bool, passed: bool) -> None:
        """Write the lesson's recording (partial unless every stage asked ran) and say where."""
        nonlocal open_rec
        open_rec = None
        target = record_targets.get(l.id)
        code, reason = _outcome(exc, stop_here, passed)
        complete = completed[l.id] == requested[l.id]
        status = dict(complete=complete, exit_reason=reason, exit_code=code, lesson=l.id,
                      stages_requested=requested[l.id], stages_completed=completed[l.id],
                      arch=common["runtime"]["arch"] if common["runtime"] else None,
                      backend=common["runtime"]["backend"] if common["runtime"] else None,
                      precision=common["runtime"]["precision"] if common["runtime"] else None,
                      threads=common["runtime"]["threads"] if common["runtime"] else None,
                      version=common["version"], finished=_now())
        was_cleaning = signals.cleaning
        signals.cleaning = True  # a signal now is noted; the file is finished first
        try:
            written = rec.close(status=status) if target is not None else rec.close()
        except OutputWriteError as e:
            raise OutputFailed(f"--record {_shown(target.given)}: could not write the recording "
                               f"({e.strerror or e}); the earlier file there is kept and the partial one "
                               f"removed") from None
        finally:
            signals.cleaning = was_cleaning
        if getattr(rec, "live_error", None):
            _say(err, f"--view: the live viewer stopped receiving ({rec.live_error}); the recording file is "
                      f"complete")
        if written is not None:
            if complete:
                _say(out, f"\nrecording: {_shown(str(written))}  (open with: rerun {_shown(str(written))})")
            else:
                kept = (f"; the earlier {_shown(str(target.path))} is kept" if target.path != written
                        and target.path.exists() else "")
                _say(out, f"\nrecording (PARTIAL: {reason}; stages {_stage_list(completed[l.id])} of "
                          f"{_stage_list(requested[l.id])}): {_shown(str(written))}{kept}")
        if not was_cleaning and signals.received and not signals.raised:
            signals.raised = True  # a signal came while the file was written: stop now
            first = signals.first
            raise KeyboardInterrupt() if first == signal.SIGINT else Terminated(first)

    live = _live_viewer(args, {k: (t.path if t is not None else None) for k, t in record_targets.items()}, out)
    try:
        _say(out, f"runtime: {info.describe()}" if info is not None else "runtime: not initialised")
        for number, l in enumerate(chosen, 1):
            if pause is not None and number > 1 and not pause.ask(
                    f"lesson {number}/{len(chosen)}: {l.id}, stage 1/{len(l.stages)}: {l.stages[0].title}"):
                stopped = True
                break
            rec = _make_recorder(l, record_targets[l.id], live)
            open_rec = (rec, l)
            # between= only with --pause (a runner stubbed in the tests may not take it)
            extra = {} if pause is None else {"between": pause.for_lesson(l)}
            try:
                ok = run_lesson(l, configs[l.id], rec, stages, out=out, err=err, quiet=args.quiet,
                                results=results, stepping=stepping, **extra)
            except BaseException as exc:
                signals.cleaning = True
                completed[l.id] = stages_done(l.id)
                try:
                    close_recording(rec, l, exc, False, False)
                except OutputFailed as e:  # the run's own failure is the one that counts
                    _say(err, f"python -m lessons: error: {e}")
                raise
            stop_here = pause is not None and pause.stopped
            completed[l.id] = stages_done(l.id) if stop_here else list(requested[l.id])
            all_passed &= ok
            close_recording(rec, l, None, stop_here, ok)
            if stop_here:
                stopped = True
                break
    except BaseException as exc:
        failure = exc
    finally:
        signals.cleaning = True
        if open_rec is not None:  # interrupted between the lesson's end and its recording's close
            rec, l = open_rec
            completed[l.id] = stages_done(l.id)
            try:
                close_recording(rec, l, failure, False, False)
            except OutputFailed as e:
                _say(err, f"python -m lessons: error: {e}")
        code, reason = _outcome(failure, stopped, all_passed)
        complete = all(completed[l.id] == requested[l.id] for l in chosen)
        if results_target is not None:
            doc = results_document(
                results, complete=complete, exit_code=code, exit_reason=reason, lessons=[l.id for l in chosen],
                stages_requested=requested, stages_completed=completed,
                parameters={l: dataclasses.asdict(c) for l, c in configs.items()},
                stepping=dataclasses.asdict(stepping), runtime=common["runtime"], version=common["version"],
                command=["python -m lessons", "run", *argv], started=_now(started), finished=_now(),
                elapsed_s=round(time.time() - started, 3))
            try:
                results_target.write_bytes(encode_results(doc))
                where = results_target.commit(complete)
                if complete:
                    _say(out, f"results: {_shown(str(where))}")
                else:
                    kept = (f"; the earlier {_shown(str(results_target.path))} is kept"
                            if results_target.path.exists() else "")
                    _say(out, f"results (PARTIAL: {reason}): {_shown(str(where))}{kept}")
            except OutputWriteError as e:
                _say(err, f"python -m lessons: error: --results {_shown(results_target.given)}: could not write "
                          f"the results ({e.strerror or e}); the earlier file there is kept and the partial one "
                          f"removed")
                if failure is None:
                    failure = OutputFailed("the results could not be written")
                    failure.reported = True
        for _, t in targets:  # any temporary file still there (a recorder never made)
            t.discard()
        n_fail = sum(not r["passed"] for r in results)
        _say(out, f"\n{len(results) - n_fail} of {len(results)} experiments passed"
                  + ("" if n_fail == 0 else f"; {n_fail} FAILED")
                  + ("" if complete else f" (the run did not complete: {reason})"))
    if failure is not None:
        raise failure
    if signals.first is not None:  # came during the clean-up of a finished run
        return 128 + signals.first
    return EXIT_OK if all_passed else EXIT_FAILED


class OutputFailed(Exception):
    """An output file could not be written at the end of the run (exit 1; one line)."""

    reported = False


def _stage_list(stages: list[int]) -> str:
    return ",".join(str(s) for s in stages) if stages else "none"


def _now(t: float | None = None) -> str:
    return datetime.fromtimestamp(time.time() if t is None else t, timezone.utc).isoformat(timespec="seconds")


def _package_version() -> str:
    from .results import package_version
    return package_version()


def _make_recorder(lesson, path, live: bool = False):
    """The lesson's recorder: the file at ``path`` (None: no file), streaming into a viewer that
    follows the stage being run when ``live``."""
    from lessons.app.recorder import NullRecorder, Recorder
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
    _pending_signal.clear()
    previous = {sig: signal.signal(sig, signals.handler) for sig in HANDLED_SIGNALS}
    try:
        try:
            from engine import runtime  # first: it prepares the environment Taichi's import needs
        except ValueError as exc:  # runtime.RuntimeConfigError: a bad TI_LOG_LEVEL
            raise UsageError(str(exc)) from None
        lessons_ = registry.all_lessons()
        ids = [l.id for l in lessons_]
        if not argv:
            raise UsageError("a command is required: list or run (see 'python -m lessons --help')")
        if argv[0] in ("-h", "--help", "--version"):
            _main_parser(ids).parse_args(argv[:1])
            return EXIT_OK
        command, rest = argv[0], argv[1:]
        if command == "list":
            if rest:
                raise UsageError(f"'list' takes no arguments (got {' '.join(rest)})")
            return _list(sys.stdout)
        if command == "run":
            return run(rest, signals=signals)
        raise UsageError(f"command must be 'list' or 'run' (got {command!r}); see 'python -m lessons --help'")
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
        _pending_signal.clear()
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
