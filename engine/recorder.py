"""Rerun recordings of lesson runs. The only module that imports rerun.

One :class:`Recorder` per lesson run writes one ``.rrd`` file through its own
``rr.RecordingStream`` (never the global stream). The file is written under a temporary
name beside the target and renamed onto the target only by :meth:`Recorder.close`, so a
crash or a kill never leaves a truncated file under the final name.

Timelines:
    ``frame``     the simulation step index, counted across the whole lesson (each run
                  continues where the previous one stopped, so runs follow each other);
    ``sim_time``  simulated seconds since the start of the run (runs overlap here, which
                  lets the viewer compare runs at the same simulated time).

Entity layout (``S`` = ``stage<N>``, ``R`` = run name inside the stage):
    /S/narrative              markdown TextDocument, static
    /S/results                markdown table of the stage's experiments, static
    /S/R/rod/nodes            Points3D, rod nodes at (x_i, 0, 0), coloured by strain
    /S/R/rod/displacement     LineStrips3D, the profile (p, gain*u(p), 0)
    /S/R/springs              LineStrips3D, one strip per spring, coloured by strain
    /S/R/mesh                 Mesh3D; triangles static, positions/colours per frame
    /S/R/energy/{kinetic,potential,total}   Scalars, one row per step (send_columns)

:class:`NullRecorder` has the same methods and does nothing; ``enabled`` is False so
callers can skip building colours and arrays altogether.
"""
from __future__ import annotations

import errno
import os
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

__all__ = ["Recorder", "NullRecorder", "strain_colors", "check_writable"]


def strain_colors(strain: np.ndarray, scale: float | None = None) -> np.ndarray:
    """Map signed strain to RGB (uint8): blue = compressed, white = rest, red = stretched.

    ``scale`` is the strain that saturates the colour (default: max |strain|).
    """
    s = np.asarray(strain, dtype=np.float64)
    if scale is None:
        scale = float(np.max(np.abs(s))) if s.size else 1.0
    t = np.clip(s / (scale if scale > 0 else 1.0), -1.0, 1.0)
    out = np.empty(s.shape + (3,), dtype=np.float64)
    pos, neg = t >= 0, t < 0
    # white -> red for tension, white -> blue for compression
    out[pos] = np.stack([np.ones(pos.sum()), 1 - t[pos], 1 - t[pos]], axis=-1)
    out[neg] = np.stack([1 + t[neg], 1 + t[neg], np.ones(neg.sum())], axis=-1)
    return (out * 255).astype(np.uint8)


def magnitude_colors(value: np.ndarray, scale: float | None = None) -> np.ndarray:
    """Map a non-negative quantity (e.g. energy density) to a dark-blue -> yellow ramp."""
    v = np.asarray(value, dtype=np.float64)
    if scale is None:
        scale = float(np.max(v)) if v.size else 1.0
    t = np.clip(v / (scale if scale > 0 else 1.0), 0.0, 1.0)[..., None]
    lo, hi = np.array([40, 40, 120.0]), np.array([255, 220, 40.0])
    return (lo + t * (hi - lo)).astype(np.uint8)


def check_writable(path: str | os.PathLike) -> Path:
    """Return the resolved path if a file can be created there; raise OSError otherwise.

    Creates missing parent directories (that is what a user asking for
    ``--record out/run.rrd`` wants) but writes nothing else.
    """
    target = Path(path)
    if target.is_dir():
        raise IsADirectoryError(f"{target} is a directory")
    parent = target.parent if str(target.parent) else Path(".")
    missing = []  # directories this call creates, removed again if the path turns out unusable
    p = parent
    while not p.exists() and p != p.parent:
        missing.append(p)
        p = p.parent
    if not p.is_dir():
        raise NotADirectoryError(errno.ENOTDIR, f"{p} is a file, not a directory", str(parent))
    try:
        parent.mkdir(parents=True, exist_ok=True)
        if not os.access(parent, os.W_OK | os.X_OK):
            raise PermissionError(f"directory {parent} is not writable")
        if target.exists() and not os.access(target, os.W_OK):
            raise PermissionError(f"{target} exists and is not writable")
        name_max = os.pathconf(parent, "PC_NAME_MAX")
        if len(os.fsencode(target.name)) > name_max:
            raise OSError(errno.ENAMETOOLONG, os.strerror(errno.ENAMETOOLONG), str(target))
        return target.resolve()
    except OSError:
        for d in missing:  # innermost first
            try:
                d.rmdir()
            except OSError:
                pass
        raise


def lesson_blueprint(stages: list[tuple[int, str]], view: str = "3d") -> rrb.Blueprint:
    """One tab per stage: the scene, the energy plot, the narrative and the results."""
    tabs = []
    for index, title in stages:
        origin = f"/stage{index}"
        scene = (rrb.Spatial2DView if view == "2d" else rrb.Spatial3DView)(
            origin=origin, name=f"{index}. scene")
        tabs.append(
            rrb.Horizontal(
                scene,
                rrb.Vertical(
                    rrb.TimeSeriesView(origin=origin, name="energies"),
                    rrb.TextDocumentView(origin=f"{origin}/results", name="results"),
                    row_shares=[2, 1],
                ),
                rrb.TextDocumentView(origin=f"{origin}/narrative", name="narrative"),
                column_shares=[3, 2, 2],
                name=f"{index}. {title}",
            )
        )
    return rrb.Blueprint(rrb.Tabs(*tabs), collapse_panels=False)


class NullRecorder:
    """A recorder that records nothing and costs nothing."""

    enabled = False
    path = None

    def __init__(self, *args, **kwargs):
        self.frame = 0  # next free step index on the ``frame`` timeline

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def stage(self, index: int, title: str, narrative: str) -> None:
        pass

    def run(self, name: str) -> str:
        return name

    def set_time(self, step: int, sim_time: float) -> None:
        pass

    def points(self, *args, **kwargs) -> None:
        pass

    def rod(self, *args, **kwargs) -> None:
        pass

    def line_strips(self, *args, **kwargs) -> None:
        pass

    def springs(self, *args, **kwargs) -> None:
        pass

    def mesh(self, *args, **kwargs) -> None:
        pass

    def energies(self, *args, **kwargs) -> None:
        pass

    def scalar_series(self, *args, **kwargs) -> None:
        pass

    def markdown(self, *args, **kwargs) -> None:
        pass

    def mark(self, *args, **kwargs) -> None:
        pass

    def close(self, *args, **kwargs) -> None:
        pass


class Recorder(NullRecorder):
    """Writes one lesson's recording to ``path`` (atomically, on :meth:`close`)."""

    enabled = True

    def __init__(self, path: str | os.PathLike, application_id: str,
                 blueprint: rrb.Blueprint | None = None, strict: bool = False):
        super().__init__()
        self.path = check_writable(path)
        self._tmp = self.path.with_name(f".{self.path.name}.partial-{os.getpid()}")
        self._rec = rr.RecordingStream(application_id)
        if strict:
            rr.set_strict_mode(True)
        self._rec.save(str(self._tmp), default_blueprint=blueprint)
        self._prefix = ""
        self._stage = ""
        self._run_start = 0
        self._closed = False
        self._static_done: set[str] = set()

    # --- structure --------------------------------------------------------------
    def stage(self, index: int, title: str, narrative: str) -> None:
        """Start stage ``index``; its narrative goes to /stage<index>/narrative."""
        self._stage = f"stage{index}"
        self._prefix = self._stage
        self.markdown("narrative", f"# {index}. {title}\n\n{narrative}")

    def run(self, name: str) -> str:
        """Start a run inside the current stage; returns its entity prefix.

        The run's first step is the current ``frame``; ``sim_time`` restarts at 0.
        """
        safe = "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in name)
        self._prefix = f"{self._stage}/{safe}" if self._stage else safe
        self._run_start = self.frame
        return self._prefix

    def _path(self, entity: str) -> str:
        return f"/{self._prefix}/{entity}" if self._prefix else f"/{entity}"

    def set_time(self, step: int, sim_time: float) -> None:
        """Set both timelines for the next logged geometry: ``step`` = steps done in this run."""
        frame = self._run_start + int(step)
        self.frame = max(self.frame, frame + 1)
        self._rec.set_time("frame", sequence=frame)
        self._rec.set_time("sim_time", duration=float(sim_time))

    # --- geometry ----------------------------------------------------------------
    def points(self, entity: str, positions, colors=None, radii=None) -> None:
        self._rec.log(self._path(entity), rr.Points3D(np.asarray(positions), colors=colors, radii=radii))

    def rod(self, x: np.ndarray, p: np.ndarray, strain_nodes: np.ndarray | None = None,
            gain: float = 1.0, radius: float = 0.004) -> None:
        """Rod nodes at (x_i, 0, 0) and the displacement profile (p_i, gain*u_i, 0)."""
        n = x.size
        pts = np.zeros((n, 3))
        pts[:, 0] = x
        colors = strain_colors(strain_nodes) if strain_nodes is not None else None
        self._rec.log(self._path("rod/nodes"), rr.Points3D(pts, colors=colors, radii=radius))
        prof = np.zeros((n, 3))
        prof[:, 0] = p
        prof[:, 1] = gain * (x - p)
        self._rec.log(self._path("rod/displacement"), rr.LineStrips3D([prof], colors=[[230, 160, 30]]))

    def line_strips(self, entity: str, strips, colors=None, radii=None) -> None:
        self._rec.log(self._path(entity), rr.LineStrips3D(strips, colors=colors, radii=radii))

    def springs(self, x: np.ndarray, edges: np.ndarray, strain: np.ndarray | None = None,
                entity: str = "springs", scale: float | None = None) -> None:
        """Springs as two-point line strips, coloured by strain."""
        segs = np.stack([x[edges[:, 0]], x[edges[:, 1]]], axis=1)
        colors = strain_colors(strain, scale) if strain is not None else None
        self._rec.log(self._path(entity), rr.LineStrips3D(segs, colors=colors))

    def mesh(self, x: np.ndarray, triangles: np.ndarray, vertex_colors=None, entity: str = "mesh") -> None:
        """Triangle mesh; the index buffer is logged once as static, positions per frame."""
        path = self._path(entity)
        if path not in self._static_done:
            self._rec.log(path, rr.Mesh3D.from_fields(triangle_indices=np.asarray(triangles, dtype=np.uint32)),
                          static=True)
            self._static_done.add(path)
        self._rec.log(path, rr.Mesh3D.from_fields(vertex_positions=np.asarray(x), vertex_colors=vertex_colors))

    # --- scalars and text ---------------------------------------------------------
    def scalar_series(self, entity: str, values: np.ndarray, dt: float, first_step: int = 0,
                      t0: float = 0.0) -> None:
        """One scalar per step, sent as a column (one call for thousands of steps)."""
        values = np.asarray(values, dtype=np.float64)
        if values.size == 0:
            return
        steps = self._run_start + first_step + 1 + np.arange(values.size)  # after step s+1
        self.frame = max(self.frame, int(steps[-1]) + 1)
        times = t0 + dt * (first_step + 1 + np.arange(values.size))
        self._rec.send_columns(
            self._path(entity),
            indexes=[rr.TimeColumn("frame", sequence=steps), rr.TimeColumn("sim_time", duration=times)],
            columns=rr.Scalars.columns(scalars=values),
        )

    def energies(self, kinetic: np.ndarray, potential: np.ndarray, dt: float, first_step: int = 0,
                 t0: float = 0.0) -> None:
        """Kinetic, potential and total energy per step (J)."""
        kinetic = np.asarray(kinetic)
        potential = np.asarray(potential)
        for name, vals in (("kinetic", kinetic), ("potential", potential), ("total", kinetic + potential)):
            self.scalar_series(f"energy/{name}", vals, dt, first_step, t0)

    def markdown(self, entity: str, text: str, static: bool = True) -> None:
        """A markdown TextDocument under the current stage (not the current run)."""
        path = f"/{self._stage}/{entity}" if self._stage else f"/{entity}"
        self._rec.log(path, rr.TextDocument(text, media_type=rr.MediaType.MARKDOWN), static=static)

    def mark(self, text: str, level: str = "WARN") -> None:
        """A time-stamped event at the current run (e.g. 'blew up here')."""
        self._rec.log(self._path("events"), rr.TextLog(text, level=level))

    # --- lifetime -----------------------------------------------------------------
    def close(self, keep: bool = True) -> Path | None:
        """Flush, finish the file and move it onto the final name (or delete it)."""
        if self._closed:
            return self.path if keep else None
        self._closed = True
        try:
            self._rec.flush()
            self._rec.disconnect()
        finally:
            if keep and self._tmp.exists():
                os.replace(self._tmp, self.path)
            elif self._tmp.exists():
                self._tmp.unlink()
        return self.path if keep else None


def summarize(path: str | os.PathLike) -> dict[str, dict]:
    """Read a recording back: per entity path, its chunk count, row count, whether it has
    static data, and the sorted ``frame`` values it was logged at. For tests and for
    inspecting a recording without the viewer."""
    from rerun.chunk import RrdReader

    out: dict[str, dict] = {}
    for chunk in RrdReader(str(path)).stream():
        info = out.setdefault(chunk.entity_path, dict(chunks=0, rows=0, static_chunks=0, frames=[],
                                                      components=set()))
        batch = chunk.to_record_batch()
        info["chunks"] += 1
        info["rows"] += batch.num_rows
        info["static_chunks"] += int(chunk.is_static)
        info["components"].update(n for n in batch.schema.names if ":" in n)
        if "frame" in batch.schema.names:
            info["frames"].extend(batch.column("frame").to_pylist())
    for info in out.values():
        info["frames"].sort()
    return out
