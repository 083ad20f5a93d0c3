"""Lesson rod-waves: every experiment, with its key figures asserted explicitly."""
import math

import pytest

from lessons.rod_waves import LESSON
from tests.helpers import assert_all_passed, assert_unique_ids, run_stage


@pytest.fixture(scope="module")
def stages(default_runs):
    return default_runs(LESSON.id).stages   # every stage at the defaults, shared with the recording tests


def test_experiment_ids_are_unique_in_the_lesson(stages, backward):
    assert_unique_ids(stages)
    assert_unique_ids({i: s for i, (s, _) in backward.items()})


def test_stage1_force_is_the_pde_stencil_and_the_energy_gradient(stages):
    s = stages[1]
    assert_all_passed(s)
    assert s["force-is-pde-stencil"].measured < 1e-12
    assert s["force-is-energy-gradient"].measured < 1e-6


@pytest.mark.parametrize("nu", [0.25, 0.5, 1.0])
def test_stage2_pulse_speed_is_sqrt_E_over_rho(stages, nu):
    e = stages[2][f"pulse-speed-nu{nu}"]
    assert e.theory == 1.0  # sqrt(E/rho) with the defaults E = rho = 1
    assert abs(e.measured - 1.0) < 5e-3


def test_stage2_left_pulse_and_dalembert_split(stages):
    assert_all_passed(stages[2])
    amp = stages[2]["dalembert-half-amplitude"]
    assert amp.measured == pytest.approx(0.5e-3, rel=1e-2)


def test_stage3_cfl(stages):
    s = stages[3]
    assert_all_passed(s)
    assert s["symplectic-nu0.99-survives"].measured == 10000
    assert s["symplectic-nu1.01-blows-up"].measured < 10000
    limit = s["stability-limit-bisection"]
    assert abs(limit.measured / limit.theory - 1) < 1e-2
    be = s["backward-euler-mode-decay-nu10"]
    assert abs(be.measured / be.theory - 1) < 1e-6
    for nu in (0.1, 0.5, 1.0):
        fe = s[f"forward-euler-mode-growth-nu{nu}"]
        assert fe.measured > 1 and abs(fe.measured / fe.theory - 1) < 1e-9


def test_stage4_reflection_and_transmission(stages):
    s = stages[4]
    assert_all_passed(s)
    r = s["stiffer-reflected"]
    assert r.theory == pytest.approx(-1 / 3) and abs(r.measured / r.theory - 1) < 2e-2
    t = s["softer-transmitted"]
    assert t.theory == pytest.approx(4 / 3) and abs(t.measured / t.theory - 1) < 2e-2


def test_a_too_narrow_pulse_fails_honestly():
    """A too-narrow pulse (2 node spacings) is dispersive: the speed claim must then fail, not be
    hidden, and say why."""
    s = run_stage(LESSON, 2, width=2.0)
    assert not s["pulse-speed-nu0.25"].passed
    assert not math.isnan(s["pulse-speed-nu0.25"].measured)
    assert "grid dispersion" in s["pulse-speed-nu0.25"].reason


# ------------------------------------------------------------------------------------------
# --integrator: scene runs (stages 2 and 4) follow it, stage 3's runs are fixed
# ------------------------------------------------------------------------------------------

BE_LABEL = "backward-euler (tridiagonal, exact)"


@pytest.fixture(scope="module")
def backward():
    """Every stage under --integrator backward-euler: (experiments, integrator notes) per stage."""
    out = {}
    for i in range(1, len(LESSON.stages) + 1):
        used = []
        out[i] = (run_stage(LESSON, i, stepping=dict(integrator="backward-euler"), used=used), used)
    return out


@pytest.mark.parametrize("stage", [1, 2, 3, 4])
def test_backward_euler_every_stage_passes(backward, stage):
    assert_all_passed(backward[stage][0])


def test_backward_euler_scene_runs_use_it_and_fixed_runs_keep_theirs(backward):
    assert backward[1][1] == []  # no time stepping in stage 1
    for stage, runs in ((2, {"right_nu0.25", "right_nu0.5", "right_nu1.0", "left", "dalembert"}),
                        (4, {"stiffer", "softer", "denser", "smooth"})):
        used = backward[stage][1]
        assert {u.split(": ")[0] for u in used} == runs
        assert all(u.endswith(f": {BE_LABEL}") for u in used), used
    fixed = backward[3][1]
    assert fixed and all(u.endswith("[fixed]") for u in fixed), fixed
    assert "symplectic_nu0.99: symplectic-euler [fixed]" in fixed
    assert f"backward_nu10: {BE_LABEL} [fixed]" in fixed
    # the fixed stage measures the same numbers as under the default integrator
    default = run_stage(LESSON, 3)
    assert {k: e.measured for k, e in default.items()} == {k: e.measured for k, e in backward[3][0].items()}
    assert {k: e.claim for k, e in default.items()} == {k: e.claim for k, e in backward[3][0].items()}


def test_backward_euler_compares_with_its_own_prediction_not_the_undamped_values(backward):
    s = backward[2][0]
    amp = s["dalembert-half-amplitude"]
    assert amp.claim.startswith("d'Alembert: each half has amplitude A/2: backward-euler's modal prediction")
    # the damped halves are far below A/2 = 0.5e-3: about A/2 / sqrt(3) at nu = 0.5, t = 0.4 s
    assert amp.theory == pytest.approx(0.5e-3 / math.sqrt(3), rel=2e-3)
    assert abs(amp.measured / amp.theory - 1) < 1e-6  # the engine is the scheme, to round-off
    diffusion = s["backward-euler-diffusion-height"]
    assert diffusion.theory == pytest.approx(0.5e-3 / math.sqrt(3)) and diffusion.passed
    for nu in (0.25, 0.5, 1.0):  # the pulse is slowed by less than 0.2%
        e = s[f"pulse-speed-nu{nu}"]
        assert e.claim.startswith(f"right-moving pulse speed at nu = {nu}: backward-euler's modal prediction")
        assert 0.998 < e.theory < 1.0 and abs(e.measured / e.theory - 1) < 1e-6
    s4 = backward[4][0]
    for name, R, ratio in (("stiffer", -1 / 3, -0.5), ("softer", 1 / 3, 0.25), ("denser", -1 / 3, -0.5)):
        r = s4[f"{name}-reflected-over-transmitted"]
        assert r.theory == pytest.approx(ratio) and abs(r.measured / ratio - 1) < 5e-3
        refl = s4[f"{name}-reflected"]
        assert refl.claim.startswith(f"{name}: reflected amplitude") and "backward" in refl.claim
        assert 0 < refl.theory / R < 0.9  # damped on the way: not R
        assert abs(refl.measured / refl.theory - 1) < 1e-6


@pytest.mark.parametrize("stage", [2, 4])
def test_velocity_verlet_scene_runs_meet_the_undamped_theory(stage):
    used = []
    s = run_stage(LESSON, stage, stepping=dict(integrator="velocity-verlet"), used=used)
    assert_all_passed(s)
    assert used and all(u.endswith(": velocity-verlet") for u in used), used
    default = run_stage(LESSON, stage)
    assert set(s) == set(default)  # the same experiments, with the same claims, against the same (undamped) theory
    assert all(s[k].claim == default[k].claim for k in s)
    for k in s:  # (the smooth rod's local speed is taken where the measured pulse is)
        assert s[k].theory == (pytest.approx(default[k].theory, rel=1e-3) if k.startswith("smooth") else default[k].theory)


def test_forward_euler_scene_run_is_stopped_at_the_step():
    from engine.errors import BlowUpError
    used = []
    with pytest.raises(BlowUpError, match="forward Euler adds energy to every undamped oscillation at any dt") as info:
        run_stage(LESSON, 2, stepping=dict(integrator="forward-euler"), used=used)
    assert 0 < info.value.step < 2000
