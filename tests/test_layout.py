"""The layout's promise, checked from the sources: the engine is physics only. No module under
engine/ imports rerun (recordings belong to lessons/recorder.py) or any lesson module, and rerun is
imported by lessons/recorder.py alone (besides the viewer tools that open recordings)."""
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


def test_the_engine_imports_neither_rerun_nor_lessons():
    offenders = {str(p.relative_to(ROOT)): sorted(_imports(p) & {"rerun", "rerun_cli", "lessons", "bench"})
                 for p in sorted((ROOT / "engine").rglob("*.py"))}
    offenders = {k: v for k, v in offenders.items() if v}
    assert not offenders, f"engine modules importing rerun or lessons/bench: {offenders}"
    assert sum(1 for _ in (ROOT / "engine").rglob("*.py")) > 20   # the scan saw the engine


def test_rerun_is_imported_by_the_recorder_alone():
    users = sorted(str(p.relative_to(ROOT)) for p in sorted((ROOT / "lessons").rglob("*.py"))
                   if "rerun" in _imports(p))
    # lessons/viewer.py drives the real viewer (headless screenshots), it writes no recording
    assert users == ["lessons/recorder.py", "lessons/viewer.py"], users
