"""python -m lessons notebook: every lesson as a notebook generated from the lesson (its narrative, one
cell per stage with the typed parameters written out), valid nbformat; one executed in a real kernel
(nbclient): no cell errs, every stage's claim table holds at the defaults, the recording is handed to
the embedded Rerun viewer (rerun-notebook's widget). Refusals: one line, exit 2, nothing replaced."""
import dataclasses
import subprocess
import sys

import nbformat
import pytest

from lessons.app import registry
from lessons.app.notebook import notebook_for

LESSONS = registry.all_lessons()


def cli(*args):
    return subprocess.run([sys.executable, "-m", "lessons", "notebook", *map(str, args)], capture_output=True,
                          text=True, timeout=120)


@pytest.mark.parametrize("lesson", LESSONS, ids=[l.id for l in LESSONS])
def test_the_notebook_is_the_lesson(lesson):
    nb = nbformat.from_dict(notebook_for(lesson))
    nbformat.validate(nb)
    cells = nb.cells
    assert cells[0].cell_type == "markdown" and cells[0].source.startswith(f"# {lesson.title}")
    config = cells[2].source
    for f in dataclasses.fields(lesson.config):   # every parameter, at its default, editable
        default = f.default if f.default is not dataclasses.MISSING else f.default_factory()
        assert f"    {f.name}={default!r}," in config, f.name
    stages = cells[3:]
    assert len(stages) == 2 * len(lesson.stages)
    for i, stage in enumerate(lesson.stages, 1):
        text, run = stages[2 * i - 2], stages[2 * i - 1]
        assert text.cell_type == "markdown" and text.source == f"## {i}. {stage.title}\n\n{stage.narrative}"
        assert run.cell_type == "code" and run.source == f"lesson.stage({i}, cfg)"   # no stage logic in the notebook


def test_a_notebook_runs_top_to_bottom_in_a_fresh_kernel(tmp_path):
    from nbclient import NotebookClient
    assert cli("rod-waves", tmp_path).returncode == 0
    nb = nbformat.read(tmp_path / "rod-waves.ipynb", as_version=4)
    NotebookClient(nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}}).execute()
    outputs = [o for c in nb.cells if c.cell_type == "code" for o in c.outputs]
    assert not [o for o in outputs if o.output_type == "error"]
    tables = [o.data["text/html"] for o in outputs if "text/html" in o.get("data", {})]
    lesson = registry.get("rod-waves")
    assert len(tables) == len(lesson.stages)
    for i, html in enumerate(tables, 1):
        n = html.count("<tr>") - 1
        assert f"{i}. " in html and f"{n} of {n} claims hold" in html and "FAIL" not in html
    widgets = [o for o in outputs if "application/vnd.jupyter.widget-view+json" in o.get("data", {})]
    assert len(widgets) == len(lesson.stages)   # each stage's recording handed to the embedded viewer


def test_an_existing_notebook_is_kept_unless_forced(tmp_path):
    assert cli("springs", tmp_path).returncode == 0
    target = tmp_path / "springs.ipynb"
    target.write_text("mine")
    done = cli("springs", tmp_path)
    assert done.returncode == 2 and "already there; --force replaces it" in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1 and target.read_text() == "mine"
    assert cli("springs", tmp_path, "--force").returncode == 0 and target.read_text() != "mine"
    assert cli("all", tmp_path / "all").returncode == 0
    assert sorted(p.name for p in (tmp_path / "all").iterdir()) == sorted(f"{l.id}.ipynb" for l in LESSONS)


def test_a_file_in_place_of_dir_is_refused(tmp_path):
    (tmp_path / "f").write_text("x")
    done = cli("springs", tmp_path / "f")
    assert done.returncode == 2 and "is a file" in done.stderr


def test_a_failed_write_leaves_no_new_notebook_and_keeps_the_old_ones(tmp_path, monkeypatch):
    import errno
    import io

    from lessons.app.cli import OutputFailed
    from lessons.app.notebook import write_notebooks
    from lessons.app.outfile import OutputFile, OutputWriteError
    (tmp_path / "springs.ipynb").write_text("mine")
    write = OutputFile.write_bytes

    def write_bytes(self, data):
        if self.path.name == "membranes.ipynb":
            self.discard()
            raise OutputWriteError(errno.ENOSPC, "No space left on device")
        return write(self, data)
    monkeypatch.setattr(OutputFile, "write_bytes", write_bytes)
    with pytest.raises(OutputFailed, match="could not write the notebooks .*; no new file is left there$"):
        write_notebooks(["all", str(tmp_path), "--force"], io.StringIO())
    assert sorted(p.name for p in tmp_path.iterdir()) == ["springs.ipynb"]
    assert (tmp_path / "springs.ipynb").read_text() == "mine"
