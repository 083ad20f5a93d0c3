# TEMPORARY: the lessons' old import path, until they move to the one runner (removed in the same series).
from engine.integrators.explicit import run_many_steps as run_fused  # noqa: F401
from engine.integrators.kernels import METHODS as _ALL

METHODS = {k: v for k, v in _ALL.items() if k != "backward-euler"}  # the explicit ones the many-steps kernel runs
