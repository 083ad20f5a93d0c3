"""The exercises' own checks (lessons/<id>/exercise.py), gold and coals: every reference solution
(lessons/<id>/solution.py) passes every function check, and each deliberately wrong solution
fails the named experiment with a reason that names the mistake.

The whole grader (child processes, time limits, the lessons' stages on the student's functions)
is tested in tests/app/test_grading.py."""
import importlib

import pytest

from lessons._exercise import LocalFunction, StudentError, load_student_module
from tests.lessons.coals import COALS

LESSONS = ["springs", "rod_waves", "area_springs", "bending", "explicit_vs_implicit", "membranes"]

# (lesson package, the reference's line, the wrong line, the experiment that catches it, words of
# its reason): each mistake a student makes, and where the grader says so
WRONG = [
    ("springs", "return 0.5 * c * strain * strain", "return c * strain * strain",
     "ex-spring-energy", "the 1/2 is missing"),
    ("springs", "strain = d.norm() / L - 1.0", "strain = d.norm() / L",
     "ex-spring-energy", "not zero at the rest length"),
    ("springs", "f = -(c / L) * (l / L - 1.0) * d / l", "f = (c / L) * (l / L - 1.0) * d / l",
     "ex-spring-force", "wrong sign"),
    ("springs", "f = -(c / L) * (l / L - 1.0) * d / l", "f = -(c / L) * (l - 1.0) * d / l",
     "ex-spring-force", "not zero at the rest length"),
    ("springs", "K = (c / (L * L)) * (nnT + (1.0 - L / l) * (ti.math.eye(3) - nnT))", "K = (c / (L * L)) * nnT",
     "ex-spring-hessian", "transverse term"),
    ("springs", "K = (c / (L * L)) * (nnT + (1.0 - L / l) * (ti.math.eye(3) - nnT))",
     "K = -(c / (L * L)) * (nnT + (1.0 - L / l) * (ti.math.eye(3) - nnT))", "ex-spring-hessian", "wrong sign"),
    ("springs", "return x + dt * v_new, v_new", "return x + dt * v, v_new",
     "ex-symplectic-euler", "forward Euler"),
    ("springs", "v_half = v + 0.5 * dt * a", "v_half = v + dt * a",
     "ex-verlet-kick-drift", "kicks by dt a"),
    ("rod_waves", "return E_right * strain_right - E_left * strain_left",
     "return E_left * strain_left - E_right * strain_right", "ex-rod-force", "wrong sign"),
    ("rod_waves", "strain_right = (x_right - x) / h_right - 1.0", "strain_right = (x_right - x) / h_right",
     "ex-rod-force", "not zero for the rod at rest"),
    ("area_springs", "np.add.at(out, rows, size / len(pairs))", "np.add.at(out, rows, size / 2)",
     "ex-edge-measure-triangles", "area/3"),
    ("bending", "return ti.atan2(sine, N0.dot(N1))", "return ti.atan2(-sine, N0.dot(N1))",
     "ex-dihedral-angle", "wrong sign"),
    ("bending", "return ti.atan2(sine, N0.dot(N1))", "return ti.acos(N0.dot(N1) / (N0.norm() * N1.norm()))",
     "ex-dihedral-angle", "loses the sign"),  # and NaN on flat hinges: acos of a cosine rounded above 1
    ("bending", "return g_v0, g_v1, g_w0, g_w1", "return g_v0, g_v1, g_w1, g_w0",
     "ex-dihedral-gradient", "gradient is not dtheta/dx"),
    ("explicit_vs_implicit", "return 1.0 / (dt * dt), 1.0", "return 1.0, 1.0",
     "ex-newton-coefficients", "a missing dt^2"),
    ("explicit_vs_implicit", "return f - m * (x - x_n - dt * v_n) / (dt * dt)", "return f - m * (x - x_n) / (dt * dt)",
     "ex-newton-residual", "leaves out dt v_n"),
    ("explicit_vs_implicit", "return (x_new - x_n) / dt", "return (x_new - x_n) / (dt * dt)",
     "ex-step-velocity", "divides by dt^2"),
    ("membranes", "return w_u, w_v", "return w_v, w_u", "ex-deformation-gradient", "returns (w_v, w_u)"),
    ("membranes", "w_v = d1 * Dinv[0, 1] + d2 * Dinv[1, 1]", "w_v = d1 * Dinv[1, 0] + d2 * Dinv[1, 1]",
     "ex-deformation-gradient", "gives w_v ="),
    ("membranes", "dW_dwu = A * (k_stretch * (lu - 1.0) * w_u / lu + k_shear * s * w_v)",
     "dW_dwu = A * (k_stretch * (lu - 1.0) * w_u / lu)", "ex-bw-stress", "leaves out the shear term"),
    ("membranes", "dW_dwv = A * (k_stretch * (lv - 1.0) * w_v / lv + k_shear * s * w_u)",
     "dW_dwv = A * (k_stretch * (lv - 1.0) * w_v + k_shear * s * w_u)", "ex-bw-stress", "along the unit vector"),
    ("membranes", "dW_dwu = A * (k_stretch * (lu - 1.0) * w_u / lu + k_shear * s * w_v)",
     "dW_dwu = A * (k_stretch * (lu - 1.0) * w_u / lu + k_shear * s * w_u)", "ex-bw-stress", "wrong column"),
]


def _source(package: str) -> str:
    return (importlib.import_module(f"lessons.{package}").__path__[0] + "/solution.py")


class _Failed:
    """A check that could not run (the student's function raised): a failed experiment of its own."""
    passed = False

    def __init__(self, name: str, reason: str):
        self.id, self.reason, self.measured = f"ex-{name.replace('_', '-')}-runs", reason, None


def _checked(package: str, module) -> dict:
    """{function name: its experiments}"""
    exercise = importlib.import_module(f"lessons.{package}.exercise")
    found = {}
    for task in exercise.TASKS:
        try:
            found[task.name] = task.check(LocalFunction(task.name, getattr(module, task.name)))
        except StudentError as exc:
            found[task.name] = [_Failed(task.name, str(exc))]
    return found


def _experiments(package: str, module) -> list:
    return [e for exps in _checked(package, module).values() for e in exps]


@pytest.mark.parametrize("package", LESSONS)
def test_the_reference_solution_passes_every_function_check(package):
    exps = _experiments(package, load_student_module(_source(package)))
    assert exps and all(e.passed for e in exps), [(e.id, e.measured, e.reason) for e in exps if not e.passed]
    tasks = importlib.import_module(f"lessons.{package}.exercise").TASKS
    assert {t.name for t in tasks} <= set(vars(load_student_module(_source(package))))


def test_at_least_twelve_mistakes_each_on_another_line_or_function():
    assert len(WRONG) >= 12
    assert len({(w[0], w[2]) for w in WRONG}) == len(WRONG)


@pytest.mark.parametrize("package,right,wrong,caught_by,words", WRONG,
                         ids=[f"{w[0]}:{w[3]}:{w[4].replace(' ', '-')}" for w in WRONG])
def test_a_wrong_solution_fails_the_experiment_that_names_its_mistake(tmp_path, package, right, wrong, caught_by,
                                                                      words):
    text = open(_source(package), encoding="utf-8").read()
    assert text.count(right) == 1, f"the reference's line {right!r} moved"
    path = tmp_path / f"{package}.py"
    path.write_text(text.replace(right, wrong), encoding="utf-8")
    checked = _checked(package, load_student_module(path))
    exps = {e.id: e for found in checked.values() for e in found}
    assert caught_by in exps
    assert not exps[caught_by].passed
    assert words in exps[caught_by].reason, exps[caught_by].reason
    # the lesson's other functions are not blamed for it
    mutated = next(name for name, found in checked.items() if caught_by in {e.id for e in found})
    blamed = {name for name, found in checked.items() if any(not e.passed for e in found)}
    assert blamed == {mutated}


# the wrong solutions whose check crashes Taichi's compiler (an abort of the process): graded through
# the grader's child process in tests/app/test_grading.py instead
IN_A_CHILD_ONLY = {"symplectic_vec3_only"}


def test_the_coals_cover_every_lesson_and_number_at_least_forty():
    assert len(COALS) + len(WRONG) >= 40
    assert {c[0] for c in COALS} == set(LESSONS)
    assert len({c[1] for c in COALS}) == len(COALS)


@pytest.mark.parametrize("package,name,function,right,wrong,mistake,words",
                         [c for c in COALS if c[1] not in IN_A_CHILD_ONLY],
                         ids=[f"{c[0]}:{c[1]}" for c in COALS if c[1] not in IN_A_CHILD_ONLY])
def test_each_coal_fails_its_own_function_check_with_a_reason_that_names_it(tmp_path, package, name, function,
                                                                             right, wrong, mistake, words):
    """Every mistake is caught by the check of the function it is in (not only by a stage), and no
    other function is blamed; the reason says what is wrong."""
    text = open(_source(package), encoding="utf-8").read()
    assert text.count(right) == 1, f"the reference's text {right!r} moved"
    path = tmp_path / f"{package}.py"
    path.write_text(text.replace(right, wrong), encoding="utf-8")
    checked = _checked(package, load_student_module(path))
    failed = [e for e in checked[function] if not e.passed]
    assert failed, f"{name}: {mistake} passes {function}'s check"
    blamed = {n for n, found in checked.items() if any(not e.passed for e in found)}
    assert blamed == {function}
    assert all(e.reason for e in failed)
    assert any(words in e.reason for e in failed), [e.reason for e in failed]
