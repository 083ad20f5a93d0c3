"""Recorder: round trip through an .rrd file, static topology once, atomic writes."""
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from engine.recorder import NullRecorder, Recorder, check_writable, strain_colors, summarize
from lessons.rod_waves import LESSON
from tests.helpers import ROOT, run_stage


def test_rod_lesson_stage_round_trip(tmp_path):
    path = tmp_path / "rod.rrd"
    rec = Recorder(path, "test_rod")
    run_stage(LESSON, 2, rec, record_every=50)
    assert not path.exists()  # only the temporary file exists until close
    rec.close()
    assert path.exists() and not list(tmp_path.glob(".*partial*"))
    info = summarize(path)
    nodes = info["/stage2/right_nu0.25/rod/nodes"]
    # 0.5 s at nu = 0.25, h = 1e-3: 2000 steps, logged every 50 steps plus step 0
    assert nodes["rows"] == 2000 // 50 + 1
    assert nodes["frames"][0] == 0 and nodes["frames"][-1] == 2000
    energy = info["/stage2/right_nu0.25/energy/total"]
    assert energy["rows"] == 2000 and energy["frames"][0] == 1
    # runs follow each other on the frame timeline
    assert info["/stage2/right_nu0.5/rod/nodes"]["frames"][0] == 2001
    assert info["/stage2/narrative"]["static_chunks"] == 1
    assert "/stage2/right_nu0.25/rod/displacement" in info


def test_mesh_topology_is_logged_once_as_static(tmp_path):
    path = tmp_path / "mesh.rrd"
    rec = Recorder(path, "test_mesh")
    rec.stage(1, "mesh", "text")
    rec.run("sheet")
    tris = np.array([[0, 1, 2], [0, 2, 3]])
    x = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    for k in range(5):
        rec.set_time(k, 0.1 * k)
        rec.mesh(x + 0.01 * k, tris, vertex_colors=strain_colors(np.linspace(-1, 1, 4)))
    rec.close()
    info = summarize(path)["/stage1/sheet/mesh"]
    static_rows = [c for c in info["components"] if "triangle_indices" in c]
    assert static_rows, info["components"]
    assert info["static_chunks"] == 1
    assert info["frames"] == [0, 1, 2, 3, 4]


def test_exception_inside_recording_still_finalises(tmp_path):
    path = tmp_path / "crash.rrd"
    with pytest.raises(RuntimeError):
        with Recorder(path, "test_crash") as rec:
            rec.stage(1, "s", "t")
            rec.run("r")
            rec.set_time(0, 0.0)
            rec.points("pts", np.zeros((3, 3)))
            raise RuntimeError("boom")
    assert path.exists()
    assert summarize(path)["/stage1/r/pts"]["rows"] == 1


def test_killed_writer_leaves_no_file_under_the_final_name(tmp_path):
    path = tmp_path / "killed.rrd"
    code = (
        "import time, numpy as np\n"
        "from engine.recorder import Recorder\n"
        f"rec = Recorder({str(path)!r}, 'test_kill')\n"
        "rec.stage(1, 's', 't'); rec.run('r')\n"
        "for k in range(10**6):\n"
        "    rec.set_time(k, k * 0.1); rec.points('p', np.random.rand(100, 3))\n"
        "    if k == 10: print('ready', flush=True)\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", code], cwd=ROOT, stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "ready"
    time.sleep(0.3)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert not path.exists()


def test_null_recorder_is_disabled_and_accepts_everything():
    rec = NullRecorder()
    assert not rec.enabled
    rec.stage(1, "a", "b")
    rec.run("x")
    rec.rod(np.zeros(3), np.zeros(3))
    rec.energies(np.zeros(3), np.zeros(3), 0.1)
    assert rec.close() is None


def test_strain_colors_are_white_at_rest_red_in_tension_blue_in_compression():
    c = strain_colors(np.array([-1.0, 0.0, 1.0]))
    assert c[1].tolist() == [255, 255, 255]
    assert c[2].tolist() == [255, 0, 0]
    assert c[0].tolist() == [0, 0, 255]


def test_check_writable_refuses_directories_and_unwritable_places(tmp_path):
    with pytest.raises(IsADirectoryError):
        check_writable(tmp_path)
    blocker = tmp_path / "a-file"
    blocker.write_text("x")
    with pytest.raises(OSError):  # a parent that is a regular file: refused even for root
        check_writable(blocker / "sub" / "x.rrd")
    assert check_writable(tmp_path / "new" / "x.rrd").parent.is_dir()
    assert not (tmp_path / "new" / "x.rrd").exists()
