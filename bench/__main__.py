"""``python -m bench``: run the benchmark suite and write the report.

Parts, each in its own process so that thread count, precision and kernel cache are set at
start-up (Taichi initialises once per process):

0. checks: bench/test_correctness.py and bench/test_peers_explicit.py (plain pytest): the engine,
   the baselines and every installed peer compute the same forces and solve the same systems;
   if they do not, nothing is timed;
1. ``pytest bench --benchmark-only`` (pytest-benchmark) for each configuration:
   t2-f64 (ELASTIC_THREADS=2), t1-f64 (ELASTIC_THREADS=1), t2-f32 (ELASTIC_FP=32);
2. the start-up probe (bench/startup.py) with an empty, then the filled, kernel cache;
3. the headline sweep (bench/headline.py): cost per simulated second against E.

Then bench/report/ merges them into ``<out>/<timestamp>.json``, ``<timestamp>.md`` and PNG
plots, with copies ``latest.md``, ``latest.json``, ``latest-*.png`` (all in bench/results/, which git
ignores: a run never changes a tracked file; the committed reference is bench/reference/, written
only by ``python -m bench.report RAW --reference``).  Raw inputs and logs stay in
``<out>/raw/<timestamp>/``; pytest-benchmark's own storage (for ``--benchmark-compare``) in
``<out>/storage/<config>/``.

Exit status: 0 when every part ran, 1 when a part failed (the report is written anyway, and
says which), 2 for bad arguments.
"""
import json
import os
import subprocess
import sys
import time
from pathlib import Path

from bench import machine
from bench.config import QUICK_SKIPS
from bench.output import Parser, out_dir_problem, usage_error

BENCH_DIR = Path(__file__).resolve().parent
PROJECT_ROOT = BENCH_DIR.parent
CONFIGS = {"t2-f64": {"ELASTIC_THREADS": "2", "ELASTIC_FP": "64"},
           "t1-f64": {"ELASTIC_THREADS": "1", "ELASTIC_FP": "64"},
           "t2-f32": {"ELASTIC_THREADS": "2", "ELASTIC_FP": "32"}}
PARTS = ("checks",) + tuple(CONFIGS) + ("startup", "headline")
# what every contender computes, checked before anything is timed (the plain-pytest checks)
CHECK_FILES = ("bench/test_correctness.py", "bench/test_peers_explicit.py")
TIMEOUT_S = {"quick": 600, "full": 1800}
PROG = "python -m bench"


def _log(msg: str) -> None:
    print(msg, flush=True)


def _run(cmd, env, log_path: Path, timeout: float, prefix: str, show=lambda line: True):
    """Run cmd, streaming the lines ``show`` accepts with a time stamp; return (rc, wall s)."""
    t0 = time.perf_counter()
    with open(log_path, "w") as log:
        proc = subprocess.Popen(cmd, cwd=PROJECT_ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                text=True, bufsize=1)
        try:
            for line in proc.stdout:
                log.write(line)
                if show(line):
                    _log(f"  [{prefix} {time.perf_counter() - t0:6.1f}s] {line.rstrip()}")
                if time.perf_counter() - t0 > timeout:
                    proc.kill()
                    break
            rc = proc.wait(timeout=max(1.0, timeout - (time.perf_counter() - t0)))
        except subprocess.TimeoutExpired:
            proc.kill()
            rc = proc.wait()
    wall = time.perf_counter() - t0
    if wall > timeout:
        rc = 124
    return rc, wall


def _pytest_line(line: str) -> bool:
    if "test_correctness.py" in line or "test_report.py" in line:  # not benchmarks: skipped by --benchmark-only
        return "FAILED" in line or "ERROR" in line
    return "::" in line and any(w in line for w in ("PASSED", "FAILED", "ERROR", "SKIPPED"))


def _skip_reasons(log_path: Path) -> list:
    """The reasons pytest gave for skipped benchmarks (``-rs`` summary), without the
    --benchmark-only skips of the correctness tests."""
    out = []
    try:
        lines = log_path.read_text().splitlines()
    except OSError:
        return out
    for line in lines:
        if line.startswith("SKIPPED [") and "--benchmark-only" not in line:
            out.append(line.split("] ", 1)[-1])
    return out


def parse_args(argv):
    """The arguments, checked: bad ones (an unknown part, parts that leave nothing to run, a part
    --quick does not run) end the program with one line on stderr and exit status 2."""
    ap = Parser(prog=PROG, description=(
        "Run the explicit-vs-implicit benchmarks (pytest-benchmark) in one process per configuration, the "
        "start-up probe and the headline E sweep, and write bench/results/<timestamp>.{json,md,png} plus "
        "latest.* copies."))
    ap.add_argument("--quick", action="store_true",
                    help="the full run's 2-thread f64 rows up to 128^2, the headline at 32^2 and 64^2 (about "
                         "6-12 minutes on the quiet 2-core machine, about half of them grading a class: 364-488 s "
                         "measured on an AMD EPYC, 685 s on an Intel Xeon)")
    ap.add_argument("--out", default=str(BENCH_DIR / "results"), help="output directory (default bench/results)")
    ap.add_argument("--skip", default="", help=f"comma list of parts to leave out: {', '.join(PARTS)}")
    ap.add_argument("--only", default="", help="comma list of the only parts to run")
    ap.add_argument("--compare", action="store_true",
                    help="also compare each configuration with its previous saved run (pytest-benchmark "
                         "--benchmark-compare) and print the comparison")
    ap.add_argument("--no-latest", action="store_true", help="do not overwrite the latest.* copies")
    args = ap.parse_args(argv)
    for opt in ("skip", "only"):
        bad = [p for p in getattr(args, opt).split(",") if p and p not in PARTS]
        if bad:
            ap.error(f"--{opt}: unknown part(s) {', '.join(bad)}; valid: {', '.join(PARTS)}")
    if args.quick:   # the quick profile times the 2-thread f64 process only (bench/config.py)
        asked = [p for p in args.only.split(",") if p in QUICK_SKIPS]
        if asked:
            ap.error(f"--quick times the t2-f64 process only; run {', '.join(asked)} without --quick")
    if not selected_parts(args):
        ap.error(f"--only {args.only or '(all)'} and --skip {args.skip or '(none)'} leave no part to run"
                 + (f" (--quick leaves out {', '.join(QUICK_SKIPS)})" if args.quick else "")
                 + f"; parts: {', '.join(PARTS)}")
    return args


def selected_parts(args) -> list:
    """The parts to run, in order: --only's (all by default) less --skip's, less QUICK_SKIPS with --quick."""
    skip = {p for p in args.skip.split(",") if p}
    only = {p for p in args.only.split(",") if p}
    return [p for p in PARTS if p not in skip and (not only or p in only) and not (args.quick and p in QUICK_SKIPS)]


def main(argv=None) -> int:
    args = parse_args(argv)
    profile = "quick" if args.quick else "full"
    out = Path(args.out).resolve()
    problem = out_dir_problem(out)
    if problem:
        return usage_error(PROG, f"--out {args.out}: {problem}; give a writable directory")
    stamp = time.strftime("%Y%m%d-%H%M%S")
    raw = out / "raw" / stamp
    skip = {p for p in args.skip.split(",") if p}
    only = {p for p in args.only.split(",") if p}
    parts = selected_parts(args)
    raw.mkdir(parents=True, exist_ok=True)
    timeout = TIMEOUT_S[profile]
    info = machine.machine_info()
    command = "python -m bench" + (" --quick" if args.quick else "") + (f" --skip {args.skip}" if skip else "") \
        + (f" --only {args.only}" if only else "")
    _log(f"bench: profile {profile}, parts {', '.join(parts)}; {info['cpu']}, {info['cores']} cores, "
         f"load {info['load_average']}; raw output in {raw}")
    run = dict(timestamp=stamp, profile=profile, command=command, machine=info, parts={}, errors=[])
    t_all = time.perf_counter()
    base_env = dict(os.environ, ELASTIC_BENCH_PROFILE=profile, PYTHONUNBUFFERED="1")

    if "checks" in parts:
        _log("[checks] the engine, the baselines and every peer compute the same thing (bench/test_correctness.py, "
             "bench/test_peers_explicit.py)")
        env = dict(base_env, ELASTIC_THREADS="2", ELASTIC_FP="64", ELASTIC_BENCH_PROFILE="smoke")
        cmd = [sys.executable, "-m", "pytest", *CHECK_FILES, "-q", "-rs", "-p", "no:cacheprovider",
               "--benchmark-disable", "-n", "0"]
        rc, wall = _run(cmd, env, raw / "checks.log", timeout, "checks",
                        show=lambda line: "passed" in line or "failed" in line or "FAILED" in line)
        run["parts"]["checks"] = dict(rc=rc, wall_s=wall, skipped=_skip_reasons(raw / "checks.log"))
        if rc != 0:
            run["errors"].append(f"checks: pytest exit {rc}: a contender does not compute what the engine does; "
                                 f"nothing was timed (log {raw / 'checks.log'})")
            parts = [p for p in parts if p == "checks"]

    for cfg, cenv in CONFIGS.items():
        if cfg not in parts:
            continue
        _log(f"[{cfg}] pytest bench --benchmark-only ({', '.join(f'{k}={v}' for k, v in cenv.items())})")
        env = dict(base_env, **cenv)
        storage = out / "storage" / cfg
        cmd = [sys.executable, "-m", "pytest", "bench", "-v", "-rs", "-p", "no:cacheprovider", "-n", "0", "--benchmark-enable",
               "--benchmark-only", f"--benchmark-json={raw / f'bench-{cfg}.json'}",
               f"--benchmark-storage=file://{storage}", f"--benchmark-save={cfg}",
               "--benchmark-columns=median,iqr,rounds", "--benchmark-sort=fullname"]
        if args.compare and storage.is_dir() and any(storage.rglob("*.json")):
            cmd.append("--benchmark-compare")
        rc, wall = _run(cmd, env, raw / f"bench-{cfg}.log", timeout, cfg,
                        show=(lambda line: True) if args.compare else _pytest_line)
        run["parts"][cfg] = dict(rc=rc, wall_s=wall, skipped=_skip_reasons(raw / f"bench-{cfg}.log"))
        _log(f"[{cfg}] done in {wall:.0f} s (exit {rc})")
        if rc != 0:
            run["errors"].append(f"{cfg}: pytest exit {rc} (log {raw / f'bench-{cfg}.log'})")

    if "startup" in parts:
        cache = raw / "startup-cache"
        cache.mkdir(exist_ok=True)
        for kind, reset in (("cold", False), ("after-plain-exit", True), ("warm", False)):
            _log(f"[startup] {kind} kernel cache")
            env = dict(base_env, ELASTIC_CACHE_DIR=str(cache), ELASTIC_THREADS="2", ELASTIC_FP="64")
            dst = raw / f"startup-{kind}.json"
            cmd = [sys.executable, "-m", "bench.startup", "--json", str(dst)] + (["--reset-at-exit"] if reset else [])
            rc, wall = _run(cmd, env, raw / f"startup-{kind}.log", timeout, "startup", show=lambda line: False)
            run["parts"][f"startup-{kind}"] = dict(rc=rc, wall_s=wall)
            if rc == 0 and dst.exists():
                d = json.loads(dst.read_text())
                d["subprocess_wall_s"] = wall
                d["cache_files_after_exit"] = sum(1 for _ in cache.iterdir())
                dst.write_text(json.dumps(d, indent=1))
                _log(f"[startup] {kind}: process {wall:.1f} s, first calls {d['first_calls_s']:.1f} s, "
                     f"cache files after exit {d['cache_files_after_exit']}")
            else:
                run["errors"].append(f"startup {kind}: exit {rc}")

    if "headline" in parts:
        _log("[headline] cost per simulated second against E")
        env = dict(base_env, ELASTIC_THREADS="2", ELASTIC_FP="64")
        cmd = [sys.executable, "-m", "bench.headline", "--json", str(raw / "headline.json")]
        if args.quick:
            cmd.append("--quick")
        rc, wall = _run(cmd, env, raw / "headline.log", timeout, "headline",
                        show=lambda line: line.lstrip().startswith("headline"))
        run["parts"]["headline"] = dict(rc=rc, wall_s=wall)
        if rc != 0:
            run["errors"].append(f"headline: exit {rc} (log {raw / 'headline.log'})")

    run["wall_s"] = time.perf_counter() - t_all
    run["load_average_end"] = machine.load_average()
    (raw / "run.json").write_text(json.dumps(run, indent=1))

    from bench import report
    doc = report.build(raw)
    paths = report.write(doc, out, stamp, latest=not args.no_latest)
    _log("")
    for t in doc["targets"]:
        status = "not measured" if t.get("met") is None else ("met" if t["met"] else f"MISSED ({t.get('by')})")
        _log(f"target: {t['name']}: {t.get('measured')} -> {status}")
    h = doc.get("headline") or {}
    for side, s in h.get("sides", {}).items():
        for name, c in s["crossover"].items():
            where = f"E ~ {c['E']:.3g} N/m ({c['note']})" if c.get("E") else c.get("note")
            _log(f"crossover {side}^2, implicit dt {name}: {where}")
    ref_json = report.REFERENCE_DIR / "report.json"
    if ref_json.exists():   # an outside rerun checks itself against the committed reference
        try:
            lines, _ = report.against_text(doc, json.loads(ref_json.read_text()), "the reference report")
            _log("")
            for line in lines:
                _log(line)
        except (OSError, ValueError, KeyError) as exc:
            _log(f"(could not compare with the reference report: {exc})")
    _log(f"wall time {run['wall_s']:.0f} s; report {paths['md']}" + (f" (and {paths['latest_md']})"
                                                                       if "latest_md" in paths else ""))
    if run["errors"]:
        _log("failed parts: " + "; ".join(run["errors"]))
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
