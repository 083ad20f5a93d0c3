"""Exceptions shared by the engine, the lessons and the benchmarks.

Each carries a one-line, user-facing message: what went wrong, the value, what to do.
"""


class ParameterError(ValueError):
    """A parameter outside its valid range. Message names the parameter, value and range."""


class ModelError(ValueError):
    """Invalid model input (mesh, energy or pins); the message is one line and names the offending element."""


class BlowUpError(RuntimeError):
    """A simulation left its stable regime; raised at the step it was detected.

    Attributes: ``step`` (index of the step after which the state was found bad, counted
    from the start of the run that raised), ``energy`` (total energy at that step, may be
    inf or nan), ``cause`` (the likely cause in words), ``stable_dt`` (for explicit
    integrators, an estimate of the largest stable time step, or None).
    """

    def __init__(self, step: int, energy: float, cause: str, stable_dt: float | None = None):
        self.step = int(step)
        self.energy = float(energy)
        self.cause = cause
        self.stable_dt = stable_dt
        msg = f"simulation blew up at step {self.step} (total energy {self.energy:.6g}): {cause}"
        if stable_dt is not None:
            msg += f"; use dt <= {stable_dt:.6g} s"
        super().__init__(msg)
