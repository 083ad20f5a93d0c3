"""Where a part run by ``python -m bench`` puts its result (the file named by ``--json``, or stdout),
and what ``python -m bench`` and ``python -m bench.report`` say about bad arguments: one line on
stderr, exit status 2, before anything is written."""
import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

EXIT_USAGE = 2


def emit_json(obj, path=None) -> int:
    """Write ``obj`` as indented JSON to ``path``, or print it to stdout when there is none.
    Returns 0, the exit status of a part that got this far."""
    text = json.dumps(obj, indent=1)
    if path:
        with open(path, "w") as fh:
            fh.write(text)
    else:
        print(text)
    return 0


def usage_error(prog: str, message: str) -> int:
    """Say ``message`` as ``PROG: error: MESSAGE``, one line on stderr; returns the exit status 2."""
    print(f"{prog}: error: {' '.join(str(message).split())}", file=sys.stderr)
    return EXIT_USAGE


class Parser(argparse.ArgumentParser):
    """argparse with its errors in one line (no usage block), exit status 2."""

    def error(self, message):
        raise SystemExit(usage_error(self.prog, f"{message} (see '{self.prog} --help')"))


def out_dir_problem(path) -> str | None:
    """Why the directory ``path`` cannot receive output files (None: it can): nothing but
    directories may stand in the way of it, and its nearest existing directory must let a file be
    created (tried, and removed at once: a read-only mount, /proc). Nothing is left behind."""
    path = Path(os.path.abspath(path))
    base = path
    while not base.exists():
        if base == base.parent:
            break
        base = base.parent
    if not base.is_dir():
        return f"{base} is a file, not a directory" if base.is_file() else f"{base} is not a directory"
    try:
        with tempfile.TemporaryFile(dir=base):
            pass
    except OSError as exc:
        return f"cannot create a file in {base} ({exc.strerror or exc})"
    return None
