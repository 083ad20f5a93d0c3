"""Lesson rod-waves: every experiment, with its key figures asserted explicitly."""
import math

import pytest

from lessons.rod_waves import LESSON
from tests.helpers import assert_all_passed, run_stage


@pytest.fixture(scope="module")
def stages():
    return {i: run_stage(LESSON, i) for i in range(1, len(LESSON.stages) + 1)}


def test_stage1_force_is_the_pde_stencil_and_the_energy_gradient(stages):
    s = stages[1]
    assert_all_passed(s)
    assert s["force/mass equals the PDE's finite-difference stencil (max rel. difference)"].measured < 1e-12
    assert s["force equals -dW/dx by central differences (rel. error)"].measured < 1e-6


@pytest.mark.parametrize("nu", [0.25, 0.5, 1.0])
def test_stage2_pulse_speed_is_sqrt_E_over_rho(stages, nu):
    e = stages[2][f"right-moving pulse speed at nu = {nu}"]
    assert e.theory == 1.0  # sqrt(E/rho) with the defaults E = rho = 1
    assert abs(e.measured - 1.0) < 5e-3


def test_stage2_left_pulse_and_dalembert_split(stages):
    assert_all_passed(stages[2])
    amp = stages[2]["d'Alembert: each half has amplitude A/2"]
    assert amp.measured == pytest.approx(0.5e-3, rel=1e-2)


def test_stage3_cfl(stages):
    s = stages[3]
    assert_all_passed(s)
    assert s["symplectic Euler at nu = 0.99 survives 10000 steps"].measured == 10000
    assert s["symplectic Euler at nu = 1.01 blows up within 10000 steps (step detected)"].measured < 10000
    limit = s["stability limit found by bisection equals h/c"]
    assert abs(limit.measured / limit.theory - 1) < 1e-2
    be = s["backward Euler, nu = 10: mode energy factor per step = 1/(1 + (w dt)^2)"]
    assert abs(be.measured / be.theory - 1) < 1e-6
    for nu in (0.1, 0.5, 1.0):
        fe = s[f"forward Euler, nu = {nu}: mode energy factor per step = 1 + (w dt)^2"]
        assert fe.measured > 1 and abs(fe.measured / fe.theory - 1) < 1e-9


def test_stage4_reflection_and_transmission(stages):
    s = stages[4]
    assert_all_passed(s)
    r = s["stiffer: reflected amplitude / incident = (Z1-Z2)/(Z1+Z2), Z2/Z1 = 2"]
    assert r.theory == pytest.approx(-1 / 3) and abs(r.measured / r.theory - 1) < 2e-2
    t = s["softer: transmitted amplitude / incident = 2 Z1/(Z1+Z2)"]
    assert t.theory == pytest.approx(4 / 3) and abs(t.measured / t.theory - 1) < 2e-2


def test_a_too_narrow_pulse_fails_honestly():
    """A too-narrow pulse is dispersive: the speed claim must then fail, not be hidden."""
    s = run_stage(LESSON, 2, width=2.0)
    assert not s["right-moving pulse speed at nu = 0.25"].passed
    assert not math.isnan(s["right-moving pulse speed at nu = 0.25"].measured)


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


def test_backward_euler_compares_with_its_own_prediction_not_the_undamped_values(backward):
    s = backward[2][0]
    amp = next(e for k, e in s.items() if k.startswith("d'Alembert: each half has amplitude A/2: backward-euler"))
    # the damped halves are far below A/2 = 0.5e-3: about A/2 / sqrt(3) at nu = 0.5, t = 0.4 s
    assert amp.theory == pytest.approx(0.5e-3 / math.sqrt(3), rel=2e-3)
    assert abs(amp.measured / amp.theory - 1) < 1e-6  # the engine is the scheme, to round-off
    diffusion = next(e for k, e in s.items() if k.startswith("backward Euler: each half flattens like diffusion"))
    assert diffusion.theory == pytest.approx(0.5e-3 / math.sqrt(3)) and diffusion.passed
    for nu in (0.25, 0.5, 1.0):  # the pulse is slowed by less than 0.2%
        e = next(e for k, e in s.items() if k.startswith(f"right-moving pulse speed at nu = {nu}: backward-euler"))
        assert 0.998 < e.theory < 1.0 and abs(e.measured / e.theory - 1) < 1e-6
    s4 = backward[4][0]
    for name, R, ratio in (("stiffer", -1 / 3, -0.5), ("softer", 1 / 3, 0.25), ("denser", -1 / 3, -0.5)):
        r = s4[f"{name}, backward Euler: reflected / transmitted amplitude = R/T = (Z1-Z2)/(2 Z1)"]
        assert r.theory == pytest.approx(ratio) and abs(r.measured / ratio - 1) < 5e-3
        refl = next(e for k, e in s4.items() if k.startswith(f"{name}: reflected amplitude") and "backward" in k)
        assert 0 < refl.theory / R < 0.9  # damped on the way: not R
        assert abs(refl.measured / refl.theory - 1) < 1e-6


@pytest.mark.parametrize("stage", [2, 4])
def test_velocity_verlet_scene_runs_meet_the_undamped_theory(stage):
    used = []
    s = run_stage(LESSON, stage, stepping=dict(integrator="velocity-verlet"), used=used)
    assert_all_passed(s)
    assert used and all(u.endswith(": velocity-verlet") for u in used), used
    default = run_stage(LESSON, stage)
    assert set(s) == set(default)  # the same claims, against the same (undamped) theory
    for k in s:  # (the smooth rod's local speed is taken where the measured pulse is)
        assert s[k].theory == (pytest.approx(default[k].theory, rel=1e-3) if k.startswith("smooth") else default[k].theory)


def test_forward_euler_scene_run_is_stopped_at_the_step():
    from engine.errors import BlowUpError
    used = []
    with pytest.raises(BlowUpError, match="forward Euler adds energy to every undamped oscillation at any dt") as info:
        run_stage(LESSON, 2, stepping=dict(integrator="forward-euler"), used=used)
    assert 0 < info.value.step < 2000
