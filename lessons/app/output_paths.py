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


def write_all_or_none(folder, contents: list, what: str) -> None:
    """Write ``contents`` ((path, bytes) pairs, all in ``folder``) every one or none: each file is first
    created as an empty temporary file beside its target (missing folders too), then written, then
    moved onto its name. A folder that cannot receive them is bad input (UsageError: "DIR ...: cannot
    write <what> there"); a write that fails leaves no new file and keeps every earlier one
    (cli.OutputFailed: "DIR ...: could not write <what>")."""
    from pathlib import Path

    from .outfile import OutputFile, OutputWriteError
    shown = shown_path(str(folder))
    new = [not Path(path).exists() for path, _ in contents]
    files = []
    try:
        for path, _ in contents:
            file = OutputFile(path)
            file.prepare()
            files.append(file)
    except OSError as exc:
        for file in reversed(files):
            file.discard(remove_dirs=True)
        raise UsageError(f"DIR {shown}: cannot write {what} there ({exc.strerror or exc}); give a folder you can "
                         f"write to") from None
    try:
        for file, (_, data) in zip(files, contents):
            file.write_bytes(data)
        for file in files:
            file.commit()
    except OutputWriteError as exc:
        for file, fresh in zip(reversed(files), reversed(new)):
            if file.written is not None and fresh:   # a new file goes; one that was replaced stays replaced
                file.written.unlink(missing_ok=True)
            file.discard(remove_dirs=True)
        from .cli import OutputFailed
        left = "nothing is left there" if all(new) else "no new file is left there"
        raise OutputFailed(f"DIR {shown}: could not write {what} ({exc.strerror or exc}); {left}") from None

