"""The report's plots (matplotlib, Agg backend): cost per simulated second against E from the
headline sweep, and cost against N (headline sweep and the step benchmarks)."""
import numpy as np



def plot_cost_vs_E(h, path) -> bool:
    if not h or not h.get("sides"):
        return False
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(7.5, 5))
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for k, (side, s) in enumerate(h["sides"].items()):
        col = colors[k % len(colors)]
        E = [p["E"] for p in s["points"]]
        ax.loglog(E, [p["explicit"]["cost"] for p in s["points"]], "-o", color=col, label=f"{side}^2 explicit")
        for name, style in (("1/60", "--s"), ("accuracy", ":^")):
            ys = [p["implicit"][name].get("best_cost") or np.nan for p in s["points"]]
            lab = "BE dt=1/60" if name == "1/60" else f"BE dt={h['dts']['accuracy'] * 1e3:.1f} ms (accuracy)"
            ax.loglog(E, ys, style, color=col, label=f"{side}^2 {lab}")
    ax.axhline(1.0, color="grey", lw=0.8)
    ax.text(ax.get_xlim()[0], 1.0, " real time", va="bottom", fontsize=8, color="grey")
    ax.set_xlabel("stretching modulus E (N/m)")
    ax.set_ylabel("wall-clock s per simulated s")
    ax.set_title("Hanging cloth: explicit vs backward Euler (2 threads, f64)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True


def plot_cost_vs_N(rows, h, path) -> bool:
    """Left: wall-clock s per simulated s against N from the headline sweep (explicit solid, backward
    Euler at 1/60 s dashed), one colour per E.  Right: ns per vertex per step against N of the step
    benchmarks (t2-f64)."""
    series = [("cloth-explicit-step", dict(impl="engine", model="springs+bending"), "engine explicit", "-o"),
              ("cloth-explicit-step", dict(impl="numba", model="springs+bending"), "Numba explicit", "--o"),
              ("cloth-explicit-step", dict(impl="warp", model="springs+bending"), "Warp explicit", ":o"),
              ("cloth-implicit-step", dict(impl="engine-pcg", tol=1e-5), "engine BE PCG 1e-5 (1/60 s)", "-s"),
              ("cloth-implicit-step", dict(impl="engine-pardiso"), "engine BE PARDISO (1/60 s)", "-^"),
              ("cloth-implicit-step", dict(impl="peer-pardiso"), "numpy + PARDISO BE (1/60 s)", "--^"),
              ("cloth-implicit-step", dict(impl="peer-pyamg-cg", tol=1e-5), "numpy + pyamg BE 1e-5 (1/60 s)",
               "--s")]
    have = [r for r in rows if r.get("config") == "t2-f64" and r.get("group") in ("cloth-explicit-step",
                                                                                    "cloth-implicit-step")]
    sides = (h or {}).get("sides", {})
    if not have and not sides:
        return False
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(12, 4.8))
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    if sides:
        Es = h.get("E") or [p["E"] for p in next(iter(sides.values()))["points"]]
        for k, E in enumerate(Es):
            col = colors[k % len(colors)]
            ns, ex, im = [], [], []
            for sd in sides.values():
                p = next((q for q in sd["points"] if q["E"] == E), None)
                if p is None:
                    continue
                ns.append(sd["n"])
                ex.append(p["explicit"]["cost"])
                im.append(p["implicit"]["1/60"].get("best_cost") or np.nan)
            a1.loglog(ns, ex, "-o", color=col, label=f"E={E:g} explicit")
            a1.loglog(ns, im, "--s", color=col, label=f"E={E:g} BE 1/60")
        a1.axhline(1.0, color="grey", lw=0.8)
        a1.set_ylabel("wall-clock s per simulated s")
        a1.set_title("headline sweep (E in N/m)", fontsize=9)
        a1.legend(fontsize=6, ncol=2)
    for group, kw, label, style in series:
        pts = sorted((r["n"], r["ns_per_vertex"]) for r in have
                     if r["group"] == group and all(r.get(k) == v for k, v in kw.items()))
        if pts:
            a2.loglog([p[0] for p in pts], [p[1] for p in pts], style, label=label)
    a2.set_ylabel("ns per vertex per step")
    a2.set_title("one step (E = 1e3 N/m)", fontsize=9)
    a2.legend(fontsize=7)
    for a in (a1, a2):
        a.set_xlabel("cloth vertices N")
        a.grid(True, which="both", alpha=0.3)
    fig.suptitle("Cloth cost against N (springs + bending, f64, 2 threads)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True

