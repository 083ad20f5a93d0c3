"""The command line: list, help, runs, results JSON, and one-line errors for bad input."""
import io
import re
import sys

import pytest

from lessons.app.results import read_results, result_rows
from tests.helpers import cli, main_in


def test_list_prints_one_line_per_lesson(tmp_path):
    r = cli("list", cwd=tmp_path)
    assert r.returncode == 0
    lines = r.stdout.strip().splitlines()
    assert any(l.startswith("rod-waves ") and "4 stages" in l for l in lines)
    assert all("stages" in l for l in lines)


def test_lesson_help_explains_parameters_with_defaults_and_units(tmp_path):
    r = cli("run", "rod-waves", "--help", cwd=tmp_path)
    assert r.returncode == 0
    out = " ".join(r.stdout.split())
    assert "--E FLOAT Young's modulus" in out and "[N]" in out and "(default: 1.0)" in out
    assert "--rho FLOAT" in out and "[kg/m]" in out
    for option in ("--stage", "--pause", "--record", "--no-record", "--results", "--threads", "--arch", "--view",
                   "--cfl"):
        assert option in out


def test_run_one_stage_writes_recording_and_results(tmp_path):
    r = cli("run", "rod-waves", "--stage", "1", "--results", "res.json", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "recordings" / "rod-waves.rrd").exists()
    rows = result_rows(tmp_path / "res.json")
    assert rows and all(set(row) >= {"lesson", "stage", "claim", "theory", "measured", "tolerance", "passed"}
                        for row in rows)
    assert all(row["lesson"] == "rod-waves" and row["stage"] == 1 and row["passed"] for row in rows)
    assert "claim" in r.stdout and "PASS" in r.stdout


def test_failed_experiment_gives_exit_1_and_is_in_results(tmp_path):
    # forward Euler gains energy on every oscillation: its scene run is stopped and the stage fails
    r = cli("run", "rod-waves", "--stage", "2", "--integrator", "forward-euler", "--no-record", "--results",
            "res.json", cwd=tmp_path)
    assert r.returncode == 1
    rows = result_rows(tmp_path / "res.json")
    assert any(not row["passed"] for row in rows)
    assert "FAIL" in r.stdout
    assert not (tmp_path / "recordings").exists()


@pytest.mark.parametrize("args,needle", [
    (["run", "no-such-lesson"], "LESSON must be one of"),
    (["run", "rod-waves", "--E", "-1"], "--E must be ≥ 1e-06 and ≤ 1e+12 (got -1.0)"),
    (["run", "rod-waves", "--E", "0"], "--E must be ≥ 1e-06"),
    (["run", "rod-waves", "--E", "1e300"], "--E must be ≥ 1e-06 and ≤ 1e+12 (got 1e+300)"),
    (["run", "rod-waves", "--rho", "0"], "--rho must be ≥ 1e-06"),
    (["run", "rod-waves", "--rho", "-3"], "--rho must be ≥ 1e-06"),
    (["run", "springs", "--rho", "1e-300"], "--rho must be ≥ 1e-06 and ≤ 1e+06 (got 1e-300)"),
    (["run", "rod-waves", "--cfl", "0"], "--cfl must be > 0 and ≤ 1 (got 0.0)"),
    (["run", "rod-waves", "--cfl", "50"], "--cfl must be > 0 and ≤ 1 (got 50.0)"),  # was run at 1, recorded as 50
    (["run", "rod-waves", "--cfl", "1.0001"], "--cfl must be > 0 and ≤ 1 (got 1.0001)"),
    (["run", "rod-waves", "--cfl", "nan"], "--cfl must be a finite number"),
    (["run", "rod-waves", "--cfl", "-0.5"], "--cfl must be > 0"),
    (["run", "rod-waves", "--nodes", "2"], "--nodes must be ≥ 101"),
    (["run", "rod-waves", "--nodes", "abc"], "--nodes must be an integer"),
    (["run", "rod-waves", "--stage", "9"], "--stage must be in 1..4"),
    (["run", "rod-waves", "--record", "blocker/sub/x.rrd"], "--record blocker/sub/x.rrd: cannot write there (blocker is a file, not a directory)"),
    (["run", "rod-waves", "--record", "new/" + "b" * 300 + ".rrd"], "cannot write there (File name too long)"),
    (["run", "rod-waves", "--threads", "0"], "--threads must be an integer in 1..256"),
    (["run", "rod-waves", "--arch", "tpu"], "--arch must be one of cpu, cuda, vulkan"),
    (["run", "rod-waves", "--integrator", "rk4"], "--integrator must be one of default, forward-euler"),
    (["run", "all", "--integrator", "implicit"], "--integrator must be one of"),
    (["run", "bending", "--solver", "lu"], "--solver must be one of default, pcg, cholesky"),
    (["run", "springs", "--tol", "0"], "--tol must be > 0 and < 1 (got 0.0)"),
    (["run", "springs", "--tol", "inf"], "--tol must be a finite number"),
    (["run", "springs", "--newton-iterations", "0"], "--newton-iterations must be ≥ 1 and ≤ 100 (got 0)"),
    (["run"], "LESSON is required"),
    (["frobnicate"], "command must be 'list', 'run', 'exercise', 'check', 'grade', 'view' or 'notebook'"),
])
def test_bad_input_is_one_line_exit_2_and_writes_nothing(tmp_path, args, needle):
    (tmp_path / "blocker").write_text("a file where a directory is expected")
    r = cli(*args, cwd=tmp_path)
    assert r.returncode == 2, (r.stdout, r.stderr)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    assert needle in lines[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["blocker"]


def test_stepping_options_are_listed_in_help(tmp_path):
    r = cli("run", "bending", "--help", cwd=tmp_path)
    assert r.returncode == 0
    out = " ".join(r.stdout.split())
    for option in ("--integrator NAME", "--solver NAME", "--tol FLOAT", "--newton-iterations INT"):
        assert option in out
    assert "backward-euler" in out and "cholesky" in out


def test_integrator_choice_reaches_the_runs_and_the_results(tmp_path):
    r = cli("run", "bending", "--stage", "5", "--integrator", "backward-euler", "--solver", "pcg",
            "--tol", "1e-9", "--no-record", "--results", "res.json", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "integrators: backward-euler (pcg, tol 1e-09)" in r.stdout
    rows = result_rows(tmp_path / "res.json")
    assert rows and all(row["integrators"] == ["backward-euler (pcg, tol 1e-09)"] for row in rows)


def test_unavailable_gpu_arch_is_a_clear_error(tmp_path):
    r = cli("run", "rod-waves", "--arch", "cuda", "--stage", "1", cwd=tmp_path)
    if r.returncode == 0:  # a machine with CUDA: then it simply ran
        assert "PASS" in r.stdout
        return
    assert r.returncode == 2
    assert "--arch cuda is not available on this machine" in r.stderr.strip().splitlines()[-1]
    assert not (tmp_path / "recordings").exists()


def test_view_without_display_says_so(tmp_path):
    r = cli("run", "rod-waves", "--stage", "1", "--view", cwd=tmp_path, env={"DISPLAY": "", "WAYLAND_DISPLAY": ""})
    assert r.returncode == 0
    assert "cannot start the Rerun viewer: no display" in r.stdout
    assert "rerun " in r.stdout


def test_an_internal_error_is_one_line_and_exit_1(tmp_path, monkeypatch, capsys):
    import lessons.app.cli as cli_mod

    def boom(*args, **kwargs):
        raise ZeroDivisionError("float division by zero")

    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("ELASTIC_DEBUG", raising=False)
    monkeypatch.setattr(cli_mod, "run_lesson", boom)
    assert cli_mod.main(["run", "rod-waves", "--stage", "1", "--no-record"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "internal error" in err[0] and "ZeroDivisionError" in err[0]
    assert "ELASTIC_DEBUG=1" in err[0]
    monkeypatch.setenv("ELASTIC_DEBUG", "1")
    with pytest.raises(ZeroDivisionError):
        cli_mod.main(["run", "rod-waves", "--stage", "1", "--no-record"])


# --------------------------------------------------------------------------------------------
# --stage lists and ranges, --pause (in process: rod-waves' stages take well under a second)
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("values,expected", [
    (["3"], [3]),
    (["2-4"], [2, 3, 4]),
    (["1,3,5"], [1, 3, 5]),
    (["2-3,5"], [2, 3, 5]),
    (["3-3"], [3]),
    (["5,1-2"], [1, 2, 5]),            # ascending, whatever the order given
    (["2-4,3", "4"], [2, 3, 4]),        # each stage once
    (["1", "3"], [1, 3]),              # a repeated --stage adds stages
    (["4-5", "1", "3,1"], [1, 3, 4, 5]),
    ([" 2 - 3 , 5 "], [2, 3, 5]),
    (["1-5"], [1, 2, 3, 4, 5]),
])
def test_parse_stages_takes_numbers_lists_ranges_and_repeats(values, expected):
    from lessons.app.arguments import parse_stages
    assert parse_stages(values, 5, "springs") == expected


@pytest.mark.parametrize("values,shown", [
    (["0"], "(got 0)"), (["6"], "(got 6)"), (["-2"], "(got -2)"), (["4-2"], "(got '4-2')"),
    (["a"], "(got 'a')"), ([""], "(got '')"), (["-"], "(got '-')"), (["1,"], "(got '1,')"),
    (["1,,3"], "(got '1,,3')"), (["2-"], "(got '2-')"), (["-3"], "(got -3)"), (["1-6"], "(got '1-6')"),
    (["1.5"], "(got '1.5')"), (["1-2-3"], "(got '1-2-3')"), (["\u0663"], "(got '\u0663')"),
    (["2", "9"], "(got 9)"),
])
def test_parse_stages_rejects_bad_forms_naming_the_range(values, shown):
    from lessons.app.arguments import UsageError, parse_stages
    with pytest.raises(UsageError) as info:
        parse_stages(values, 5, "springs")
    message = str(info.value)
    assert message.startswith("--stage must be in 1..5 for springs: stage numbers, a list (1,3), a range (2-3)")
    assert message.endswith(shown)


def _stages_run(out, lesson="rod-waves"):
    """The stage numbers whose headers ("== <id> · stage i/n: title") the output shows, in order."""
    return [int(i) for i in re.findall(rf"^== {re.escape(lesson)} · stage (\d+)/\d+: ", out, re.MULTILINE)]


@pytest.mark.parametrize("argv,needle", [
    (["--stage", "7"], "--stage must be in 1..4 for rod-waves: stage numbers, a list (1,3), a range (2-3) "
                       "or both (1,2-3) (got 7)"),
    (["--stage", "0"], "--stage must be in 1..4 for rod-waves: "),
    (["--stage", "4-2"], "--stage must be in 1..4 for rod-waves: "),
    (["--stage", "a"], "(got 'a')"),
    (["--stage", ""], "(got '')"),
    (["--stage", "-"], "(got '-')"),
    (["--stage=1,"], "(got '1,')"),
    (["--stage", "1", "--stage", "5"], "--stage must be in 1..4 for rod-waves: "),  # each repeat is checked
    (["--stage", "2-9"], "(got '2-9')"),
])
def test_bad_stage_values_are_one_line_exit_2_and_write_nothing(monkeypatch, tmp_path, capsys, argv, needle):
    import lessons.app.cli as cli_mod
    monkeypatch.setattr(cli_mod, "run_lesson", lambda *a, **k: pytest.fail("a stage ran"))
    rc, out, err = main_in(tmp_path, monkeypatch, capsys, "run", "rod-waves", *argv, "--results", "res.json")
    assert rc == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("python -m lessons: error: --stage must be in 1..4"), err
    assert needle in lines[0]
    assert list(tmp_path.iterdir()) == []


def test_stage_with_all_is_still_refused(monkeypatch, tmp_path, capsys):
    rc, out, err = main_in(tmp_path, monkeypatch, capsys, "run", "all", "--stage", "1-2", "--no-record")
    assert rc == 2 and "--stage needs a single lesson, not 'all'" in err and len(err.strip().splitlines()) == 1


def test_stage_list_and_repeats_run_those_stages_in_ascending_order(monkeypatch, tmp_path, capsys):
    rc, out, err = main_in(tmp_path, monkeypatch, capsys, "run", "rod-waves", "--stage", "4,1", "--stage", "1-1",
                         "--no-record", "--quiet", "--results", "res.json")
    assert rc == 0, err
    assert _stages_run(out) == [1, 4]
    rows = result_rows(tmp_path / "res.json")
    assert sorted({row["stage"] for row in rows}) == [1, 4]


class _FakeTty(io.StringIO):
    """What the user types, on a stream that says it is a terminal."""

    def isatty(self):
        return True


@pytest.mark.parametrize("stdin", [io.StringIO("\n"), None])
def test_pause_is_refused_when_stdin_is_not_a_tty(monkeypatch, tmp_path, capsys, stdin):
    import lessons.app.cli as cli_mod
    monkeypatch.setattr(cli_mod, "run_lesson", lambda *a, **k: pytest.fail("a stage ran"))
    monkeypatch.setattr(sys, "stdin", stdin)  # None: no stdin at all (e.g. a detached process)
    rc, out, err = main_in(tmp_path, monkeypatch, capsys, "run", "rod-waves", "--pause", "--results", "res.json")
    assert rc == 2
    assert err.strip().splitlines() == [
        "python -m lessons: error: --pause needs an interactive terminal (stdin is not a tty); run without "
        "--pause, or with --stage N to run one stage"]
    assert list(tmp_path.iterdir()) == []  # neither recordings/ nor res.json


def test_pause_waits_for_enter_between_stages_and_q_stops(monkeypatch, tmp_path, capsys):
    stdin = _FakeTty("\nq\n")
    rc, out, err = main_in(tmp_path, monkeypatch, capsys, "run", "rod-waves", "--stage", "1-2,4", "--pause",
                         "--no-record", "--quiet", "--results", "res.json", stdin=stdin)
    assert rc == 0, err
    assert _stages_run(out) == [1, 2]
    assert "press Enter for stage 2/4: sound waves, or q + Enter to stop" in out
    assert "press Enter for stage 4/4: a heterogeneous rod, or q + Enter to stop" in out
    assert out.index("stage 1/4: energy") < out.index("press Enter for stage 2/4") < out.index("== rod-waves · stage 2/4")
    assert "stopped before stage 4/4" in out
    assert stdin.read() == ""  # both answers read, nothing more asked
    # stopped before stage 4: the results are those of a partial run, beside (not over) res.json
    assert not (tmp_path / "res.json").exists()
    doc = read_results(tmp_path / "res.partial.json")
    assert doc["complete"] is False and doc["exit_reason"] == "stopped at --pause" and doc["exit_code"] == 0
    assert doc["stages_requested"] == {"rod-waves": [1, 2, 4]} and doc["stages_completed"] == {"rod-waves": [1, 2]}
    assert sorted({row["stage"] for row in doc["experiments"]}) == [1, 2]
    assert re.search(r"^(\d+) of \1 experiments passed \(the run did not complete: stopped at --pause\)$", out,
                     re.MULTILINE)


def test_pause_stops_at_end_of_input_and_keeps_the_exit_code_of_what_ran(monkeypatch, tmp_path, capsys):
    # stage 2 fails under forward Euler; Ctrl-D (end of input) at the prompt stops like q
    rc, out, err = main_in(tmp_path, monkeypatch, capsys, "run", "rod-waves", "--stage", "2,4", "--integrator",
                         "forward-euler",
                         "--pause", "--no-record", "--quiet", "--results", "res.json", stdin=_FakeTty(""))
    assert rc == 1
    assert _stages_run(out) == [2]
    assert "stopped before stage 4/4" in out and "FAILED" in out
    rows = result_rows(tmp_path / "res.partial.json")  # written, as a partial run
    assert {row["stage"] for row in rows} == {2} and not all(row["passed"] for row in rows)


def test_pause_with_all_pauses_between_stages_and_between_lessons(monkeypatch, tmp_path, capsys):
    from lessons.app import registry
    first, second = registry.all_lessons()[:2]
    n = len(registry.all_lessons())
    answers = "\n" * (len(first.stages) - 1) + "q\n"
    rc, out, err = main_in(tmp_path, monkeypatch, capsys, "run", "all", "--pause", "--no-record", "--quiet",
                         stdin=_FakeTty(answers))
    assert rc == 0, err
    assert _stages_run(out, first.id) == list(range(1, len(first.stages) + 1))
    assert f"== {second.id}" not in out
    assert out.count("press Enter for stage ") == len(first.stages) - 1
    assert (f"press Enter for lesson 2/{n}: {second.id}, stage 1/{len(second.stages)}: {second.stages[0].title}, "
            f"or q + Enter to stop") in out
    assert "stopped before lesson 2/" in out


def test_results_rows_carry_the_reason_a_claim_is_known_to_fail():
    from lessons._framework import Experiment
    failed = Experiment("pulse speed", 1.0, 0.9, 0.01, id="speed", reason="the pulse is 2 spacings wide")
    held = Experiment("pulse speed", 1.0, 1.0, 0.01, id="speed", reason="the pulse is 2 spacings wide")
    row = failed.to_dict("rod-waves", 2)
    assert row["passed"] is False and row["reason"] == "the pulse is 2 spacings wide"
    assert held.to_dict("rod-waves", 2)["reason"] == ""   # a claim that held has nothing to explain
