"""Exercises as notebooks: ``python -m lessons exercise LESSON DIR --notebook`` and a notebook graded.

The notebook ``DIR/<lesson id with _>.ipynb`` is made of the module template's own pieces
(lessons.app.exercises: the instructions, the imports, each function's signature, docstring and
empty body), so the two never drift: a Markdown cell with the instructions, a cell with the
imports, one cell per function, and a last cell, the check cell (its first line is
:data:`CHECK_MARK`), that grades the notebook and shows the claim table.

A notebook handed in is graded as a module (lessons.app.grading): :func:`read_notebook` takes its
code cells in the notebook's order (Markdown and raw cells are text; the check cell is left out),
joins them into one module and keeps where each cell starts, so that the grader's lines say
"springs.ipynb: cell 4, line 2" (cells counted from 1, every cell of the notebook counted, as they
stand top to bottom). The module then goes through everything a module goes through: the reading
of what a solution may not do, the guarded child, the time and memory limits. Leaving out the
check cell only ever grades less: whatever a cell holds, it is read and run under the same rules.
A function defined in two cells is the last one, as running the notebook top to bottom leaves it
(a note says so). IPython's own syntax, magics (``%run``, ``%%bash``) and shell escapes
(``!rm``), is not Python: a cell with it refuses the notebook, in one line naming the cell, and so
does ``get_ipython()`` (lessons.app.sandbox): a shell escape is a way out of the grading child. A
notebook's code may import numpy, math, cmath and taichi, not modules beside it. A file that is
not a notebook (not JSON, not nbformat 4) is one line naming it, exit 2, before anything is graded.

What the check cell grades: the notebook as saved on disk, found through the kernel
(``__session__`` in Jupyter, ``__vsc_ipynb_file__`` in VS Code, else ``<lesson>.ipynb`` in the
kernel's folder), copied and graded by ``python -m lessons check`` in a process of its own. Not the
kernel's live functions: a function object can be anything (its code, its globals, what it
closes over), and the grader reads source, never objects. Not IPython's history either: it holds
every cell ever run, deleted and edited ones included, in the order they ran. The saved notebook is
what the student sees (once saved: the cell says when the file was saved) and exactly what
``python -m lessons check LESSON --solution DIR`` and ``grade`` will grade.
"""
from __future__ import annotations

import ast
import html
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

from .._exercise import module_file
from .arguments import UsageError
from .exercises import IMPORTS, exercise_module, function_templates, instructions

CHECK_MARK = "# check cell: grades this notebook as saved (not part of your solution)"


def notebook_file(folder: Path, lesson_id: str) -> Path:
    """Where a lesson's notebook lives in a solution folder: ``<dir>/<lesson id with _>.ipynb``."""
    return Path(folder) / (lesson_id.replace("-", "_") + ".ipynb")


def solution_file(folder: Path, lesson_id: str) -> Path | None:
    """The student's solution of ``lesson_id`` in ``folder``: the module, or else the notebook, or
    None. Both there is a UsageError: which one is the solution is the student's to say."""
    module, notebook = module_file(folder, lesson_id), notebook_file(folder, lesson_id)
    if module.exists() and notebook.exists():
        raise UsageError(f"{module} and {notebook} are both there: a solution is one of them; move the other "
                         f"away")
    return module if module.exists() else notebook if notebook.exists() else None


# ------------------------------------------------------------------ the notebook, generated

def _cell(kind: str, text: str, cell_id: str) -> dict:
    cell = {"cell_type": kind, "id": cell_id, "metadata": {}, "source": text}
    return cell if kind == "markdown" else {**cell, "execution_count": None, "outputs": []}


def check_source(lesson_id: str) -> str:
    return (f"{CHECK_MARK}\nfrom lessons.app.exercise_notebook import check_notebook\n\n"
            f"# save the notebook first; check_notebook({lesson_id!r}, functions_only=True) skips the lesson's stages\n"
            f"check_notebook({lesson_id!r})")


def exercise_notebook(lesson, folder: str) -> dict:
    """The exercise of ``lesson`` as a notebook (nbformat 4, as a dict)."""
    how = (f"Run the last cell of this notebook (save it first: it grades the notebook as saved), or in a terminal:\n\n"
           f"    python -m lessons check {lesson.id} --solution {folder}")
    text = instructions(lesson, how)
    title, _, rest = text.partition("\n")
    cells = [_cell("markdown", f"# {title}\n{rest}", "instructions"),
             _cell("code", IMPORTS.rstrip("\n"), "imports")]
    for task, source in zip(exercise_module(lesson).TASKS, function_templates(lesson)):
        cells.append(_cell("code", source.rstrip("\n"), task.name.replace("_", "-")))
    cells.append(_cell("code", check_source(lesson.id), "check"))
    return {"nbformat": 4, "nbformat_minor": 5, "cells": cells,
            "metadata": {"kernelspec": {"name": "python3", "display_name": "Python 3", "language": "python"},
                         "language_info": {"name": "python"}}}


def notebook_bytes(lesson, folder: str) -> bytes:
    return (json.dumps(exercise_notebook(lesson, folder), indent=1) + "\n").encode("utf-8")


# ------------------------------------------------------------------ a notebook read as a module

class NotebookError(Exception):
    """The file is not a notebook that can be read (one line naming it)."""


@dataclass
class Extracted:
    """A notebook's code as one module: ``source``; ``starts``: (first line in the module, cell
    number, lines) of each cell taken; ``unreadable``/``problems``: cells that refuse the notebook
    (Python's syntax errors; IPython's syntax), one line each; ``notes`` for the student."""
    path: Path
    source: str = ""
    starts: list = field(default_factory=list)
    unreadable: list = field(default_factory=list)
    problems: list = field(default_factory=list)
    notes: list = field(default_factory=list)

    def where(self, line: int) -> str:
        """``cell C, line L`` of the module's line ``line``."""
        for first, cell, count in reversed(self.starts):
            if line >= first:
                return f"cell {cell}, line {min(line - first + 1, max(count, 1))}"
        return f"line {line}"

    def relabel(self, text: str) -> str:
        """The grader's text about the module made about the notebook: ``x.py: line N`` becomes
        ``x.ipynb: cell C, line L``."""
        module = module_file(Path(), self.path.stem).name
        text = re.sub(re.escape(module) + r"(: |, )line (\d+)",
                      lambda m: f"{self.path.name}{m.group(1)}{self.where(int(m.group(2)))}", str(text))
        return text.replace(module, self.path.name)


IPYTHON_SYNTAX = re.compile(r"^\s*([%!]|[\w.]+\s*=\s*[%!]|[\w.]*\?\??\s*$|\?)")


def _magic_line(lines: list[str]) -> int:
    """The first line (from 1) that is IPython's syntax (a magic, a shell escape, ``x = !cmd``,
    ``name?``), or 0. Asked only of a cell that is not Python: a line of a string is never taken."""
    return next((k for k, line in enumerate(lines, 1) if IPYTHON_SYNTAX.match(line)), 0)


def read_notebook(path: Path) -> Extracted:
    """The notebook ``path`` as one module (see the module docstring); NotebookError, one line,
    when it is not a notebook."""
    path = Path(path)
    try:
        import nbformat
    except ImportError:
        raise NotebookError(f"{path}: reading a notebook needs nbformat: pip install -e '.[notebook]', or hand in "
                            f"the module") from None
    try:
        text = path.read_text(encoding="utf-8")
        json.loads(text)
        nb = nbformat.reads(text, as_version=4)
        nbformat.validate(nb)
    except json.JSONDecodeError as exc:
        raise NotebookError(f"{path}: is not a Jupyter notebook (not JSON: line {exc.lineno}, column {exc.colno}: "
                            f"{exc.msg}): save it again from Jupyter or write the module instead") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise NotebookError(f"{path}: cannot be read ({type(exc).__name__}): save it again from Jupyter") from None
    except Exception as exc:  # noqa: BLE001 - JSON, nbformat's validation: the file is not a notebook
        why = " ".join(str(exc).split())[:160]
        raise NotebookError(f"{path}: is not a Jupyter notebook ({type(exc).__name__}: {why}): save it again from "
                            f"Jupyter or write the module instead") from None
    out = Extracted(path)
    lines: list[str] = []
    defined: dict[str, list[int]] = {}
    for number, cell in enumerate(nb.cells, 1):
        text = cell.source if isinstance(cell.source, str) else "".join(cell.source)
        if cell.cell_type != "code" or text.lstrip().startswith(CHECK_MARK):
            continue
        cell_lines = text.splitlines()
        try:
            tree = ast.parse(text)
        except SyntaxError as exc:
            magic = _magic_line(cell_lines)
            if magic:
                out.problems.append(f"{path.name}: cell {number}, line {magic}: {cell_lines[magic - 1].strip()[:60]!r} "
                                    f"is IPython's syntax (a magic or a shell command), not Python: a solution is "
                                    f"Python only; remove it")
            else:
                out.unreadable.append(f"{path.name}: cell {number}, line {exc.lineno}: {exc.msg}")
            continue
        except (ValueError, RecursionError, MemoryError) as exc:
            out.unreadable.append(f"{path.name}: cell {number}: cannot be read ({type(exc).__name__})")
            continue
        for node in tree.body:
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                defined.setdefault(node.name, []).append(number)
        out.starts.append((len(lines) + 1, number, len(cell_lines)))
        lines += cell_lines + [""]
    out.source = "\n".join(lines) + "\n"
    for name, cells in defined.items():
        if len(cells) > 1:
            out.notes.append(f"{path.name}: {name} is defined in cells {', '.join(map(str, cells))}: the last one is "
                             f"graded (as running the notebook top to bottom leaves it)")
    return out


# ------------------------------------------------------------------ the check cell

class CheckReport:
    """What ``python -m lessons check`` said of the notebook: shown as HTML tables in Jupyter, as the
    check's text elsewhere. ``passed``: every claim held."""

    def __init__(self, notebook: Path, exit_code: int, text: str, rows: list):
        self.notebook, self.exit_code, self.text, self.rows = notebook, exit_code, text, rows

    @property
    def passed(self) -> bool:
        return self.exit_code == 0 and bool(self.rows) and all(r.get("passed") for r in self.rows)

    def __repr__(self) -> str:
        return self.text

    def _repr_html_(self) -> str:
        if not self.rows:
            return f"<pre>{html.escape(self.text)}</pre>"
        parts, head = [], "".join(f"<th>{h}</th>" for h in ("result", "claim", "theory", "measured", "why"))
        titles: dict = {}
        for r in self.rows:
            titles.setdefault((r.get("stage"), r.get("stage_title") or "your functions, each on its own"), []).append(r)
        for (stage, title), rows in titles.items():
            text = lambda r, key: html.escape(str(r.get(key) if r.get(key) is not None else ""))  # noqa: E731
            body = "".join(f"<tr><td><b>{'PASS' if r.get('passed') else 'FAIL'}</b></td>"
                           f"<td style='text-align:left'>{text(r, 'claim')}</td><td>{text(r, 'theory')}</td>"
                           f"<td>{text(r, 'measured')}</td><td style='text-align:left'>{text(r, 'reason')}</td></tr>"
                           for r in rows)
            name = f"stage {stage}: {title}" if stage else title
            parts.append(f"<h4>{html.escape(name)}: {sum(bool(r.get('passed')) for r in rows)} of {len(rows)} claims "
                         f"hold</h4><table><tr>{head}</tr>{body}</table>")
        summary = [line for line in self.text.splitlines() if "claims passed" in line or "note:" in line]
        return "".join(parts) + "".join(f"<p>{html.escape(s.strip())}</p>" for s in summary)


def this_notebook(lesson_id: str) -> Path:
    """The notebook the check cell runs in (see the module docstring)."""
    names = []
    try:
        from IPython import get_ipython
        shell = get_ipython()
        ns = shell.user_ns if shell is not None else {}
        names = [ns.get("__vsc_ipynb_file__"), ns.get("__session__")]
    except ImportError:
        pass
    for name in names:
        if isinstance(name, str) and name.endswith(".ipynb"):
            for candidate in (Path(name), Path.cwd() / Path(name).name):
                if candidate.is_file():
                    return candidate
    return notebook_file(Path.cwd(), lesson_id)


def check_notebook(lesson_id: str, functions_only: bool = False, stages=(), time_limit: float | None = None,
                   notebook: str | os.PathLike | None = None) -> CheckReport:
    """Grade the notebook (as saved) with ``python -m lessons check`` in a process of its own: the same
    reading, guarded child and limits as a module; the live functions of this kernel are never used."""
    from .grading_remote import PROJECT_ROOT
    path = Path(notebook) if notebook is not None else this_notebook(lesson_id)
    if not path.is_file():
        return CheckReport(path, 2, f"{path} is not there: save this notebook as {notebook_file(Path(), lesson_id)} "
                                    f"or give its file: check_notebook({lesson_id!r}, notebook='...')", [])
    print(f"grading {path} as saved at {time.strftime('%H:%M:%S', time.localtime(path.stat().st_mtime))} ...",
          flush=True)
    options = (["--functions-only"] if functions_only else []) + [f"--stage={s}" for s in stages] + \
        ([f"--time-limit={time_limit:g}"] if time_limit is not None else [])
    with tempfile.TemporaryDirectory(prefix="elastic-notebook-") as work:
        folder = Path(work) / "solution"
        folder.mkdir()
        shutil.copyfile(path, notebook_file(folder, lesson_id))
        results = Path(work) / "results.json"
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join([str(PROJECT_ROOT)] + [p for p in [env.get("PYTHONPATH")] if p])
        done = subprocess.run([sys.executable, "-m", "lessons", "check", lesson_id, "--solution", str(folder),
                               "--results", str(results), *options], cwd=work, env=env, stdin=subprocess.DEVNULL,
                              capture_output=True, text=True)
        rows = json.loads(results.read_text())["experiments"] if results.is_file() else []
    text = (done.stdout + done.stderr).replace(str(notebook_file(folder, lesson_id)), str(path)).strip()
    return CheckReport(path, done.returncode, text, rows)
