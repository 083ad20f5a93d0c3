"""The layout's promise, checked from the sources: the engine is physics only. No module under
engine/ imports rerun (recordings belong to lessons/app/recorder.py) or any lesson module; rerun
is imported by the recorder and the blueprint it sends (lessons/app/) alone, besides the viewer
tools that open recordings (lessons/tools/); and the lessons never import those tools."""
import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _imports(path: Path) -> set:
    """Top-level package names a module imports (absolute imports, at any depth in the module)."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            out.update(a.name.split(".")[0] for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out.add(node.module.split(".")[0])
    return out


def _modules(path: Path) -> set:
    """Dotted names a module imports, relative imports resolved (``from X import y`` gives X and
    X.y, since y may be a module), at any depth in the module."""
    package = list(path.relative_to(ROOT).with_suffix("").parts[:-1])
    out = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = package[:len(package) - node.level + 1] if node.level else []
            module = ".".join(base + ([node.module] if node.module else []))
            out.add(module)
            out.update(f"{module}.{a.name}" for a in node.names)
    return out


def test_the_engine_imports_neither_rerun_nor_lessons():
    offenders = {str(p.relative_to(ROOT)): sorted(_imports(p) & {"rerun", "rerun_cli", "lessons", "bench"})
                 for p in sorted((ROOT / "engine").rglob("*.py"))}
    offenders = {k: v for k, v in offenders.items() if v}
    assert not offenders, f"engine modules importing rerun or lessons/bench: {offenders}"
    assert sum(1 for _ in (ROOT / "engine").rglob("*.py")) > 20   # the scan saw the engine


def test_rerun_is_imported_by_the_recorder_alone():
    users = sorted(str(p.relative_to(ROOT)) for p in sorted((ROOT / "lessons").rglob("*.py"))
                   if "rerun" in _imports(p))
    # the recorder, in parts: its geometry and energy plots, the blueprint (layout) it sends, and
    # the reading of a recording back (recorder_read.py); lessons/tools/viewer_processes.py drives
    # the real viewer (headless screenshots), it writes no recording
    assert users == ["lessons/app/blueprint.py", "lessons/app/recorder.py", "lessons/app/recorder_energies.py",
                     "lessons/app/recorder_geometry.py", "lessons/app/recorder_read.py",
                     "lessons/tools/viewer_processes.py"], users


def test_the_lessons_do_not_import_the_tools():
    lessons = ROOT / "lessons"
    packages = [d for d in sorted(lessons.iterdir()) if (d / "__init__.py").is_file()
                and not d.name.startswith("_") and d.name not in ("app", "tools")]
    files = [p for d in packages for p in sorted(d.rglob("*.py"))] + sorted(lessons.glob("_*.py"))
    offenders = {str(p.relative_to(ROOT)): sorted(m for m in _modules(p)
                                                  if m == "lessons.tools" or m.startswith("lessons.tools."))
                 for p in files}
    offenders = {k: v for k, v in offenders.items() if v}
    assert not offenders, f"lesson modules importing lessons.tools: {offenders}"
    assert len(packages) >= 5 and len(files) > len(packages)   # the scan saw the lessons and lessons/_*.py


def _engine_graph() -> dict:
    """{engine module: engine modules it imports (at any depth: a function-level import counts)};
    ``from P import m`` names the module P.m when m is one, else P."""
    files = {".".join(p.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__"): p
             for p in (ROOT / "engine").rglob("*.py")}
    graph = {}
    for name, path in files.items():
        package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
        deps = set()
        tree = ast.parse(path.read_text(), filename=str(path))
        typing_only = {id(n) for block in ast.walk(tree) if isinstance(block, ast.If)
                       and getattr(block.test, "id", getattr(block.test, "attr", None)) == "TYPE_CHECKING"
                       for n in ast.walk(block)}
        for node in ast.walk(tree):
            if id(node) in typing_only:
                continue  # read by type checkers only: not an import at run time
            if isinstance(node, ast.Import):
                deps.update(a.name for a in node.names if a.name in files)
            elif isinstance(node, ast.ImportFrom):
                base = package[:len(package) - node.level + 1] if node.level else []
                module = ".".join(base + ([node.module] if node.module else []))
                for a in node.names:
                    sub = f"{module}.{a.name}"
                    deps.add(sub if sub in files else module)
        graph[name] = {d for d in deps if d in files and d != name}
    return graph


def test_no_import_circle_in_the_engine():
    """No engine module reaches itself through its imports, function-level ones included (the
    explicit integrators and the run loop once imported each other inside functions)."""
    graph = _engine_graph()
    assert "engine.integrators.stepper" in graph and graph["engine.integrators.explicit"]
    state, circles = {}, []

    def visit(node, path):
        state[node] = "open"
        for dep in sorted(graph[node]):
            if state.get(dep) == "open":
                circles.append(path[path.index(dep):] + [dep])
            elif dep not in state:
                visit(dep, path + [dep])
        state[node] = "done"

    for node in sorted(graph):
        if node not in state:
            visit(node, [node])
    assert circles == []


def test_no_per_model_caches_in_the_engine():
    """Work arrays and plans belong to whoever steps or solves (a Stepper, a solver's set-up), not to
    module-level caches keyed by the model."""
    offenders = [str(p.relative_to(ROOT)) for p in sorted((ROOT / "engine").rglob("*.py"))
                 if "WeakKeyDictionary" in p.read_text()]
    assert offenders == []


def test_each_list_of_names_is_written_once():
    """The integrator and solver names are spelled out as a list in engine/constants.py alone; the
    CLI's choices, the registry, the kernels' method codes and the solvers read them from there.
    (A lesson's stages may still name the methods it compares, in the order it shows them.)"""
    from engine import constants
    from engine.integrators import INTEGRATORS, METHODS
    from engine.solvers import SOLVERS
    from lessons._framework import INTEGRATOR_CHOICES, SOLVER_CHOICES
    assert tuple(INTEGRATORS) == tuple(METHODS) == constants.INTEGRATOR_NAMES == INTEGRATOR_CHOICES[1:]
    assert SOLVERS == constants.SOLVERS == SOLVER_CHOICES[1:]
    lists = []
    shell = [p for p in (ROOT / "lessons").rglob("*.py") if p.name.startswith("_") or p.parent.name in ("app", "tools")]
    for p in sorted(list((ROOT / "engine").rglob("*.py")) + shell):
        for node in ast.walk(ast.parse(p.read_text(), filename=str(p))):
            if isinstance(node, (ast.Tuple, ast.List, ast.Set)):
                words = {e.value for e in node.elts if isinstance(e, ast.Constant)}
                if {"forward-euler", "symplectic-euler", "velocity-verlet"} <= words or \
                        {"pcg", "cholesky", "pardiso"} <= words:
                    lists.append(f"{p.relative_to(ROOT)}:{node.lineno}")
    assert len(lists) == 2 and all(x.startswith("engine/constants.py:") for x in lists), lists


def test_tests_mirror_the_tree():
    """Tests live beside what they test: tests/engine, tests/lessons and tests/app; only the layout
    rules, the shared fixtures and the helpers sit at the top, and an engine test never drives the
    application."""
    tests = ROOT / "tests"
    assert sorted(p.name for p in tests.glob("*.py")) == ["conftest.py", "helpers.py", "test_layout.py"]
    assert {p.parent.name for p in tests.rglob("test_*.py")} == {"tests", "engine", "lessons", "app"}
    offenders = {str(p.relative_to(ROOT)): sorted(m for m in _modules(p) if m.startswith(("lessons.app", "lessons.tools")))
                 for p in sorted((tests / "engine").glob("*.py"))}
    assert {k: v for k, v in offenders.items() if v} == {}


def _source_files(*folders: str) -> list[Path]:
    return [p for folder in folders for p in sorted((ROOT / folder).rglob("*.py"))]


def _dynamic_imports(path: Path) -> set:
    """Module names imported through importlib.import_module / __import__ / spec_from_file_location with a
    literal (or the literal head of an f-string: ``f"lessons.{name}"`` gives ``lessons.``)."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if not (isinstance(node, ast.Call) and node.args):
            continue
        name = getattr(node.func, "attr", getattr(node.func, "id", ""))
        if name not in ("import_module", "__import__"):
            continue
        arg = node.args[0]
        if isinstance(arg, ast.Constant) and isinstance(arg.value, str):
            out.add(arg.value)
        elif isinstance(arg, ast.JoinedStr) and arg.values and isinstance(arg.values[0], ast.Constant):
            out.add(str(arg.values[0].value))
    return out


def _lesson_files() -> list[Path]:
    """Every module of the lessons floor: the lesson packages and lessons/*.py, not the app (lessons/app),
    the viewer tools (lessons/tools) or the program's entry (lessons/__main__.py)."""
    return [p for p in _source_files("lessons") if p.relative_to(ROOT / "lessons").parts[0] not in ("app", "tools")
            and p.name != "__main__.py"]


def test_the_lessons_do_not_import_the_app_even_through_importlib():
    """The app (recorder, blueprint, output files, CLI, grader) is the top floor: it imports the lessons,
    never the other way (lessons say how a run is shown with lessons.views, plain data)."""
    files = _lesson_files()
    offenders = {}
    for p in files:
        names = _modules(p) | _dynamic_imports(p)
        bad = sorted(m for m in names if m in ("lessons.app", "lessons.tools") or m.startswith(("lessons.app.",
                                                                                                 "lessons.tools.")))
        if bad:
            offenders[str(p.relative_to(ROOT))] = bad
    assert not offenders, f"lesson modules importing the app or the tools: {offenders}"
    assert len(files) > 30
    # the scan sees dynamic imports: the app's registry loads the lesson packages that way
    assert "lessons." in _dynamic_imports(ROOT / "lessons" / "app" / "registry.py")


def test_no_module_imports_another_modules_private_name():
    """A name with a leading underscore is its module's own: one another module needs is public."""
    offenders = []
    for p in _source_files("engine", "lessons", "bench"):
        for node in ast.walk(ast.parse(p.read_text(), filename=str(p))):
            if isinstance(node, ast.ImportFrom):
                private = [a.name for a in node.names if a.name.startswith("_") and not a.name.startswith("__")]
                if private:
                    offenders.append(f"{p.relative_to(ROOT)}:{node.lineno} {node.module} {private}")
    assert not offenders, offenders


def test_a_lesson_imports_and_runs_without_rerun_or_the_app():
    """Every lesson module imports, and a stage runs, with rerun and lessons.app made unimportable."""
    import subprocess
    import sys
    code = r'''
import importlib, importlib.abc, pkgutil, sys, io
class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name.split(".")[0] in ("rerun", "rerun_bindings") or name == "lessons.app" or name.startswith(
                ("lessons.app.", "lessons.tools")):
            raise ImportError(f"blocked for this test: {name}")
sys.meta_path.insert(0, Block())
import lessons
seen = []
for info in pkgutil.walk_packages(lessons.__path__, "lessons."):
    if info.name.startswith(("lessons.app", "lessons.tools")) or info.name == "lessons.__main__":
        continue
    importlib.import_module(info.name)
    seen.append(info.name)
assert len(seen) > 30, seen
import engine.runtime as rt
rt.init()
from lessons._framework import run_lesson
from lessons.rod_waves import LESSON
class Null:
    enabled = False
    def __getattr__(self, name):
        return lambda *a, **k: None
rows = []
assert run_lesson(LESSON, LESSON.config(), Null(), [1], out=io.StringIO(), err=io.StringIO(), quiet=True, results=rows)
assert len(rows) == 4 and not [m for m in sys.modules if m.startswith(("rerun", "lessons.app"))]
print("ok", len(seen))
'''
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert done.returncode == 0 and done.stdout.startswith("ok"), done.stderr[-3000:]


def test_one_newton_loop_in_the_engine():
    """The static solve and the backward-Euler step minimise through engine.newton.minimize: no other
    engine module holds a line search (its constants) or calls a linear solve in a loop of its own."""
    users = sorted(str(p.relative_to(ROOT)) for p in _source_files("engine") if "engine.newton" in _modules(p))
    assert users == ["engine/integrators/implicit.py", "engine/statics.py"], users
    holders = sorted(str(p.relative_to(ROOT)) for p in _source_files("engine")
                     if any(isinstance(n, ast.Assign) and any(getattr(t, "id", "") in ("ARMIJO_C1", "MAX_BACKTRACKS")
                                                             for t in n.targets)
                            for n in ast.walk(ast.parse(p.read_text()))))
    assert holders == ["engine/newton.py"], holders


def test_no_source_module_is_over_500_lines():
    """Modules are split along what they are about before they grow past 500 lines."""
    long = {str(p.relative_to(ROOT)): n for p in _source_files("engine", "lessons", "bench")
            if (n := len(p.read_text().splitlines())) > 500}
    assert not long, long


def test_the_viewer_tools_import_neither_the_app_nor_the_lessons():
    """lessons/tools drives the real viewer; the app's view command and the tests use it, not the other way."""
    offenders = {str(p.relative_to(ROOT)): sorted(m for m in _modules(p) | _dynamic_imports(p)
                                                  if m.startswith("lessons.") and not m.startswith("lessons.tools"))
                 for p in _source_files("lessons/tools")}
    assert not {k: v for k, v in offenders.items() if v}, offenders


def _grouped_by_xdist(config) -> bool:
    """True on a pytest-xdist worker under --dist loadgroup (the flag xdist sets there), where a grouped
    test's id carries its group."""
    return hasattr(config, "workerinput") and bool(config.getvalue("loadgroup"))


def test_a_test_reading_the_default_runs_is_in_their_worker_group(default_runs, request):
    """The test run's split over its two pytest-xdist workers (pyproject.toml: -n 2 --dist loadgroup):
    every test that reads the session's default runs carries the ``default-runs`` group
    (tests/conftest.py) and xdist sends the whole group to one worker, so the six lessons run once per
    test run, not once per worker. xdist reads the group from a suffix it writes into each test's id;
    pytest 9.2 keeps ids where that write no longer lands (pytest-xdist issue 1386), and then nothing
    fails: every lesson simply runs on both workers (~120 s of work twice). This test fails instead.
    Asking for default_runs runs no lesson (it is lazy)."""
    assert request.node.get_closest_marker("xdist_group").args == ("default-runs",)
    if not hasattr(request.config, "workerinput"):
        pytest.skip("not under pytest-xdist: nothing is split")
    if not _grouped_by_xdist(request.config):
        pytest.skip("pytest-xdist runs without --dist loadgroup here")
    assert request.node.nodeid.endswith("@default-runs"), (
        f"{request.node.nodeid}: pytest-xdist did not group it (pytest {pytest.__version__}); the default runs "
        "would be made on both workers - pyproject.toml pins the pytest versions whose ids xdist can group")


def test_the_tests_sharing_a_module_fixture_run_on_one_worker(request):
    """The same split for every module-scoped fixture of a test module (a lesson run again under
    backward Euler, a recording made for the module): a module fixture is made once per worker that
    runs one of its tests, so every test reading it carries one group, shared by all its readers
    (tests/conftest.py), and under --dist loadgroup its id says so. Without it, area-springs' and
    springs' backward-Euler stages were made three times each (the setup of three tests: ~65 s and
    ~27 s of a ~430 s run)."""
    from tests.conftest import shared_work
    items = request.session.items
    groups: dict = {}
    for item in items:
        work = shared_work(item)
        if not work:
            continue
        marker = item.get_closest_marker("xdist_group")
        assert marker is not None, f"{item.nodeid} shares {sorted(work)} but has no worker group"
        for key in work:
            groups.setdefault(key, set()).add(marker.args[0])
        if _grouped_by_xdist(request.config):
            assert item.nodeid.endswith("@" + marker.args[0]), f"{item.nodeid}: not grouped by pytest-xdist"
    split = {key: names for key, names in groups.items() if len(names) > 1}
    assert not split, f"the readers of one fixture are in several groups: {split}"
    if any(i.nodeid.startswith("tests/lessons/test_lesson_area_springs.py") for i in items):
        assert "tests/lessons/test_lesson_area_springs.py::be_stages" in groups
