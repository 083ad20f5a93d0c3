"""The command line: list, help, runs, results JSON, and one-line errors for bad input."""
import json

import pytest

from tests.helpers import cli


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
    for option in ("--stage", "--record", "--no-record", "--results", "--threads", "--arch", "--view", "--cfl"):
        assert option in out


def test_run_one_stage_writes_recording_and_results(tmp_path):
    r = cli("run", "rod-waves", "--stage", "1", "--results", "res.json", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "recordings" / "rod-waves.rrd").exists()
    rows = json.loads((tmp_path / "res.json").read_text())
    assert rows and all(set(row) >= {"lesson", "stage", "claim", "theory", "measured", "tolerance", "passed"}
                        for row in rows)
    assert all(row["lesson"] == "rod-waves" and row["stage"] == 1 and row["passed"] for row in rows)
    assert "claim" in r.stdout and "PASS" in r.stdout


def test_failed_experiment_gives_exit_1_and_is_in_results(tmp_path):
    r = cli("run", "rod-waves", "--stage", "2", "--width", "2", "--no-record", "--results", "res.json",
            cwd=tmp_path)
    assert r.returncode == 1
    rows = json.loads((tmp_path / "res.json").read_text())
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
    (["run", "rod-waves", "--cfl", "0"], "--cfl must be > 0 and ≤ 1000"),
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
    (["run", "bending", "--solver", "lu"], "--solver must be one of default, pcg, cholesky (got 'lu')"),
    (["run", "springs", "--tol", "0"], "--tol must be > 0 and < 1 (got 0.0)"),
    (["run", "springs", "--tol", "inf"], "--tol must be a finite number"),
    (["run", "springs", "--newton-iterations", "0"], "--newton-iterations must be ≥ 1 and ≤ 100 (got 0)"),
    (["run"], "LESSON is required"),
    (["frobnicate"], "command must be 'list' or 'run'"),
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
    rows = json.loads((tmp_path / "res.json").read_text())
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
    import lessons.cli as cli_mod

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
