"""The results file of a lesson run (``--results PATH``) and how to read it back.

The file is one JSON object::

    {"format": "elastic-lessons-results", "format_version": 2,
     "complete": true,                      # every stage asked ran to its end
     "exit_code": 0, "exit_reason": "completed",
     "lessons": ["springs"], "stages_requested": {"springs": [1, 2]}, "stages_completed": {...},
     "parameters": {"springs": {...every config field...}}, "stepping": {...},
     "runtime": {"arch": "cpu", "backend": "x64", "precision": "f64", "threads": 2, ...},
     "version": "0.1.0", "command": [...], "started": "...Z", "finished": "...Z", "elapsed_s": 1.2,
     "passed": 9, "failed": 0,
     "experiments": [{lesson, stage, stage_title, id, claim, theory, measured, tolerance,
                      comparison, unit, passed, integrators}, ...]}

A run that did not complete (interrupted, stopped at ``--pause``, an internal error, a
recording that could not be written) says so (``complete`` false, ``exit_reason``) and is written
to ``<stem>.partial.json`` instead of the final name unless ``--overwrite-partial``
(:mod:`lessons.app.outfile`). Files written before this format (a bare list of rows) are still read by
:func:`read_results` / :func:`result_rows`.
"""
from __future__ import annotations

import json
import math
import os
from pathlib import Path

FORMAT = "elastic-lessons-results"
FORMAT_VERSION = 2


def package_version() -> str:
    try:
        from importlib.metadata import version
        return version("elastic-lessons")
    except Exception:  # not installed (run from a checkout): the version in pyproject.toml
        import re
        text = (Path(__file__).resolve().parents[2] / "pyproject.toml").read_text(encoding="utf-8")
        m = re.search(r'^version\s*=\s*"([^"]+)"', text, re.MULTILINE)
        return m[1] if m else "unknown"


def results_document(rows: list[dict], **meta) -> dict:
    """The results object: ``meta`` (complete, exit_code, exit_reason, lessons, ...) and the rows."""
    n_fail = sum(not r.get("passed") for r in rows)
    doc = {"format": FORMAT, "format_version": FORMAT_VERSION}
    doc.update(meta)
    doc.update(passed=len(rows) - n_fail, failed=n_fail, experiments=list(rows))
    return doc


def _finite(value):
    """JSON has no inf or nan: they are written as null (the rows' theory and measured already are)."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    return value


def encode(doc: dict) -> bytes:
    """The file's bytes: strict JSON (readable by any JSON reader, jq included)."""
    return (json.dumps(_finite(doc), indent=1, allow_nan=False) + "\n").encode("utf-8")


def read_results(source) -> dict:
    """A results file (path) or its parsed JSON as the results object; an old-style file (a bare
    list of rows) comes back as ``{"experiments": rows, "complete": None}`` (unknown)."""
    data = source
    if isinstance(source, (str, os.PathLike)):
        data = json.loads(Path(source).read_text(encoding="utf-8"))
    if isinstance(data, list):
        return {"format": FORMAT, "format_version": 1, "complete": None, "experiments": data}
    if isinstance(data, dict) and isinstance(data.get("experiments"), list):
        return data
    raise ValueError("not a results file: expected a JSON object with 'experiments' (or a list of rows)")


def result_rows(source) -> list[dict]:
    """The experiment rows of a results file, whichever format (path, parsed object or list)."""
    return read_results(source)["experiments"]
