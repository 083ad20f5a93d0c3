"""Exceptions shared by the engine, the lessons and the benchmarks.

Each carries a one-line, user-facing message: what went wrong, the value, what to do.
"""


class ParameterError(ValueError):
    """A parameter outside its valid range. Message names the parameter, value and range."""


class ModelError(ValueError):
    """Invalid model input (mesh, energy or pins); the message is one line and names the offending element."""


class BlowUpError(RuntimeError):
    """A simulation left its stable regime; raised at the step it was detected (the one class for
    every integrator and runner; built by :class:`engine.integrators.monitor.Monitor`).

    Attributes: ``step`` (0-based index of the step after which the state was found bad, counted
    from the start of the run), ``time`` (s), ``energy`` (total energy at that step, J; may be inf
    or nan), ``dt`` (s), ``dt_stable`` (the CFL estimate of the largest stable dt, s, or None),
    ``integrator`` (its name), ``cause`` (the likely cause in words), and ``kinetic`` /
    ``potential`` (per-step energies up to the bad step, where the runner recorded them).
    """

    def __init__(self, message: str, *, step: int, energy: float, time: float = float("nan"),
                 dt: float = float("nan"), dt_stable: float | None = None, integrator: str = "", cause: str = ""):
        super().__init__(message)
        self.step = int(step)
        self.energy = float(energy)
        self.time = float(time)
        self.dt = float(dt)
        self.dt_stable = dt_stable
        self.integrator = integrator
        self.cause = cause
        self.kinetic = None
        self.potential = None
