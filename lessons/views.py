"""What a lesson says about how its runs are shown, as plain data: the app (lessons/app: the
recorder and the blueprint it sends) turns it into a Rerun recording and its layout. Nothing here
imports rerun or the app, so a lesson can be imported, run and tested without either."""
from __future__ import annotations

from dataclasses import dataclass

CAMERAS = ("top", "front", "outside")   # from above (rods, flat sheets); along +y (a hanging cloth); oblique
ENERGY_PLOTS = ("split", "drift", None)


@dataclass
class RunView:
    """How a run is shown: its view's ``label``, the ``camera`` (one of CAMERAS; default: the
    lesson's), what its energy plot shows (``"split"``: kinetic, potential and total; ``"drift"``:
    the relative change of the total, for runs about conservation; None: no plot) and its ``span``
    on the progress timeline in simulated seconds (default: the run's planned duration; give the
    stage's longest run's to keep runs of different lengths in step). ``plot`` (entity, title): a plot
    of the run's own series under ``<run>/<entity>`` (logged with the recorder's scalar_series) in
    place of the energy plot."""

    label: str | None = None
    camera: str | None = None
    energy: str | None = "split"
    span: float | None = None
    plot: tuple[str, str] | None = None

    def __post_init__(self):
        if self.camera is not None and self.camera not in CAMERAS:
            raise ValueError(f"camera must be one of {CAMERAS} (got {self.camera!r})")
        if self.energy not in ENERGY_PLOTS:
            raise ValueError(f"energy must be 'split', 'drift' or None (got {self.energy!r})")
