"""Pictures of the recordings as the real Rerun viewer shows them, for the README.

    python -m lessons.tools.pictures --readme         # the README's pictures, docs/pictures/*.jpg
    python -m lessons.tools.pictures                  # recordings/*.rrd -> docs/pictures/
    python -m lessons.tools.pictures recordings/bending.rrd --tab 4 --out /tmp/pics
    python -m lessons.tools.pictures --also bending=4 --also springs=5

Each recording (lesson = the file's name without .rrd) is opened in the viewer headless
(lessons.tools.viewer.HeadlessViewer: Xvfb + the viewer from rerun-sdk on Vulkan/lavapipe) and gives

  <lesson>-open.png     the whole window as the viewer shows it at open (its opening tab)
  <lesson>-stage<N>.png the whole window with tab N shown (N: 1-based position of the tab in
                        the viewer's root Tabs container; the lessons have one tab per stage)

By default the stage pictures are of the opening tab only, plus the tabs named with --also for
that lesson; --tab N (repeatable, or "all") picks the tabs for every recording instead.
The recordings start playing when opened; for pictures that come out the same every time the
time cursor is first paused at --time (default: the end of the timeline the viewer opens on,
where every entity shows its last state), and each picture is taken once the window is steady
(two identical frames in a row). --time playing leaves playback running and catches a moment.
Exit codes: 0 written, 1 the viewer could not run (the message says what is missing), 2 bad input
(a recording that is missing or that rerun's reader cannot read: corrupted, truncated, not a recording).
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

from .screenshots import png_size
from .viewer import HeadlessViewer
from .viewer_processes import unreadable_recording
from .viewer_requirements import ViewerUnavailable


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--size must be WIDTHxHEIGHT, e.g. 1600x1000 (got {text!r})")
    if not (200 <= w <= 8192 and 200 <= h <= 8192):
        raise argparse.ArgumentTypeError(f"--size: each side must be 200 to 8192 (got {text!r})")
    return w, h


def _tab(text: str) -> int | str:
    if text == "all":
        return "all"
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n < 1:
        raise argparse.ArgumentTypeError(f"--tab must be a tab number (1, 2, ...) or 'all' (got {text!r})")
    return n


def _also(text: str) -> tuple[str, int]:
    lesson, _, n = text.partition("=")
    try:
        number = int(n)
    except ValueError:
        number = 0
    if not lesson or number < 1:
        raise argparse.ArgumentTypeError(f"--also must be LESSON=N, e.g. bending=4 (got {text!r})")
    return lesson, number


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m lessons.tools.pictures", description=__doc__.split("\n\n")[0],
                                epilog=__doc__.split("\n\n", 2)[2], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("recordings", nargs="*", metavar="RRD", help="recordings to photograph (default: recordings/*.rrd)")
    p.add_argument("--out", default="docs/pictures", metavar="DIR", help="where the PNGs go (default: docs/pictures)")
    p.add_argument("--size", type=_size, default=(1600, 1000), metavar="WxH",
                   help="viewer window size in pixels (default: 1600x1000)")
    p.add_argument("--tab", type=_tab, action="append", default=None, metavar="N",
                   help="photograph tab N (1-based) of every recording; repeatable; 'all' for every tab "
                        "(default: the opening tab plus the --also ones)")
    p.add_argument("--also", type=_also, action="append", default=[], metavar="LESSON=N",
                   help="also photograph tab N of LESSON's recording (LESSON: the file name without .rrd); "
                        "repeatable")
    p.add_argument("--time", default="end", metavar="WHEN",
                   help="where to pause the time cursor on the timeline the viewer opens on: end (default), "
                        "start, a number (seconds, or a sequence number on a sequence timeline), or 'playing' "
                        "(do not pause)")
    p.add_argument("--timeout", type=float, default=120.0, metavar="S",
                   help="seconds to wait for the viewer to load a recording (default: 120)")
    p.add_argument("--readme", action="store_true",
                   help="the README's pictures: for every recording its opening tab and the tab README_TABS "
                        "names, paused at progress 900 (of 1000: late in every run, the reflected pulses, the settled folds), as 1280x800 JPEGs docs/pictures/"
                        "<lesson>-stage<N>.jpg")
    return p


# The README shows each lesson's opening tab and one more that is characteristic of it.
README_TABS = {"rod-waves": 2, "springs": 2, "area-springs": 2, "bending": 4, "explicit-vs-implicit": 3,
               "membranes": 3}
README_TIME = 900.0
README_SIZE = (1280, 800)


def _readme_pictures(rrds: list[Path], out: Path, timeout: float, log=print) -> None:
    """Photograph into a scratch directory, then keep the stage pictures as small JPEGs."""
    import tempfile

    from PIL import Image
    with tempfile.TemporaryDirectory() as scratch:
        for rrd in rrds:
            also = [README_TABS[rrd.stem]] if rrd.stem in README_TABS else []
            for path in photograph(rrd, Path(scratch), (1600, 1000), None, also, timeout, README_TIME, log=log):
                if "-stage" not in path.stem:
                    continue
                target = out / f"{path.stem}.jpg"
                Image.open(path).convert("RGB").resize(README_SIZE, Image.LANCZOS).save(
                    target.with_suffix(".jpg.tmp"), "JPEG", quality=85, optimize=True)
                os.replace(target.with_suffix(".jpg.tmp"), target)
                log(f"{rrd.stem}: {target} ({target.stat().st_size // 1000} kB)")


def _write(path: Path, png: bytes) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_bytes(png)
    os.replace(tmp, path)


def _when(text: str) -> str | float:
    if text in ("end", "start", "playing"):
        return text
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--time must be end, start, playing or a number (got {text!r})")


def photograph(rrd: Path, out: Path, size: tuple[int, int], tabs: list[int | str] | None, also: list[int],
               timeout: float = 120.0, when: str | float = "end", log=print) -> list[Path]:
    """Write the pictures of one recording; returns their paths."""
    lesson = rrd.stem
    written = []
    t0 = time.monotonic()
    steady = when != "playing"
    with HeadlessViewer(rrd, size=size, timeout=timeout) as v:
        all_tabs = v.tabs()
        opening = v.active_tab_index()
        timeline = v.current_time()[0]
        log(f"{lesson}: opened in {v.open_seconds:.1f} s; {len(all_tabs)} tabs, opening tab "
            f"{'?' if opening is None else opening + 1}; {v.play_state().lower()} on {timeline}"
            + ("" if not steady else f", pausing at {when}"))
        if steady and timeline is not None:
            v.set_time(timeline, when)
        png = v.screenshot_window(settle=steady)
        path = out / f"{lesson}-open.png"
        _write(path, png)
        written.append(path)
        log(f"{lesson}: {path} ({'x'.join(map(str, png_size(png)))}, what the viewer shows at open)")
        if tabs is None:
            wanted = ([] if opening is None else [opening + 1]) + list(also)
        elif "all" in tabs:
            wanted = list(range(1, len(all_tabs) + 1))
        else:
            wanted = [t for t in tabs if t != "all"] + list(also)
        for n in dict.fromkeys(wanted):  # in order, once each
            if n > len(all_tabs):
                log(f"{lesson}: no tab {n} (it has {len(all_tabs)}); skipped")
                continue
            t = time.monotonic()
            tab = v.show_tab(n - 1, settle=False)
            png = v.screenshot_window(settle=steady)
            path = out / f"{lesson}-stage{n}.png"
            _write(path, png)
            written.append(path)
            log(f"{lesson}: {path} (tab {n}, {tab.name!r}, {time.monotonic() - t:.1f} s"
                + ("" if v.settled or not steady else ", did not settle") + ")")
    log(f"{lesson}: done in {time.monotonic() - t0:.1f} s")
    return written


def main(argv: list[str] | None = None) -> int:
    try:
        args = parser().parse_args(argv)
    except SystemExit as exc:
        return 0 if exc.code == 0 else 2
    rrds = [Path(r) for r in args.recordings] or sorted(Path("recordings").glob("*.rrd"))
    if not rrds:
        print("python -m lessons.tools.pictures: no recordings given and none in recordings/ "
              "(run 'python -m lessons run all' first)", file=sys.stderr)
        return 2
    absent = [str(r) for r in rrds if not r.is_file()]
    if absent:
        print(f"python -m lessons.tools.pictures: no such recording: {', '.join(absent)}", file=sys.stderr)
        return 2
    for rrd in rrds:  # the viewer would wait out --timeout on a file it cannot read: refused at once
        problem = unreadable_recording(rrd)
        if problem:
            print(f"python -m lessons.tools.pictures: {rrd} is not a readable Rerun recording ({problem}); record it "
                  f"again: python -m lessons run LESSON --record {rrd}", file=sys.stderr)
            return 2
    out = Path(args.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        print(f"python -m lessons.tools.pictures: --out {out}: cannot create it ({exc.strerror or exc})", file=sys.stderr)
        return 2
    try:
        when = _when(args.time)
    except argparse.ArgumentTypeError as exc:
        print(f"python -m lessons.tools.pictures: {exc}", file=sys.stderr)
        return 2
    if args.readme:
        try:
            _readme_pictures(rrds, out, args.timeout, log=lambda s: print(s, flush=True))
        except ViewerUnavailable as exc:
            print(f"python -m lessons.tools.pictures: {exc}", file=sys.stderr)
            return 1
        return 0
    for rrd in rrds:
        also = [n for lesson, n in args.also if lesson == rrd.stem]
        try:
            photograph(rrd, out, args.size, args.tab, also, args.timeout, when, log=lambda s: print(s, flush=True))
        except ViewerUnavailable as exc:
            print(f"python -m lessons.tools.pictures: {exc}", file=sys.stderr)
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
