"""What one ``python -m lessons run`` asks for, checked before anything runs: the lesson named,
its parameter overrides, the stepping options, ``--stage``, ``--pause`` (its prompt between
stages) and each chosen lesson's configuration (lessons.app.cli runs the plan)."""
from __future__ import annotations

import dataclasses

from . import registry
from .arguments import UsageError, lesson_token, run_parser, parse_stages
from .._framework import Stepping, validate_config


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



@dataclasses.dataclass
class RunRequest:
    """What one ``run`` asks for, checked: its arguments as typed (``argv``) and parsed (``args``),
    the lessons to run, the stepping options, the stage numbers (None: every stage), the ``--pause``
    prompt (None without it) and each lesson's configuration by id."""

    argv: list[str]
    args: object
    chosen: list
    stepping: Stepping
    stages: list[int] | None
    pause: _Pause | None
    configs: dict


def _parse_lesson_argument(argv: list[str]):
    """Parse ``run``'s arguments with the parser of the lesson they name; returns (the parsed
    arguments, the lessons to run, the lesson named or None for 'all'). A missing or unknown
    lesson is a UsageError."""
    lessons_ = registry.all_lessons()
    ids = [l.id for l in lessons_]
    by_id = {l.id: l for l in lessons_}
    lesson_arg = lesson_token(argv, lessons_)
    lesson = by_id.get(lesson_arg)
    parser = run_parser(ids, lesson)
    if lesson_arg is None and not any(a in ("-h", "--help") for a in argv):
        raise UsageError("LESSON is required: one of " + ", ".join(ids) + ", or all")
    if lesson_arg is not None and lesson is None and lesson_arg != "all":
        raise UsageError(f"LESSON must be one of {', '.join(ids)}, or all (got {lesson_arg!r})")
    args = parser.parse_args(argv)
    return args, (lessons_ if args.lesson == "all" else [lesson]), lesson


def plan_run(argv: list[str], stdin, out) -> RunRequest:
    """Parse and check ``run``'s arguments: the lesson, its parameter overrides, the stepping
    options, ``--stage`` and ``--pause``, and every chosen lesson's configuration. Bad input is a
    UsageError; nothing has run yet."""
    args, chosen, lesson = _parse_lesson_argument(argv)
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
    configs = _validated_configs(chosen, lesson, overrides, stepping)
    return RunRequest(argv, args, chosen, stepping, stages, pause, configs)


def _validated_configs(chosen: list, lesson, overrides: dict, stepping: Stepping) -> dict:
    """Each chosen lesson's configuration by id (the overrides apply to ``lesson``, the one named),
    validated with the stepping options before any kernel runs or any file is written; a bad value
    is a UsageError."""
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
    return configs


