"""Lesson bending: every experiment, with its key figures asserted explicitly, and the recording.

The engine's own physics tests are in tests/test_bending_energy.py (angle, gradients,
Hessians, invariances, errors: B < 0, degenerate wings) and tests/test_mesh.py (hinges on
open and closed meshes, boundary edges without hinges, non-manifold edges refused); they
are not repeated here.
"""
import math

import numpy as np
import pytest

from engine.errors import ParameterError
from engine.recorder import Recorder, summarize
from lessons._framework import validate_config
from lessons.bending import LESSON, BendingConfig
from lessons.bending.stages import closed_form_ratio
from tests.helpers import assert_all_passed, cli, run_stage


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    path = tmp_path_factory.mktemp("bending") / "bending.rrd"
    rec = Recorder(path, "test_bending")
    stages = {i: run_stage(LESSON, i, rec=rec) for i in range(1, len(LESSON.stages) + 1)}
    rec.close()
    return stages, path


@pytest.fixture(scope="module")
def stages(recording):
    return recording[0]


def test_stage1_hinge_gradient_bridson_invariances(stages):
    s = stages[1]
    assert_all_passed(s)
    assert s["Bridson's u1..u4 equal -dtheta/dx (max difference / max |grad|)"].measured < 1e-13
    assert s["dtheta/dx equals central finite differences (rel. error, 12 random hinges)"].measured < 1e-7
    assert s["zero net force per hinge (max |sum f| / sum |f|)"].measured < 1e-13
    assert s["rigid motion leaves the energy unchanged (max rel. change)"].measured < 1e-12


@pytest.mark.parametrize("theta", [0.5, 1.0])
def test_stage1_half_angle_force_ratio(stages, theta):
    exact = stages[1][f"theta = {theta}: Bridson/notes force ratio equals 2 sin(theta/2)/theta"]
    assert exact.theory == pytest.approx(2 * math.sin(theta / 2) / theta, rel=1e-15)
    assert abs(exact.measured / exact.theory - 1) < 1e-12
    series = stages[1][f"theta = {theta}: force ratio equals 1 - theta^2/24 within the truncation error theta^4/1920"]
    assert series.theory == pytest.approx(1 - theta ** 2 / 24) and series.tolerance == pytest.approx(theta ** 4 / 1920)
    # the two-term series is short by almost exactly the next term, theta^4/1920 (minus theta^6/322560)
    assert series.measured - series.theory == pytest.approx(theta ** 4 / 1920 - theta ** 6 / 322560, rel=1e-3)


def test_stage2_curvature_estimate_and_inverse_square_scaling(stages):
    s = stages[2]
    assert_all_passed(s)
    for label in ("right-triangle grid", "equilateral lattice"):
        order = s[f"{label}: chord-height estimate converges at order 2 in h"]
        assert abs(order.measured - 2) < 0.05
        est = s[f"{label}, n = 33: theta/(h1+h2) with the bent hinge's heights -> 1/(2R)"]
        assert est.theory == 0.5 and 0 < est.measured - 0.5 < 5e-4  # chords are shorter than arcs: slightly high
        assert s[f"{label}, n = 33: with the rest heights the estimate is exact (max rel. error)"].measured < 1e-12
        assert s[f"{label}: the other hinges are flat (max |theta|)"].measured < 1e-12
    p = s["jittered sheet: total energy ~ R^p, fitted exponent p (R/2, R, 2R)"]
    assert abs(p.measured + 2) < 1e-3


def test_closed_form_ratio():
    assert closed_form_ratio("grid", 0) == pytest.approx(1 / 3)
    assert closed_form_ratio("grid", 45) == pytest.approx(1 / 3)
    assert closed_form_ratio("grid", 15) == pytest.approx(1 / 4)
    assert closed_form_ratio("grid", 30) == pytest.approx((1 - math.sqrt(3) / 2 + 3 / 4) / 3)
    assert closed_form_ratio("grid", -45) == pytest.approx(1.0)
    assert closed_form_ratio("lattice", 27) == pytest.approx(1 / 3)
    # the minimum over orientations is 1/4 (sin 2a = 1/2), the maximum 1 (a = -45 degrees)
    a = np.radians(np.linspace(-90, 90, 721))
    r = [closed_form_ratio("grid", math.degrees(v)) for v in a]
    assert min(r) == pytest.approx(0.25, abs=1e-6) and max(r) == pytest.approx(1.0, abs=1e-12)


def test_stage3_one_third_on_regular_meshes_and_discrete_shells_fix(stages):
    s = stages[3]
    assert_all_passed(s)
    for label in ("right-triangle grid at 0 deg", "right-triangle grid at 45 deg (diagonals along the axis)",
                  "equilateral lattice at 0 deg", "equilateral lattice at 15 deg"):
        e = s[f"{label}: notes / continuum, extrapolated to h -> 0"]
        assert e.theory == pytest.approx(1 / 3) and abs(e.measured - 1 / 3) < 1e-3 / 3
    finest = s["right-triangle grid at 0 deg: notes / continuum at the finest level (n = 129)"]
    assert finest.measured == pytest.approx((129 - 2) / (129 - 1) / 3, rel=1e-9)  # one strip of width h is missing
    assert s["right-triangle grid at 0 deg: the ratio's error shrinks at order 1 (the free-edge strip)"].passed
    for label in ("right-triangle grid at 0 deg", "right-triangle grid at 45 deg (diagonals along the axis)",
                  "equilateral lattice at 0 deg"):
        ds = s[f"{label}: Discrete Shells / continuum at the finest level (n = 129)"]
        assert abs(ds.measured - 1) < 1e-2


@pytest.mark.parametrize("label,value", [("right-triangle grid at 15 deg", 0.25),
                                         ("right-triangle grid at 30 deg", 0.2947),
                                         ("right-triangle grid at -45 deg (diagonals around the cylinder)", 1.0)])
def test_stage3_ratio_depends_on_orientation(stages, label, value):
    e = stages[3][f"{label}: notes / continuum, extrapolated to h -> 0"]
    assert e.theory == pytest.approx(value, abs=1e-4)
    assert abs(e.measured / e.theory - 1) < 1e-3


@pytest.mark.parametrize("label", ["jittered right-triangle grid", "jittered equilateral lattice"])
def test_stage3_jittered_meshes_are_mesh_dependent(stages, label):
    s = stages[3]
    pred = s[f"{label}, n = 65: ratio equals the small-bend sum of its own hinges"]
    assert abs(pred.measured / pred.theory - 1) < 1e-3
    above = s[f"{label}, n = 65: ratio / regular mesh's ratio exceeds 1.01 (mesh-dependent)"]
    assert above.passed and above.measured > 1.01
    assert abs(pred.measured - 1 / 3) > 0.02  # not the regular meshes' third


def test_stage4_cloth_folds_fewer_as_B_grows_and_pins_carry_the_weight(stages):
    s = stages[4]
    assert_all_passed(s)
    small = s["folds at B = 0.0003 >= folds at B = 0.003 (mean over three lines)"]
    large = s["folds at B = 0.003 >= folds at B = 0.03"]
    assert small.measured >= small.theory == large.measured >= large.theory
    assert small.measured >= large.theory + 1
    R = s["B = 0.003: vertical pin reactions / total weight (bound: N tol m_max g / W)"]
    assert abs(R.measured - 1) <= R.tolerance < 2e-5  # 439 free vertices x tol 1e-5 x m_max g / W
    for B in ("0.0003", "0.003", "0.03"):
        assert s[f"B = {B}: static equilibrium reached (residual)"].measured <= 1e-5


def test_stage5_curved_shell_linear_response_and_spring_back(stages):
    s = stages[5]
    assert_all_passed(s)
    assert s["rest angles from the curved mesh: no force at rest (max |f| / vertex weight)"].measured < 1e-9
    assert s["with theta_bar = 0 the rest shape is pushed (max bending |f| / vertex weight)"].measured > 10
    ratio = s["twice the weight gives twice the displacement (ratio)"]
    assert abs(ratio.measured / 2 - 1) < 3e-2
    assert s["own weight: max displacement / radius is small"].measured < 1e-2
    assert s["the push (40 x weight) deforms visibly (max displacement / R)"].measured > 1e-2
    assert s["2 s after the release the shell is back at rest (max |x - X| / R)"].measured < 1e-6
    assert s["static solves (weight, 2x weight, push) reached the tolerance (max residual)"].measured <= 1e-5


def test_recording_has_coloured_meshes_and_energies(recording):
    _, path = recording
    info = summarize(path)
    for B in ("0.0003", "0.003", "0.03"):
        mesh = info[f"/stage4/cloth_B{B}/mesh"]
        assert mesh["static_chunks"] >= 1 and len(mesh["frames"]) >= 50  # the fall, then the equilibrium
        assert any("vertex_colors" in c.lower() or "color" in c.lower() for c in mesh["components"])
        assert len(info[f"/stage4/cloth_B{B}/energy/potential"]["frames"]) == 100
    assert len(info["/stage5/release/energy/total"]["frames"]) == 200
    assert "/stage3/grid_0deg/mesh" in info and "/stage1/hinge/mesh" in info
    assert path.stat().st_size < 50e6


@pytest.mark.parametrize("variant", ["bridson", "discrete-shells"])
def test_other_variants_pass_hinge_curvature_and_shell(variant):
    for stage in (1, 2, 5):
        assert_all_passed(run_stage(LESSON, stage, bending=variant))


def test_config_validation():
    with pytest.raises(ParameterError, match="--bending must be one of notes, bridson, discrete-shells"):
        validate_config(BendingConfig(bending="plates"))
    with pytest.raises(ParameterError, match="--finest must be 4k"):
        validate_config(BendingConfig(finest=131))
    with pytest.raises(ParameterError, match="--jitter"):
        validate_config(BendingConfig(jitter=0.5))
    validate_config(BendingConfig())


def test_cli_lists_the_bending_option(tmp_path):
    r = cli("run", "bending", "--help", cwd=tmp_path)
    assert r.returncode == 0
    out = " ".join(r.stdout.split())
    assert "--bending NAME" in out and "one of notes, bridson, discrete-shells" in out and "(default: notes)" in out
    r = cli("run", "bending", "--bending", "plates", "--no-record", cwd=tmp_path)
    assert r.returncode == 2 and "--bending must be one of" in r.stderr


# ------------------------------------------------------------ stepping options (--integrator)

CLOTH_RUNS = [f"cloth_B{B}" for B in ("0.0003", "0.003", "0.03")]


def test_backward_euler_override_runs_the_cloth_falls_and_the_release_as_scene_runs():
    for stage, runs in ((4, CLOTH_RUNS), (5, ["release"])):
        used = []
        s = run_stage(LESSON, stage, stepping=dict(integrator="backward-euler"), used=used)
        assert_all_passed(s)
        # scene runs (not [fixed]) that keep their own solver, since --solver was not given
        assert used == [f"{run}: backward-euler (cholesky, tol 1e-08)" for run in runs]
    assert s["2 s after the release the shell is back at rest (max |x - X| / R)"].measured < 1e-6


def test_explicit_override_substeps_the_release_and_keeps_its_energy():
    import io

    from engine.recorder import NullRecorder
    from lessons._framework import StageContext, Stepping

    stream = io.StringIO()  # a softer shell (larger CFL step) keeps the test short: ~30000 -> ~16000 sub-steps
    ctx = StageContext(LESSON, LESSON.config(shell_E=2.5e3), NullRecorder(), 5, stream=stream,
                       stepping=Stepping(integrator="velocity-verlet"))
    s = {e.claim: e for e in LESSON.stages[4].run(ctx)}
    assert_all_passed(s)
    assert ctx.integrators_used == ["release: velocity-verlet"]
    progress = stream.getvalue()
    assert "release: velocity-verlet needs dt <=" in progress and "sub-steps per step" in progress
    drift = s["velocity-verlet does not damp: total energy after the release = the push's elastic energy "
              "(max |E - W0| / W0)"]
    assert drift.measured < 1e-3  # second order: far inside the 1% of the claim
    virial = s["velocity-verlet: the shell oscillates about its rest shape: mean kinetic / mean elastic energy = 1 "
               "(virial theorem)"]
    assert abs(virial.measured - 1) < 2e-2
    assert not any("back at rest" in claim for claim in s)  # that claim is backward Euler's damping


def test_explicit_override_keeps_the_cloth_falls_fixed_to_backward_euler():
    used = []
    assert_all_passed(run_stage(LESSON, 4, stepping=dict(integrator="symplectic-euler"), used=used, cloth_n=11))
    assert used == [f"{run}: backward-euler (cholesky, tol 1e-08) [fixed]" for run in CLOTH_RUNS]


def test_forward_euler_release_is_stopped_at_the_step_with_the_cause():
    from engine.errors import BlowUpError
    with pytest.raises(BlowUpError, match=r"forward-euler blew up at step \d+ .*unstable for springs"):
        run_stage(LESSON, 5, stepping=dict(integrator="forward-euler"), shell_E=2.5e3)
