"""What a lesson is, how its experiments are judged, and how a lesson run is driven.

A lesson is a scene with a typed configuration (a dataclass whose fields carry help text,
SI unit and valid range in their metadata; the CLI is derived from it) and a sequence of
stages. A stage narrates one idea, runs simulations through the engine, and returns
experiments: a claim, the theory's value, the measured value and a tolerance.
"""
from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import os
import sys
import textwrap
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from engine.errors import BlowUpError, ParameterError

COMPARISONS = ("rel", "abs", "<=", ">=")


# --------------------------------------------------------------------------- config

def param(default, help: str, unit: str = "", *, gt=None, ge=None, lt=None, le=None, choices=None):
    """A config field with its help text, unit and valid range (checked before any kernel)."""
    return field(default=default, metadata=dict(help=help, unit=unit, gt=gt, ge=ge, lt=lt, le=le,
                                                choices=tuple(choices) if choices else None))


def _field_type(f: dataclasses.Field) -> type:
    t = f.type if isinstance(f.type, str) else getattr(f.type, "__name__", str(f.type))
    return {"float": float, "int": int, "str": str, "bool": bool}[t]


def range_text(meta: dict) -> str:
    """Human-readable valid range of a field, e.g. '> 0', 'in [3, 100000]'."""
    if meta.get("choices"):
        return "one of " + ", ".join(map(str, meta["choices"]))
    lo = ("> %s" % meta["gt"]) if meta.get("gt") is not None else ("≥ %s" % meta["ge"]) if meta.get("ge") is not None else None
    hi = ("< %s" % meta["lt"]) if meta.get("lt") is not None else ("≤ %s" % meta["le"]) if meta.get("le") is not None else None
    if lo and hi:
        return f"{lo} and {hi}"
    return lo or hi or "any value"


def validate_config(cfg) -> None:
    """Raise ParameterError naming the first field outside its range (then cfg.validate())."""
    for f in dataclasses.fields(cfg):
        meta, value = f.metadata, getattr(cfg, f.name)
        if not meta:
            continue
        flag = "--" + f.name.replace("_", "-")
        kind = _field_type(f)
        if meta.get("choices"):
            if value not in meta["choices"]:
                raise ParameterError(f"{flag} must be {range_text(meta)} (got {value!r})")
            continue
        if kind in (int, float):
            if isinstance(value, float) and not math.isfinite(value):
                raise ParameterError(f"{flag} must be a finite number {range_text(meta)} (got {value!r})")
            ok = ((meta.get("gt") is None or value > meta["gt"]) and (meta.get("ge") is None or value >= meta["ge"])
                  and (meta.get("lt") is None or value < meta["lt"]) and (meta.get("le") is None or value <= meta["le"]))
            if not ok:
                raise ParameterError(f"{flag} must be {range_text(meta)} (got {value!r})")
    extra = getattr(cfg, "validate", None)
    if callable(extra):
        extra()


# ----------------------------------------------------------------------- experiments

@dataclass
class Experiment:
    """One measured claim. ``compare``: 'rel' |m-t| <= tol |t|; 'abs' |m-t| <= tol;
    '<=' m <= t (t is a bound); '>=' m >= t."""

    claim: str
    theory: float
    measured: float
    tolerance: float = 0.0
    compare: str = "rel"
    unit: str = ""

    def __post_init__(self):
        if self.compare not in COMPARISONS:
            raise ValueError(f"compare must be one of {COMPARISONS}")
        self.theory = float(self.theory)
        self.measured = float(self.measured)
        self.tolerance = float(self.tolerance)

    @property
    def passed(self) -> bool:
        t, m, tol = self.theory, self.measured, self.tolerance
        if not (math.isfinite(m) and math.isfinite(t)):
            return False
        if self.compare == "rel":
            return abs(m - t) <= tol * abs(t)
        if self.compare == "abs":
            return abs(m - t) <= tol
        if self.compare == "<=":
            return m <= t
        return m >= t

    @property
    def error(self) -> float:
        """The measured deviation in the units of the tolerance (relative or absolute)."""
        if self.compare == "rel":
            return abs(self.measured - self.theory) / abs(self.theory) if self.theory else math.inf
        return abs(self.measured - self.theory)

    def tolerance_text(self) -> str:
        if self.compare == "rel":
            return f"±{self.tolerance:.3g} rel"
        if self.compare == "abs":
            return f"±{self.tolerance:.3g}"
        return "upper bound" if self.compare == "<=" else "lower bound"

    def to_dict(self, lesson: str, stage: int, stage_title: str = "") -> dict:
        def num(v):
            return v if math.isfinite(v) else None
        return dict(lesson=lesson, stage=stage, stage_title=stage_title, claim=self.claim,
                    theory=num(self.theory), measured=num(self.measured), tolerance=self.tolerance,
                    comparison=self.compare, unit=self.unit, passed=self.passed)


def _fmt(v: float) -> str:
    return f"{v:.6g}" if math.isfinite(v) else str(v)


def _rows(experiments: list[Experiment]) -> list[list[str]]:
    return [[e.claim, _fmt(e.theory) + (f" {e.unit}" if e.unit else ""), _fmt(e.measured),
             ("≤ " if e.compare == "<=" else "≥ " if e.compare == ">=" else "") + e.tolerance_text()
             if e.compare in ("rel", "abs") else e.tolerance_text(),
             "PASS" if e.passed else "FAIL"] for e in experiments]


HEADER = ["claim", "theory", "measured", "tolerance", "result"]


def text_table(experiments: list[Experiment], width: int = 60) -> str:
    rows = _rows(experiments)
    rows = [[textwrap.shorten(r[0], width, placeholder="…")] + r[1:] for r in rows]
    widths = [max(len(h), *(len(r[i]) for r in rows)) if rows else len(h) for i, h in enumerate(HEADER)]
    line = lambda cells: "  ".join(c.ljust(w) for c, w in zip(cells, widths)).rstrip()
    out = [line(HEADER), line(["-" * w for w in widths])]
    out += [line(r) for r in rows]
    return "\n".join(out)


def markdown_table(experiments: list[Experiment]) -> str:
    rows = _rows(experiments)
    out = ["| " + " | ".join(HEADER) + " |", "|" + "---|" * len(HEADER)]
    out += ["| " + " | ".join(c.replace("|", "\\|") for c in r) + " |" for r in rows]
    return "\n".join(out)


# ---------------------------------------------------------------------------- lessons

@dataclass
class Stage:
    title: str
    narrative: str
    run: Callable[["StageContext"], list[Experiment]]


@dataclass
class Lesson:
    id: str
    title: str
    summary: str
    config: type
    stages: list[Stage]
    order: int = 100
    view: str = "3d"
    validate: Callable[[Any], None] | None = None  # extra up-front checks (e.g. build meshes)


class StageContext:
    """What a stage sees: its lesson, config, recorder, and progress reporting."""

    def __init__(self, lesson: Lesson, cfg, rec, index: int, stream=sys.stderr, quiet: bool = False):
        self.lesson, self.cfg, self.rec, self.index = lesson, cfg, rec, index
        self._stream, self._quiet = stream, quiet

    def progress(self, message: str) -> None:
        if not self._quiet:
            print(f"    {message}", file=self._stream, flush=True)

    @contextlib.contextmanager
    def timed(self, label: str, n_steps: int):
        """Report '<label>: N steps in T s (R steps/s)' when the block ends."""
        t0 = time.perf_counter()
        yield
        dt = time.perf_counter() - t0
        rate = n_steps / dt if dt > 0 else float("inf")
        self.progress(f"{label}: {n_steps} steps in {dt:.2f} s ({rate:,.0f} steps/s)")


def run_lesson(lesson: Lesson, cfg, rec, stages: list[int] | None = None, out=sys.stdout,
               err=sys.stderr, quiet: bool = False, results: list | None = None) -> bool:
    """Run the chosen stages; print and record each stage's table; return all-passed.

    Results are appended to ``results`` as they are produced, so an interrupted run
    still leaves the finished stages' results to the caller.
    """
    results = results if results is not None else []
    all_passed = True
    for index in stages or range(1, len(lesson.stages) + 1):
        stage = lesson.stages[index - 1]
        print(f"\n== {lesson.id} · stage {index}/{len(lesson.stages)}: {stage.title}", file=out, flush=True)
        if not quiet:
            for para in stage.narrative.strip().split("\n\n"):
                print(textwrap.fill(" ".join(para.split()), 96, initial_indent="   ", subsequent_indent="   "),
                      file=out)
            print(file=out, flush=True)
        rec.stage(index, stage.title, stage.narrative)
        ctx = StageContext(lesson, cfg, rec, index, stream=err, quiet=quiet)
        t0 = time.perf_counter()
        try:
            experiments = stage.run(ctx)
        except BlowUpError as exc:
            rec.mark(str(exc), level="ERROR")
            print(f"   error: {exc}", file=err, flush=True)
            experiments = [Experiment("stage ran without an unexpected blow-up", 0, exc.step + 1, 0, "<=")]
        print(text_table(experiments), file=out)
        print(f"   ({time.perf_counter() - t0:.1f} s)", file=out, flush=True)
        rec.markdown("results", f"## {index}. {stage.title}: experiments\n\n" + markdown_table(experiments))
        results.extend(e.to_dict(lesson.id, index, stage.title) for e in experiments)
        all_passed &= all(e.passed for e in experiments)
    return all_passed


def write_json_atomic(path: str | os.PathLike, data) -> None:
    path = Path(path)
    tmp = path.with_name(f".{path.name}.partial-{os.getpid()}")
    with open(tmp, "w") as fh:
        json.dump(data, fh, indent=1)
        fh.write("\n")
    os.replace(tmp, path)
