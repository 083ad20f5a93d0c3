"""python -m lessons notebook: every lesson as a notebook generated from the lesson (its narrative, one
cell per stage with the typed parameters written out), valid nbformat; one executed in a real kernel
(nbclient): no cell errs, every stage's claim table holds at the defaults, the recording is handed to
the embedded Rerun viewer (rerun-notebook's widget). Every lesson's notebook executed the same way, its
stages replayed from the session's default runs (ELASTIC_NOTEBOOK_REPLAY, lessons.app.replay: the
physics is not run twice), and an edited configuration never replayed. Refusals: one line, exit 2,
nothing replaced."""
import dataclasses
import subprocess
import sys

import nbformat
import pytest

from lessons.app import registry, replay
from lessons.app.notebook import notebook_for
from tests.helpers import notebook_asset_server

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


def execute_and_check(folder, lesson):
    """Execute ``folder/<lesson>.ipynb`` in a fresh kernel; check that no cell erred, that every stage
    showed its claim table with all claims holding and handed its recording to the embedded viewer.
    Returns the cells' printed text."""
    from nbclient import NotebookClient
    nb = nbformat.read(folder / f"{lesson.id}.ipynb", as_version=4)
    NotebookClient(nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(folder)}}).execute()
    outputs = [o for c in nb.cells if c.cell_type == "code" for o in c.outputs]
    errors = [f"{o.ename}: {o.evalue}" for o in outputs if o.output_type == "error"]
    assert not errors, f"{lesson.id}: {errors}"
    tables = [o.data["text/html"] for o in outputs if "text/html" in o.get("data", {})]
    assert len(tables) == len(lesson.stages), lesson.id
    for i, html in enumerate(tables, 1):
        n = html.count("<tr>") - 1
        assert n > 0 and f"{i}. " in html and f"{n} of {n} claims hold" in html and "FAIL" not in html, (lesson.id, i)
    widgets = [o for o in outputs if "application/vnd.jupyter.widget-view+json" in o.get("data", {})]
    assert len(widgets) == len(lesson.stages), lesson.id   # each stage's recording handed to the embedded viewer
    return "".join(o.get("text", "") for o in outputs if o.output_type == "stream")


def test_a_notebook_runs_top_to_bottom_in_a_fresh_kernel(tmp_path, monkeypatch):
    monkeypatch.delenv(replay.ENV, raising=False)   # its stages run for real
    assert cli("rod-waves", tmp_path).returncode == 0
    printed = execute_and_check(tmp_path, registry.get("rod-waves"))
    assert "replayed from" not in printed


def test_every_notebook_runs_with_its_stages_replayed_from_the_default_runs(default_runs, tmp_path, monkeypatch):
    for lesson in LESSONS:   # the runs the lesson tests make (or have made) anyway, stage by stage in the store
        default_runs(lesson.id)
    monkeypatch.setenv(replay.ENV, str(default_runs.replay_store))   # the kernels inherit it
    assert cli("all", tmp_path).returncode == 0
    with notebook_asset_server() as widget:   # one for the six kernels (the test above runs serve-local)
        monkeypatch.setenv("RERUN_NOTEBOOK_ASSET", widget)
        for lesson in LESSONS:
            printed = execute_and_check(tmp_path, lesson)
            assert printed.count("replayed from") == len(lesson.stages), lesson.id


def test_a_replayed_stage_is_the_default_run_and_an_edited_configuration_runs_for_real(default_runs, tmp_path,
                                                                                        monkeypatch):
    from lessons.app.notebook import NotebookLesson
    run = default_runs("springs")
    monkeypatch.setenv(replay.ENV, str(default_runs.replay_store))
    notebook = NotebookLesson("springs", tmp_path)
    cfg = notebook.lesson.config()
    same = notebook.stage(1, cfg)
    assert same.replayed and same.passed and same.recording.stat().st_size > 0
    assert [(e.id, e.theory, e.measured) for e in same.experiments] == \
        [(e.id, e.theory, e.measured) for e in run.stages[1].values()]
    edited = notebook.stage(1, dataclasses.replace(cfg, k=80.0))   # the cell's parameter edited: run for real
    assert not edited.replayed and edited.experiments
    assert {e.id: e.theory for e in edited.experiments} != {e.id: e.theory for e in same.experiments}
    assert not notebook.stage(1, dataclasses.replace(cfg, steps=cfg.steps + 1000)).replayed   # any field counts


def test_the_replay_key_is_lesson_stage_configuration_and_code(default_runs, tmp_path, monkeypatch):
    import json
    import shutil
    lesson = registry.get("springs")
    default_runs("springs")
    cfg = lesson.config()
    key = replay.stage_key(lesson, 1, cfg)
    assert key != replay.stage_key(lesson, 2, cfg) != replay.stage_key(lesson, 1, dataclasses.replace(cfg, k=50.0001))
    assert replay.load(default_runs.replay_store, lesson, 1, cfg) is not None
    for name in ("springs-stage1.json", "springs-stage1.rrd"):
        shutil.copy(default_runs.replay_store / name, tmp_path / name)
    meta = tmp_path / "springs-stage1.json"
    body = json.loads(meta.read_text())
    meta.write_text(json.dumps(dict(body, key="0" * 64)))   # stored for another configuration: ignored
    assert replay.load(tmp_path, lesson, 1, cfg) is None
    meta.write_text(json.dumps(body))
    assert replay.load(tmp_path, lesson, 1, cfg) is not None
    monkeypatch.setattr(replay, "code_fingerprint", lambda: "other code")   # the lessons or the engine edited
    assert replay.stage_key(lesson, 1, cfg) != key and replay.load(tmp_path, lesson, 1, cfg) is None


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
