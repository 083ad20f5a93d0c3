"""The default recording of every lesson, as a student opens it: its layout (the blueprint the
recorder built from what each run drew) and its size.

Checked for every lesson: each run that drew geometry has exactly one scene view, whose origin is
that run and nothing else; every scene view has a camera that frames the run's geometry; the
recording opens on a tab with geometry; no view shows an entity path that holds nothing; every
tab with events has an event log; the file is within the size budget.
"""
import math

import numpy as np
import pytest

from lessons.app.blueprint import FOV_Y
from lessons.app.recorder_read import summarize
from lessons.app import registry

SIZE_BUDGET = 20_000_000  # bytes, every default recording
LESSON_IDS = [l.id for l in registry.all_lessons()]


def walk(node):
    """Every view and container under a blueprint node (depth first)."""
    yield node
    for child in getattr(node, "contents", None) or []:
        if not isinstance(child, str):
            yield from walk(child)


def views(node, cls=None):
    return [n for n in walk(node) if hasattr(n, "class_identifier") and (cls is None or n.class_identifier == cls)]


@pytest.fixture(scope="module")
def layouts(default_recordings):
    out = {}
    for lesson_id, (path, rec) in default_recordings.items():
        out[lesson_id] = (path, rec, rec.blueprint(), summarize(path))
    return out


@pytest.mark.parametrize("lesson_id", LESSON_IDS)
def test_every_run_with_geometry_has_exactly_one_scene_view(layouts, lesson_id):
    path, rec, bp, info = layouts[lesson_id]
    tabs = bp.root_container.contents
    assert len(tabs) == len(rec.stages)
    for stage, tab in zip(rec.stages, tabs):
        scenes = views(tab, "3D") + views(tab, "2D")
        drawn = [r.entity for r in stage.runs if r.has_geometry]
        assert sorted(v.origin for v in scenes) == sorted(drawn), (stage.index, stage.title)
        assert len(set(drawn)) == len(drawn)
        for v in scenes:  # the origin is the run itself, named by its label
            run = next(r for r in stage.runs if r.entity == v.origin)
            assert v.name.startswith(run.label)
            assert v.contents == "$origin/**"
        # runs that drew nothing have no view; every scene view's run is in the file
        for v in scenes:
            assert any(p == v.origin or p.startswith(v.origin + "/") for p in info), v.origin


@pytest.mark.parametrize("lesson_id", LESSON_IDS)
def test_every_scene_view_has_a_camera_that_frames_its_run(layouts, lesson_id):
    _, rec, bp, _ = layouts[lesson_id]
    runs = {r.entity: r for s in rec.stages for r in s.runs}
    for v in views(bp.root_container, "3D"):
        eye = v.properties.get("EyeControls3D")
        assert eye is not None, v.name
        pos = np.array(eye.position.as_arrow_array().to_pylist()[0], dtype=float)
        target = np.array(eye.look_target.as_arrow_array().to_pylist()[0], dtype=float)
        run = runs[v.origin]
        centre = 0.5 * (run.lo + run.hi)
        assert np.allclose(target, centre, atol=1e-6 * (1 + np.abs(centre).max()))
        # every corner of the run's box is inside the field of view: vertical half-angle FOV_Y/2,
        # horizontal as wide times the aspect of the view the camera was placed for
        up = np.array(eye.eye_up.as_arrow_array().to_pylist()[0], dtype=float)
        axis = (target - pos) / np.linalg.norm(target - pos)
        up = up - (up @ axis) * axis
        up /= np.linalg.norm(up)
        right = np.cross(axis, up)
        tan = math.tan(FOV_Y / 2)
        for corner in np.array(np.meshgrid(*zip(run.lo, run.hi))).reshape(3, -1).T:
            d = corner - pos
            along = d @ axis
            assert along > 0, (v.name, "the body is behind the eye")
            assert abs(d @ up) / along <= tan * (1 + 1e-9), (v.name, "clipped at the top or bottom")
            assert abs(d @ right) / along <= run.aspect * tan * (1 + 1e-9), (v.name, "clipped at a side")


@pytest.mark.parametrize("lesson_id", LESSON_IDS)
def test_every_stage_shows_a_picture_of_its_point(layouts, lesson_id):
    """No tab is text alone: each stage draws at least one scene (rod-waves' stencil check and
    explicit-vs-implicit's cost curves were tables only)."""
    _, rec, bp, _ = layouts[lesson_id]
    for stage, tab in zip(rec.stages, bp.root_container.contents):
        assert views(tab, "3D") or views(tab, "2D"), f"{lesson_id} stage {stage.index} ({stage.title}) draws nothing"


@pytest.mark.parametrize("lesson_id", LESSON_IDS)
def test_the_recording_opens_on_a_tab_with_geometry(layouts, lesson_id):
    _, rec, bp, _ = layouts[lesson_id]
    tabs = bp.root_container
    active = tabs.active_tab
    opening = tabs.contents[active]
    assert views(opening, "3D") or views(opening, "2D"), f"{lesson_id} opens on {opening.name!r}"
    first = next(s for s in rec.stages if s.scene_runs)
    assert opening.name.startswith(f"{first.index}. ")


@pytest.mark.parametrize("lesson_id", LESSON_IDS)
def test_no_view_is_empty_and_events_are_shown_where_they_happen(layouts, lesson_id):
    _, rec, bp, info = layouts[lesson_id]
    for stage, tab in zip(rec.stages, bp.root_container.contents):
        for v in views(tab):
            holds = [p for p in info if p == v.origin or p.startswith(v.origin.rstrip("/") + "/")]
            assert holds, f"stage {stage.index}: view {v.name!r} ({v.origin}) shows nothing"
        logs = views(tab, "TextLog")
        assert bool(logs) == stage.has_events, stage.index
        if stage.has_events:
            assert any(p.endswith("/events") and p.startswith(f"/stage{stage.index}/") for p in info)
        plots = views(tab, "TimeSeries")
        own = {f"{r.entity}/{r.plot[0]}" for r in stage.runs if r.plot}
        assert all(("energy" in p.origin) or p.origin in own for p in plots)


def test_the_hanging_cloth_plots_what_settles_on_a_log_scale(layouts):
    """membranes stage 4: the cloth looks still after a few percent of the playback, while its distance
    to the static equilibrium falls by orders of magnitude: each run's plot shows that (log10), not the
    energy, whose change is invisible on a linear axis."""
    _, rec, bp, info = layouts["membranes"]
    stage = next(s for s in rec.stages if s.index == 4)
    tab = bp.root_container.contents[rec.stages.index(stage)]
    plots = views(tab, "TimeSeries")
    assert len(plots) == 2 and all(p.origin.endswith("/settling") and p.name.startswith("log10") for p in plots)
    for p in plots:
        assert {f"{p.origin}/log10_distance", f"{p.origin}/log10_excess"} <= set(info), p.origin


@pytest.mark.parametrize("lesson_id", LESSON_IDS)
def test_default_recording_is_within_the_size_budget(layouts, lesson_id):
    path, *_ = layouts[lesson_id]
    assert path.stat().st_size <= SIZE_BUDGET, f"{path.name}: {path.stat().st_size / 1e6:.1f} MB"


@pytest.mark.parametrize("lesson_id", LESSON_IDS)
def test_runs_draw_enough_frames_to_see_them_move(layouts, lesson_id):
    """A run stepped through the lesson runner draws tens of frames, not a slideshow: at least
    MIN_FRAMES_PER_RUN over its span on the progress timeline (pro rata when the stage gives its
    runs a common span longer than this run; at most one per step; runs that blew up early or drew
    a single state are exempt)."""
    from lessons.app.recorder import MIN_FRAMES_PER_RUN
    _, rec, _, _ = layouts[lesson_id]
    for stage in rec.stages:
        for run in stage.scene_runs:
            if run.span is None or run.has_events or not run.n_steps or not run.duration:
                continue
            share = min(1.0, run.duration / run.span)
            expected = min(math.floor(MIN_FRAMES_PER_RUN * share), run.n_steps + 1)
            assert run.frames >= expected, (stage.index, run.label, run.frames, expected)
