"""One lesson's module graded: :class:`Grader` checks each function the student wrote on its own,
then runs the lesson's stages with the student's functions in the engine's place (both in the
grading child, lessons.app.grading_remote), and prints the claim tables.
"""
import ast
import math
import time
from pathlib import Path

from .._exercise import StudentError, empty_functions, module_file
from .._framework import Experiment, text_table
from .exercises import exercise_module
from .grading_remote import (PROJECT_ROOT, Crashed, Refused, RemoteFunction, Server, Stopped, printable,
                             validated_rows)
from .sandbox import copied_from, policy_problems

UNIT_STAGE = 0   # the "stage" of the function-by-function checks in the results


def _experiment(row: dict) -> Experiment:
    num = lambda v: math.nan if v is None else v  # noqa: E731
    return Experiment(row["claim"], num(row["theory"]), num(row["measured"]), row["tolerance"], row["comparison"],
                      row.get("unit", ""), id=row["id"], reason=row.get("reason", ""))


def _failure(lesson_id: str, stage: int, id: str, claim: str, reason: str) -> dict:
    """A row for a check that could not run (the student's code did not import, is empty, ...)."""
    e = Experiment(claim, 1.0, 0.0, 0.0, ">=", id=id, reason=printable(reason))
    return e.to_dict(lesson_id, stage, "your functions" if stage == UNIT_STAGE else "")


class Grader:
    """Grades one lesson's module; collects rows and notes and prints the tables."""

    def __init__(self, lesson, solution_dir: Path, limit: float, out, workdir: Path, memory_bytes: int,
                 notebook=None):
        """``notebook``: the student's notebook read as a module (lessons.app.exercise_notebook.Extracted),
        graded from a folder of its own in ``workdir``, its lines told as the notebook's cells."""
        self.lesson, self.limit, self.out, self.workdir = lesson, limit, out, workdir
        self.memory = memory_bytes
        self.tasks = exercise_module(lesson).TASKS
        self.path = module_file(solution_dir, lesson.id)
        self.notebook = notebook
        if notebook is not None:
            folder = workdir / f"notebook-{lesson.id}"
            folder.mkdir()
            self.path = module_file(folder, lesson.id)
            self.path.write_text(notebook.source, encoding="utf-8")
        self.rows: list[dict] = []
        self.notes: list[str] = []
        self.flags: list[str] = []              # for the instructor (e.g. a copy of the shipped solution)
        self.usable: list[str] = []
        self.failed_checks: dict[str, str] = {}   # function -> the id of its failed check
        self.refused = ""                          # the guard's line: nothing more is graded
        self.server: Server | None = None
        self.deadline = math.inf
        self.hang = False

    # ---------------------------------------------------------------- the child
    def _server(self, items: int) -> Server:
        if self.server is None or not self.server.alive:
            self.server = Server(self.lesson.id, self.path, self.limit, self.memory, self.workdir, items)
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
            text = self._shown(printable(n))[:300] if isinstance(n, str) else ""
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
    def _shown(self, text: str) -> str:
        """The grader's text about the module, about the notebook when the solution is one."""
        return self.notebook.relabel(text) if self.notebook is not None and text else text

    def _print_table(self, title: str, rows: list[dict], hint: str = "") -> None:
        for r in rows:
            if r.get("reason"):
                r["reason"] = self._shown(r["reason"])
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

        if self.notebook is not None:
            self._note(self.notebook.notes)
            if self.notebook.unreadable or self.notebook.problems:
                found = self.notebook.unreadable or self.notebook.problems
                more = f" (and {len(found) - 1} more)" if len(found) > 1 else ""
                if self.notebook.unreadable:
                    fail("ex-module", "your module can be read", found[0] + more)
                else:
                    self.refused = found[0] + more
                    fail("ex-module-rules", "your module keeps to what a solution may do", self.refused)
                return self._done(rows)
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
