"""Command line: ``python -m lessons list`` and ``python -m lessons run <id>|all``.

``--stage`` takes stage numbers, lists and ranges (``3``, ``2-4``, ``1,3,5``, ``2-3,5``; repeatable);
``--pause`` waits for Enter between stages (``q`` stops there, as if the run had ended).

Exit codes: 0 every experiment passed; 1 an experiment failed (or a simulation blew
up unexpectedly); 2 bad input (one line on stderr, nothing written); 130 interrupted
(Ctrl-C); 143 terminated (SIGTERM). On 1, 130 and 143 the recording and the results
gathered so far are still finalised and written.
"""
from __future__ import annotations

import argparse
import dataclasses
import os
import re
import shutil
import signal
import subprocess
import sys
from pathlib import Path

from . import registry
from ._framework import (Stepping, Terminated, _field_type, _pending_signal, note_signal, range_text, run_lesson,
                         validate_config, write_json_atomic)

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_INT, EXIT_TERM = 0, 1, 2, 130, 143


class UsageError(Exception):
    """Bad command-line input: reported as one line, exit code 2."""


# What argparse takes for a (negative) number rather than an option: by default only -1 and
# -1.5, so "--E -1e-3" or "--E -inf" would be reported as a missing value instead of a bad one.
_NEGATIVE_NUMBER = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$|^-(inf|infinity|nan)$", re.IGNORECASE)


class _Parser(argparse.ArgumentParser):
    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = _NEGATIVE_NUMBER

    def error(self, message):  # one line instead of argparse's usage + error
        # "argument --E: --E must be ..." -> "--E must be ..."
        message = re.sub(r"^argument (-[\w-]+): (?=\1 )", "", message)
        raise UsageError(f"{message} (see '{self.prog} --help')")


_CONTROL = re.compile("[\x00-\x1f\x7f-\x9f\u2028\u2029]")  # would break the one-line error message


def _number(kind: type, flag: str, meta: dict):
    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"{flag} must be {'an integer' if kind is int else 'a number'} {range_text(meta)} (got {text!r})")
        return value
    parse.__name__ = kind.__name__
    return parse


_STAGE_RANGE = re.compile(r"\s*([0-9]+)\s*(?:-\s*([0-9]+)\s*)?", re.ASCII)


def parse_stages(values: list[str], count: int, lesson_id: str) -> list[int]:
    """The stages that ``--stage`` values name, ascending and without repeats: each value is a
    comma-separated list of stage numbers (``3``) and ranges (``2-4``) in 1..``count``; a
    repeated ``--stage`` adds to the others (``["1", "3"]`` -> [1, 3]).
    Raises UsageError naming the first bad value and the valid range."""
    chosen: set[int] = set()
    for text in values:
        for piece in text.split(","):
            m = _STAGE_RANGE.fullmatch(piece)
            lo, hi = (int(m[1]), int(m[2] or m[1])) if m else (0, 0)
            if not (m and 1 <= lo <= hi <= count):
                shown = text if re.fullmatch(r"-?[0-9]+", text, re.ASCII) else repr(text)
                raise UsageError(f"--stage must be in 1..{count} for {lesson_id}: stage numbers, a list (1,3), "
                                 f"a range (2-3) or both (1,2-3) (got {shown})")
            chosen.update(range(lo, hi + 1))
    return sorted(chosen)


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


def _add_config_options(parser: argparse.ArgumentParser, config_cls, title: str | None = None) -> None:
    group = parser.add_argument_group(title or f"lesson parameters ({config_cls.__name__})")
    defaults = config_cls()
    for f in dataclasses.fields(config_cls):
        meta = f.metadata
        if not meta:
            continue
        kind = _field_type(f)
        flag = "--" + f.name.replace("_", "-")
        unit = f" [{meta['unit']}]" if meta.get("unit") else ""
        default = getattr(defaults, f.name)
        help_ = f"{meta['help']}{unit}; {range_text(meta)}" + ("" if default is None else f" (default: {default})")
        if kind is bool:
            group.add_argument(flag, dest=f.name, action=argparse.BooleanOptionalAction, default=None, help=help_)
        elif kind is str:
            group.add_argument(flag, dest=f.name, default=None, metavar="NAME", help=help_)
        else:
            group.add_argument(flag, dest=f.name, default=None, type=_number(kind, flag, meta),
                               metavar=kind.__name__.upper(), help=help_)


def _run_parser(lesson_ids: list[str], lesson=None) -> argparse.ArgumentParser:
    prog = "python -m lessons run"
    desc = ("Run a lesson's stages: each stage prints its narrative and a table of experiments "
            "(claim, theory, measured, tolerance, pass/fail) and logs everything to a Rerun recording.")
    if lesson is not None:
        desc = f"{lesson.id}: {lesson.title}. {lesson.summary}\nStages: " + "; ".join(
            f"{i}. {s.title}" for i, s in enumerate(lesson.stages, 1))
    p = _Parser(prog=prog, description=desc, formatter_class=argparse.RawDescriptionHelpFormatter,
                epilog="Exit codes: 0 all experiments passed, 1 an experiment failed, 2 bad input, "
                       "130 interrupted, 143 terminated. Environment: ELASTIC_ARCH, ELASTIC_THREADS, "
                       "ELASTIC_FP, ELASTIC_CACHE_DIR set the defaults of --arch/--threads/precision/cache.")
    p.add_argument("lesson", metavar="LESSON", help="lesson id (" + ", ".join(lesson_ids) + ") or 'all'")
    p.add_argument("--stage", action="append", default=None, metavar="N|A-B|LIST",
                   help="run only these stages (1-based): a number (3), a range (2-4), a list (1,3,5) or "
                        "both (2-3,5); repeating it adds stages (--stage 1 --stage 3); they run in "
                        "ascending order, each once (default: every stage); needs a single lesson")
    p.add_argument("--pause", action="store_true",
                   help="after each stage (with 'all', also after each lesson) wait for Enter before the "
                        "next; q + Enter (or Ctrl-D) stops there, the recording and results written as on "
                        "a normal end; needs an interactive terminal")
    rec = p.add_mutually_exclusive_group()
    rec.add_argument("--record", metavar="PATH", default=None,
                     help="write the Rerun recording to PATH (default: recordings/<id>.rrd); with 'all', "
                          "PATH is a directory that receives <id>.rrd for each lesson")
    rec.add_argument("--no-record", action="store_true", help="do not write a recording")
    p.add_argument("--results", metavar="PATH", default=None,
                   help="also write every experiment as JSON (list of {lesson, stage, id, claim, theory, "
                        "measured, tolerance, passed}; id: the experiment's stable name in its lesson) to PATH")
    p.add_argument("--threads", type=int, default=None, metavar="N",
                   help="CPU threads for Taichi (default: 2, or $ELASTIC_THREADS)")
    p.add_argument("--arch", default=None, metavar="NAME",
                   help="Taichi backend: cpu, cuda or vulkan (default: cpu, or $ELASTIC_ARCH)")
    p.add_argument("--view", action="store_true",
                   help="stream the run live into a Rerun viewer (started for it) that shows each stage as it "
                        "runs; the recording is written as well unless --no-record (needs a display)")
    p.add_argument("--quiet", action="store_true", help="print only the tables, not the narratives and progress")
    _add_config_options(p, Stepping, "time stepping (every lesson; runs that test one particular integrator "
                                     "keep it and are marked [fixed] in the stage's integrator line)")
    if lesson is not None:
        _add_config_options(p, lesson.config)
    return p


def _main_parser(lesson_ids: list[str]) -> argparse.ArgumentParser:
    p = _Parser(prog="python -m lessons",
                description="Elastic-simulation lessons in Taichi, recorded with Rerun.",
                epilog="Commands:\n  list              one line per lesson: id, title, stages\n"
                       "  run LESSON|all    run lessons (see 'python -m lessons run LESSON --help' for "
                       "the lesson's parameters)\n\nLessons: " + ", ".join(lesson_ids),
                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("command", choices=["list", "run"], help="list or run")
    return p


def _list(out) -> int:
    for lesson in registry.all_lessons():
        print(f"{lesson.id:22s} {lesson.title}  [{len(lesson.stages)} stages: "
              + "; ".join(s.title for s in lesson.stages) + "]", file=out)
    return EXIT_OK


def _record_paths(args, chosen) -> dict:
    if args.no_record:
        return {l.id: None for l in chosen}
    if args.record is None:
        return {l.id: Path("recordings") / f"{l.id}.rrd" for l in chosen}
    if len(chosen) > 1:
        return {l.id: Path(args.record) / f"{l.id}.rrd" for l in chosen}
    return {chosen[0].id: Path(args.record)}


def _check_output(flag: str, path: Path) -> None:
    from engine.recorder import check_writable  # imports rerun; only when recording
    try:
        check_writable(path)
    except OSError as exc:
        raise UsageError(f"{flag} {path}: cannot write there ({exc.strerror or exc}); "
                         f"choose a writable path{' or --no-record' if flag == '--record' else ''}")


def _check_results_path(path: Path) -> None:
    parent = path.parent if str(path.parent) else Path(".")
    try:
        ok = not path.is_dir() and parent.is_dir() and os.access(parent, os.W_OK)
    except OSError as exc:  # e.g. a name too long for the file system
        raise UsageError(f"--results {path}: cannot write there ({exc.strerror or exc})") from None
    if not ok:
        raise UsageError(f"--results {path}: cannot write there (the directory must exist and be writable)")


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


def _lesson_token(argv: list[str], lessons_) -> str | None:
    """The LESSON argument: the first token that is neither an option nor an option's value, so
    that options may come first (``run --stage 2 rod-waves``). Mirrors argparse: a value follows
    an option that takes one (spelled out or abbreviated) unless it looks like an option."""
    parsers = [_run_parser([], None)] + [_run_parser([], l) for l in lessons_]
    actions = [a for p in parsers for a in p._actions]
    options = {s for a in actions for s in a.option_strings}
    takes_value = {s for a in actions if a.nargs is None for s in a.option_strings}
    expect_value = False
    for i, tok in enumerate(argv):
        if tok == "--":
            return argv[i + 1] if i + 1 < len(argv) else None
        is_option = tok.startswith("-") and len(tok) > 1 and not _NEGATIVE_NUMBER.match(tok)
        if expect_value and not is_option:
            expect_value = False
            continue
        expect_value = False
        if not is_option:
            return tok
        if "=" not in tok:
            spelled = [tok] if tok in options else [o for o in options if tok.startswith("--") and o.startswith(tok)]
            expect_value = bool(spelled) and all(o in takes_value for o in spelled)
    return None


def run(argv: list[str], out=None, err=None, stdin=None) -> int:
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
        runtime.init(arch=args.arch, threads=args.threads)
        from .backends import check
        check(chosen, configs)  # f64 only, and the backends each lesson's physics holds on
    except runtime.RuntimeConfigError as exc:
        raise UsageError(str(exc)) from None

    if args.results:  # before --record, whose check creates missing directories
        _check_results_path(Path(args.results))
    paths = _record_paths(args, chosen)
    for p in paths.values():
        if p is not None:
            _check_output("--record", p)

    live = _live_viewer(args, paths, out)
    results: list[dict] = []
    all_passed = True
    finished_paths = []
    try:
        for number, l in enumerate(chosen, 1):
            if pause is not None and number > 1 and not pause.ask(
                    f"lesson {number}/{len(chosen)}: {l.id}, stage 1/{len(l.stages)}: {l.stages[0].title}"):
                break
            rec = _make_recorder(l, paths[l.id], live)
            # between= only with --pause (a runner stubbed in the tests may not take it)
            extra = {} if pause is None else {"between": pause.for_lesson(l)}
            try:
                ok = run_lesson(l, configs[l.id], rec, stages, out=out, err=err, quiet=args.quiet,
                                results=results, stepping=stepping, **extra)
            finally:
                final = rec.close()
                if getattr(rec, "live_error", None):
                    print(f"--view: the live viewer stopped receiving ({rec.live_error}); the recording "
                          f"file is complete", file=err)
            if final is not None:
                finished_paths.append(final)
                print(f"\nrecording: {final}  (open with: rerun {final})", file=out)
            all_passed &= ok
            if pause is not None and pause.stopped:
                break
    finally:
        if args.results:
            write_json_atomic(args.results, results)
    n_fail = sum(not r["passed"] for r in results)
    print(f"\n{len(results) - n_fail} of {len(results)} experiments passed"
          + ("" if n_fail == 0 else f"; {n_fail} FAILED"), file=out)
    return EXIT_OK if all_passed else EXIT_FAILED


def _make_recorder(lesson, path, live: bool = False):
    """The lesson's recorder: the file at ``path`` (None: no file), streaming into a viewer that
    follows the stage being run when ``live``."""
    from engine.recorder import NullRecorder, Recorder
    if path is None and not live:
        return NullRecorder()
    return Recorder(path, "elastic_lessons_" + lesson.id.replace("-", "_"), title=f"{lesson.id}: {lesson.title}",
                    camera=lesson.camera, live=live)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)

    def on_signal(signum, frame):
        note_signal(signum)  # acted on later if this raise lands in a __del__ and is swallowed
        raise KeyboardInterrupt() if signum == signal.SIGINT else Terminated()

    _pending_signal.clear()
    previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        lessons_ = registry.all_lessons()
        ids = [l.id for l in lessons_]
        if not argv:
            raise UsageError("a command is required: list or run (see 'python -m lessons --help')")
        if argv[0] in ("-h", "--help"):
            _main_parser(ids).print_help()
            return EXIT_OK
        command, rest = argv[0], argv[1:]
        if command == "list":
            if rest:
                raise UsageError(f"'list' takes no arguments (got {' '.join(rest)})")
            return _list(sys.stdout)
        if command == "run":
            return run(rest)
        raise UsageError(f"command must be 'list' or 'run' (got {command!r}); see 'python -m lessons --help'")
    except SystemExit as exc:  # --help
        return int(exc.code or 0)
    except UsageError as exc:  # one line, whatever the user typed (control characters escaped)
        message = _CONTROL.sub(lambda m: repr(m.group())[1:-1], str(exc))
        print(f"python -m lessons: error: {message}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("\ninterrupted: the recording and the results so far were written", file=sys.stderr)
        return EXIT_INT
    except Terminated:
        print("\nterminated: the recording and the results so far were written", file=sys.stderr)
        return EXIT_TERM
    except Exception as exc:  # a bug, not bad input: one line, the work so far kept, exit 1
        if os.environ.get("ELASTIC_DEBUG"):
            raise
        where = exc.__traceback__
        while where is not None and where.tb_next is not None:
            where = where.tb_next
        loc = f" at {Path(where.tb_frame.f_code.co_filename).name}:{where.tb_lineno}" if where else ""
        print(f"python -m lessons: internal error{loc}: {type(exc).__name__}: {exc} (the recording and the "
              f"results so far were written; set ELASTIC_DEBUG=1 for the traceback, and please report it)",
              file=sys.stderr)
        return EXIT_FAILED
    finally:
        _pending_signal.clear()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
