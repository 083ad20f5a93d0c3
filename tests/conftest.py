"""Shared fixtures: one Taichi runtime per test session (CPU, 2 threads, f64), and every lesson
run once per session at its defaults with its recording, for the tests that inspect either. The same
run also fills a notebook replay store (lessons.app.replay: each stage's results and its recording
alone), so that executing the generated notebooks does not run the physics again."""
import io
from pathlib import Path
from typing import NamedTuple

import pytest

from engine import runtime


@pytest.fixture(scope="session", autouse=True)
def taichi_runtime():
    return runtime.init()


class DefaultRun(NamedTuple):
    """One lesson run at its defaults with its recording."""
    path: Path        # the .rrd
    rec: object       # the Recorder that wrote it (its plan is what the blueprint was built from)
    stages: dict      # {stage index: {experiment id: Experiment}}
    used: dict        # {stage index: the stage's integrator notes}


@pytest.fixture(scope="session")
def default_runs(tmp_path_factory):
    """``get(lesson id) -> DefaultRun``: the lesson run once per session at its defaults, as
    ``python -m lessons run`` records it; the recording tests and the lessons' own tests share it.
    ``get.replay_store``: the folder where each stage of those runs is stored for the notebooks."""
    from lessons.app import registry, replay
    from lessons._framework import run_lesson
    from lessons.app.cli import make_recorder

    out_dir = tmp_path_factory.mktemp("recordings")
    store = tmp_path_factory.mktemp("notebook-replay")
    made = {}

    def get(lesson_id: str) -> DefaultRun:
        if lesson_id not in made:
            lesson = registry.get(lesson_id)
            path = out_dir / f"{lesson.id}.rrd"
            rec = make_recorder(lesson, path)
            tee = replay.StageTee(rec, lambda i: make_recorder(lesson, replay.entry_paths(store, lesson.id, i)[1]))
            collected = {}
            try:
                passed = run_lesson(lesson, lesson.config(), tee, None, out=io.StringIO(), err=io.StringIO(),
                                    quiet=True, collected=collected)
            finally:
                tee.close()
            failed = [(e.id, e.measured, e.theory, e.reason) for exps, _ in collected.values() for e in exps
                      if not e.passed]
            assert passed and not failed, f"{lesson.id}: experiments failed at the defaults: {failed}"
            stages = {}
            for index, (exps, _) in collected.items():
                stages[index] = {e.id: e for e in exps}
                assert len(stages[index]) == len(exps), f"duplicate experiment ids: {[e.id for e in exps]}"
            for index, (exps, used) in collected.items():
                replay.save(store, lesson, index, lesson.config(), exps, used)
            made[lesson_id] = DefaultRun(path, rec, stages, {i: used for i, (_, used) in collected.items()})
        return made[lesson_id]
    get.replay_store = store
    return get


@pytest.fixture(scope="session")
def default_recordings(default_runs):
    """{lesson id: (path of its .rrd, the Recorder that wrote it)} for every lesson (default_runs)."""
    from lessons.app import registry
    return {lesson.id: tuple(default_runs(lesson.id)[:2]) for lesson in registry.all_lessons()}


SHARED_SESSION = ("default_runs", "default_recordings")   # the session fixtures that make the default runs


def shared_work(item) -> set:
    """The shared work ``item`` reads: "default-runs" when it reads the default runs, and
    "<module>::<name>" for each module-scoped fixture of its own test module it reads (a lesson run
    under another integrator, a recording made once for the module's tests)."""
    keys = set()
    info = getattr(item, "_fixtureinfo", None)
    for name in getattr(item, "fixturenames", ()):
        if name in SHARED_SESSION:
            keys.add("default-runs")
            continue
        for fdef in (info.name2fixturedefs.get(name, ()) if info is not None else ()):
            if fdef.scope == "module" and fdef.baseid == item.nodeid.split("::")[0]:
                keys.add(f"{fdef.baseid}::{name}")
    return keys


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    """Under pytest-xdist (``--dist loadgroup``), the tests that share one piece of costly work are
    sent to the same worker, so that work is done once per test run, not once on each worker: every
    test that reads the default runs (group "default-runs": the six lessons are run once per
    session there), and every test that reads a module-scoped fixture of its own module (group named
    after the fixture). A test that reads two of them joins their groups into one (the default runs'
    name wins): ``xdist`` gives a test one group."""
    parent: dict = {}

    def find(k):
        while parent.setdefault(k, k) != k:
            parent[k] = parent[parent[k]]
            k = parent[k]
        return k

    def join(a, b):
        root, other = sorted((find(a), find(b)), key=lambda k: (k != "default-runs", k))
        if root != other:
            parent[other] = root

    shared = [(item, sorted(shared_work(item))) for item in items]
    for _, keys in shared:
        for k in keys[1:]:
            join(keys[0], k)
    for item, keys in shared:
        if keys:
            item.add_marker(pytest.mark.xdist_group(find(keys[0])))
