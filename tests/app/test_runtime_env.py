"""The runtime's environment: errors name the variable they come from, a kernel cache that cannot
be used is a one-line warning (not a crash at exit), a process without HOME still starts, and a
run says what it runs on (read back from Taichi)."""
import os
import subprocess
import sys

import pytest

from engine import runtime
from tests.helpers import ROOT


def run_py(args, env_changes, cwd, drop=()):
    env = dict(os.environ, PYTHONPATH=str(ROOT), ELASTIC_CACHE_DIR=str(ROOT / ".ti_cache"))
    env.update(env_changes)
    for name in drop:
        env.pop(name, None)
    return subprocess.run([sys.executable, "-m", "lessons", *args], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=300)


@pytest.mark.parametrize("name,value,needle", [
    ("ELASTIC_THREADS", "abc", "ELASTIC_THREADS must be an integer in 1..256 (got 'abc')"),
    ("ELASTIC_THREADS", "0", "ELASTIC_THREADS must be an integer in 1..256 (got 0)"),
    ("ELASTIC_ARCH", "tpu", "ELASTIC_ARCH must be one of cpu, cuda, vulkan (got 'tpu')"),
    ("ELASTIC_FP", "16", "ELASTIC_FP must be 32 or 64 (got 16)"),
    ("ELASTIC_PIN", "yes", "ELASTIC_PIN must be one of auto, off (got 'yes')"),
    ("TI_LOG_LEVEL", "banana", "TI_LOG_LEVEL must be one of trace, debug, info, warn, error, critical, off "
                               "(got 'banana')"),
])
def test_environment_errors_name_the_variable(monkeypatch, name, value, needle):
    monkeypatch.setenv(name, value)
    with pytest.raises(runtime.RuntimeConfigError) as info:
        runtime.init()
    assert needle in str(info.value) and "--threads" not in str(info.value)


def test_a_bad_environment_variable_is_bad_input_on_the_command_line(tmp_path, monkeypatch, capsys):
    import lessons.app.cli as cli_mod
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("ELASTIC_THREADS", "abc")
    assert cli_mod.main(["run", "rod-waves", "--stage", "1", "--no-record"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["python -m lessons: error: ELASTIC_THREADS must be an integer in 1..256 (got 'abc')"]
    assert list(tmp_path.iterdir()) == []


def test_a_bad_log_level_stops_before_taichi_is_imported(tmp_path):
    r = run_py(["run", "rod-waves", "--stage", "1", "--no-record"], {"TI_LOG_LEVEL": "banana"}, tmp_path)
    assert r.returncode == 2, r.stderr
    assert r.stderr.strip().splitlines() == [
        "python -m lessons: error: TI_LOG_LEVEL must be one of trace, debug, info, warn, error, critical, off "
        "(got 'banana')"]


def test_help_works_without_home(tmp_path):
    r = run_py(["--help"], {}, tmp_path, drop=("HOME",))
    assert r.returncode == 0, r.stderr
    assert "usage: python -m lessons" in r.stdout and r.stderr == ""


def test_version_prints_the_package_version(tmp_path, capsys):
    import lessons.app.cli as cli_mod
    from lessons.app.results import package_version
    assert cli_mod.main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"python -m lessons (elastic-lessons) {package_version()}"


@pytest.mark.parametrize("kind", ["a file", "under /proc"])
def test_an_unusable_kernel_cache_is_a_warning_not_a_crash(tmp_path, kind):
    if kind == "a file":
        cache = tmp_path / "cache"
        cache.write_text("not a directory")
    else:
        cache = "/proc/elastic-cache"
    r = run_py(["run", "rod-waves", "--stage", "1", "--no-record", "--quiet"], {"ELASTIC_CACHE_DIR": str(cache)},
               tmp_path)
    assert r.returncode == 0, r.stderr  # it crashed with SIGSEGV (-11 / 139) at exit
    warnings = [l for l in r.stderr.splitlines() if l.startswith("warning:")]
    assert len(warnings) == 1 and warnings[0].startswith(f"warning: ELASTIC_CACHE_DIR={cache}: cannot use it as "
                                                         "the kernel cache")
    assert "running without it" in warnings[0]
    assert r.stdout.splitlines()[0].endswith(", no kernel cache")


def test_the_runtime_is_read_back_from_taichi():
    from taichi.lang import impl
    info = runtime.current()
    cfg = impl.get_runtime().prog.config()
    assert info.precision == "f64" and str(cfg.default_fp) == "f64"
    assert info.cpu_threads == cfg.cpu_max_num_threads == 2
    assert info.backend in ("x64", "arm64") and info.arch == "cpu"
    on = f" on CPUs {', '.join(map(str, info.pinned))}" if info.pinned else ""
    assert info.describe() == f"cpu ({info.backend}), f64, 2 CPU threads{on}, kernel cache {info.cache_dir}"
