"""The grading child seen from the grader: the process started, asked and stopped, and its answers
checked here.

:class:`Server` starts one grading child (lessons.app.grading_child) for one student's module, in
its own session and process group, sends it requests on the grading channel (lessons.app.channel)
and reads its answers within a deadline; :class:`Stopped`, :class:`Crashed` and :class:`Refused`
say how a child ended without answering. :class:`RemoteFunction` is the student's function as the
checks see it (each call answered by the child), :func:`validated_rows` a stage's rows as the
child sent them, checked field by field and rebuilt here, and :func:`printable` the child's text
with its control characters escaped.
"""
import math
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from .._exercise import StudentError
from .._framework import COMPARISONS, Experiment, Terminated
from . import channel

PROJECT_ROOT = Path(__file__).resolve().parents[2]


_CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f]")


def printable(text: str) -> str:
    """Text from the student's process with its control characters escaped (an exception's message
    may carry terminal escapes that would redraw the table)."""
    return _CONTROL.sub(lambda m: repr(m.group())[1:-1], str(text))


class Stopped(Exception):
    """The child was stopped at the time limit."""


class Crashed(Exception):
    """The child ended without answering (its reason: a signal or its last words)."""


class Refused(Exception):
    """The child ended because the solution did what a solution may not (the guard's line)."""


class Server:
    """One grading child for one student's module: started, asked, stopped (lessons.app.grading_child).

    It runs in its own session and process group (killed as a group), ends itself when this process
    ends (PR_SET_PDEATHSIG), and its CPU time is capped at ``limit`` times the work it may be given
    (a backstop: the grader stops it at ``limit`` seconds of wall time per request)."""

    def __init__(self, lesson_id: str, path: Path, limit: float, memory_bytes: int, workdir: Path, items: int):
        self.lesson_id, self.path, self.limit = lesson_id, path, limit
        self.memory, self.workdir, self.items = memory_bytes, workdir, items
        self.proc = None
        self.ready: dict = {}

    def start(self) -> dict:
        """Start the child and wait for its module to load (``limit`` s): returns its ready message, or
        raises Stopped (a hang at import), Crashed or Refused; ``{"error": line}`` for a module that
        does not import."""
        to_child_r, to_child_w = os.pipe()
        from_child_r, from_child_w = os.pipe()
        log_fd, self.log_path = tempfile.mkstemp(suffix=".log", dir=self.workdir)
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join([str(PROJECT_ROOT)] + [p for p in [env.get("PYTHONPATH")] if p])
        cpu = self.limit * (self.items + 2) * 2 + 120
        try:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "lessons.app.grading_child", self.lesson_id, str(self.path.resolve()), str(to_child_r),
                 str(from_child_w), str(os.getpid()), f"{cpu:.0f}", str(self.memory)],
                stdin=subprocess.DEVNULL, stdout=log_fd, stderr=subprocess.STDOUT, env=env, start_new_session=True,
                pass_fds=(to_child_r, from_child_w), cwd=self.workdir)
        finally:
            os.close(to_child_r)
            os.close(from_child_w)
            os.close(log_fd)
        self.to_child, self.reader = to_child_w, channel.Reader(from_child_r)
        self.ready = self._answer(time.monotonic() + self.limit)
        return self.ready

    def _answer(self, deadline: float) -> dict:
        try:
            answer = self.reader.read(deadline)
        except channel.ChannelTimeout:
            self.stop()
            raise Stopped() from None
        except channel.ChannelClosed:
            self.proc.wait()
            raise Crashed(self.crash_text()) from None
        except channel.ChannelError as exc:
            self.stop()
            raise Crashed(f"the student's process sent a malformed answer ({exc})") from None
        except (KeyboardInterrupt, Terminated):   # an interrupt of the grader stops the child with it
            self.stop()
            raise
        except Exception as exc:  # noqa: BLE001 - anything else in reading the child's answer: its fault
            self.stop()
            raise Crashed(f"the student's process sent a malformed answer ({type(exc).__name__})") from None
        except BaseException:
            self.stop()
            raise
        if not isinstance(answer, dict):
            self.stop()
            raise Crashed("the student's process sent a malformed answer (not an object)")
        if "violation" in answer:
            self.stop()
            raise Refused(str(answer["violation"])[:400])
        return answer

    def ask(self, request: dict, deadline: float) -> dict:
        try:
            channel.send(self.to_child, request, deadline)
        except channel.ChannelTimeout:   # the child stopped reading
            self.stop()
            raise Stopped() from None
        except OSError:   # the child is gone: its reason comes with the answer's end of the channel
            pass
        return self._answer(deadline)

    @property
    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def stop(self) -> None:
        """Kill the child and everything it started (its own process group), and reap it."""
        if self.proc is None:
            return
        try:
            os.killpg(self.proc.pid, 9)
        except (ProcessLookupError, PermissionError):
            pass
        self.proc.wait()
        for fd in (self.to_child, self.reader.fd):
            try:
                os.close(fd)
            except OSError:
                pass
        self.proc = None

    def crash_text(self, returns: str = "") -> str:
        """Why the child ended without its answer: a signal (a crash of Taichi's compiler, most
        often on a function that returns another type than it should), a limit, or its last words."""
        code = self.proc.returncode if self.proc is not None else None
        if code is not None and code < 0:
            if -code in (24,):   # SIGXCPU
                return "the CPU-time limit of the student's process was reached"
            hint = f": check that it returns {returns}" if returns else ""
            return f"the Taichi compiler crashed on it (signal {-code}){hint}"
        lines = [s for s in Path(self.log_path).read_text(encoding="utf-8", errors="replace").splitlines()
                 if s.strip() and not s.startswith("[Taichi]")]
        if any("MemoryError" in s or "bad_alloc" in s for s in lines[-5:]):
            return "the memory limit of the student's process was reached"
        return f"the check's process ended with exit code {code}" + (f": {lines[-1][:200]}" if lines else "")


class RemoteFunction:
    """The student's function as the checks see it here (lessons._exercise.LocalFunction's ``via``):
    each call is answered by the grading child within the task's deadline."""

    def __init__(self, name: str, grader):   # grader: a grading_lesson.Grader
        self.name, self.grader = name, grader

    def via(self, factory, *args):
        spec = f"{factory.__module__}:{factory.__qualname__}"

        def call(*inputs):
            answer = self.grader.call(self.name, spec, list(args), list(inputs))
            if "error" in answer:
                raise StudentError(printable(str(answer["error"])[:4000]))
            out = answer.get("ok")
            if answer.get("tuple") and isinstance(out, list) and all(hasattr(o, "shape") for o in out):
                return tuple(o.astype(float) for o in out)
            if hasattr(out, "shape") and out.dtype.kind in "fib":
                return out.astype(float)
            raise StudentError(f"{self.name}: the student's process sent no numbers")
        return call


ROW_TYPES = {"id": str, "claim": str, "tolerance": (int, float), "comparison": str}


def validated_rows(rows, lesson_id: str, index: int, title: str) -> list[dict]:
    """A stage's rows as the child sent them, checked field by field and rebuilt here (each verdict
    recomputed from theory, measured, tolerance and comparison); raises ValueError naming the first
    malformed field."""
    if not isinstance(rows, list) or not rows:
        raise ValueError("no rows")
    out, seen = [], set()
    for k, row in enumerate(rows):
        if not isinstance(row, dict):
            raise ValueError(f"row {k} is not an object")
        for key, kind in ROW_TYPES.items():
            if not isinstance(row.get(key), kind) or isinstance(row.get(key), bool):
                raise ValueError(f"row {k}'s {key} is missing or of the wrong type")
        for key in ("theory", "measured"):
            if row.get(key) is not None and (not isinstance(row[key], (int, float)) or isinstance(row[key], bool)):
                raise ValueError(f"row {k}'s {key} is not a number")
        if row["comparison"] not in COMPARISONS or row["id"] in seen:
            raise ValueError(f"row {k}'s comparison or id is not valid")
        seen.add(row["id"])
        num = lambda v: math.nan if v is None else float(v)  # noqa: E731
        try:
            e = Experiment(printable(row["claim"][:2000]), num(row["theory"]), num(row["measured"]),
                           float(row["tolerance"]), row["comparison"], printable(str(row.get("unit", ""))[:40]),
                           id=row["id"], reason=printable(str(row.get("reason", ""))[:2000]))
        except ValueError as exc:
            raise ValueError(f"row {k}: {exc}") from None
        d = e.to_dict(lesson_id, index, title)
        integrators = row.get("integrators")
        if isinstance(integrators, (str, list)) and all(isinstance(x, str) for x in integrators):
            d["integrators"] = integrators
        out.append(d)
    return out
