"""The lessons' time budget: a stage's work is estimated before it runs (each lesson knows how its
stages scale with the parameters), a stage over the budget is refused up front with the flags that
set it, and a long stage says how long it will take before it starts.

The estimates are for the reference 2-thread CPU; ``time_text`` writes them for people.

One vocabulary for every lesson: a lesson's ``scene.py`` answers ``stage_seconds(cfg, stage)``, the
seconds stage ``stage`` takes on the reference CPU (however it counts its work inside: steps,
node-steps, launches), and lists ``BUDGET = {stage: StageCost(flags, advice)}``, the parameters that
set each stage's work and what to change. ``check_stages`` refuses a configuration up front from
those two; ``announce`` says before a long stage how long it takes.
"""
import math
from dataclasses import dataclass
from typing import Callable

from engine.errors import ParameterError

WORK_BUDGET_S = 3600.0   # a stage estimated to take longer than this on the reference CPU is refused
ANNOUNCE_S = 30.0        # a stage estimated to take longer than this says so before it starts
REFERENCE_CPU = "the reference 2-thread CPU"


def time_text(seconds: float) -> str:
    """'12 s', '7 min', '1.5 h'; 'forever (...)' for a non-finite estimate (a time step below the
    float range makes a run's step count infinite)."""
    if not math.isfinite(seconds):
        return "forever (its time step is below the float range)"
    if seconds >= 3600:
        return f"{seconds / 3600:.3g} h"
    return f"{seconds / 60:.0f} min" if seconds >= 60 else f"{seconds:.0f} s"


@dataclass(frozen=True)
class StageCost:
    """What sets a stage's work (``flags``: the options, as the user types them) and what to change
    when it is over the budget (``advice``)."""
    flags: str
    advice: str


def check_stages(cfg, stage_seconds: Callable[[object, int], float], budget: dict) -> None:
    """Refuse ``cfg`` when any stage of ``budget`` ({stage: StageCost}) would take more than
    WORK_BUDGET_S by ``stage_seconds(cfg, stage)``."""
    for stage, cost in budget.items():
        refuse_over_budget(stage, stage_seconds(cfg, stage), cost.flags, cost.advice)


def refuse_over_budget(stage: int, seconds: float, flags: str, advice: str) -> None:
    """Raise ParameterError when stage ``stage`` would take more than WORK_BUDGET_S: the message names
    ``flags`` (the parameters that set its work), the estimate, the budget and ``advice``."""
    if seconds > WORK_BUDGET_S:
        raise ParameterError(f"{flags}: stage {stage} would take about {time_text(seconds)} on {REFERENCE_CPU}, "
                             f"over the lesson's budget of {time_text(WORK_BUDGET_S)}; {advice}")


def announce(ctx, seconds: float, bound: bool = False) -> None:
    """Say before a stage starts how long it takes, when that is more than ANNOUNCE_S. ``bound``: the
    estimate counts every run to its planned end (a run may stop early), so it is an upper bound."""
    if seconds > ANNOUNCE_S:
        ctx.progress(f"this stage takes {'up to ' if bound else ''}about {time_text(seconds)} on {REFERENCE_CPU} "
                     "(a progress bar follows each long run on a terminal)")
