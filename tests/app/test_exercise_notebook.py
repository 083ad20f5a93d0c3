"""python -m lessons exercise LESSON DIR --notebook, and a notebook handed in: the template is the
module template's pieces in cells; a notebook is graded as the module of its code cells is (the same
claims, the same refusals, its lines told as cells); IPython's magics and shell escapes refuse it; a
file that is not a notebook is one line, exit 2, nothing written; the check cell grades the notebook
as saved (executed in a real kernel). Grader runs: rod-waves (one function) and springs with
--functions-only, the cheapest."""
import ast
import json
import shutil
from pathlib import Path

import nbformat
import pytest

from lessons.app import registry
from lessons.app.exercise_notebook import CHECK_MARK, exercise_notebook, read_notebook
from lessons.app.exercises import IMPORTS, function_templates, instructions
from tests.helpers import ROOT, cli

PACKAGE = {"springs": "springs", "rod-waves": "rod_waves"}


def reference_functions(lesson_id: str) -> dict:
    """{name: source with its decorator} of the lesson's reference solution."""
    text = (ROOT / "lessons" / PACKAGE[lesson_id] / "solution.py").read_text()
    lines = text.splitlines()
    return {n.name: "\n".join(lines[n.decorator_list[0].lineno - 1 if n.decorator_list else n.lineno - 1:n.end_lineno])
            for n in ast.parse(text).body if isinstance(n, ast.FunctionDef)}


def solved(lesson_id: str, replace: dict | None = None, drop=(), extra: list | None = None) -> dict:
    """The generated notebook with the reference solution in its function cells (``replace``: other
    sources by name; ``drop``: cells left out), ``extra`` code cells inserted before the check cell."""
    nb = exercise_notebook(registry.get(lesson_id), "ex")
    sources = {**reference_functions(lesson_id), **(replace or {})}
    cells = []
    for cell in nb["cells"]:
        name = cell["id"].replace("-", "_")
        if name in drop:
            continue
        if name in sources:
            cell = {**cell, "source": sources[name]}
        cells.append(cell)
    cells[-1:-1] = [{"cell_type": "code", "id": f"extra{k}", "metadata": {}, "execution_count": None, "outputs": [],
                     "source": s} for k, s in enumerate(extra or [])]
    return {**nb, "cells": cells}


def module_of(nb: dict) -> str:
    """The same solution written as a module: its code cells but the check cell, in order."""
    return "\n\n".join(c["source"] for c in nb["cells"] if c["cell_type"] == "code"
                       and not c["source"].startswith(CHECK_MARK)) + "\n"


def write(folder: Path, lesson_id: str, nb: dict | str) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{PACKAGE[lesson_id]}.ipynb"
    path.write_text(nb if isinstance(nb, str) else json.dumps(nb))
    return path


def grade(tmp_path, folder: str, lesson_id: str, *options) -> tuple:
    out = tmp_path / f"{folder}.json"
    r = cli("check", lesson_id, "--solution", folder, "--results", str(out), *options, cwd=tmp_path)
    rows = {row["id"]: row for row in json.loads(out.read_text())["experiments"]} if out.exists() else {}
    return r, rows


def verdicts(rows: dict) -> dict:
    return {k: (r["passed"], r["measured"], r["theory"]) for k, r in rows.items()}


# ------------------------------------------------------------------ the template

def test_the_notebook_is_made_of_the_module_templates_pieces():
    for lesson_id in PACKAGE:
        lesson = registry.get(lesson_id)
        nb = nbformat.from_dict(exercise_notebook(lesson, "ex"))
        nbformat.validate(nb)
        first, imports, *functions, check = nb.cells
        assert first.cell_type == "markdown" and first.source.startswith(f"# Exercise: {lesson.title}.")
        assert instructions(lesson, "").split("\n\n")[-1] in first.source   # the rules and equations, as the module's
        assert "Run the last cell" in first.source
        assert f"python -m lessons check {lesson_id} --solution ex" in first.source
        assert imports.source == IMPORTS.rstrip("\n")
        assert [c.source for c in functions] == [f.rstrip("\n") for f in function_templates(lesson)]
        assert check.source.startswith(CHECK_MARK) and f"check_notebook({lesson_id!r})" in check.source
        extracted = read_notebook_from(nb, lesson_id)
        assert "check_notebook" not in extracted.source and not extracted.problems   # the check cell is not graded


def read_notebook_from(nb, lesson_id: str):
    """read_notebook of ``nb`` saved as the lesson's notebook."""
    import tempfile
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / f"{PACKAGE[lesson_id]}.ipynb"
        path.write_text(json.dumps(nb))
        return read_notebook(path)


def test_exercise_notebook_writes_it_never_over_work_nor_beside_the_module(tmp_path):
    r = cli("exercise", "rod-waves", "ex", "--notebook", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "run its last cell" in r.stdout
    nbformat.validate(nbformat.read(tmp_path / "ex" / "rod_waves.ipynb", as_version=4))
    for args, there in ((["--notebook"], "ex/rod_waves.ipynb already exists: it may hold your work"),
                        ([], "ex/rod_waves.ipynb already exists: a folder holds one solution per lesson")):
        r = cli("exercise", "rod-waves", "ex", *args, cwd=tmp_path)
        assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and there in r.stderr, r.stderr
    assert not (tmp_path / "ex" / "rod_waves.py").exists()
    assert "--notebook" in cli("exercise", "--help", cwd=tmp_path).stdout


# ------------------------------------------------------------------ graded as the module is

def test_a_correct_notebook_passes_exactly_as_the_module_does(tmp_path):
    nb = solved("rod-waves")
    write(tmp_path / "nb", "rod-waves", nb)
    (tmp_path / "py").mkdir()
    (tmp_path / "py" / "rod_waves.py").write_text(module_of(nb))
    r_nb, rows_nb = grade(tmp_path, "nb", "rod-waves")
    r_py, rows_py = grade(tmp_path, "py", "rod-waves")
    assert r_nb.returncode == r_py.returncode == 0, r_nb.stdout[-2000:]
    assert len(rows_nb) > 5 and verdicts(rows_nb) == verdicts(rows_py)


def test_a_wrong_missing_or_redefined_function_fails_the_checks_the_module_fails(tmp_path):
    """spring_force's sign flipped in a later cell (the last definition is graded, as running the
    notebook top to bottom leaves it), verlet_kick's cell deleted: the module with the same code fails
    the same checks, and the reasons name the notebook."""
    wrong = reference_functions("springs")["spring_force"].replace("return ", "return -", 1)
    nb = solved("springs", drop=("verlet_kick",), extra=[wrong])
    write(tmp_path / "nb", "springs", nb)
    (tmp_path / "py").mkdir()
    (tmp_path / "py" / "springs.py").write_text(module_of(nb))
    r_nb, rows_nb = grade(tmp_path, "nb", "springs", "--functions-only")
    r_py, rows_py = grade(tmp_path, "py", "springs", "--functions-only")
    assert r_nb.returncode == r_py.returncode == 1
    assert verdicts(rows_nb) == verdicts(rows_py)
    failed = {k for k, (passed, *_) in verdicts(rows_nb).items() if not passed}
    assert failed == {"ex-spring-force", "ex-verlet-kick-written"}, failed   # the sign flip is caught; the rest holds
    assert rows_nb["ex-verlet-kick-written"]["reason"] == "verlet_kick: not defined in springs.ipynb"
    assert "spring_force is defined in cells 4, 8: the last one is graded" in r_nb.stdout


@pytest.mark.parametrize("cell,line,needle", [
    ("from engine.energies.springs import spring_force as engine_force", 1, "imports from engine.energies.springs"),
    ("x = 1\n!rm -rf {victim}", 2, "is IPython's syntax (a magic or a shell command)"),
    ("%run {victim}", 1, "is IPython's syntax (a magic or a shell command)"),
    ("%%bash\nrm -rf {victim}", 1, "is IPython's syntax (a magic or a shell command)"),
    ("x = 1\nget_ipython().run_cell('!rm -rf {victim}')", 2, "uses get_ipython (reaches the notebook's kernel"),
    ("open('{victim}', 'w').write('forged')", 1, "uses open"),
])
def test_a_notebook_that_reaches_past_its_arguments_is_refused_naming_the_cell(tmp_path, cell, line, needle):
    victim = tmp_path / "victim.txt"
    victim.write_text("kept")
    nb = solved("springs", extra=[cell.format(victim=victim)])
    write(tmp_path / "nb", "springs", nb)
    r, rows = grade(tmp_path, "nb", "springs", "--functions-only")
    assert r.returncode == 1, r.stderr
    reason = rows["ex-module-rules"]["reason"]
    assert needle in reason and f"springs.ipynb: cell 9, line {line}: " in reason, reason
    assert all(not row["passed"] for row in rows.values())
    assert victim.read_text() == "kept"


def test_a_forgery_in_a_top_level_cell_is_stopped_when_it_runs(tmp_path):
    """What the reading misses (ndarray.dump writes a file) the guard stops in the grading child."""
    target = tmp_path / "forged.pickle"
    nb = solved("rod-waves", extra=[f"import numpy as np\nnp.zeros(3).dump({str(target)!r})"])
    write(tmp_path / "nb", "rod-waves", nb)
    r, rows = grade(tmp_path, "nb", "rod-waves", "--functions-only")
    assert r.returncode == 1 and not target.exists()
    assert "the solution tried to write" in rows["ex-rod-force-runs"]["reason"]


@pytest.mark.parametrize("text,needle", [
    ('{"cells": [', "is not a Jupyter notebook (not JSON: line 1, column 12: "),
    ('{"cells": 3}', "is not a Jupyter notebook"),
])
def test_a_file_that_is_not_a_notebook_is_one_line_exit_2_and_nothing_written(tmp_path, text, needle):
    write(tmp_path / "nb", "rod-waves", text)
    r, rows = grade(tmp_path, "nb", "rod-waves", "--functions-only")
    assert r.returncode == 2 and not rows and not (tmp_path / "nb.json").exists()
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "nb/rod_waves.ipynb: " in lines[0] and needle in lines[0], r.stderr


def test_a_module_and_a_notebook_of_one_lesson_is_one_line_exit_2(tmp_path):
    write(tmp_path / "nb", "rod-waves", solved("rod-waves"))
    shutil.copy(ROOT / "lessons" / "rod_waves" / "solution.py", tmp_path / "nb" / "rod_waves.py")
    r, rows = grade(tmp_path, "nb", "rod-waves")
    assert r.returncode == 2 and not rows
    assert r.stderr.strip().splitlines() == [f"python -m lessons: error: {Path('nb/rod_waves.py')} and "
                                             f"{Path('nb/rod_waves.ipynb')} are both there: a solution is one of "
                                             f"them; move the other away"]


def test_a_syntax_error_names_its_cell_and_line(tmp_path):
    nb = solved("rod-waves", extra=["x = 1\ny = (2"])
    extracted = read_notebook_from(nb, "rod-waves")
    assert extracted.unreadable and extracted.unreadable[0].startswith("rod_waves.ipynb: cell 4, line 2: ")


def test_the_class_grader_takes_a_notebook(tmp_path):
    from lessons.app.roster import grade_task
    text = json.dumps(solved("rod-waves"))
    result = grade_task("ann", "rod-waves", {"rod_waves.ipynb": text}, ["--functions-only"], 300)
    assert result["status"] == "graded" and result["rows"] and all(r["passed"] for r in result["rows"]), result


# ------------------------------------------------------------------ the check cell, in a real kernel

def test_the_check_cell_grades_the_saved_notebook_in_a_fresh_kernel(tmp_path):
    from nbclient import NotebookClient
    path = write(tmp_path, "rod-waves", solved("rod-waves"))
    nb = nbformat.read(path, as_version=4)
    NotebookClient(nb, timeout=300, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}}).execute()
    outputs = [o for c in nb.cells if c.cell_type == "code" for o in c.outputs]
    assert not [o for o in outputs if o.output_type == "error"]
    last = nb.cells[-1].outputs
    shown = [o for o in last if o.output_type == "execute_result"]
    assert len(shown) == 1
    text, page = shown[0].data["text/plain"], shown[0].data["text/html"]
    n = sum(1 for line in text.splitlines() if line.rstrip().endswith("PASS"))
    assert n > 5 and f"{n} of {n} claims passed" in text and "FAIL" not in text
    assert "claims hold" in page and "FAIL" not in page
    assert "grading " in "".join(o.get("text", "") for o in last if o.output_type == "stream")
