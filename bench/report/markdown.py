"""The Markdown report of one run's merged document (``build``, bench/report/__init__.py): machine,
targets and why, headline, one section per benchmark group, scaling, threads and precision,
start-up, the bandwidth floor, what was left out, and how it was measured."""
import math

from bench import traffic
from bench.config import MEMBRANE_IMPLICIT_GROUP, MEMBRANE_MODEL
from bench.report.derive import ALL_KERNELS, CONFIGS, STARTUP_RUNS, STEP_KERNELS, TARGET_SIDE, find
from bench.report.ratios import ratio_text
from engine.constants import CFL_SAFETY


def _fmt(x, spec=".3g", none="-"):
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return none
    return format(x, spec)


def _table(header, rows) -> list:
    out = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    out += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return out + [""]


def _sides(rows, **kw):
    return sorted({r["side"] for r in rows if r.get("side") and all(r.get(k) == v for k, v in kw.items())})


def _pin_row(pin) -> list:
    """The machine table's row on Taichi's CPU pool threads (bench.machine: ELASTIC_PIN), if recorded."""
    if not pin:
        return []
    said = ("bound one per CPU when as many as the usable CPUs (ELASTIC_PIN=auto)" if pin == "auto"
            else f"unbound (ELASTIC_PIN={pin})")
    return [("Taichi's CPU pool threads", said)]


def _waits_row(w) -> list:
    """The machine table's row on how long the libraries' threads wait awake (bench.machine.thread_waits)."""
    return [("thread waits after work", f"MKL (PARDISO) KMP_BLOCKTIME={w.get('KMP_BLOCKTIME')} ms, OpenBLAS "
                                        f"OPENBLAS_THREAD_TIMEOUT={w.get('OPENBLAS_THREAD_TIMEOUT')}")] if w else []


def markdown(doc: dict, image_prefix: str) -> str:
    rows = doc["rows"]
    m = doc.get("machine", {})
    L = [f"# Benchmark report {doc.get('timestamp', '')}", ""]
    L += [f"Profile **{doc.get('profile', '?')}** (`{doc.get('command', 'python -m bench')}`), "
          f"wall time {_fmt(doc.get('wall_s'), '.0f')} s. Timings are medians of the rounds shown; "
          f"every engine call ends with `ti.sync()` and runs after warm-up (compilation) outside the clock.", ""]
    # the load at the start says what else ran; at the end it counts the benchmark's own two threads
    start_load = (m.get("load_average") or [None])[0]
    cores = m.get("affinity") or m.get("cores") or 0
    if start_load is not None and cores and start_load > 0.75 * cores:
        L += [f"**The machine was busy when this run started** (1-minute load average {start_load:.1f} on {cores} "
              f"cores): absolute times are inflated and 2-thread kernels suffer most; ratios measured within one "
              f"process (engine vs baseline, kernel vs copy floor) hold better. Re-measure on a quiet machine.", ""]
    if doc.get("errors"):
        L += ["**Parts that failed:** " + "; ".join(doc["errors"]), ""]
    if doc.get("missing"):
        L += ["Missing inputs: " + ", ".join(doc["missing"]), ""]

    # machine
    L += ["## Machine", ""]
    L += _table(["", ""], [
        ("CPU", m.get("cpu", "?")), ("cores (usable)", f"{m.get('cores')} ({m.get('affinity')})"),
        ("last-level cache", f"{(m.get('last_level_cache_bytes') or 0) / 2 ** 20:.0f} MiB"),
        ("memory", f"{(m.get('memory_bytes') or 0) / 2 ** 30:.0f} GiB"), ("system", m.get("system", "?")),
        ("load average at start / end", f"{m.get('load_average')} / {doc.get('load_average_end')}"),
        ("Python", m.get("python")), ("versions", ", ".join(f"{k} {v}" for k, v in m.get("versions", {}).items())),
        ("commit", m.get("commit") or "?")] + _pin_row(m.get("elastic_pin")) + _waits_row(m.get("thread_waits")))

    # targets
    L += ["## Targets (measured and reported, never asserted)", ""]
    trows = []
    for t in doc.get("targets", []):
        status = "not measured" if t.get("met") is None else ("met" if t["met"] else f"**missed** ({t.get('by')})")
        trows.append((t["name"], t["target"], t.get("measured", ""), status))
    L += _table(["target", "goal", "measured", "status"], trows)
    for t in doc.get("targets", []):
        if t.get("why") and t.get("met") is not True:
            L += [f"Why ({t['name']}):", ""] + [f"- {w}" for w in t["why"]] + [""]
        elif t.get("why"):
            L += [f"Details ({t['name']}):", ""] + [f"- {w}" for w in t["why"]] + [""]

    L += _peers_md(doc)
    L += _headline_md(doc.get("headline"), image_prefix)
    L += _explicit_md(rows)
    L += _kernels_md(rows)
    L += _implicit_md(rows)
    L += _rod_md(rows)
    L += ["## Cost against N", "", "Left: wall-clock seconds per simulated second from the headline sweep, explicit "
          "(solid) and backward Euler at 1/60 s (dashed), one colour per E. Right: one step of each kind, ns per "
          "vertex (t2-f64).", "", f"![cost against N]({image_prefix}cost_vs_N.png)", ""]
    L += _scaling_md(doc.get("scaling", []))
    L += _configs_md(rows)
    L += _startup_md(doc.get("startup", {}))
    L += _bandwidth_md(doc)
    L += _left_out_md(doc)
    L += _method_md(doc)
    return "\n".join(L) + "\n"


def _headline_md(h, image_prefix) -> list:
    L = ["## Headline: wall-clock seconds per simulated second", ""]
    if not h:
        return L + ["Not measured in this run.", ""]
    dts = h["dts"]
    check_steps = h["sides"][next(iter(h["sides"]))]["points"][0]["explicit"]["stable_check_steps"]
    L += [f"The lessons' hanging cloth (rho = 0.1 kg/m^2, B = 1e-4 N m, pinned at two corners), E swept from soft "
          f"to cloth-stiff. Explicit = symplectic Euler at s x the power-iteration stability limit at rest "
          f"(s = {CFL_SAFETY:g}, lowered by 0.1 where a {check_steps}-step check run blew up). "
          f"Implicit = backward Euler (one Newton iteration; PCG rtol 1e-5 or the fastest direct solver installed, "
          f"PARDISO or else Eigen's LL^T, the cheaper one) at "
          f"dt = 1/60 s and at the accuracy-matched dt = {dts['accuracy'] * 1e3:.2f} ms: the largest dt at which "
          f"backward Euler removes at most {h['accuracy_loss']:.0%} of the energy of the cloth's slowest mode "
          f"(the sheet swinging about its pin line, w1 = sqrt(3g/2L) = {h['pendulum_omega']:.2f} rad/s) per simulated "
          f"second, (1 + w1^2 dt^2)^(-1/dt) >= {1 - h['accuracy_loss']:.2f}. Costs are measured by timing a few steps "
          f"and dividing by dt (the explicit step once per resolution, in launches of 50 steps as a run between two "
          f"displayed frames takes them: its kernels do not depend on E).", ""]
    L += [f"![cost per simulated second against E]({image_prefix}cost_vs_E.png)", ""]
    cross = []
    for side, s in h["sides"].items():
        for name in dts:
            c = s["crossover"][name]
            where = f"E ~ {c['E']:.3g} N/m ({c['note']})" if c.get("E") else c.get("note", "")
            cross.append((f"{side}^2", name, where))
    L += ["Crossover (explicit = implicit cost):", ""]
    L += _table(["cloth", "implicit dt", "crossover"], cross)
    for side, s in h["sides"].items():
        L += [f"{side}^2 cloth ({s['n']} vertices; explicit step {s['explicit_step_s'] * 1e3:.3f} ms):", ""]
        tr = []
        for p in s["points"]:
            ex = p["explicit"]
            cells = [f"{p['E']:g}", f"{ex['dt']:.3g} (s={ex['safety']:g}{'' if ex['stable'] else ', UNSTABLE'})",
                     _fmt(ex["cost"])]
            for name in dts:
                r = p["implicit"][name]
                det = []
                for sv in ("pcg", "pardiso", "cholesky"):
                    v = r.get(sv, {})
                    if "cost" in v:
                        det.append(f"{sv} {_fmt(v['cost'])}" + (f" ({v['iterations']} it)" if sv == "pcg" else ""))
                    elif "skipped" in v:
                        det.append(f"{sv} skipped")
                    elif "error" in v:
                        det.append(f"{sv} failed")
                cells.append(f"**{_fmt(r.get('best_cost'))}** " + "; ".join(det))
            best_imp = min([p["implicit"][n]["best_cost"] for n in dts if p["implicit"][n].get("best_cost")]
                           or [math.inf])
            cells.append("explicit" if ex["cost"] < best_imp else "implicit")
            tr.append(cells)
        L += _table(["E (N/m)", "explicit dt (s)", "explicit s/s"] + [f"implicit dt={k} s/s" for k in dts]
                    + ["cheaper"], tr)
    return L


def _per_config(sizes_of, rows_of, header) -> list:
    """A ``### <config>`` table for each configuration that measured the group: ``sizes_of(cfg)``
    lists the sizes it measured (none: no table), ``rows_of(cfg, sizes)`` gives the table's rows."""
    L = []
    for cfg in CONFIGS:
        sizes = sizes_of(cfg)
        if sizes:
            L += [f"### {cfg}", ""] + _table(header, rows_of(cfg, sizes))
    return L


def _explicit_md(rows) -> list:
    L = ["## Cloth: explicit (symplectic Euler) step", "",
         "ns per vertex per step (median) of the engine, the Numba and Warp peers (bench/peers) and the numpy "
         "baseline (timed in the 2-thread f64 process); floor = the engine's fraction of the bandwidth floor "
         "(bench/traffic.py).", ""]

    def table_rows(cfg, sides):
        tr = []
        for side in sides:
            cells = [f"{side}^2", str(find(rows, config=cfg, group="cloth-explicit-step", side=side)["n"])]
            for model in ("springs+bending", "springs"):
                e = find(rows, config=cfg, group="cloth-explicit-step", impl="engine", model=model, side=side)
                b = find(rows, config="t2-f64", group="cloth-explicit-step", impl="numpy", model=model, side=side)
                nb = find(rows, config=cfg, group="cloth-explicit-step", impl="numba", model=model, side=side)
                wp = find(rows, config=cfg, group="cloth-explicit-step", impl="warp", model=model, side=side)
                cells += [_fmt(e and e["ns_per_vertex"], ".1f"), _fmt(nb and nb["ns_per_vertex"], ".1f"),
                          _fmt(wp and wp["ns_per_vertex"], ".1f"), _fmt(b and b["ns_per_vertex"], ".1f")]
                if model == "springs+bending":
                    cells.append(_fmt(e and e.get("bw_fraction"), ".2f"))
            tr.append(cells)
        return tr

    return L + _per_config(lambda cfg: _sides(rows, config=cfg, group="cloth-explicit-step"), table_rows,
                           ["cloth", "vertices", "engine s+b", "Numba s+b", "Warp s+b", "numpy s+b", "floor",
                            "engine springs", "Numba springs", "Warp springs", "numpy springs"])


def _kernels_md(rows) -> list:
    L = ["## Step kernels and force-kernel variants", "",
         "One call of each kernel of the explicit step (zero, spring_gather, hinge_pass1, hinge_gather, update) "
         "and of the force variants: springs and bending with parallel float atomics, with a serialized scatter, "
         "and the engine's deterministic gathers. " + "; ".join(f"`{k}`: {v}" for k, v in traffic.KERNELS.items())
         + ".", ""]
    sides = _sides(rows, config="t2-f64", group="cloth-force-kernels")
    if not sides:
        return L + ["Not measured.", ""]
    tr = []
    for k in ALL_KERNELS:
        cells = [k]
        for side in sides:
            r = find(rows, config="t2-f64", group="cloth-force-kernels", kernel=k, side=side)
            cells.append(_fmt(r and r["ns_per_vertex"], ".1f"))
        tr.append(cells)
    L += ["ns per vertex per call, t2-f64:", ""]
    L += _table(["kernel"] + [f"{s}^2" for s in sides], tr)
    side = TARGET_SIDE if TARGET_SIDE in sides else sides[-1]
    tr = []
    for k in ALL_KERNELS:
        r = find(rows, config="t2-f64", group="cloth-force-kernels", kernel=k, side=side)
        if not r:
            continue
        t1 = find(rows, config="t1-f64", group="cloth-force-kernels", kernel=k, side=side)
        f32 = find(rows, config="t2-f32", group="cloth-force-kernels", kernel=k, side=side)
        tr.append((k, _fmt(r["per_step_s"] * 1e6, ".1f"), _fmt(r["bytes"] / 1e6, ".2f"),
                   _fmt(r.get("floor_s") and r["floor_s"] * 1e6, ".1f"), r.get("floor_level", "-"),
                   _fmt(r.get("bw_fraction"), ".2f"), _fmt(t1 and t1["per_step_s"] * 1e6, ".1f"),
                   _fmt(f32 and f32["per_step_s"] * 1e6, ".1f")))
    L += [f"At {side}^2 (t2-f64 unless named):", ""]
    L += _table(["kernel", "us/call", "MB moved", "floor us", "floor level", "fraction of floor", "1 thread us",
                 "f32 us"], tr)
    return L


IMPLICIT_IMPLS = ("engine-pardiso", "engine-pardiso-double", "engine-cholesky", "engine-pcg", "peer-pardiso", "peer-pardiso-factor",
                  "peer-pardiso-factor-mixed", "peer-pardiso-spsolve", "peer-cholmod", "peer-pyamg-cg", "scipy")


def _peers_md(doc) -> list:
    ratios = doc.get("peer_ratios") or []
    L = ["## Against the peers", "",
         "Per row: the engine's fastest way and the fastest contender, all of the row's contenders timed "
         "interleaved in the same rounds in one process (bench/interleave.py: every round runs each once, in a "
         "rotating order) (explicit: Numba `prange` and Warp CPU kernels, bench/peers; implicit: scipy CG, pyamg, "
         "PARDISO, CHOLMOD driven from numpy with a scatter map built once, bench/peers/sparse.py), each checked to "
         "compute the same forces / solve the same system (bench/test_correctness.py, "
         "bench/test_peers_explicit.py). ratio = engine time / peer time in the same round (below 1: the engine "
         "is faster), the median over the rounds, with the spread of the per-round ratios (smallest-largest); a "
         "row whose spread contains 1 is marked not resolved. "
         "The *library* rows set the engine's whole step against PARDISO's numeric factorisation + solve of the "
         "same matrix alone (analysis once, no assembly, no check): in f64 (pardiso-factor, the row the targets "
         "are read against) and with the engine's own technique, an f32 factorisation refined in f64 to the same "
         "tolerance (pardiso-factor-mixed): what the engine adds around the library. "
         "floor = the engine row's bandwidth floor time (bench/traffic.py), where a traffic model exists.", ""]
    if not ratios:
        return L + ["Not measured.", ""]
    tr = []
    for p in ratios:
        tr.append((p["kind"], p["config"], f"{p['side']}^2", p["what"], _short(p["engine"]),
                   _fmt(p["engine_s"] * 1e3, ".3g"), _short(p["peer"]) if p["peer"] else "-",
                   _fmt(p["peer_s"] and p["peer_s"] * 1e3, ".3g"), ratio_text(p),
                   _fmt(p.get("floor_s") and p["floor_s"] * 1e3, ".3g")))
    return L + _table(["step", "config", "cloth", "model / tol", "engine", "engine ms", "fastest peer", "peer ms",
                       "ratio (spread, rounds)", "floor ms"], tr)


def _short(impl) -> str:
    return str(impl or "-").replace("peer-", "")


def _implicit_md(rows) -> list:
    L = ["## Cloth: backward-Euler step (dt = 1/60 s, E = 1e3 N/m)", "",
         "One Baraff-Witkin step (one Newton iteration, no line search) from the same moving, deformed state: "
         "assembly + set-up (factorisation, multigrid hierarchy, preconditioner) + solve, ms. Engine: PCG with 3x3 "
         "block-Jacobi, Eigen LL^T, MKL PARDISO; peers: numpy assembly into a precomputed pattern, then scipy CG "
         "(Jacobi), pyamg smoothed aggregation + CG, PARDISO (analysis once; spsolve: every call), CHOLMOD "
         "(cholespy: analysis every step, it cannot refactorise); pardiso-factor: PARDISO's factorisation + solve "
         "of the same matrix alone (no assembly, no check); pardiso-factor-mixed: the same in f32, refined in f64 "
         "to the tolerance (the engine's PARDISO technique, alone). Iterative solvers to the relative residual "
         "shown; the f64 direct ones reach ~1e-13, the engine's PARDISO (f32 factorisation, f64 refinement) "
         "stops at the tolerance (one row). The direct contenders of a size are one interleaved row, the "
         "iterative ones of a size and tolerance another; left out of a row: said below the table.", ""]

    def table_rows(cfg, sides, group="cloth-implicit-step"):
        tr = []
        for side in sides:
            for impl in IMPLICIT_IMPLS:
                for r in [r for r in rows if r.get("config") == cfg and r.get("group") == group
                          and r.get("side") == side and r.get("impl") == impl and r.get("per_step_s")]:
                    setup = r.get("factorization_s", r.get("setup_s"))
                    split = (f"{r['assembly_s'] * 1e3:.0f} / {setup * 1e3:.0f} / {r['solve_s'] * 1e3:.0f}"
                             if r.get("assembly_s") is not None and setup is not None else "-")
                    tr.append((f"{side}^2", _short(impl), _fmt(r.get("tol"), ".0e"), _fmt(r["per_step_s"] * 1e3, ".1f"),
                               split, r.get("linear_iterations", "-"), _fmt(r.get("bw_fraction"), ".2f")))
        return tr

    head = ["cloth", "solver", "tol", "ms/step", "assembly / set-up / solve ms", "iterations", "fraction of floor"]
    L += _per_config(lambda cfg: _sides(rows, config=cfg, group="cloth-implicit-step"), table_rows, head)
    msides = _sides(rows, config="t2-f64", group=MEMBRANE_IMPLICIT_GROUP)
    if msides:
        L += [f"The same step of the same mesh with Baraff-Witkin's stretch and shear conditions instead of springs "
              f"and hinges ({MEMBRANE_MODEL}: k_stretch = E, k_shear = E/2; the peers assemble its PSD triangle "
              f"blocks in numpy, bench/baseline.NumpyMembrane), t2-f64:", ""]
        L += _table(head[:-1], [t[:-1] for t in table_rows("t2-f64", msides, MEMBRANE_IMPLICIT_GROUP)])
    seq = [r for r in rows if r.get("group") == "cloth-implicit-sequence" and r.get("per_step_s")]
    if seq:
        L += ["60 consecutive steps of the hanging cloth (tol 1e-5), ms per step:", ""]
        L += _table(["cloth", "solver", "ms/step"], [(f"{r['side']}^2", _short(r["impl"]),
                                                     _fmt(r["per_step_s"] * 1e3, ".1f"))
                                                    for r in sorted(seq, key=lambda r: (r["side"], r["per_step_s"]))])
    left = {}
    for r in rows:
        if r.get("group") in ("cloth-implicit-step", "cloth-implicit-sequence", MEMBRANE_IMPLICIT_GROUP) \
                and r.get("config") == "t2-f64":
            for impl, why in (r.get("left_out") or {}).items():
                left.setdefault((impl, why), set()).add(r.get("side"))
    if left:
        L += ["Left out of the implicit rows (t2-f64): " + "; ".join(
            f"{_short(impl)} at {', '.join(f'{s}^2' for s in sorted(sides))}: {why}"
            for (impl, why), sides in sorted(left.items(), key=str)) + ".", ""]
    return L


def _rod_md(rows) -> list:
    L = ["## Rod (1D, engine.rod)", "",
         f"Symplectic Euler at {CFL_SAFETY:g} of the stable dt and backward Euler (Thomas algorithm) at dt = 10 h/c, "
         "many steps per kernel launch (Rod.run); the same rod as a spring-chain Model through the general backward "
         "Euler (PCG, Cholesky; one step per call); numpy and scipy `solve_banded` baselines.", ""]

    def table_rows(cfg, ns):
        tr = []
        for n in ns:
            for impl, base in (("engine-rod", "numpy"), ("engine-rod-thomas", "scipy-banded"),
                               ("engine-model-pcg", "scipy-banded"), ("engine-model-cholesky", "scipy-banded")):
                e = find(rows, config=cfg, group="rod-step", impl=impl, n=n)
                b = find(rows, config="t2-f64", group="rod-step", impl=base, n=n)
                if not e:
                    continue
                tr.append((n, impl, e.get("method", ""), _fmt(e["per_step_s"] * 1e6, ".1f"),
                           _fmt(e["ns_per_vertex"], ".1f"), e.get("linear_iterations", "-"),
                           f"{base} {_fmt(b and b['per_step_s'] * 1e6, '.1f')}" if b else "-",
                           _fmt(b and b["per_step_s"] / e["per_step_s"], ".2f") + ("x" if b else ""),
                           _fmt(e.get("bw_fraction"), ".2f")))
        return tr

    return L + _per_config(lambda cfg: sorted({r["n"] for r in rows
                                               if r.get("config") == cfg and r.get("group") == "rod-step"}),
                           table_rows, ["nodes", "engine", "method", "us/step", "ns/node", "CG iterations",
                                        "baseline us/step", "speed-up (baseline/ours)", "fraction of floor"])


def _scaling_md(scaling) -> list:
    L = ["## Scaling with N", "", "Least-squares exponent p of time per step ~ N^p over the sizes measured "
         "(1 = linear; below 1 where fixed launch costs dominate the small sizes).", ""]
    tr = [(s["config"], s["group"], s["impl"], s["what"] or "", s["solver"] or "", ",".join(map(str, s["n"])),
           f"{s['exponent']:.2f}") for s in scaling if s["group"] != "cloth-force-kernels" or s["what"] in STEP_KERNELS]
    return L + _table(["config", "group", "impl", "what", "solver", "N", "exponent"], tr)


def _configs_md(rows) -> list:
    L = ["## Threads and precision", "",
         "Time ratios at the largest size measured in both processes (each thread count and precision in its own "
         "process): t2/t1 < 1 means the second thread helps; f32/f64 < 1 means f32 is faster. The numpy rows are a "
         "control: numpy runs the same f64 single-threaded code in every process, so its ratio (ideally 1) shows "
         "how much the machine's load changed between the processes. On a loaded 2-core machine 2-thread kernels "
         "suffer most: a parallel loop waits for its slower thread, and with other work on the machine one of the "
         "two is often descheduled.", ""]
    tr = []
    def keyf(r):
        return r.get("group"), r.get("impl"), r.get("model") or r.get("kernel") or r.get("method"), r.get("solver")
    base = {}
    for r in rows:
        if r.get("config") == "t2-f64" and r.get("per_step_s") and r.get("group") != "bandwidth":
            base.setdefault(keyf(r), {})[r.get("n")] = r
    for other, label in (("t1-f64", "t2/t1"), ("t2-f32", "f32/f64")):
        for r in rows:
            if r.get("config") != other or not r.get("per_step_s") or r.get("group") == "bandwidth":
                continue
            b = base.get(keyf(r), {}).get(r.get("n"))
            if b is None:
                continue
            ratio = b["per_step_s"] / r["per_step_s"] if other == "t1-f64" else r["per_step_s"] / b["per_step_s"]
            tr.append((label, r["group"], r.get("impl"), keyf(r)[2] or "", r.get("n"), _fmt(ratio, ".2f")))
    # keep the largest n per series
    best = {}
    for t in tr:
        k = t[:4]
        if k not in best or t[4] > best[k][4]:
            best[k] = t
    return L + _table(["ratio", "group", "impl", "what", "N", "value"], sorted(best.values(), key=str))


def _startup_md(st) -> list:
    L = ["## Start-up", "", "A fresh process each, all with the same kernel-cache directory: import, `ti.init`, "
         "building a 32^2 cloth, and the first call of each stepping path against its second call (the difference "
         "is compilation, or loading from Taichi's offline cache). `cold`: empty cache, ending with a plain exit as "
         "the engine's programs do; `after-plain-exit`: the next process, which finds whatever that exit wrote, and "
         "ends with `ti.reset()`; `warm`: the process after that.", ""]
    if not st or not any(st.values()):
        return L + ["Not measured.", ""]
    runs = [k for k in STARTUP_RUNS if st.get(k)]
    tr = []
    for k in ["import_s", "init_s", "scene_s", "first_calls_s", "compile_total_s", "process_s", "subprocess_wall_s",
              "cache_files_after_exit"]:
        tr.append([k] + [_fmt(st[c].get(k), ".2f" if k != "cache_files_after_exit" else "d") for c in runs])
    for p in st[runs[0]].get("paths", {}):
        tr.append([f"first call {p} (compile part)"] + [
            _fmt(st[c]["paths"][p]["first_s"], ".2f") + " (" + _fmt(st[c]["paths"][p]["compile_s"], ".2f") + ")"
            for c in runs])
    L += _table(["seconds"] + runs, tr)
    cold, mid = st.get("cold"), st.get("after-plain-exit")
    if cold and cold.get("cache_files_after_exit") == 0:
        L += ["The cold process wrote no kernel cache on its plain exit (0 files): Taichi 1.7.4 writes its offline "
              "cache when its program is torn down (`ti.reset()`), and an engine process that just exits does not "
              "get there, so the next one compiles every kernel again. Calling `ti.reset()` at exit (e.g. "
              "`atexit.register(ti.reset)` in engine/runtime.py after `ti.init`) writes it: compare the first calls "
              "of the second and third runs.", ""]
    elif cold and mid:
        L += [f"Kernel cache files after the cold run: {cold.get('cache_files_after_exit')}.", ""]
    return L


def _bandwidth_md(doc) -> list:
    L = ["## Bandwidth floor", "",
         "Streaming copy of one f64 array into another, bytes = 2 x 8 x elements (read + write), in each process: "
         "`dram` 256 MiB per array (beyond the last-level cache), `cache` 4 MiB per array (cache-resident). The floor "
         "bandwidth at each level is the fastest copy (Taichi or numpy) measured in any of this run's processes: "
         "the hardware is the same, and other work on a shared machine can only make a copy slower.", ""]
    tr = []
    for cfg, levels in doc.get("bandwidth", {}).items():
        for lv, v in levels.items():
            tr.append((cfg, lv, _fmt(v.get("taichi", 0) / 1e9, ".1f"), _fmt(v.get("numpy", 0) / 1e9, ".1f"),
                       _fmt(v["floor"] / 1e9, ".1f")))
    L += _table(["config", "level", "Taichi GB/s", "numpy GB/s", "floor used GB/s"], tr)
    L += ["Traffic model (bench/traffic.py): " + " ".join(traffic.__doc__.split("\n\n")[1].split()), "",
          "Each kernel's floor uses the cache-resident bandwidth when its working set is at most half the "
          "last-level cache, the DRAM bandwidth otherwise; every cloth up to 256^2 fits in the cache here.", ""]
    return L


def _left_out_md(doc) -> list:
    L = ["## Left out, skipped, caveats", ""]
    items = []
    ran = set(doc.get("parts", {}))
    for p in ("t2-f64", "t1-f64", "t2-f32", "startup-cold", "headline"):
        if doc.get("parts") is not None and p not in ran:
            items.append(f"part `{p}` was not run in this invocation")
    for cfg, part in doc.get("parts", {}).items():
        for reason in part.get("skipped", []) or []:
            if "got empty parameter set" in reason:
                reason = reason.split(":")[0] + ": no sizes for this configuration in this profile"
            items.append(f"{cfg}: skipped: {reason}")
    for r in doc.get("rows", []):
        if r.get("tol_failed"):
            items.append(f"{r['config']} {r['group']} {r.get('impl')} n={r.get('n')}: relative tolerance(s) "
                         f"{r['tol_failed']} not reachable in f32, measured at {r.get('tol')}")
    h = doc.get("headline") or {}
    for side, sd in h.get("sides", {}).items():
        for p in sd["points"]:
            if not p["explicit"].get("stable", True):
                items.append(f"headline {side}^2 E={p['E']:g}: explicit run unstable even at "
                             f"s={p['explicit']['safety']}")
            for name, r in p["implicit"].items():
                for sv in ("pcg", "pardiso", "cholesky"):
                    v = r.get(sv, {})
                    if "skipped" in v:
                        items.append(f"headline {side}^2 E={p['E']:g} dt={name}: {sv} not run ({v['skipped']})")
                    if "error" in v:
                        items.append(f"headline {side}^2 E={p['E']:g} dt={name}: {sv} failed: {v['error']}")
    items += [
        "the explicit peers (Numba, Warp, numpy) run in every process, in its precision and beside the engine; "
        "the sparse peers run in the 2-thread f64 process only, so the 1-thread and f32 implicit rows have no ratio",
        "each contender's turn in a round starts after an untimed 10 ms pause (thread pools of the contender before "
        "it stop spinning) and, for a fast step timed in batches, one untimed call (its own threads awake, as in a "
        "loop); the ratio of a round compares the engine and the peer of that round only",
        "the scipy baseline preconditions with scalar Jacobi, the engine's PCG with 3x3 block Jacobi: iteration "
        "counts differ; both stop at the same relative residual",
        "the rod's PCG/Cholesky rows step the rod as a 3D spring-chain Model; engine.rod's own backward Euler is "
        "the Thomas algorithm in one kernel",
        "the headline's costs per simulated second are a few timed steps scaled by 1/dt, not full simulated seconds",
        "no GPU run: the suite measures the 2-core CPU it targets",
    ]
    return L + [f"- {x}" for x in items] + [""]


def _method_md(doc) -> list:
    return ["## How this was measured", "",
            "- `python -m bench` runs `pytest bench --benchmark-only` (pytest-benchmark) once per configuration in "
            "its own process (ELASTIC_THREADS=2 and 1 with f64, ELASTIC_THREADS=2 with ELASTIC_FP=32), then the "
            "start-up probe (cold and warm kernel cache) and the headline sweep, and merges everything here.",
            "- Each benchmark warms up outside the clock (until two successive calls agree, i.e. compilation is "
            "over), then runs as many rounds as fit its time budget; fast bodies repeat within a round. Medians.",
            "- Engine and baseline step from the same state (bench/config.py `cloth_start_state`); "
            "bench/test_correctness.py checks that each benchmark computes what it claims (forces, explicit steps, "
            "backward-Euler steps and rod steps agree with the baselines; the variants agree with the engine).",
            "- The machine was shared while this ran if the load average above exceeds the core count: "
            "compare ratios measured in one process rather than absolute times across runs.",
            "- Compare two runs with pytest-benchmark: `python -m bench --compare` (or "
            "`pytest-benchmark compare bench/results/raw/<a>/bench-t2-f64.json "
            "bench/results/raw/<b>/bench-t2-f64.json`).",
            ""]

