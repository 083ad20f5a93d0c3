"""What a lesson is, how its experiments are judged, and how a lesson run is driven.

A lesson is a scene with a typed configuration (a dataclass whose fields carry help text,
SI unit and valid range in their metadata; the CLI is derived from it) and a sequence of
stages. A stage narrates one idea, runs simulations through the engine, and returns
experiments: a claim, the theory's value, the measured value and a tolerance.
"""
from __future__ import annotations

import contextlib
import dataclasses
import math
import re
import sys
import textwrap
import time
from dataclasses import dataclass, field
from typing import Any, Callable

from engine.constants import EXPLICIT, INTEGRATOR_NAMES, SOLVERS
from engine.errors import BlowUpError, ParameterError

COMPARISONS = ("rel", "abs", "<=", ">=")


# --------------------------------------------------------------------------- config

def param(default, help: str, unit: str = "", *, gt=None, ge=None, lt=None, le=None, choices=None,
          optional: bool = False):
    """A config field with its help text, unit and valid range (checked before any kernel).
    ``optional``: None is allowed and means "not given" (the run's own choice)."""
    return field(default=default, metadata=dict(help=help, unit=unit, gt=gt, ge=ge, lt=lt, le=le,
                                                choices=tuple(choices) if choices else None,
                                                optional=optional))


def field_type(f: dataclasses.Field) -> type:
    t = f.type if isinstance(f.type, str) else getattr(f.type, "__name__", str(f.type))
    return {"float": float, "int": int, "str": str, "bool": bool}[t]


def range_text(meta: dict) -> str:
    """Human-readable valid range of a field, e.g. '> 0', 'in [3, 100000]'."""
    if meta.get("choices"):
        return "one of " + ", ".join(map(str, meta["choices"]))
    num = lambda v: f"{v:g}" if isinstance(v, float) else str(v)
    lo = ("> " + num(meta["gt"])) if meta.get("gt") is not None else ("≥ " + num(meta["ge"])) if meta.get("ge") is not None else None
    hi = ("< " + num(meta["lt"])) if meta.get("lt") is not None else ("≤ " + num(meta["le"])) if meta.get("le") is not None else None
    if lo and hi:
        return f"{lo} and {hi}"
    return lo or hi or "any value"


def validate_config(cfg) -> None:
    """Raise ParameterError naming the first field outside its range (then cfg.validate())."""
    for f in dataclasses.fields(cfg):
        meta, value = f.metadata, getattr(cfg, f.name)
        if not meta or (value is None and meta.get("optional")):
            continue
        flag = "--" + f.name.replace("_", "-")
        kind = field_type(f)
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


# ------------------------------------------------------------------------ interrupts

class Terminated(BaseException):
    """SIGTERM or SIGHUP during a run (exit code 128 + the signal: 143, 129); ``args[0]`` is the
    signal number when known."""

    @property
    def signum(self) -> int:
        import signal as _signal
        return self.args[0] if self.args and isinstance(self.args[0], int) else int(_signal.SIGTERM)


pending_signal: list = []  # the signal a handler saw; re-raised at the next check point


def note_signal(signum: int) -> None:
    """Called by the CLI's signal handlers before they raise: if the exception they raise is
    swallowed (a signal landing inside a ``__del__`` is only printed), :func:`check_interrupt`
    raises it again at the next chunk of the run."""
    pending_signal.append(signum)


def check_interrupt() -> None:
    """Raise KeyboardInterrupt / :class:`Terminated` if a signal arrived and was not acted on."""
    import signal as _signal
    if pending_signal:
        signum = pending_signal[-1]
        pending_signal.clear()
        raise KeyboardInterrupt() if signum == _signal.SIGINT else Terminated(signum)


# -------------------------------------------------------------------------- stepping

INTEGRATOR_CHOICES = ("default",) + INTEGRATOR_NAMES
SOLVER_CHOICES = ("default",) + SOLVERS
EXPLICIT_INTEGRATORS = EXPLICIT


@dataclass
class Stepping:
    """How every lesson's scene runs are stepped in time (``--integrator/--solver/--tol/
    --newton-iterations``, shared by all lessons).

    "default" keeps each run's own choice. Runs whose claim is about one particular
    integrator (a CFL limit, energy conservation of a symplectic method, the damping of
    backward Euler) are *fixed* and ignore the choice; the stage says so. With an explicit
    integrator a scene whose dt exceeds engine.constants.CFL_SAFETY (0.9) x the stable
    estimate is sub-stepped.
    """

    integrator: str = param("default", "time integrator for the lessons' scene runs ('default': each run's own "
                            "choice; runs that test one integrator keep it)", choices=INTEGRATOR_CHOICES)
    solver: str = param("default", "linear solver of backward Euler ('default': the run's choice, usually pcg)",
                        choices=SOLVER_CHOICES)
    tol: float = param(None, "relative residual tolerance of backward Euler's linear solves (default: the "
                       "run's choice, usually 1e-8)", gt=0.0, lt=1.0, optional=True)
    newton_iterations: int = param(None, "Newton iterations per backward-Euler step (1 = Baraff-Witkin "
                                   "linearised step; default: the run's choice)", ge=1, le=100, optional=True)

    @property
    def overridden(self) -> bool:
        return self.integrator != "default"

    def validate(self) -> None:
        """The solver options apply only to backward Euler: refused with an explicit integrator."""
        if self.integrator in EXPLICIT_INTEGRATORS:
            given = [flag for flag, on in (("--solver", self.solver != "default"), ("--tol", self.tol is not None),
                                           ("--newton-iterations", self.newton_iterations is not None)) if on]
            if given:
                raise ParameterError(
                    f"{given[0]} applies only to backward-euler, but --integrator {self.integrator} is explicit "
                    f"(it solves no system); drop {' and '.join(given)} or use --integrator backward-euler")

    def describe(self) -> str:
        if not self.overridden and self.solver == "default" and self.tol is None and self.newton_iterations is None:
            return "each run's own integrator"
        parts = [self.integrator if self.overridden else "each run's own integrator"]
        if self.solver != "default":
            parts.append(f"solver {self.solver}")
        if self.tol is not None:
            parts.append(f"tol {self.tol:g}")
        if self.newton_iterations is not None:
            parts.append(f"{self.newton_iterations} Newton iteration(s)")
        return ", ".join(parts)


# ----------------------------------------------------------------------- experiments

ID_PATTERN = re.compile(r"[a-z0-9]+(?:[.-][a-z0-9]+)*")  # a slug: "pulse-speed-nu0.25"


@dataclass
class Experiment:
    """One measured claim. ``compare``: 'rel' |m-t| <= tol |t|; 'abs' |m-t| <= tol;
    '<=' m <= t (t is a bound); '>=' m >= t.

    ``id`` (required, keyword): a slug unique within the lesson that names the experiment whatever
    the claim's text (which may carry measured numbers or the integrator's name) and whatever
    options the run had; results and tests find experiments by it.

    ``reason`` (optional, keyword): why the claim is expected to fail for the run's parameters
    (a physical limit the lesson knows of); printed under the stage's table when it does fail."""

    claim: str
    theory: float
    measured: float
    tolerance: float = 0.0
    compare: str = "rel"
    unit: str = ""
    id: str = field(kw_only=True)
    reason: str = field(default="", kw_only=True)

    def __post_init__(self):
        if self.compare not in COMPARISONS:
            raise ValueError(f"compare must be one of {COMPARISONS}")
        if not isinstance(self.id, str) or not ID_PATTERN.fullmatch(self.id):
            raise ValueError(f"experiment id must be a slug like 'pulse-speed-nu0.25' (got {self.id!r})")
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
        return dict(lesson=lesson, stage=stage, stage_title=stage_title, id=self.id, claim=self.claim,
                    theory=num(self.theory), measured=num(self.measured), tolerance=self.tolerance,
                    comparison=self.compare, unit=self.unit, passed=self.passed,
                    reason=self.reason if not self.passed else "")


def _fmt(v: float) -> str:
    return f"{v:.6g}" if math.isfinite(v) else str(v)


def _rows(experiments: list[Experiment]) -> list[list[str]]:
    return [[e.claim, _fmt(e.theory) + (f" {e.unit}" if e.unit else ""), _fmt(e.measured),
             ("≤ " if e.compare == "<=" else "≥ " if e.compare == ">=" else "") + e.tolerance_text()
             if e.compare in ("rel", "abs") else e.tolerance_text(),
             "PASS" if e.passed else "FAIL"] for e in experiments]


HEADER = ["claim", "theory", "measured", "tolerance", "result"]


def text_table(experiments: list[Experiment], width: int = 60) -> str:
    """The stage's table for the terminal; a claim longer than ``width`` wraps onto the next
    lines of its column (the full text is always shown)."""
    rows = _rows(experiments)
    claims = [textwrap.wrap(r[0], width, break_on_hyphens=False) or [""] for r in rows]
    widths = [max(len(h), *(len(r[i]) for r in rows)) if rows else len(h) for i, h in enumerate(HEADER)]
    widths[0] = max([len(HEADER[0])] + [len(piece) for c in claims for piece in c])
    line = lambda cells: "  ".join(c.ljust(w) for c, w in zip(cells, widths)).rstrip()
    out = [line(HEADER), line(["-" * w for w in widths])]
    for r, pieces in zip(rows, claims):
        out.append(line([pieces[0]] + r[1:]))
        out += [line([piece]) for piece in pieces[1:]]
    return "\n".join(out)


MARKDOWN_ORDER = (4, 1, 2, 3, 0)   # result, theory, measured, tolerance, claim


def markdown_table(experiments: list[Experiment]) -> str:
    """The stage's table for the viewer: the claim, the one column of unbounded width, comes last, so
    that a view narrower than the table cuts a claim's end and never the numbers or the verdict."""
    rows = [[r[i] for i in MARKDOWN_ORDER] for r in _rows(experiments)]
    header = [HEADER[i] for i in MARKDOWN_ORDER]
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(c.replace("|", "\\|") for c in r) + " |" for r in rows]
    return "\n".join(out)


# ---------------------------------------------------------------------------- lessons

@dataclass
class Stage:
    title: str
    narrative: str
    run: Callable[["StageContext"], list[Experiment]]


def narrated_stages(package: str, runs: list[tuple[str, Callable[["StageContext"], list[Experiment]]]]) -> list[Stage]:
    """The stages of a lesson package, (title, run) in order, each narrated by its section of the
    package's ``narrative.md``: a section starts with the line ``## <title>``, and its text (without
    the blank lines around it) is the narrative that is printed and recorded. Anything above the
    first section is a preamble. The sections must be the stages, in the same order."""
    from importlib.resources import files

    text = files(package).joinpath("narrative.md").read_text(encoding="utf-8")
    titles, bodies = [], []
    for line in text.splitlines():
        if line.startswith("## "):
            titles.append(line[3:].strip())
            bodies.append([])
        elif bodies:
            bodies[-1].append(line)
    wanted = [title for title, _ in runs]
    if titles != wanted:
        raise ValueError(f"{package}/narrative.md: sections {titles} do not match the stages {wanted}")
    return [Stage(title, "\n" + "\n".join(body).strip("\n") + "\n", run)
            for (title, run), body in zip(runs, bodies)]


@dataclass
class Lesson:
    id: str
    title: str
    summary: str
    config: type
    stages: list[Stage]
    order: int = 100
    camera: str = "outside"  # the default camera of its runs' views (lessons.views.CAMERAS)
    validate: Callable[[Any], None] | None = None  # extra up-front checks (e.g. build meshes)


class StageContext:
    """What a stage sees: its lesson, config, recorder, and progress reporting."""

    def __init__(self, lesson: Lesson, cfg, rec, index: int, stream=sys.stderr, quiet: bool = False,
                 stepping: Stepping | None = None):
        self.lesson, self.cfg, self.rec, self.index = lesson, cfg, rec, index
        self._stream, self._quiet = stream, quiet
        self.stepping = stepping or Stepping()
        self.integrators_used: list[str] = []  # "run: integrator" for every run of this stage
        self.result_notes: list[str] = []      # markdown shown under the stage's results table (e.g. a table)

    def integrator_name(self, default: str, fixed: bool = False) -> str:
        """The integrator a run uses: ``default`` unless ``--integrator`` overrides it (never
        when ``fixed``: the run is about that integrator)."""
        return default if fixed or not self.stepping.overridden else self.stepping.integrator

    def integrator(self, default="symplectic-euler", fixed: bool = False, run: str = "", **options):
        """An engine integrator for a run whose own choice is ``default`` (with backward-Euler
        ``options`` such as solver="cholesky"), after applying ``--integrator/--solver/--tol/
        --newton-iterations``; ``fixed`` runs keep ``default`` and its options. The choice is
        noted (``integrators_used``) and shown after the stage."""
        from engine.integrators import make_integrator
        if not isinstance(default, str):  # an integrator object: keep it unless options change it
            obj = default
            st = self.stepping
            be_options = st.solver != "default" or st.tol is not None or st.newton_iterations is not None
            if fixed or not (st.overridden or (obj.name == "backward-euler" and be_options)):
                self.note_integrator(run, obj, fixed)
                return obj
            if obj.name == "backward-euler":
                options = dict(solver=obj.solver.name, tol=obj.tol, newton_iterations=obj.newton_iterations,
                               line_search=obj.line_search, rayleigh_alpha=obj.rayleigh_alpha,
                               rayleigh_beta=obj.rayleigh_beta)
            default = obj.name
        name = self.integrator_name(default, fixed)
        kw = dict(options) if name == default else {}
        if not fixed and name == "backward-euler":
            st = self.stepping
            if st.solver != "default":
                kw["solver"] = st.solver
            if st.tol is not None:
                kw["tol"] = st.tol
            if st.newton_iterations is not None:
                kw["newton_iterations"] = st.newton_iterations
        integ = make_integrator(name, **kw)
        self.note_integrator(run, integ, fixed)
        return integ

    def note_integrator(self, run: str, integ, fixed: bool = False) -> None:
        """Record which integrator a run used (name, solver and tolerance for implicit ones)."""
        name = integ if isinstance(integ, str) else getattr(integ, "name", type(integ).__name__)
        solver = getattr(integ, "solver", None)
        if solver is not None and not isinstance(integ, str):
            name += f" ({getattr(solver, 'name', type(solver).__name__)}, tol {getattr(integ, 'tol', 0):g})"
        self.integrators_used.append(f"{run or 'run'}: {name}{' [fixed]' if fixed else ''}")

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
               err=sys.stderr, quiet: bool = False, results: list | None = None,
               stepping: Stepping | None = None,
               between: Callable[[int, str], bool] | None = None, collected: dict | None = None) -> bool:
    """Run the chosen stages (in the order given; default: every stage); print and record each
    stage's table; return all-passed (of the stages that ran).

    Results are appended to ``results`` as they are produced, so an interrupted run
    still leaves the finished stages' results to the caller.

    ``between``: called after each stage but the last with the next stage's (1-based) index and
    title, e.g. to wait for the user; when it returns False the run ends there (the remaining
    stages are skipped, and the result is that of the stages run so far).

    ``collected``: a dict that receives, per stage index, (its Experiments, the stage's
    integrator notes), for callers that look at more than the results' rows (the tests).
    """
    results = results if results is not None else []
    all_passed = True
    order = list(stages) if stages else list(range(1, len(lesson.stages) + 1))
    for position, index in enumerate(order):
        if position and between is not None and not between(index, lesson.stages[index - 1].title):
            break
        check_interrupt()
        stage = lesson.stages[index - 1]
        print(f"\n== {lesson.id} · stage {index}/{len(lesson.stages)}: {stage.title}", file=out, flush=True)
        if not quiet:
            for para in stage.narrative.strip().split("\n\n"):
                print(textwrap.fill(" ".join(para.split()), 96, initial_indent="   ", subsequent_indent="   "),
                      file=out)
            print(file=out, flush=True)
        rec.stage(index, stage.title, stage.narrative)
        ctx = StageContext(lesson, cfg, rec, index, stream=err, quiet=quiet, stepping=stepping)
        t0 = time.perf_counter()
        try:
            experiments = stage.run(ctx)
        except BlowUpError as exc:
            rec.mark(str(exc), level="ERROR")
            print(f"   error: {exc}", file=err, flush=True)
            experiments = [Experiment("stage ran without an unexpected blow-up", 0, exc.step + 1, 0, "<=",
                                      id=f"no-blow-up-stage{index}", reason=str(exc))]
        print(text_table(experiments), file=out)
        for e in experiments:
            if e.reason and not e.passed:
                print(f"   FAIL {e.id}: {e.reason}", file=out)
        used = _summarise_integrators(ctx.integrators_used)
        if used:
            print(f"   integrators: {used}", file=out)
        print(f"   ({time.perf_counter() - t0:.1f} s)", file=out, flush=True)
        rec.markdown("results", f"## {index}. {stage.title}: experiments\n\n" + markdown_table(experiments)
                     + (f"\n\nIntegrators: {used}" if used else "")
                     + "".join(f"\n\n{note}" for note in ctx.result_notes))
        for e in experiments:
            d = e.to_dict(lesson.id, index, stage.title)
            d["integrators"] = sorted({u.split(": ", 1)[1] for u in ctx.integrators_used})
            results.append(d)
        if collected is not None:
            collected[index] = (experiments, list(ctx.integrators_used))
        all_passed &= all(e.passed for e in experiments)
    return all_passed


def _summarise_integrators(used: list[str]) -> str:
    """'symplectic-euler x3; backward-euler (pcg, tol 1e-08) x1' from the per-run notes."""
    counts: dict[str, int] = {}
    for u in used:
        name = u.split(": ", 1)[1]
        counts[name] = counts.get(name, 0) + 1
    return "; ".join(f"{k} x{v}" for k, v in counts.items())
