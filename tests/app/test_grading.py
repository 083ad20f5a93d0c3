"""python -m lessons exercise / check: the template, the grader's verdicts and its one-line reports.

The reference solutions (lessons/<id>/solution.py) pass every claim of every lesson with the
engine's kernels compiled around them; the template as written fails with one line per function;
a student's module that does not import, a function that raises, returns the wrong shape or
NaN, or loops forever is one line naming it (the function checks: tests/lessons/test_exercises.py).
"""
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.helpers import ROOT

PACKAGES = {"springs": "springs", "rod-waves": "rod_waves", "area-springs": "area_springs", "bending": "bending",
            "explicit-vs-implicit": "explicit_vs_implicit", "membranes": "membranes"}


def lessons_cli(*args, cwd, timeout=900):
    env = dict(os.environ, PYTHONPATH=str(ROOT), ELASTIC_CACHE_DIR=str(ROOT / ".ti_cache"))
    return subprocess.run([sys.executable, "-m", "lessons", *args], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=timeout)


def reference(folder: Path, *ids) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for lesson_id in ids or PACKAGES:
        shutil.copy(ROOT / "lessons" / PACKAGES[lesson_id] / "solution.py", folder / f"{PACKAGES[lesson_id]}.py")
    return folder


def test_exercise_writes_one_module_per_lesson_with_every_function_and_refuses_to_overwrite(tmp_path):
    r = lessons_cli("exercise", "all", "ex", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    for package in PACKAGES.values():
        text = (tmp_path / "ex" / f"{package}.py").read_text()
        assert "python -m lessons check" in text
    springs = (tmp_path / "ex" / "springs.py").read_text()
    for name in ("spring_energy", "spring_force", "spring_hessian", "symplectic_euler", "verlet_kick_drift",
                 "verlet_kick"):
        assert f"def {name}(" in springs
    assert "solution" not in springs.lower().replace("--solution", "")   # no answers in the template
    before = springs
    (tmp_path / "ex" / "springs.py").write_text(before + "# my work\n")
    r = lessons_cli("exercise", "springs", "ex", cwd=tmp_path)
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == [
        f"python -m lessons: error: {Path('ex') / 'springs.py'} already exists: it may hold your work; give another "
        f"DIR or move it away first"]
    assert (tmp_path / "ex" / "springs.py").read_text() == before + "# my work\n"


@pytest.mark.parametrize("args,needle", [
    (["exercise", "nosuch"], "LESSON must be one of rod-waves, springs,"),
    (["exercise"], "LESSON is required: one of rod-waves, springs,"),
    (["exercise", "springs", "a", "b"], "'exercise' takes LESSON and an optional DIR"),
    (["check", "nosuch", "--solution", "."], "LESSON must be one of rod-waves, springs,"),
    (["check", "springs", "--solution", "missing"], "--solution 'missing' is not a folder"),
    (["check", "springs", "--solution", "."], "springs.py does not exist: write it first with 'python -m lessons "
                                              "exercise springs .'"),
    (["check", "springs", "--solution", ".", "--time-limit", "0"], "--time-limit must be a number of seconds > 0"),
])
def test_bad_input_is_one_line_and_exit_2(tmp_path, args, needle):
    r = lessons_cli(*args, cwd=tmp_path)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0], r.stderr
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("lesson,folder,needle", [
    ("springs", "/proc/ex", "DIR /proc/ex: cannot write the templates there (cannot create a file in /proc/ex: "),
    ("all", "blocker/ex", "DIR blocker/ex: cannot write the templates there (blocker is a file, not a directory); "
                          "give a folder you can write to"),
    ("springs", "read-only/ex", "DIR read-only/ex: cannot write the templates there (directory "),
])
def test_a_folder_that_cannot_receive_the_templates_is_one_line_exit_2_and_nothing_written(tmp_path, lesson, folder,
                                                                                           needle):
    """It was an internal error (exit 1) once the folder's creation failed."""
    (tmp_path / "blocker").write_text("a file where a folder is expected")
    (tmp_path / "read-only").mkdir(mode=0o555)
    if folder.startswith("read-only") and os.access(tmp_path / "read-only", os.W_OK):
        pytest.skip("root writes into a read-only folder (the /proc case covers a folder that refuses files)")
    r = lessons_cli("exercise", lesson, folder, cwd=tmp_path)
    assert r.returncode == 2, (r.stdout, r.stderr)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"python -m lessons: error: {needle}"), r.stderr
    assert r.stdout == "" and sorted(p.name for p in tmp_path.rglob("*")) == ["blocker", "read-only"]


def test_templates_are_written_all_or_none(tmp_path, monkeypatch):
    """Missing folders are created; a write that fails (a full disk) leaves neither templates nor folders."""
    import errno
    import io

    from lessons.app.cli import OutputFailed
    from lessons.app.exercises import write_template
    from lessons.app.outfile import OutputFile, OutputWriteError
    monkeypatch.chdir(tmp_path)
    assert write_template(["springs", "new/deeper/ex"], io.StringIO()) == 0
    assert sorted(p.name for p in (tmp_path / "new" / "deeper" / "ex").iterdir()) == ["springs.py"]
    write = OutputFile.write_bytes

    def write_bytes(self, data):
        if self.path.name == "bending.py":
            self.discard()
            raise OutputWriteError(errno.ENOSPC, "No space left on device after 0 of 10 bytes")
        return write(self, data)
    monkeypatch.setattr(OutputFile, "write_bytes", write_bytes)
    with pytest.raises(OutputFailed, match=r"^DIR full/ex: could not write the templates \(No space left on device "
                                           r"after 0 of 10 bytes\); nothing is left there$"):
        write_template(["all", "full/ex"], io.StringIO())
    assert not (tmp_path / "full").exists()


def test_the_template_as_written_fails_with_one_line_per_function(tmp_path):
    assert lessons_cli("exercise", "all", "ex", cwd=tmp_path).returncode == 0
    r = lessons_cli("check", "all", "--solution", "ex", "--results", "out.json", cwd=tmp_path)
    assert r.returncode == 1, r.stderr
    assert r.stderr == "" or "Traceback" not in r.stderr
    written = [line for line in r.stdout.splitlines() if "not written yet" in line]
    assert len(written) == 15   # springs 6, rod-waves 1, area-springs 1, bending 2, explicit-vs-implicit 3, membranes 2
    doc = json.loads((tmp_path / "out.json").read_text())
    assert doc["failed"] == len(doc["experiments"]) and doc["passed"] == 0
    assert {row["lesson"] for row in doc["experiments"]} == set(PACKAGES)


def test_the_reference_solutions_pass_every_check_of_every_lesson(tmp_path):
    reference(tmp_path / "ref")
    r = lessons_cli("check", "all", "--solution", "ref", "--results", "out.json", cwd=tmp_path, timeout=1500)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr
    doc = json.loads((tmp_path / "out.json").read_text())
    assert doc["failed"] == 0 and doc["complete"]
    rows = doc["experiments"]
    functions = [row for row in rows if row["stage"] == 0]
    assert len(functions) >= 14
    for lesson_id in PACKAGES:   # every stage of every lesson ran on the student's functions
        stages = {row["stage"] for row in rows if row["lesson"] == lesson_id and row["stage"] > 0}
        assert len(stages) >= 3, (lesson_id, stages)
    assert not [row for row in rows if row["id"].endswith("-ran")]


STAGE_CATCHES = [
    # (the reference's line, the wrong line, the stage, a lesson experiment that fails on it, the function check)
    ("return x + dt * v_new, v_new", "return x + dt * v, v_new", 2, "no-blow-up-stage2", "ex-symplectic-euler"),
    ("K = (c / (L * L)) * (nnT + (1.0 - L / l) * (ti.math.eye(3) - nnT))",
     "K = -(c / (L * L)) * (nnT + (1.0 - L / l) * (ti.math.eye(3) - nnT))", 5, "hanging-uniform-converged",
     "ex-spring-hessian"),
]


@pytest.mark.parametrize("right,wrong,stage,lesson_claim,function_claim", STAGE_CATCHES,
                         ids=["forward-euler", "hessian-sign"])
def test_a_mistake_is_caught_by_the_lessons_own_experiments_too(tmp_path, right, wrong, stage, lesson_claim,
                                                                function_claim):
    """Forward Euler written for symplectic Euler blows the energy-conservation stage up; a Hessian
    of the wrong sign stops the hanging rod's static (Newton) solve; the function checks name both."""
    folder = reference(tmp_path / "s", "springs")
    path = folder / "springs.py"
    assert right in path.read_text()
    path.write_text(path.read_text().replace(right, wrong))
    r = lessons_cli("check", "springs", "--solution", "s", "--stage", str(stage), "--results", "out.json",
                    cwd=tmp_path)
    assert r.returncode == 1
    failed = {row["id"]: row for row in json.loads((tmp_path / "out.json").read_text())["experiments"]
              if not row["passed"]}
    assert function_claim in failed
    assert failed[lesson_claim]["stage"] == stage
    assert f"FAIL {lesson_claim}: " in r.stdout and "(this stage ran on your " in r.stdout


BROKEN = [
    ("syntax", "def spring_energy(d, L, c):\n", "ex-module", "springs.py: line"),
    ("raises", "    v_new = v + dt * a\n", "ex-symplectic-euler-runs", "symplectic_euler: could not be compiled or run"),
    ("shape", "    return 0.5 * c * strain * strain\n", "ex-spring-energy-runs",
     "spring_energy: the Taichi compiler crashed on it (signal 6): check that it returns float"),
    ("nan", "    return 0.5 * c * strain * strain\n", "ex-spring-energy", "returns NaN or inf"),
    ("vec3-only", "    v_new = v + dt * a\n", "ex-symplectic-euler-runs",
     "symplectic_euler: the Taichi compiler crashed on it (signal 6)"),
]


@pytest.mark.parametrize("kind,line,caught_by,needle", BROKEN, ids=[b[0] for b in BROKEN])
def test_a_broken_function_is_one_line_that_names_it(tmp_path, kind, line, caught_by, needle):
    folder = reference(tmp_path / "s", "springs")
    path = folder / "springs.py"
    text = path.read_text()
    assert line in text
    new = {"syntax": "def spring_energy(d, L, c\n",
           "raises": "    v_new = v + dt * a\n    v_new = undefined_name\n",
           "shape": "    return ti.math.vec3(0.5 * c * strain * strain)\n",
           "nan": "    return 0.5 * c * strain * strain * (d.norm() - d.norm()) / (d.norm() - d.norm())\n",
           # results declared as vectors: works for vec3 states, crashes the compiler on floats
           "vec3-only": "    v_new = ti.math.vec3(0.0)\n    v_new = v + dt * a\n"}[kind]
    path.write_text(text.replace(line, new, 1))
    r = lessons_cli("check", "springs", "--solution", "s", "--functions-only", "--results", "out.json", cwd=tmp_path)
    assert r.returncode == 1
    assert "Traceback" not in r.stdout + r.stderr
    rows = {row["id"]: row for row in json.loads((tmp_path / "out.json").read_text())["experiments"]}
    assert not rows[caught_by]["passed"]
    assert needle in rows[caught_by]["reason"], rows[caught_by]["reason"]
    assert "\n" not in rows[caught_by]["reason"]


def test_an_endless_loop_is_stopped_at_the_time_limit_and_the_other_functions_are_still_checked(tmp_path):
    folder = reference(tmp_path / "s", "springs")
    path = folder / "springs.py"
    text = path.read_text()
    path.write_text(text.replace("    v_half = v + 0.5 * dt * a\n",
                                 "    v_half = v + 0.5 * dt * a\n    k = 1.0\n    while k > 0.0:\n"
                                 "        k = k + 1.0\n", 1))
    r = lessons_cli("check", "springs", "--solution", "s", "--functions-only", "--time-limit", "20",
                    "--results", "out.json", cwd=tmp_path)
    assert r.returncode == 1
    rows = {row["id"]: row for row in json.loads((tmp_path / "out.json").read_text())["experiments"]}
    assert rows["ex-verlet-kick-drift-runs"]["reason"] == "verlet_kick_drift: stopped after 20 s (an endless loop?)"
    assert rows["ex-verlet-kick"]["passed"] and rows["ex-spring-energy"]["passed"]


def test_an_interrupted_check_stops_its_child_and_exits_130(tmp_path):
    import signal
    import time
    folder = reference(tmp_path / "s", "springs")
    path = folder / "springs.py"
    path.write_text(path.read_text().replace("    v_half = v + 0.5 * dt * a\n",
                                             "    v_half = v + 0.5 * dt * a\n    k = 1.0\n    while k > 0.0:\n"
                                             "        k = k + 1.0\n", 1))
    env = dict(os.environ, PYTHONPATH=str(ROOT), ELASTIC_CACHE_DIR=str(ROOT / ".ti_cache"))
    proc = subprocess.Popen([sys.executable, "-m", "lessons", "check", "springs", "--solution", "s",
                             "--functions-only"], cwd=tmp_path, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    time.sleep(12)   # the checks have reached the endless loop
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    left = subprocess.run(["pgrep", "-f", f"grading_child springs {folder}"], capture_output=True, text=True)
    assert left.stdout.strip() == "", "a child of the check is still running"


# ------------------------------------------------------------------ solutions that try to pass without the physics

def _springs_with(tmp_path, head: str = "", replace: tuple = ()) -> Path:
    folder = reference(tmp_path / "s", "springs")
    path = folder / "springs.py"
    text = path.read_text()
    for old, new in replace:
        assert old in text
        text = text.replace(old, new, 1)
    path.write_text(text.replace("import taichi as ti\n", "import taichi as ti\n" + head, 1))
    return folder


def _rows(tmp_path) -> dict:
    return {row["id"]: row for row in json.loads((tmp_path / "out.json").read_text())["experiments"]}


@pytest.mark.parametrize("head,needle", [
    ("from engine.energies.springs import spring_force as engine_force\n", "imports from engine.energies.springs"),
    ("import lessons.springs.solution as answer\n", "imports lessons.springs.solution"),
    ("import sys\n", "imports sys"),
    ("import numpy as np\nnp.abs = lambda x: 0.0 * x\n", "changes np.abs"),
    ("import numpy as np\nhelper = getattr(np, 'sy' + 's')\n", "uses getattr"),
    ("open('/tmp/forged.jsonl', 'a').write('{}')\n", "uses open"),
    ("k = ti.lang.impl.__dict__\n", "private attribute .__dict__"),
    ("import numpy as np\nm = np\nm.abs = None\n", "uses the module numpy as a value"),
    ("import numpy as np\nla = np.linalg\n", "uses the module numpy.linalg as a value"),
    ("import taichi as ti\nhints = ti.aot.module\n", "reaches ti.aot"),
    ("from numpy.f2py.crackfortran import myeval\n", "imports from numpy.f2py.crackfortran"),
    ("def probe(f: \"x\"):\n    pass\n", "has a string as an annotation"),
    ("import numpy as np\nget = np.ma.core.operator.attrgetter\n", "reaches .attrgetter"),
    ("from numpy.linalg._linalg import norm\n", "imports from numpy.linalg._linalg"),
    ("match ti.init:\n    case object(x=y):\n        pass\n", "uses a match statement"),
])
def test_a_module_that_reaches_past_its_arguments_is_refused_in_one_line_before_it_runs(tmp_path, head, needle):
    _springs_with(tmp_path, head)
    r = lessons_cli("check", "springs", "--solution", "s", "--functions-only", "--results", "out.json", cwd=tmp_path)
    assert r.returncode == 1
    rows = _rows(tmp_path)
    assert not rows["ex-module-rules"]["passed"]
    assert needle in rows["ex-module-rules"]["reason"], rows["ex-module-rules"]["reason"]
    assert "springs.py: line " in rows["ex-module-rules"]["reason"]
    assert all(not row["passed"] for row in rows.values())
    assert not Path("/tmp/forged.jsonl").exists()


def test_a_forgery_the_reading_misses_is_stopped_when_it_runs_and_fails_the_module(tmp_path):
    """ndarray.dump writes a file: the guard ends the student's process at the attempt, and every
    function then fails with its reason (nothing the solution wrote reaches the verdicts)."""
    target = tmp_path / "forged.pickle"
    _springs_with(tmp_path, f"import numpy as np\nnp.zeros(3).dump({str(target)!r})\n")
    r = lessons_cli("check", "springs", "--solution", "s", "--results", "out.json", cwd=tmp_path)
    assert r.returncode == 1
    rows = _rows(tmp_path)
    assert not target.exists()
    assert rows and all(not row["passed"] for row in rows.values())
    assert "the solution tried to write" in rows["ex-spring-energy-runs"]["reason"]
    assert "not run:" in rows["stage1-ran"]["reason"]


def test_ti_init_in_a_solution_is_ignored_and_said(tmp_path):
    folder = reference(tmp_path / "s", "membranes")
    path = folder / "membranes.py"
    path.write_text(path.read_text().replace("import taichi as ti\n", "import taichi as ti\n\nti.init(arch=ti.cpu)\n"))
    r = lessons_cli("check", "membranes", "--solution", "s", "--stage", "1", "--results", "out.json", cwd=tmp_path)
    assert r.returncode == 0, r.stdout[-2000:]
    assert "note: membranes.py: line 4: calls ti.init(...): the grader ignores it" in r.stdout
    doc = json.loads((tmp_path / "out.json").read_text())
    assert doc["failed"] == 0 and any("ti.init" in n for n in doc["notes"])


def test_a_hang_at_import_is_charged_once(tmp_path, monkeypatch):
    """A module that never finishes importing is started once: the grader does not start it again for
    each function or stage (each start would wait out the time limit). The witness is the count of
    grading-child starts (the check runs in this process, its children as always)."""
    from lessons.app import cli, grading_remote
    _springs_with(tmp_path, "k = 1.0\nwhile k > 0.0:\n    k = k + 1.0\n")
    starts = []
    start = grading_remote.Server.start
    monkeypatch.setattr(grading_remote.Server, "start", lambda self: starts.append(self.lesson_id) or start(self))
    monkeypatch.chdir(tmp_path)
    rc = cli.main(["check", "springs", "--solution", "s", "--time-limit", "15", "--results", "out.json"])
    assert rc == 1
    rows = _rows(tmp_path)
    assert rows["ex-spring-energy-runs"]["reason"] == ("your module did not finish importing within 15 s (an endless "
                                                      "loop at import?)")
    assert starts == ["springs"], starts


@pytest.mark.parametrize("results", ["s/springs.py", "s/answer.py", "out.py"])
def test_results_that_would_replace_the_solution_are_refused_up_front(tmp_path, results):
    folder = reference(tmp_path / "s", "springs")
    before = (folder / "springs.py").read_text()
    r = lessons_cli("check", "springs", "--solution", "s", "--functions-only", "--results", results, cwd=tmp_path)
    assert r.returncode == 2
    assert len(r.stderr.strip().splitlines()) == 1 and "--results" in r.stderr
    assert (folder / "springs.py").read_text() == before
    assert sorted(p.name for p in folder.iterdir()) == ["springs.py"]


def test_killing_the_grader_ends_its_child(tmp_path):
    import signal
    import time
    folder = _springs_with(tmp_path, replace=[("    v_half = v + 0.5 * dt * a\n",
                                               "    v_half = v + 0.5 * dt * a\n    k = 1.0\n    while k > 0.0:\n"
                                               "        k = k + 1.0\n")])
    env = dict(os.environ, PYTHONPATH=str(ROOT), ELASTIC_CACHE_DIR=str(ROOT / ".ti_cache"))
    proc = subprocess.Popen([sys.executable, "-m", "lessons", "check", "springs", "--solution", "s",
                             "--functions-only"], cwd=tmp_path, env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    time.sleep(12)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    for _ in range(50):
        left = subprocess.run(["pgrep", "-f", f"grading_child springs {folder}"], capture_output=True, text=True)
        if not left.stdout.strip():
            break
        time.sleep(0.2)
    assert left.stdout.strip() == "", "the grading child outlived a killed grader"


def test_an_interrupted_check_writes_its_partial_results(tmp_path):
    import signal
    import time
    _springs_with(tmp_path, replace=[("    v_half = v + 0.5 * dt * a\n",
                                      "    v_half = v + 0.5 * dt * a\n    k = 1.0\n    while k > 0.0:\n"
                                      "        k = k + 1.0\n")])
    env = dict(os.environ, PYTHONPATH=str(ROOT), ELASTIC_CACHE_DIR=str(ROOT / ".ti_cache"))
    proc = subprocess.Popen([sys.executable, "-m", "lessons", "check", "springs", "--solution", "s",
                             "--functions-only", "--results", "out.json"], cwd=tmp_path, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(12)
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 130
    assert not (tmp_path / "out.json").exists()
    doc = json.loads((tmp_path / "out.partial.json").read_text())
    assert doc["complete"] is False and doc["exit_reason"] == "interrupted (SIGINT)"
    assert doc["experiments"] == [] or all("id" in row for row in doc["experiments"])
    assert "partial" in out


def test_malformed_stage_rows_are_a_failed_claim_never_an_internal_error():
    from lessons.app.grading_remote import printable, validated_rows
    assert printable("a\x1b[2Kb\nc") == "a\\x1b[2Kb\\nc"   # terminal escapes from a student's message are shown, not run
    good = {"id": "a-claim", "claim": "c", "theory": 1.0, "measured": 1.0, "tolerance": 0.1, "comparison": "rel",
            "passed": False}
    assert validated_rows([good], "springs", 1, "t")[0]["passed"] is True   # the verdict is recomputed here
    for bad in ([], "rows", [1], [dict(good, id=3)], [dict(good, measured="1")], [dict(good, comparison="==")],
                [good, good], [dict(good, tolerance=True)]):
        with pytest.raises(ValueError):
            validated_rows(bad, "springs", 1, "t")


def test_every_equation_a_template_cites_is_defined_in_it(tmp_path):
    import re
    assert lessons_cli("exercise", "all", "ex", cwd=tmp_path).returncode == 0
    for package in PACKAGES.values():
        text = (tmp_path / "ex" / f"{package}.py").read_text()
        cited = set(re.findall(r"\(([A-Z]{1,2}\d?)\)", text)) - {"E", "N", "X", "P", "D"}
        defined = set(re.findall(r"^\(([A-Z]{1,2}\d?)\) ", text, flags=re.M))
        assert cited <= defined, (package, cited - defined)


def test_a_link_to_the_reference_is_refused_and_a_copy_of_it_flagged(tmp_path):
    linked = tmp_path / "linked"
    linked.mkdir()
    (linked / "springs.py").symlink_to(ROOT / "lessons" / "springs" / "solution.py")
    r = lessons_cli("check", "springs", "--solution", "linked", "--functions-only", "--results", "out.json",
                    cwd=tmp_path)
    assert r.returncode == 1
    rows = _rows(tmp_path)
    assert "is a link to" in rows["ex-module-rules"]["reason"] and "outside the solution folder" in \
        rows["ex-module-rules"]["reason"]
    reference(tmp_path / "copied", "springs")
    r = lessons_cli("check", "springs", "--solution", "copied", "--functions-only", "--results", "out.json",
                    cwd=tmp_path)
    assert r.returncode == 0   # a copy computes the physics: it passes, and the instructor is told
    doc = json.loads((tmp_path / "out.json").read_text())
    assert doc["flags"] == {"springs": ["copy of the reference solution"]}
    assert "every function is the reference solution shipped with the suite" in r.stdout
    # one function written another way is not a copy
    folder = _springs_with(tmp_path / "own", replace=[("return 0.5 * c * strain * strain",
                                                       "return c * strain * strain / 2.0")])
    r = lessons_cli("check", "springs", "--solution", str(folder), "--functions-only", "--results", "out.json",
                    cwd=tmp_path)
    assert r.returncode == 0 and json.loads((tmp_path / "out.json").read_text())["flags"] == {}


def test_the_module_is_compiled_from_its_source_never_from_a_bytecode_cache(tmp_path):
    """A __pycache__ file compiled from other code (unchecked hash: Python would trust it) is not
    what runs: the grader compiles the source it read."""
    import importlib.util
    import py_compile
    folder = reference(tmp_path / "s", "springs")
    path = folder / "springs.py"
    good = path.read_text()
    path.write_text(good.replace("return 0.5 * c * strain * strain", "return 0.0 * c * strain * strain"))
    py_compile.compile(str(path), cfile=importlib.util.cache_from_source(str(path)),
                       invalidation_mode=py_compile.PycInvalidationMode.UNCHECKED_HASH)
    path.write_text(good.replace("return 0.5 * c * strain * strain", "return 0.5 * c * strain * strain  # mine"))
    r = lessons_cli("check", "springs", "--solution", "s", "--functions-only", "--results", "out.json", cwd=tmp_path)
    assert r.returncode == 0, r.stdout[-2000:]
    assert _rows(tmp_path)["ex-spring-energy"]["passed"]


def test_a_module_too_deep_for_the_parser_is_one_line_not_an_internal_error(tmp_path):
    folder = reference(tmp_path / "s", "springs")
    (folder / "springs.py").write_text("x = " + "-" * 3000 + "1\n")
    r = lessons_cli("check", "springs", "--solution", "s", "--functions-only", "--results", "out.json", cwd=tmp_path)
    assert r.returncode == 1 and "internal error" not in r.stderr
    assert "nests too deeply" in _rows(tmp_path)["ex-module"]["reason"]
