"""Each lesson's recording in the real Rerun viewer (headless: Xvfb + Vulkan, lavapipe where
there is no GPU), tab by tab.

For every tab of the root Tabs container, with the time cursor paused at the start of the
timeline the viewer opens on (what it shows first; CHECK_AT):
  * every view: the viewer reports no error for it;
  * 3D/2D scene views: the screenshot has more than SCENE_MIN_DRAWN of its pixels drawn (off
    the background by more than lessons.tools.screenshots.DRAWN_TOLERANCE; the grid does not count);
  * TimeSeries/TextDocument/TextLog views: the recording holds their kind of data under the
    entities they show (scalars, text), read from the recording's schema;
and the tab the viewer opens on has at least one scene view with something drawn.

The recordings are the session's default recordings (every lesson at its defaults, made once in
tests/conftest.py), or ELASTIC_VIEWER_RECORDINGS=<dir with <lesson>.rrd files> to check existing ones.
When the viewer cannot run here the tests fail, saying what is missing and how to install it;
ELASTIC_SKIP_VIEWER=1 skips them instead. Select them with ``-m viewer``. The measured
fractions are printed (``-rA`` or ``-s`` shows them; a failure shows them anyway).
"""
from __future__ import annotations

import os
import time
from pathlib import Path

import pytest

from lessons.app import registry
from lessons.tools.screenshots import drawn_fraction
from lessons.tools.viewer import HeadlessViewer
from lessons.tools.viewer_requirements import APT_INSTALL, ViewerUnavailable, missing

pytestmark = pytest.mark.viewer

ROOT = Path(__file__).resolve().parents[2]
LESSON_IDS = [lesson.id for lesson in registry.all_lessons()]

# Fraction of a scene view's pixels that must be drawn (1600x1000 window, paused at the start).
# Measured: every view with nothing on camera gives 0.0000 (background and grid; the grid stays
# under the tolerance): the old layout's rod-waves stage 1 and springs stage 2 at the end. Views
# showing geometry: one-view-per-stage layout (465x651 px views) 0.0078 (two spring nodes and a
# line) to 0.97; grid-of-runs layout (68 scene views, ~400x180 px) 0.0045 (a short chain of
# springs seen end-on) and 0.0060, then 0.014 upwards, to 0.43.
SCENE_MIN_DRAWN = 0.002
# The window the test opens: smaller than the README's 1600x1000, since lavapipe renders every
# frame in software and its cost grows with the pixels; the fractions are per view, so they hold.
VIEWER_SIZE = (1200, 750)
# Where the time cursor is put (paused) on the timeline the viewer opens on, for each tab:
# "start" is what the viewer shows first (it opens playing from the start); add "end" (every
# entity's last state) or a time in seconds to check those too (each costs a visit per tab).
CHECK_AT = ("start",)
DATA_CLASSES = ("TimeSeries", "TextDocument", "TextLog")


SKIP_REASON = "ELASTIC_SKIP_VIEWER=1 is set: the recordings are not checked in the Rerun viewer"


def _skip_or_fail(reason: str):
    if os.environ.get("ELASTIC_SKIP_VIEWER") == "1":
        pytest.skip(f"{SKIP_REASON} ({reason})")
    pytest.fail(reason, pytrace=False)


@pytest.fixture(scope="session")
def viewer_recordings(request) -> Path:
    """A directory with <lesson>.rrd for every lesson: ELASTIC_VIEWER_RECORDINGS, else the
    session's default recordings (tests/conftest.py: default_recordings, shared with
    tests/app/test_recordings.py)."""
    given = os.environ.get("ELASTIC_VIEWER_RECORDINGS")
    if given:
        return Path(given)
    made = request.getfixturevalue("default_recordings")
    folders = {path.parent for path, _ in made.values()}
    assert len(folders) == 1, folders
    return folders.pop()


@pytest.mark.parametrize("lesson_id", LESSON_IDS)
def test_recording_in_viewer(lesson_id, request, default_runs):
    # default_runs (lazy: it runs nothing) puts the test in the default-runs worker group (tests/conftest.py),
    # so the recordings it opens are made once per test run, on the worker that made them for the others
    if os.environ.get("ELASTIC_SKIP_VIEWER") == "1":
        pytest.skip(SKIP_REASON)
    lacks = missing()
    if lacks:
        _skip_or_fail("cannot run the Rerun viewer headless: missing " + "; ".join(lacks)
                      + f". Install with: {APT_INSTALL}")
    path = request.getfixturevalue("viewer_recordings") / f"{lesson_id}.rrd"
    assert path.is_file(), f"no recording {path}"

    problems, lines = [], []
    t0 = time.monotonic()
    try:
        with HeadlessViewer(path, size=VIEWER_SIZE) as v:
            tabs = v.tabs()
            opening = v.active_tab_index()
            timeline = v.current_time()[0]
            lines.append(f"{lesson_id}: opened in {v.open_seconds:.1f} s, {len(tabs)} tabs, opening tab "
                         f"{'?' if opening is None else opening + 1}, {v.play_state().lower()} on {timeline}")
            if not tabs:
                problems.append("the blueprint has no tabs or views")
            v.pause()
            drawn_in_opening = 0
            for i, tab in enumerate(tabs):
                v.show_tab(i, settle=False)
                where = f"tab {i + 1} ({tab.name!r})"
                for at in CHECK_AT:
                    if timeline is not None:
                        v.set_time(timeline, at)  # paused there, and settled
                    else:
                        v.settle()
                    views = [view for view in v.views() if view.visible]
                    if not views:
                        problems.append(f"{where}: no views")
                    for view in views:
                        what = f"{where} {view.view_class} {view.name!r} ({view.origin}) at {at}"
                        for error in view.errors:
                            problems.append(f"{what}: the viewer reports: {error}")
                        for warning in view.warnings:
                            lines.append(f"  {what}: warning: {warning}")
                        if view.is_scene:
                            fraction = drawn_fraction(v.screenshot_view(view.id))
                            lines.append(f"  {what}: drawn {fraction:.4f}")
                            if fraction > SCENE_MIN_DRAWN:
                                drawn_in_opening += i == opening
                            else:
                                problems.append(f"{what}: drawn fraction {fraction:.4f} <= {SCENE_MIN_DRAWN} "
                                                "(nothing on camera)")
                        elif view.view_class in DATA_CLASSES and at == CHECK_AT[0] and not v.view_has_data(view):
                            problems.append(f"{what}: empty (no {view.view_class} data under {view.origin})")
                    if not v.settled:
                        lines.append(f"  {where} at {at}: the picture did not settle")
            if opening is not None and tabs and not drawn_in_opening:
                problems.append(f"the opening tab ({opening + 1}, {tabs[opening].name!r}) shows no geometry")
            lines.append(f"{lesson_id}: checked in {time.monotonic() - t0:.1f} s")
    except ViewerUnavailable as exc:
        _skip_or_fail(str(exc))
    print("\n".join(lines))
    assert not problems, (f"{lesson_id} ({path}) in the viewer: {len(problems)} problem(s):\n  "
                          + "\n  ".join(problems) + "\nmeasured:\n" + "\n".join(lines))
