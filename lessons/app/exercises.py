"""``python -m lessons exercise LESSON [DIR]``: the student's template of a lesson's exercise.

The template is one Python module per lesson, ``DIR/<lesson id with _>.py``, with the functions
the student writes (lessons/<id>/exercise.py: TASKS): each with its signature, units and the
equation it implements, and an empty body. ``python -m lessons check LESSON --solution DIR``
grades it (lessons.app.grading).
"""
import importlib
import sys
import textwrap
from pathlib import Path

from .._exercise import NUMPY, TI_FUNC, module_file
from .arguments import UsageError
from .output_paths import write_all_or_none
from . import registry

TEMPLATE_HEAD = '''"""Exercise: {title}.

Write the body of every function below (each says what it computes, in which units, and which
equation of the lesson it is), then let the lesson grade your code:

    python -m lessons check {id} --solution {folder}

The check runs each function on its own first (against the lesson's formula, and every force and
Hessian against finite differences), then the lesson's own experiments with your functions in
place of the engine's: the engine's kernels are compiled around them.

{kinds}{labels}
"""
import numpy as np
import taichi as ti
'''

TI_FUNC_RULES = """Functions marked @ti.func are Taichi functions: they run inside the engine's kernels, once per
spring, hinge, triangle or vertex. Use Taichi's math on their arguments (d.norm(), a.dot(b),
a.cross(b), n.outer_product(n), ti.math.eye(3), ti.math.vec3(0.0), ti.sqrt, ti.atan2); `if` and `for` are
fine; numpy, Python lists and print are not. Give each function one `return`, at its end
(set the result before an `if`, then change it inside)."""

NUMPY_RULES = """Functions without @ti.func are set-up code: plain Python and numpy, called once with numpy
arrays before a run."""


def exercise_module(lesson):
    """The lesson's exercise module (lessons/<id>/exercise.py), or None when it has none."""
    try:
        return importlib.import_module(f"lessons.{lesson.id.replace('-', '_')}.exercise")
    except ModuleNotFoundError:
        return None


def lessons_with_exercises() -> list:
    return [l for l in registry.all_lessons() if exercise_module(l) is not None]


def template_text(lesson, folder: str) -> str:
    tasks = exercise_module(lesson).TASKS
    kinds = [TI_FUNC_RULES] if any(t.kind == TI_FUNC for t in tasks) else []
    kinds += [NUMPY_RULES] if any(t.kind == NUMPY for t in tasks) else []
    table = getattr(exercise_module(lesson), "LABELS", {})
    labels = ("\n\nThe equations the functions below cite:\n" + "\n".join(
        textwrap.fill(f"({k}) {v}", width=100, subsequent_indent="     ") for k, v in table.items())) if table else ""
    parts = [TEMPLATE_HEAD.format(title=lesson.title, id=lesson.id, folder=folder, kinds="\n\n".join(kinds),
                                  labels=labels)]
    for t in tasks:
        decorator = "@ti.func\n" if t.kind == TI_FUNC else ""
        doc = t.doc.rstrip() + (f"\n\nReturns: {t.returns}" if t.returns else "")
        parts.append(f"\n\n{decorator}def {t.name}({t.args}):\n"
                     f'{textwrap.indent(chr(34) * 3 + doc + chr(10) + chr(34) * 3, "    ")}\n'
                     f"    ...  # your code here\n")
    return "".join(parts)


def write_template(argv: list[str], out, err=sys.stderr) -> int:
    """``exercise LESSON|all [DIR]``: write the templates; refuse to overwrite a file."""
    available = lessons_with_exercises()
    ids = [l.id for l in available]
    if not argv:
        raise UsageError(f"LESSON is required: one of {', '.join(ids)}, or all (see 'python -m lessons exercise "
                         f"--help')")
    if argv[0] in ("-h", "--help"):
        out.write(f"usage: python -m lessons exercise LESSON [DIR]\n\nWrite the student's template of LESSON's "
                  f"exercise (or of every lesson: all) to DIR/<lesson>.py (DIR: ./exercises).\n"
                  f"Then: python -m lessons check LESSON --solution DIR.\nLessons: {', '.join(ids)}\n")
        return 0
    if len(argv) > 2:
        raise UsageError(f"'exercise' takes LESSON and an optional DIR (got {' '.join(argv)})")
    wanted = available if argv[0] == "all" else [l for l in available if l.id == argv[0]]
    if not wanted:
        raise UsageError(f"LESSON must be one of {', '.join(ids)} or all (got {argv[0]!r})")
    folder = Path(argv[1] if len(argv) > 1 else "exercises")
    if folder.exists() and not folder.is_dir():
        raise UsageError(f"DIR {str(folder)!r} is a file: give a folder for the exercise templates")
    targets = [(l, module_file(folder, l.id)) for l in wanted]
    existing = [str(p) for _, p in targets if p.exists()]
    if existing:
        raise UsageError(f"{', '.join(existing)} already exists: it may hold your work; give another DIR "
                         f"or move it away first")
    write_all_or_none(folder, [(path, template_text(lesson, str(folder)).encode("utf-8")) for lesson, path in targets],
                      "the templates")
    for lesson, path in targets:
        names = ", ".join(t.name for t in exercise_module(lesson).TASKS)
        out.write(f"wrote {path}: {names}\n")
    first = wanted[0].id if len(wanted) == 1 else "LESSON"
    out.write(f"next: write the functions' bodies, then: python -m lessons check {first} --solution {folder}\n")
    return 0
