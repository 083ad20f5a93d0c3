"""Reading a recording back, without the viewer: :func:`run_status` (the run's completeness, the
recording property ``run`` that :meth:`lessons.app.recorder.Recorder.close` writes) and
:func:`summarize` (per entity path, what was logged and when: for tests and for inspecting a
recording).
"""
from __future__ import annotations

import os


def run_status(path: str | os.PathLike) -> dict | None:
    """The recording property ``run`` written by :meth:`Recorder.close` (complete, exit_reason,
    stages_requested, stages_completed, ...), or None if the file has none."""
    from rerun.chunk import RrdReader

    status = None
    for chunk in RrdReader(str(path)).stream():
        if str(chunk.entity_path) == "/__properties/run":
            for row in chunk.to_record_batch().to_pylist():
                status = {k: (v[0] if isinstance(v, list) and len(v) == 1 and k != "stages_requested"
                              and k != "stages_completed" else v)
                          for k, v in row.items() if not k.startswith("rerun.")}
    return status


def summarize(path: str | os.PathLike) -> dict[str, dict]:
    """Read a recording back: per entity path, its chunk count, row count, whether it has
    static data, and the sorted ``progress`` (and ``step``) values it was logged at. For tests
    and for inspecting a recording without the viewer."""
    from rerun.chunk import RrdReader

    out: dict[str, dict] = {}
    for chunk in RrdReader(str(path)).stream():
        info = out.setdefault(chunk.entity_path, dict(chunks=0, rows=0, static_chunks=0, frames=[], steps=[],
                                                      components=set()))
        batch = chunk.to_record_batch()
        info["chunks"] += 1
        info["rows"] += batch.num_rows
        info["static_chunks"] += int(chunk.is_static)
        info["components"].update(n for n in batch.schema.names if ":" in n)
        if "progress" in batch.schema.names:
            info["frames"].extend(batch.column("progress").to_pylist())
        if "step" in batch.schema.names:
            info["steps"].extend(batch.column("step").to_pylist())
    for info in out.values():
        info["frames"].sort()
        info["steps"].sort()
    return out
