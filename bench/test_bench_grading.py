"""Timed: a class graded by ``python -m lessons grade`` (a Dask LocalCluster of two worker processes
on this 2-core machine) against one ``python -m lessons check all`` of a single student in a fresh
process: students per minute, and what one student of a class costs against that single check.

The class is three copies of the reference solutions (every lesson, every stage: the whole grading a
student gets). The smoke profile (plain pytest, CI) grades two students on rod-waves' function
checks only, to keep the path working; the timed profiles run the 2-thread f64 configuration only."""
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from bench import config

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ["springs", "rod_waves", "area_springs", "bending", "explicit_vs_implicit", "membranes"]


def _cli(*args, cwd):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    r = subprocess.run([sys.executable, "-m", "lessons", *args], cwd=cwd, env=env, capture_output=True, text=True)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    return r


def _roster(root: Path, students: int, packages) -> None:
    for k in range(students):
        folder = root / f"student{k}"
        folder.mkdir(parents=True)
        for package in packages:
            shutil.copy(ROOT / "lessons" / package / "solution.py", folder / f"{package}.py")


def test_class_grading_students_per_minute(benchmark, tmp_path):
    if config.config_name() != "t2-f64":
        pytest.skip("the class is graded in the 2-thread f64 configuration only")
    smoke = config.profile() == "smoke"
    students = 2 if smoke else 3
    packages = ["rod_waves"] if smoke else PACKAGES
    lesson = "rod-waves" if smoke else "all"
    extra = ["--functions-only"] if smoke else []
    _roster(tmp_path / "class", students, packages)
    single = {}
    if not smoke:
        t0 = time.perf_counter()
        _cli("check", "all", "--solution", str(tmp_path / "class" / "student0"), cwd=tmp_path)
        single["check_all_s"] = time.perf_counter() - t0

    def grade():
        shutil.rmtree(tmp_path / "grades", ignore_errors=True)
        _cli("grade", "class", lesson, "--workers", "2", "--out", "grades", *extra, cwd=tmp_path)

    t0 = time.perf_counter()
    benchmark.group = "class-grading"
    benchmark.pedantic(grade, rounds=1, iterations=1, warmup_rounds=0)
    wall = time.perf_counter() - t0
    per_student = wall / students
    benchmark.extra_info.update(config=config.config_name(), profile=config.profile(), students=students,
                                lessons=len(packages), stages=not smoke, wall_s=round(wall, 2),
                                students_per_minute=round(60.0 / per_student, 3),
                                seconds_per_student=round(per_student, 2), **{k: round(v, 2) for k, v in single.items()})
    if single:
        benchmark.extra_info["per_student_over_check_all"] = round(per_student / single["check_all_s"], 3)
    import csv
    with open(tmp_path / "grades" / "gradebook.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == students * (1 if smoke else len(PACKAGES))
    assert all(row["score"] == "100" for row in rows), rows
