"""Shared fixtures: one Taichi runtime per test session (CPU, 2 threads, f64), and the default
recordings of every lesson, made once per session for the tests that inspect them."""
import io

import pytest

from engine import runtime


@pytest.fixture(scope="session", autouse=True)
def taichi_runtime():
    return runtime.init()


@pytest.fixture(scope="session")
def default_recordings(tmp_path_factory):
    """{lesson id: (path of its .rrd, the Recorder that wrote it)}: every lesson run at its
    defaults, as ``python -m lessons run all`` records it (the recorder's plan is what the
    blueprint was built from)."""
    from lessons.app import registry
    from lessons._framework import run_lesson
    from lessons.app.cli import _make_recorder

    out_dir = tmp_path_factory.mktemp("recordings")
    made = {}
    for lesson in registry.all_lessons():
        path = out_dir / f"{lesson.id}.rrd"
        rec = _make_recorder(lesson, path)
        try:
            passed = run_lesson(lesson, lesson.config(), rec, None, out=io.StringIO(), err=io.StringIO(), quiet=True)
        finally:
            rec.close()
        assert passed, f"{lesson.id}: an experiment failed at the defaults"
        made[lesson.id] = (path, rec)
    return made
