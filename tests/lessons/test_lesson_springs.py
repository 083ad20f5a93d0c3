"""Lesson springs (every experiment, key figures asserted) and the fused spring kernel
(the Stepper's many-steps path, Stepper.energies) against the step-by-step explicit integrators.

The bad-input cases of the issue (zero/negative rest length, coincident endpoints, k <= 0,
edge or pin index out of range) are covered by tests/engine/test_springs_energy.py.
"""
import math

import numpy as np
import pytest

from engine import diagnostics, errors, integrators
from engine.energies.bending import BendingEnergy
from engine.errors import BlowUpError
from engine.integrators import Stepper
from engine.stability import stable_dt_estimate
from engine.model import Model
from lessons._framework import validate_config
from lessons.springs import LESSON, SpringsConfig
from tests.helpers import assert_all_passed, assert_unique_ids, run_stage

METHODS = ["forward-euler", "symplectic-euler", "velocity-verlet"]


# ------------------------------------------------------------------------------------------
# the fused kernel
# ------------------------------------------------------------------------------------------

def _network(gravity=None, pinned=None, seed=0):
    """A small 3D network (two tets sharing a face) displaced and moving."""
    X = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]]) * 0.2
    E = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3], [4, 1], [4, 2], [4, 3]])
    rng = np.random.default_rng(seed)
    model = Model.from_springs(X, E, k=rng.uniform(50, 150, len(E)), mass=rng.uniform(0.05, 0.15, len(X)),
                               pinned=pinned, gravity=gravity)
    x0 = X + 0.02 * rng.standard_normal(X.shape)
    v0 = 0.5 * rng.standard_normal(X.shape)
    return model, x0, v0


def run_fused(model, state, dt, n_steps, method="symplectic-euler", energy_bound=None, step_offset=0):
    """n_steps of ``method`` in one launch of the many-steps kernel, through the Stepper (its energies)."""
    from engine.integrators.stepper import Stepper
    return Stepper(model, method, many_steps=True).energies(state, dt, n_steps, energy_bound, step_offset)


CASES = {"free": dict(), "gravity_and_pins": dict(gravity=(0.0, -9.81, 0.0), pinned=[0, 3])}


@pytest.mark.parametrize("case", list(CASES))
@pytest.mark.parametrize("method", METHODS)
def test_one_fused_step_equals_one_explicit_step(method, case):
    model, x0, v0 = _network(**CASES[case])
    dt = 0.2 * stable_dt_estimate(model)
    a, b = model.make_state(x0, v0), model.make_state(x0, v0)
    K, W = run_fused(model, a, dt, 1, method)
    Stepper(model, integrators.get(method)).step(b, dt, 1)
    xa, va, ta = a.numpy()
    xb, vb, tb = b.numpy()
    np.testing.assert_allclose(xa, xb, rtol=0, atol=1e-15)
    np.testing.assert_allclose(va, vb, rtol=0, atol=1e-14)
    assert ta == tb == pytest.approx(dt)
    assert K.shape == W.shape == (1,)
    assert K[0] == pytest.approx(diagnostics.kinetic_energy(model, b), rel=1e-13)
    assert W[0] == pytest.approx(model.potential_energy(b.x), rel=1e-13, abs=1e-15)
    assert np.all(xa[model.pinned] == x0[model.pinned]) and np.all(va[model.pinned] == 0)


@pytest.mark.parametrize("case", list(CASES))
@pytest.mark.parametrize("method", METHODS)
def test_fused_energies_of_every_step_match_the_engine(method, case):
    model, x0, v0 = _network(**CASES[case], seed=1)
    dt = 0.2 * stable_dt_estimate(model)
    a, b = model.make_state(x0, v0), model.make_state(x0, v0)
    K, W = run_fused(model, a, dt, 50, method)
    stepper = integrators.Stepper(model, method)
    stepper.begin(b)
    for s in range(50):
        stepper.advance(b, dt)
        assert K[s] == pytest.approx(diagnostics.kinetic_energy(model, b), rel=1e-12)
        assert W[s] == pytest.approx(model.potential_energy(b.x), rel=1e-12, abs=1e-14)
    np.testing.assert_allclose(a.numpy().x, b.numpy().x, rtol=0, atol=1e-13)
    assert a.t == pytest.approx(b.t, rel=1e-14)


@pytest.mark.parametrize("method", METHODS)
def test_chunked_fused_runs_equal_one_long_run(method):
    model, x0, v0 = _network(**CASES["gravity_and_pins"])
    dt = 0.2 * stable_dt_estimate(model)
    a, b = model.make_state(x0, v0), model.make_state(x0, v0)
    K1, W1 = run_fused(model, a, dt, 300, method)
    parts = [run_fused(model, b, dt, 100, method) for _ in range(3)]
    np.testing.assert_array_equal(a.numpy().x, b.numpy().x)
    np.testing.assert_array_equal(K1, np.concatenate([p[0] for p in parts]))
    np.testing.assert_array_equal(W1, np.concatenate([p[1] for p in parts]))


def test_fused_blow_up_is_detected_at_the_same_step_as_the_explicit_runner():
    model, x0, v0 = _network()
    dt = 1.5 * stable_dt_estimate(model, method="power")  # above the CFL limit
    a, b = model.make_state(x0, v0), model.make_state(x0, v0)
    E0 = diagnostics.total_energy(model, a)
    with pytest.raises(BlowUpError) as fused_info:
        run_fused(model, a, dt, 10_000, "symplectic-euler", energy_bound=100 * E0, step_offset=7)
    with pytest.raises(BlowUpError) as ref_info:
        integrators.run(model, b, dt, 10_000, "symplectic-euler", energy_bound=100 * E0)
    exc = fused_info.value
    assert isinstance(exc, errors.BlowUpError)
    assert exc.step == ref_info.value.step + 7
    assert 0 < ref_info.value.step < 10_000
    assert exc.energy > 100 * E0 and exc.energy == pytest.approx(ref_info.value.energy, rel=1e-9)
    assert exc.kinetic.size == exc.potential.size == ref_info.value.step + 1
    assert exc.kinetic[-1] + exc.potential[-1] > 100 * E0 >= np.max((exc.kinetic + exc.potential)[:-1])
    assert "symplectic-euler blew up at step" in str(exc) and "CFL" in str(exc) and "\n" not in str(exc)
    assert a.t == pytest.approx(b.t)


def test_fused_forward_euler_grows_and_non_finite_energy_is_caught_without_a_bound():
    model, x0, v0 = _network()
    st = model.make_state(x0, v0)
    E0 = diagnostics.total_energy(model, st)
    K, W = run_fused(model, st, 0.3 * stable_dt_estimate(model), 500, "forward-euler")
    assert (K + W)[-1] > 10 * E0
    st = model.make_state(x0, v0)
    with pytest.raises(errors.BlowUpError) as info:
        run_fused(model, st, 100 * stable_dt_estimate(model), 10_000, "symplectic-euler")
    assert not math.isfinite(info.value.energy) and info.value.step < 10_000


def test_fused_bad_input():
    model, x0, v0 = _network()
    st = model.make_state(x0, v0)
    with pytest.raises(ValueError, match="unknown integrator 'leapfrog'"):
        run_fused(model, st, 1e-3, 10, "leapfrog")
    for dt in (0.0, -1e-3, math.nan, math.inf):
        with pytest.raises(ValueError, match="dt must be > 0"):
            run_fused(model, st, dt, 10, "symplectic-euler")
    with pytest.raises(ValueError, match="n_steps"):
        run_fused(model, st, 1e-3, -1, "symplectic-euler")
    with pytest.raises(ValueError, match="energy_bound"):
        run_fused(model, st, 1e-3, 10, "symplectic-euler", energy_bound=math.nan)
    assert run_fused(model, st, 1e-3, 0, "symplectic-euler")[0].size == 0
    # not a spring-only model
    X = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.1]])
    cloth = Model.from_springs(X, np.array([[0, 1], [1, 2], [2, 0], [1, 3], [3, 2]]), k=1.0)
    cloth.add_energy(BendingEnergy(X, np.array([[1, 2, 0, 3]]), 1e-3))
    with pytest.raises(ValueError, match="spring-only model"):
        run_fused(cloth, cloth.make_state(), 1e-3, 10)
    with pytest.raises(ValueError, match="spring-only model"):
        run_fused(Model(X), Model(X).make_state(), 1e-3, 10)


# ------------------------------------------------------------------------------------------
# the lesson
# ------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def stages(default_runs):
    return default_runs(LESSON.id).stages   # every stage at the defaults, shared with the recording tests


def test_lesson_is_registered():
    from lessons.app import registry
    assert registry.get("springs") is LESSON and LESSON.order == 2


def test_experiment_ids_are_unique_in_the_lesson(stages, backward):
    assert_unique_ids({i: stages[i] for i in range(1, len(LESSON.stages) + 1)})
    assert_unique_ids({i: s for i, (s, _) in backward.items()})


def test_config_ranges_are_checked():
    from engine.errors import ParameterError
    validate_config(SpringsConfig())
    for bad in (dict(dt_fraction=0.0), dict(steps=10), dict(chain_nodes=2), dict(k=-1.0), dict(E=math.nan)):
        with pytest.raises(ParameterError):
            validate_config(SpringsConfig(**bad))


def test_stage1_one_spring(stages):
    s = stages[1]
    assert_all_passed(s)
    assert s["force-is-energy-gradient"].measured < 1e-7
    assert s["directional-derivative"].measured < 1e-7
    assert s["no-force-at-rest"].measured < 1e-14
    assert s["force-along-spring"].measured < 1e-14
    assert s["rigid-motion-energy"].measured < 1e-12
    assert s["closed-form-force"].measured < 1e-13


def test_stage2_conservation(stages):
    s = stages[2]
    assert_all_passed(s)
    for method in METHODS:
        assert s[f"fused-equals-stepwise-{method}"].measured < 1e-12
    for net, what in (("chain", "peak kinetic energy"), ("frame", "initial energy")):
        for method, ratio in (("symplectic-euler", 2.0), ("velocity-verlet", 4.0)):
            drift = s[f"{net}-{method}-no-drift"]
            assert drift.claim.endswith(f"over 100000 steps (|mean E last tenth - first tenth| / {what})")
            assert drift.measured < 0.01
            r = s[f"{net}-{method}-wobble-order"]
            assert r.theory == ratio and abs(r.measured / ratio - 1) < 0.05
    for method in ("symplectic-euler", "velocity-verlet"):
        assert s[f"frame-{method}-linear-momentum"].measured < 1e-12
        assert s[f"frame-{method}-angular-momentum"].measured < 1e-12
    fe = s["chain-forward-euler-blows-up"]
    assert "within 100000 steps" in fe.claim
    assert fe.measured < 100000
    growth = s["frame-forward-euler-growth"]
    assert growth.measured > 10 and abs(growth.measured / growth.theory - 1) < 1e-3
    step = s["frame-forward-euler-detected-step"]
    assert "blow-up (E > 10 E0)" in step.claim
    assert abs(step.measured - step.theory) <= 1


def test_stage3_variational_derivative(stages):
    s = stages[3]
    assert_all_passed(s)
    for kind in ("graded", "random"):
        e = s[f"{kind}-gradient-is-stencil"]
        assert e.measured < 1e-13
    for kind in ("uniform", "graded"):
        o = s[f"{kind}-force-density-order"]
        assert 1.9 <= o.measured <= 2.1
    assert 1.9 <= s["graded-force-density-max-order"].measured <= 2.1
    o = s["random-force-density-order"]
    assert o.theory == 1.0 and 0.85 <= o.measured <= 1.15


def test_stage4_stiffness_from_the_speed_of_sound(stages):
    s = stages[4]
    assert_all_passed(s)
    c = math.sqrt(100.0 / 1.0)
    for kind in ("uniform", "alternating", "graded"):
        e = s[f"matched-{kind}-speed"]
        assert e.theory == pytest.approx(c) and abs(e.measured / c - 1) < 0.01
    assert s["matched-speed-spread"].measured < 0.01
    alt = s["constant-kappa-alternating-speed"]
    assert alt.theory == pytest.approx(c * math.sqrt(1.5), rel=1e-3)  # L_mean = 1.5 h
    assert abs(alt.measured / alt.theory - 1) < 0.01
    assert s["constant-kappa-patterns-differ"].measured > 0.01


def test_stage5_hanging_rod(stages):
    s = stages[5]
    assert_all_passed(s)
    for kind in ("uniform", "graded"):
        assert s[f"hanging-{kind}-converged"].measured <= 1e-10
        assert s[f"hanging-{kind}-displacement"].measured < 1e-9
        r = s[f"hanging-{kind}-pin-reaction"]
        assert r.theory == pytest.approx(9.81) and r.measured == pytest.approx(9.81, rel=1e-8)


# ------------------------------------------------------------------------------------------
# --integrator: stage 4's pulses are scene runs, stage 2's runs are fixed, 1, 3, 5 do not step
# ------------------------------------------------------------------------------------------

SMALL = dict(wave_segments=1000)  # the smallest chains stage 4 allows: keeps backward Euler's runs short


@pytest.fixture(scope="module")
def backward():
    """Every stage under --integrator backward-euler: (experiments, integrator notes) per stage."""
    out = {}
    for i in range(1, len(LESSON.stages) + 1):
        used = []
        out[i] = (run_stage(LESSON, i, stepping=dict(integrator="backward-euler"), used=used, **SMALL), used)
    return out


@pytest.mark.parametrize("stage", [1, 2, 3, 4, 5])
def test_backward_euler_every_stage_passes(backward, stage):
    assert_all_passed(backward[stage][0])


def test_backward_euler_scene_runs_use_it_and_fixed_runs_keep_theirs(backward, stages):
    for i in (1, 3, 5):
        assert backward[i][1] == []  # no time stepping
    fixed = backward[2][1]
    assert len(fixed) == 18 and all(u.endswith("[fixed]") for u in fixed), fixed
    assert "chain_velocity-verlet: velocity-verlet [fixed]" in fixed
    assert not any("backward" in u for u in fixed)
    assert {k: e.measured for k, e in stages[2].items()} == {k: e.measured for k, e in backward[2][0].items()}
    assert {k: e.claim for k, e in stages[2].items()} == {k: e.claim for k, e in backward[2][0].items()}
    scene = backward[4][1]
    assert {u.split(": ")[0] for u in scene} == {"matched_uniform", "matched_alternating", "matched_graded",
                                                 "constant_kappa_uniform", "constant_kappa_alternating"}
    assert all(u.endswith(": backward-euler (pcg, tol 1e-08)") for u in scene), scene


def test_backward_euler_speeds_are_its_modal_prediction(backward):
    s = backward[4][0]
    c = 10.0
    for kind in ("uniform", "alternating", "graded"):
        e = s[f"matched-{kind}-speed"]
        assert e.claim.startswith(f"k_j = rho c^2 ({kind} lengths") and "backward-euler's modal prediction" in e.claim
        # slowed a little (phase atan(w dt) < w dt), much less than the 1% tolerance
        assert 0.998 * c < e.theory < c and abs(e.measured / e.theory - 1) < 1e-5
    alt = s["constant-kappa-alternating-speed"]
    assert alt.theory == pytest.approx(c * math.sqrt(1.5), rel=2e-3) and alt.theory < c * math.sqrt(1.5)


def test_velocity_verlet_pulses_meet_the_undamped_theory():
    used = []
    s = run_stage(LESSON, 4, stepping=dict(integrator="velocity-verlet"), used=used, **SMALL)
    assert_all_passed(s)
    assert len(used) == 5 and all(u.endswith(": velocity-verlet") for u in used), used
    default = run_stage(LESSON, 4, **SMALL)
    assert set(s) == set(default) and all(s[k].theory == default[k].theory for k in s)
    assert all(s[k].claim == default[k].claim for k in s)


def test_backward_euler_with_cholesky_on_one_chain():
    """--solver cholesky reaches the scheme's prediction too (one chain: the cost is in the factorisations)."""
    from lessons._framework import StageContext, Stepping
    from lessons.app.recorder_null import NullRecorder
    from lessons.springs import scene, stages_dynamics as springs
    cfg = SpringsConfig(**SMALL)
    ctx = StageContext(LESSON, cfg, NullRecorder(), 4, quiet=True,
                       stepping=Stepping(integrator="backward-euler", solver="cholesky"))
    h = 1.0 / cfg.wave_segments
    Ls = scene.chain_lengths("graded", h)
    k = np.full(Ls.size, 100.0)
    model, p = scene.chain_model(Ls, k, 1.0)
    v, v_pred = springs._pulse_speed(ctx, "graded", model, p, 10.0, 30 * h, k, 1.0)
    assert ctx.integrators_used == ["graded: backward-euler (cholesky, tol 1e-08)"]
    assert abs(v / v_pred - 1) < 1e-5 and 9.98 < v_pred < 10.0


def test_forward_euler_pulse_is_stopped_at_the_step():
    with pytest.raises(errors.BlowUpError, match="forward Euler adds energy") as info:
        run_stage(LESSON, 4, stepping=dict(integrator="forward-euler"), **SMALL)
    assert 0 < info.value.step < 1000


def test_stage2_views_frame_each_run(tmp_path):
    """The chains are seen from the front, the drifting frame about its centre of mass (its drawn
    box stays about its own size over the run), and forward Euler's view spans its first 1000 steps,
    drawn every few steps up to where it is stopped."""
    from lessons.app.recorder import Recorder
    from lessons.app.recorder_read import summarize
    rec = Recorder(tmp_path / "a.rrd", "test")
    assert_all_passed(run_stage(LESSON, 2, rec=rec, steps=20_000))
    rec.close()
    runs = {r.name: r for r in rec.stages[-1].runs if r.has_geometry}
    assert set(runs) == {f"{net}_{m}" for net in ("chain", "frame") for m in ("symplectic-euler", "velocity-verlet")
                         } | {"chain_forward-euler"}
    for name, run in runs.items():
        assert run.camera == ("front" if name.startswith("chain") else "outside")
        assert run.energy == ("drift" if name.startswith("frame") else "split")
        assert list(run.scales) == ["strain"] and run.frames >= 100
        if name.startswith("frame"):
            assert np.max(run.hi - run.lo) < 0.5  # the frame is 0.2 m; it drifts 1 m over these steps
    fe = runs["chain_forward-euler"]
    info = summarize(tmp_path / "a.rrd")
    ticks = info["/stage2/chain_forward-euler/springs"]["frames"]
    assert 100 < max(ticks) < 1000 and len(ticks) > 100  # one tick per step: stopped after a few hundred
    assert fe.span == pytest.approx(runs["chain_symplectic-euler"].span / 20)


def test_stage5_draws_the_rod_unloaded_and_hanging_side_by_side(tmp_path):
    from lessons.app.recorder import Recorder
    from lessons.app.recorder_read import summarize
    rec = Recorder(tmp_path / "a.rrd", "test")
    assert_all_passed(run_stage(LESSON, 5, rec=rec))
    rec.close()
    info = summarize(tmp_path / "a.rrd")
    for kind in ("uniform", "graded"):
        for body in ("unloaded", "hanging"):
            assert f"/stage5/hanging_{kind}/{body}/springs" in info
        assert info[f"/stage5/hanging_{kind}/labels"]["static_chunks"] == 1
    run = rec.stages[-1].runs[0]
    assert run.camera == "front" and run.scales["strain"] == pytest.approx(9.81 * 1.0 / 100.0, rel=1e-3)
