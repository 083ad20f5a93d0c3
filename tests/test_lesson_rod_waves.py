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
