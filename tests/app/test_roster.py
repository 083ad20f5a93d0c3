"""python -m lessons grade: a class of 20 synthetic students graded end to end on a Dask
LocalCluster (references, wrong solutions, broken and hostile modules), the gradebook checked row
by row, the Gradescope files and the feedback read back, and a rerun that grades only what changed."""
import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.helpers import ROOT
from tests.lessons.coals import COALS

LESSONS = ["rod-waves", "springs", "area-springs", "bending", "explicit-vs-implicit", "membranes"]
REFERENCE_CLAIMS = {"springs": 10, "rod-waves": 2}   # --functions-only: the reference's own function checks


def _cli(*args, cwd, timeout=900):
    env = dict(os.environ, PYTHONPATH=str(ROOT), ELASTIC_CACHE_DIR=str(ROOT / ".ti_cache"))
    return subprocess.run([sys.executable, "-m", "lessons", *args], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=timeout)


def _reference(package: str) -> str:
    return (ROOT / "lessons" / package / "solution.py").read_text()


def _roster(root: Path) -> dict:
    """20 students: {name: {lesson: expectation}} with expectation 'full', 'partial', 'zero' or 'missing'."""
    students: dict = {}

    def add(name, springs=None, rod=None, springs_want="missing", rod_want="missing"):
        folder = root / name
        folder.mkdir(parents=True)
        if springs is not None:
            (folder / "springs.py").write_text(springs)
        if rod is not None:
            (folder / "rod_waves.py").write_text(rod)
        students[name] = {"springs": springs_want, "rod-waves": rod_want}

    for k in range(4):
        add(f"ref{k}", _reference("springs"), _reference("rod_waves"), "full", "full")
    coals = [c for c in COALS if c[0] in ("springs", "rod_waves") and c[1] != "symplectic_vec3_only"][:10]
    for k, (package, name, _, right, wrong, _, _) in enumerate(coals):
        text = _reference(package).replace(right, wrong)
        if package == "springs":
            add(f"coal{k}", springs=text, springs_want="partial")
        else:
            add(f"coal{k}", rod=text, rod_want="partial")
    add("syntax", springs="def spring_energy(d, L, c\n", springs_want="zero")
    add("engine-import", springs="from engine.energies.springs import spring_energy\n" + _reference("springs"),
        springs_want="zero")
    add("forger", springs=_reference("springs").replace(
        "import taichi as ti\n", "import numpy as np\nimport taichi as ti\n\nnp.zeros(3).dump('forged.pickle')\n"),
        springs_want="zero")
    add("hangs", rod="while True:\n    pass\n" + _reference("rod_waves"), rod_want="zero")
    add("ti-init", springs=_reference("springs").replace("import taichi as ti\n",
                                                         "import taichi as ti\nti.init(arch=ti.cpu)\n"),
        springs_want="full")
    add("template", springs=None, rod=None)   # written below, the template as handed out
    r = _cli("exercise", "springs", str(root / "template"), cwd=root)
    assert r.returncode == 0, r.stderr
    students["template"]["springs"] = "zero"
    assert len(students) == 20
    return students


@pytest.mark.slow
def test_a_class_is_graded_in_parallel_and_the_gradebook_holds_every_student(tmp_path):
    students = _roster(tmp_path / "class")
    r = _cli("grade", "class", "all", "--functions-only", "--time-limit", "20", "--out", "grades", cwd=tmp_path)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    assert "graded 24 in" in r.stdout and "students per minute" in r.stdout
    with open(tmp_path / "grades" / "gradebook.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 20 * len(LESSONS)
    for row in rows:
        want = students[row["student"]].get(row["lesson"], "missing")
        passed, total, score = int(row["passed"]), int(row["total"]), float(row["score"])
        where = (row["student"], row["lesson"], row)
        if want == "missing":
            assert row["status"] == "missing" and passed == 0, where
            continue
        assert row["status"] == "graded", where
        assert total == REFERENCE_CLAIMS[row["lesson"]], where
        copied = row["student"].startswith("ref") or row["student"] in ("ti-init", "engine-import", "forger", "hangs")
        assert row["flags"] == ("copy of the reference solution" if copied else ""), where
        if want == "full":
            assert passed == total and score == 100, where
        elif want == "partial":
            assert 0 < passed < total and score == pytest.approx(100 * passed / total, abs=0.01), where
        else:
            assert passed == 0 and score == 0, where
    assert not (tmp_path / "forged.pickle").exists()
    # each student's Gradescope file: one test per claim, the same points for everyone
    maxima = set()
    for name in students:
        doc = json.loads((tmp_path / "grades" / name / "results.json").read_text())
        assert {"score", "tests"} <= set(doc)
        for t in doc["tests"]:
            assert {"name", "score", "max_score", "status", "output"} <= set(t)
            assert t["status"] in ("passed", "failed") and 0 <= t["score"] <= t["max_score"]
        maxima.add(sum(t["max_score"] for t in doc["tests"] if not t["name"].startswith(tuple(
            l for l in LESSONS if l not in REFERENCE_CLAIMS))))
        assert doc["score"] == sum(t["score"] for t in doc["tests"])
    feedback = (tmp_path / "grades" / "engine-import" / "feedback.md").read_text()
    assert "imports from engine.energies.springs" in feedback
    assert "did not finish importing within 20 s" in (tmp_path / "grades" / "hangs" / "feedback.md").read_text()
    # a rerun grades nothing; a changed file is graded again, alone
    r = _cli("grade", "class", "all", "--functions-only", "--time-limit", "20", "--out", "grades", cwd=tmp_path)
    assert r.returncode == 0 and "0 to grade" in r.stdout, r.stdout
    (tmp_path / "class" / "syntax" / "springs.py").write_text(_reference("springs"))
    r = _cli("grade", "class", "all", "--functions-only", "--time-limit", "20", "--out", "grades", cwd=tmp_path)
    assert r.returncode == 0 and "1 to grade" in r.stdout, r.stdout
    with open(tmp_path / "grades" / "gradebook.csv", newline="") as f:
        fixed = {(row["student"], row["lesson"]): row for row in csv.DictReader(f)}
    assert fixed[("syntax", "springs")]["score"] == "100"


@pytest.mark.parametrize("args,needle", [
    (["grade", "nosuch"], "ROSTER 'nosuch' is not a folder"),
    (["grade", "class", "nolesson"], "LESSON must be one of"),
    (["grade", "class", "--workers", "0"], "--workers must be an integer in 1..64"),
    (["grade", "class", "--out", "class/x"], "is inside the roster"),
])
def test_grade_bad_input_is_one_line_and_exit_2(tmp_path, args, needle):
    (tmp_path / "class" / "alice").mkdir(parents=True)
    r = _cli(*args, cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0], r.stderr
    assert not (tmp_path / "grades").exists()


def _free_port() -> int:
    import socket
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow
def test_a_class_is_graded_on_a_running_dask_scheduler(tmp_path):
    """--scheduler: a scheduler and a worker started apart (on this machine's loopback, as they would
    run on a cluster's nodes) grade the class; the task carries the students' files."""
    import time
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    env = dict(os.environ, PYTHONPATH=str(ROOT), ELASTIC_CACHE_DIR=str(ROOT / ".ti_cache"))
    scheduler = subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1",
                                  "--port", str(port), "--dashboard-address", ":0"], env=env,
                                 stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    worker = subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_worker", address, "--nworkers", "1",
                               "--nthreads", "1", "--dashboard-address", ":0"], env=env, cwd=tmp_path,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        for name in ("ann", "ben"):
            folder = tmp_path / "class" / name
            folder.mkdir(parents=True)
            (folder / "rod_waves.py").write_text(_reference("rod_waves"))
        time.sleep(3)
        r = _cli("grade", "class", "rod-waves", "--functions-only", "--scheduler", address, "--out", "grades",
                 cwd=tmp_path)
        assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
        with open(tmp_path / "grades" / "gradebook.csv", newline="") as f:
            rows = list(csv.DictReader(f))
        assert [(row["student"], row["score"]) for row in rows] == [("ann", "100"), ("ben", "100")]
    finally:
        for proc in (worker, scheduler):
            os.killpg(proc.pid, 9)
            proc.wait()
