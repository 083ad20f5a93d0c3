"""The one watcher of a run: its energy bound, the blow-up at the step it happens, and the message.

Every integrator and runner reports a diverging run the same way: the run stops at the first
checked step whose total energy is not finite or exceeds the bound, and :class:`Monitor` builds the
one :class:`engine.errors.BlowUpError` naming that step, the time, the energy, dt against the CFL
estimate and the likely cause. A linear solve of an implicit step that fails is reported through
the same class, naming the solver.

Many-steps kernels take :attr:`Monitor.bound` as an argument and stop themselves at the bad step;
the run loop (engine.integrators.loop) tests Python-driven steps with :meth:`Monitor.exceeded`.
"""
from __future__ import annotations

import math

import numpy as np

from engine.errors import BlowUpError

def exceeded(E: float, bound: float = math.inf) -> bool:
    """True when a total energy marks a blow-up: not finite (nan or +-inf, bound or not) or above ``bound``."""
    return not math.isfinite(E) or E > bound


def blowup_cause(integrator: str, dt: float, dt_stable: float | None) -> str:
    """The likely cause of a blow-up of ``integrator`` at step ``dt`` (one clause, what to do next)."""
    if integrator == "forward-euler":
        return ("forward Euler adds energy to every undamped oscillation at any dt (it is unstable "
                "for springs); use symplectic-euler, velocity-verlet or backward-euler")
    if integrator == "backward-euler":
        return ("backward Euler damps every mode at any dt, so energy came in from outside or a Newton "
                "step did not converge (raise --newton-iterations or lower dt)")
    ds = dt_stable if dt_stable is not None else math.inf
    ratio = dt / ds if math.isfinite(ds) and ds > 0 else 0.0
    if ratio > 1.0:
        return (f"dt is {ratio:.2f}x the CFL limit: explicit steps must not outrun the fastest mode "
                f"(dt <= 2/w_max); reduce dt below {ds:.3g} s or use backward-euler")
    return ("dt is below the rest-state CFL limit, so large deformation or compression probably "
            "raised the stiffness (or an external input injected energy); reduce dt or use backward-euler")


class Monitor:
    """Watches one run of ``integrator`` (a name) at step ``dt``.

    ``energy_bound`` (J) or None (then only a non-finite energy is a blow-up); ``dt_stable``: the CFL
    estimate, a number or a callable evaluated only when a blow-up is reported (default: the model's
    Gershgorin bound, or power iteration for energies without one). Steps are counted from the start
    of the run (a run continued in chunks passes the steps already done)."""

    def __init__(self, integrator: str, dt: float, energy_bound: float | None = None, model=None,
                 dt_stable=None):
        if energy_bound is not None and math.isnan(float(energy_bound)):
            raise ValueError("energy_bound must be a number or None (got nan)")
        self.integrator = integrator
        self.dt = float(dt)
        self.energy_bound = None if energy_bound is None else float(energy_bound)
        self.model = model
        self._dt_stable = dt_stable

    @property
    def bound(self) -> float:
        """The bound as a number for kernels: the largest finite number of the runtime's precision
        when there is none (or a larger one), so that a kernel's ``not (E <= bound)`` also stops
        at an energy that overflowed to +inf (a comparison with inf lets +inf through, and
        Taichi folds an explicit nan test away)."""
        from engine.fields import float_dtype
        largest = float(np.finfo(float_dtype()).max)
        return largest if self.energy_bound is None else min(self.energy_bound, largest)

    def dt_stable(self) -> float | None:
        d = self._dt_stable
        if callable(d):
            d = d()
        elif d is None and self.model is not None:
            from engine.stability import best_stable_dt
            d = best_stable_dt(self.model)
        return d

    def exceeded(self, E: float) -> bool:
        return exceeded(E, self.bound)

    def blow_up(self, step: int, t: float, E: float, kinetic=None, potential=None) -> BlowUpError:
        """The error for a blow-up detected after ``step`` (0-based, from the start of the run)."""
        step = int(step)
        dts = self.dt_stable()
        what = "is not finite" if not math.isfinite(E) else f"exceeds the bound {self.bound:.4g} J"
        cause = blowup_cause(self.integrator, self.dt, dts)
        dts_text = f"{dts:.3g} s" if dts is not None else "none (implicit)"
        msg = (f"{self.integrator} blew up at step {step} (t={t:.4g} s): total energy {E:.4g} J {what}; "
               f"dt={self.dt:.3g} s vs CFL estimate dt_stable={dts_text}; likely cause: {cause}")
        exc = BlowUpError(msg, step=step, energy=E, time=t, dt=self.dt, dt_stable=dts, integrator=self.integrator,
                          cause=cause)
        exc.kinetic, exc.potential = kinetic, potential
        return exc

    def solver_failure(self, step: int, t: float, E: float, err: Exception) -> BlowUpError:
        """The error for an implicit step whose linear solve failed after ``step`` good steps."""
        step = int(step)
        cause = ("the linear solver did not converge (raise --tol, allow more iterations, or use "
                 "--solver cholesky)")
        msg = (f"{self.integrator} failed at step {step} (t={t:.4g} s, total energy {E:.4g} J at the last "
               f"good step): {err}; likely cause: {cause}")
        return BlowUpError(msg, step=step, energy=E, time=t, dt=self.dt, dt_stable=math.inf,
                           integrator=self.integrator, cause=cause)
