"""The edges of the documented ranges of rod-waves, springs, area-springs and explicit-vs-implicit.

Every value inside a parameter's documented range (its ``param(...)`` metadata) must either run and
pass, fail with the physical reason the lesson states (``Experiment.reason``), or be refused up
front with one line naming the parameter (a ParameterError, exit code 2) before any kernel runs;
never an internal error. This walks each parameter's ends and a value between (the others at their
defaults): always the up-front checks and the set-up estimates (the stage plans, pulse widths,
tolerances), and the whole stage only where it takes well under a second. Then the cases that were
internal errors, unexplained failures or silent many-minute runs, cheaply.
"""
import dataclasses
import io
import math

import numpy as np
import pytest

from engine.errors import BlowUpError, ParameterError
from lessons.app import registry
from lessons._budget import WORK_BUDGET_S
from lessons._framework import StageContext, field_type, validate_config
from lessons.app.recorder_null import NullRecorder

LESSONS = {l.id: l for l in registry.all_lessons()}
WALKED = ("rod-waves", "springs", "area-springs", "explicit-vs-implicit")


def range_values(meta: dict, kind: type, default):
    """The ends of a documented range and a value between (an open end: just inside it; no end: far out)."""
    lo_in, hi_in = meta.get("ge"), meta.get("le")
    lo = lo_in if lo_in is not None else meta.get("gt")
    hi = hi_in if hi_in is not None else meta.get("lt")
    if kind is int:
        lo = None if lo is None else (lo if lo_in is not None else lo + 1)
        hi = None if hi is None else (hi if hi_in is not None else hi - 1)
        lo = 0 if lo is None else lo
        hi = max(lo, int(default)) * 1000 if hi is None else hi
        return sorted({lo, hi, int(round(math.sqrt(max(lo, 1) * hi)))})
    lo = (lo if lo_in is not None else (lo * (1 + 1e-12) if lo else 1e-300)) if lo is not None else -1e300
    hi = (hi if hi_in is not None else hi * (1 - 1e-12)) if hi is not None else 1e300
    mid = math.sqrt(lo * hi) if lo > 0 and hi > 0 else 0.5 * (lo + hi)
    return [lo, mid, hi]


def cases(lesson_id: str):
    """(field, value) for every numeric field of the lesson's config, at its ends and between."""
    config = LESSONS[lesson_id].config
    out = []
    for f in dataclasses.fields(config):
        meta = f.metadata
        if not meta or meta.get("choices"):
            continue
        kind = field_type(f)
        for v in range_values(meta, kind, getattr(config(), f.name) or 1):
            out.append((f.name, v))
    return out


def up_front(lesson, **overrides):
    """The CLI's checks before any kernel: the config, then the lesson's own; the config or the
    ParameterError (whose one-line message must name a parameter)."""
    cfg = lesson.config(**overrides)
    try:
        validate_config(cfg)
        if lesson.validate is not None:
            lesson.validate(cfg)
    except ParameterError as exc:
        text = str(exc)
        assert "\n" not in text and "--" in text, text
        return exc
    return cfg


def run_whole(lesson, index: int, cfg) -> list:
    """Run a stage in-process; a pass, a failure whose every failed experiment says why, or a
    blow-up (its message is the reason) are outcomes; anything else is an internal error."""
    ctx = StageContext(lesson, cfg, NullRecorder(), index, stream=io.StringIO(), quiet=True)
    try:
        exps = lesson.stages[index - 1].run(ctx)
    except BlowUpError as exc:
        assert "likely cause" in str(exc)
        return []
    unexplained = [f"{e.id}: theory {e.theory!r}, measured {e.measured!r}" for e in exps if not e.passed and not e.reason]
    assert not unexplained, unexplained
    return exps


# ------------------------------------------------------------------------- the walk

def check_plan(lesson_id: str, cfg) -> None:
    """The set-up an accepted configuration gets, computed before any stage runs: finite estimates
    within the budget, and the pieces the stages are sized with."""
    if lesson_id == "rod-waves":
        from lessons.rod_waves import scene as S
        h = 1.0 / (cfg.nodes - 1)
        sigma = S.pulse_width(cfg, h)
        assert 2 * h * (1 - 1e-9) <= sigma <= 0.05
        assert S.fewest_fit_points(cfg) >= S.MIN_FIT_POINTS
        for stage in (2, 3, 4):
            assert 0 <= S.stage_work(cfg, stage) <= S.WORK_BUDGET
    elif lesson_id == "springs":
        from lessons.springs import scene as S
        plan = S.stage2_plan(cfg)
        assert plan["longest"] <= S.MAX_LAUNCH_STEPS and plan["seconds"] <= WORK_BUDGET_S
        assert all(math.isfinite(dt) and dt > 0 for dt in plan["dt"].values())
        assert S.stage4_seconds(cfg) <= WORK_BUDGET_S
    elif lesson_id == "area-springs":
        from lessons.area_springs import scene as S
        assert all(S.stage_seconds(cfg, i) <= WORK_BUDGET_S for i in range(1, 6))
    else:
        from lessons.explicit_vs_implicit import scene as S
        assert math.isfinite(S.limit_estimate(cfg.n, cfg.E, cfg.rho, cfg.B))
        assert all(S.stage_seconds(cfg, i) <= WORK_BUDGET_S for i in (1, 2))


# stages that take well under a second at the defaults, and the parameters whose edges they run at
# (the whole stage is run only there; a value that makes it long is skipped by its own estimate)
QUICK = {
    "rod-waves": {1: {"E", "rho", "nodes"}},
    "springs": {1: {"k"}, 5: {"E", "rho", "hang_nodes"}},
    "area-springs": {5: {"E", "rho", "strain", "strip_cells"}},
    "explicit-vs-implicit": {},
}


@pytest.mark.parametrize("lesson_id", WALKED)
def test_every_documented_value_is_refused_up_front_or_set_up_within_budget(lesson_id):
    lesson = LESSONS[lesson_id]
    outcomes = {"refused": 0, "accepted": 0}
    for name, value in cases(lesson_id):
        got = up_front(lesson, **{name: value})
        if isinstance(got, ParameterError):
            outcomes["refused"] += 1
            continue
        outcomes["accepted"] += 1
        check_plan(lesson_id, got)
    assert outcomes["accepted"] > outcomes["refused"], outcomes  # the ranges are mostly runnable


@pytest.mark.parametrize("lesson_id,stage,names", [(l, s, n) for l, st in QUICK.items() for s, n in st.items()])
def test_quick_stages_pass_or_fail_saying_why_at_every_edge(lesson_id, stage, names):
    lesson = LESSONS[lesson_id]
    ran = 0
    for name, value in cases(lesson_id):
        if name not in names:
            continue
        got = up_front(lesson, **{name: value})
        if isinstance(got, ParameterError):
            continue
        if lesson_id == "area-springs" and got.strip_cells > 120:
            continue  # its statics take seconds: checked once below (the strip of 240 cells)
        run_whole(lesson, stage, got)
        ran += 1
    assert ran


# ------------------------------------------------------------------------- regressions: internal errors

def test_rod_record_every_that_starves_a_speed_fit_is_refused():
    exc = up_front(LESSONS["rod-waves"], record_every=501)
    assert isinstance(exc, ParameterError) and "--record-every 501" in str(exc) and "<= 149" in str(exc)
    assert not isinstance(up_front(LESSONS["rod-waves"], record_every=149), ParameterError)


def test_springs_dt_fraction_too_small_for_one_launch_is_refused():
    exc = up_front(LESSONS["springs"], dt_fraction=1e-7)
    assert isinstance(exc, ParameterError) and "stage 2 would take" in str(exc)
    # past one launch's 2^31 - 1 steps, even where the budget would allow it
    from lessons.springs import scene as S
    plan = S.stage2_plan(LESSONS["springs"].config(dt_fraction=1e-7))
    assert plan["longest"] > S.MAX_LAUNCH_STEPS


def test_tiny_seeds_amplitudes_and_moduli_are_refused_by_their_ranges():
    for lesson_id, kw, flag in (("explicit-vs-implicit", dict(seed_size=1e-300, n=6), "--seed-size"),
                                ("area-springs", dict(E=1e-308, rho=1e308), "--E"),
                                ("rod-waves", dict(amplitude=1e-300), "--amplitude"),
                                ("area-springs", dict(strain=1e-300), "--strain"),
                                ("springs", dict(k=1e-300), "--k"),
                                ("springs", dict(dt_fraction=1.0), "--dt-fraction"),  # the stiffened chain blows up
                                ("explicit-vs-implicit", dict(E=1.0), "--E 1"),  # its weight strains it by 98%
                                ("explicit-vs-implicit", dict(seed_size=1e-3), "--seed-size"),
                                # the sweep's softest cloth: its weight would strain it by 1e300
                                ("explicit-vs-implicit", dict(E_soft=1e-300), "--E-soft 1e-300"),
                                ("explicit-vs-implicit", dict(E_soft=9.8), "--E-soft 9.8")):
        exc = up_front(LESSONS[lesson_id], **kw)
        assert isinstance(exc, ParameterError) and str(exc).startswith(flag), (lesson_id, kw, exc)


def test_area_springs_strip_of_240_cells_converges():
    """The stretch's static solve stalled (noisy Armijo at round-off, a 1e-10 Cholesky residual) and
    asked for a tolerance no option sets; it now converges."""
    s = {e.id: e for e in run_whole(LESSONS["area-springs"], 5, LESSONS["area-springs"].config(strip_cells=240))}
    assert all(e.passed for e in s.values()), s


# ------------------------------------------------------------------------- regressions: failures unexplained

@pytest.mark.parametrize("nodes", [50, 100, 200, 1000])
def test_springs_hanging_rod_of_many_nodes_converges(nodes):
    s = run_whole(LESSONS["springs"], 5, LESSONS["springs"].config(hang_nodes=nodes))
    assert all(e.passed for e in s), [(e.id, e.measured, e.reason) for e in s if not e.passed]


def test_springs_round_off_floor_scales_the_hanging_tolerance():
    from engine import runtime
    from lessons.springs import scene, stages as S
    runtime.init()
    cfg = LESSONS["springs"].config()
    model, _ = scene.hanging_rod(cfg, "uniform")
    assert 2 * S.force_roundoff(model, 0.05) < S.HANG_TOL  # the defaults keep 1e-10
    cfg = LESSONS["springs"].config(hang_nodes=5000)
    model, _ = scene.hanging_rod(cfg, "uniform")
    assert S.HANG_TOL < 2 * S.force_roundoff(model, 0.05) < S.HANG_TOL_MAX  # 5000 nodes: ~1e-7


def test_rod_default_pulse_is_a_length_so_fine_rods_resolve_it_better():
    """--nodes 10001 failed: a pulse of 10 spacings disperses over the 5000 spacings it crosses;
    the default pulse is 1 cm, 100 spacings there, and the grid's predicted slowdown shrinks."""
    from lessons.rod_waves import scene, stages as S
    cfg = LESSONS["rod-waves"].config(nodes=10001)
    h = 1e-4
    assert scene.pulse_width(cfg, h) == 0.01
    assert S.dispersion_spread(0.5, h, 0.01, 0.4) < 0.1 < 0.3 < S.dispersion_spread(0.5, h, 10 * h, 0.4)
    assert scene.pulse_width(LESSONS["rod-waves"].config(), 1e-3) == 10 * 1e-3  # the defaults' 10 spacings
    assert scene.pulse_width(LESSONS["rod-waves"].config(nodes=201), 5e-3) == 0.05  # coarse grids keep 10 spacings
    assert scene.pulse_width(LESSONS["rod-waves"].config(width=2.0), 1e-3) == 2e-3  # --width counts spacings


def test_rod_stencil_check_at_50001_nodes_passes_to_the_spacings_round_off():
    s = {e.id: e for e in run_whole(LESSONS["rod-waves"], 1, LESSONS["rod-waves"].config(nodes=50001))}
    e = s["force-is-pde-stencil"]
    assert e.passed and e.tolerance > 1e-12  # 4 eps max|x| / h
    d = {e.id: e for e in run_whole(LESSONS["rod-waves"], 1, LESSONS["rod-waves"].config())}
    assert d["force-is-pde-stencil"].tolerance == 1e-12  # the defaults keep theirs


def test_evi_unsettled_cloth_says_why():
    """explicit-vs-implicit --n 40: backward Euler at 10 x the (smaller) limit damps the cloth too
    little to settle in 2 s; the failure names the slowest mode's remaining amplitude."""
    from engine import runtime
    from engine.scenes import cloth
    from lessons.explicit_vs_implicit import stages as S
    from lessons.explicit_vs_implicit.scene import stage_seconds
    runtime.init()
    cfg = LESSONS["explicit-vs-implicit"].config(n=6)
    scene = cloth(cfg.n, 1.0, E=cfg.E, rho=cfg.rho, B=cfg.B)
    cl = S._HangingCloth(scene, scene.model.X.copy(), 1.0, 1e-3, None, None, 0.0, 0.0, 1.0)
    ctx = StageContext(LESSONS["explicit-vs-implicit"], cfg, NullRecorder(), 1, stream=io.StringIO(), quiet=True)
    w1 = S.slowest_in_plane(scene.model, scene.model.X)
    assert w1 > 0
    assert S._unsettled_reason(ctx, cl, w1, 1e-3, 10, 10.0, 0.5).startswith("numerical damping too weak")
    assert S._unsettled_reason(ctx, cl, w1, 1e-3, 10, 10.0, 1e-4) == ""  # settled: nothing to explain
    assert S._unsettled_reason(ctx, cl, w1, 10.0, 10**6, 10.0, 0.5) == ""  # theory says settled: no excuse
    assert stage_seconds(LESSONS["explicit-vs-implicit"].config(n=40), 1) < WORK_BUDGET_S


# ------------------------------------------------------------------------- regressions: long and silent

@pytest.mark.parametrize("lesson_id,kw,within", [
    ("rod-waves", dict(nodes=200001), (1e11, 4e11)),       # stage 2 or 4: ~45 min, announced, with a bar
    ("rod-waves", dict(cfl_steps=10**7), (1e11, 4e11)),    # stage 3's bisection
    ("explicit-vs-implicit", dict(E=1e6), (60, 3600)),
    ("springs", dict(steps=10**7), (600, 3600)),
])
def test_long_runs_are_estimated_and_allowed(lesson_id, kw, within):
    cfg = up_front(LESSONS[lesson_id], **kw)
    assert not isinstance(cfg, ParameterError), cfg
    if lesson_id == "rod-waves":
        from lessons.rod_waves import scene as S
        worst = max(S.stage_work(cfg, i) for i in (2, 3, 4))
    elif lesson_id == "springs":
        from lessons.springs import scene as S
        worst = S.stage2_plan(cfg)["seconds"]
    else:
        from lessons.explicit_vs_implicit import scene as S
        worst = S.stage_seconds(cfg, 1)
    assert within[0] < worst < within[1]


@pytest.mark.parametrize("lesson_id,kw", [
    ("rod-waves", dict(nodes=200001, record_every=1)), ("rod-waves", dict(cfl=1e-6)),
    ("rod-waves", dict(nodes=200001, cfl_steps=10**7)), ("springs", dict(steps=10**7, record_every=1)),
    ("area-springs", dict(cfl=1e-4)), ("explicit-vs-implicit", dict(n=40, E=1e7)),
])
def test_runs_of_hours_are_refused_up_front(lesson_id, kw):
    exc = up_front(LESSONS[lesson_id], **kw)
    assert isinstance(exc, ParameterError) and "would take" in str(exc) and " h " in str(exc), exc


class FakeTerminal(io.StringIO):
    def isatty(self):
        return True


def test_progress_bar_shows_rate_and_time_left_on_a_terminal_and_is_cleared(monkeypatch):
    from engine.integrators import loop
    monkeypatch.setattr(loop, "PROGRESS_AFTER_S", 0.0)
    monkeypatch.setattr(loop, "PROGRESS_EXPECTED_S", 0.0)
    monkeypatch.setattr(loop, "PROGRESS_INTERVAL_S", 0.0)

    def advance(chunk, done):
        return np.arange(done + 1, done + chunk + 1), np.full(chunk, 1.0), np.full(chunk, 2.0)
    term = FakeTerminal()
    s1, k1, w1 = loop.run(advance, 100, 10, progress=loop.Progress("    run", 100, stream=term))
    text = term.getvalue()
    assert "steps/s" in text and "<" in text and "run:" in text  # rate and time left
    assert text.endswith("\r") and text.rstrip("\r").split("\r")[-1].strip() == ""  # cleared at the end
    s0, k0, w0 = loop.run(advance, 100, 10)
    assert np.array_equal(s0, s1) and np.array_equal(k0, k1) and np.array_equal(w0, w1)
    pipe = io.StringIO()
    loop.run(advance, 100, 10, progress=loop.Progress("    run", 100, stream=pipe))
    assert pipe.getvalue() == ""  # not a terminal: no bar


def test_progress_bar_waits_for_a_long_run():
    from engine.integrators import loop
    term = FakeTerminal()
    bar = loop.Progress("    run", 1000, stream=term)
    bar.update(500)  # half done at once: expected far under PROGRESS_EXPECTED_S
    bar.close()
    assert term.getvalue() == ""


def test_rod_quiet_runs_in_launches_step_exactly_as_one_launch(monkeypatch):
    from engine import runtime
    from engine.scenes import Rod
    from lessons.rod_waves import scene, stages as S
    runtime.init()
    rod = Rod.uniform(101, 1.0, 1.0, 1.0)
    u0 = scene.gaussian(rod.p, 0.5, 0.05, 1e-3)
    one, chunked = rod.new_state(u0), rod.new_state(u0)
    dt = 0.99 * float(rod.h[0])
    rod.run(one, dt, 1000, "symplectic-euler")
    monkeypatch.setattr(S, "QUIET_CHUNK", 101 * 37)  # launches of 37 steps
    ctx = StageContext(LESSONS["rod-waves"], LESSONS["rod-waves"].config(), NullRecorder(), 3, stream=io.StringIO(),
                       quiet=True)
    S._quiet_run(ctx, "run", rod, chunked, dt, 1000, "symplectic-euler", None)
    assert np.array_equal(one.positions(), chunked.positions())
    assert np.array_equal(one.velocity(), chunked.velocity())


@pytest.mark.parametrize("lesson_id,stage,kw", [("rod-waves", 2, dict(nodes=6001)), ("rod-waves", 4, dict(nodes=6001)),
                                                ("springs", 4, dict(wave_segments=6000))])
def test_backward_eulers_modal_reference_too_large_is_a_failure_with_its_reason(lesson_id, stage, kw):
    """Under backward Euler the scene claims compare with the scheme's modal reference, which holds
    all n^2 mode shapes: past 5001 nodes the stage says so at once instead of running out of memory."""
    from lessons._framework import Stepping
    lesson = LESSONS[lesson_id]
    ctx = StageContext(lesson, lesson.config(**kw), NullRecorder(), stage, stream=io.StringIO(), quiet=True,
                       stepping=Stepping(integrator="backward-euler"))
    (e,) = lesson.stages[stage - 1].run(ctx)
    assert not e.passed and "mode shapes" in e.reason and "--integrator backward-euler" in e.reason
