"""The stepper drives, the integrator is driven (issue: integrators reached back into the stepper, and
backward Euler kept its statistics and its solver's set-up on the shared registry instance).

- an integrator is handed a StepContext and the state; no integrator module touches a stepper;
- the fast paths are the stepper's own (FastStep, planned for one method): no method strings at a step;
- each stepper solves with its own linear solver (LinearSolver.fresh), so two steppers sharing one
  integrator instance (the registry's) step exactly as each would alone, and keep their own statistics;
  the integrator instance does not change while it steps."""
import ast
import copy
from pathlib import Path

import numpy as np

from engine.integrators import get
from engine.integrators.stepper import Stepper, StepContext
from engine.scenes import cloth
from engine.solvers import LinearSolver, make_solver

ROOT = Path(__file__).resolve().parents[2]


def test_no_integrator_module_reaches_into_a_stepper():
    for name in ("explicit.py", "implicit.py"):
        tree = ast.parse((ROOT / "engine" / "integrators" / name).read_text())
        used = {n.value.id for n in ast.walk(tree) if isinstance(n, ast.Attribute) and isinstance(n.value, ast.Name)}
        assert "stepper" not in used, name
        args = {a.arg for n in ast.walk(tree) if isinstance(n, ast.FunctionDef) and n.name in ("begin", "advance")
                for a in n.args.args}
        assert "stepper" not in args and ("ctx" in args or name == "explicit.py"), (name, args)
    assert not hasattr(LinearSolver, "using")   # no set-up swapped in and out of a shared solver


def test_a_stepper_has_its_own_solver_of_the_integrators_kind():
    be = get("backward-euler")
    model = cloth(5, B=1e-4).model
    a, b = Stepper(model, be), Stepper(model, be)
    assert a.solver is not b.solver and a.solver is not be.solver
    assert type(a.solver) is type(be.solver) and a.solver.tol == be.solver.tol and a.solver.max_iter == be.solver.max_iter
    assert isinstance(a.context, StepContext) and a.context.solver is a.solver and a.context.model is model
    fresh = make_solver("cholesky").fresh()
    assert fresh._set_up is None and fresh._model is None


def test_two_steppers_share_one_integrator_and_step_as_if_alone():
    be = get("backward-euler")   # the registry's instance
    before = copy.deepcopy({k: v for k, v in vars(be).items() if k != "solver"})
    small, big = cloth(5, B=1e-4).model, cloth(7, B=1e-4).model
    dt = 1.0 / 60.0

    def alone(model):
        st = model.make_state()
        Stepper(model, be).step(st, dt, 6)
        return st.numpy().x

    ref_small, ref_big = alone(small), alone(big)
    sa, sb = Stepper(small, be), Stepper(big, be)
    xa, xb = small.make_state(), big.make_state()
    for _ in range(6):   # alternately: each with its own solver set-up
        sa.step(xa, dt)
        sb.step(xb, dt)
    assert np.array_equal(xa.numpy().x, ref_small) and np.array_equal(xb.numpy().x, ref_big)
    assert sa.stats.steps == sb.stats.steps == 6 and sa.stats.solves >= 6 and sb.stats.solves >= 6
    assert sa.last_info is not sb.last_info and sa.last_info.linear_iterations
    assert {k: v for k, v in vars(be).items() if k != "solver"} == before   # nothing kept on the integrator
    assert be.solver._set_up is None   # the registry's solver never solved: the steppers' own did
