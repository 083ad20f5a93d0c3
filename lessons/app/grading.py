"""``python -m lessons check LESSON --solution DIR``: grade a student's exercise.

For each lesson checked: the student's module ``DIR/<lesson id with _>.py`` (or, when there is no
module, the notebook ``DIR/<lesson id with _>.ipynb``, read as one module of its code cells:
lessons.app.exercise_notebook; both there is bad input) is read; each function
with an empty body is one line "not written yet"; the module (and its own modules beside it) is
read for what a solution may not do (lessons.app.sandbox: imports other than numpy, math, cmath,
taichi and its own; builtins and attributes that reach files, processes or other code); then the
written functions are checked on their own (the lesson's ``exercise.TASKS``: against the lesson's
formula, forces and Hessians against finite differences) and the lesson's own stages run with the
student's functions in the engine's place.

Only the grading child (lessons.app.grading_child) runs the student's code, under the guard, a
CPU-time and a memory limit, in its own process group, ended with the grader however the grader
ends. The checks themselves run here: the child gets the inputs and returns the student's outputs,
and every verdict is computed here, from values read and validated here (a malformed answer is a
failed claim with its reason). Each function and each stage has ``--time-limit`` seconds; a module
that hangs at import is charged once; a stopped or crashed child is started again for the rest.
The claim table is the lessons' own, ``--results`` the same JSON as ``run --results``, prepared
before the grading (refused up front when it cannot be written or would replace a file of the
solution) and written, marked partial, when the check is interrupted. Exit 0 when every claim
passes, 1 when one fails, 2 for bad input.

This module holds the command (its arguments, the checks on them shared with ``grade``, the results
file); one lesson's module is graded by lessons.app.grading_lesson, and the grading child is
started, asked and its answers checked by lessons.app.grading_remote.
"""
import math
import os
import sys
import tempfile
import time
from pathlib import Path

from .._exercise import module_file
from .._framework import Terminated
from .arguments import UsageError, Parser
from .exercise_notebook import NotebookError, read_notebook, solution_file
from .exercises import lessons_with_exercises
from .grading_lesson import Grader
from .results import encode, package_version, results_document

DEFAULT_TIME_LIMIT_S = 600.0
DEFAULT_MEMORY_GB = 4.0


def _parser(ids: list[str]) -> Parser:
    p = Parser(prog="python -m lessons check", description=(
        "Grade a student's exercise: each function the student wrote is checked on its own (against the "
        "lesson's formula; forces and Hessians against finite differences), then the lesson's own "
        "experiments run with the student's functions in place of the engine's. Exit 0 when every claim "
        "passes, 1 when one fails."))
    p.add_argument("lesson", metavar="LESSON", help=f"one of {', '.join(ids)}, or all")
    p.add_argument("--solution", metavar="DIR", required=True,
                   help="the folder with the student's <lesson>.py or <lesson>.ipynb (written by 'python -m lessons "
                        "exercise')")
    p.add_argument("--stage", type=int, action="append", metavar="N",
                   help="run only this stage of the lesson (repeatable; default: every stage)")
    p.add_argument("--functions-only", action="store_true",
                   help="check the functions on their own only, without the lesson's stages")
    p.add_argument("--results", metavar="FILE", help="write the claims as JSON (the format of 'run --results')")
    p.add_argument("--time-limit", type=float, default=DEFAULT_TIME_LIMIT_S, metavar="S",
                   help=f"seconds one check may take before it is stopped (the module's import, a function's checks, "
                        f"or one stage; default {DEFAULT_TIME_LIMIT_S:g})")
    p.add_argument("--memory-limit", type=float, default=DEFAULT_MEMORY_GB, metavar="GB",
                   help=f"address space the student's process may take, in GiB (0.5..256; default "
                        f"{DEFAULT_MEMORY_GB:g})")
    return p


def check_limits(args) -> None:
    """``--time-limit`` and ``--memory-limit`` (check and grade): bad values are UsageError."""
    if not (args.time_limit > 0 and math.isfinite(args.time_limit)):
        raise UsageError(f"--time-limit must be a number of seconds > 0 (got {args.time_limit:g})")
    if not (0.5 <= args.memory_limit <= 256):
        raise UsageError(f"--memory-limit must be a number of GiB in 0.5..256 (got {args.memory_limit:g})")


def check_stages(lessons, stages) -> None:
    """Every ``--stage`` in range for every lesson asked (check and grade)."""
    for lesson in lessons:
        bad = [s for s in (stages or []) if not 1 <= s <= len(lesson.stages)]
        if bad:
            raise UsageError(f"--stage must be in 1..{len(lesson.stages)} for {lesson.id} (got {bad[0]})")


def _end_with_parent(signal_number: int) -> None:
    """Ask Linux to send ``signal_number`` to this process when its parent ends (a no-op elsewhere)."""
    try:
        import ctypes
        ctypes.CDLL(None).prctl(1, signal_number)   # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def _results_target(text: str, solution: Path):
    """``--results PATH`` checked and its temporary file created before any grading (bad input,
    exit 2, when it cannot be written or would replace a file of the student's solution)."""
    from .output_paths import output_target, prepare_outputs, shown_path
    if text.strip() in ("", "-"):
        raise UsageError(f"--results needs a file name (got {text!r})")
    target = output_target("--results", text, False)
    resolved = Path(os.path.realpath(target.path))
    sol = Path(os.path.realpath(solution))
    if resolved.parent == sol and (resolved.suffix in (".py", ".ipynb") or resolved.is_dir()):
        raise UsageError(f"--results {shown_path(text)} is a file of the solution in {solution}: give the results "
                         f"another name (a .json file)")
    if resolved.suffix == ".py":
        raise UsageError(f"--results {shown_path(text)} would write JSON over a Python file: give the results a .json "
                         f"name")
    prepare_outputs([("--results", target)])
    return target


def check(argv: list[str], out=sys.stdout, err=sys.stderr) -> int:
    available = lessons_with_exercises()
    ids = [l.id for l in available]
    args = _parser(ids).parse_args(argv)
    if args.lesson != "all" and args.lesson not in ids:
        raise UsageError(f"LESSON must be one of {', '.join(ids)} or all (got {args.lesson!r})")
    check_limits(args)
    solution = Path(args.solution)
    if not solution.is_dir():
        raise UsageError(f"--solution {str(solution)!r} is not a folder: give the folder written by "
                         f"'python -m lessons exercise {args.lesson}'")
    wanted = [l for l in available if args.lesson in ("all", l.id)]
    if args.lesson == "all":
        wanted = [l for l in wanted if solution_file(solution, l.id) is not None]
        if not wanted:
            raise UsageError(f"--solution {str(solution)!r} holds no lesson module or notebook "
                             f"({', '.join(i.replace('-', '_') + '.py' for i in ids)}, or .ipynb)")
    elif solution_file(solution, args.lesson) is None:
        raise UsageError(f"{module_file(solution, args.lesson)} does not exist: write it first with "
                         f"'python -m lessons exercise {args.lesson} {solution}' (--notebook: as a notebook)")
    check_stages(wanted, args.stage)
    notebooks = {}
    for lesson in wanted:
        path = solution_file(solution, lesson.id)
        if path.suffix == ".ipynb":
            try:
                notebooks[lesson.id] = read_notebook(path)
            except NotebookError as exc:
                raise UsageError(str(exc)) from None
    target = _results_target(args.results, solution) if args.results is not None else None
    if os.environ.get("ELASTIC_GRADE_TASK") == "1":   # a task of 'grade': end (cleanly) with the worker
        _end_with_parent(signal_number=15)
    from engine import runtime
    runtime.init()   # the checks' own references run here; the student's code only in the grading child
    started = time.time()
    rows: list[dict] = []
    notes: list[str] = []
    flags: dict[str, list] = {}
    meta = dict(lessons=[l.id for l in wanted], solution=str(solution), command=["python", "-m", "lessons", "check",
                *argv], version=package_version())
    exit_code, reason, complete = 0, "completed", False
    try:
        with tempfile.TemporaryDirectory(prefix="elastic-check-") as work:
            for lesson in wanted:
                grader = Grader(lesson, solution, args.time_limit, out, Path(work), int(args.memory_limit * 2 ** 30),
                                notebooks.get(lesson.id))
                try:
                    grader.functions()
                    if not args.functions_only:
                        grader.stages(list(args.stage or range(1, len(lesson.stages) + 1)))
                finally:
                    grader.close()
                    rows += grader.rows
                    notes += [f"{lesson.id}: {n}" for n in grader.notes]
                    if grader.flags:
                        flags[lesson.id] = list(grader.flags)
        complete = True
        failed = sum(not r["passed"] for r in rows)
        exit_code = 1 if failed else 0
        out.write(f"\n{len(rows) - failed} of {len(rows)} claims passed"
                  + (f"; {failed} failed (see the FAIL lines above)" if failed else "") + "\n")
    except (KeyboardInterrupt, Terminated) as exc:   # the child is stopped already (Grader.close)
        signum = getattr(exc, "signum", 2)
        exit_code = 128 + signum
        reason = {2: "interrupted (SIGINT)", 15: "terminated (SIGTERM)", 1: "hung up (SIGHUP)"}.get(
            signum, f"signal {signum}")
    written = ""
    if target is not None:
        doc = results_document(rows, complete=complete, exit_code=exit_code, exit_reason=reason, notes=notes, flags=flags,
                               elapsed_s=round(time.time() - started, 3), **meta)
        try:
            target.write_bytes(encode(doc))
            written = str(target.commit(complete))
            out.write(f"results: {written}" + ("" if complete else " (partial: the check did not finish)") + "\n")
        except OSError as exc:
            target.discard()
            out.write(f"results: could not be written ({exc.strerror or exc}); nothing was written\n")
            exit_code = exit_code or 1
    if not complete:
        sys.stderr.write(f"\n{reason}: " + (f"the claims graded so far are in {written}, marked partial\n" if written
                                             else "nothing was written (no --results)\n" if target is None
                                             else "nothing was written\n"))
    return exit_code
