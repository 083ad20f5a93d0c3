"""Merge one ``python -m bench`` run into a JSON document, a Markdown report and PNG plots.

Inputs (a raw directory written by bench/__main__.py): ``bench-<config>.json`` (pytest-benchmark
JSON, one per process configuration), ``startup-{cold,after-plain-exit,warm}.json``,
``headline.json`` and ``run.json`` (timestamp, profile, machine, wall times, errors).  Any of them
may be missing: the report says what is missing instead of failing.

    derive.py    loading, the derived figures (per-step time, ns per vertex, bandwidth floor and
                 fraction of it, scaling exponents)
    ratios.py    the engine against its peers (ratio per comparison, round by round when
                 interleaved) and the agreement with a reference run
    targets.py   the targets and why they are missed
    markdown.py  the Markdown text
    plots.py     the matplotlib plots
    (here)       ``build``, ``write`` and ``main`` (``python -m bench.report RAW_DIR``)

``report.markdown`` is the function that renders the text; its module is
``bench.report.markdown`` (import from it with ``from bench.report.markdown import ...``).
"""
import json
import shutil
from pathlib import Path

from bench.report.derive import (ALL_KERNELS, CONFIGS, STARTUP_RUNS, STEP_KERNELS, TARGET_FLOOR_FACTOR,
                                 TARGET_SIDE, bandwidths, derive_floors, find, rows_from_pytest_benchmark,
                                 scaling_exponents)
from bench.report.markdown import markdown
from bench.report.plots import plot_cost_vs_E, plot_cost_vs_N
from bench.report.ratios import agreement, peer_ratios
from bench.report.targets import targets

__all__ = ["ALL_KERNELS", "CONFIGS", "STARTUP_RUNS", "STEP_KERNELS", "TARGET_FLOOR_FACTOR",
           "TARGET_SIDE", "against_text", "agreement", "bandwidths", "build", "derive_floors", "find", "main", "peer_ratios",
           "markdown", "plot_cost_vs_E", "plot_cost_vs_N", "rows_from_pytest_benchmark", "scaling_exponents",
           "targets", "write"]


REPO = Path(__file__).resolve().parents[2]
REFERENCE_DIR = REPO / "bench" / "reference"  # the committed report (python -m bench.report RAW --reference)


def _load_json(path: Path):
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


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


def write(doc: dict, out_dir, stem: str, latest: bool = True) -> dict:
    """Write <stem>.json, <stem>.md, <stem>-cost_vs_E.png, <stem>-cost_vs_N.png into out_dir, and
    copies named latest.* (the Markdown copy links the latest-*.png).  Returns the paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {}
    p = out / f"{stem}.json"
    p.write_text(json.dumps(doc, indent=1, default=str))
    paths["json"] = p
    pe, pn = out / f"{stem}-cost_vs_E.png", out / f"{stem}-cost_vs_N.png"
    if plot_cost_vs_E(doc.get("headline"), pe):
        paths["cost_vs_E"] = pe
    if plot_cost_vs_N(doc.get("rows", []), doc.get("headline"), pn):
        paths["cost_vs_N"] = pn
    p = out / f"{stem}.md"
    p.write_text(markdown(doc, f"{stem}-"))
    paths["md"] = p
    if latest:
        for key, src in list(paths.items()):
            if key == "md":
                dst = out / "latest.md"
                dst.write_text(markdown(doc, "latest-"))
            else:
                dst = out / src.name.replace(stem, "latest", 1)
                shutil.copyfile(src, dst)
            paths["latest_" + key] = dst
    return paths


def against_text(doc: dict, ref: dict, ref_name: str) -> tuple:
    """(lines, number of rows outside the reference's spread): each comparison row of ``doc``
    beside the same row of the reference run ``ref``."""
    rows = agreement(doc, ref)
    if not rows:
        return [f"no comparison row in common with {ref_name}"], 0
    lines = [f"ratios of this run against {ref_name} (engine / fastest peer; inside = within the reference's "
             f"spread):"]
    outside = 0
    for a in rows:
        sp = a["ref_spread"]
        verdict = "no spread" if a["inside"] is None else ("inside" if a["inside"] else "OUTSIDE")
        outside += a["inside"] is False
        lines.append(f"  {a['kind']:<8} {a['config']} {a['side']:>3}^2 {a['what']:<40} {a['ratio']:.2f}  "
                     f"reference {a['ref_ratio']:.2f}" + (f" ({sp[0]:.2f}-{sp[1]:.2f})" if sp else "")
                     + f"  {verdict}")
    n_sp = sum(a["inside"] is not None for a in rows)
    lines.append(f"{n_sp - outside} of {n_sp} ratios within the reference's spread")
    return lines, outside


RAW_INPUTS = ("run.json", *(f"bench-{c}.json" for c in CONFIGS), *(f"startup-{k}.json" for k in STARTUP_RUNS),
              "headline.json")  # what a raw directory of python -m bench holds (any may be missing, not all)


def main(argv=None) -> int:
    """``python -m bench.report RAW_DIR [--out DIR]``: re-render the report of a run from its raw
    directory (bench/results/raw/<timestamp>). Bad arguments (a RAW_DIR that is not a raw
    directory, an --out that cannot be written, an --against that cannot be read): one line,
    exit status 2, nothing written."""
    from bench.output import Parser, out_dir_problem, usage_error
    prog = "python -m bench.report"
    ap = Parser(prog=prog, description=main.__doc__.split("\n")[0])
    ap.add_argument("raw", help="a raw directory written by python -m bench")
    ap.add_argument("--out", help="output directory (default: two levels above RAW_DIR, i.e. bench/results)")
    ap.add_argument("--no-latest", action="store_true", help="do not overwrite the latest.* copies")
    ap.add_argument("--against", metavar="JSON",
                    help="also compare this run's ratios with another run's document (e.g. "
                         "bench/reference/report.json); exit status 1 when a ratio lies outside that run's spread")
    ap.add_argument("--reference", action="store_true",
                    help=f"write the report as the committed reference instead ({REFERENCE_DIR.relative_to(REPO)}/"
                         f"report.*, which the README shows); nothing else is written")
    args = ap.parse_args(argv)
    raw = Path(args.raw).resolve()
    if not raw.is_dir():
        return usage_error(prog, f"RAW_DIR {args.raw}: {'not a directory' if raw.exists() else 'no such directory'}; "
                                 f"give a raw directory written by python -m bench (bench/results/raw/<timestamp>)")
    if not any((raw / name).is_file() for name in RAW_INPUTS):
        return usage_error(prog, f"RAW_DIR {args.raw} holds none of {', '.join(RAW_INPUTS)}: not a raw directory "
                                 f"of python -m bench (bench/results/raw/<timestamp>)")
    out = REFERENCE_DIR if args.reference else (Path(args.out) if args.out else raw.parent.parent)
    problem = out_dir_problem(out)
    if problem:
        return usage_error(prog, f"{'--out ' + args.out if args.out else 'the output directory ' + str(out)}: "
                                 f"{problem}; give a writable directory with --out")
    ref = None
    if args.against:
        try:
            ref = json.loads(Path(args.against).read_text())
            if not isinstance(ref, dict):
                raise ValueError("not a report document (a JSON object)")
        except (OSError, ValueError) as exc:
            return usage_error(prog, f"--against {args.against}: cannot read it ({getattr(exc, 'strerror', None) or exc}); "
                                     f"give a report's .json, e.g. bench/reference/report.json")
    doc = build(raw)
    if args.reference:
        paths = write(doc, out, "report", latest=False)
    else:
        paths = write(doc, out, raw.name, latest=not args.no_latest)
    print(paths["md"])
    if ref is not None:
        lines, outside = against_text(doc, ref, args.against)
        print("\n".join(lines))
        return 1 if outside else 0
    return 0
