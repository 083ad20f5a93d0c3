"""The energy plots of a recording: the samples of a run's energies, at most ENERGY_SAMPLES per
series and run (the lowest and highest of each bin of steps, so a curve that oscillates faster
than a bin is drawn as its envelope, not aliased), sent in columns. A part of
:class:`lessons.app.recorder.Recorder`, which holds the state these methods use."""
from __future__ import annotations

import math

import numpy as np
import rerun as rr

from .blueprint import PROGRESS_TICKS

ENERGY_SAMPLES = 2000       # energy samples per series and run at most (min and max per bin)
RAW_ENERGY_SAMPLES = 4 * ENERGY_SAMPLES  # samples held before the bin width is fixed
# the energy series: name and colour (the plots name them in their titles, with no legend)
SERIES = {"kinetic": ("kinetic", (90, 200, 90)), "potential": ("potential", (90, 150, 255)),
          "total": ("total", (235, 235, 235)), "relative": ("(E - E1) / |E1|", (255, 190, 60)),
          "log10_distance": ("log10 distance / size", (255, 190, 60)),
          "log10_excess": ("log10 energy above equilibrium / at start", (235, 235, 235))}


class RecorderEnergies:
    """Recorder's energy series (its ``_rec``, ``_run``, ``_path`` and ``_static_done``, and the
    per-run energy state set by ``Recorder._reset_run``)."""

    def _columns(self, steps: np.ndarray):
        dt = self._energy_dt
        run = self._run
        times = dt * steps
        if run is not None and run.span is not None:
            ticks = np.rint(PROGRESS_TICKS * times / run.span).astype(np.int64)
        else:
            ticks = steps
        return [rr.TimeColumn("progress", sequence=ticks), rr.TimeColumn("sim_time", duration=times),
                rr.TimeColumn("step", sequence=steps)]

    def scalar_series(self, entity: str, values: np.ndarray, steps: np.ndarray) -> None:
        """Scalars at the run's ``steps``, sent as one column (styled once: SERIES)."""
        values = np.asarray(values, dtype=np.float64)
        if values.size == 0:
            return
        path = self._path(entity)
        if self._run is not None and not entity.startswith("energy"):
            self._run.has_series = True
        if path not in self._static_done:
            name, color = SERIES.get(entity.rsplit("/", 1)[-1], (entity.rsplit("/", 1)[-1], (200, 200, 200)))
            self._rec.log(path, rr.SeriesLines(colors=[color], names=[name], widths=[1.5],
                                               aggregation_policy="minmax"), static=True)
            self._static_done.add(path)
        self._rec.send_columns(self._path(entity), indexes=self._columns(np.asarray(steps, dtype=np.int64)),
                               columns=rr.Scalars.columns(scalars=values))

    def energies(self, kinetic, potential, dt: float, first_step: int = 0) -> None:
        """Kinetic and potential energy (J) after steps first_step+1, first_step+2, ...; at most
        ENERGY_SAMPLES per series and run are kept (the lowest and highest of each bin)."""
        kinetic = np.asarray(kinetic, dtype=np.float64)
        potential = np.asarray(potential, dtype=np.float64)
        if kinetic.size == 0:
            return
        if not self._energy_dt:
            self._energy_dt = float(dt)
        steps = first_step + 1 + np.arange(kinetic.size)
        self._pending.append((steps, kinetic, potential))
        self._pending_count += kinetic.size
        if self._run is not None:
            self._run.has_energy = True
        # the first RAW_ENERGY_SAMPLES samples are kept as they are, so a run that stops early
        # (a blow-up) is binned by the steps it ran, not by the steps it planned
        if self._energy_width is None and self._pending_count <= RAW_ENERGY_SAMPLES:
            return
        self._flush_energies(final=False)

    def _bin(self, last_step: int) -> int:
        """Steps per bin: from the run's planned steps once it has run long, else from the steps
        it ran (``last_step``)."""
        if self._energy_width is None:
            run = self._run
            planned = run.n_steps if run is not None and run.n_steps else 0
            n = planned if self._pending_count > RAW_ENERGY_SAMPLES else last_step
            self._energy_width = max(1, math.ceil(2 * max(n, last_step) / ENERGY_SAMPLES))
        return self._energy_width

    def _flush_energies(self, final: bool) -> None:
        if not self._pending:
            if final:
                self._send_energies(True)
            return
        steps = np.concatenate([p[0] for p in self._pending])
        K = np.concatenate([p[1] for p in self._pending])
        W = np.concatenate([p[2] for p in self._pending])
        width = self._bin(int(steps[-1]))
        bins = (steps - 1) // width
        if not final:  # keep the last (maybe incomplete) bin for the next call
            done = bins < bins[-1]
            if not done.any():
                self._pending = [(steps, K, W)]
                return
            self._pending = [(steps[~done], K[~done], W[~done])]
            self._pending_count = int((~done).sum())
            steps, K, W, bins = steps[done], K[done], W[done], bins[done]
        else:
            self._pending = []
            self._pending_count = 0
        total = K + W
        if self._energy_first_total is None:
            self._energy_first_total = float(total[0])
        if self._energy_factor is None:   # a unit in which the run's energies read as 1 .. 1000
            self._energy_factor, unit = energy_unit(max(np.abs(K).max(), np.abs(W).max(), np.abs(total).max()))
            if self._run is not None:
                self._run.energy_unit = unit
        f = self._energy_factor
        series = {"energy/kinetic": K / f, "energy/potential": W / f, "energy/total": total / f}
        if self._run is not None and self._run.energy == "drift":
            e0 = self._energy_first_total
            series["energy_change/relative"] = (total - e0) / (abs(e0) if e0 else 1.0)
        for entity, values in series.items():
            keep = _envelope(bins, values) if width > 1 else np.arange(values.size)
            self._outbox.setdefault(entity, []).append((steps[keep], values[keep]))
        self._send_energies(final)

    def _send_energies(self, final: bool) -> None:
        """Send the kept samples in columns of at least 1000 (one chunk each, not one per call)."""
        for entity, parts in list(self._outbox.items()):
            if final or sum(len(p[0]) for p in parts) >= 1000:
                self.scalar_series(entity, np.concatenate([p[1] for p in parts]),
                                   np.concatenate([p[0] for p in parts]))
                del self._outbox[entity]



ENERGY_UNITS = ((1e6, "MJ"), (1e3, "kJ"), (1.0, "J"), (1e-3, "mJ"), (1e-6, "µJ"), (1e-9, "nJ"), (1e-12, "pJ"),
                (1e-15, "fJ"), (1e-18, "aJ"))


def energy_unit(magnitude: float) -> tuple[float, str]:
    """(J per unit, its name) of the largest unit in which ``magnitude`` J is at least 1 (J for 0 or a
    non-finite magnitude): a plot's axis then reads 1 .. 1000, not 0.000 000 000 02."""
    if not (math.isfinite(magnitude) and magnitude > 0):
        return 1.0, "J"
    for factor, name in ENERGY_UNITS:
        if magnitude >= factor:
            return factor, name
    return ENERGY_UNITS[-1]


def _envelope(bins: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Indices of the lowest and highest value in each bin (in time order)."""
    order = np.lexsort((values, bins))
    b = bins[order]
    first = np.r_[True, b[1:] != b[:-1]]
    last = np.r_[b[1:] != b[:-1], True]
    keep = np.union1d(order[first], order[last])
    return keep
