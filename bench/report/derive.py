"""The figures of one ``python -m bench`` run: the raw inputs loaded, derived per row, and judged
against the targets.

Per benchmark row: per-step time = median / steps_per_call; ns per vertex per step; for rows
with a traffic model (bench/traffic.py) the floor time = bytes / floor bandwidth and the
fraction of the floor = floor time / measured time.  The floor bandwidth is the best streaming
copy (Taichi or numpy) measured in any process of the run, at the cache level that fits the
kernel's working set (cache-resident copy when the working set is at most half the last-level
cache, DRAM copy otherwise).  Then the scaling exponent of each series, and the targets (reported,
never asserted) with the measured reasons ("why") for each one missed.
"""
import json
from pathlib import Path

import numpy as np

from bench import traffic
from bench.config import MEMBRANE_IMPLICIT_GROUP, MEMBRANE_MODEL, QUICK_SKIPS
from bench.interleave import spread
from engine.constants import SERIAL_BELOW

TARGET_SIDE = 128
TARGET_FLOOR_FACTOR = 3.0
CONFIGS = ("t2-f64", "t1-f64", "t2-f32")
STARTUP_RUNS = ("cold", "after-plain-exit", "warm")
STEP_KERNELS = ("zero", "spring_gather", "hinge_pass1", "hinge_gather", "update")
ALL_KERNELS = ("zero", "spring_gather", "spring_atomic", "spring_serial", "hinge_pass1", "hinge_gather",
               "bending_gather", "bending_atomic", "bending_serial", "update")


# --------------------------------------------------------------------------------------------
# Loading and deriving
# --------------------------------------------------------------------------------------------

def _load_json(path: Path):
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def rows_from_pytest_benchmark(data: dict) -> list:
    """One flat dict per benchmark: extra_info + timing statistics (seconds).  An interleaved row
    (bench/interleave.py) becomes one dict per contender, with its per-round seconds
    (``round_s``) and the row's name (``row_id``), so that ratios can be taken round by round."""
    rows = []
    for b in data.get("benchmarks", []):
        ei = dict(b.get("extra_info", {}))
        inter = ei.pop("interleaved", None)
        if inter is not None:
            for impl, c in inter.items():
                rs = [float(t) for t in c.get("round_s", [])]
                if not rs:
                    continue
                row = dict(ei)
                row.update(c.get("info", {}))
                q1, q3 = np.percentile(rs, [25, 75])
                row.update(group=b.get("group"), name=f"{b.get('name')}[{impl}]", impl=impl, row_id=b.get("name"),
                           round_s=rs, median_s=float(np.median(rs)), iqr_s=float(q3 - q1), min_s=min(rs),
                           rounds_done=len(rs))
                rows.append(_per_step(row))
            continue
        st = b.get("stats", {})
        row = dict(ei)
        row.update(group=b.get("group"), name=b.get("name"), median_s=st.get("median"), iqr_s=st.get("iqr"),
                   min_s=st.get("min"), rounds_done=st.get("rounds"))
        rows.append(_per_step(row))
    return rows


def _per_step(row: dict) -> dict:
    steps = max(int(row.get("steps_per_call", 1) or 1), 1)
    if row["median_s"] is not None:
        row["per_step_s"] = row["median_s"] / steps
        if row.get("n"):
            row["ns_per_vertex"] = row["per_step_s"] / row["n"] * 1e9
    return row


def bandwidths(rows: list) -> dict:
    """{config: {level: {"taichi": B/s, "numpy": B/s, "floor": best}}} from the copy probes."""
    out = {}
    for r in rows:
        if r.get("group") != "bandwidth" or not r.get("median_s"):
            continue
        lv = out.setdefault(r["config"], {}).setdefault(r["level"], {})
        lv[r["impl"]] = r["bytes"] / r["median_s"]
    best = {}
    for cfg in out.values():
        for level, lv in cfg.items():
            lv["best"] = max(v for k, v in lv.items())
            best[level] = max(best.get(level, 0.0), lv["best"])
    for cfg in out.values():  # the hardware's floor: the best copy seen in this run at that level
        for level, lv in cfg.items():
            lv["floor"] = best[level]
    return out


def _fb(config: str) -> int:
    return 4 if config and config.endswith("f32") else 8


def _working_set(r: dict) -> int:
    fb = _fb(r.get("config", ""))
    if r.get("group", "").startswith("rod"):
        return 10 * fb * int(r.get("n", 0))
    return traffic.working_set_bytes(int(r.get("n", 0)), int(r.get("m", 0) or 0), int(r.get("h", 0) or 0), fb)


def derive_floors(rows: list, bw: dict, llc_bytes: int) -> None:
    """Add floor_s, floor_level and bw_fraction to rows with a byte count."""
    for r in rows:
        if not r.get("bytes") or not r.get("per_step_s") or r.get("group") == "bandwidth":
            continue
        levels = bw.get(r.get("config")) or bw.get("t2-f64") or {}
        ws = r.get("bytes_per_iteration") or _working_set(r)  # a CG iteration touches the solver's arrays too
        level = "cache" if llc_bytes and ws <= llc_bytes / 2 else "dram"
        if level not in levels:
            level = "dram" if "dram" in levels else (next(iter(levels)) if levels else None)
        if level is None:
            continue
        r["working_set_bytes"] = ws
        r["floor_level"] = level
        r["floor_bandwidth"] = levels[level]["floor"]
        r["floor_s"] = r["bytes"] / levels[level]["floor"]
        r["bw_fraction"] = r["floor_s"] / r["per_step_s"]


def find(rows: list, **kw):
    for r in rows:
        if all(r.get(k) == v for k, v in kw.items()):
            return r
    return None


def scaling_exponents(rows: list) -> list:
    """Least-squares slope of log(time per step) against log(n) for every series with >= 2 sizes."""
    series = {}
    for r in rows:
        if not r.get("per_step_s") or not r.get("n") or r.get("group") == "bandwidth":
            continue
        key = (r.get("config"), r.get("group"), r.get("impl"), r.get("model") or r.get("kernel") or r.get("method"),
               r.get("solver"))
        series.setdefault(key, []).append((r["n"], r["per_step_s"]))
    out = []
    for key, pts in sorted(series.items(), key=lambda kv: tuple(str(k) for k in kv[0])):
        pts = sorted(set(pts))
        if len({p[0] for p in pts}) < 2:
            continue
        x = np.log([p[0] for p in pts])
        y = np.log([p[1] for p in pts])
        slope = float(np.polyfit(x, y, 1)[0])
        out.append(dict(config=key[0], group=key[1], impl=key[2], what=key[3], solver=key[4],
                        n=[int(p[0]) for p in pts], exponent=slope))
    return out


def build(raw_dir) -> dict:
    """The merged result document of one run, from its raw directory (written by bench/__main__.py):
    ``bench-<config>.json`` (pytest-benchmark JSON, one per process configuration),
    ``startup-{cold,after-plain-exit,warm}.json``, ``headline.json`` and ``run.json`` (timestamp,
    profile, machine, wall times, errors).  Any of them may be missing: the document lists the
    missing benchmark files instead of failing."""
    raw = Path(raw_dir)
    run = _load_json(raw / "run.json") or {}
    rows, missing = [], []
    for cfg in CONFIGS:
        data = _load_json(raw / f"bench-{cfg}.json")
        if data is None:
            missing.append(f"bench-{cfg}.json")
            continue
        rows.extend(rows_from_pytest_benchmark(data))
    machine = run.get("machine", {})
    bw = bandwidths(rows)
    derive_floors(rows, bw, int(machine.get("last_level_cache_bytes", 0) or 0))
    doc = dict(run)
    doc.update(rows=rows, bandwidth=bw, scaling=scaling_exponents(rows),
               startup={k: _load_json(raw / f"startup-{k}.json") for k in STARTUP_RUNS},
               headline=_load_json(raw / "headline.json"), missing=missing)
    doc["peer_ratios"] = peer_ratios(rows)
    doc["targets"] = targets(doc)
    return doc


# --------------------------------------------------------------------------------------------
# Targets (reported, never asserted)
# --------------------------------------------------------------------------------------------

EXPLICIT_PEERS = ("numba", "warp")
EXPLICIT_MODELS = ("springs+bending", "springs", MEMBRANE_MODEL)   # the models of the explicit rows
STEP_GROUPS = ("cloth-implicit-step", MEMBRANE_IMPLICIT_GROUP)   # one backward-Euler step per call, per solver
IMPLICIT_TARGET_RATIO = 0.8      # engine whole step <= 0.8 x the fastest contender (128^2, 256^2, tol 1e-5)
SEQUENCE_TARGET_RATIO = 0.5      # over 60 consecutive steps
EXPLICIT_TARGET_RATIO = 0.8      # engine <= 0.8 x the faster of Warp and Numba


def _is_engine(impl: str) -> bool:
    return impl == "engine" or impl.startswith("engine-")


def _implicit_rows(rows, cfg, side, tol, group="cloth-implicit-step"):
    """The rows of one implicit comparison: iterative solvers at ``tol``, direct ones (timed once,
    at 1e-5: they reach ~1e-13) whatever ``tol``."""
    out = []
    for r in rows:
        if r.get("config") != cfg or r.get("group") != group or r.get("side") != side or not r.get("per_step_s"):
            continue
        iterative = r.get("impl") in ("engine-pcg", "scipy", "peer-pyamg-cg")
        if group in STEP_GROUPS and iterative and not _close(r.get("tol"), tol):
            continue
        out.append(r)
    return out


def _close(a, b) -> bool:
    return a is not None and b is not None and abs(float(a) - float(b)) <= 1e-12 + 1e-6 * abs(float(b))


def peer_ratios(rows: list) -> list:
    """One entry per comparison row: the engine's fastest time and the fastest peer's, their ratio
    (engine / peer: below 1 the engine is faster) and the engine row's bandwidth floor."""
    out = []
    for cfg in CONFIGS:
        for group in ("cloth-explicit-step", "cloth-explicit-block"):
            for model in EXPLICIT_MODELS:
                for side in sorted({r["side"] for r in rows if r.get("config") == cfg
                                    and r.get("group") == group and r.get("model") == model}):
                    rs = [r for r in rows if r.get("config") == cfg and r.get("group") == group
                          and r.get("model") == model and r.get("side") == side and r.get("per_step_s")]
                    out.append(_ratio_entry("explicit", cfg, side, _explicit_what(model, rs), rs, EXPLICIT_PEERS))
        for group, kind, model in (("cloth-implicit-step", "implicit", ""), ("cloth-implicit-sequence", "sequence", ""),
                                   (MEMBRANE_IMPLICIT_GROUP, "implicit", MEMBRANE_MODEL + ", ")):
            sides = sorted({r["side"] for r in rows if r.get("config") == cfg and r.get("group") == group})
            for side in sides:
                tols = sorted({float(r["tol"]) for r in rows if r.get("config") == cfg and r.get("group") == group
                               and r.get("side") == side and r.get("tol")}, reverse=True)
                for tol in tols:
                    rs = _implicit_rows(rows, cfg, side, tol, group)
                    out.append(_ratio_entry(kind, cfg, side, f"{model}tol {tol:.0e}", rs, None))
        # the engine's whole step against PARDISO's factorisation + solve of the same matrix alone
        for side in sorted({r["side"] for r in rows if r.get("config") == cfg and r.get("library_only")}):
            rs = [r for r in rows if r.get("config") == cfg and r.get("group") == "cloth-implicit-step"
                  and r.get("side") == side and r.get("impl") in ("engine-pardiso", "peer-pardiso-factor")
                  and r.get("per_step_s")]
            out.append(_ratio_entry("library", cfg, side, "PARDISO factorisation + solve alone", rs,
                                    ("peer-pardiso-factor",)))
    return [e for e in out if e]


def _explicit_what(model: str, rs: list) -> str:
    """The comparison's name: the model, and the steps per call when more than one (block rows)."""
    k = max((int(r.get("steps_per_call", 1) or 1) for r in rs), default=1)
    return model if k == 1 else f"{model}, {k} steps per call"


def _ratio_entry(kind, cfg, side, what, rs, peer_names):
    """The engine's fastest way against the fastest peer of one comparison.  When both were timed
    in the same interleaved row, the ratio is the median of the per-round ratios (engine / peer in
    the same round) and ``spread`` their range (bench/interleave.spread); ``resolved`` is False
    when that range contains 1 (the row cannot tell which is faster)."""
    eng = [r for r in rs if _is_engine(r.get("impl", ""))]
    if peer_names is None:
        peer = [r for r in rs if not _is_engine(r.get("impl", "")) and not r.get("library_only")]
    else:
        peer = [r for r in rs if r.get("impl") in peer_names]
    if not eng:
        return None
    e = min(eng, key=lambda r: r["per_step_s"])
    p = min(peer, key=lambda r: r["per_step_s"]) if peer else None
    out = dict(kind=kind, config=cfg, side=side, what=what, engine=e.get("impl"), engine_solver=e.get("solver"),
               engine_s=e["per_step_s"], peer=p and p.get("impl"), peer_s=p and p["per_step_s"],
               ratio=(e["per_step_s"] / p["per_step_s"]) if p else None, spread=None, rounds=None,
               interleaved=False, resolved=None,
               floor_s=e.get("floor_s"), bw_fraction=e.get("bw_fraction"),
               all={r.get("impl"): r["per_step_s"] for r in rs})
    if p and e.get("row_id") and e.get("row_id") == p.get("row_id") and e.get("round_s") and p.get("round_s"):
        per_round = [a / b for a, b in zip(e["round_s"], p["round_s"])]
        med, lo, hi = spread(per_round)
        out.update(ratio=med, spread=(lo, hi), rounds=len(per_round), interleaved=True, resolved=not lo <= 1.0 <= hi)
    return out


def ratio_text(p) -> str:
    """"0.78 (0.74-0.83, 9 rounds)" for an interleaved row; "not resolved" when its spread
    contains 1; "(not interleaved)" for a ratio of medians taken at different times."""
    if p.get("ratio") is None:
        return "-"
    if not p.get("interleaved"):
        return f"{p['ratio']:.2f} (not interleaved)"
    lo, hi = p["spread"]
    text = f"{p['ratio']:.2f} ({lo:.2f}-{hi:.2f}, {p['rounds']} rounds)"
    return text if p.get("resolved") else text + ", not resolved"


def agreement(doc: dict, ref: dict) -> list:
    """Each comparison row present in both run documents: this run's ratio against the reference's
    ratio and spread; ``inside`` is True when this run's ratio lies within the reference's spread
    (None when the reference row has no spread)."""
    key = lambda p: (p["kind"], p["config"], p["side"], p["what"])  # noqa: E731
    theirs = {key(p): p for p in ref.get("peer_ratios") or [] if p.get("ratio") is not None}
    out = []
    for p in doc.get("peer_ratios") or []:
        r = theirs.get(key(p))
        if r is None or p.get("ratio") is None:
            continue
        sp = r.get("spread")
        inside = None if not sp else bool(sp[0] <= p["ratio"] <= sp[1])
        out.append(dict(kind=p["kind"], config=p["config"], side=p["side"], what=p["what"], ratio=p["ratio"],
                        spread=p.get("spread"), ref_ratio=r["ratio"], ref_spread=sp, inside=inside))
    return out


def targets(doc: dict) -> list:
    rows = doc["rows"]
    ratios = doc.get("peer_ratios") or peer_ratios(rows)
    out = []

    def judge(name, target, picks, goal, cfg="t2-f64"):
        t = dict(name=name, target=target)
        picks = [p for p in picks if p and p.get("ratio") is not None]
        if not picks:
            skipped = doc.get("profile") == "quick" and cfg in QUICK_SKIPS  # by design, not for want of peers
            t.update(measured=f"not measured (skipped by --quick: {cfg} runs without it)" if skipped
                     else "not measured (needs the peers: pip install -e '.[peers]')", met=None)
            return t
        # met only when every row's whole spread lies at or under the goal
        upper = lambda p: p["spread"][1] if p.get("spread") else p["ratio"]  # noqa: E731
        worst = max(picks, key=upper)
        t.update(measured="; ".join(f"{p['side']}^2 {p['what']}: {ratio_text(p)} ({_short(p['engine'])} "
                                    f"{p['engine_s'] * 1e3:.3g} ms vs {_short(p['peer'])} {p['peer_s'] * 1e3:.3g} ms)"
                                    for p in picks),
                 value=worst["ratio"], met=upper(worst) <= goal,
                 by=f"worst {worst['ratio']:.2f}x (spread up to {upper(worst):.2f}) at {worst['side']}^2 "
                    f"{worst['what']}" if upper(worst) > goal else "")
        return t

    pick = lambda kind, cfg, side=None, what=None: [p for p in ratios if p["kind"] == kind and p["config"] == cfg
                                                    and (side is None or p["side"] == side)
                                                    and (what is None or p["what"] == what)]
    t = judge("implicit step, whole step (assembly + set-up + solve), 128^2 and 256^2, tol 1e-5, f64, 2 threads",
              f"<= {IMPLICIT_TARGET_RATIO:g} x the fastest contender",
              pick("implicit", "t2-f64", 128, "tol 1e-05") + pick("implicit", "t2-f64", 256, "tol 1e-05"),
              IMPLICIT_TARGET_RATIO)
    t["why"] = _why_implicit(rows, ratios)
    out.append(t)
    out.append(judge("implicit steps, 60 consecutive steps of the hanging cloth, tol 1e-5",
                     f"<= {SEQUENCE_TARGET_RATIO:g} x the fastest contender", pick("sequence", "t2-f64"),
                     SEQUENCE_TARGET_RATIO))
    out[-1]["why"] = _why_sequence(ratios)
    blocks = sorted({p["what"].split(", ", 1)[1] for p in ratios if p["kind"] == "explicit" and ", " in p["what"]})
    for cfg in ("t2-f64", "t2-f32"):
        for model in ("springs+bending", "springs"):
            for block in [None] + blocks:
                what = model if block is None else f"{model}, {block}"
                t = judge(f"explicit step, {what if block else model + ', one step per call'}, 64^2 to 256^2, {cfg}",
                          f"<= {EXPLICIT_TARGET_RATIO:g} x the faster of Warp and Numba (timed over the same steps)",
                          [p for p in pick("explicit", cfg, what=what) if 64 <= p["side"] <= 256],
                          EXPLICIT_TARGET_RATIO, cfg)
                if cfg == "t2-f64" and model == "springs+bending" and block is None:
                    r = find(rows, config="t2-f64", group="cloth-explicit-step", impl="engine", model=model,
                             side=TARGET_SIDE)
                    if r:
                        t["why"] = _why_explicit(rows, TARGET_SIDE, r)
                out.append(t)
    # every kernel's fraction of the bandwidth floor: reported
    side = TARGET_SIDE
    ks = [find(rows, config="t2-f64", group="cloth-force-kernels", kernel=k, side=side) for k in STEP_KERNELS]
    ks = [k for k in ks if k and k.get("bw_fraction")]
    for extra in (find(rows, config="t2-f64", group="cloth-explicit-step", impl="engine", model="springs+bending",
                       side=side),
                  find(rows, config="t2-f64", group="cloth-implicit-step", impl="engine-pcg", side=side)):
        if extra and extra.get("bw_fraction"):
            ks.append(extra)
    t = dict(name=f"each engine kernel's fraction of its bandwidth floor ({side}^2, f64, 2 threads)",
             target=f"reported (within {TARGET_FLOOR_FACTOR:g}x: fraction >= {1 / TARGET_FLOOR_FACTOR:.2f})")
    if ks:
        misses = [k for k in ks if k["bw_fraction"] < 1 / TARGET_FLOOR_FACTOR]
        t.update(measured=", ".join(f"{_kname(k)} {k['bw_fraction']:.2f}" for k in ks), met=not misses,
                 value=min(k["bw_fraction"] for k in ks))
        t["by"] = ", ".join(f"{_kname(k)} {1 / k['bw_fraction']:.0f}x from floor" for k in misses)
        t["why"] = _why_floor(rows, misses, side)
    else:
        t.update(measured="not measured", met=None)
    out.append(t)
    return out


def _short(impl) -> str:
    return str(impl or "-").replace("peer-", "")


def _kname(r: dict) -> str:
    if r.get("group") == "cloth-force-kernels":
        return r["kernel"]
    if r.get("group") == "cloth-explicit-step":
        return "explicit step"
    if r.get("group") == "cloth-implicit-step":
        return f"backward-Euler step ({r.get('solver')})"
    return r.get("name", "?")


def _why_explicit(rows, side, step) -> list:
    why = []
    ks = {k: find(rows, config="t2-f64", group="cloth-force-kernels", kernel=k, side=side) for k in STEP_KERNELS}
    if all(ks.values()):
        total = sum(k["per_step_s"] for k in ks.values())
        parts = ", ".join(f"{k} {v['per_step_s'] * 1e6:.0f} us ({v['per_step_s'] / total:.0%})" for k, v in ks.items())
        why.append(f"The engine's step is one kernel launch (engine/integrators/cloth_kernels.py, cloth_step: one "
                   f"parallel loop over vertex blocks, each block summing its vertices' spring and hinge forces in the "
                   f"generic path's order and updating them; cloth_steps takes many steps in one launch); the "
                   f"{len(ks)} kernels of the generic path, launched alone, take {parts} "
                   f"(sum {total * 1e3:.3f} ms against {step['per_step_s'] * 1e3:.3f} ms for the fused step).")
        bend = ks["hinge_pass1"]["per_step_s"] + ks["hinge_gather"]["per_step_s"]
        why.append(f"Bending costs {bend * 1e6:.0f} us of the generic path ({bend / total:.0%}): its per-hinge pass "
                   f"evaluates the dihedral angle, cross products, square roots and divisions for ~{step['h']} "
                   f"hinges and writes 4 vectors per hinge, which its gather pass reads back (the fused step "
                   f"adds them to the block's sums instead).")
        z = ks["zero"]["per_step_s"]
        why.append(f"A launch that only zeroes f takes {z * 1e6:.0f} us, which bounds the fixed cost per "
                   f"kernel on this machine (parallel-for launch + Python argument handling + ti.sync).")
        if step.get("floor_s"):
            why.append(f"At its bandwidth floor the step would take {step['floor_s'] * 1e6:.0f} us "
                       f"({step['floor_s'] / step['n'] * 1e9:.1f} ns/vertex): the target is within the hardware's "
                       f"reach, not within this formulation's (a trigonometric per-hinge pass in f64, "
                       f"per-hinge vectors written and read back, a fixed launch cost).")
    sp = find(rows, config="t2-f64", group="cloth-explicit-step", impl="engine", model="springs", side=side)
    if sp:
        peers = [find(rows, config="t2-f64", group="cloth-explicit-step", impl=k, model="springs", side=side)
                 for k in EXPLICIT_PEERS]
        peers = ", ".join(f"{p['impl']} {p['ns_per_vertex']:.1f}" for p in peers if p and p.get("ns_per_vertex"))
        why.append(f"Without bending the engine's step is {sp['ns_per_vertex']:.1f} ns/vertex"
                   + (f" (the peers' in the same run: {peers})." if peers else "."))
    f32 = find(rows, config="t2-f32", group="cloth-explicit-step", impl="engine", model="springs+bending", side=side)
    if f32:
        why.append(f"In f32 the same step is {f32['ns_per_vertex']:.1f} ns/vertex.")
    var = {k: find(rows, config="t2-f64", group="cloth-force-kernels", kernel=k, side=side)
           for k in ("bending_gather", "bending_serial", "bending_atomic")}
    if all(var.values()):
        why.append("Bending variants: " + ", ".join(f"{k} {v['per_step_s'] * 1e6:.0f} us" for k, v in var.items())
                   + " (the engine uses the deterministic two-pass gather).")
    return why


def _why_implicit(rows, ratios) -> list:
    why = []
    for p in ratios:
        if p["kind"] != "implicit" or p["config"] != "t2-f64" or p["what"] != "tol 1e-05":
            continue
        parts = ", ".join(f"{_short(k)} {v * 1e3:.0f}" for k, v in sorted(p["all"].items(), key=lambda kv: kv[1]))
        why.append(f"{p['side']}^2, ms per step: {parts}.")
    sides = sorted({r["side"] for r in rows if r.get("config") == "t2-f64" and r.get("impl") == "engine-pardiso"
                    and r.get("group") == "cloth-implicit-step"})
    for side in sides:
        e = find(rows, config="t2-f64", group="cloth-implicit-step", impl="engine-pardiso", side=side)
        pp = find(rows, config="t2-f64", group="cloth-implicit-step", impl="peer-pardiso", side=side)
        lib = find(rows, config="t2-f64", group="cloth-implicit-step", impl="peer-pardiso-factor", side=side)
        if not (e and e.get("factorization_s") is not None):
            continue
        line = (f"{side}^2, split of the timed steps (medians): engine PARDISO {e['per_step_s'] * 1e3:.1f} ms = assembly "
                f"{e['assembly_s'] * 1e3:.1f} (Taichi gather into the fixed pattern) + numeric factorisation "
                f"{e['factorization_s'] * 1e3:.1f} + back-substitution and residual check {e['solve_s'] * 1e3:.1f} "
                f"+ the rest of the step {max(e['per_step_s'] - e['assembly_s'] - e['factorization_s'] - e['solve_s'], 0) * 1e3:.1f}")
        if pp and pp.get("setup_s") is not None:
            line += (f"; numpy + PARDISO {pp['per_step_s'] * 1e3:.1f} ms = assembly {pp['assembly_s'] * 1e3:.1f} + "
                     f"factorisation {pp['setup_s'] * 1e3:.1f} + solve {pp['solve_s'] * 1e3:.1f} + the rest (residual "
                     f"check, update) {max(pp['per_step_s'] - pp['assembly_s'] - pp['setup_s'] - pp['solve_s'], 0) * 1e3:.1f}")
        if lib:
            line += f"; PARDISO's factorisation + solve alone {lib['per_step_s'] * 1e3:.1f} ms"
        why.append(line + ".")
    if sides:
        why.append("Both factorise with the same library and settings, so the engine's margin is its assembly (a "
                   "parallel Taichi gather into a pattern fixed per model, against numpy's single-threaded scatter) "
                   "and a residual check without a second matrix.")
    return why


def _why_sequence(ratios) -> list:
    why = []
    for p in ratios:
        if p["kind"] == "sequence" and p["config"] == "t2-f64":
            parts = ", ".join(f"{_short(k)} {v * 1e3:.0f}" for k, v in sorted(p["all"].items(), key=lambda kv: kv[1]))
            why.append(f"{p['side']}^2, ms per step over 60 steps: {parts}.")
    why.append("Reusing a factorisation across steps as the preconditioner of CG was measured on the 64^2 hanging "
               "cloth (E = 1e3 N/m, dt = 1/60 s): CG with the previous step's PARDISO factor needed 12-31 iterations "
               "to reach 1e-5 (refreshed when above 15), and one back-substitution costs about 1/15-1/7 of a "
               "numeric factorisation, so reuse costs as much as refactorising: the engine refactorises every step.")
    return why


def _why_floor(rows, misses, side) -> list:
    why = []
    zero = find(rows, config="t2-f64", group="cloth-force-kernels", kernel="zero", side=side)
    reasons = {
        "zero": "moves only n x 24 bytes: the fixed launch cost dominates",
        "update": "one short pass: the fixed launch cost dominates",
        "spring_gather": "gathers x of each neighbour through an index (2 per edge) and divides/square-roots per "
                         "incidence; every edge is computed twice (once from each end)",
        "spring_atomic": "float atomics are compare-and-swap loops on the CPU",
        "spring_serial": "one thread",
        "hinge_pass1": "arithmetic-bound: trigonometry, cross products, square roots and divisions per hinge",
        "hinge_gather": "indexed reads of 4 vectors per hinge through the incidence (entry // 4, entry % 4)",
        "bending_gather": "the two passes above",
        "bending_atomic": "arithmetic-bound per hinge plus compare-and-swap atomics",
        "bending_serial": "arithmetic-bound per hinge on one thread",
    }
    for k in misses:
        name = _kname(k)
        r = reasons.get(k.get("kernel"), "")
        if k.get("group") == "cloth-explicit-step":
            r = "the sum of its kernels above"
        if k.get("group") == "cloth-implicit-step":
            r = (f"the CG loop runs serially (one thread) below {SERIAL_BELOW} vertices and each iteration does "
                 "3x3 block products per incidence and rank-one hinge products")
        fixed = ""
        if zero and k.get("group") == "cloth-force-kernels":
            fixed = f"; fixed cost ~{zero['per_step_s'] * 1e6:.0f} us of {k['per_step_s'] * 1e6:.0f} us"
        why.append(f"{name}: {k['bw_fraction']:.2f} of the floor ({k['floor_s'] * 1e6:.1f} us for "
                   f"{k['bytes'] / 1e6:.2f} MB at {k['floor_bandwidth'] / 1e9:.0f} GB/s, {k['floor_level']}); "
                   f"{r}{fixed}.")
    return why

