"""Exercises: the student writes a lesson's formulas, the lesson grades them.

Each lesson package that has an exercise holds ``exercise.py`` with ``TASKS``, a list of
:class:`Task`: a function the student writes (its name, signature, units and the equation it
implements, for the template), how it takes the engine's place (``install``: the engine's kernels
are then compiled around the student's function) and its own checks (``check``: the function on
its own, against the engine's value or finite differences, as experiments whose ``reason`` says
what a failure means for the student's code). The lesson's reference solution is
``solution.py`` beside it, written as a student would.

The grader (:mod:`lessons.app.grading`) runs every check in a child process with a time limit:
a Taichi kernel cannot be interrupted, and a student's endless loop must not hang the grader.
"""
from __future__ import annotations

import ast
import importlib
import math
import pkgutil
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from ._framework import Experiment

TI_FUNC, NUMPY = "ti.func", "numpy"


@dataclass(frozen=True)
class Task:
    """One function the student writes.

    ``args``: the parameters as written in the template's ``def`` line; ``doc``: the template's
    docstring (arguments with units, what it returns, the equation in words); ``install(func)``:
    put the student's function where the engine's is; ``check(func)``: its own experiments;
    ``stages``: the lesson's stages whose experiments run on it (empty: every stage)."""
    name: str
    kind: str
    args: str
    doc: str
    install: Callable[[Callable], None]
    check: Callable[[Callable], list]
    stages: tuple = ()
    returns: str = ""


class StudentError(Exception):
    """The student's function could not be used: one line naming the function and what is wrong."""


# ------------------------------------------------------------------ the student's module

def module_file(solution_dir: Path, lesson_id: str) -> Path:
    """Where a lesson's module lives in a solution folder: ``<dir>/<lesson id with _>.py``."""
    return Path(solution_dir) / (lesson_id.replace("-", "_") + ".py")


def empty_functions(path: Path, names) -> list[str]:
    """The functions among ``names`` that ``path`` defines with an empty body (only a docstring,
    ``pass``, ``...`` or ``raise NotImplementedError``), in the order of ``names``."""
    tree = ast.parse(Path(path).read_text(encoding="utf-8"), filename=str(path))
    bodies = {n.name: n.body for n in ast.walk(tree) if isinstance(n, ast.FunctionDef)}
    empty = []
    for name in names:
        body = [s for s in bodies.get(name, [None]) if s is not None]
        real = [s for s in body if not (isinstance(s, ast.Pass) or (isinstance(s, ast.Expr) and isinstance(s.value, ast.Constant)))
                and not (isinstance(s, ast.Raise) and "NotImplementedError" in ast.unparse(s))]
        if name in bodies and not real:
            empty.append(name)
    return empty


def load_student_module(path: Path):
    """Import the student's module from ``path`` (a fresh module object, not cached by name). The
    grader loads it in its child under the guard instead (lessons.app.sandbox_guard); tests load the
    lessons' own reference solutions with this."""
    spec = importlib.util.spec_from_file_location(f"student_{Path(path).stem}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


# ------------------------------------------------------------------ calling the student's function

def direct(func):
    """The factory of a set-up (numpy) function: it is called as it is."""
    return func


def normalise_result(name: str, result, kernel: bool):
    """What a call of the student's function gave, as the checks read it: an array of floats, or a
    tuple of them (a kernel's outputs). A set-up function's result that is not numbers is one
    StudentError line naming the function."""
    if isinstance(result, tuple) and result and all(isinstance(r, np.ndarray) for r in result) and kernel:
        return tuple(np.asarray(r, dtype=float) for r in result)
    try:
        out = np.asarray(result, dtype=float)
    except (TypeError, ValueError):
        raise StudentError(f"{name}: returns {type(result).__name__}, expected numbers") from None
    return out


def call_student(name: str, fn, *args, kernel: bool = True):
    """``fn(*args)`` (a kernel built around the student's function ``name``, or the function
    itself); any error but a StudentError becomes one StudentError line naming the function."""
    try:
        return fn(*args)
    except StudentError:
        raise
    except Exception as exc:  # noqa: BLE001 - a Taichi compile or run error, or the student's own
        text = " ".join(str(exc).split())
        if kernel:
            raise StudentError(f"{name}: could not be compiled or run in a kernel: {text[:200]}") from None
        raise StudentError(f"{name}: raised {type(exc).__name__}: {text[:200]}") from None


class LocalFunction:
    """The student's function in this process (the tests of the checks). The grader hands the
    checks a remote one instead (lessons.app.grading_remote): the same ``via``, with the student's code
    in a guarded child process and the verdicts here.

    ``via(factory, *args)`` is the function around which ``factory(func, *args)`` builds a
    callable on numpy inputs (a kernel calling it for a batch; :func:`direct` for set-up code);
    calling it returns :func:`normalise_result`'s arrays."""

    def __init__(self, name: str, func):
        self.name, self.func = name, func
        self._built: dict = {}

    def via(self, factory, *args):
        key = (factory, args)
        if key not in self._built:
            self._built[key] = factory(self.func, *args)
        fn, kernel = self._built[key], factory is not direct
        return lambda *inputs: normalise_result(self.name, call_student(self.name, fn, *inputs, kernel=kernel),
                                                kernel)


# ------------------------------------------------------------------ taking the engine's place

def import_package(name: str) -> None:
    """Import every module of package ``name``, so that a substitution reaches all of them (a
    module imported after it would keep the engine's function)."""
    package = importlib.import_module(name)
    for info in pkgutil.walk_packages(package.__path__, name + "."):
        importlib.import_module(info.name)


def load_before_swap(lesson_package: str) -> None:
    """Import every module a lesson's stages may use (the engine, the lesson's package, the
    lessons' shared modules), so that a substitution reaches them all."""
    import lessons
    import_package("engine")
    import_package(lesson_package)
    for info in pkgutil.iter_modules(lessons.__path__):
        if info.name.startswith("_") and not info.name.startswith("__"):
            importlib.import_module(f"lessons.{info.name}")


def substitute(original, replacement) -> int:
    """Replace ``original`` by ``replacement`` in every loaded module of the engine, the lessons and
    the benchmarks (module attributes and names imported into other modules); returns how many
    places. Taichi resolves a kernel's functions when it compiles it, so kernels compiled afterwards
    call ``replacement``."""
    count = 0
    for name, module in list(sys.modules.items()):
        if module is None or name.split(".")[0] not in ("engine", "lessons", "bench"):
            continue
        for key, value in list(vars(module).items()):
            if value is original:
                setattr(module, key, replacement)
                count += 1
    if count == 0:
        raise RuntimeError(f"{getattr(original, '__name__', original)} was not found in any loaded module")
    return count


# ------------------------------------------------------------------ checks

def _row_scale(reference: np.ndarray, scale) -> np.ndarray:
    """The scale each call's deviation is measured against: ``scale`` per call when given (the
    natural size of the result at that call's inputs, e.g. c/L for a spring's force), else the
    largest reference value of all calls."""
    n = len(reference)
    if scale is None:
        largest = float(np.max(np.abs(reference))) if reference.size else 0.0
        return np.full(n, largest or 1.0)
    return np.broadcast_to(np.asarray(scale, float), (n,)).copy()


def _row_errors(measured, reference, scale) -> np.ndarray:
    measured, reference = np.asarray(measured, float), np.asarray(reference, float)
    if measured.shape != reference.shape:
        raise StudentError(f"returns shape {measured.shape[1:]} per call, expected {reference.shape[1:]}")
    err = np.abs(measured - reference).reshape(len(measured), -1).max(axis=1, initial=0.0)
    err = np.where(np.isfinite(measured).reshape(len(measured), -1).all(axis=1), err, math.inf)
    return err / _row_scale(reference, scale)


def deviation(measured: np.ndarray, reference: np.ndarray, scale=None) -> float:
    """The largest deviation of a call's result from its reference, relative to the largest
    reference value (or to ``scale``, one value per call: checks whose inputs span several scales
    measure each call against its own); inf where the measured has NaN or inf."""
    err = _row_errors(measured, reference, scale)
    return float(err.max()) if len(err) else 0.0


def first_bad(measured: np.ndarray, reference: np.ndarray, tol: float, scale=None) -> int:
    """The index of the first call whose result deviates by more than ``tol`` (as :func:`deviation`
    measures), or -1."""
    bad = np.flatnonzero(~(_row_errors(measured, reference, scale) <= tol))
    return int(bad[0]) if len(bad) else -1


def matches(measured, wrong, scale=None, tol: float = 1e-8) -> bool:
    """Whether the student's results are those of a known mistake ``wrong`` (within ``tol``)."""
    try:
        return bool(np.all(np.isfinite(measured))) and deviation(measured, wrong, scale) <= tol
    except StudentError:
        return False


def ratio(measured: np.ndarray, reference: np.ndarray, rtol: float = 1e-4) -> float | None:
    """The constant factor measured/reference where there is one (within ``rtol``, over the entries
    above 1e-3 of the largest: a finite-difference reference is noisy near zero), else None."""
    measured, reference = np.ravel(np.asarray(measured, float)), np.ravel(np.asarray(reference, float))
    if measured.shape != reference.shape or not np.all(np.isfinite(measured)):
        return None
    keep = np.abs(reference) > 1e-3 * (np.max(np.abs(reference)) if reference.size else 1.0)
    if not np.any(keep):
        return None
    r = measured[keep] / reference[keep]
    return float(np.median(r)) if np.allclose(r, np.median(r), rtol=rtol, atol=0) else None


FACTOR_WORDS = {2.0: "twice", 0.5: "half", -1.0: "minus", -2.0: "minus twice", -0.5: "minus half"}


def factor_text(r: float | None) -> str:
    """'twice' / 'minus' / '3 times' / '1.0001 times' for a constant factor (as many digits as it
    takes to tell it from 1), '' for none or 1."""
    if r is None or abs(r - 1.0) < 1e-9:
        return ""
    for value, word in FACTOR_WORDS.items():
        if abs(r - value) < 1e-9:
            return word
    for digits in range(3, 13):
        text = f"{r:.{digits}g}"
        if float(text) != 1.0:
            return f"{text} times"
    return f"{r!r} times"


def named_mistake(measured, mistakes, scale=None) -> str:
    """The text of the first known mistake, of ``mistakes`` ((wrong results, text) pairs, in order),
    whose results the student's are (:func:`matches`), or ''."""
    return next((text for wrong, text in mistakes if matches(measured, wrong, scale)), "")


def explain_failure(name: str, got, ref, tol: float, scale=None, *, where: Callable[[int], str],
                    otherwise: Callable[[int], str], of: str, mistakes=(), checks=(), sign: str = "",
                    after_mistakes=(), factor_notes: dict | None = None) -> str:
    """Why the student's ``name`` returned ``got`` where ``ref`` was expected, for a check that failed
    (a deviation above ``tol``, measured against ``scale`` as :func:`deviation` does): the first rung
    of this ladder that holds, with i the first call off by more than ``tol``:

    1. NaN or inf in ``got``: '<name> returns NaN or inf at <where(i)>';
    2. ``checks``, in order: (test, text) pairs, ``test()`` called only when this rung is reached;
    3. when ``sign`` is given, ``got`` is minus ``ref``: '<name> has the wrong sign: <sign>';
    4. a known mistake of ``mistakes`` ((wrong results, text) pairs; :func:`named_mistake`): '<name> <text>';
    5. ``after_mistakes``: (test, text) pairs as in 2;
    6. a constant factor from ``ref`` (:func:`factor_text`): '<name> is <factor> <of>', followed by
       ``factor_notes``' text for that factor where it has one;
    7. else ``otherwise(i)``."""
    i = first_bad(got, ref, tol, scale)
    r = factor_text(ratio(got, ref))
    named = named_mistake(got, mistakes, scale)
    if not np.all(np.isfinite(got)):
        return f"{name} returns NaN or inf at {where(i)}"
    for test, text in checks:
        if test():
            return text
    if sign and r == "minus":
        return f"{name} has the wrong sign: {sign}"
    if named:
        return f"{name} {named}"
    for test, text in after_mistakes:
        if test():
            return text
    if r:
        return f"{name} is {r} {of}" + (factor_notes or {}).get(r, "")
    return otherwise(i)


def agreement(claim: str, id: str, dev: float, tol: float, reason: str, unit: str = "") -> Experiment:
    """An experiment 'the largest relative deviation is at most ``tol``' (theory = the bound)."""
    return Experiment(claim, tol, dev, 0.0, "<=", unit=unit, id=id, reason=reason)


@dataclass
class Sampler:
    """Reproducible random inputs for a check (seeded per check)."""
    seed: int = 7
    rng: np.random.Generator = field(init=False)

    def __post_init__(self):
        self.rng = np.random.default_rng(self.seed)

    def vectors(self, n: int, scale: float = 1.0) -> np.ndarray:
        return scale * self.rng.standard_normal((n, 3))

    def uniform(self, n: int, lo: float, hi: float) -> np.ndarray:
        return self.rng.uniform(lo, hi, n)

    def log_uniform(self, n: int, lo: float, hi: float) -> np.ndarray:
        """``n`` values spread evenly in log between ``lo`` and ``hi`` (several scales)."""
        return np.exp(self.rng.uniform(np.log(lo), np.log(hi), n))

    def rotations(self, n: int) -> np.ndarray:
        """``n`` random proper rotations (3, 3)."""
        q, r = np.linalg.qr(self.rng.standard_normal((n, 3, 3)))
        q *= np.sign(np.einsum("nii->ni", r))[:, None, :]
        q[np.linalg.det(q) < 0, :, 0] *= -1
        return q


def central_difference(fn: Callable[[np.ndarray], np.ndarray], x: np.ndarray, eps: float) -> np.ndarray:
    """d fn / dx by central differences, for a batch: ``x`` (n, k), ``fn`` maps (m, k) -> (m, ...)
    (any trailing shape); returns (n, ..., k), the derivative in the last axis."""
    n, k = x.shape
    plus = np.repeat(x[:, None, :], k, axis=1) + eps * np.eye(k)[None]
    minus = np.repeat(x[:, None, :], k, axis=1) - eps * np.eye(k)[None]
    fp = np.asarray(fn(plus.reshape(n * k, k)))
    fm = np.asarray(fn(minus.reshape(n * k, k)))
    d = (fp - fm).reshape((n, k) + fp.shape[1:]) / (2 * eps)
    return np.moveaxis(d, 1, -1)
