"""``python -m lessons check LESSON --solution DIR``: grade a student's exercise.

For each lesson checked: the student's module ``DIR/<lesson id with _>.py`` is read; each function
with an empty body is one line "not written yet"; the written ones are checked on their own (the
lesson's ``exercise.TASKS``: against the lesson's formula, forces and Hessians against finite
differences); then the lesson's own stages run with the student's functions in the engine's
place. The function checks run in one child process and the stages in another
(lessons.app.grading_child), each function and each stage under a time limit (a child stopped or
crashed is started again for the rest), so a student's error is one line naming the function and an
endless loop is stopped. The claim table
is the lessons' own, ``--results`` the same JSON as ``run --results``. Exit 0 when every claim
passes, 1 when one fails, 2 for bad input.
"""
import ast
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from .._exercise import empty_functions, module_file
from .._framework import Experiment, text_table, write_json_atomic
from .arguments import UsageError, _Parser
from .exercises import exercise_module, lessons_with_exercises
from .results import package_version, results_document

DEFAULT_TIME_LIMIT_S = 600.0
UNIT_STAGE = 0   # the "stage" of the function-by-function checks in the results
PROJECT_ROOT = Path(__file__).resolve().parents[2]


def _parser(ids: list[str]) -> _Parser:
    p = _Parser(prog="python -m lessons check", description=(
        "Grade a student's exercise: each function the student wrote is checked on its own (against the "
        "lesson's formula; forces and Hessians against finite differences), then the lesson's own "
        "experiments run with the student's functions in place of the engine's. Exit 0 when every claim "
        "passes, 1 when one fails."))
    p.add_argument("lesson", metavar="LESSON", help=f"one of {', '.join(ids)}, or all")
    p.add_argument("--solution", metavar="DIR", required=True,
                   help="the folder with the student's <lesson>.py (written by 'python -m lessons exercise')")
    p.add_argument("--stage", type=int, action="append", metavar="N",
                   help="run only this stage of the lesson (repeatable; default: every stage)")
    p.add_argument("--functions-only", action="store_true",
                   help="check the functions on their own only, without the lesson's stages")
    p.add_argument("--results", metavar="FILE", help="write the claims as JSON (the format of 'run --results')")
    p.add_argument("--time-limit", type=float, default=DEFAULT_TIME_LIMIT_S, metavar="S",
                   help=f"seconds one check may take before it is stopped (a function's checks, or one stage; "
                        f"default {DEFAULT_TIME_LIMIT_S:g})")
    return p


def _experiment(row: dict) -> Experiment:
    num = lambda v: math.nan if v is None else v  # noqa: E731
    return Experiment(row["claim"], num(row["theory"]), num(row["measured"]), row["tolerance"], row["comparison"],
                      row.get("unit", ""), id=row["id"], reason=row.get("reason", ""))


def _failure(lesson_id: str, stage: int, id: str, claim: str, reason: str) -> dict:
    """A row for a check that could not run (the student's code did not import, is empty, ...)."""
    e = Experiment(claim, 1.0, 0.0, 0.0, ">=", id=id, reason=reason)
    return e.to_dict(lesson_id, stage, "your functions" if stage == UNIT_STAGE else "")


class _Child:
    """One child process of checks: started, read line by line, stopped at its time limit."""

    def __init__(self, lesson_id: str, solution: Path, args: list[str], limit: float, workdir: Path):
        self.out_path = Path(tempfile.mkstemp(suffix=".jsonl", dir=workdir)[1])
        self.log_path = self.out_path.with_suffix(".log")
        self.log = open(self.log_path, "w", encoding="utf-8")
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join([str(PROJECT_ROOT)] + [p for p in [env.get("PYTHONPATH")] if p])
        self.proc = subprocess.Popen([sys.executable, "-m", "lessons.app.grading_child", lesson_id, str(solution),
                                      str(self.out_path), *args], stdout=self.log, stderr=subprocess.STDOUT,
                                     env=env, start_new_session=True)
        self.limit = limit
        self.lines: list[dict] = []

    def _read(self) -> None:
        text = self.out_path.read_text(encoding="utf-8")
        self.lines = [json.loads(s) for s in text.splitlines() if s.strip()]

    def wait(self) -> bool:
        """Wait for the child; the limit counts from its start and again from each function's start.
        Returns False when it was stopped at the limit."""
        deadline = time.monotonic() + self.limit
        seen = 0
        try:
            while self.proc.poll() is None:
                time.sleep(0.05)
                self._read()
                if len(self.lines) > seen:
                    if any("start" in line for line in self.lines[seen:]):
                        deadline = time.monotonic() + self.limit
                    seen = len(self.lines)
                if time.monotonic() > deadline:
                    self.stop()
                    self._read()
                    return False
        except BaseException:   # an interrupt (Ctrl-C, a signal) of the grader stops the check with it
            self.stop()
            raise
        self._read()
        return True

    def stop(self) -> None:
        """Kill the child and everything it started (its own process group), and reap it."""
        try:
            os.killpg(self.proc.pid, 9)
        except ProcessLookupError:
            pass
        self.proc.wait()

    def crash_text(self, returns: str = "") -> str:
        """Why the child ended without its result: a signal (a crash of Taichi's compiler, most
        often on a function that returns another type than it should) or its last words."""
        if self.proc.returncode is not None and self.proc.returncode < 0:
            hint = f": check that it returns {returns}" if returns else ""
            return f"the Taichi compiler crashed on it (signal {-self.proc.returncode}){hint}"
        return self._last_words()

    def _last_words(self) -> str:
        lines = [s for s in self.log_path.read_text(encoding="utf-8", errors="replace").splitlines() if s.strip() and not s.startswith("[Taichi]")]
        return f"the check's process ended with exit code {self.proc.returncode}" + (f": {lines[-1][:200]}" if lines else "")

    def close(self) -> None:
        self.log.close()


class Grader:
    """Grades one lesson's module; collects rows and prints the tables."""

    def __init__(self, lesson, solution_dir: Path, limit: float, out, workdir: Path):
        self.lesson, self.limit, self.out, self.workdir = lesson, limit, out, workdir
        self.tasks = exercise_module(lesson).TASKS
        self.path = module_file(solution_dir, lesson.id)
        self.rows: list[dict] = []
        self.usable: list[str] = []

    def _print_table(self, title: str, rows: list[dict], hint: str = "") -> None:
        self.out.write(f"\n== {self.lesson.id} · {title}\n")
        exps = [_experiment(r) for r in rows]
        self.out.write(text_table(exps) + "\n")
        for e in exps:
            if not e.passed:
                why = e.reason or (f"measured {e.measured:.6g} against {e.theory:.6g} ({e.tolerance_text()})"
                                   f"{' ' + e.unit if e.unit else ''}")
                self.out.write(f"   FAIL {e.id}: {why}{hint}\n")
        self.out.flush()

    def _module_problem(self) -> str:
        """One line when the module cannot be graded at all, else ''."""
        try:
            ast.parse(self.path.read_text(encoding="utf-8"), filename=str(self.path))
        except SyntaxError as exc:
            return f"{self.path}: line {exc.lineno}: {exc.msg}"
        except (OSError, UnicodeDecodeError) as exc:
            return f"{self.path}: cannot be read: {exc}"
        return ""

    def functions(self) -> None:
        """The function-by-function checks."""
        rows: list[dict] = []
        problem = self._module_problem()
        if problem:
            rows.append(_failure(self.lesson.id, UNIT_STAGE, "ex-module", "your module can be read", problem))
            self.rows += rows
            self._print_table("your functions", rows)
            return
        names = [t.name for t in self.tasks]
        defined = {n.name for n in ast.walk(ast.parse(self.path.read_text(encoding="utf-8"))) if isinstance(n, ast.FunctionDef)}
        empty = set(empty_functions(self.path, names))
        todo = []
        for name in names:
            if name not in defined:
                rows.append(_failure(self.lesson.id, UNIT_STAGE, f"ex-{name.replace('_', '-')}-written",
                                     f"{name} is written", f"{name}: not defined in {self.path.name}"))
            elif name in empty:
                rows.append(_failure(self.lesson.id, UNIT_STAGE, f"ex-{name.replace('_', '-')}-written",
                                     f"{name} is written", f"{name}: not written yet (its body is empty)"))
            else:
                todo.append(name)
        def outcome(name, result, why):
            if result is not None and "rows" in result:
                rows.extend(result["rows"])
                self.usable.append(name)
            else:
                rows.append(_failure(self.lesson.id, UNIT_STAGE, f"ex-{name.replace('_', '-')}-runs", f"{name} runs",
                                     why or result["error"]))

        def stopped(name, finished, child):
            returns = next(t.returns for t in self.tasks if t.name == name)
            return (f"{name}: stopped after {self.limit:g} s (an endless loop?)" if not finished
                    else f"{name}: {child.crash_text(returns)}")
        self._in_children(todo, lambda left: ["units", *left], "task", lambda name: name, outcome, stopped)
        self.rows += rows
        self._print_table("your functions, each on its own", rows)

    def _in_children(self, todo: list, args_of, key: str, start_of, outcome, stopped) -> None:
        """Run the items ``todo`` (functions or stages) in a child process, ``args_of(items)`` its
        arguments, and again for the items after one that was stopped at the time limit or crashed.
        The child writes one line per finished item under ``key`` and a "start" line
        (``start_of(item)``) before each. ``outcome(item, its line, None)`` takes a finished item,
        ``outcome(item, None, why)`` one that could not run: the child broke before it (its error for
        every item), or it was the one running when the child stopped (``stopped(item, finished, child)``
        says why)."""
        while todo:
            child = _Child(self.lesson.id, self.path, args_of(todo), self.limit, self.workdir)
            finished = child.wait()
            child.close()
            results = {line[key]: line for line in child.lines if key in line}
            broken = next((line["error"] for line in child.lines if "error" in line and key not in line), "")
            left = []
            for position, item in enumerate(todo):
                if broken:
                    outcome(item, None, broken)
                elif item in results:
                    outcome(item, results[item], None)
                elif any(line.get("start") == start_of(item) for line in child.lines) or position == 0:
                    outcome(item, None, stopped(item, finished, child))
                    left = todo[position + 1:]
                    break
            todo = left

    def _needed(self, index: int) -> list:
        return [t.name for t in self.tasks if not t.stages or index in t.stages]

    def stages(self, indices: list) -> None:
        """The lesson's stages ``indices`` with the student's functions in the engine's place, in one
        child process (started again after a stage that was stopped or crashed); a stage that needs
        a function which cannot be used is not run."""
        found: dict = {}
        runnable = []
        for index in indices:
            missing = [n for n in self._needed(index) if n not in self.usable]
            if missing:
                found[index] = [_failure(self.lesson.id, index, f"stage{index}-ran",
                                         f"stage {index} ran with your functions",
                                         f"not run: it needs {', '.join(missing)}, which cannot be used yet "
                                         f"(see above)")]
            else:
                runnable.append(index)
        installed = [t.name for t in self.tasks if any(t.name in self._needed(i) for i in runnable)]

        def outcome(index, result, why):
            found[index] = (result or {}).get("rows") or [_failure(
                self.lesson.id, index, f"stage{index}-ran", f"stage {index} ran with your functions",
                why or result["error"])]

        def stopped(index, finished, child):
            return (f"stopped after {self.limit:g} s (an endless loop in one of {', '.join(self._needed(index))}?)"
                    if not finished else child.crash_text())
        self._in_children(runnable, lambda left: ["stages", ",".join(map(str, left)), *installed], "stage",
                          lambda index: f"stage {index}", outcome, stopped)
        for index in indices:
            title = self.lesson.stages[index - 1].title
            rows = found[index]
            for r in rows:
                r["stage_title"] = title
            self.rows += rows
            hint = "" if index not in runnable else f" (this stage ran on your {', '.join(self._needed(index))})"
            self._print_table(f"stage {index}: {title}", rows, hint=hint)


def check(argv: list[str], out=sys.stdout) -> int:
    available = lessons_with_exercises()
    ids = [l.id for l in available]
    args = _parser(ids).parse_args(argv)
    if args.lesson != "all" and args.lesson not in ids:
        raise UsageError(f"LESSON must be one of {', '.join(ids)} or all (got {args.lesson!r})")
    if not (args.time_limit > 0 and math.isfinite(args.time_limit)):
        raise UsageError(f"--time-limit must be a number of seconds > 0 (got {args.time_limit:g})")
    solution = Path(args.solution)
    if not solution.is_dir():
        raise UsageError(f"--solution {str(solution)!r} is not a folder: give the folder written by "
                         f"'python -m lessons exercise {args.lesson}'")
    wanted = [l for l in available if args.lesson in ("all", l.id)]
    if args.lesson == "all":
        wanted = [l for l in wanted if module_file(solution, l.id).exists()]
        if not wanted:
            raise UsageError(f"--solution {str(solution)!r} holds no lesson module ({', '.join(i.replace('-', '_') + '.py' for i in ids)})")
    elif not module_file(solution, args.lesson).exists():
        raise UsageError(f"{module_file(solution, args.lesson)} does not exist: write it first with "
                         f"'python -m lessons exercise {args.lesson} {solution}'")
    for lesson in wanted:
        bad = [s for s in (args.stage or []) if not 1 <= s <= len(lesson.stages)]
        if bad:
            raise UsageError(f"--stage must be in 1..{len(lesson.stages)} for {lesson.id} (got {bad[0]})")
    if args.results is not None:
        if args.results.strip() in ("", "-"):
            raise UsageError(f"--results needs a file name (got {args.results!r})")
        from .output_paths import _output
        _output("--results", args.results, False)
    started = time.time()
    rows: list[dict] = []
    with tempfile.TemporaryDirectory(prefix="elastic-check-") as work:
        for lesson in wanted:
            grader = Grader(lesson, solution, args.time_limit, out, Path(work))
            grader.functions()
            if not args.functions_only:
                grader.stages(list(args.stage or range(1, len(lesson.stages) + 1)))
            rows += grader.rows
    failed = sum(not r["passed"] for r in rows)
    out.write(f"\n{len(rows) - failed} of {len(rows)} claims passed"
              + (f"; {failed} failed (see the FAIL lines above)" if failed else "") + "\n")
    if args.results:
        doc = results_document(rows, complete=True, exit_code=1 if failed else 0,
                               exit_reason="completed", lessons=[l.id for l in wanted], solution=str(solution),
                               command=["python", "-m", "lessons", "check", *argv], version=package_version(),
                               elapsed_s=round(time.time() - started, 3))
        write_json_atomic(args.results, doc)
        out.write(f"results: {args.results}\n")
    return 1 if failed else 0
