"""The output paths of a run (``--record``, ``--results``): each checked (kinds, names, overlaps)
before anything runs, then created as empty temporary files beside their targets (all or none);
a bad one is bad input (UsageError)."""
from __future__ import annotations

import os

from .arguments import UsageError

def shown_path(text: str) -> str:
    """A path as the user typed it, printable (bytes that are not UTF-8 as \\xNN escapes)."""
    return text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")


def output_target(flag: str, text: str, overwrite_partial: bool, lesson_id: str | None = None):
    """The OutputFile for ``flag PATH`` (constructed and checked, nothing created yet)."""
    from lessons.app.outfile import OutputFile
    hint = "choose a writable path" + (" or --no-record" if flag == "--record" else "")
    try:
        target = OutputFile(text, overwrite_partial=overwrite_partial)
        target.check()
    except IsADirectoryError as exc:
        more = (f"; end it with / to record into it as {text.rstrip('/')}/{lesson_id}.rrd"
                if flag == "--record" and lesson_id and not text.endswith("/") else "")
        raise UsageError(f"{flag} {shown_path(text)}: cannot write there ({exc.strerror or exc}{more}); {hint}") from None
    except OSError as exc:
        raise UsageError(f"{flag} {shown_path(text)}: cannot write there ({exc.strerror or exc}); {hint}") from None
    return target


def output_targets(args, chosen) -> tuple:
    """(results OutputFile or None, {lesson id: recording OutputFile or None}), every path checked
    (kinds, names, overlaps) but nothing created."""
    ow = args.overwrite_partial
    for flag, value in (("--results", args.results), ("--record", args.record)):
        if value is not None and value.strip() in ("", "-"):
            raise UsageError(f"{flag} needs a file name (got {value!r}); standard output is not supported "
                             f"(the tables go there)" + ("; use --no-record for no recording" if flag == "--record"
                                                         else ""))
    results = output_target("--results", args.results, ow) if args.results is not None else None
    records = {}
    for l in chosen:
        if args.no_record:
            records[l.id] = None
            continue
        if args.record is None:
            text = os.path.join("recordings", f"{l.id}.rrd")
        elif len(chosen) > 1 or args.record.endswith(("/", os.sep)):
            text = os.path.join(args.record, f"{l.id}.rrd")
        else:
            text = args.record
        records[l.id] = output_target("--record", text, ow, l.id)
    # one file must not receive two outputs (--record X --results X would put the JSON over the recording)
    names = [("--results", results)] + [("--record", r) for r in records.values()]
    names = [(flag, t) for flag, t in names if t is not None]
    for i, (flag_a, a) in enumerate(names):
        for flag_b, b in names[i + 1:]:
            if {a.path, a.partial_path} & {b.path, b.partial_path}:
                raise UsageError(f"{flag_a} {shown_path(a.given)} and {flag_b} {shown_path(b.given)} name the same file "
                                 f"({a.path if a.path in (b.path, b.partial_path) else a.partial_path}); give them "
                                 f"different names")
    return results, records


def prepare_outputs(targets: list) -> None:
    """Create every output's directories and temporary file (all or none)."""
    done = []
    try:
        for flag, t in targets:
            try:
                t.prepare()
            except OSError as exc:
                hint = "choose a writable path" + (" or --no-record" if flag == "--record" else "")
                raise UsageError(f"{flag} {shown_path(t.given)}: cannot write there ({exc.strerror or exc}); "
                                 f"{hint}") from None
            done.append(t)
    except BaseException:
        for t in reversed(done):
            t.discard(remove_dirs=True)
        raise
