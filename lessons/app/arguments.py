"""The command line's arguments (:mod:`lessons.app.cli`): the parsers of ``python -m lessons`` and
``python -m lessons run`` (one line per error, each option but ``--stage`` given once, a
lesson's parameters as options), ``--stage`` lists and ranges, and the LESSON among the tokens."""
from __future__ import annotations

import argparse
import dataclasses
import difflib
import re

from .._framework import Stepping, field_type, range_text

class UsageError(Exception):
    """Bad command-line input: reported as one line, exit code 2."""


# What argparse takes for a (negative) number rather than an option: by default only -1 and
# -1.5, so "--E -1e-3" or "--E -inf" would be reported as a missing value instead of a bad one.
_NEGATIVE_NUMBER = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$|^-(inf|infinity|nan)$", re.IGNORECASE)


class Parser(argparse.ArgumentParser):
    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = _NEGATIVE_NUMBER
        self._given: dict = {}

    def parse_known_args(self, args=None, namespace=None):
        self._given = {}  # action -> the option string that set it (repeats are refused)
        return super().parse_known_args(args, namespace)

    def _get_values(self, action, arg_strings):
        # "--E=--": argparse (3.11) drops the "--" of an attached value like an end-of-options marker
        # and hands the option an empty list, unconverted and unchecked; the "--" is the value given
        if action.option_strings and action.nargs is None and arg_strings == ["--"]:
            value = self._get_value(action, "--")
            self._check_value(action, value)
            return value
        return super()._get_values(action, arg_strings)

    def error(self, message):  # one line instead of argparse's usage + error
        # "argument --E: --E must be ..." -> "--E must be ..."
        message = re.sub(r"^argument (-[\w-]+): (?=\1 )", "", message)
        m = re.match(r"unrecognized arguments: (.*)", message)
        if m:
            message += _suggestion(m[1].split(), self._option_string_actions)
        raise UsageError(f"{message} (see '{self.prog} --help')")


def _suggestion(tokens: list[str], options) -> str:
    """'; did you mean --E?' for the first unknown option close to a known one (e.g. -E 4)."""
    known = sorted(o for o in options if o.startswith("--"))
    for tok in tokens:
        if not tok.startswith("-") or _NEGATIVE_NUMBER.match(tok):
            continue
        name = tok.split("=", 1)[0]
        close = difflib.get_close_matches(name, known, n=1, cutoff=0.6)
        if not close and not name.startswith("--"):
            close = difflib.get_close_matches("-" + name, known, n=1, cutoff=0.6)
        if close:
            return f"; did you mean {close[0]}?"
    return ""


_ONCE_CLASSES: dict = {}


def _given_once(parser: argparse.ArgumentParser) -> None:
    """Make every option of ``parser`` but the repeatable ones (append actions: --stage) refuse a
    second use: argparse would silently keep the last value (--E 1 --E 2)."""
    for action in parser._actions:
        base = type(action)
        if not action.option_strings or isinstance(action, (argparse._AppendAction, argparse._HelpAction,
                                                             argparse._VersionAction)):
            continue
        if base not in _ONCE_CLASSES:
            def __call__(self, parser_, namespace, values, option_string=None, _base=base):
                given = getattr(parser_, "_given", None)
                if given is not None:
                    if self in given:
                        first = given[self]
                        name = next((o for o in self.option_strings if o.startswith("--")), self.option_strings[0])
                        also = "" if first == option_string else f" (as {first} and {option_string})"
                        raise UsageError(f"{name} is given twice{also}: give each option once (only --stage "
                                         f"may be repeated)")
                    given[self] = option_string
                _base.__call__(self, parser_, namespace, values, option_string)
            _ONCE_CLASSES[base] = type(f"Once{base.__name__}", (base,), {"__call__": __call__})
        action.__class__ = _ONCE_CLASSES[base]


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


# at most 9 digits: a longer number is out of range anyway, and int() refuses more than 4300 digits
_STAGE_RANGE = re.compile(r"\s*([0-9]{1,9})\s*(?:-\s*([0-9]{1,9})\s*)?", re.ASCII)


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


def _add_config_options(parser: argparse.ArgumentParser, config_cls, title: str | None = None) -> None:
    group = parser.add_argument_group(title or f"lesson parameters ({config_cls.__name__})")
    defaults = config_cls()
    for f in dataclasses.fields(config_cls):
        meta = f.metadata
        if not meta:
            continue
        kind = field_type(f)
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


def run_parser(lesson_ids: list[str], lesson=None) -> argparse.ArgumentParser:
    prog = "python -m lessons run"
    desc = ("Run a lesson's stages: each stage prints its narrative and a table of experiments "
            "(claim, theory, measured, tolerance, pass/fail) and logs everything to a Rerun recording.")
    if lesson is not None:
        desc = f"{lesson.id}: {lesson.title}. {lesson.summary}\nStages: " + "; ".join(
            f"{i}. {s.title}" for i, s in enumerate(lesson.stages, 1))
    p = Parser(prog=prog, description=desc, formatter_class=argparse.RawDescriptionHelpFormatter,
                epilog="Exit codes: 0 all experiments passed, 1 an experiment failed (or an output file could "
                       "not be written), 2 bad input, 130 interrupted (SIGINT), 143 terminated (SIGTERM), 129 "
                       "hung up (SIGHUP), 141 output pipe closed. Environment: ELASTIC_ARCH, ELASTIC_THREADS, "
                       "ELASTIC_FP, ELASTIC_CACHE_DIR set the defaults of --arch/--threads/precision/cache; "
                       "ELASTIC_PIN=off leaves Taichi's CPU threads unbound (default auto: one CPU each when "
                       "as many as the CPUs); TI_LOG_LEVEL Taichi's log level. Every option but --stage may be "
                       "given once.")
    p.add_argument("lesson", metavar="LESSON", help="lesson id (" + ", ".join(lesson_ids) + ") or 'all'")
    p.add_argument("--stage", action="append", default=None, metavar="N|A-B|LIST",
                   help="run only these stages (1-based): a number (3), a range (2-4), a list (1,3,5) or "
                        "both (2-3,5); repeating it adds stages (--stage 1 --stage 3); they run in "
                        "ascending order, each once (default: every stage); needs a single lesson")
    p.add_argument("--pause", action="store_true",
                   help="after each stage (with 'all', also after each lesson) wait for Enter before the "
                        "next; q + Enter (or Ctrl-D) stops there, the recording and results of the stages run "
                        "written (as partial: see --overwrite-partial); needs an interactive terminal")
    rec = p.add_mutually_exclusive_group()
    rec.add_argument("--record", metavar="PATH", default=None,
                     help="write the Rerun recording to PATH (default: recordings/<id>.rrd); PATH ending in / "
                          "(and, with 'all', any PATH) is a directory that receives <id>.rrd; missing "
                          "directories are created; only a regular file (or a new name) is replaced")
    rec.add_argument("--no-record", action="store_true", help="do not write a recording")
    p.add_argument("--results", metavar="PATH", default=None,
                   help="also write the results as JSON to PATH: an object with the run's metadata (complete, "
                        "exit_reason, lessons, stages asked and completed, parameters, runtime, version, times) "
                        "and 'experiments', a list of {lesson, stage, id, claim, theory, measured, tolerance, "
                        "passed, ...} (id: the experiment's stable name in its lesson); missing directories are "
                        "created; '-' and '' are refused (the tables go to standard output)")
    p.add_argument("--overwrite-partial", action="store_true",
                   help="a run that does not complete (interrupted, stopped at --pause, failed to write) writes "
                        "its recording and results under the final names, replacing earlier files (still "
                        "marked partial inside); default: <stem>.partial.rrd / <stem>.partial.json, so that a "
                        "complete earlier file is never replaced by a partial one")
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
    _given_once(p)
    return p


def main_parser(lesson_ids: list[str]) -> argparse.ArgumentParser:
    p = Parser(prog="python -m lessons",
                description="Elastic-simulation lessons in Taichi, recorded with Rerun.",
                epilog="Commands:\n  list              one line per lesson: id, title, stages\n"
                       "  run LESSON|all    run lessons (see 'python -m lessons run LESSON --help' for "
                       "the lesson's parameters)\n"
                       "  exercise LESSON|all [DIR]\n"
                       "                    write a student's template: the lesson's formulas to write\n"
                       "  check LESSON|all --solution DIR\n"
                       "                    grade a student's functions with the lesson's own experiments\n"
                       "                    (see 'python -m lessons check --help')\n"
                       "  grade ROSTER [LESSON|all]\n"
                       "                    grade a class in parallel (Dask): gradebook CSV, Gradescope files\n"
                       "                    (see 'python -m lessons grade --help')\n"
                       "  view FILE.rrd [--web]\n"
                       "                    open a recording in Rerun's viewer; --web serves the web viewer on\n"
                       "                    this machine and prints its address (see 'python -m lessons view --help')\n"
                       "  notebook LESSON|all DIR\n"
                       "                    write each lesson as a Jupyter notebook generated from it\n"
                       "                    (see 'python -m lessons notebook --help')"
                       "\n\nLessons: " + ", ".join(lesson_ids),
                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("command", choices=["list", "run", "exercise", "check", "grade", "view", "notebook"],
                   help="list, run, exercise, check, grade, view or notebook")
    p.add_argument("--version", action="version", version=f"%(prog)s {_version()}",
                   help="print the package version and exit")
    return p


def _version() -> str:
    from .results import package_version
    return f"(elastic-lessons) {package_version()}"


def lesson_token(argv: list[str], lessons_) -> str | None:
    """The LESSON argument: the first token that is neither an option nor an option's value, so
    that options may come first (``run --stage 2 rod-waves``). Mirrors argparse: a value follows
    an option that takes one (spelled out or abbreviated) unless it looks like an option."""
    parsers = [run_parser([], None)] + [run_parser([], l) for l in lessons_]
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
