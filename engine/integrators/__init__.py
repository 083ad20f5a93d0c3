"""Time integrators picked by name, so lessons, CLI and benchmarks can all say
``--integrator symplectic-euler``.

Every integrator has ``name``, ``implicit`` and ``step(model, state, dt, n_steps=1)``; explicit
ones also ``begin(model, state)`` / ``advance(model, state, dt)`` (used by
:func:`engine.integrators.explicit.run` for per-step blow-up checks).
Further integrators (e.g. backward-euler) join with :func:`register`.
"""
from __future__ import annotations

from engine.integrators.explicit import (BlowUpError, ForwardEuler, SymplecticEuler, VelocityVerlet, run,
                                         stable_dt_estimate)

INTEGRATORS: dict[str, object] = {
    "forward-euler": ForwardEuler(),
    "symplectic-euler": SymplecticEuler(),
    "velocity-verlet": VelocityVerlet(),
}


def register(name: str, integrator) -> None:
    """Add an integrator under ``name`` (must have ``step(model, state, dt, n_steps)``)."""
    if not callable(getattr(integrator, "step", None)):
        raise TypeError(f"integrator {name!r} has no step(model, state, dt, n_steps) method")
    INTEGRATORS[name] = integrator


def names() -> list[str]:
    return list(INTEGRATORS)


def get(name: str):
    """The integrator registered as ``name``; ValueError (one line) listing the valid names."""
    try:
        return INTEGRATORS[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown integrator {name!r}; valid names: {', '.join(INTEGRATORS)}") from None


__all__ = ["INTEGRATORS", "get", "register", "names", "BlowUpError", "run", "stable_dt_estimate"]
