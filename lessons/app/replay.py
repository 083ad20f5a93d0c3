"""Notebook stages replayed from runs already made: a test and CI facility, off unless asked for.

The tests run every lesson once at its defaults (tests/conftest.py); executing the generated notebooks
must not run the same physics again. While that run is made, :class:`StageTee` also writes each stage's
recording alone (what ``NotebookLesson.stage`` records: a recorder of its own that sees only that stage)
and :func:`save` puts it in a replay store, a folder, with the stage's experiments and its key.

A notebook stage cell (:meth:`lessons.app.notebook.NotebookLesson.stage`) consults the store only when
the environment variable ``ELASTIC_NOTEBOOK_REPLAY`` names it, and takes an entry only when its key is
the key of the cell's own request (:func:`stage_key`: the lesson, the stage, the configuration's class
and every field's value, and a fingerprint of the code of the lessons and the engine). An edited
parameter, another stage, or changed code gives another key: the stage runs for real. Without the
variable a notebook always runs its stages.
"""
from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import os
from pathlib import Path

from .._framework import Experiment

ENV = "ELASTIC_NOTEBOOK_REPLAY"
_ROOT = Path(__file__).resolve().parents[2]
_CODE = ("lessons", "engine")   # the packages whose code decides a stage's results and recording


@functools.lru_cache(maxsize=1)
def code_fingerprint() -> str:
    """A hash of every .py and .md file of the lessons and the engine (names and bytes)."""
    h = hashlib.sha256()
    for package in _CODE:
        for path in sorted((_ROOT / package).rglob("*")):
            if path.suffix in (".py", ".md") and path.is_file():
                h.update(str(path.relative_to(_ROOT)).encode() + b"\0" + path.read_bytes() + b"\0")
    return h.hexdigest()


def stage_key(lesson, index: int, cfg) -> str:
    """The key of stage ``index`` of ``lesson`` run with ``cfg``: every field's exact value (repr)."""
    fields = {f.name: repr(getattr(cfg, f.name)) for f in dataclasses.fields(cfg)}
    text = json.dumps({"lesson": lesson.id, "stage": index, "config": f"{type(cfg).__module__}.{type(cfg).__qualname__}",
                       "fields": fields, "code": code_fingerprint()}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()


def entry_paths(store: str | os.PathLike, lesson_id: str, index: int) -> tuple[Path, Path]:
    """(the entry's JSON, its recording) in the store."""
    base = Path(store) / f"{lesson_id}-stage{index}"
    return base.with_suffix(".json"), base.with_suffix(".rrd")


def save(store: str | os.PathLike, lesson, index: int, cfg, experiments: list[Experiment], used: list[str]) -> Path:
    """Put stage ``index``'s experiments in the store beside its recording (written by StageTee)."""
    meta, rrd = entry_paths(store, lesson.id, index)
    if not rrd.is_file():
        raise FileNotFoundError(f"{rrd}: the stage's recording is missing")
    body = {"key": stage_key(lesson, index, cfg), "lesson": lesson.id, "stage": index, "integrators": list(used),
            "experiments": [dataclasses.asdict(e) for e in experiments]}
    meta.write_text(json.dumps(body, indent=1), encoding="utf-8")
    return meta


@dataclasses.dataclass
class Replay:
    """A stage found in the store: its experiments, integrator notes and recording."""
    experiments: list[Experiment]
    integrators: list[str]
    recording: Path


def load(store: str | os.PathLike, lesson, index: int, cfg) -> Replay | None:
    """The stored stage whose key is that of (lesson, index, cfg), or None (no entry, another key)."""
    meta, rrd = entry_paths(store, lesson.id, index)
    try:
        body = json.loads(meta.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if body.get("key") != stage_key(lesson, index, cfg) or not rrd.is_file():
        return None
    return Replay([Experiment(**e) for e in body["experiments"]], list(body["integrators"]), rrd)


class StageTee:
    """A recorder that passes every call to the lesson's recorder ``main`` and to a recorder of the
    current stage alone, made by ``make(index)`` when the stage starts and closed when the next one
    starts or this one closes. What ``main`` returns is returned (both see the same calls, so they
    agree). ``written``: {stage index: where its recording went}."""

    enabled = True

    def __init__(self, main, make):
        self.main, self._make = main, make
        self._current = None
        self.written: dict = {}

    def stage(self, index: int, title: str, narrative: str) -> None:
        self._finish()
        self._current = (index, self._make(index))
        self.main.stage(index, title, narrative)
        self._current[1].stage(index, title, narrative)

    def _finish(self) -> None:
        if self._current is not None:
            index, rec = self._current
            self._current = None
            self.written[index] = rec.close()

    def close(self, *args, **kwargs):
        try:
            self._finish()
        finally:
            result = self.main.close(*args, **kwargs)
        return result

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def __getattr__(self, name):
        attr = getattr(self.main, name)
        if not callable(attr):
            return attr

        def both(*args, **kwargs):
            result = attr(*args, **kwargs)
            if self._current is not None:
                getattr(self._current[1], name)(*args, **kwargs)
            return result
        return both


__all__ = ["ENV", "Replay", "StageTee", "code_fingerprint", "entry_paths", "load", "save", "stage_key"]
