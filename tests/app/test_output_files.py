"""Output files (recording, results JSON): never replace anything but a regular file, never lose
or truncate an earlier file (full disk, partial runs), say whether they are complete, and refuse
unusable paths before the run starts. In process where the behaviour is not about the process
(rod-waves stage 1 runs in well under a second); a subprocess for the broken pipe."""
import io
import os
import stat
import subprocess
import sys

import pytest

from engine import runtime
from lessons.app.outfile import OutputFile
from lessons.app.recorder_read import run_status, summarize
from lessons.app.results import read_results, result_rows
from tests.helpers import ROOT, main_in


def no_stage_runs(monkeypatch):
    import lessons.app.cli as cli_mod
    monkeypatch.setattr(cli_mod, "run_lesson", lambda *a, **k: pytest.fail("a stage ran"))


def one_error_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("python -m lessons: error: "), err
    return lines[0]


# --------------------------------------------------------------------------------------------
# what may be replaced
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("flag", ["--record", "--results"])
def test_a_fifo_is_never_replaced(tmp_path, monkeypatch, capfd, flag):
    os.mkfifo(tmp_path / "pipe")
    no_stage_runs(monkeypatch)
    extra = ["--no-record"] if flag == "--results" else []
    rc, out, err = main_in(tmp_path, monkeypatch, capfd, "run", "rod-waves", "--stage", "1", *extra, flag, "pipe")
    assert rc == 2
    assert f"{flag} pipe: cannot write there (pipe is a FIFO (named pipe), not a regular file" in one_error_line(err)
    assert stat.S_ISFIFO(os.lstat(tmp_path / "pipe").st_mode)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pipe"]


@pytest.mark.parametrize("flag", ["--record", "--results"])
def test_a_device_node_is_never_replaced(tmp_path, monkeypatch, capfd, flag):
    node = tmp_path / "null"
    try:
        os.mknod(node, 0o666 | stat.S_IFCHR, os.makedev(1, 3))  # what /dev/null is
    except PermissionError:
        pytest.skip("making a device node needs root (as --results /dev/null run as root did the harm)")
    no_stage_runs(monkeypatch)
    extra = ["--no-record"] if flag == "--results" else []
    rc, out, err = main_in(tmp_path, monkeypatch, capfd, "run", "rod-waves", "--stage", "1", *extra, flag, "null")
    assert rc == 2 and "null is a character device, not a regular file" in one_error_line(err)
    assert stat.S_ISCHR(os.lstat(node).st_mode)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["null"]


# --------------------------------------------------------------------------------------------
# bad paths, found before the run
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("argv,needle", [
    (["--record", "x", "--results", "x"], "--results x and --record x name the same file"),
    (["--record", "out/x.rrd", "--results", "out/../out/x.rrd"], "name the same file"),
    (["--record", "r.rrd", "--results", "r.partial.rrd"], "name the same file"),
    (["--record", "/proc/x.rrd"], "--record /proc/x.rrd: cannot write there (cannot create a file in /proc"),
    (["--no-record", "--results", "/proc/r.json"], "--results /proc/r.json: cannot write there (cannot create"),
    (["--no-record", "--results", "a" * 254], "File name too long (254 bytes): a run that does not complete "
                                              "writes"),
    (["--no-record", "--results", "r\udcff.json"], "--results r\\xff.json: cannot write there (the name is not "
                                                  "valid UTF-8"),
    (["--record", "\udcfe.rrd"], "the name is not valid UTF-8"),
    (["--no-record", "--results", ""], "--results needs a file name (got '')"),
    (["--no-record", "--results", "-"], "--results needs a file name (got '-'); standard output is not supported"),
    (["--record", "-"], "--record needs a file name (got '-')"),
    (["--record", "sub"], "--record sub: cannot write there (sub is a directory; end it with / to record into "
                          "it as sub/rod-waves.rrd)"),
])
def test_unusable_output_paths_are_bad_input_before_the_run(tmp_path, monkeypatch, capfd, argv, needle):
    (tmp_path / "sub").mkdir()
    no_stage_runs(monkeypatch)
    rc, out, err = main_in(tmp_path, monkeypatch, capfd, "run", "rod-waves", "--stage", "1", *argv)
    assert rc == 2, (out, err)
    assert needle in one_error_line(err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["sub"] and not list((tmp_path / "sub").iterdir())


def test_directories_are_created_and_a_trailing_slash_means_a_directory(tmp_path, monkeypatch, capfd):
    rc, out, err = main_in(tmp_path, monkeypatch, capfd, "run", "rod-waves", "--stage", "1", "--quiet",
                           "--record", "recs/", "--results", "deep/er/res.json")
    assert rc == 0, err
    assert "/stage1/results" in summarize(tmp_path / "recs" / "rod-waves.rrd")
    assert read_results(tmp_path / "deep" / "er" / "res.json")["complete"] is True
    assert not list(tmp_path.rglob(".*partial*"))


def test_stale_temporary_files_of_dead_runs_are_removed(tmp_path, monkeypatch, capfd):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True).stdout.strip()  # a process that has ended
    stale = tmp_path / f".res.json.partial-{dead}"
    alive = tmp_path / ".res.json.partial-1"  # pid 1 is alive: another run may still be writing it
    other = tmp_path / f".other.json.partial-{dead}"  # another target's: not this run's business
    for p in (stale, alive, other):
        p.write_text("left by a killed run")
    rc, out, err = main_in(tmp_path, monkeypatch, capfd, "run", "rod-waves", "--stage", "1", "--quiet",
                           "--no-record", "--results", "res.json")
    assert rc == 0, err
    assert not stale.exists() and alive.exists() and other.exists()
    assert result_rows(tmp_path / "res.json")


# --------------------------------------------------------------------------------------------
# a full disk
# --------------------------------------------------------------------------------------------

@pytest.fixture
def small_disk(tmp_path):
    """A 1 MiB tmpfs (root only); skipped where mounting is not allowed."""
    where = tmp_path / "disk"
    where.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(where)], capture_output=True,
                       text=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a small tmpfs here ({r.stderr.strip() or 'mount failed'}): needs root")
    try:
        yield where
    finally:
        subprocess.run(["umount", "-l", str(where)], capture_output=True)


def test_a_full_disk_keeps_the_earlier_recording(small_disk, tmp_path, monkeypatch, capfd):
    earlier = b"an earlier, complete recording " * 1000  # 31 kB
    (small_disk / "r.rrd").write_bytes(earlier)
    # rod-waves stage 2 records about 2.5 MB: more than the 1 MiB disk holds
    rc, out, err = main_in(tmp_path, monkeypatch, capfd, "run", "rod-waves", "--stage", "2", "--quiet",
                           "--record", str(small_disk / "r.rrd"), "--results", str(small_disk / "res.json"))
    assert rc == 1, (out, err)
    assert "\x1b[" not in err and "Traceback" not in err  # no raw log lines from the SDK
    line = [l for l in err.splitlines() if "error" in l]
    assert len(line) == 1 and "could not write the recording (No space left on device after" in line[0], err
    assert "the earlier file there is kept and the partial one removed" in line[0]
    assert (small_disk / "r.rrd").read_bytes() == earlier
    assert sorted(p.name for p in small_disk.iterdir()) == ["r.rrd", "res.partial.json"]  # no temporary
    doc = read_results(small_disk / "res.partial.json")  # the results fit once the partial recording is gone
    assert doc["complete"] is False and doc["exit_code"] == 1 and "could not write the recording" in doc["exit_reason"]
    assert {r["stage"] for r in doc["experiments"]} == {2}


def test_a_write_error_keeps_the_earlier_file_at_the_file_level(small_disk):
    (small_disk / "x.json").write_bytes(b"earlier")
    out = OutputFile(small_disk / "x.json")
    out.prepare()
    with pytest.raises(OSError) as info:
        out.write_bytes(b"y" * (2 << 20))
    assert "No space left on device" in str(info.value)
    assert (small_disk / "x.json").read_bytes() == b"earlier" and sorted(os.listdir(small_disk)) == ["x.json"]


# --------------------------------------------------------------------------------------------
# complete or partial, and where each goes
# --------------------------------------------------------------------------------------------

def test_results_json_carries_the_runs_metadata_and_a_complete_flag(tmp_path, monkeypatch, capfd):
    (tmp_path / "res.partial.json").write_text('{"complete": false, "experiments": []}')  # an older partial run
    rc, out, err = main_in(tmp_path, monkeypatch, capfd, "run", "rod-waves", "--stage", "1", "--quiet",
                           "--record", "r.rrd", "--results", "res.json", "--E", "2")
    assert rc == 0, err
    doc = read_results(tmp_path / "res.json")
    assert doc["format"] == "elastic-lessons-results" and doc["complete"] is True
    assert doc["exit_code"] == 0 and doc["exit_reason"] == "completed"
    assert doc["lessons"] == ["rod-waves"] and doc["stages_requested"] == doc["stages_completed"] == {"rod-waves": [1]}
    assert doc["parameters"]["rod-waves"]["E"] == 2.0 and doc["stepping"]["integrator"] == "default"
    info = runtime.current()
    assert doc["runtime"] == dict(arch="cpu", backend=info.backend, precision="f64", threads=info.cpu_threads,
                                  offline_cache=info.cache_dir, pinned=list(info.pinned) if info.pinned else None)
    assert doc["version"] and doc["started"] <= doc["finished"]
    assert doc["passed"] == len(doc["experiments"]) > 0 and doc["failed"] == 0
    assert all(r["lesson"] == "rod-waves" and r["stage"] == 1 for r in doc["experiments"])
    assert not (tmp_path / "res.partial.json").exists()  # superseded by the complete run
    status = run_status(tmp_path / "r.rrd")
    assert status["complete"] is True and status["stages_completed"] == [1] and status["precision"] == "f64"
    first = out.splitlines()[0]
    assert first == f"runtime: {info.describe()}" and first.startswith("runtime: cpu (x")


def test_old_results_files_are_still_read():
    rows = [{"lesson": "springs", "stage": 1, "id": "x", "passed": True}]
    assert result_rows(rows) == rows and read_results(rows)["complete"] is None
    assert result_rows({"experiments": rows, "complete": True}) == rows


def _text(path, entity: str) -> str:
    from rerun.chunk import RrdReader
    return " ".join(str(row.get("TextDocument:text")) for chunk in RrdReader(str(path)).stream()
                    if str(chunk.entity_path) == entity for row in chunk.to_record_batch().to_pylist())


class _Tty(io.StringIO):
    def isatty(self):
        return True


@pytest.mark.parametrize("overwrite", [False, True])
def test_a_partial_run_never_replaces_a_complete_file_unless_asked(tmp_path, monkeypatch, capfd, overwrite):
    earlier = {"r.rrd": b"complete recording", "res.json": b'{"complete": true, "experiments": []}'}
    for name, data in earlier.items():
        (tmp_path / name).write_bytes(data)
    flags = ["--overwrite-partial"] if overwrite else []
    rc, out, err = main_in(tmp_path, monkeypatch, capfd, "run", "rod-waves", "--stage", "1,4", "--pause", "--quiet",
                           "--record", "r.rrd", "--results", "res.json", *flags, stdin=_Tty("q\n"))
    assert rc == 0, err
    rec, res = (("r.rrd", "res.json") if overwrite else ("r.partial.rrd", "res.partial.json"))
    doc = read_results(tmp_path / res)
    assert doc["complete"] is False and doc["exit_reason"] == "stopped at --pause"
    assert doc["stages_completed"] == {"rod-waves": [1]} and doc["stages_requested"] == {"rod-waves": [1, 4]}
    status = run_status(tmp_path / rec)
    assert status["complete"] is False and status["stages_completed"] == [1]
    assert "This recording is partial" in _text(tmp_path / rec, "/stage1/run_status")
    if not overwrite:
        for name, data in earlier.items():
            assert (tmp_path / name).read_bytes() == data
        assert "(PARTIAL: stopped at --pause" in out and "is kept" in out


@pytest.mark.parametrize("overwrite", [False, True])
@pytest.mark.parametrize("earlier", [False, True])
def test_a_partial_run_says_truly_what_became_of_the_earlier_files(tmp_path, monkeypatch, capfd, overwrite, earlier):
    """"is kept" only when an earlier file under the final name is there and was not written over;
    "replaced" only when --overwrite-partial wrote over one; neither when there was none."""
    if earlier:
        (tmp_path / "r.rrd").write_bytes(b"complete recording")
        (tmp_path / "res.json").write_bytes(b'{"complete": true, "experiments": []}')
    flags = ["--overwrite-partial"] if overwrite else []
    rc, out, err = main_in(tmp_path, monkeypatch, capfd, "run", "rod-waves", "--stage", "1,4", "--pause", "--quiet",
                           "--record", "r.rrd", "--results", "res.json", *flags, stdin=_Tty("q\n"))
    assert rc == 0, err
    lines = {kind: next(l for l in out.splitlines() if l.startswith(f"{kind} (PARTIAL"))
             for kind in ("recording", "results")}
    for kind, name in (("recording", "r.rrd"), ("results", "res.json")):
        where = tmp_path / (name if overwrite else name.replace(".", ".partial."))
        if not earlier:
            tail = ""
        elif overwrite:
            tail = f"; it replaced the earlier {tmp_path / name} (--overwrite-partial)"
        else:
            tail = f"; the earlier {tmp_path / name} is kept"
        assert lines[kind].endswith(f": {where}{tail}"), lines[kind]
    if earlier and not overwrite:
        assert (tmp_path / "r.rrd").read_bytes() == b"complete recording"


def _failing_recording_writes(monkeypatch):
    """Writing a .rrd fails as on a full disk (the temporary file removed, the earlier file untouched)."""
    import errno

    from lessons.app.outfile import OutputFile, OutputWriteError
    write = OutputFile.write_bytes

    def write_bytes(self, data):
        if self.path.suffix != ".rrd":
            return write(self, data)
        self.discard()
        raise OutputWriteError(errno.ENOSPC, f"No space left on device after 0 of {len(data):,} bytes")
    monkeypatch.setattr(OutputFile, "write_bytes", write_bytes)


@pytest.mark.parametrize("earlier", [False, True])
def test_a_recording_that_cannot_be_written_makes_the_run_partial(tmp_path, monkeypatch, capfd, earlier):
    if earlier:
        (tmp_path / "r.rrd").write_bytes(b"complete recording")
        (tmp_path / "res.json").write_bytes(b'{"complete": true, "experiments": []}')
    _failing_recording_writes(monkeypatch)
    rc, out, err = main_in(tmp_path, monkeypatch, capfd, "run", "rod-waves", "--stage", "1", "--quiet",
                           "--record", "r.rrd", "--results", "res.json")
    assert rc == 1, (out, err)
    line = one_error_line(err)
    assert "--record r.rrd: could not write the recording (No space left on device after 0 of" in line
    assert line.endswith("the earlier file there is kept and the partial one removed" if earlier
                         else "the partial file is removed and nothing is left there"), line
    doc = read_results(tmp_path / "res.partial.json")  # partial, as the README says, under the partial name
    assert doc["complete"] is False and doc["exit_code"] == 1 and "could not write the recording" in doc["exit_reason"]
    assert doc["stages_completed"] == doc["stages_requested"] == {"rod-waves": [1]}
    assert f"(the run did not complete: --record r.rrd: could not write the recording" in out
    if earlier:
        assert (tmp_path / "r.rrd").read_bytes() == b"complete recording"
        assert read_results(tmp_path / "res.json")["complete"] is True
        assert f"; the earlier {tmp_path / 'res.json'} is kept" in out
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["res.partial.json"] + (["r.rrd", "res.json"]
                                                                                      if earlier else []))


# --------------------------------------------------------------------------------------------
# signals and pipes
# --------------------------------------------------------------------------------------------

def test_a_second_signal_during_clean_up_is_noted_not_raised():
    import signal

    from lessons.app.cli import _Signals
    s = _Signals()
    with pytest.raises(KeyboardInterrupt):
        s.handler(signal.SIGINT, None)
    s.handler(signal.SIGINT, None)  # a second Ctrl-C: noted, the clean-up goes on
    s.cleaning = True
    s.handler(signal.SIGTERM, None)
    assert s.received == [signal.SIGINT, signal.SIGINT, signal.SIGTERM] and s.first == signal.SIGINT
    from lessons._framework import pending_signal
    pending_signal.clear()


def test_a_closed_stdout_pipe_ends_the_run_quietly(tmp_path):
    env = dict(os.environ, PYTHONPATH=str(ROOT), ELASTIC_CACHE_DIR=str(ROOT / ".ti_cache"))
    proc = subprocess.Popen([sys.executable, "-m", "lessons", "run", "springs", "--stage", "1", "--no-record"],
                            cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    first = proc.stdout.readline()  # like '| head -1'
    proc.stdout.close()
    err = proc.stderr.read().decode()
    proc.wait(timeout=120)
    assert first.startswith(b"runtime: ")
    assert proc.returncode == 141, err
    assert "Traceback" not in err and "BrokenPipe" not in err and "error" not in err, err
