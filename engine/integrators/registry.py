"""The integrators by name, so lessons, CLI and benchmarks can all say ``--integrator symplectic-euler``.

:data:`INTEGRATORS` holds one integrator under each of engine.constants.INTEGRATOR_NAMES (the
one list of the names: the CLI's choices are read from it); :data:`EXPLICIT` those that are explicit. ``backward-euler`` (default linear solver PCG)
is registered here; :func:`make_integrator` gives one with other options (``--solver``, ``--tol``,
Newton iterations). Further integrators join with :func:`register`.
"""
from __future__ import annotations

from engine.integrators.explicit import ForwardEuler, SymplecticEuler, VelocityVerlet
from engine.integrators.implicit import BackwardEuler
from engine.constants import EXPLICIT, INTEGRATOR_NAMES

INTEGRATORS: dict[str, object] = {i.name: i for i in (
    ForwardEuler(), SymplecticEuler(), VelocityVerlet(),
    BackwardEuler(),  # PCG, tol 1e-8, one Newton (Baraff-Witkin) iteration
)}
assert tuple(INTEGRATORS) == INTEGRATOR_NAMES and tuple(n for n, i in INTEGRATORS.items() if not i.implicit) == EXPLICIT


def register(name: str, integrator) -> None:
    """Add an integrator under ``name`` (it needs ``begin(ctx, state)`` and ``advance(ctx, state, dt)``,
    handed a StepContext; see :class:`engine.integrators.stepper.Stepper`; it keeps nothing between
    steps, since the registered instance serves every stepper)."""
    for method in ("begin", "advance"):
        if not callable(getattr(integrator, method, None)):
            raise TypeError(f"integrator {name!r} has no {method}(ctx, state, ...) method")
    INTEGRATORS[name] = integrator


def names() -> list[str]:
    return list(INTEGRATORS)


def get(name: str):
    """The integrator registered as ``name``; ValueError (one line) listing the valid names."""
    try:
        return INTEGRATORS[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown integrator {name!r}; valid names: {', '.join(INTEGRATORS)}") from None


def make_integrator(name: str, solver: str | None = None, tol: float | None = None,
                    newton_iterations: int | None = None, **options):
    """An integrator for ``name`` with options (for ``--integrator/--solver/--tol``).

    "backward-euler": a new :class:`BackwardEuler` (solver one of engine.solvers.SOLVERS, default pcg;
    tol default 1e-8; newton_iterations default 1; further keyword options such as newton_tol,
    line_search, rayleigh_alpha, rayleigh_beta, max_iter are passed on).
    Explicit names: the registered instance; the implicit-only options are ignored.
    ValueError (one line, listing the valid names) for an unknown name."""
    if name == "backward-euler":
        kw = dict(options)
        if solver is not None:
            kw["solver"] = solver
        if tol is not None:
            kw["tol"] = tol
        if newton_iterations is not None:
            kw["newton_iterations"] = newton_iterations
        return BackwardEuler(**kw)
    return get(name)
