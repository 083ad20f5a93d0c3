"""Time integrators picked by name, so lessons, CLI and benchmarks can all say
``--integrator symplectic-euler``.

Every integrator has ``name``, ``implicit``, ``step(model, state, dt, n_steps=1)`` and
``begin(model, state)`` / ``advance(model, state, dt)`` (one step), which the one run loop
(:mod:`engine.integrators.loop`) drives, watching energies and blow-ups with its Monitor. Further integrators join with :func:`register`.
``backward-euler`` (:mod:`engine.integrators.implicit`, default linear solver PCG) is registered
here; use :func:`make_integrator` to get one with other options (``--solver``, ``--tol``, Newton
iterations). :data:`METHODS` is the one table of method codes the many-steps kernels use.
"""
from __future__ import annotations

from engine.errors import BlowUpError
from engine.integrators.explicit import ForwardEuler, SymplecticEuler, VelocityVerlet, run
from engine.integrators.implicit import BackwardEuler
from engine.integrators.kernels import METHODS
from engine.integrators.monitor import Monitor
from engine.linalg import SOLVERS, SolverError
from engine.stability import stable_dt_estimate

INTEGRATORS: dict[str, object] = {
    "forward-euler": ForwardEuler(),
    "symplectic-euler": SymplecticEuler(),
    "velocity-verlet": VelocityVerlet(),
    "backward-euler": BackwardEuler(),  # PCG, tol 1e-8, one Newton (Baraff-Witkin) iteration
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


def make_integrator(name: str, solver: str | None = None, tol: float | None = None,
                    newton_iterations: int | None = None, **options):
    """An integrator for ``name`` with options (for ``--integrator/--solver/--tol``).

    "backward-euler": a new :class:`BackwardEuler` (solver "pcg" | "cholesky" | "pardiso" | "direct", default pcg; tol
    default 1e-8; newton_iterations default 1; further keyword options such as newton_tol,
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


__all__ = ["INTEGRATORS", "METHODS", "get", "register", "names", "make_integrator", "BackwardEuler", "SOLVERS",
           "SolverError", "BlowUpError", "Monitor", "run", "stable_dt_estimate"]
