"""Lesson bending: every experiment, with its key figures asserted explicitly, and the recording.

The engine's own physics tests are in tests/engine/test_bending_energy.py (angle, gradients,
Hessians, invariances, errors: B < 0, degenerate wings) and tests/engine/test_mesh.py (hinges on
open and closed meshes, boundary edges without hinges, non-manifold edges refused); they
are not repeated here.
"""
import math

import numpy as np
import pytest

from engine.errors import ParameterError
from lessons.app.recorder_read import summarize
from lessons._framework import validate_config
from lessons.bending import LESSON, BendingConfig
from lessons.bending.stages import closed_form_ratio
from tests.helpers import assert_all_passed, assert_unique_ids, cli, run_stage


@pytest.fixture(scope="module")
def recording(default_runs):
    run = default_runs(LESSON.id)   # every stage at the defaults, as `run` records it (shared)
    return run.stages, run.path, run.rec


@pytest.fixture(scope="module")
def stages(recording):
    return recording[0]


def test_experiment_ids_are_unique_in_the_lesson(stages):
    assert_unique_ids(stages)


def test_stage1_hinge_gradient_bridson_invariances(stages):
    s = stages[1]
    assert_all_passed(s)
    assert s["bridson-u-is-gradient"].measured < 1e-13
    assert s["theta-gradient-fd"].measured < 1e-7
    assert s["zero-net-force"].measured < 1e-13
    assert s["rigid-motion-energy"].measured < 1e-12


@pytest.mark.parametrize("theta", [0.5, 1.0])
def test_stage1_half_angle_force_ratio(stages, theta):
    exact = stages[1][f"bridson-ratio-theta{theta}"]
    assert exact.theory == pytest.approx(2 * math.sin(theta / 2) / theta, rel=1e-15)
    assert abs(exact.measured / exact.theory - 1) < 1e-12
    series = stages[1][f"bridson-ratio-series-theta{theta}"]  # an identity once the exact ratio holds
    assert series.theory == pytest.approx(1 - theta ** 2 / 24) and series.tolerance == pytest.approx(theta ** 4 / 1920)
    # the two-term series is short by almost exactly the next term, theta^4/1920 (minus theta^6/322560)
    assert series.measured - series.theory == pytest.approx(theta ** 4 / 1920 - theta ** 6 / 322560, rel=1e-3)


def test_stage2_curvature_estimate_and_inverse_square_scaling(stages):
    s = stages[2]
    assert_all_passed(s)
    for kind in ("grid", "lattice"):
        order = s[f"{kind}-chord-order"]
        assert abs(order.measured - 2) < 0.05
        est = s[f"{kind}-curvature-estimate"]
        assert "n = 33:" in est.claim
        assert est.theory == 0.5 and 0 < est.measured - 0.5 < 5e-4  # chords are shorter than arcs: slightly high
        assert s[f"{kind}-rest-heights-exact"].measured < 1e-12
        assert s[f"{kind}-other-hinges-flat"].measured < 1e-12
    p = s["jittered-energy-exponent"]
    assert abs(p.measured + 2) < 1e-3


def test_closed_form_ratio_formula_values():
    """The formula's values (an identity check of the closed form as written, not of the physics: that
    the sheets' energies follow it is test_stage3_ratio_depends_on_orientation, measured)."""
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
    for mesh in ("grid-0deg", "grid-45deg", "lattice-0deg", "lattice-15deg"):
        e = s[f"{mesh}-ratio-extrapolated"]
        assert e.theory == pytest.approx(1 / 3) and abs(e.measured - 1 / 3) < 1e-3 / 3
    finest = s["grid-0deg-ratio-finest"]
    assert finest.claim.endswith("(n = 129)")
    assert finest.measured == pytest.approx((129 - 2) / (129 - 1) / 3, rel=1e-9)  # one strip of width h is missing
    assert s["grid-0deg-ratio-error-order"].passed
    for mesh in ("grid-0deg", "grid-45deg", "lattice-0deg"):
        ds = s[f"{mesh}-discrete-shells-ratio"]
        assert ds.claim.endswith("(n = 129)")
        assert abs(ds.measured - 1) < 1e-2


@pytest.mark.parametrize("mesh,value", [("grid-15deg", 0.25), ("grid-30deg", 0.2947), ("grid-minus45deg", 1.0)])
def test_stage3_ratio_depends_on_orientation(stages, mesh, value):
    e = stages[3][f"{mesh}-ratio-extrapolated"]
    assert e.theory == pytest.approx(value, abs=1e-4)
    assert abs(e.measured / e.theory - 1) < 1e-3


@pytest.mark.parametrize("mesh", ["grid-0deg", "grid-45deg", "grid-15deg", "grid-30deg", "grid-minus45deg"])
def test_stage3_each_edge_family_folds_as_the_narrative_says_signs_included(stages, mesh):
    """The narrative's three per-family fold angles, checked hinge by hinge; the second family's
    sign was once written the other way, which this would catch wherever sin a != 0 (at -45 deg
    the diagonals fold against the legs, a concave kink)."""
    e = stages[3][f"{mesh}-edge-family-folds"]
    assert e.passed and e.tolerance == pytest.approx(0.1 / 64 ** 2)  # (h/R)^2 / 10 at n = 65, R = 1


def test_edge_families_on_the_turned_grid_tell_the_signs_apart():
    """At -45 deg the legs' families give +1 and the diagonals -sqrt2/2 (in h/R); flipping the
    second family's sign moves its prediction by 2, far beyond the stage's 2.4e-5."""
    from lessons.bending.scene import edge_family_folds, sheet
    flat, _ = sheet("grid", 9, -45.0)
    family, predicted = edge_family_folds(flat, -45.0)
    for f, value in ((0, 1.0), (1, 1.0), (2, -math.sqrt(0.5))):
        assert np.allclose(predicted[family == f], value)
    assert (family == 2).sum() == 64  # 8 x 8 cells, one diagonal each, all of them hinges


@pytest.mark.parametrize("mesh,value", [("grid-15deg", 0.75), ("grid-30deg", 0.8840), ("grid-minus45deg", 3.0),
                                        ("lattice-15deg", 1.0)])
def test_stage3_discrete_shells_fixes_the_third_only_on_aligned_meshes(stages, mesh, value):
    """Discrete Shells' energy is 3 x the notes' hinge by hinge, so on turned grids it misses the
    continuum just as the notes' does, by 3 x the notes' closed form (measured with its own energy)."""
    e = stages[3][f"{mesh}-discrete-shells-ratio-extrapolated"]
    assert e.theory == pytest.approx(value, abs=1e-4)
    assert abs(e.measured / e.theory - 1) < 1e-4  # measured 3e-7 .. 1.5e-5
    identity = stages[3]["discrete-shells-three-times-notes-identity"]
    assert identity.claim.startswith("identity") and identity.measured < 1e-12


@pytest.mark.parametrize("kind", ["grid", "lattice"])
def test_stage3_jittered_meshes_are_mesh_dependent(stages, kind):
    s = stages[3]
    pred = s[f"jittered-{kind}-ratio-predicted"]
    assert "n = 65:" in pred.claim
    assert abs(pred.measured / pred.theory - 1) < 1e-3
    above = s[f"jittered-{kind}-ratio-above-regular"]
    assert above.passed and above.measured > 1.01
    assert abs(pred.measured - 1 / 3) > 0.02  # not the regular meshes' third


def test_stage4_cloth_folds_fewer_as_B_grows_and_pins_carry_the_weight(stages):
    s = stages[4]
    assert_all_passed(s)
    small = s["folds-soft-vs-mid"]
    large = s["folds-mid-vs-stiff"]
    assert small.claim.startswith("folds at B = 0.0003 >= folds at B = 0.003") and "B = 0.03" in large.claim
    assert small.measured >= small.theory == large.measured >= large.theory
    assert small.measured >= large.theory + 1
    R = s["cloth-mid-vertical-reactions"]
    assert abs(R.measured - 1) <= R.tolerance < 2e-5  # 439 free vertices x tol 1e-5 x m_max g / W
    for cloth in ("soft", "mid", "stiff"):
        assert s[f"cloth-{cloth}-equilibrium"].measured <= 1e-5


def test_stage5_curved_shell_linear_response_and_spring_back(stages):
    s = stages[5]
    assert_all_passed(s)
    assert s["curved-rest-no-force"].measured < 1e-9
    assert s["flat-rest-pushes"].measured > 10
    ratio = s["linear-response"]
    assert abs(ratio.measured / 2 - 1) < 3e-2
    assert s["own-weight-small-displacement"].measured < 1e-2
    assert s["push-deforms"].measured > 1e-2 and "(40 x weight)" in s["push-deforms"].claim
    assert s["release-back-at-rest"].measured < 1e-6
    assert s["static-solves-converged"].measured <= 1e-5


def test_recording_has_coloured_meshes_and_energies(recording):
    _, path, _ = recording
    info = summarize(path)
    for B in ("0.0003", "0.003", "0.03"):
        mesh = info[f"/stage4/cloth_B{B}/mesh"]
        assert mesh["static_chunks"] >= 1 and len(mesh["frames"]) >= 50  # the fall, then the equilibrium
        assert any("vertex_colors" in c.lower() or "color" in c.lower() for c in mesh["components"])
        assert len(info[f"/stage4/cloth_B{B}/energy/potential"]["frames"]) == 100
    assert len(info["/stage5/release/energy/total"]["frames"]) == 200
    assert "/stage3/grid_0deg/mesh" in info and "/stage1/hinge/mesh" in info
    assert path.stat().st_size < 20e6
    # the hinge opens over the whole progress timeline; the sheets are single frames
    hinge = info["/stage1/hinge/mesh"]["frames"]
    assert len(hinge) == 121 and hinge[0] == 0 and hinge[-1] == 1000
    for run in ("grid_0deg", "grid_0deg_discrete-shells", "grid_-45deg", "grid_jittered"):
        assert len(info[f"/stage3/{run}/mesh"]["frames"]) == 1, run
    # the cloth's fall, then its static equilibrium at the end of the timeline
    for B in ("0.0003", "0.003", "0.03"):
        assert info[f"/stage4/cloth_B{B}/mesh"]["frames"][-1] == 1000
    assert len(info["/stage5/release/mesh"]["frames"]) >= 100


def test_recording_views_are_labelled_framed_and_keyed(recording):
    """Every run that drew has its own view: a label (not the run's name), the camera for its
    geometry, and a colour key on a fixed scale; cloths are seen from the front."""
    _, _, rec = recording
    drawn = {(s.index, r.name): r for s in rec.stages for r in s.runs if r.has_geometry}
    assert {name for (i, name) in drawn if i == 3} == {"grid_0deg", "grid_0deg_discrete-shells", "grid_-45deg",
                                                        "grid_jittered"}
    for (i, name), run in drawn.items():
        assert run.label and run.label != name, (i, name)
        assert len(run.keys) == 1, (i, name, run.keys)
        assert run.camera == ("front" if i == 4 else "outside"), (i, name)
    # the sheets on the continuum's scale (yellow: W = W_continuum), the cloths of the sweep on one scale
    for (i, name), run in drawn.items():
        if i in (2, 3):
            assert run.scales == {"energy density / continuum": 1.0}, (i, name)
    cloth_scales = {tuple(run.scales.values()) for (i, _), run in drawn.items() if i == 4}
    assert len(cloth_scales) == 1
    assert drawn[(5, "weight_x1")].scales == drawn[(5, "weight_x2")].scales


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
    assert s["release-back-at-rest"].measured < 1e-6


def test_explicit_override_substeps_the_release_and_keeps_its_energy():
    import io

    from lessons.app.recorder_null import NullRecorder
    from lessons._framework import StageContext, Stepping

    stream = io.StringIO()  # a softer shell (larger CFL step) keeps the test short: ~30000 -> ~16000 sub-steps
    ctx = StageContext(LESSON, LESSON.config(shell_E=2.5e3), NullRecorder(), 5, stream=stream,
                       stepping=Stepping(integrator="velocity-verlet"))
    s = {e.id: e for e in LESSON.stages[4].run(ctx)}
    assert_all_passed(s)
    assert ctx.integrators_used == ["release: velocity-verlet"]
    progress = stream.getvalue()
    assert "release: velocity-verlet needs dt <=" in progress and "sub-steps per step" in progress
    drift = s["release-keeps-energy"]
    assert drift.claim.startswith("velocity-verlet does not damp")
    assert drift.measured < 1e-3  # second order: far inside the 1% of the claim
    virial = s["release-virial"]
    assert virial.claim.startswith("velocity-verlet: the shell oscillates")
    assert abs(virial.measured - 1) < 2e-2
    assert "release-back-at-rest" not in s  # that claim is backward Euler's damping
    assert not any("back at rest" in e.claim for e in s.values())


def test_explicit_override_keeps_the_cloth_falls_fixed_to_backward_euler():
    used = []
    assert_all_passed(run_stage(LESSON, 4, stepping=dict(integrator="symplectic-euler"), used=used, cloth_n=11))
    assert used == [f"{run}: backward-euler (cholesky, tol 1e-08) [fixed]" for run in CLOTH_RUNS]


def test_forward_euler_release_is_stopped_at_the_step_with_the_cause():
    from engine.errors import BlowUpError
    with pytest.raises(BlowUpError, match=r"forward-euler blew up at step \d+ .*unstable for springs"):
        run_stage(LESSON, 5, stepping=dict(integrator="forward-euler"), shell_E=2.5e3)


# ------------------------------------------------------------ range edges

@pytest.mark.parametrize("overrides,needle", [
    (dict(shell_B=1e300), "--shell-B must be ≥ 0.001 and ≤ 1000"),
    (dict(cloth_E=1e300), "--cloth-E must be ≥ 30 and ≤ 100000"),
    (dict(cloth_E=100.0), "E/(rho g L) = 101.9 must be in [300, 102000]"),
    (dict(cloth_B=3e-4), "the bending length (B/(rho g))^(1/3) = 0.0674 m must be in [0.1, 0.31] m"),
    (dict(shell_B=100.0), "rho g R^3/B = 6.131e-05 must be in"),
    (dict(shell_E=50.0), "E R^2/B = 12.5 must be in [25, 250000]"),
    (dict(push=2.0), "--push 2 with --shell-rho 0.005 and --shell-B 1"),
    (dict(push=100.0), "snaps the arch through"),
    (dict(dt=0.002), "--dt must be ≥ 0.005"),
    (dict(radius=100.0), "--radius must be ≥ 0.5 and ≤ 30"),
    (dict(static_tol=1e-12), "--static-tol must be ≥ 1e-08"),
])
def test_values_whose_claims_cannot_hold_are_refused_with_the_reason(overrides, needle):
    with pytest.raises(ParameterError) as info:
        validate_config(BendingConfig(**overrides))
    assert needle in str(info.value) and "\n" not in str(info.value)


def test_range_edges_run_and_pass():
    """Ends of the documented ranges that the claims' tolerances had to follow: the finest level at
    n = 33 (the free-edge strip costs 1/32 of the ratio: tolerance 1.25 h), the exact rest-height
    estimate on a 30 m cylinder (round-off 4 eps (R/h)^2), and the shell at a corner of its box
    (the heaviest load, the softest membrane, dt = 5 ms)."""
    s3 = run_stage(LESSON, 3, finest=33)
    assert_all_passed(s3)
    assert s3["grid-0deg-ratio-finest"].tolerance == pytest.approx(1.25 / 32)
    assert abs(s3["grid-0deg-ratio-finest"].measured * 3 - 31 / 32) < 1e-12
    s2 = run_stage(LESSON, 2, radius=30.0)
    assert_all_passed(s2)
    assert s2["grid-rest-heights-exact"].measured > 1e-12  # round-off, inside 4 eps (R/h)^2 = 9e-10
    corner = dict(shell_B=0.5, shell_E=50.0, push=20.0, dt=0.005)
    validate_config(BendingConfig(**corner))
    assert_all_passed(run_stage(LESSON, 5, **corner))


def test_stiff_cloths_get_newton_steps_in_proportion():
    from lessons.bending.stages_structures import newton_cap
    assert newton_cap(BendingConfig()) == 400  # the default cloth: unchanged
    assert newton_cap(BendingConfig(cloth_E=1e5)) == 4000  # 786 steps measured for the softest cloth there


def test_cli_refuses_a_bad_range_edge_before_any_work(tmp_path):
    r = cli("run", "bending", "--stage", "5", "--shell-B", "1e300", "--results", "r.json", cwd=tmp_path)
    assert r.returncode == 2 and "--shell-B must be" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert list(tmp_path.iterdir()) == []
