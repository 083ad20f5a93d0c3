"""The engine against its peers in one run: per comparison row, the engine's fastest time against
the fastest peer's, their ratio (round by round when both were timed in the same interleaved row,
bench/interleave.py), its text, and the agreement of a run's ratios with a reference run's.
"""
from bench.config import MEMBRANE_IMPLICIT_GROUP, MEMBRANE_MODEL
from bench.interleave import spread
from bench.report.derive import CONFIGS

EXPLICIT_PEERS = ("numba", "warp")
EXPLICIT_MODELS = ("springs+bending", "springs", MEMBRANE_MODEL)   # the models of the explicit rows
LIBRARY_ROWS = {"peer-pardiso-factor": "PARDISO factorisation + solve alone",
                "peer-pardiso-factor-mixed":
                    "PARDISO f32 factorisation + f64 refinement alone (the engine's technique)"}
STEP_GROUPS = ("cloth-implicit-step", MEMBRANE_IMPLICIT_GROUP)   # one backward-Euler step per call, per solver


def _is_engine(impl: str) -> bool:
    return impl == "engine" or impl.startswith("engine-")


def _refines_to_tol(r) -> bool:
    """A direct contender that stops at its tolerance instead of reaching ~1e-13: PARDISO in mixed
    precision (the engine's, and the library row of its technique)."""
    return r.get("precision") == "mixed" or r.get("impl") == "engine-pardiso"


def _implicit_rows(rows, cfg, side, tol, group="cloth-implicit-step"):
    """The rows of one implicit comparison: iterative solvers at ``tol``, f64 direct ones (timed once,
    at 1e-5: they reach ~1e-13) whatever ``tol``, mixed-precision ones (refined to the tolerance they
    were given) at theirs only."""
    out = []
    for r in rows:
        if r.get("config") != cfg or r.get("group") != group or r.get("side") != side or not r.get("per_step_s"):
            continue
        iterative = r.get("impl") in ("engine-pcg", "scipy", "peer-pyamg-cg")
        if group in STEP_GROUPS and (iterative or _refines_to_tol(r)) and not _close(r.get("tol"), tol):
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
        # the membrane's PCG against scipy's CG (the same tolerance, the same interleaved row)
        pcg = [r for r in rows if r.get("config") == cfg and r.get("group") == MEMBRANE_IMPLICIT_GROUP
               and r.get("impl") == "engine-pcg"]
        for side in sorted({r["side"] for r in pcg}):
            for tol in sorted({float(r["tol"]) for r in pcg if r.get("side") == side}, reverse=True):
                rs = [r for r in _implicit_rows(rows, cfg, side, tol, MEMBRANE_IMPLICIT_GROUP)
                      if r.get("impl") in ("engine-pcg", "scipy")]
                if len(rs) == 2:
                    out.append(_ratio_entry("iterative", cfg, side, f"{MEMBRANE_MODEL}, PCG against scipy CG, "
                                            f"tol {tol:.0e}", rs, ("scipy",)))
        # the engine's whole step against PARDISO's factorisation + solve of the same matrix alone: in f64
        # (the target) and with the engine's own technique (f32 factorisation refined in f64)
        for side in sorted({r["side"] for r in rows if r.get("config") == cfg and r.get("library_only")}):
            for peer, what in LIBRARY_ROWS.items():
                rs = [r for r in rows if r.get("config") == cfg and r.get("group") == "cloth-implicit-step"
                      and r.get("side") == side and r.get("impl") in ("engine-pardiso", peer) and r.get("per_step_s")]
                if any(r.get("impl") == peer for r in rs):
                    out.append(_ratio_entry("library", cfg, side, what, rs, (peer,)))
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
