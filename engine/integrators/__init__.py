"""Time integrators and the one stepping path.

An integrator is a method: ``name``, ``implicit``, ``begin(stepper, state)`` and
``advance(stepper, state, dt)`` (one step); :class:`engine.integrators.stepper.Stepper`
``(model, integrator)`` plans which kernels its steps launch on a model and owns their work arrays;
the run loop (:mod:`engine.integrators.loop`) drives a stepper in chunks, watching energies and
blow-ups with its Monitor. The integrators by name are in :mod:`engine.integrators.registry`
(``backward-euler``: default linear solver PCG; :func:`make_integrator` for other options).
:data:`METHODS` is the one table of method codes the many-steps kernels use.
"""
from __future__ import annotations

from engine.errors import BlowUpError
from engine.integrators.explicit import ForwardEuler, SymplecticEuler, VelocityVerlet
from engine.integrators.implicit import BackwardEuler
from engine.integrators.kernels import METHODS
from engine.integrators.monitor import Monitor
from engine.integrators.registry import EXPLICIT, INTEGRATORS, get, make_integrator, names, register
from engine.integrators.stepper import Stepper, run
from engine.solvers import SOLVERS, SolverError
from engine.stability import stable_dt_estimate

__all__ = ["INTEGRATORS", "EXPLICIT", "METHODS", "get", "register", "names", "make_integrator", "Stepper",
           "BackwardEuler", "ForwardEuler", "SymplecticEuler", "VelocityVerlet", "SOLVERS", "SolverError",
           "BlowUpError", "Monitor", "run", "stable_dt_estimate"]
