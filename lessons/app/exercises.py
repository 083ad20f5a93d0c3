"""``python -m lessons exercise LESSON [DIR]``: the student's template of a lesson's exercise.

The template is one Python module per lesson, ``DIR/<lesson id with _>.py``, with the functions
the student writes (lessons/<id>/exercise.py: TASKS): each with its signature, units and the
equation it implements, and an empty body. ``python -m lessons check LESSON --solution DIR``
grades it (lessons.app.grading). With ``--notebook`` the template is a Jupyter notebook,
``DIR/<lesson id with _>.ipynb``, made of the same pieces (lessons.app.exercise_notebook). A folder
holds one of the two per lesson: neither is written over an existing module or notebook.
"""
import importlib
import sys
import textwrap
from pathlib import Path

from .._exercise import NUMPY, TI_FUNC, module_file
from .arguments import UsageError
from .output_paths import write_all_or_none
from . import registry

INSTRUCTIONS = """Exercise: {title}.

Write the body of every function below (each says what it computes, in which units, and which
equation of the lesson it is), then let the lesson grade your code:

{how}

The check runs each function on its own first (against the lesson's formula, and every force and
Hessian against finite differences), then the lesson's own experiments with your functions in
place of the engine's: the engine's kernels are compiled around them.

{kinds}{labels}"""
HOW_MODULE = "    python -m lessons check {id} --solution {folder}"
IMPORTS = "import numpy as np\nimport taichi as ti\n"


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


def instructions(lesson, how: str) -> str:
    """The exercise's instructions (the module template's docstring, a notebook's first cell): ``how``
    says how to have the functions graded."""
    tasks = exercise_module(lesson).TASKS
    kinds = [TI_FUNC_RULES] if any(t.kind == TI_FUNC for t in tasks) else []
    kinds += [NUMPY_RULES] if any(t.kind == NUMPY for t in tasks) else []
    table = getattr(exercise_module(lesson), "LABELS", {})
    labels = ("\n\nThe equations the functions below cite:\n" + "\n".join(
        textwrap.fill(f"({k}) {v}", width=100, subsequent_indent="     ") for k, v in table.items())) if table else ""
    return INSTRUCTIONS.format(title=lesson.title, how=how, kinds="\n\n".join(kinds), labels=labels)


def function_templates(lesson) -> list[str]:
    """Each function the student writes: decorator, signature, docstring and an empty body (the
    module template and the notebook's cells are both made of these)."""
    parts = []
    for t in exercise_module(lesson).TASKS:
        decorator = "@ti.func\n" if t.kind == TI_FUNC else ""
        doc = t.doc.rstrip() + (f"\n\nReturns: {t.returns}" if t.returns else "")
        parts.append(f"{decorator}def {t.name}({t.args}):\n"
                     f'{textwrap.indent(chr(34) * 3 + doc + chr(10) + chr(34) * 3, "    ")}\n'
                     f"    ...  # your code here\n")
    return parts


def template_text(lesson, folder: str) -> str:
    how = HOW_MODULE.format(id=lesson.id, folder=folder)
    return f'"""{instructions(lesson, how)}\n"""\n{IMPORTS}' + "".join("\n\n" + f for f in function_templates(lesson))


def write_template(argv: list[str], out, err=sys.stderr) -> int:
    """``exercise LESSON|all [DIR] [--notebook]``: write the templates; refuse to overwrite a file
    (or to write a notebook beside the module of the same lesson, or the other way round)."""
    from .exercise_notebook import notebook_bytes, notebook_file
    available = lessons_with_exercises()
    ids = [l.id for l in available]
    notebook = "--notebook" in argv
    argv = [a for a in argv if a != "--notebook"]
    if not argv:
        raise UsageError(f"LESSON is required: one of {', '.join(ids)}, or all (see 'python -m lessons exercise "
                         f"--help')")
    if argv[0] in ("-h", "--help"):
        out.write(f"usage: python -m lessons exercise LESSON [DIR] [--notebook]\n\nWrite the student's template of "
                  f"LESSON's exercise (or of every lesson: all) to DIR/<lesson>.py (DIR: ./exercises).\n"
                  f"--notebook: write it as a Jupyter notebook, DIR/<lesson>.ipynb, instead: one cell per function, "
                  f"and a last cell that grades the notebook as saved and shows the claim table.\n"
                  f"Then: python -m lessons check LESSON --solution DIR (a module or a notebook).\n"
                  f"Lessons: {', '.join(ids)}\n")
        return 0
    if len(argv) > 2:
        raise UsageError(f"'exercise' takes LESSON and an optional DIR, and --notebook (got {' '.join(argv)})")
    wanted = available if argv[0] == "all" else [l for l in available if l.id == argv[0]]
    if not wanted:
        raise UsageError(f"LESSON must be one of {', '.join(ids)} or all (got {argv[0]!r})")
    folder = Path(argv[1] if len(argv) > 1 else "exercises")
    if folder.exists() and not folder.is_dir():
        raise UsageError(f"DIR {str(folder)!r} is a file: give a folder for the exercise templates")
    place, other = (notebook_file, module_file) if notebook else (module_file, notebook_file)
    targets = [(l, place(folder, l.id)) for l in wanted]
    existing = [str(p) for _, p in targets if p.exists()]
    if existing:
        raise UsageError(f"{', '.join(existing)} already exists: it may hold your work; give another DIR "
                         f"or move it away first")
    beside = [str(other(folder, l.id)) for l in wanted if other(folder, l.id).exists()]
    if beside:
        raise UsageError(f"{', '.join(beside)} already exists: a folder holds one solution per lesson, the module or "
                         f"the notebook; give another DIR or move it away first")
    text = (lambda lesson: notebook_bytes(lesson, str(folder))) if notebook else \
        (lambda lesson: template_text(lesson, str(folder)).encode("utf-8"))
    write_all_or_none(folder, [(path, text(lesson)) for lesson, path in targets], "the templates")
    for lesson, path in targets:
        names = ", ".join(t.name for t in exercise_module(lesson).TASKS)
        out.write(f"wrote {path}: {names}\n")
    first = wanted[0].id if len(wanted) == 1 else "LESSON"
    last = "run its last cell, or: " if notebook else "then: "
    out.write(f"next: write the functions' bodies, {last}python -m lessons check {first} --solution {folder}\n")
    return 0
