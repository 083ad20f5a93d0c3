"""The geometry a recording draws: colours on a run's fixed scales, points, labels, a rod, line
strips, springs and meshes. A part of :class:`lessons.app.recorder.Recorder`, which holds the
state these methods use."""
from __future__ import annotations

import numpy as np
import rerun as rr


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



class RecorderGeometry:
    """Recorder's colours and geometry (its ``_rec``, ``_run``, ``_path``, ``_drew`` and
    ``_static_done``)."""

    # --- colours ----------------------------------------------------------------
    def colors(self, values, kind: str = "signed", quantity: str = "strain", scale: float | None = None):
        """Colours of ``values`` on the run's fixed scale for ``quantity``: ``scale`` if given,
        else the largest |value| the first time the run shows a non-zero value. ``kind``
        "signed": blue (-scale) / white (0) / red (+scale); "magnitude": dark blue (0) to yellow
        (scale). The scale goes into the run's view name as the colour key."""
        v = np.asarray(values, dtype=np.float64)
        run = self._run
        fixed = run.scales.get(quantity) if run is not None else None
        if fixed is None:
            fixed = scale if scale is not None else (float(np.max(np.abs(v))) if v.size else 0.0)
            if run is not None and fixed > 0:
                run.scales[quantity] = fixed
                run.keys[quantity] = (f"{quantity}: blue −{fixed:.2g} · white 0 · red +{fixed:.2g}"
                                      if kind == "signed" else f"{quantity}: blue 0 → yellow {fixed:.2g}")
        scale_ = fixed if fixed and fixed > 0 else 1.0
        return strain_colors(v, scale_) if kind == "signed" else magnitude_colors(v, scale_)

    # --- geometry ----------------------------------------------------------------
    def points(self, entity: str, positions, colors=None, radii=None, labels=None) -> None:
        pts = np.asarray(positions)
        self._drew(pts, colors)
        self._rec.log(self._path(entity), rr.Points3D(pts, colors=colors, radii=radii, labels=labels))

    def labels(self, entity: str, positions, texts, colors=None) -> None:
        """Text labels at points (e.g. the name of each of several bodies drawn side by side)."""
        pts = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
        self._drew(pts, frame=False)  # framed by the camera, but static: not a frame of the run
        self._rec.log(self._path(entity), rr.Points3D(pts, labels=list(texts), radii=0.0,
                                                      colors=colors if colors is not None else [[230, 230, 230]]),
                      static=True)

    def rod(self, x: np.ndarray, p: np.ndarray, strain_nodes: np.ndarray | None = None,
            gain: float = 1.0, radius: float = 0.004, scale: float | None = None) -> None:
        """Rod nodes at (p_i, 0, 0) (static) coloured by strain on the run's fixed scale, and the
        displacement profile (p_i, gain*u_i, 0) drawn above them."""
        n = x.size
        pts = np.zeros((n, 3))
        pts[:, 0] = p
        colors = self.colors(strain_nodes, "signed", "strain", scale) if strain_nodes is not None else None
        nodes = self._path("rod/nodes")
        if nodes not in self._static_done:  # the nodes stay where they are drawn: only their colours change
            self._rec.log(nodes, rr.Points3D(pts, radii=radius), static=True)
            self._static_done.add(nodes)
        self._drew(pts[[0, -1]], colors)
        if colors is not None:
            self._rec.log(nodes, rr.Points3D.from_fields(colors=colors))
        prof = np.zeros((n, 3))
        prof[:, 0] = p
        prof[:, 1] = gain * (x - p)
        prof = prof[_corners(prof[:, 0], prof[:, 1])]  # drawn the same, smaller
        self._drew(prof)
        self._rec.log(self._path("rod/displacement"),
                      rr.LineStrips3D([prof], colors=[[230, 160, 30]], radii=radius * 0.6))

    def line_strips(self, entity: str, strips, colors=None, radii=None) -> None:
        pts = np.concatenate([np.asarray(s, dtype=np.float64).reshape(-1, 3) for s in strips]) if len(strips) else np.zeros((0, 3))
        self._drew(pts, colors)
        self._rec.log(self._path(entity), rr.LineStrips3D(strips, colors=colors, radii=radii))

    def springs(self, x: np.ndarray, edges: np.ndarray, strain: np.ndarray | None = None,
                entity: str = "springs", scale: float | None = None, radii=None) -> None:
        """Springs as two-point line strips, coloured by strain on the run's fixed scale."""
        segs = np.stack([x[edges[:, 0]], x[edges[:, 1]]], axis=1)
        colors = self.colors(strain, "signed", "strain", scale) if strain is not None else None
        self._drew(segs.reshape(-1, 3), colors)
        self._rec.log(self._path(entity), rr.LineStrips3D(segs, colors=colors, radii=radii))

    def mesh(self, x: np.ndarray, triangles: np.ndarray, vertex_colors=None, entity: str = "mesh") -> None:
        """Triangle mesh; the index buffer is logged once as static, positions per frame."""
        path = self._path(entity)
        if path not in self._static_done:
            self._rec.log(path, rr.Mesh3D.from_fields(triangle_indices=np.asarray(triangles, dtype=np.uint32)),
                          static=True)
            self._static_done.add(path)
        self._drew(np.asarray(x), vertex_colors)
        self._rec.log(path, rr.Mesh3D.from_fields(vertex_positions=np.asarray(x), vertex_colors=vertex_colors))



def _corners(px: np.ndarray, py: np.ndarray, tol: float = 1e-4) -> np.ndarray:
    """Indices of the points of the polyline (px, py) to draw: all but the inner points of
    stretches at rest (|py| below ``tol`` times the curve's height at the point and both its
    neighbours), so a rod at rest ahead of and behind a pulse is drawn by its ends alone."""
    n = px.size
    if n < 3:
        return np.arange(n)
    height = float(np.max(np.abs(py))) or 1.0
    flat = np.abs(py) <= tol * height
    inner = np.r_[False, flat[:-2] & flat[1:-1] & flat[2:], False]
    return np.flatnonzero(~inner)

