"""Lessons as Jupyter notebooks: ``python -m lessons notebook LESSON|all DIR [--force]``.

A lesson's notebook is generated from the lesson itself, so it never drifts from it: its title and
summary, then for every stage the stage's narrative (Markdown) and one code cell that runs that
stage with the lesson's typed configuration written out parameter by parameter (edit a value and
run the cell again). Running a cell prints the stage's progress, shows its claim table and the
stage's recording in the Rerun viewer embedded in the notebook (rerun-notebook, the ``notebook``
extra), with the layout the recording opens on in the desktop viewer. The viewer's page and
WebAssembly are served from the installed package (RERUN_NOTEBOOK_ASSET=serve-local unless set):
nothing is fetched from a network. No stage logic lives in the notebook: a cell calls
:meth:`NotebookLesson.stage`, the same runner as ``python -m lessons run``.

For the tests and CI only: with ``ELASTIC_NOTEBOOK_REPLAY=DIR`` a stage whose lesson, stage number,
configuration and code are those of a run stored in DIR (written while the tests ran every lesson at
its defaults) shows that run's table and recording instead of running again; anything else runs
(:mod:`lessons.app.replay`).
"""
from __future__ import annotations

import dataclasses
import html
import json
import os
import shutil
import sys
import tempfile
from pathlib import Path

from .arguments import Parser, UsageError
from .output_paths import write_all_or_none
from . import registry, replay
from .._framework import run_lesson, text_table, validate_config

VIEWER_HEIGHT = 720   # pixels of the embedded viewer


# ------------------------------------------------------------------ what a notebook cell calls

@dataclasses.dataclass
class StageResult:
    """One stage run from a notebook: its experiments and the recording it wrote. Shown in a notebook as
    the claim table and, when rerun-notebook is installed, the recording in the embedded viewer."""
    lesson: str
    index: int
    title: str
    experiments: list
    recording: Path | None
    replayed: bool = False   # taken from ELASTIC_NOTEBOOK_REPLAY's store (tests and CI), not run here

    @property
    def passed(self) -> bool:
        return all(e.passed for e in self.experiments)

    def table_html(self) -> str:
        head = "".join(f"<th>{h}</th>" for h in ("result", "theory", "measured", "tolerance", "claim"))
        rows = []
        for e in self.experiments:
            unit = f" {e.unit}" if e.unit else ""
            verdict = "PASS" if e.passed else "FAIL"
            rows.append(f"<tr><td><b>{verdict}</b></td><td>{e.theory:.6g}{html.escape(unit)}</td>"
                        f"<td>{e.measured:.6g}</td><td>{html.escape(e.tolerance_text())}</td>"
                        f"<td style='text-align:left'>{html.escape(e.claim)}</td></tr>")
        return (f"<h4>{self.index}. {html.escape(self.title)}: {sum(e.passed for e in self.experiments)} of "
                f"{len(self.experiments)} claims hold</h4><table><tr>{head}</tr>{''.join(rows)}</table>")

    def _repr_html_(self) -> str:
        return self.table_html()

    def __repr__(self) -> str:
        return text_table(self.experiments)

    def viewer(self, height: int = VIEWER_HEIGHT):
        """The recording in the embedded Rerun viewer (rerun-notebook's widget), or None without it."""
        if self.recording is None:
            return None
        os.environ.setdefault("RERUN_NOTEBOOK_ASSET", "serve-local")   # the package's own assets: no network
        try:
            from rerun_notebook import Viewer
        except ImportError:
            return None
        widget = Viewer(width="auto", height=height)
        widget.send_rrd(self.recording.read_bytes())
        return widget

    def _ipython_display_(self) -> None:
        from IPython.display import HTML, display
        display(HTML(self.table_html()))
        widget = self.viewer()
        if widget is not None:
            display(widget)
        elif self.recording is not None:
            display(HTML("<p>(install the notebook extra to see the recording here: pip install -e '.[notebook]'; "
                         f"or open it: rerun {html.escape(str(self.recording))})</p>"))


class NotebookLesson:
    """A lesson as a notebook runs it: ``stage(N, cfg)`` runs stage N with the typed configuration
    ``cfg`` (checked as the command line checks it) and returns a :class:`StageResult`. Taichi is
    initialised once (the CLI's defaults: CPU, 2 threads, f64)."""

    def __init__(self, lesson_id: str, recordings: str | os.PathLike | None = None):
        from engine import runtime
        if runtime.current() is None:
            runtime.init()
        self.lesson = registry.get(lesson_id)
        self.folder = Path(recordings) if recordings else Path(tempfile.mkdtemp(prefix=f"{lesson_id}-"))
        self.folder.mkdir(parents=True, exist_ok=True)

    def stage(self, index: int, cfg=None, record: bool = True) -> StageResult:
        from .cli import make_recorder
        lesson = self.lesson
        cfg = cfg if cfg is not None else lesson.config()
        validate_config(cfg)
        if lesson.validate is not None:
            lesson.validate(cfg)
        if not 1 <= index <= len(lesson.stages):
            raise ValueError(f"stage must be in 1..{len(lesson.stages)} (got {index})")
        path = self.folder / f"{lesson.id}-stage{index}.rrd" if record else None
        title = lesson.stages[index - 1].title
        store = os.environ.get(replay.ENV)
        stored = replay.load(store, lesson, index, cfg) if store else None
        if stored is not None:
            print(f"== {lesson.id} · stage {index}/{len(lesson.stages)}: {title}\n   replayed from {store} "
                  f"({replay.ENV} is set: the run made with this very configuration and code)")
            print(text_table(stored.experiments))
            if path is not None:
                shutil.copyfile(stored.recording, path)
            return StageResult(lesson.id, index, title, stored.experiments, path, replayed=True)
        rec = make_recorder(lesson, path)
        collected: dict = {}
        try:
            run_lesson(lesson, cfg, rec, [index], out=sys.stdout, err=sys.stdout, quiet=False, collected=collected)
        finally:
            rec.close()
        experiments = collected.get(index, ([], None))[0]
        return StageResult(lesson.id, index, title, experiments, path)


# ------------------------------------------------------------------ the notebook, generated from the lesson

def _markdown(text: str, cell_id: str) -> dict:
    return {"cell_type": "markdown", "id": cell_id, "metadata": {}, "source": text}


def _code(text: str, cell_id: str) -> dict:
    return {"cell_type": "code", "id": cell_id, "metadata": {}, "execution_count": None, "outputs": [], "source": text}


def _config_source(cfg_cls, package: str) -> str:
    """``cfg = <Config>(name=default, ...)``, one parameter a line with its help, unit and range."""
    from .._framework import range_text
    lines = [f"from lessons.{package} import {cfg_cls.__name__}", "", f"cfg = {cfg_cls.__name__}("]
    for f in dataclasses.fields(cfg_cls):
        value = f.default if f.default is not dataclasses.MISSING else f.default_factory()
        meta = f.metadata or {}
        about = meta.get("help", "")
        unit = meta.get("unit", "")
        span = range_text(meta) if meta else ""
        note = "; ".join(x for x in (about, unit and f"unit {unit}", span) if x)
        lines.append(f"    {f.name}={value!r},  # {note}" if note else f"    {f.name}={value!r},")
    lines.append(")")
    return "\n".join(lines)


def notebook_for(lesson) -> dict:
    """The notebook (nbformat 4, as a dict) of ``lesson``."""
    package = lesson.config.__module__.split(".")[1]
    intro = (f"# {lesson.title}\n\n{lesson.summary}\n\nEach stage below is its narrative and one code cell that runs "
             f"it (the same runner as `python -m lessons run {lesson.id}`): edit a parameter of `cfg` and run the cell "
             "again. The claim table shows what the stage measured against the theory; the embedded Rerun viewer "
             "shows its recording.")
    setup = f"from lessons.app.notebook import NotebookLesson\n\nlesson = NotebookLesson({lesson.id!r})"
    cells = [_markdown(intro, "title"), _code(setup, "setup"), _code(_config_source(lesson.config, package), "config")]
    for i, stage in enumerate(lesson.stages, 1):
        cells.append(_markdown(f"## {i}. {stage.title}\n\n{stage.narrative}", f"stage{i}-narrative"))
        cells.append(_code(f"lesson.stage({i}, cfg)", f"stage{i}-run"))
    return {"nbformat": 4, "nbformat_minor": 5, "cells": cells,
            "metadata": {"kernelspec": {"name": "python3", "display_name": "Python 3", "language": "python"},
                         "language_info": {"name": "python"}}}


def _parser() -> Parser:
    p = Parser(prog="python -m lessons notebook",
               description="Write each lesson as a Jupyter notebook DIR/<lesson>.ipynb, generated from the lesson: its "
                           "narrative, one cell per stage that runs it with editable parameters, the claim table and "
                           "the recording in the embedded Rerun viewer (pip install -e '.[notebook]').")
    p.add_argument("lesson", metavar="LESSON|all")
    p.add_argument("dir", metavar="DIR", help="folder to write the notebooks in (made if missing)")
    p.add_argument("--force", action="store_true", help="replace notebooks that are already there")
    return p


def write_notebooks(argv: list[str], out=sys.stdout, err=sys.stderr) -> int:
    args = _parser().parse_args(argv)
    lessons = registry.all_lessons() if args.lesson == "all" else [registry.get(args.lesson)]
    folder = Path(args.dir)
    targets = [folder / f"{lesson.id}.ipynb" for lesson in lessons]
    there = [str(t) for t in targets if t.exists()]
    if there and not args.force:
        raise UsageError(f"{', '.join(there)} already there; --force replaces it")
    if folder.exists() and not folder.is_dir():
        raise UsageError(f"DIR {folder} is a file; give a folder")
    write_all_or_none(folder, [(t, (json.dumps(notebook_for(lesson), indent=1) + "\n").encode("utf-8"))
                               for t, lesson in zip(targets, lessons)], "the notebooks")
    for t in targets:
        print(f"wrote {t}", file=out)
    print("open them with: jupyter lab " + str(folder) + "  (pip install -e '.[notebook]')", file=out)
    return 0


__all__ = ["NotebookLesson", "StageResult", "notebook_for", "write_notebooks"]
