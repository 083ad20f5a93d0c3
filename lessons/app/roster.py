"""``python -m lessons grade ROSTER [LESSON|all]``: grade a whole class.

ROSTER is a folder with one folder per student (its name is the student's id) holding the modules
the student wrote (``springs.py``, ``bending.py`` ..., and any helper modules beside them), or
their notebooks (``springs.ipynb``: graded as ``check`` grades one, lessons.app.exercise_notebook). Every
(student, lesson) pair is one task on a Dask cluster: a LocalCluster of ``--workers`` processes on
this machine by default, or the scheduler at ``--scheduler ADDRESS`` when a class outgrows one
machine. A task carries the student's files (so a remote worker needs no shared file system), writes
them to a temporary folder there and runs ``python -m lessons check`` on them in a process of its own
(whose grading child alone runs the student's code; lessons.app.grading): one student's crash,
hang or forgery ends in that student's grade and nowhere else. The kernel cache
(``ELASTIC_CACHE_DIR``) is shared by every check on a machine, so the engine's kernels compile once.

What it writes, into ``--out DIR`` (default ``grades``), each file atomically:

- ``gradebook.csv``: one row per student and lesson: student, lesson, status (graded, missing,
  failed to grade), claims passed, claims total, score (percent of the claims passed), flags for
  the instructor (``copy of the reference solution``: every function has the shipped solution's
  syntax tree);
- ``<student>/results.json``: Gradescope's autograder results (one test per claim: name, score,
  max_score, status, output);
- ``<student>/feedback.md``: per lesson, the claims that failed with their reasons, and the
  grader's notes;
- ``.grade-state.json``: each graded pair's hash (the student's files, the options, the suite's
  version) and result: a rerun grades again only the pairs whose hash changed (``--force``: all).
"""
from __future__ import annotations

import csv
import hashlib
import io
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from .._exercise import module_file
from .._framework import Terminated
from .arguments import UsageError, Parser
from .exercise_notebook import notebook_file
from .exercises import lessons_with_exercises
from .grading import DEFAULT_MEMORY_GB, DEFAULT_TIME_LIMIT_S, check_limits, check_stages
from .grading_remote import PROJECT_ROOT
from .results import package_version

STATE = ".grade-state.json"
MAX_FILE_BYTES = 1 << 20          # a student's module (or notebook) larger than this is not graded
STUDENT_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._@+-]{0,99}$")


def _parser(ids: list[str]) -> Parser:
    p = Parser(prog="python -m lessons grade", description=(
        "Grade a class: ROSTER holds one folder per student (the folder's name is the student's id) with "
        "the lesson modules the student wrote. Every student and lesson is graded as 'python -m lessons "
        "check' grades one, in parallel on a Dask cluster, each in its own processes. Writes gradebook.csv, "
        "one Gradescope results.json and one feedback.md per student into --out; a rerun grades only what "
        "changed."))
    p.add_argument("roster", metavar="ROSTER", help="the folder of student folders")
    p.add_argument("lesson", metavar="LESSON", nargs="?", default="all", help=f"one of {', '.join(ids)}, or all "
                   f"(default)")
    p.add_argument("--out", metavar="DIR", default="grades", help="where the gradebook and the students' files go "
                   "(default: grades)")
    p.add_argument("--workers", type=int, default=2, metavar="N",
                   help="processes of the local Dask cluster (1..64; default 2); ignored with --scheduler")
    p.add_argument("--scheduler", metavar="ADDRESS", help="a running Dask scheduler (tcp://host:8786) instead of "
                   "a local cluster; its workers need this suite installed")
    p.add_argument("--functions-only", action="store_true", help="check the functions only, without the stages")
    p.add_argument("--stage", type=int, action="append", metavar="N", help="run only this stage (repeatable)")
    p.add_argument("--time-limit", type=float, default=DEFAULT_TIME_LIMIT_S, metavar="S",
                   help=f"seconds per import, function and stage (default {DEFAULT_TIME_LIMIT_S:g})")
    p.add_argument("--memory-limit", type=float, default=DEFAULT_MEMORY_GB, metavar="GB",
                   help=f"address space of a student's process in GiB (default {DEFAULT_MEMORY_GB:g})")
    p.add_argument("--force", action="store_true", help="grade every student again, changed or not")
    return p


# ------------------------------------------------------------------ one task: a student and a lesson

def _student_files(folder: Path) -> dict[str, str]:
    """The student's Python files and notebooks (name -> text): what a task carries and what its hash
    covers."""
    files = {}
    for path in sorted([*folder.glob("*.py"), *folder.glob("*.ipynb")]):
        if path.is_file() and path.stat().st_size <= MAX_FILE_BYTES:
            files[path.name] = path.read_text(encoding="utf-8", errors="replace")
    return files


def _digest(files: dict, options: list, version: str) -> str:
    h = hashlib.sha256(json.dumps([sorted(files.items()), options, version]).encode("utf-8"))
    return h.hexdigest()


def grade_task(student: str, lesson_id: str, files: dict, options: list, hard_limit: float) -> dict:
    """Run on a Dask worker: write the student's files to a temporary folder, grade them with
    ``python -m lessons check`` in a process of its own, and return the claims (or why there are
    none). Never raises: a failure is part of the result."""
    started = time.time()
    result = {"student": student, "lesson": lesson_id, "rows": [], "notes": [], "status": "graded", "error": ""}
    with tempfile.TemporaryDirectory(prefix="elastic-grade-") as work:
        folder = Path(work) / "solution"
        folder.mkdir()
        for name, text in files.items():
            (folder / name).write_text(text, encoding="utf-8")
        out = Path(work) / "results.json"
        env = dict(os.environ, ELASTIC_GRADE_TASK="1")   # the check ends with this worker
        env["PYTHONPATH"] = os.pathsep.join([str(PROJECT_ROOT)] + [p for p in [env.get("PYTHONPATH")] if p])
        proc = subprocess.Popen([sys.executable, "-m", "lessons", "check", lesson_id, "--solution", str(folder),
                                 "--results", str(out), *options], cwd=work, env=env, stdin=subprocess.DEVNULL,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
        try:
            stdout, stderr = proc.communicate(timeout=hard_limit)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()
            result.update(status="failed to grade", error=f"the check did not finish within {hard_limit:.0f} s")
            return result
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
        try:
            doc = json.loads(out.read_text(encoding="utf-8"))
            result["rows"] = [{k: r.get(k) for k in ("stage", "stage_title", "id", "claim", "passed", "reason")}
                              for r in doc["experiments"]]
            result["notes"] = list(doc.get("notes", []))
            result["flags"] = [str(f) for f in (doc.get("flags") or {}).get(lesson_id, [])]
        except (OSError, ValueError, KeyError, TypeError):
            last = (stderr or stdout or "").strip().splitlines()
            result.update(status="failed to grade", error=f"the check ended with exit code {proc.returncode}"
                                                          + (f": {last[-1][:300]}" if last else ""))
    result["elapsed_s"] = round(time.time() - started, 2)
    return result


# ------------------------------------------------------------------ the class

def _state(out: Path) -> dict:
    try:
        doc = json.loads((out / STATE).read_text(encoding="utf-8"))
        return doc if isinstance(doc, dict) else {}
    except (OSError, ValueError):
        return {}


def _write_atomic(path: Path, text: str) -> None:
    from .outfile import OutputFile
    target = OutputFile(path)
    target.prepare()
    target.write_bytes(text.encode("utf-8"))
    target.commit(True)


REFERENCE = "(reference)"   # the lesson's own solution, graded with the class for each lesson's claim count


def _score(result: dict, expected: dict) -> tuple[int, int, float]:
    """(claims passed, claims of the lesson, percent): the lesson's count is the reference's, so that a
    module refused in one row or stopped half-way scores against the same total as a complete one."""
    rows = result.get("rows") or []
    passed = sum(bool(r.get("passed")) for r in rows)
    total = max(len(rows), expected.get(result["lesson"], 0))
    return passed, total, (round(100.0 * passed / total, 2) if total else 0.0)


def gradebook_text(results: list[dict], expected: dict) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["student", "lesson", "status", "passed", "total", "score", "flags"])
    for r in sorted(results, key=lambda r: (r["student"], r["lesson"])):
        passed, total, score = _score(r, expected)
        w.writerow([r["student"], r["lesson"], r["status"], passed, total, f"{score:g}", "; ".join(r.get("flags") or [])])
    return buf.getvalue()


def gradescope(results: list[dict], elapsed: float, expected: dict) -> dict:
    """Gradescope's autograder results.json for one student: one test per claim (1 point each), and
    for a lesson with fewer claims than its reference (missing, refused, stopped) one more test worth
    the claims not reached, so that every student's tests add up to the same points."""
    tests = []
    for r in sorted(results, key=lambda r: r["lesson"]):
        rows = r.get("rows") or []
        short = max(expected.get(r["lesson"], 0) - len(rows), 0)
        if short or r["status"] != "graded":
            why = {"missing": "not handed in"}.get(r["status"], r["error"] or "the lesson's other claims were not "
                                                                              "reached (see the failures above)")
            tests.append({"name": f"{r['lesson']}: claims not reached", "score": 0, "max_score": max(short, 1),
                          "status": "failed", "output": why, "number": f"{r['lesson']}.0"})
        for k, row in enumerate(rows, start=1):
            where = "your functions" if row.get("stage") == 0 else f"stage {row.get('stage')}"
            tests.append({"name": f"{r['lesson']} · {where} · {row.get('claim')}",
                          "number": f"{r['lesson']}.{k}", "score": 1 if row.get("passed") else 0, "max_score": 1,
                          "status": "passed" if row.get("passed") else "failed",
                          "output": "" if row.get("passed") else (row.get("reason") or "failed")})
    score = sum(t["score"] for t in tests)
    return {"score": score, "execution_time": round(elapsed, 1), "output": f"{score} of {len(tests)} claims passed",
            "stdout_visibility": "hidden", "tests": tests}


def feedback(student: str, results: list[dict], expected: dict) -> str:
    lines = [f"# Feedback for {student}", ""]
    for r in sorted(results, key=lambda r: r["lesson"]):
        passed, total, score = _score(r, expected)
        if r["status"] == "missing":
            lines += [f"## {r['lesson']}: not handed in", "", f"No `{r['lesson'].replace('-', '_')}.py` (or `.ipynb`) "
                      f"in your folder.", ""]
            continue
        if r["status"] != "graded":
            lines += [f"## {r['lesson']}: could not be graded", "", r["error"], ""]
            continue
        lines += [f"## {r['lesson']}: {passed} of {total} claims passed ({score:g}%)", ""]
        failed = [row for row in r["rows"] if not row.get("passed")]
        for row in failed:
            where = "your functions" if row.get("stage") == 0 else f"stage {row.get('stage')}"
            lines.append(f"- **{row.get('id')}** ({where}): {row.get('claim')}" +
                         (f" — {row.get('reason')}" if row.get("reason") else ""))
        for note in r.get("notes") or []:
            lines.append(f"- note: {note}")
        if failed:
            lines += ["", f"Check it yourself: `python -m lessons check {r['lesson']} --solution YOUR_FOLDER`."]
        lines.append("")
    return "\n".join(lines)


def _client(args):
    from dask.distributed import Client, LocalCluster
    if args.scheduler:
        return Client(args.scheduler, timeout="30s"), None
    cluster = LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True, dashboard_address=None)
    return Client(cluster), cluster


def grade(argv: list[str], out=sys.stdout, err=sys.stderr) -> int:
    available = lessons_with_exercises()
    ids = [l.id for l in available]
    args = _parser(ids).parse_args(argv)
    if args.lesson != "all" and args.lesson not in ids:
        raise UsageError(f"LESSON must be one of {', '.join(ids)} or all (got {args.lesson!r})")
    roster = Path(args.roster)
    if not roster.is_dir():
        raise UsageError(f"ROSTER {args.roster!r} is not a folder: give a folder with one folder per student")
    students = sorted(p for p in roster.iterdir() if p.is_dir() and not p.name.startswith("."))
    if not students:
        raise UsageError(f"ROSTER {args.roster!r} holds no student folder")
    bad = [p.name for p in students if not STUDENT_NAME.match(p.name)]
    if bad:
        raise UsageError(f"student folder {bad[0]!r}: a student's id must be letters, digits and . _ @ + - "
                         f"(at most 100)")
    if not 1 <= args.workers <= 64:
        raise UsageError(f"--workers must be an integer in 1..64 (got {args.workers})")
    check_limits(args)
    outdir = Path(args.out)
    if outdir.exists() and not outdir.is_dir():
        raise UsageError(f"--out {args.out!r} is a file: give a folder for the gradebook")
    if outdir.resolve() == roster.resolve() or roster.resolve() in outdir.resolve().parents:
        raise UsageError(f"--out {args.out!r} is inside the roster: give a folder outside {args.roster!r}")
    lessons = [l for l in available if args.lesson in ("all", l.id)]
    check_stages(lessons, args.stage)
    try:
        outdir.mkdir(parents=True, exist_ok=True)
        probe = outdir / f".grade-probe-{os.getpid()}"
        probe.write_text("")
        probe.unlink()
    except OSError as exc:
        raise UsageError(f"--out {args.out!r}: cannot write there ({exc.strerror or exc})") from None

    options = (["--functions-only"] if args.functions_only else []) + \
        [f"--stage={s}" for s in sorted(set(args.stage or []))] + \
        [f"--time-limit={args.time_limit:g}", f"--memory-limit={args.memory_limit:g}"]
    version = package_version()
    state = {} if args.force else _state(outdir)
    results: dict[tuple, dict] = {}
    todo = []
    for lesson in lessons:   # the reference, for each lesson's number of claims
        package = lesson.id.replace("-", "_")
        files = {f"{package}.py": (PROJECT_ROOT / "lessons" / package / "solution.py").read_text(encoding="utf-8")}
        digest = _digest(files, options, version)
        kept = state.get(REFERENCE, {}).get(lesson.id)
        if isinstance(kept, dict) and kept.get("hash") == digest and isinstance(kept.get("result"), dict):
            results[(REFERENCE, lesson.id)] = kept["result"]
        else:
            todo.append((REFERENCE, lesson, files, digest))
    for folder in students:
        files = _student_files(folder)
        for lesson in lessons:
            key = (folder.name, lesson.id)
            if module_file(folder, lesson.id).name not in files and notebook_file(folder, lesson.id).name not in files:
                results[key] = {"student": folder.name, "lesson": lesson.id, "rows": [], "notes": [],
                                "status": "missing", "error": ""}
                continue
            digest = _digest(files, options, version)
            kept = state.get(folder.name, {}).get(lesson.id)
            if isinstance(kept, dict) and kept.get("hash") == digest and isinstance(kept.get("result"), dict):
                results[key] = kept["result"]
            else:
                todo.append((folder.name, lesson, files, digest))
    pupils = [t for t in todo if t[0] != REFERENCE]
    out.write(f"grading {len(students)} students, {len(lessons)} lesson(s): {len(pupils)} to grade, "
              f"{sum(r['status'] != 'missing' and k[0] != REFERENCE for k, r in results.items())} unchanged since the "
              f"last run\n")
    out.flush()
    new_state = {s: dict(v) for s, v in state.items() if isinstance(v, dict)}
    started = time.time()
    if todo:
        n_items = lambda lesson: len(lesson.stages) + 8  # noqa: E731 - functions and stages, generously
        from tqdm import tqdm
        client, cluster = _client(args)
        done = 0
        try:
            futures = {client.submit(grade_task, s, lesson.id, files, options,
                                     args.time_limit * (n_items(lesson) + 2) + 120, pure=False, retries=0):
                       (s, lesson.id, digest) for s, lesson, files, digest in todo}
            from dask.distributed import as_completed
            bar = tqdm(total=len(futures), unit="grade", file=err, disable=not err.isatty())
            for future in as_completed(futures):
                s, lesson_id, digest = futures[future]
                try:
                    result = future.result()
                except Exception as exc:  # noqa: BLE001 - a worker lost: that pair only
                    result = {"student": s, "lesson": lesson_id, "rows": [], "notes": [], "status": "failed to grade",
                              "error": f"the worker failed: {type(exc).__name__}: {exc}"[:300]}
                results[(s, lesson_id)] = result
                if result["status"] == "graded":
                    new_state.setdefault(s, {})[lesson_id] = {"hash": digest, "result": result}
                    _write_atomic(outdir / STATE, json.dumps(new_state))
                done += 1
                bar.update(1)
                bar.set_postfix_str(f"{s} {lesson_id}")
            bar.close()
        except (KeyboardInterrupt, Terminated) as exc:
            signum = getattr(exc, "signum", signal.SIGINT)
            err.write(f"\n{'interrupted (SIGINT)' if signum == signal.SIGINT else f'signal {signum}'}: {done} of "
                      f"{len(todo)} graded are kept in {outdir / STATE}; the gradebook is not written. Run the same "
                      f"command again to grade the rest.\n")
            return 128 + int(signum)
        finally:
            client.close()
            if cluster is not None:
                cluster.close()
    elapsed = time.time() - started
    expected = {k[1]: len(r.get("rows") or []) for k, r in results.items() if k[0] == REFERENCE}
    rows = [r for k, r in results.items() if k[0] != REFERENCE]
    _write_atomic(outdir / "gradebook.csv", gradebook_text(rows, expected))
    for folder in students:
        mine = [r for r in rows if r["student"] == folder.name]
        (outdir / folder.name).mkdir(exist_ok=True)
        _write_atomic(outdir / folder.name / "results.json",
                      json.dumps(gradescope(mine, sum(r.get("elapsed_s", 0) for r in mine), expected), indent=1)
                      + "\n")
        _write_atomic(outdir / folder.name / "feedback.md", feedback(folder.name, mine, expected))
    graded = sum(r["status"] == "graded" for r in rows)
    failed = sum(r["status"] == "failed to grade" for r in rows)
    out.write(f"graded {len(pupils)} in {elapsed:.0f} s ({60 * len({t[0] for t in pupils}) / elapsed:.2f} students "
              f"per minute, the reference included)" if pupils and elapsed > 0 else "nothing changed: nothing graded")
    out.write(f"; {graded} graded, {failed} could not be graded, "
              f"{sum(r['status'] == 'missing' for r in rows)} missing\ngradebook: {outdir / 'gradebook.csv'}\n")
    return 1 if failed else 0
