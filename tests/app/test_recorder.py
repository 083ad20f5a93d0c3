"""Recorder: round trip through an .rrd file, static topology once, atomic writes."""
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from lessons.app.blueprint import PROGRESS_TICKS
from lessons.views import RunView
from lessons.app.recorder import FRAMES_PER_RUN, MIN_FRAMES_PER_RUN, Recorder, check_writable
from lessons.app.recorder_energies import ENERGY_SAMPLES
from lessons.app.recorder_geometry import strain_colors
from lessons.app.recorder_null import NullRecorder
from lessons.app.recorder_read import summarize
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
    # 0.5 s at CFL number 0.25, h = 1e-3: 2000 steps; the nodes are static, their colours drawn
    # at about FRAMES_PER_RUN frames spread over the run's 0..PROGRESS_TICKS, its last step included
    nodes = info["/stage2/right_nu0.25/rod/nodes"]
    assert nodes["static_chunks"] >= 1
    profile = info["/stage2/right_nu0.25/rod/displacement"]
    assert MIN_FRAMES_PER_RUN <= profile["rows"] <= FRAMES_PER_RUN + 1
    assert profile["frames"][0] == 0 and profile["frames"][-1] == PROGRESS_TICKS
    assert profile["steps"][0] == 0 and profile["steps"][-1] == 2000
    # the energies: at most ENERGY_SAMPLES per series, from step 1 to the last
    energy = info["/stage2/right_nu0.25/energy/total"]
    assert len(energy["steps"]) <= ENERGY_SAMPLES and energy["steps"][0] == 1 and energy["steps"][-1] == 2000
    # every run spans the same progress range (runs of a stage play side by side)
    assert info["/stage2/right_nu0.5/rod/displacement"]["frames"][-1] == PROGRESS_TICKS
    assert info["/stage2/narrative"]["static_chunks"] == 1
    stage = rec.stages[0]
    assert [r.label for r in stage.runs][:1] == ["pulse to the right, CFL number 0.25"]
    assert all(r.has_geometry and r.keys["strain"].startswith("strain: blue") for r in stage.runs)


def test_energy_envelope_keeps_the_extremes_of_a_fast_oscillation(tmp_path):
    """10^5 steps of an energy exchange with a 37-step period: kept as at most ENERGY_SAMPLES
    samples per series, and the lowest and highest values of every bin are among them, so the
    plot shows the band the curve fills instead of an aliased slow wave."""
    path = tmp_path / "env.rrd"
    n = 100_000
    s = np.arange(1, n + 1)
    K = 1.0 + np.sin(2 * np.pi * s / 37.0)
    W = 2.0 - K + 1e-6 * np.sin(2 * np.pi * s / 20000.0)
    rec = Recorder(path, "test_env")
    rec.stage(1, "s", "t")
    rec.run("r", RunView(energy="drift"), n_steps=n, dt=1e-3)
    for start in range(0, n, 1000):  # in chunks, as the run loop hands them out
        rec.energies(K[start:start + 1000], W[start:start + 1000], 1e-3, first_step=start)
    rec.close()
    from rerun.chunk import RrdReader
    got = {}
    for chunk in RrdReader(str(path)).stream():
        if chunk.entity_path.startswith("/stage1/r/energy"):
            batch = chunk.to_record_batch()
            col = next((c for c in batch.schema.names if c.endswith("scalars")), None)
            if col is None:  # the series' static style
                continue
            vals = [v[0] for v in batch.column(col).to_pylist() if v]
            got.setdefault(chunk.entity_path, []).extend(vals)
    kin = np.array(got["/stage1/r/energy/kinetic"])
    assert len(kin) <= ENERGY_SAMPLES
    assert kin.max() == K.max() and kin.min() == K.min()
    assert "/stage1/r/energy_change/relative" in got


def test_blueprint_one_view_per_drawn_run_opening_where_there_is_geometry(tmp_path):
    import rerun.blueprint as rrb  # noqa: F401
    rec = Recorder(tmp_path / "bp.rrd", "test_bp", title="test", camera="top")
    rec.stage(1, "no geometry", "text")
    rec.run("measure only", n_steps=10, dt=0.1)
    rec.energies(np.ones(10), np.ones(10), 0.1)
    rec.markdown("results", "| a |")
    rec.stage(2, "two rods", "text")
    for k, name in enumerate(["a", "b"]):
        rec.run(name, RunView(label=f"rod {name}"), n_steps=10, dt=0.1)
        for step in (0, 10):
            rec.set_time(step, 0.1 * step)
            rec.rod(np.linspace(0, 1, 11) + 0.001 * step, np.linspace(0, 1, 11), np.full(11, 0.01 * (k + 1)), gain=10)
        rec.energies(np.ones(10), np.ones(10), 0.1)
    rec.mark("something happened")
    bp = rec.blueprint()
    rec.close()
    tabs = bp.root_container
    assert tabs.active_tab == 1  # stage 2: the first with geometry

    def views(node):
        for child in getattr(node, "contents", None) or []:
            if hasattr(child, "class_identifier"):
                yield child
            elif not isinstance(child, str):
                yield from views(child)

    first, second = tabs.contents
    assert {v.class_identifier for v in views(first)} == {"TextDocument"}  # no empty scene or plot
    scenes = [v for v in views(second) if v.class_identifier == "3D"]
    assert sorted(v.origin for v in scenes) == ["/stage2/a", "/stage2/b"]
    assert all("EyeControls3D" in v.properties for v in scenes)
    assert scenes[0].name.startswith("rod a · strain: blue −0.01")  # the key of its own fixed scale
    assert scenes[1].name.startswith("rod b · strain: blue −0.02")
    assert [v.class_identifier for v in views(second)].count("TimeSeries") == 2
    assert [v.class_identifier for v in views(second)].count("TextLog") == 1


def test_colour_scale_is_fixed_per_run_not_per_frame(tmp_path):
    rec = Recorder(tmp_path / "c.rrd", "test_c")
    rec.stage(1, "s", "t")
    rec.run("r")
    big = rec.colors(np.array([0.0, 0.5]), "signed", "strain")
    small = rec.colors(np.array([0.0, 0.05]), "signed", "strain")  # a later, smaller frame
    rec.close()
    assert big[1].tolist() == [255, 0, 0]      # saturates at the first frame's 0.5
    assert small[1].tolist() == [255, 229, 229]  # 0.05 of 0.5: a faint red, not saturated


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
        "from lessons.app.recorder import Recorder\n"
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


def test_tiny_energies_are_plotted_in_a_unit_that_reads(tmp_path):
    """A run of 2e-11 J plots in pJ (axis 0 .. 20, not 0.000 000 000 02); the plot's title names the
    unit and the stage's colour keys say which curve is which (the title is short enough to read)."""
    from rerun.chunk import RrdReader

    from lessons.app.blueprint import ENERGY_KEY
    from lessons.app.recorder_energies import energy_unit

    assert energy_unit(2e-11) == (1e-12, "pJ") and energy_unit(0.5) == (1e-3, "mJ")
    assert energy_unit(3.0) == (1.0, "J") and energy_unit(0.0) == (1.0, "J") and energy_unit(5e4) == (1e3, "kJ")
    path = tmp_path / "tiny.rrd"
    rec = Recorder(path, "test_units", camera="top")
    rec.stage(1, "s", "t")
    rec.run("r", RunView(label="tiny"), n_steps=10, dt=0.1)
    for step in (0, 10):
        rec.set_time(step, 0.1 * step)
        rec.points("p", np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 0.0]]))
    rec.energies(np.full(10, 0.5e-11), np.full(10, 1.5e-11), 0.1)
    rec.close()   # flushes the run's energies: the blueprint written with the file is this one
    bp = rec.blueprint()
    run = rec.stages[0].runs[0]
    assert run.energy_unit == "pJ"
    names = []

    def walk(node):
        for child in getattr(node, "contents", None) or []:
            if hasattr(child, "class_identifier"):
                names.append(child.name)
            elif not isinstance(child, str):
                walk(child)
    walk(bp.root_container)
    assert "pJ: K · W · E" in names
    got = {}
    for chunk in RrdReader(str(path)).stream():
        batch = chunk.to_record_batch()
        col = next((c for c in batch.schema.names if c.endswith("scalars")), None)
        if col is not None:
            got.setdefault(chunk.entity_path, []).extend(v[0] for v in batch.column(col).to_pylist() if v)
        text = next((c for c in batch.schema.names if c.endswith("text")), None)
        if text is not None and chunk.entity_path.endswith("colour_keys"):
            got["keys"] = batch.column(text).to_pylist()[0]
    assert np.allclose(got["/stage1/r/energy/total"], 20.0)
    assert ENERGY_KEY in str(got["keys"])
