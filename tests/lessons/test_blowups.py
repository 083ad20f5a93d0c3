"""Blow-ups are caught at the step they happen, explained, and kept in the recording.

For every integrator a run is made to fail on purpose: forward Euler (unstable at any dt),
symplectic Euler and velocity Verlet above their CFL limit, backward Euler whose linear solver
is starved of iterations (its SolverError must come out as a BlowUpError), the rod's one-launch
runner and the fused spring kernel. Each time:

- the run stops at the step where the energy first leaves its bound, found independently by
  stepping a copy of the same state without any bound;
- the message names that step, the energy and the likely cause (explicit: the CFL limit and the
  stable dt estimate; implicit: the solver that did not converge);
- the recording keeps every energy sample up to that step, the geometry at that step, and an
  ERROR event (rec.mark) at that step.

The recorder here is a fake that writes down every call; one test reads a real .rrd back.
"""
import math
from types import SimpleNamespace

import numpy as np
import pytest

from engine import diagnostics
from engine import mesh as meshes
from engine.errors import BlowUpError
from engine.integrators import Stepper, make_integrator, stable_dt_estimate
from engine.model import Model
from lessons.app.recorder import Recorder
from lessons.app.recorder_null import NullRecorder
from lessons.app.recorder_read import summarize
from engine.scenes import Rod
from lessons import rod_waves
from lessons._framework import Lesson, StageContext
from lessons._scene import simulate


# --------------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------------

class CallRecorder(NullRecorder):
    """A recorder that records which frames got energies, geometry and marks."""

    enabled = True

    def __init__(self):
        super().__init__()
        self.now = None
        self.energy_frames: list[int] = []   # "after step s" frames (1-based), as the Recorder logs them
        self.energy_values: list[float] = []
        self.geometry_frames: list[int] = []
        self.marks: list[tuple] = []
        self.runs: list[str] = []

    def run(self, name, view=None, n_steps=None, dt=None, draw_every=None):
        self.runs.append(name)
        return name

    def wants_frame(self, step, sim_time):  # every chunk, so the frames are the chunks' ends
        return True

    def frame_spacing(self, n_steps):  # no finer chunks than the run's own
        return n_steps

    def set_time(self, step, sim_time):
        self.now = int(step)

    def energies(self, kinetic, potential, dt, first_step=0):
        k, w = np.asarray(kinetic, float), np.asarray(potential, float)
        self.energy_frames += list(first_step + 1 + np.arange(k.size))
        self.energy_values += list(k + w)

    def points(self, entity, positions, *args, **kwargs):
        self.geometry_frames.append(self.now)

    def rod(self, *args, **kwargs):
        self.geometry_frames.append(self.now)

    def mark(self, text, level="WARN"):
        self.marks.append((self.now, text, level))


def run_fused(model, state, dt, n_steps, method="symplectic-euler", energy_bound=None, step_offset=0):
    """n_steps of ``method`` in one launch of the many-steps kernel, through the Stepper (its energies)."""
    from engine.integrators.stepper import Stepper
    return Stepper(model, method, many_steps=True).energies(state, dt, n_steps, energy_bound, step_offset)


def make_ctx(rec, **cfg):
    lesson = Lesson(id="blowups", title="blow-ups", summary="", config=SimpleNamespace, stages=[])
    return StageContext(lesson, SimpleNamespace(record_every=5, amplitude=1e-3, **cfg), rec, 1, quiet=True)


def spring_sheet(seed=0, n=6):
    """A 6 x 6 sheet of area-scaled springs (1 m, E = 100 N/m, rho = 1 kg/m^2), one corner
    pinned, with small random velocities so every mode is excited."""
    m3 = meshes.embed_3d(meshes.right_triangle_grid(n, n), "xy")
    X = np.asarray(m3.vertices)
    model = Model.from_springs(X, m3.edges, c=100.0 * m3.edge_measure, mass=meshes.lumped_masses(m3, 1.0),
                               pinned=[0])
    rng = np.random.default_rng(seed)
    v0 = 0.05 * rng.standard_normal(X.shape)
    return model, X, v0


def first_bad_step(model, X, v0, integ, dt, bound, n_steps):
    """0-based index of the first step after which K + W > bound (or is not finite), by plain
    stepping without any check; None if there is none."""
    state = model.make_state(X, v0)
    stepper = Stepper(model, integ)
    stepper.begin(state)
    for s in range(n_steps):
        stepper.advance(state, dt)
        E = diagnostics.kinetic_energy(model, state) + model.potential_energy(state.x)
        if not (E <= bound):
            return s, E
    return None, None


def draw_points(rec, state):
    rec.points("x", state.x.to_numpy())


def assert_recorded_up_to(rec, step, every, energies=True):
    """Energies after every step 1..step+1 (1..step when the failed step produced none: a solver
    failure undoes its step), geometry every ``every`` steps and at the bad step, one ERROR mark
    at the bad step. Returns the mark's text."""
    last = step + 1
    assert rec.energy_frames == list(range(1, last + 1 if energies else last))
    assert rec.geometry_frames == list(range(0, last, every)) + [last]
    assert len(rec.marks) == 1
    frame, text, level = rec.marks[0]
    assert frame == last and level == "ERROR"
    return text


def energies_until_blowup(run):
    """Per-step (kinetic, potential) of a run with no bound: all of them, or, when it ends in
    non-finite numbers (which every runner refuses), those up to that step."""
    try:
        return run()
    except BlowUpError as exc:
        return exc.kinetic, exc.potential


# --------------------------------------------------------------------------------------------
# explicit integrators through lessons._scene.simulate
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("name,over", [("forward-euler", 0.5), ("symplectic-euler", 1.05), ("velocity-verlet", 1.05)])
def test_explicit_blowup_stops_at_its_step_with_cfl_and_stable_dt(name, over):
    """``over``: dt as a multiple of the true stability limit 2/w_max (power iteration); the
    message compares dt with the conservative Gershgorin estimate."""
    model, X, v0 = spring_sheet()
    dts = stable_dt_estimate(model)
    dt = over * stable_dt_estimate(model, method="power")
    E0 = diagnostics.kinetic_energy(model, model.make_state(X, v0))
    bound = 100.0 * E0
    expected, E_bad = first_bad_step(model, X, v0, make_integrator(name), dt, bound, 400)
    assert expected is not None and expected >= 3  # a few good steps first

    rec = CallRecorder()
    state = model.make_state(X, v0)
    with pytest.raises(BlowUpError) as info:
        simulate(make_ctx(rec), "sheet", model, state, dt, 400, integrator=name, every=5, energy_bound=bound,
                 log=draw_points, fixed=True)
    exc = info.value
    assert exc.step == expected
    assert math.isclose(exc.energy, E_bad, rel_tol=1e-9)
    msg = str(exc)
    assert f"{name} blew up at step {expected} " in msg
    assert f"total energy {E_bad:.4g} J" in msg
    assert "CFL" in msg and f"dt_stable={dts:.3g} s" in msg and "likely cause" in msg
    if name == "forward-euler":
        assert "unstable" in msg and "any dt" in msg
    else:
        assert f"dt is {dt / dts:.2f}x the CFL limit" in msg and f"below {dts:.3g} s" in msg
    assert exc.dt_stable == pytest.approx(dts)
    text = assert_recorded_up_to(rec, expected, 5)
    assert text == msg
    assert rec.energy_values[-1] == pytest.approx(E_bad, rel=1e-9)
    assert state.t == pytest.approx((expected + 1) * dt)  # the run stopped there


def test_explicit_blowup_in_a_real_recording(tmp_path):
    model, X, v0 = spring_sheet(seed=3)
    dt = 1.05 * stable_dt_estimate(model, method="power")
    bound = 100.0 * diagnostics.kinetic_energy(model, model.make_state(X, v0))
    expected, _ = first_bad_step(model, X, v0, make_integrator("symplectic-euler"), dt, bound, 400)
    path = tmp_path / "blowup.rrd"
    rec = Recorder(path, "test_blowup")
    rec.stage(1, "blow-up", "text")
    with pytest.raises(BlowUpError) as info:
        simulate(make_ctx(rec), "sheet", model, model.make_state(X, v0), dt, 400, every=4, energy_bound=bound,
                 log=draw_points, fixed=True)
    rec.close()
    assert info.value.step == expected
    info_rrd = summarize(path)
    total = info_rrd["/stage1/sheet/energy/total"]
    assert total["steps"] == list(range(1, expected + 2))  # a short run: every step's energy
    last = expected + 1
    # the recorder's frames (every 2 steps: FRAMES_PER_RUN over 400 steps) up to the bad step,
    # which is drawn whatever the spacing
    geometry = info_rrd["/stage1/sheet/x"]["steps"]
    assert geometry[-1] == last and geometry[:-1] == list(range(0, last, 2))[: len(geometry) - 1]
    assert len(geometry) >= last // 2
    events = info_rrd["/stage1/sheet/events"]
    assert events["rows"] == 1 and events["steps"] == [last]


# --------------------------------------------------------------------------------------------
# backward Euler: a linear solve that does not converge is a blow-up at that step
# --------------------------------------------------------------------------------------------

def test_backward_euler_solver_failure_is_a_blowup_at_the_step():
    model, X, v0 = spring_sheet()
    dt = 20.0 * stable_dt_estimate(model)  # stiffness dominates the system: Jacobi-PCG needs many iterations
    fail_after = 5
    from engine.integrators.implicit import BackwardEuler
    from engine.solvers import PCGSolver

    class Starving(PCGSolver):
        """PCG that, after 5 good solves (one per step), is allowed only 2 iterations at tol 1e-14 (the
        stepper solves with its own copy of it: LinearSolver.fresh keeps the class)."""
        def solve(self, *args, **kwargs):
            self.solves = getattr(self, "solves", 0) + 1
            if self.solves > fail_after:
                self.max_iter, self.tol = 2, 1e-14
            return super().solve(*args, **kwargs)

    integ = BackwardEuler(solver=Starving(1e-8, 1000), tol=1e-8)
    rec = CallRecorder()
    state = model.make_state(X, v0)
    with pytest.raises(BlowUpError) as info:
        simulate(make_ctx(rec), "sheet", model, state, dt, 50, integrator=integ, every=5, log=draw_points,
                 fixed=True)
    exc = info.value
    assert exc.step == fail_after
    msg = str(exc)
    assert f"backward-euler failed at step {fail_after} " in msg
    assert "pcg" in msg and "max_iter=2" in msg and "likely cause: the linear solver did not converge" in msg
    text = assert_recorded_up_to(rec, fail_after, 5, energies=False)
    assert text == msg
    # the state is the last good one (the failed step was undone)
    assert state.t == pytest.approx(fail_after * dt)
    assert np.isfinite(state.numpy().x).all()


def test_backward_euler_that_never_converges_fails_at_step_0():
    model, X, v0 = spring_sheet()
    integ = make_integrator("backward-euler", solver="pcg", tol=1e-14, max_iter=2)
    rec = CallRecorder()
    with pytest.raises(BlowUpError) as info:
        simulate(make_ctx(rec), "sheet", model, model.make_state(X, v0), 20.0 * stable_dt_estimate(model), 10,
                 integrator=integ, every=5, log=draw_points, fixed=True)
    assert info.value.step == 0
    assert "failed at step 0 " in str(info.value) and "did not converge" in str(info.value)
    assert rec.marks and rec.marks[0][0] == 1 and rec.geometry_frames == [0, 1]


def test_backward_euler_failure_message_gives_the_energy():
    model, X, v0 = spring_sheet()
    integ = make_integrator("backward-euler", solver="pcg", tol=1e-14, max_iter=2)
    state = model.make_state(X, v0)
    E = diagnostics.kinetic_energy(model, state) + model.potential_energy(state.x)
    with pytest.raises(BlowUpError) as info:
        simulate(make_ctx(CallRecorder()), "sheet", model, state, 20.0 * stable_dt_estimate(model), 10,
                 integrator=integ, every=5, fixed=True)
    assert math.isclose(info.value.energy, E, rel_tol=1e-9)
    assert f"{E:.4g} J" in str(info.value)


# --------------------------------------------------------------------------------------------
# the rod's one-launch runner (engine.scenes.Rod via lessons/rod_waves.simulate)
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("method,cfl", [("symplectic-euler", 1.05), ("forward-euler", 0.5)])
def test_rod_runner_blowup_at_its_step(method, cfl):
    rod = Rod.uniform(101, 1.0, 1.0, 1.0, pinned=(0, 100))
    u0 = 1e-3 * np.exp(-0.5 * ((rod.p - 0.5) / 0.05) ** 2)
    u0 += 1e-6 * np.cos(np.pi * np.arange(rod.n))  # a little of the highest mode
    dt = cfl * rod.stable_dt()
    E0 = rod.energy(rod.p + u0)
    bound = 10.0 * E0
    ref = rod.new_state(u0)
    K, W = energies_until_blowup(lambda: rod.run(ref, dt, 3000, method))
    bad = np.flatnonzero(~(K + W <= bound))
    assert bad.size and bad[0] >= 3
    expected = int(bad[0])

    rec = CallRecorder()
    state = rod.new_state(u0)
    with pytest.raises(BlowUpError) as info:
        rod_waves.simulate(make_ctx(rec), "rod", rod, state, dt, 3000, method, energy_bound=bound, every=25)
    exc = info.value
    assert exc.step == expected
    assert math.isclose(exc.energy, K[expected] + W[expected], rel_tol=1e-12)
    msg = str(exc)  # the engine's one blow-up message (engine.integrators.monitor)
    assert f"step {expected} " in msg and f"{exc.energy:.4g} J" in msg
    if method == "symplectic-euler":
        assert "CFL limit" in msg and f"dt_stable={rod.stable_dt():.3g} s" in msg
    else:
        assert "forward Euler" in msg
    assert exc.kinetic.size == expected + 1  # energies up to and including the bad step
    text = assert_recorded_up_to(rec, expected, 25)
    assert text == msg
    assert rec.energy_values[-1] == pytest.approx(K[expected] + W[expected], rel=1e-12)


# --------------------------------------------------------------------------------------------
# the fused many-steps-per-launch spring kernel (the Stepper's many-steps path, Stepper.energies)
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("method,over", [("symplectic-euler", 1.05), ("velocity-verlet", 1.05), ("forward-euler", 0.5)])
def test_fused_spring_kernel_blowup_at_its_step(method, over):
    n = 12
    X = np.stack([np.zeros(n), np.zeros(n), -np.linspace(0, 1, n)], axis=1)
    edges = np.stack([np.arange(n - 1), np.arange(1, n)], axis=1)
    model = Model.from_springs(X, edges, k=1000.0, mass=1.0 / n, pinned=[0])
    rng = np.random.default_rng(1)
    v0 = 0.01 * rng.standard_normal(X.shape)
    v0[0] = 0.0
    dts = stable_dt_estimate(model)
    dt = over * stable_dt_estimate(model, method="power")  # a multiple of the true limit 2/w_max
    bound = 100.0 * 0.5 * np.sum((1.0 / n) * v0 ** 2)
    K, W = energies_until_blowup(lambda: run_fused(model, model.make_state(X, v0), dt, 5000, method))
    bad = np.flatnonzero(~(K + W <= bound))
    assert bad.size and bad[0] >= 3
    expected = int(bad[0])

    # directly: the step (with an offset), the energies up to it, the message
    with pytest.raises(BlowUpError) as info:
        run_fused(model, model.make_state(X, v0), dt, 5000, method, energy_bound=bound, step_offset=1000)
    exc = info.value
    assert exc.step == 1000 + expected
    assert exc.kinetic.size == expected + 1 and exc.energy == pytest.approx(K[expected] + W[expected], rel=1e-12)
    msg = str(exc)
    assert f"blew up at step {1000 + expected} " in msg and f"{exc.energy:.4g} J" in msg
    assert f"dt_stable={dts:.3g} s" in msg and "likely cause" in msg

    # in chunks through the lessons' one runner: recorded up to the step and marked there
    rec = CallRecorder()
    state = model.make_state(X, v0)

    with pytest.raises(BlowUpError) as info:
        simulate(make_ctx(rec), "chain", model, state, dt, 5000, method, 7, bound,
                 log=lambda r, st: r.points("x", st.x.to_numpy()), chosen=True)
    assert info.value.step == expected
    text = assert_recorded_up_to(rec, expected, 7)
    assert text == str(info.value)
    assert info.value.kinetic.size == expected + 1


def test_fused_spring_kernel_without_a_bound_stops_where_the_energy_overflows():
    """No energy bound: a run over the stability limit still stops at the first step whose total
    energy is not finite (here +inf: the velocities overflow), not after all its steps."""
    n = 12
    X = np.stack([np.zeros(n), np.zeros(n), -np.linspace(0, 1, n)], axis=1)
    edges = np.stack([np.arange(n - 1), np.arange(1, n)], axis=1)
    model = Model.from_springs(X, edges, k=1000.0, mass=1.0 / n, pinned=[0])
    v0 = 0.01 * np.random.default_rng(2).standard_normal(X.shape)
    v0[0] = 0.0
    dt = 1.5 * stable_dt_estimate(model, method="power")
    with pytest.raises(BlowUpError) as info:
        run_fused(model, model.make_state(X, v0), dt, 200000, "symplectic-euler")
    exc = info.value
    assert not np.isfinite(exc.energy)
    assert exc.step < 200000 - 1
    finite = exc.kinetic[:-1] + exc.potential[:-1]
    assert np.all(np.isfinite(finite)) and finite[-1] > 1e200   # every step before it had a finite energy
