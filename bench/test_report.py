"""The report tooling without timing: ``python -m bench --help`` works, and the report writer turns
synthetic benchmark data into the JSON, Markdown and PNG files with the derived figures right."""
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from bench import config, report, traffic
from bench.machine import machine_info, thread_waits


def _bench(group, median, **extra):
    extra.setdefault("steps_per_call", 1)
    extra.setdefault("config", "t2-f64")
    return dict(group=group, name=f"test_{group}", fullname="x", params={}, param="", extra_info=extra, options={},
                stats=dict(min=median, max=median, mean=median, stddev=0.0, rounds=3, median=median, iqr=0.0))


def _synthetic_raw(tmp_path):
    raw = tmp_path / "raw"
    raw.mkdir()
    n, m, h = 16384, 48641, 48133
    cl = dict(side=128, n=n, m=m, h=h)
    b = []
    b.append(_bench("bandwidth", 1e-3, impl="taichi", level="cache", kernel="copy", n=1 << 19, bytes=8e7))  # 80 GB/s
    b.append(_bench("bandwidth", 2e-3, impl="numpy", level="cache", kernel="copy", n=1 << 19, bytes=8e7))
    b.append(_bench("bandwidth", 0.02, impl="taichi", level="dram", kernel="copy", n=1 << 25, bytes=4e8))
    b.append(_bench("cloth-explicit-step", 16384 * 30e-9, impl="engine", model="springs+bending",
                    kernel="explicit_step", bytes=traffic.kernel_bytes("explicit_step", n, m, h), **cl))
    b.append(_bench("cloth-explicit-step", 16384 * 300e-9, impl="numpy", model="springs+bending", **cl))
    b.append(_bench("cloth-explicit-step", 16384 * 25e-9, impl="numba", model="springs+bending", **cl))
    b.append(_bench("cloth-explicit-step", 16384 * 40e-9, impl="warp", model="springs+bending", **cl))
    b.append(_bench("cloth-explicit-step", 4096 * 60e-9, impl="engine", model="springs+bending",
                    kernel="explicit_step", side=64, n=4096, m=12033, h=11781,
                    bytes=traffic.kernel_bytes("explicit_step", 4096, 12033, 11781)))
    for k in report.ALL_KERNELS:
        b.append(_bench("cloth-force-kernels", 100e-6, impl="engine", kernel=k,
                        bytes=traffic.kernel_bytes(k, n, m, h), **cl))
    b.append(_bench("cloth-implicit-step", 0.5, impl="engine-pcg", solver="pcg", linear_iterations=1000, tol=1e-5,
                    bytes=traffic.implicit_step_bytes(n, m, h, 1000), **cl))
    b.append(_bench("cloth-implicit-step", 0.3, impl="engine-pardiso", solver="pardiso", linear_iterations=1,
                    tol=1e-5, assembly_s=0.02, factorization_s=0.25, solve_s=0.03, **cl))
    b.append(_bench("cloth-implicit-step", 0.4, impl="peer-pardiso", solver="pardiso", linear_iterations=1,
                    tol=1e-5, assembly_s=0.1, setup_s=0.28, solve_s=0.02, **cl))
    b.append(_bench("cloth-implicit-step", 2.0, impl="peer-pyamg-cg", solver="pyamg-cg", linear_iterations=30,
                    tol=1e-8, **cl))
    b.append(_bench("cloth-implicit-sequence", 60 * 0.3, impl="engine-pardiso", tol=1e-5, steps_per_call=60, **cl))
    b.append(_bench("cloth-implicit-sequence", 60 * 0.4, impl="peer-pardiso", tol=1e-5, steps_per_call=60, **cl))
    b.append(_bench("cloth-implicit-step", 0.8, impl="engine-cholesky", solver="cholesky", linear_iterations=1, **cl))
    b.append(_bench("cloth-implicit-step", 4.0, impl="scipy", solver="scipy-cg", linear_iterations=1200,
                    assembly_s=1.0, setup_s=0.0, solve_s=3.0, tol=1e-5, **cl))
    b.append(_bench("rod-step", 1e-3, impl="engine-rod", method="symplectic-euler", n=10000, steps_per_call=100,
                    bytes=traffic.kernel_bytes("rod_explicit_step", 10000)))
    b.append(_bench("rod-step", 3e-3, impl="numpy", method="symplectic-euler", n=10000, steps_per_call=100))
    (raw / "bench-t2-f64.json").write_text(json.dumps(dict(benchmarks=b)))
    t1 = [_bench("cloth-explicit-step", 16384 * 50e-9, impl="engine", model="springs+bending", config="t1-f64",
                 kernel="explicit_step", **cl)]
    (raw / "bench-t1-f64.json").write_text(json.dumps(dict(benchmarks=t1)))
    pts = []
    for E, ex, imp in ((10.0, 0.1, 1.0), (1e3, 1.0, 1.0 * 10 ** 0.5), (1e5, 10.0, 1.0)):
        imp_r = {k: dict(pcg=dict(cost=imp, iterations=100, step_s=imp / 60), cholesky=dict(skipped="x"), best="pcg",
                         best_cost=imp) for k in ("1/60", "accuracy")}
        pts.append(dict(E=E, explicit=dict(lambda_max=1.0, safety=0.9, dt=1e-4, stable=True, stable_check_steps=200,
                                           cost=ex), implicit=imp_r))
    side = dict(n=4096, explicit_step_s=1e-3, points=pts,
                crossover={"1/60": dict(E=1e3, note="explicit cheaper below"), "accuracy": dict(E=None, note="none")})
    (raw / "headline.json").write_text(json.dumps(dict(pendulum_omega=3.84, accuracy_loss=0.1,
                                                       dts={"1/60": 1 / 60, "accuracy": 7.16e-3}, sides={"64": side})))
    st = dict(import_s=1.0, init_s=0.1, scene_s=0.2, compile_total_s=5.0, process_s=7.0, first_calls_s=5.1,
              cache_files_after_exit=0,
              paths={"explicit-step": dict(first_s=1.0, second_s=0.001, compile_s=0.999)})
    (raw / "startup-cold.json").write_text(json.dumps(st))
    info = machine_info()
    info["last_level_cache_bytes"] = 32 << 20
    (raw / "run.json").write_text(json.dumps(dict(timestamp="T", profile="quick", command="python -m bench --quick",
                                                  machine=info, errors=[], wall_s=1.0)))
    return raw


def test_bench_help():
    out = subprocess.run([sys.executable, "-m", "bench", "--help"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0
    assert "--quick" in out.stdout and "--out" in out.stdout


def test_bench_rejects_unknown_part():
    out = subprocess.run([sys.executable, "-m", "bench", "--skip", "nonsense"], capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 2 and "unknown part" in out.stderr


def test_report_writer_on_synthetic_data(tmp_path):
    raw = _synthetic_raw(tmp_path)
    doc = report.build(raw)
    # derived figures
    r = report.find(doc["rows"], group="cloth-explicit-step", impl="engine", side=128, config="t2-f64")
    assert r["ns_per_vertex"] == pytest.approx(30.0)
    assert doc["bandwidth"]["t2-f64"]["cache"]["floor"] == pytest.approx(8e10)
    assert r["floor_level"] == "cache"
    assert r["bw_fraction"] == pytest.approx(r["bytes"] / 8e10 / r["per_step_s"])
    rod = report.find(doc["rows"], group="rod-step", impl="engine-rod")
    assert rod["per_step_s"] == pytest.approx(1e-5)
    t = {x["name"].split(",")[0] + ("" if "explicit" not in x["name"] else ", " + x["name"].split(", ")[1]
                                   + ", " + x["name"].split(", ")[-1]): x for x in doc["targets"]}
    ex = t["explicit step, springs+bending, t2-f64"]
    assert ex["met"] is False and "1.20x (spread up to 1.20) at 128^2" in ex["by"]          # 30 ns against Numba's 25
    im = t["implicit step"]
    assert im["met"] is True and im["value"] == pytest.approx(0.75)     # 0.3 s against PARDISO from numpy's 0.4
    assert t["implicit steps"]["met"] is False and t["implicit steps"]["value"] == pytest.approx(0.75)
    ratios = {(p["kind"], p["side"], p["what"]): p for p in doc["peer_ratios"] if p["config"] == "t2-f64"}
    p8 = ratios[("implicit", 128, "tol 1e-08")]        # f64 direct rows count at every tol; the engine's PARDISO,
    assert p8["peer"] == "peer-pardiso" and p8["engine"] == "engine-cholesky"   # refined to 1e-5 only, does not
    assert ratios[("explicit", 128, "springs+bending")]["peer"] == "numba"
    exps = {(s["group"], s["impl"]): s["exponent"] for s in doc["scaling"]}
    assert exps[("cloth-explicit-step", "engine")] == pytest.approx(0.5)  # 2x the time for 4x the vertices
    paths = report.write(doc, tmp_path / "out", "T")
    for key in ("json", "md", "cost_vs_E", "cost_vs_N", "latest_md", "latest_json", "latest_cost_vs_E"):
        assert paths[key].exists() and paths[key].stat().st_size > 0, key
    md = paths["md"].read_text()
    for section in ("## Machine", "## Targets", "## Headline", "## Cloth: explicit", "## Step kernels",
                    "## Cloth: backward-Euler", "## Rod", "## Scaling with N", "## Start-up", "## Bandwidth floor"):
        assert section in md, section
    assert "T-cost_vs_E.png" in md and "latest-cost_vs_E.png" in paths["latest_md"].read_text()
    # the libraries' thread waits in effect (the engine's settings unless set before the run)
    assert f"KMP_BLOCKTIME={thread_waits()['KMP_BLOCKTIME']} ms" in md and "OPENBLAS_THREAD_TIMEOUT=" in md
    assert "**missed** (worst 1.20x (spread up to 1.20) at 128^2 springs+bending)" in md and "## Against the peers" in md
    assert json.loads(paths["json"].read_text())["targets"][0]["met"] is True


def test_a_benchmark_run_writes_only_untracked_files():
    """python -m bench writes under its default --out (bench/results), which git ignores and
    which holds no tracked file; the committed reference lives elsewhere."""
    import subprocess
    from bench.__main__ import parse_args
    from bench.report import REFERENCE_DIR, REPO

    out = Path(parse_args([]).out).resolve()
    assert out == (REPO / "bench" / "results").resolve()
    git = lambda *a: subprocess.run(["git", *a], cwd=REPO, capture_output=True, text=True)
    if git("rev-parse", "--is-inside-work-tree").returncode != 0:
        pytest.skip("not a git checkout")
    assert git("ls-files", str(out)).stdout.strip() == ""
    for name in ("x.json", "x.md", "latest.md", "latest-cost_vs_E.png", "raw/x/run.json"):
        assert git("check-ignore", "-q", str(out / name)).returncode == 0, name
    assert (REFERENCE_DIR / "report.md").exists()
    assert git("ls-files", str(REFERENCE_DIR / "report.md")).stdout.strip()


def _interleaved(group, name, contenders, **extra):
    """A pytest-benchmark entry as bench/interleave.measure_row writes it."""
    extra.setdefault("steps_per_call", 1)
    extra.setdefault("config", "t2-f64")
    inter = {impl: dict(round_s=list(ts), calls_per_round=1, info=dict(info)) for impl, (ts, info) in contenders.items()}
    d = _bench(group, 1.0, interleaved=inter, **extra)
    d["name"] = name
    return d


def test_interleaved_rows_give_per_round_ratios(tmp_path):
    """An interleaved row becomes one report row per contender (median of its rounds), and the ratio
    is the median of the per-round ratios with their spread: a drift that moves both contenders in
    a round leaves the ratio alone; a spread that contains 1 is 'not resolved'."""
    raw = tmp_path / "raw"
    raw.mkdir()
    cl = dict(side=64, n=4096, m=12033, h=11781, model="springs+bending")
    load = [1.0, 1.0, 2.0, 1.0, 3.0, 1.0, 1.0]               # the machine slows down in rounds 3 and 5
    eng = [0.8 * f for f in load]
    numba = [1.0 * f for f in load]
    warp = [1.05 * f for f in load[::-1]]                     # drifts at other times: the medians are close
    b = [_interleaved("cloth-explicit-step", "row-explicit", {"engine": (eng, {}), "numba": (numba, {}),
                                                              "warp": (warp, {})}, **cl)]
    # implicit: the engine and PARDISO alternate which is faster: not resolved
    e_imp = [1.0, 1.2, 0.9, 1.1, 1.0]
    p_imp = [1.1, 1.0, 1.0, 1.0, 1.05]
    b.append(_interleaved("cloth-implicit-step", "row-direct",
                          {"engine-pardiso": (e_imp, dict(solver="pardiso", tol=1e-5)),
                           "peer-pardiso": (p_imp, dict(solver="pardiso", tol=1e-5)),
                           "peer-pardiso-factor": ([0.5] * 5, dict(solver="pardiso", tol=1e-5, library_only=True)),
                           "peer-pardiso-factor-mixed": ([0.25] * 5, dict(solver="pardiso", precision="mixed",
                                                                          tol=1e-5, library_only=True))},
                          **cl))
    (raw / "bench-t2-f64.json").write_text(json.dumps(dict(benchmarks=b)))
    doc = report.build(raw)
    rows = [r for r in doc["rows"] if r["group"] == "cloth-explicit-step"]
    assert {r["impl"] for r in rows} == {"engine", "numba", "warp"}
    assert report.find(rows, impl="numba")["per_step_s"] == pytest.approx(1.0)
    ratios = {p["kind"]: p for p in doc["peer_ratios"]}
    ex = ratios["explicit"]
    assert ex["peer"] == "numba" and ex["interleaved"] and ex["rounds"] == 7
    assert ex["ratio"] == pytest.approx(0.8) and ex["spread"] == pytest.approx((0.8, 0.8)) and ex["resolved"]
    imp = ratios["implicit"]
    assert imp["peer"] == "peer-pardiso"                      # the factorisation alone is not a contender
    per_round = sorted(a / b for a, b in zip(e_imp, p_imp))
    assert imp["ratio"] == pytest.approx(per_round[2])
    assert imp["spread"] == pytest.approx((per_round[0], per_round[-1])) and imp["resolved"] is False
    assert "not resolved" in report.ratios.ratio_text(imp)
    lib = {p["peer"]: p for p in doc["peer_ratios"] if p["kind"] == "library"}
    assert lib["peer-pardiso-factor"]["ratio"] == pytest.approx(2.0)     # per round: 1.0/0.5, 1.2/0.5, ...
    assert lib["peer-pardiso-factor-mixed"]["ratio"] == pytest.approx(4.0)
    assert lib["peer-pardiso-factor-mixed"]["what"].startswith("PARDISO f32 factorisation")
    md = report.markdown(doc, "x-")
    assert "not resolved" in md and "PARDISO factorisation + solve alone" in md
    assert "PARDISO f32 factorisation + f64 refinement alone" in md
    # the target is read against the f64 factorisation alone (64^2 here: <= 1.0), never the mixed row
    t = [t for t in doc["targets"] if t["name"].startswith("implicit step against PARDISO")]
    assert len(t) == 2 and t[1]["met"] is False and "pardiso-factor " in t[1]["measured"]


def test_library_target_says_the_techniques_floor_round_by_round(tmp_path):
    """The library target's reasons, round by round: the technique alone against f64 alone (mixed / f64,
    not its inverse), what the engine adds to the technique, what a round allows under the goal, and
    how many rounds meet it (per round, not from the medians); no such line when the three were not
    timed in one interleaved row."""
    f64 = [1.0, 1.0, 1.0, 1.0]
    mixed = [0.6, 0.7, 0.6, 0.65]
    engine = [0.66, 0.84, 0.72, 0.78]          # adds 10%, 20%, 20%, 20%: rounds at 0.66, 0.84, 0.72, 0.78
    cl = dict(side=128, n=16384, m=48641, h=48133, model="springs+bending")

    def doc_of(split, where):
        raw = tmp_path / where
        raw.mkdir()
        lib = dict(solver="pardiso", tol=1e-5, library_only=True)
        peers = {"peer-pardiso-factor": (f64, lib), "peer-pardiso-factor-mixed": (mixed, dict(lib, precision="mixed"))}
        eng = {"engine-pardiso": (engine, dict(solver="pardiso", tol=1e-5))}
        b = ([_interleaved("cloth-implicit-step", "row-a", eng, **cl), _interleaved("cloth-implicit-step", "row-b", peers, **cl)]
             if split else [_interleaved("cloth-implicit-step", "row-a", {**eng, **peers}, **cl)])
        (raw / "bench-t2-f64.json").write_text(json.dumps(dict(benchmarks=b)))
        doc = report.build(raw)
        return [t for t in doc["targets"] if t["name"].startswith("implicit step against PARDISO") and "128^2" in t["name"]][0]
    t = doc_of(False, "one")
    assert t["met"] is False                   # one round of four above 0.8
    line = t["why"][0]
    assert "128^2, round by round (4 rounds)" in line
    assert "alone 0.62 (0.60-0.70)" in line    # mixed / f64 per round, median 0.625
    assert "adds 20% (10% to 20%)" in line
    assert "allows 28% (14% to 33%): 3 of 4 rounds at or under it" in line   # 0.8 / floor - 1 per round
    assert "already above" not in line         # every round's technique alone is under 0.8
    assert "why" not in doc_of(True, "two")    # not timed in the same rounds: no round-by-round reasons
    mixed[1] = 0.85                            # one round where the library's f32 path alone is above the goal
    engine[1] = 0.9
    line = doc_of(False, "three")["why"][0]
    assert "3 of 4 rounds at or under it. In 1 of 4 rounds the technique alone was already above 0.8" in line


def test_a_rerun_is_checked_against_the_reference_spread(tmp_path):
    """report.agreement / against_text: a rerun's ratio inside the reference's spread passes, one
    outside is named; rows without a spread are not judged."""
    ref = dict(peer_ratios=[
        dict(kind="implicit", config="t2-f64", side=128, what="tol 1e-05", ratio=0.8, spread=(0.7, 0.9)),
        dict(kind="explicit", config="t2-f64", side=64, what="springs", ratio=1.1, spread=(1.05, 1.2)),
        dict(kind="sequence", config="t2-f64", side=64, what="tol 1e-05", ratio=0.5, spread=None)])
    run = dict(peer_ratios=[
        dict(kind="implicit", config="t2-f64", side=128, what="tol 1e-05", ratio=0.85, spread=(0.8, 0.9)),
        dict(kind="explicit", config="t2-f64", side=64, what="springs", ratio=0.9, spread=(0.85, 0.95)),
        dict(kind="sequence", config="t2-f64", side=64, what="tol 1e-05", ratio=0.6, spread=None),
        dict(kind="explicit", config="t2-f64", side=256, what="springs", ratio=0.9, spread=None)])
    rows = {a["kind"]: a for a in report.agreement(run, ref)}
    assert set(rows) == {"implicit", "explicit", "sequence"}
    assert rows["implicit"]["inside"] is True and rows["explicit"]["inside"] is False
    assert rows["sequence"]["inside"] is None
    lines, outside = report.against_text(run, ref, "ref")
    assert outside == 1 and "1 of 2 ratios within the reference's spread" in lines[-1]
    assert any("OUTSIDE" in line and "explicit" in line for line in lines)


def test_membrane_implicit_rows_are_their_own_comparison(tmp_path):
    """The membrane's backward-Euler rows (group config.MEMBRANE_IMPLICIT_GROUP) give their own ratio
    entry, named by the model, beside the cloth's at the same size and tolerance, and their own table."""
    from bench.config import MEMBRANE_IMPLICIT_GROUP, MEMBRANE_MODEL
    raw = tmp_path / "raw"
    raw.mkdir()
    cl = dict(side=64, n=4096, m=12033, h=11781, model="springs+bending")
    mem = dict(side=64, n=4096, triangles=7938, model=MEMBRANE_MODEL)
    d = dict(solver="pardiso", tol=1e-5)
    b = [_interleaved("cloth-implicit-step", "row-direct", {"engine-pardiso": ([1.0] * 5, d),
                                                            "peer-pardiso": ([2.0] * 5, d)}, **cl),
         _interleaved(MEMBRANE_IMPLICIT_GROUP, "row-membrane", {"engine-pardiso": ([0.6] * 5, d),
                                                                "peer-pardiso": ([1.0] * 5, d)}, **mem),
         _interleaved(MEMBRANE_IMPLICIT_GROUP, "row-membrane-cg",
                      {"engine-pcg": ([3.0] * 3, dict(solver="pcg", tol=1e-5)),
                       "scipy": ([2.0] * 3, dict(solver="scipy-cg", tol=1e-5, assembly_s=0.1, setup_s=0.0,
                                                 solve_s=1.9))}, **mem)]
    (raw / "bench-t2-f64.json").write_text(json.dumps(dict(benchmarks=b)))
    doc = report.build(raw)
    ratios = {p["what"]: p for p in doc["peer_ratios"] if p["kind"] == "implicit"}
    assert set(ratios) == {"tol 1e-05", f"{MEMBRANE_MODEL}, tol 1e-05"}
    assert ratios["tol 1e-05"]["ratio"] == pytest.approx(0.5)
    m = ratios[f"{MEMBRANE_MODEL}, tol 1e-05"]
    assert m["engine"] == "engine-pardiso" and m["peer"] == "peer-pardiso" and m["ratio"] == pytest.approx(0.6)
    assert m["all"]["scipy"] == pytest.approx(2.0)     # the iterative row at the same tolerance is in the comparison
    md = report.markdown(doc, "x-")
    assert "bench/baseline.NumpyMembrane" in md and f"{MEMBRANE_MODEL}, tol 1e-05" in md


def _cli(module, *args, cwd=None):
    from bench.report import REPO
    return subprocess.run([sys.executable, "-m", module, *args], capture_output=True, text=True, timeout=120,
                          cwd=cwd, env=dict(os.environ, PYTHONPATH=str(REPO)))


def _one_error_line(r, prog) -> str:
    assert r.returncode == 2, (r.stdout, r.stderr)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"{prog}: error: "), r.stderr
    assert r.stdout == ""
    return lines[0]


def _tree(root: Path) -> dict:
    return {str(p.relative_to(root)): p.read_bytes() if p.is_file() else None for p in sorted(root.rglob("*"))}


@pytest.mark.parametrize("args,needle", [
    (["results/raw/mistyped"], "RAW_DIR results/raw/mistyped: no such directory; give a raw directory written by "
                               "python -m bench"),
    (["results/raw/empty"], "RAW_DIR results/raw/empty holds none of run.json, bench-t2-f64.json"),
    (["results/raw/notes.txt"], "RAW_DIR results/raw/notes.txt: not a directory"),
    (["raw", "--out", "results/latest.md"], "--out results/latest.md: {t}/results/latest.md is a file, not a directory"),
    (["raw", "--out", "/proc/bench"], "--out /proc/bench: cannot create a file in /proc"),
    (["raw", "--against", "nowhere.json"], "--against nowhere.json: cannot read it (No such file or directory)"),
    (["raw", "--frobnicate"], "unrecognized arguments: --frobnicate (see 'python -m bench.report --help')"),
])
def test_report_refuses_bad_arguments_in_one_line_and_writes_nothing(tmp_path, args, needle):
    """A mistyped RAW_DIR used to be rendered as an empty run over <grandparent>/<name>.* and latest.*."""
    _synthetic_raw(tmp_path)
    (tmp_path / "results" / "raw" / "empty").mkdir(parents=True)
    (tmp_path / "results" / "raw" / "notes.txt").write_text("notes")
    (tmp_path / "results" / "latest.md").write_text("the latest report")
    before = _tree(tmp_path)
    r = _cli("bench.report", *args, cwd=tmp_path)
    assert needle.format(t=tmp_path) in _one_error_line(r, "python -m bench.report")
    assert _tree(tmp_path) == before


def test_report_of_a_raw_directory_still_writes_it(tmp_path):
    raw = _synthetic_raw(tmp_path)
    r = _cli("bench.report", str(raw), "--out", str(tmp_path / "out"), "--no-latest")
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in (tmp_path / "out").iterdir())[:2] == ["raw-cost_vs_E.png", "raw-cost_vs_N.png"]
    assert (tmp_path / "out" / "raw.md").exists() and not (tmp_path / "out" / "latest.md").exists()


@pytest.mark.parametrize("args,needle", [
    (["--out", "FILE"], "--out FILE: {t}/FILE is a file, not a directory; give a writable directory"),
    (["--out", "FILE/sub"], "--out FILE/sub: {t}/FILE is a file, not a directory"),
    (["--out", "/proc/bench"], "--out /proc/bench: cannot create a file in /proc"),
    (["--only", "checks", "--skip", "checks"], "--only checks and --skip checks leave no part to run; parts: checks, "),
    (["--quick", "--only", "t2-f32"], "--quick times the t2-f64 process only; run t2-f32 without --quick"),
    (["--quick", "--skip", "checks,t2-f64,startup,headline"], "leave no part to run (--quick leaves out t1-f64, "
                                                              "t2-f32)"),
    (["--skip", "nonsense"], "--skip: unknown part(s) nonsense; valid: checks,"),
])
def test_bench_refuses_bad_arguments_in_one_line_and_writes_nothing(tmp_path, args, needle):
    """--out naming a file (a traceback), or parts that leave nothing to run (an empty report over
    latest.*), are bad input: one line, exit 2, before anything is written."""
    (tmp_path / "FILE").write_text("not a directory")
    out = [] if "--out" in args else ["--out", str(tmp_path / "results")]
    r = _cli("bench", *args, *out, cwd=tmp_path)
    assert needle.format(t=tmp_path) in _one_error_line(r, "python -m bench")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["FILE"] and (tmp_path / "FILE").read_text() == "not a directory"


def test_quick_report_says_the_rows_it_skips_by_design_are_skipped():
    """--quick does not run t2-f32 (bench/config.QUICK_SKIPS): its targets are 'skipped by --quick',
    not 'needs the peers'; a full run without a contender's rows still points at the peers."""
    import tempfile
    with tempfile.TemporaryDirectory() as d:
        doc = report.build(_synthetic_raw(Path(d)))
    assert doc["profile"] == "quick" and "bench-t2-f32.json" in doc["missing"]
    f32 = [t for t in doc["targets"] if t["name"].startswith("explicit step") and t["name"].endswith("t2-f32")]
    assert f32 and all(t["measured"] == "not measured (skipped by --quick: t2-f32 runs without it)" for t in f32)
    doc["profile"] = "full"
    f32 = [t for t in report.targets(doc) if t["name"].startswith("explicit step") and t["name"].endswith("t2-f32")]
    assert all(t["measured"] == "not measured (needs the peers: pip install -e '.[peers]')" for t in f32)


def test_the_membrane_pcg_is_set_against_scipy_cg_at_its_tolerance(tmp_path):
    """The membrane's iterative row gives the engine's PCG against scipy CG alone (pyamg, faster here, is
    not that comparison), per tolerance, and the target reads those ratios: met only where every one's
    spread is at or under 1."""
    raw = tmp_path / "raw"
    raw.mkdir()
    cl = dict(side=64, n=4096, triangles=7938, model=config.MEMBRANE_MODEL)
    b = []
    for tol, pcg in ((1e-5, [0.8, 0.9, 0.85]), (1e-8, [1.2, 1.1, 1.3])):
        b.append(_interleaved(config.MEMBRANE_IMPLICIT_GROUP, f"row-iterative-{tol}",
                              {"engine-pcg": (pcg, dict(solver="pcg", tol=tol)),
                               "scipy": ([1.0] * 3, dict(solver="scipy-cg", tol=tol)),
                               "peer-pyamg-cg": ([0.5] * 3, dict(solver="pyamg-cg", tol=tol))}, tol=tol, **cl))
    (raw / "bench-t2-f64.json").write_text(json.dumps(dict(benchmarks=b)))
    doc = report.build(raw)
    it = {p["what"]: p for p in doc["peer_ratios"] if p["kind"] == "iterative"}
    assert set(it) == {f"{config.MEMBRANE_MODEL}, PCG against scipy CG, tol 1e-05",
                       f"{config.MEMBRANE_MODEL}, PCG against scipy CG, tol 1e-08"}
    loose = it[f"{config.MEMBRANE_MODEL}, PCG against scipy CG, tol 1e-05"]
    assert loose["peer"] == "scipy" and loose["ratio"] == pytest.approx(0.85)
    assert loose["spread"] == pytest.approx((0.8, 0.9))
    t = [t for t in doc["targets"] if t["name"].startswith("membrane backward-Euler step, the engine's PCG")]
    assert len(t) == 1 and t[0]["met"] is True and "0.85" in t[0]["measured"]
