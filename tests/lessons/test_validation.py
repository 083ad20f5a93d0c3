"""Bad input is refused up front, in one line, and nothing is written.

- Every numeric config field of every lesson (and the time-stepping options): 0, -1, nan,
  +-inf and the values just outside its documented range give exit 2, one line on stderr
  naming the flag, the value and the valid range, and no recording or results file.
- Broken meshes (degenerate, inverted, non-manifold, inconsistently oriented, duplicate or
  non-finite vertices, indices out of range) and broken models (pins out of range, massless
  free vertices, bad gravity, non-finite states) raise MeshError/ModelError naming the element.
- Unknown lesson, stage, integrator, solver or arch: exit 2, one line.
- Output paths: a recording that already exists is replaced atomically (the old file stays
  intact until the new one is complete, even if the writer is killed); an unwritable place
  (a parent that is a regular file, which stops even root) is exit 2.
"""
import contextlib
import dataclasses
import io
import math
import os
import signal
import subprocess
import sys
import time
from unittest import mock

import numpy as np
import pytest

from engine import mesh as M
from engine.energies.bending import BendingEnergy
from engine.mesh import Mesh, MeshError
from engine.errors import ModelError
from engine.model import Model
from lessons.app.recorder_read import summarize
from lessons.app import cli, registry
from lessons._framework import Stepping, field_type, range_text
from tests.helpers import ROOT

LESSONS = registry.all_lessons()


def main_in(tmp_path, *argv):
    """``lessons.app.cli.main(argv)`` in-process with ``tmp_path`` as the working directory; returns
    (rc, stdout, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    old = os.getcwd()
    os.chdir(tmp_path)
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            rc = cli.main(list(argv))
    finally:
        os.chdir(old)
    return rc, out.getvalue(), err.getvalue()


def assert_usage_error(tmp_path, rc, out, err, *needles, files=()):
    assert rc == 2, (out, err)
    lines = err.strip("\n").split("\n")
    assert len(lines) == 1 and lines[0].startswith("python -m lessons: error: "), err
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(files), "something was written"
    return lines[0]


# --------------------------------------------------------------------------------------------
# every numeric field of every lesson
# --------------------------------------------------------------------------------------------

def _outside(kind, meta) -> list[str]:
    """0, -1, nan, +-inf and the nearest values outside the range that are invalid for it."""
    values = ["0", "-1", "nan", "inf", "-inf"]
    if meta.get("gt") is not None:
        values.append(repr(kind(meta["gt"])))
    if meta.get("ge") is not None:
        values.append(str(meta["ge"] - 1) if kind is int else repr(float(np.nextafter(meta["ge"], -np.inf))))
    if meta.get("lt") is not None:
        values.append(repr(kind(meta["lt"])))
    if meta.get("le") is not None:
        values.append(str(meta["le"] + 1) if kind is int else repr(float(np.nextafter(meta["le"], np.inf))))
    out = []
    for text in dict.fromkeys(values):
        try:
            v = kind(text)
        except ValueError:  # "nan"/"inf" for an integer field: not an integer at all
            out.append(text)
            continue
        ok = (math.isfinite(v) and (meta.get("gt") is None or v > meta["gt"]) and (meta.get("ge") is None or v >= meta["ge"])
              and (meta.get("lt") is None or v < meta["lt"]) and (meta.get("le") is None or v <= meta["le"]))
        if not ok:
            out.append(text)
    return out


def _numeric_fields():
    cases = []
    for lesson in LESSONS:
        for f in dataclasses.fields(lesson.config):
            if f.metadata and not f.metadata.get("choices") and field_type(f) in (int, float):
                cases.append(pytest.param(lesson.id, f, id=f"{lesson.id}--{f.name}"))
    for f in dataclasses.fields(Stepping):
        if f.metadata and not f.metadata.get("choices") and field_type(f) in (int, float):
            cases.append(pytest.param(LESSONS[0].id, f, id=f"stepping--{f.name}"))
    return cases


def test_every_lesson_has_numeric_fields_with_documented_ranges():
    for lesson in LESSONS:
        for f in dataclasses.fields(lesson.config):
            if f.metadata and field_type(f) in (int, float) and not f.metadata.get("choices"):
                assert range_text(f.metadata) != "any value", f"{lesson.id}: --{f.name} has no range"


@pytest.mark.parametrize("lesson_id,field", _numeric_fields())
def test_out_of_range_values_are_one_line_errors_naming_flag_value_and_range(tmp_path, lesson_id, field):
    kind, meta = field_type(field), field.metadata
    flag = "--" + field.name.replace("_", "-")
    values = _outside(kind, meta)
    assert {"nan", "inf", "-inf"} <= set(values)
    for text in values:
        rc, out, err = main_in(tmp_path, "run", lesson_id, flag, text, "--results", "res.json")
        try:
            shown = repr(kind(text))
        except ValueError:
            shown = repr(text)
        line = assert_usage_error(tmp_path, rc, out, err, flag, range_text(meta))
        assert shown in line or f"got {text}" in line, (text, line)


# --------------------------------------------------------------------------------------------
# names that must be one of a list
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("argv,needles", [
    (["run", "no-such-lesson"], ["LESSON must be one of", "'no-such-lesson'"]),
    (["run", "rod_waves", "--stage", "1"], ["LESSON must be one of", "'rod_waves'"]),
    (["run", "rod-waves", "--stage", "0"], ["--stage must be in 1..4", "(got 0)"]),
    (["run", "rod-waves", "--stage", "5"], ["--stage must be in 1..4", "(got 5)"]),
    (["run", "rod-waves", "--stage", "-2"], ["--stage must be in 1..4", "(got -2)"]),
    (["run", "rod-waves", "--stage", "two"], ["--stage", "'two'"]),
    (["run", "all", "--stage", "1"], ["--stage needs a single lesson"]),
    (["run", "rod-waves", "--integrator", "runge-kutta"], ["--integrator must be one of", "'runge-kutta'",
                                                          "backward-euler"]),
    (["run", "all", "--integrator", "euler"], ["--integrator must be one of", "'euler'"]),
    (["run", "springs", "--solver", "lu"], ["--solver must be one of default, pcg, cholesky", "'lu'"]),
    (["run", "springs", "--tol", "0"], ["--tol must be > 0 and < 1", "(got 0.0)"]),
    (["run", "springs", "--tol", "1"], ["--tol must be > 0 and < 1", "(got 1.0)"]),
    (["run", "springs", "--newton-iterations", "0"], ["--newton-iterations must be ≥ 1 and ≤ 100", "(got 0)"]),
    (["run", "rod-waves", "--arch", "tpu"], ["--arch must be one of cpu, cuda, vulkan", "'tpu'"]),
    (["run", "rod-waves", "--threads", "0"], ["--threads must be an integer in 1..256", "(got 0)"]),
    (["run", "rod-waves", "--threads", "many"], ["--threads", "'many'"]),
    (["run", "bending", "--bending", "elastic"], ["--bending must be one of notes, bridson, discrete-shells",
                                                  "'elastic'"]),
    (["run", "rod-waves", "--no-such-flag", "1"], ["unrecognized arguments: --no-such-flag 1"]),
    (["run", "rod-waves", "--E"], ["--E: expected one argument"]),
    (["walk"], ["command must be 'list', 'run', 'exercise', 'check', 'grade', 'view' or 'notebook'", "'walk'"]),
    ([], ["a command is required: list, run, exercise, check, grade, view or notebook"]),
    (["run"], ["LESSON is required"]),
])
def test_unknown_names_and_missing_values_are_one_line_errors(tmp_path, argv, needles):
    assert_usage_error(tmp_path, *main_in(tmp_path, *argv), *needles)


def test_options_before_the_lesson_are_read_as_options(tmp_path):
    """``run --stage 9 rod-waves``: 9 is the value of --stage, not the lesson."""
    assert_usage_error(tmp_path, *main_in(tmp_path, "run", "--stage", "2", "--E", "-1e-3", "rod-waves"),
                       "--E must be ≥ 1e-06 and ≤ 1e+12 (got -0.001)")
    assert_usage_error(tmp_path, *main_in(tmp_path, "run", "--results", "res.json", "--stage", "9", "rod-waves"),
                       "--stage must be in 1..4")


# --------------------------------------------------------------------------------------------
# output paths
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("argv,needle", [
    (["run", "rod-waves", "--record", "blocker/x.rrd"], "--record blocker/x.rrd: cannot write there"),
    (["run", "all", "--record", "blocker"], "--record blocker/rod-waves.rrd: cannot write there"),
    (["run", "rod-waves", "--record", "sub"], "--record sub: cannot write there"),
    (["run", "rod-waves", "--no-record", "--results", "blocker/res.json"], "--results blocker/res.json: cannot write"),
    (["run", "rod-waves", "--no-record", "--results", "sub"], "--results sub: cannot write there"),
    # (a missing directory is created, as for --record: tests/app/test_output_files.py)
    (["run", "rod-waves", "--no-record", "--results", "blocker/new/res.json"], "--results blocker/new/res.json: cannot"),
    (["run", "rod-waves", "--no-record", "--results", "r" * 300], "cannot write there"),
    (["run", "rod-waves", "--results", "blocker/res.json", "--record", "new/r.rrd"], "--results blocker/res.json"),
])
def test_unwritable_output_is_a_usage_error_and_creates_nothing(tmp_path, argv, needle):
    (tmp_path / "blocker").write_text("a regular file where a directory is expected")
    (tmp_path / "sub").mkdir()
    assert_usage_error(tmp_path, *main_in(tmp_path, *argv), needle, files=["blocker", "sub"])
    assert list((tmp_path / "sub").iterdir()) == []


def test_existing_recording_is_replaced_only_when_the_new_one_is_complete(tmp_path):
    target = tmp_path / "r.rrd"
    old = b"the previous recording, which must survive until the new one is complete"
    target.write_bytes(old)
    seen = {}
    real = cli.run_lesson

    def watching(lesson, cfg, rec, *args, **kwargs):
        seen["before"] = target.read_bytes()
        ok = real(lesson, cfg, rec, *args, **kwargs)
        seen["after_run"] = target.read_bytes()  # everything logged, file not yet closed
        seen["partials"] = [p.name for p in tmp_path.glob(".r.rrd.partial-*")]
        return ok

    with mock.patch.object(cli, "run_lesson", watching):
        rc, out, err = main_in(tmp_path, "run", "rod-waves", "--stage", "1", "--record", "r.rrd", "--quiet")
    assert rc == 0, err
    assert seen["before"] == old and seen["after_run"] == old and len(seen["partials"]) == 1
    assert target.read_bytes() != old and not list(tmp_path.glob(".*partial*"))
    assert "/stage1/narrative" in summarize(target)


def test_killed_run_leaves_the_old_recording_intact(tmp_path):
    target = tmp_path / "r.rrd"
    old = b"the previous recording"
    target.write_bytes(old)
    env = dict(os.environ, PYTHONPATH=str(ROOT), ELASTIC_CACHE_DIR=str(ROOT / ".ti_cache"))
    proc = subprocess.Popen([sys.executable, "-m", "lessons", "run", "rod-waves", "--cfl-steps", "10000000",
                             "--record", "r.rrd"], cwd=tmp_path, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    deadline = time.time() + 120
    while time.time() < deadline:
        line = proc.stdout.readline()
        if "stage 3/4" in line or not line:
            break
    time.sleep(0.5)
    assert proc.poll() is None, "the run ended before it could be killed"
    proc.send_signal(signal.SIGKILL)
    proc.communicate(timeout=60)
    assert target.read_bytes() == old


# --------------------------------------------------------------------------------------------
# meshes and models, directly
# --------------------------------------------------------------------------------------------

SQUARE = [[0, 0], [1, 0], [1, 1], [0, 1]]
TETRA = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]


@pytest.mark.parametrize("mesh,need_hinges,pattern", [
    (Mesh([[0, 0, 0], [1, 0, 0], [2, 0, 0]], triangles=[[0, 1, 2]]), False,
     r"^triangle 0 \(vertices 0, 1, 2\) has (zero|near-zero) area"),                     # degenerate in 3D
    (Mesh([[0, 0, 0], [1, 0, 0], [1, 1e-11, 0], [0, 1, 0]], triangles=[[0, 1, 2], [0, 2, 3]]), False,
     r"^triangle 0 \(vertices 0, 1, 2\) has near-zero area"),
    (Mesh(SQUARE, triangles=[[0, 2, 1]]), False, r"^triangle 0 \(vertices 0, 2, 1\) is inverted"),
    (Mesh(SQUARE, triangles=[[0, 1, 2], [0, 3, 2]]), False, r"^triangle 1 \(vertices 0, 3, 2\) is inverted"),
    (Mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1]],
          triangles=[[0, 1, 2], [1, 0, 3], [0, 1, 4]]), True, r"^edge \(0, 1\) is shared by 3 triangles"),
    (Mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0]], triangles=[[0, 1, 2], [0, 1, 3]]), True,
     r"^triangles 0 \(0, 1, 2\) and 1 \(0, 1, 3\) are inconsistently oriented"),
    (Mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], triangles=[[0, 1, 2], [0, 1, 2]]), True,
     r"inconsistently oriented"),                                                          # a duplicated triangle
    (Mesh(TETRA, tets=[[0, 2, 1, 3]]), False, r"^tet 0 \(vertices 0, 2, 1, 3\) is inverted"),
    (Mesh(TETRA[:3] + [[1, 1, 0]], tets=[[0, 1, 2, 3]]), False, r"^tet 0 \(vertices 0, 1, 2, 3\) is flat"),
    (Mesh(SQUARE, triangles=[[0, 1, 4]]), False, r"^triangle 0 \(vertices 0, 1, 4\) has index 4 outside"),
    (Mesh(SQUARE + [[1, 1]], triangles=[[0, 1, 2], [0, 2, 3]]), False, r"^vertices 2 and 4 are at the same position"),
    (Mesh([[0, 0], [1, 0], [0, math.nan]], triangles=[[0, 1, 2]]), False, r"^vertex 2 has non-finite"),
    (Mesh([[0, 0, 0], [1, 0, 0], [1, 0, 0]], segments=[[0, 1], [1, 2]]), False, r"same position"),
])
def test_broken_meshes_are_refused_naming_the_element(mesh, need_hinges, pattern):
    with pytest.raises(MeshError, match=pattern) as info:
        M.validate(mesh, need_hinges=need_hinges)
    assert "\n" not in str(info.value)


def test_bending_on_a_non_manifold_mesh_is_refused():
    mesh = Mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1]],
                triangles=[[0, 1, 2], [1, 0, 3], [0, 1, 4]])
    with pytest.raises(MeshError, match=r"edge \(0, 1\) is shared by 3 triangles"):
        BendingEnergy.from_mesh(mesh, 1.0)


X4 = np.array(TETRA, float)
EDGES = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]])


@pytest.mark.parametrize("build,pattern", [
    (lambda: Model(X4, pinned=[4]), r"^pin index 4 is out of range 0\.\.3$"),
    (lambda: Model(X4, pinned=[-1]), r"^pin index -1 is out of range 0\.\.3$"),
    (lambda: Model(X4, pinned=[0, 2 ** 40]), r"^pin index 1099511627776 is out of range"),
    (lambda: Model(X4, pinned=np.array([True, False])), r"^pinned mask must have shape \(4,\)"),
    (lambda: Model(X4, pinned=[0.5]), r"^pinned must be a boolean mask or integer vertex indices"),
    (lambda: Model(X4, mass=[1, 1, 0, 1]), r"^vertex 2 is free but has mass 0\.0"),
    (lambda: Model(X4, mass=[1, -1, 1, 1], pinned=[1]), r"^vertex 1 has invalid mass -1\.0"),
    (lambda: Model(X4, mass=math.nan), r"^vertex 0 has invalid mass nan"),
    (lambda: Model(X4, mass=[1, 1]), r"^mass must be a scalar or have shape \(4,\)"),
    (lambda: Model(X4, gravity=[0, -9.81]), r"^gravity must be 3 finite numbers"),
    (lambda: Model(X4, gravity=[0, 0, math.inf]), r"^gravity must be 3 finite numbers"),
    (lambda: Model(np.array([[0, 0, 0], [math.inf, 0, 0]])), r"^vertex 1 has a non-finite rest position"),
    (lambda: Model(np.zeros((0, 3))), r"^model has no vertices$"),
    (lambda: Model(X4[:, :2]), r"^rest positions X must have shape \(n, 3\)"),
    (lambda: Model.from_springs(X4, [[0, 4]], k=1.0), r"^edge 0 = \(0, 4\) has a vertex index out of range"),
    (lambda: Model.from_springs(X4, [[1, 1]], k=1.0), r"^edge 0 joins vertex 1 to itself"),
    (lambda: Model.from_springs(np.vstack([X4, X4[:1]]), [[0, 4]], k=1.0), r"^edge 0 joins vertices 0 and 4 at the same"),
    (lambda: Model.from_springs(X4, EDGES, k=-1.0), r"^edge 0 = \(0, 1\) has stiffness k=-1\.0"),
    (lambda: Model.from_springs(X4, EDGES, c=math.nan), r"^edge 0 = \(0, 1\) has stiffness c=nan"),
    (lambda: Model.from_springs(X4, EDGES, k=1.0, L=0.0), r"^edge 0 = \(0, 1\) has rest length 0\.0"),
    (lambda: Model.from_springs(X4, EDGES, k=1.0, pinned=[9]), r"^pin index 9 is out of range"),
    (lambda: BendingEnergy(X4, [[0, 1, 2, 2]], 1.0), r"are not four distinct vertices"),
    (lambda: BendingEnergy(X4, [[0, 1, 2, 7]], 1.0), r"vertex index 7 out of range 0\.\.3"),
    (lambda: BendingEnergy(X4, [[0, 1, 2, 3]], -1.0), r"bending modulus B = -1\.0 must be finite and >= 0"),
    (lambda: BendingEnergy(np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0]]), [[0, 1, 2, 3]], 1.0),
     r"wing triangle \(0, 1, 2\) has zero area"),
    (lambda: Model(X4).make_state(np.full((4, 3), math.nan)), r"^initial positions: vertex 0 is not finite"),
    (lambda: Model(X4).make_state(v=np.array([[0, 0, 0], [0, 0, 0], [0, math.inf, 0], [0, 0, 0]])),
     r"^initial velocities: vertex 2 is not finite"),
    (lambda: Model(X4).make_state(np.zeros((3, 3))), r"^state arrays must have shape \(4, 3\)"),
])
def test_broken_models_are_refused_naming_the_element(build, pattern):
    with pytest.raises(ModelError, match=pattern) as info:
        build()
    assert "\n" not in str(info.value)
