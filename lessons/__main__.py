"""``python -m lessons``: the command line (lessons/app/cli.py), with signals handled from the first
instruction to the last.

A signal before the command line has installed its handlers (while Taichi is imported) ends the
process quietly with 128 + the signal (130 for Ctrl-C); during the run the command line handles
them (the output files are finished); after it has returned, a signal no longer interrupts the
shutdown (Taichi writing its kernel cache) but still decides the exit code: 130 for SIGINT,
every time.
"""
import atexit
import os
import signal
import sys

_SIGNALS = [getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name)]


def _before_main(signum, frame):
    raise SystemExit(128 + signum)


_code: list = []  # main()'s exit code


def _late_exit_code():
    """Runs last at exit (registered first, after Taichi has written its kernel cache): the exit
    code is main()'s, or 128 + a signal that came after main() returned; the process ends here,
    because the interpreter's own finalisation puts the default signal handlers back and a
    signal then would kill it (exit -2 instead of 130)."""
    if not _code:
        return
    cli = sys.modules.get("lessons.app.cli")
    signum = cli.late_signal() if cli is not None else None
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(128 + signum if signum is not None else _code[0])


for _sig in _SIGNALS:
    signal.signal(_sig, _before_main)
atexit.register(_late_exit_code)

from .app.cli import main  # noqa: E402

_code.append(main(restore_signals=False))
sys.exit(_code[0])
