"""Lesson membranes: every claim passes at the defaults, and the measured moduli follow the
parameters (any Poisson's ratio in [0, 0.45] on both meshes; springs keep theirs).

Engine-level checks of the membrane energies are in tests/engine/test_membrane.py."""
import io

import pytest

from engine.errors import ParameterError
from lessons._framework import run_lesson, validate_config
from lessons.app.recorder_null import NullRecorder
from lessons.membranes import LESSON, MembranesConfig


def run(cfg, stages=None):
    rows = []
    passed = run_lesson(LESSON, cfg, NullRecorder(), stages, out=io.StringIO(), err=io.StringIO(), quiet=True,
                        results=rows)
    return passed, {r["id"]: r for r in rows}


def test_every_claim_holds_at_the_defaults(default_runs):
    stages = default_runs(LESSON.id).stages   # every stage at the defaults (shared); all passed, or it fails
    rows = {k: dict(measured=e.measured, theory=e.theory) for s in stages.values() for k, e in s.items()}
    assert len(rows) >= 40
    for kind in ("equilateral", "alternating"):
        for nu in (0.0, 0.3, 0.45):
            assert abs(rows[f"stvk-poisson-{kind}-nu{nu:g}"]["measured"] - nu) < 2e-3
        assert rows[f"bw-poisson-{kind}"]["measured"] == pytest.approx(0.0, abs=1e-9)
        # the claims resolve the finite-strain response: its small-strain limit would fail them
        young = stages[2][f"stvk-young-{kind}-nu0.3"]
        assert abs(young.measured - 1.0) > 3 * young.tolerance            # Y (1 + eps)(1 + eps/2), not Y
        finite = stages[2][f"stvk-finite-poisson-{kind}"]
        assert finite.theory == pytest.approx(0.4849, abs=1e-4)
        assert abs(finite.measured - 0.45) > 10 * finite.tolerance        # 0.485, not 0.45
        finite_young = stages[2][f"stvk-finite-young-{kind}"]
        assert abs(finite_young.measured - 1.0) > 100 * finite_young.tolerance
    assert rows["springs-poisson-equilateral"]["measured"] == pytest.approx(1 / 3, rel=2e-2)
    assert rows["springs-anisotropic"]["measured"] > 1.5      # springs: 73% faster along one diagonal
    # the continuum triangle on the grid: each speed is the grid's own wave, which is not isotropic at 32 spacings
    # (S along x 0.52% slower than along the diagonal) and becomes so as h -> 0 (order 2)
    assert rows["stvk-lattice-speeds"]["measured"] < 2e-6
    s_gap = stages[3]["stvk-s-anisotropy"]
    assert s_gap.theory == pytest.approx(-0.00524, abs=1e-5) and abs(s_gap.measured) > 100 * s_gap.tolerance
    assert stages[3]["stvk-p-spread"].theory == pytest.approx(0.00157, abs=1e-5)
    assert rows["stvk-isotropy-order"]["measured"] == pytest.approx(2.0, abs=5e-3)
    # the lattice's rate under velocity Verlet is 2.3e-3 below the continuum's (stage 5's narrative)
    assert rows["damping-decay-rate"]["measured"] == pytest.approx(0.05 * 2 * 3.14159265 / 32, rel=3e-3)


def test_a_stronger_damping_decays_faster_as_predicted():
    passed, rows = run(MembranesConfig(damping_ratio=0.2), [5])
    assert passed, [(k, r["measured"], r["theory"]) for k, r in rows.items() if not r["passed"]]
    assert rows["damping-decay-rate"]["measured"] == pytest.approx(0.2 * 2 * 3.14159265 / 32, rel=1e-2)


def test_the_unit_mass_prediction_would_not_pass(monkeypatch):
    """Stage 5 predicts with the alternating grid's own mode (lumped masses 4/3 and 2/3 of rho h^2, the
    wave started in that mode's shape). The prediction it replaced, every vertex of mass rho h^2 and
    moving alike, misses the measured decay and frequency by far more than the tolerances."""
    import math

    from lessons.membranes import stages

    def unit_mass(pattern, k_vec, polarization, build):
        k = k_vec[0]
        ks, kd = 1.0, 2 * 0.05 / k                      # the defaults: Y = rho = 1, damping ratio 0.05
        k2h = (2 * math.sin(k / 2)) ** 2
        return ks * k2h, kd * k2h, lambda X: None
    monkeypatch.setattr(stages, "lattice_wave", unit_mass)
    passed, rows = run(MembranesConfig(), [5])
    assert not passed
    for claim in ("damping-decay-rate", "damped-frequency", "damping-backward-euler"):
        row = rows[claim]
        assert not row["passed"], claim
        miss = abs(row["measured"] - row["theory"]) / (abs(row["theory"]) if row["comparison"] == "rel" else 1)
        assert miss > 100 * row["tolerance"], (claim, miss)


def test_the_grids_own_waves_are_resolved_under_backward_euler_too():
    """Backward Euler's step couples the whole sheet: its free edges disturbed the disc by 1.2e-4 until
    the sheet was made twice as large under it (now 5e-6)."""
    from lessons._framework import Stepping

    rows = []
    passed = run_lesson(LESSON, MembranesConfig(), NullRecorder(), [3], out=io.StringIO(), err=io.StringIO(),
                        quiet=True, results=rows, stepping=Stepping(integrator="backward-euler"))
    rows = {r["id"]: r for r in rows}
    assert passed, [(k, r["measured"], r["theory"]) for k, r in rows.items() if not r["passed"]]
    assert rows["stvk-lattice-speeds"]["measured"] < 1e-5


@pytest.mark.parametrize("nu", [0.1, 0.42])
def test_the_poisson_ratio_measured_is_the_one_set(nu):
    passed, rows = run(MembranesConfig(nu=nu), [2])
    assert passed
    for kind in ("equilateral", "alternating"):
        assert rows[f"stvk-poisson-{kind}-nu{nu:g}"]["measured"] == pytest.approx(nu, abs=2e-3)


def test_the_wave_speeds_follow_nu():
    passed, rows = run(MembranesConfig(nu=0.1), [3])
    assert passed
    assert rows["stvk-p-wave-x"]["theory"] == pytest.approx((1 / (1 - 0.01)) ** 0.5)


@pytest.mark.parametrize("field,value,needle", [
    ("nu", 0.46, "--nu must be"),
    ("large_step", 61, "--large-step must be"),
])
def test_out_of_range_is_refused(field, value, needle):
    with pytest.raises(ParameterError, match=needle):
        validate_config(MembranesConfig(**{field: value}))


def test_a_large_step_longer_than_the_settling_time_is_refused():
    with pytest.raises(ParameterError, match="--large-step 60 .* is longer than --settle-time 0.5 s"):
        LESSON.validate(MembranesConfig(large_step=60, settle_time=0.5))
