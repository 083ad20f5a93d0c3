"""Lesson explicit-vs-implicit: every experiment, with its key figures asserted explicitly, the
recording, and that every run is fixed (about one integrator) whatever --integrator says.

Engine-level checks of backward Euler and its linear solvers are in tests/engine/test_implicit.py,
tests/engine/test_solvers.py and tests/engine/test_implicit_more.py; they are not repeated here.
"""
import math

import pytest

from engine.solvers import pardiso_available

from engine.constants import G
from engine.errors import ParameterError
from lessons.app.recorder_read import summarize
from lessons._framework import validate_config
from lessons.explicit_vs_implicit import LESSON, ExplicitImplicitConfig
from engine.theory.schemes import symplectic_euler_growth
from lessons.explicit_vs_implicit.stages_tradeoffs import _crossover
from tests.helpers import assert_all_passed, assert_unique_ids, run_stage


@pytest.fixture(scope="module")
def recording(default_runs):
    run = default_runs(LESSON.id)   # every stage at the defaults, as `run` records it (shared)
    return run.stages, run.used, run.path, run.rec


@pytest.fixture(scope="module")
def stages(recording):
    return recording[0]


def test_experiment_ids_are_unique_in_the_lesson(stages):
    assert_unique_ids(stages)


def test_stage1_cfl_limit_and_blow_up(stages):
    s = stages[1]
    assert_all_passed(s)
    power = s["power-iteration-w-max"]
    assert abs(power.measured / power.theory - 1) < 1e-4
    gersh = s["gershgorin-dt-safe"]
    assert 0.8 < gersh.measured / gersh.theory <= 1.0  # safe, and tight on this grid
    survive = s["symplectic-below-survives"]
    assert survive.claim.startswith("symplectic Euler at 0.9 x the limit survives")
    assert survive.measured == survive.theory > 1000
    blow = s["symplectic-above-blows-up"]
    assert blow.claim.startswith("symplectic Euler at 1.1 x the limit blows up")
    assert 3 <= blow.measured <= 50  # caught within tens of steps of the release
    assert s["blow-up-message-names-cfl"].measured == 1.0
    growth = s["seed-growth-modal"]
    assert growth.theory > 1e3 and abs(growth.measured / growth.theory - 1) < 1e-2


def test_stage1_backward_euler_far_above_the_limit(stages):
    s = stages[1]
    for which, factor in (("big", "10"), ("huge", "100")):
        energy = s[f"backward-euler-{which}-energy-bounded"]
        assert energy.claim.startswith(f"backward Euler at {factor} x the limit: total energy never exceeds the start")
        assert energy.measured < energy.theory
        eq = s[f"backward-euler-{which}-reaches-equilibrium"]
        assert eq.claim.startswith(f"backward Euler at {factor} x: reaches the hanging equilibrium")
        assert eq.measured < 1e-3
    assert s["backward-euler-huge-reaches-equilibrium"].measured < 1e-6  # damped out completely
    assert s["newton-steps-sound"].measured == 0
    assert s["linear-solves-converged"].measured <= 1e-8
    assert s["pins-never-moved"].measured == 0.0


@pytest.mark.parametrize("wdt", [0.1, 1.0, 0.3, 3.0, 30.0])
def test_stage2_damping_factor(stages, wdt):
    e = stages[2][f"damping-wdt{wdt:g}"]
    assert e.theory == pytest.approx(1.0 / (1.0 + wdt * wdt), rel=1e-14)
    assert abs(e.measured / e.theory - 1) < 1e-5


def test_stage2_orders(stages):
    s = stages[2]
    assert_all_passed(s)
    assert abs(s["backward-euler-first-order"].measured - 1) < 0.1
    assert abs(s["symplectic-euler-first-order"].measured - 1) < 0.05
    assert abs(s["velocity-verlet-second-order"].measured - 2) < 0.1
    assert s["half-step-start-is-verlet"].measured < 1e-6
    ref = s["reference-error-one-64th"]
    assert abs(ref.measured * 64 - 1) < 0.05


def test_stage3_counts(stages):
    s = stages[3]
    assert_all_passed(s)
    assert s["timed-runs-bounded"].measured == 0
    assert abs(s["explicit-steps-grow-like-sqrt-e"].measured - 0.5) < 0.01
    assert s["backward-euler-energy-bounded-at-every-e"].measured <= 0.0
    grow = s["pcg-iterations-grow"]
    assert grow.measured > 2.0
    slope = s["pcg-iterations-below-condition-bound"]
    assert 0.0 < slope.measured < slope.theory and slope.theory == pytest.approx(0.5, abs=0.02)


def test_every_run_is_fixed_and_noted(recording):
    _, used, _, _ = recording
    for i, notes in used.items():
        assert notes and all(n.endswith("[fixed]") for n in notes), (i, notes)
    assert any("symplectic-euler" in n for n in used[1]) and any("backward-euler (pcg" in n for n in used[1])
    names = " ".join(used[2])
    assert "velocity-verlet" in names and "symplectic-euler" in names and "backward-euler (cholesky" in names
    direct = "pardiso" if pardiso_available() else "cholesky"   # stage 3 times the fastest direct solver installed
    assert sum(f"backward-euler ({direct}" in n for n in used[3]) == sum("backward-euler (pcg" in n for n in used[3])


def test_stepping_options_do_not_change_fixed_runs():
    """--integrator/--solver/--tol leave this lesson's runs alone (a small stage-3 sweep)."""
    small = dict(speed_n=8, E_values=3, frames=3)
    used = []
    s = run_stage(LESSON, 3, stepping=dict(integrator="velocity-verlet", solver="cholesky", tol=1e-3), used=used,
                  **small)
    assert len(used) == 9 and all(n.endswith("[fixed]") for n in used), used
    assert sum(": symplectic-euler [fixed]" in n for n in used) == 3
    assert sum("backward-euler (pcg, tol 1e-08) [fixed]" in n for n in used) == 3
    default = run_stage(LESSON, 3, **small)
    assert set(s) == set(default) and all(s[k].claim == default[k].claim for k in s)
    # the same runs: the same counts (up to the round-off of two-thread reductions)
    for key in ("explicit-steps-grow-like-sqrt-e", "pcg-iterations-grow"):
        assert s[key].measured == pytest.approx(default[key].measured, rel=1e-6)


def test_recording_has_meshes_energies_blow_up_marks_and_timings(recording):
    _, _, path, _ = recording
    info = summarize(path)
    below = info["/stage1/symplectic_0.9x/mesh"]
    assert below["static_chunks"] >= 1 and len(below["frames"]) >= 100  # the cloth, every 10th step
    assert any("color" in c.lower() for c in below["components"])
    assert len(info["/stage1/symplectic_0.9x/energy/total"]["frames"]) > 1000  # every step
    for run in ("symplectic_1.1x", "symplectic_1.1x_opposite_seed"):
        events = info[f"/stage1/{run}/events"]
        assert events["rows"] == 1  # the blow-up, marked at its step
        assert events["frames"][0] == info[f"/stage1/{run}/mesh"]["frames"][-1]
    for run in ("backward_euler_10x", "backward_euler_100x"):
        assert len(info[f"/stage1/{run}/mesh"]["frames"]) >= 10
        # the blow-up is shown over the steps it took, not at the start of the second it was planned for
        assert 300 < events["frames"][0] <= 1000
    assert "/stage2/mode0_wdt1/mesh" in info
    assert len(info["/stage2/mode0_wdt1/mesh"]["frames"]) == 4  # the mode and its three steps
    assert "/stage3/results" in info and "/stage3/narrative" in info   # the timings table: under the results
    # stage 3's point drawn: the three cost curves against E, a point per timed modulus
    for key in ("explicit", "pcg", "direct"):
        assert f"/stage3/cost/{key}/curve" in info and f"/stage3/cost/{key}/runs" in info
    # measurements only: the convergence runs and the timed runs draw nothing
    drawn = {e.split("/")[2] for e in info if e.startswith(("/stage2/", "/stage3/")) and e.endswith("/mesh")}
    assert drawn == {"mode0_wdt0.1", "mode0_wdt1", "mode47_wdt0.3", "mode47_wdt3", "mode93_wdt30"}
    assert path.stat().st_size < 20e6


def test_recording_views_are_labelled_seen_from_the_front_and_keyed(recording):
    _, _, _, rec = recording
    drawn = [(s.index, r) for s in rec.stages for r in s.runs if r.has_geometry and s.index < 3]
    assert [i for i, _ in drawn] == [1] * 5 + [2] * 5
    chart = [r for s in rec.stages for r in s.runs if r.has_geometry and s.index == 3]   # the cost curves, from above
    assert [r.name for r in chart] == ["cost"] and chart[0].camera == "top" and not chart[0].has_energy
    for i, run in drawn:
        assert run.label and run.label != run.name and run.camera == "front", run.name
        assert list(run.keys) == ["strain"], run.name
    # stage 1 on one physical scale: the strain of the sheet's weight hung from its top edge, rho g L / E
    cfg = LESSON.config()
    scales = {run.scales["strain"] for i, run in drawn if i == 1}
    assert len(scales) == 1 and scales.pop() == pytest.approx(cfg.rho * G / cfg.E, rel=1e-12)
    assert all(run.energy == "drift" for i, run in drawn if i == 1)


def test_symplectic_euler_growth_and_crossover_helpers():
    assert symplectic_euler_growth(4 * 1.21) == pytest.approx(2.428166652890285, rel=1e-12)
    assert symplectic_euler_growth(3.99) == 1.0 and symplectic_euler_growth(0.5) == 1.0
    lam = symplectic_euler_growth(9.0)  # lambda^2 - (2 - z) lambda + 1 = 0 with z = 9: lambda = (-7 - sqrt 45)/2
    assert lam == pytest.approx((7 + math.sqrt(45)) / 2, rel=1e-14)
    assert _crossover([1, 10, 100], [1, 2, 4], [3, 2.5, 2]) == pytest.approx(10 * 10 ** (math.log(2.5 / 2) / (
        math.log(2.5 / 2) + math.log(4 / 2))), rel=1e-12)
    assert _crossover([1, 10], [1, 2], [3, 4]) is None


def test_config_validation():
    with pytest.raises(ParameterError, match="--huge must be larger than --big"):
        validate_config(ExplicitImplicitConfig(big=50.0, huge=20.0))
    with pytest.raises(ParameterError, match="--E-stiff must be larger than --E-soft"):
        validate_config(ExplicitImplicitConfig(E_soft=1e4, E_stiff=1e3))
    with pytest.raises(ParameterError, match="--below"):
        validate_config(ExplicitImplicitConfig(below=1.0))
    validate_config(ExplicitImplicitConfig())
