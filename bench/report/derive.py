"""The figures of one ``python -m bench`` run, row by row: the raw benchmark rows loaded and derived,
and the scaling exponent of each series.

Per benchmark row: per-step time = median / steps_per_call; ns per vertex per step; for rows
with a traffic model (bench/traffic.py) the floor time = bytes / floor bandwidth and the
fraction of the floor = floor time / measured time.  The floor bandwidth is the best streaming
copy (Taichi or numpy) measured in any process of the run, at the cache level that fits the
kernel's working set (cache-resident copy when the working set is at most half the last-level
cache, DRAM copy otherwise).  Then the scaling exponent of each series.  The engine against its
peers is bench/report/ratios.py, the targets (reported, never asserted) with the measured reasons
("why") for each one missed bench/report/targets.py, and the merged document (``build``)
bench/report/__init__.py.
"""
import numpy as np

from bench import traffic

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
