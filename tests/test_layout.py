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
