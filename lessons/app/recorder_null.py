"""The recorder that records nothing: :class:`NullRecorder` has every method of
:class:`lessons.app.recorder.Recorder` (its subclass) and does nothing; ``enabled`` is False so
callers can skip building colours and arrays altogether. It needs no rerun: the grading child and
the tests run lessons with it.
"""
from __future__ import annotations

from ..views import RunView


class NullRecorder:
    """A recorder that records nothing and costs nothing."""

    enabled = False
    path = None

    def __init__(self, *args, **kwargs):
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def stage(self, index: int, title: str, narrative: str) -> None:
        pass

    def run(self, name: str, view: RunView | None = None, n_steps: int | None = None,
            dt: float | None = None, draw_every: int | None = None) -> str:
        return name

    def wants_frame(self, step: int, sim_time: float) -> bool:
        return False

    def frame_spacing(self, n_steps: int) -> int:
        return n_steps or 1

    def colors(self, values, kind: str = "signed", quantity: str = "strain", scale: float | None = None):
        return None

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

    def labels(self, *args, **kwargs) -> None:
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
