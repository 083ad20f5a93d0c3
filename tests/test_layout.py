"""The layout's promise, checked from the sources: the engine is physics only. No module under
engine/ imports rerun (recordings belong to lessons/app/recorder.py) or any lesson module; rerun
is imported by the recorder and the blueprint it sends (lessons/app/) alone, besides the viewer
tools that open recordings (lessons/tools/); and the lessons never import those tools."""
import ast
from pathlib import Path

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
    # the recorder, in parts: its geometry and energy plots, and the blueprint (layout) it sends;
    # lessons/tools/viewer_processes.py drives the real viewer (headless screenshots), it writes
    # no recording
    assert users == ["lessons/app/blueprint.py", "lessons/app/recorder.py", "lessons/app/recorder_energies.py",
                     "lessons/app/recorder_geometry.py", "lessons/tools/viewer_processes.py"], users


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
