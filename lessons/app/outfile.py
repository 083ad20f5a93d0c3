"""Output files that are never lost, half-written or mislabelled.

An :class:`OutputFile` is one file a run produces (a recording, a results table). Its life:

1. ``OutputFile(path)`` and :meth:`~OutputFile.check` (no side effects): the name is a file
   name in UTF-8 that fits the file system, nothing but a directory stands in the way of its
   parent directories, and the target, if it exists, is a regular file: a device node, a FIFO,
   a socket or a directory is never replaced (``--results /dev/null`` run as root would
   otherwise turn the device into a regular file).
2. :meth:`~OutputFile.prepare`: creates the missing parent directories, removes the temporary
   files of earlier runs over the same path whose process is gone, and creates this run's
   temporary file ``.<name>.partial-<pid>`` beside the target: the up-front proof that the
   file can be created there (``/proc``, a read-only mount, a name the file system refuses).
3. :meth:`~OutputFile.write_bytes` fills the temporary file (``fsync``-ed); a write error
   (a full disk) removes it and raises :class:`OutputWriteError`: the earlier file under the
   final name is untouched.
4. :meth:`~OutputFile.commit` renames it onto the final name when the run is complete, and onto
   ``<stem>.partial<suffix>`` when it is not (unless ``overwrite_partial``): a partial run
   never replaces a complete earlier file. A complete run removes an older partial file of
   the same target. :meth:`~OutputFile.discard` removes the temporary file (and the directories
   :meth:`prepare` created, when asked).

A killed process leaves at most its (empty or partial) temporary file, never a truncated file
under the final name; the next run over the same path removes it.
"""
from __future__ import annotations

import errno
import hashlib
import os
import stat
from pathlib import Path

__all__ = ["OutputFile", "OutputPathError", "OutputWriteError", "partial_name", "TEMP_TAG"]

TEMP_TAG = ".partial-"   # temporary files: .<name>.partial-<pid>
PARTIAL_TAG = ".partial"  # output of a run that did not complete: <stem>.partial<suffix>


class OutputPathError(OSError):
    """The path cannot receive the output (bad input: found before the run starts)."""


class OutputWriteError(OSError):
    """Writing the output failed (e.g. the disk is full); the earlier file is kept."""


def partial_name(name: str) -> str:
    """``results.json`` -> ``results.partial.json``, ``run.rrd`` -> ``run.partial.rrd``."""
    p = Path(name)
    return f"{p.stem}{PARTIAL_TAG}{p.suffix}" if p.suffix else f"{name}{PARTIAL_TAG}"


def _kind(mode: int) -> str | None:
    """What a non-regular file is, in words (None for a regular file)."""
    for test, word in ((stat.S_ISDIR, "a directory"), (stat.S_ISCHR, "a character device"),
                       (stat.S_ISBLK, "a block device"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
                       (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return word
    return None if stat.S_ISREG(mode) else "not a regular file"


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process: alive
        return True
    except OSError:
        return True
    return True


class OutputFile:
    """One output file, written atomically (see the module docstring).

    ``path``: the final name (a symbolic link is followed: its target is what gets replaced).
    ``overwrite_partial``: a run that does not complete writes under the final name too (the
    file still says it is partial); by default it goes to :func:`partial_name`.
    """

    def __init__(self, path: str | os.PathLike, overwrite_partial: bool = False):
        text = os.fspath(path)
        if isinstance(text, bytes):
            text = os.fsdecode(text)
        self.given = text
        self.overwrite_partial = overwrite_partial
        if text in ("", "-"):
            raise OutputPathError(errno.EINVAL, "a file name is needed (standard output is not supported: "
                                                "the tables go there)")
        try:
            text.encode("utf-8")
        except UnicodeEncodeError:
            raise OutputPathError(errno.EINVAL, "the name is not valid UTF-8; use a UTF-8 file name") from None
        if "\x00" in text:
            raise OutputPathError(errno.EINVAL, "the name contains a NUL character")
        if text.endswith(("/", os.sep)):
            raise IsADirectoryError(errno.EISDIR, f"{text} names a directory, not a file")
        self.path = Path(os.path.abspath(text))
        try:
            self.path = self.path.resolve()  # follow symbolic links (strict=False: may not exist yet)
        except (OSError, RuntimeError):  # a symlink loop: reported by check()
            pass
        self.partial_path = self.path.with_name(partial_name(self.path.name))
        self.tmp: Path | None = None
        self._created: list[Path] = []  # directories prepare() made (innermost first)
        self.written: Path | None = None
        self.replaced = False  # whether commit() replaced a file that was there

    # --- up front ------------------------------------------------------------------
    def _existing_ancestor(self) -> tuple[Path, list[Path]]:
        """The nearest existing ancestor of the target and the directories missing below it."""
        missing = []
        p = self.path.parent
        while True:
            try:
                os.stat(p)
                break
            except (FileNotFoundError, NotADirectoryError):  # (a file further up: found below)
                missing.append(p)
                if p == p.parent:
                    break
                p = p.parent
        return p, missing

    def check(self) -> None:
        """Everything that can be known without writing (raises OSError with a one-line reason)."""
        base, missing = self._existing_ancestor()
        if not base.is_dir():
            shown = os.path.relpath(base) if not os.path.isabs(self.given) else str(base)
            raise NotADirectoryError(errno.ENOTDIR, f"{shown} is a file, not a directory")
        if not os.access(base, os.W_OK | os.X_OK):
            raise PermissionError(errno.EACCES, f"directory {base} is not writable")
        try:
            name_max = os.pathconf(base, "PC_NAME_MAX")
        except (OSError, ValueError):
            name_max = 255
        for d in missing:
            if len(os.fsencode(d.name)) > name_max:
                raise OSError(errno.ENAMETOOLONG, f"File name too long (directory {d.name[:40]}…)")
        size = len(os.fsencode(self.path.name))
        need = len(os.fsencode(self.partial_path.name)) if not self.overwrite_partial else size
        if size > name_max:
            raise OSError(errno.ENAMETOOLONG, os.strerror(errno.ENAMETOOLONG))
        if need > name_max:
            raise OSError(errno.ENAMETOOLONG,
                          f"File name too long ({size} bytes): a run that does not complete writes "
                          f"{self.partial_path.name[:20]}…{PARTIAL_TAG}{self.path.suffix}, which must fit in "
                          f"{name_max} bytes (use a shorter name, or --overwrite-partial)")
        for target in (self.path, self.partial_path):
            self._check_replaceable(target)

    @staticmethod
    def _check_replaceable(target: Path) -> None:
        try:
            st = os.stat(target)
        except FileNotFoundError:
            return
        except OSError as exc:
            if exc.errno == errno.ELOOP:
                raise OSError(errno.ELOOP, f"{target.name} is a loop of symbolic links") from None
            raise
        if stat.S_ISDIR(st.st_mode):
            raise IsADirectoryError(errno.EISDIR, f"{target.name} is a directory")
        kind = _kind(st.st_mode)
        if kind is not None:
            raise OutputPathError(errno.EEXIST, f"{target.name} is {kind}, not a regular file; only a regular "
                                                f"file (or a new name) is replaced")

    def _temp_name(self, pid: int | None = None) -> str:
        pid = os.getpid() if pid is None else pid
        name = f".{self.path.name}{TEMP_TAG}{pid}"
        if len(os.fsencode(name)) <= 255:
            return name
        digest = hashlib.sha256(os.fsencode(self.path.name)).hexdigest()[:24]
        return f".{digest}{TEMP_TAG}{pid}"

    def stale_temporaries(self) -> list[Path]:
        """Temporary files of earlier runs over this path whose process no longer exists."""
        out = []
        parent = self.path.parent
        prefixes = {self._temp_name(0)[:-1]}  # ".<name>.partial-" (or its hashed form)
        try:
            entries = list(os.scandir(parent))
        except OSError:
            return out
        for entry in entries:
            for prefix in prefixes:
                if entry.name.startswith(prefix) and entry.name[len(prefix):].isdigit():
                    pid = int(entry.name[len(prefix):])
                    if pid != os.getpid() and not _pid_alive(pid) and entry.is_file(follow_symlinks=False):
                        out.append(Path(entry.path))
        return out

    def prepare(self) -> None:
        """Check, create the missing directories, remove stale temporaries and create this run's
        temporary file (the proof that the file can be written there). On failure nothing is left."""
        self.check()
        _, missing = self._existing_ancestor()
        try:
            for d in reversed(missing):  # outermost first
                os.mkdir(d)
                self._created.insert(0, d)
            for stale in self.stale_temporaries():
                try:
                    stale.unlink()
                except OSError:
                    pass
            tmp = self.path.with_name(self._temp_name())
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | getattr(os, "O_NOFOLLOW", 0), 0o666)
            os.close(fd)
            self.tmp = tmp
        except OSError as exc:
            self.discard(remove_dirs=True)
            raise OutputPathError(exc.errno or errno.EIO, f"cannot create a file in {self.path.parent}: "
                                                          f"{exc.strerror or exc}") from None

    # --- at the end ----------------------------------------------------------------
    def write_bytes(self, data: bytes) -> None:
        """Fill the temporary file with ``data`` and flush it to disk. On an error (a full disk,
        a vanished directory) the temporary file is removed and OutputWriteError says why."""
        if self.tmp is None:
            raise RuntimeError("OutputFile.prepare() was not called")
        done = 0
        try:
            fd = os.open(self.tmp, os.O_WRONLY | os.O_TRUNC | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0), 0o666)
            try:
                view = memoryview(data)
                while done < len(data):
                    done += os.write(fd, view[done:])
                os.fsync(fd)
            finally:
                os.close(fd)
        except OSError as exc:
            self.discard()
            raise OutputWriteError(exc.errno or errno.EIO,
                                   f"{exc.strerror or exc} after {done:,} of {len(data):,} bytes") from None

    def destination(self, complete: bool) -> Path:
        return self.path if (complete or self.overwrite_partial) else self.partial_path

    def commit(self, complete: bool = True) -> Path:
        """Move the written temporary file onto its name (see :meth:`destination`); returns it."""
        if self.tmp is None:
            raise RuntimeError("nothing to commit")
        dest = self.destination(complete)
        try:
            self._check_replaceable(dest)  # something may have appeared there during the run
            replaced = os.path.lexists(dest)
            os.replace(self.tmp, dest)
        except OSError as exc:
            self.discard()
            raise OutputWriteError(exc.errno or errno.EIO, exc.strerror or str(exc)) from None
        self.tmp, self.replaced = None, replaced
        try:  # make the rename itself durable
            dfd = os.open(dest.parent, os.O_RDONLY)
            try:
                os.fsync(dfd)
            finally:
                os.close(dfd)
        except OSError:
            pass
        if complete and dest == self.path:  # an older partial output of this target is superseded
            try:
                if stat.S_ISREG(os.lstat(self.partial_path).st_mode):
                    os.unlink(self.partial_path)
            except OSError:
                pass
        self.written = dest
        return dest

    def discard(self, remove_dirs: bool = False) -> None:
        """Remove the temporary file (and, with ``remove_dirs``, the directories prepare() made)."""
        if self.tmp is not None:
            try:
                os.unlink(self.tmp)
            except OSError:
                pass
            self.tmp = None
        if remove_dirs:
            for d in self._created:  # innermost first
                try:
                    os.rmdir(d)
                except OSError:
                    pass
            self._created = []
