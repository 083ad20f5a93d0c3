"""``python -m lessons check LESSON --solution DIR``: grade a student's exercise.

For each lesson checked: the student's module ``DIR/<lesson id with _>.py`` is read; each function
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
"""
import ast
import math
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from .._exercise import StudentError, empty_functions, module_file
from .._framework import COMPARISONS, Experiment, Terminated, text_table
from . import channel
from .arguments import UsageError, Parser
from .exercises import exercise_module, lessons_with_exercises
from .results import encode, package_version, results_document
from .sandbox import copied_from, policy_problems

DEFAULT_TIME_LIMIT_S = 600.0
DEFAULT_MEMORY_GB = 4.0
UNIT_STAGE = 0   # the "stage" of the function-by-function checks in the results
PROJECT_ROOT = Path(__file__).resolve().parents[2]


def _parser(ids: list[str]) -> Parser:
    p = Parser(prog="python -m lessons check", description=(
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
                   help=f"seconds one check may take before it is stopped (the module's import, a function's checks, "
                        f"or one stage; default {DEFAULT_TIME_LIMIT_S:g})")
    p.add_argument("--memory-limit", type=float, default=DEFAULT_MEMORY_GB, metavar="GB",
                   help=f"address space the student's process may take, in GiB (0.5..256; default "
                        f"{DEFAULT_MEMORY_GB:g})")
    return p


def _experiment(row: dict) -> Experiment:
    num = lambda v: math.nan if v is None else v  # noqa: E731
    return Experiment(row["claim"], num(row["theory"]), num(row["measured"]), row["tolerance"], row["comparison"],
                      row.get("unit", ""), id=row["id"], reason=row.get("reason", ""))


_CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f]")


def printable(text: str) -> str:
    """Text from the student's process with its control characters escaped (an exception's message
    may carry terminal escapes that would redraw the table)."""
    return _CONTROL.sub(lambda m: repr(m.group())[1:-1], str(text))


def _failure(lesson_id: str, stage: int, id: str, claim: str, reason: str) -> dict:
    """A row for a check that could not run (the student's code did not import, is empty, ...)."""
    e = Experiment(claim, 1.0, 0.0, 0.0, ">=", id=id, reason=printable(reason))
    return e.to_dict(lesson_id, stage, "your functions" if stage == UNIT_STAGE else "")


class Stopped(Exception):
    """The child was stopped at the time limit."""


class Crashed(Exception):
    """The child ended without answering (its reason: a signal or its last words)."""


class Refused(Exception):
    """The child ended because the solution did what a solution may not (the guard's line)."""


class _Server:
    """One grading child for one student's module: started, asked, stopped (lessons.app.grading_child).

    It runs in its own session and process group (killed as a group), ends itself when this process
    ends (PR_SET_PDEATHSIG), and its CPU time is capped at ``limit`` times the work it may be given
    (a backstop: the grader stops it at ``limit`` seconds of wall time per request)."""

    def __init__(self, lesson_id: str, path: Path, limit: float, memory_bytes: int, workdir: Path, items: int):
        self.lesson_id, self.path, self.limit = lesson_id, path, limit
        self.memory, self.workdir, self.items = memory_bytes, workdir, items
        self.proc = None
        self.ready: dict = {}

    def start(self) -> dict:
        """Start the child and wait for its module to load (``limit`` s): returns its ready message, or
        raises Stopped (a hang at import), Crashed or Refused; ``{"error": line}`` for a module that
        does not import."""
        to_child_r, to_child_w = os.pipe()
        from_child_r, from_child_w = os.pipe()
        log_fd, self.log_path = tempfile.mkstemp(suffix=".log", dir=self.workdir)
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join([str(PROJECT_ROOT)] + [p for p in [env.get("PYTHONPATH")] if p])
        cpu = self.limit * (self.items + 2) * 2 + 120
        try:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "lessons.app.grading_child", self.lesson_id, str(self.path.resolve()), str(to_child_r),
                 str(from_child_w), str(os.getpid()), f"{cpu:.0f}", str(self.memory)],
                stdin=subprocess.DEVNULL, stdout=log_fd, stderr=subprocess.STDOUT, env=env, start_new_session=True,
                pass_fds=(to_child_r, from_child_w), cwd=self.workdir)
        finally:
            os.close(to_child_r)
            os.close(from_child_w)
            os.close(log_fd)
        self.to_child, self.reader = to_child_w, channel.Reader(from_child_r)
        self.ready = self._answer(time.monotonic() + self.limit)
        return self.ready

    def _answer(self, deadline: float) -> dict:
        try:
            answer = self.reader.read(deadline)
        except channel.ChannelTimeout:
            self.stop()
            raise Stopped() from None
        except channel.ChannelClosed:
            self.proc.wait()
            raise Crashed(self.crash_text()) from None
        except channel.ChannelError as exc:
            self.stop()
            raise Crashed(f"the student's process sent a malformed answer ({exc})") from None
        except (KeyboardInterrupt, Terminated):   # an interrupt of the grader stops the child with it
            self.stop()
            raise
        except Exception as exc:  # noqa: BLE001 - anything else in reading the child's answer: its fault
            self.stop()
            raise Crashed(f"the student's process sent a malformed answer ({type(exc).__name__})") from None
        except BaseException:
            self.stop()
            raise
        if not isinstance(answer, dict):
            self.stop()
            raise Crashed("the student's process sent a malformed answer (not an object)")
        if "violation" in answer:
            self.stop()
            raise Refused(str(answer["violation"])[:400])
        return answer

    def ask(self, request: dict, deadline: float) -> dict:
        try:
            channel.send(self.to_child, request, deadline)
        except channel.ChannelTimeout:   # the child stopped reading
            self.stop()
            raise Stopped() from None
        except OSError:   # the child is gone: its reason comes with the answer's end of the channel
            pass
        return self._answer(deadline)

    @property
    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def stop(self) -> None:
        """Kill the child and everything it started (its own process group), and reap it."""
        if self.proc is None:
            return
        try:
            os.killpg(self.proc.pid, 9)
        except (ProcessLookupError, PermissionError):
            pass
        self.proc.wait()
        for fd in (self.to_child, self.reader.fd):
            try:
                os.close(fd)
            except OSError:
                pass
        self.proc = None

    def crash_text(self, returns: str = "") -> str:
        """Why the child ended without its answer: a signal (a crash of Taichi's compiler, most
        often on a function that returns another type than it should), a limit, or its last words."""
        code = self.proc.returncode if self.proc is not None else None
        if code is not None and code < 0:
            if -code in (24,):   # SIGXCPU
                return "the CPU-time limit of the student's process was reached"
            hint = f": check that it returns {returns}" if returns else ""
            return f"the Taichi compiler crashed on it (signal {-code}){hint}"
        lines = [s for s in Path(self.log_path).read_text(encoding="utf-8", errors="replace").splitlines()
                 if s.strip() and not s.startswith("[Taichi]")]
        if any("MemoryError" in s or "bad_alloc" in s for s in lines[-5:]):
            return "the memory limit of the student's process was reached"
        return f"the check's process ended with exit code {code}" + (f": {lines[-1][:200]}" if lines else "")


class RemoteFunction:
    """The student's function as the checks see it here (lessons._exercise.LocalFunction's ``via``):
    each call is answered by the grading child within the task's deadline."""

    def __init__(self, name: str, grader: "Grader"):
        self.name, self.grader = name, grader

    def via(self, factory, *args):
        spec = f"{factory.__module__}:{factory.__qualname__}"

        def call(*inputs):
            answer = self.grader.call(self.name, spec, list(args), list(inputs))
            if "error" in answer:
                raise StudentError(printable(str(answer["error"])[:4000]))
            out = answer.get("ok")
            if answer.get("tuple") and isinstance(out, list) and all(hasattr(o, "shape") for o in out):
                return tuple(o.astype(float) for o in out)
            if hasattr(out, "shape") and out.dtype.kind in "fib":
                return out.astype(float)
            raise StudentError(f"{self.name}: the student's process sent no numbers")
        return call


ROW_TYPES = {"id": str, "claim": str, "tolerance": (int, float), "comparison": str}


def validated_rows(rows, lesson_id: str, index: int, title: str) -> list[dict]:
    """A stage's rows as the child sent them, checked field by field and rebuilt here (each verdict
    recomputed from theory, measured, tolerance and comparison); raises ValueError naming the first
    malformed field."""
    if not isinstance(rows, list) or not rows:
        raise ValueError("no rows")
    out, seen = [], set()
    for k, row in enumerate(rows):
        if not isinstance(row, dict):
            raise ValueError(f"row {k} is not an object")
        for key, kind in ROW_TYPES.items():
            if not isinstance(row.get(key), kind) or isinstance(row.get(key), bool):
                raise ValueError(f"row {k}'s {key} is missing or of the wrong type")
        for key in ("theory", "measured"):
            if row.get(key) is not None and (not isinstance(row[key], (int, float)) or isinstance(row[key], bool)):
                raise ValueError(f"row {k}'s {key} is not a number")
        if row["comparison"] not in COMPARISONS or row["id"] in seen:
            raise ValueError(f"row {k}'s comparison or id is not valid")
        seen.add(row["id"])
        num = lambda v: math.nan if v is None else float(v)  # noqa: E731
        try:
            e = Experiment(printable(row["claim"][:2000]), num(row["theory"]), num(row["measured"]),
                           float(row["tolerance"]), row["comparison"], printable(str(row.get("unit", ""))[:40]),
                           id=row["id"], reason=printable(str(row.get("reason", ""))[:2000]))
        except ValueError as exc:
            raise ValueError(f"row {k}: {exc}") from None
        d = e.to_dict(lesson_id, index, title)
        integrators = row.get("integrators")
        if isinstance(integrators, (str, list)) and all(isinstance(x, str) for x in integrators):
            d["integrators"] = integrators
        out.append(d)
    return out


class Grader:
    """Grades one lesson's module; collects rows and notes and prints the tables."""

    def __init__(self, lesson, solution_dir: Path, limit: float, out, workdir: Path, memory_bytes: int):
        self.lesson, self.limit, self.out, self.workdir = lesson, limit, out, workdir
        self.memory = memory_bytes
        self.tasks = exercise_module(lesson).TASKS
        self.path = module_file(solution_dir, lesson.id)
        self.rows: list[dict] = []
        self.notes: list[str] = []
        self.flags: list[str] = []              # for the instructor (e.g. a copy of the shipped solution)
        self.usable: list[str] = []
        self.failed_checks: dict[str, str] = {}   # function -> the id of its failed check
        self.refused = ""                          # the guard's line: nothing more is graded
        self.server: _Server | None = None
        self.deadline = math.inf
        self.hang = False

    # ---------------------------------------------------------------- the child
    def _server(self, items: int) -> _Server:
        if self.server is None or not self.server.alive:
            self.server = _Server(self.lesson.id, self.path, self.limit, self.memory, self.workdir, items)
            ready = self.server.start()
            self._note(ready.get("notes"))
            if "error" in ready:
                raise StudentError(str(ready["error"])[:400])
            own = ready.get("own")
            if ready.get("ready") is not True or not isinstance(own, dict) or \
                    not all(isinstance(k, str) and isinstance(v, str) for k, v in own.items()):
                self.server.stop()
                raise Crashed("the student's process sent a malformed answer (not ready)")
        return self.server

    def _note(self, notes) -> None:
        """Notes from the reading or from the child (checked: a list of strings, printable)."""
        if not isinstance(notes, list):
            return
        for n in notes[:20]:
            text = printable(n)[:300] if isinstance(n, str) else ""
            if text and text not in self.notes:
                self.notes.append(text)

    def call(self, name: str, factory: str, args: list, inputs: list) -> dict:
        server = self._server(len(self.tasks))
        answer = server.ask({"op": "call", "task": name, "factory": factory, "args": args, "inputs": inputs},
                            self.deadline)
        self._note(answer.pop("notes", None))
        return answer

    def close(self) -> None:
        if self.server is not None:
            self.server.stop()

    # ---------------------------------------------------------------- printing
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
            return f"{self.path.name}: line {exc.lineno}: {exc.msg}"
        except (OSError, UnicodeDecodeError, ValueError) as exc:
            return f"{self.path.name}: cannot be read: {exc}"
        except (RecursionError, MemoryError) as exc:
            return f"{self.path.name}: cannot be read: it nests too deeply for the parser ({type(exc).__name__})"
        return ""

    # ---------------------------------------------------------------- the function checks
    def functions(self) -> None:
        rows: list[dict] = []
        lesson = self.lesson.id

        def fail(id: str, claim: str, reason: str) -> None:
            rows.append(_failure(lesson, UNIT_STAGE, id, claim, reason))

        problem = self._module_problem()
        if problem:
            fail("ex-module", "your module can be read", problem)
            return self._done(rows)
        reading = policy_problems(self.path)
        self._note(reading.notes)
        reference = PROJECT_ROOT / "lessons" / self.lesson.id.replace("-", "_") / "solution.py"
        if copied_from(self.path, reference, [t.name for t in self.tasks]):
            self.flags.append("copy of the reference solution")
            self._note([f"{self.path.name}: every function is the reference solution shipped with the suite "
                        f"(lessons/{reference.parent.name}/solution.py), syntax tree for syntax tree: flagged for the "
                        f"instructor"])
        if reading.problems:
            more = f" (and {len(reading.problems) - 1} more)" if len(reading.problems) > 1 else ""
            self.refused = reading.problems[0] + more
            fail("ex-module-rules", "your module keeps to what a solution may do", self.refused)
            return self._done(rows)
        names = [t.name for t in self.tasks]
        defined = {n.name for n in ast.walk(ast.parse(self.path.read_text(encoding="utf-8")))
                   if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))}
        empty = set(empty_functions(self.path, names))
        todo = []
        for name in names:
            slug = name.replace("_", "-")
            if name not in defined:
                fail(f"ex-{slug}-written", f"{name} is written", f"{name}: not defined in {self.path.name}")
            elif name in empty:
                fail(f"ex-{slug}-written", f"{name} is written", f"{name}: not written yet (its body is empty)")
            else:
                todo.append(name)
        if todo:
            self._check_tasks(todo, rows, fail)
        self._done(rows)

    def _check_tasks(self, todo: list, rows: list, fail) -> None:
        try:
            self.deadline = time.monotonic() + self.limit
            ready = self._server(len(todo)).ready
        except Stopped:
            self.hang = True
            for name in todo:
                fail(f"ex-{name.replace('_', '-')}-runs", f"{name} runs",
                     f"your module did not finish importing within {self.limit:g} s (an endless loop at import?)")
            return
        except (StudentError, Crashed, Refused) as exc:
            if isinstance(exc, Refused):
                self.refused = str(exc)
            for name in todo:
                fail(f"ex-{name.replace('_', '-')}-runs", f"{name} runs", str(exc))
            return
        own = ready.get("own") if isinstance(ready.get("own"), dict) else {}
        tasks = {t.name: t for t in self.tasks}
        for name in todo:
            slug = name.replace("_", "-")
            if self.refused:
                fail(f"ex-{slug}-runs", f"{name} runs", f"not checked: {self.refused}")
                continue
            if own.get(name):
                fail(f"ex-{slug}-own", f"{name} is written in your module", str(own[name])[:300])
                continue
            self.deadline = time.monotonic() + self.limit
            try:
                found = [e.to_dict(self.lesson.id, UNIT_STAGE, "your functions")
                         for e in tasks[name].check(RemoteFunction(name, self))]
                rows.extend(found)
                self.usable.append(name)
                bad = next((r["id"] for r in found if not r["passed"]), "")
                if bad:
                    self.failed_checks[name] = bad
            except StudentError as exc:
                fail(f"ex-{slug}-runs", f"{name} runs", str(exc))
            except Stopped:
                fail(f"ex-{slug}-runs", f"{name} runs", f"{name}: stopped after {self.limit:g} s (an endless loop?)")
            except Crashed as exc:
                text = str(exc)
                if "Taichi compiler crashed" in text and tasks[name].returns:
                    text += f": check that it returns {tasks[name].returns}"
                fail(f"ex-{slug}-runs", f"{name} runs", f"{name}: {text}")
            except Refused as exc:
                self.refused = str(exc)
                fail(f"ex-{slug}-runs", f"{name} runs", self.refused)
            finally:
                self.deadline = math.inf

    def _done(self, rows: list) -> None:
        self.rows += rows
        self._print_table("your functions, each on its own", rows)
        for n in self.notes:
            self.out.write(f"   note: {n}\n")

    # ---------------------------------------------------------------- the stages
    def _needed(self, index: int) -> list:
        return [t.name for t in self.tasks if not t.stages or index in t.stages]

    def stages(self, indices: list) -> None:
        """The lesson's stages ``indices`` with the student's functions in the engine's place, in the
        grading child (started again after a stage that was stopped or crashed); a stage that needs a
        function which cannot be used is not run."""
        installed = [n for n in self.usable if any(n in self._needed(i) for i in indices)]
        for index in indices:
            title = self.lesson.stages[index - 1].title
            missing = [n for n in self._needed(index) if n not in self.usable]
            if self.refused or self.hang:
                rows = [self._stage_failure(index, f"not run: {self.refused or 'your module did not import'}")]
            elif missing:
                rows = [self._stage_failure(index, f"not run: it needs {', '.join(missing)}, which cannot be used "
                                                   f"yet (see above)")]
            else:
                rows = self._run_stage(index, title, installed)
            for r in rows:
                r["stage_title"] = title
            self._blame(index, rows)
            self.rows += rows
            ran = not (self.refused or self.hang or missing)
            hint = f" (this stage ran on your {', '.join(self._needed(index))})" if ran else ""
            self._print_table(f"stage {index}: {title}", rows, hint=hint)

    def _stage_failure(self, index: int, reason: str) -> dict:
        return _failure(self.lesson.id, index, f"stage{index}-ran", f"stage {index} ran with your functions", reason)

    def _run_stage(self, index: int, title: str, installed: list) -> list:
        try:
            fresh = self.server is None or not self.server.alive
            self.deadline = time.monotonic() + self.limit
            server = self._server(len(self.lesson.stages))
            if fresh or not getattr(server, "installed", False):
                server.ask({"op": "install", "names": installed}, self.deadline)
                server.installed = True
            answer = server.ask({"op": "stage", "index": index}, self.deadline)
            self._note(answer.pop("notes", None))
            if "error" in answer:
                return [self._stage_failure(index, str(answer["error"])[:4000])]
            return validated_rows(answer.get("rows"), self.lesson.id, index, title)
        except ValueError as exc:
            return [self._stage_failure(index, f"the stage's results came back malformed ({exc}): not graded")]
        except Stopped:
            return [self._stage_failure(index, f"stopped after {self.limit:g} s (an endless loop in one of "
                                               f"{', '.join(self._needed(index))}?)")]
        except (Crashed, StudentError) as exc:
            return [self._stage_failure(index, str(exc))]
        except Refused as exc:
            self.refused = str(exc)
            return [self._stage_failure(index, self.refused)]
        finally:
            self.deadline = math.inf

    def _blame(self, index: int, rows: list) -> None:
        """A failed claim of a stage that ran on a function which failed its own check says so."""
        suspects = [f"{n} (which failed {self.failed_checks[n]} above)" for n in self._needed(index)
                    if n in self.failed_checks]
        if not suspects:
            return
        for r in rows:
            if not r["passed"] and not r["id"].endswith("-ran"):
                blame = f"likely from your {' and '.join(suspects)}"
                r["reason"] = f"{r['reason']} ({blame})" if r.get("reason") else blame

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
    if resolved.parent == sol and (resolved.suffix == ".py" or resolved.is_dir()):
        raise UsageError(f"--results {shown_path(text)} is a file of the solution in {solution}: give the results "
                         f"another name (a .json file)")
    if resolved.suffix == ".py":
        raise UsageError(f"--results {shown_path(text)} would write JSON over a Python file: give the results a .json "
                         f"name")
    prepare_outputs([("--results", target)])
    return target


def check(argv: list[str], out=sys.stdout) -> int:
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
        wanted = [l for l in wanted if module_file(solution, l.id).exists()]
        if not wanted:
            raise UsageError(f"--solution {str(solution)!r} holds no lesson module ({', '.join(i.replace('-', '_') + '.py' for i in ids)})")
    elif not module_file(solution, args.lesson).exists():
        raise UsageError(f"{module_file(solution, args.lesson)} does not exist: write it first with "
                         f"'python -m lessons exercise {args.lesson} {solution}'")
    check_stages(wanted, args.stage)
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
                grader = Grader(lesson, solution, args.time_limit, out, Path(work), int(args.memory_limit * 2 ** 30))
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
