"""Merge one ``python -m bench`` run into a JSON document, a Markdown report and PNG plots.

Inputs (a raw directory written by bench/__main__.py): ``bench-<config>.json`` (pytest-benchmark
JSON, one per process configuration), ``startup-{cold,after-plain-exit,warm}.json``,
``headline.json`` and ``run.json`` (timestamp, profile, machine, wall times, errors).  Any of them
may be missing: the report says what is missing instead of failing.

    derive.py    loading, the derived figures (per-step time, ns per vertex, bandwidth floor and
                 fraction of it, scaling exponents), the targets and why they are missed
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
                                 TARGET_SIDE, bandwidths, build, derive_floors, find, peer_ratios,
                                 rows_from_pytest_benchmark, scaling_exponents, targets)
from bench.report.markdown import markdown
from bench.report.plots import plot_cost_vs_E, plot_cost_vs_N

__all__ = ["ALL_KERNELS", "CONFIGS", "STARTUP_RUNS", "STEP_KERNELS", "TARGET_FLOOR_FACTOR",
           "TARGET_SIDE", "bandwidths", "build", "derive_floors", "find", "main", "peer_ratios",
           "markdown", "plot_cost_vs_E", "plot_cost_vs_N", "rows_from_pytest_benchmark", "scaling_exponents",
           "targets", "write"]


REPO = Path(__file__).resolve().parents[2]
REFERENCE_DIR = REPO / "bench" / "reference"  # the committed report (python -m bench.report RAW --reference)


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


def main(argv=None) -> int:
    """``python -m bench.report RAW_DIR [--out DIR]``: re-render the report of a run from its raw
    directory (bench/results/raw/<timestamp>)."""
    import argparse
    ap = argparse.ArgumentParser(prog="python -m bench.report", description=main.__doc__.split("\n")[0])
    ap.add_argument("raw", help="a raw directory written by python -m bench")
    ap.add_argument("--out", help="output directory (default: two levels above RAW_DIR, i.e. bench/results)")
    ap.add_argument("--no-latest", action="store_true", help="do not overwrite the latest.* copies")
    ap.add_argument("--reference", action="store_true",
                    help=f"write the report as the committed reference instead ({REFERENCE_DIR.relative_to(REPO)}/"
                         f"report.*, which the README shows); nothing else is written")
    args = ap.parse_args(argv)
    raw = Path(args.raw).resolve()
    doc = build(raw)
    if args.reference:
        paths = write(doc, REFERENCE_DIR, "report", latest=False)
    else:
        paths = write(doc, Path(args.out) if args.out else raw.parent.parent, raw.name, latest=not args.no_latest)
    print(paths["md"])
    return 0
