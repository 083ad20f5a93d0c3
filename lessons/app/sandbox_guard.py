"""The grading child's side of the sandbox: the student's modules loaded under restricted builtins,
the guard armed before they are, and the child's own limits (layers 2 and 3 of lessons.app.sandbox,
whose docstring says what each layer refuses).

:func:`load_guarded` executes the solution's modules with restricted builtins and an
``__import__`` that lets through only the libraries and the solution's own modules;
:func:`own_function` says whether a function the lesson asks for was written in the solution;
:class:`Guard` is the audit hook and the libraries' fingerprint; :func:`limit_child` ends the
child with the grader and caps its CPU time and address space.
"""
from __future__ import annotations

import builtins
import os
import sys
import threading
import types
from pathlib import Path

from .sandbox import BANNED_NAMES, PolicyError, allowed, sibling_module


_REMOVED_BUILTINS = {n for n in BANNED_NAMES if hasattr(builtins, n)} - {"__import__"}


class _Loader:
    """Imports the solution's modules with restricted builtins; records the files it executed (in
    ``files``, the guard's set when given)."""

    def __init__(self, folder: Path, files: set | None = None):
        self.folder = Path(folder).resolve()
        self.loaded: dict[str, types.ModuleType] = {}
        self.files: set[str] = files if files is not None else set()
        safe = {k: v for k, v in vars(builtins).items() if k not in _REMOVED_BUILTINS}
        safe["__import__"] = self._import
        self.builtins = safe

    def _import(self, name, globals=None, locals=None, fromlist=(), level=0):
        if level == 0 and allowed(name, strict=False):
            return builtins.__import__(name, globals, locals, fromlist, 0)
        target = name if level == 0 else (name or (fromlist[0] if fromlist else ""))
        sibling = sibling_module(self.folder, target) if target else None
        if sibling is None and level and not name:
            # 'from . import a, b': each name a module of the folder
            mods = {n: self.load(sibling_module(self.folder, n)) for n in fromlist if sibling_module(self.folder, n)}
            return types.SimpleNamespace(**mods)
        if sibling is None:
            raise PolicyError(f"imports {name or target}: a solution may import only numpy, math, cmath, taichi and "
                              f"its own modules")
        module = self.load(sibling)
        return module

    def load(self, path: Path) -> types.ModuleType:
        path = Path(path).resolve()
        key = str(path)
        if key in self.loaded:
            return self.loaded[key]
        # compiled from the source read here: never from a __pycache__ file, which could hold other code
        source = path.read_text(encoding="utf-8")
        code = compile(source, key, "exec", dont_inherit=True)
        module = types.ModuleType(f"student_{path.stem}")
        module.__dict__.update(__file__=key, __builtins__=self.builtins)
        self.loaded[key] = module
        self.files.add(key)
        exec(code, module.__dict__)   # noqa: S102 - the student's module, under the guard
        return module


def function_file(func) -> str | None:
    """The file a function (a plain one or a Taichi function) was written in, or None."""
    inner = getattr(func, "__wrapped__", None) or getattr(func, "func", None) or func
    code = getattr(inner, "__code__", None)
    return str(Path(code.co_filename).resolve()) if code is not None else None


def load_guarded(path: Path, files: set | None = None):
    """Import the student's module ``path`` with restricted builtins; returns (module, files): the
    solution's files it executed (added to ``files`` as they load, when given)."""
    loader = _Loader(Path(path).parent, files)
    module = loader.load(path)
    return module, loader.files


def own_function(module, name: str, files: set) -> str:
    """'' when ``module.name`` is a function written in the solution's files, else why not."""
    func = vars(module).get(name)
    if func is None:
        return f"{name}: not defined in the module"
    where = function_file(func)
    if where is None:
        return f"{name}: is a {type(func).__name__}, not a function written in the solution"
    if where not in files:
        return f"{name}: is defined in {where}, not in the solution; write it yourself"
    return ""


# ------------------------------------------------------------------ the guard of the grading child

# audit events refused while the solution's own code runs (a frame of its files on the stack: the
# engine's set-up may start a process, load a C library or set an environment variable)
REFUSED_EVENTS = {
    "subprocess.Popen": "starts a process", "os.system": "starts a process", "os.exec": "replaces the process",
    "os.posix_spawn": "starts a process", "os.spawn": "starts a process", "os.fork": "forks the process",
    "os.forkpty": "forks the process", "pty.spawn": "starts a process", "os.kill": "sends a signal",
    "os.killpg": "sends a signal", "signal.pthread_kill": "sends a signal", "socket.__new__": "opens a socket",
    "socket.connect": "opens a connection", "socket.bind": "opens a socket", "ctypes.dlopen": "loads a C library",
    "ctypes.dlsym": "reaches a C function", "ctypes.addressof": "reaches raw memory", "gc.get_objects": "walks the "
    "interpreter's objects", "gc.get_referrers": "walks the interpreter's objects", "gc.get_referents": "walks the "
    "interpreter's objects", "sys._current_frames": "reaches other threads' frames", "os.putenv": "changes the "
    "environment", "os.unsetenv": "changes the environment", "os.chdir": "changes the working directory",
    "sys.addaudithook": "adds an audit hook", "os.remove": "removes a file", "os.rmdir": "removes a directory",
    "shutil.rmtree": "removes a directory", "os.truncate": "truncates a file", "os.chmod": "changes a file's mode",
    "os.symlink": "creates a link", "os.link": "creates a link", "webbrowser.open": "opens a browser",
    "urllib.Request": "opens a connection", "mmap.__new__": "maps memory", "os.chown": "changes a file's owner",
}
PROCESS_EVENTS = {"subprocess.Popen", "os.system", "os.posix_spawn", "os.fork", "os.forkpty", "pty.spawn", "os.kill",
                  "os.killpg", "socket.__new__", "socket.connect", "socket.bind", "os.exec", "os.spawn"}
_WRITE_FLAGS = os.O_WRONLY | os.O_RDWR | os.O_CREAT | os.O_APPEND | os.O_TRUNC
WATCHED_MODULES = ("numpy", "numpy.linalg", "math", "cmath", "taichi", "taichi.math", "builtins")


def _fingerprint() -> dict:
    out = {}
    for name in WATCHED_MODULES:
        module = sys.modules.get(name)
        if module is not None:
            out[name] = {k: id(v) for k, v in vars(module).items() if not k.startswith("__")}
    return out


class _Ignored:
    """``ti.init``'s stand-in in the grading child: callable with any arguments; only slots, no
    reference to the guard or to this module's globals."""
    __slots__ = ("_notes", "_note")

    def __init__(self, notes: list, note: str):
        self._notes, self._note = notes, note

    def __call__(self, *args, **kwargs):
        self._notes.append(self._note)


class Guard:
    """The grading child's guard (see the module docstring). ``report(text)`` writes the reason on
    the grading channel; the process then ends with exit code 3."""

    EXIT = 3

    def __init__(self, report):
        self.report = report
        self.files: set[str] = set()   # the solution's files (load_guarded adds each as it loads it)
        self.armed = False
        self.notes: list[str] = []
        self.snapshot: dict = {}

    def arm(self) -> None:
        import taichi
        self.snapshot = _fingerprint()
        taichi.init = self._ignored("ti.init")
        taichi.reset = self._ignored("ti.reset")
        self.snapshot = _fingerprint()
        if not self.armed:
            sys.addaudithook(self._hook)
        self.armed = True

    def _ignored(self, what: str):
        """A stand-in for ti.init/ti.reset with no Python frame or globals behind it (a builtin
        method): calling it adds a note and does nothing else."""
        note = f"{what}(...) was called and ignored: the engine runs Taichi as it started it"
        return _Ignored(self.notes, note)

    def refuse(self, why: str) -> None:
        try:
            self.report(why)
        finally:
            os._exit(self.EXIT)

    def _hook(self, event: str, args) -> None:
        if not self.armed or event == "sys._getframe":
            return
        if event not in REFUSED_EVENTS and event not in ("open", "os.rename", "os.replace", "os.mkdir") and \
                not event.startswith(("os.exec", "os.spawn")):
            return
        if not self._solution_running():   # the engine's or Taichi's own work, from the main thread
            if event in PROCESS_EVENTS and threading.current_thread() is not threading.main_thread():
                self.refuse(f"a thread started by the solution {REFUSED_EVENTS.get(event, 'starts a process')} "
                            f"({event})")
            return
        if event == "open":
            path, mode, flags = (tuple(args) + (None, None, None))[:3]
            writing = (isinstance(mode, str) and any(c in mode for c in "wax+")) or \
                      (isinstance(flags, int) and flags & _WRITE_FLAGS and not isinstance(mode, str))
            if writing:
                self.refuse(f"the solution tried to write {path!r}: a solution may not write files")
        elif event in ("os.rename", "os.replace", "os.mkdir"):
            self.refuse(f"the solution tried to {event[3:]} {tuple(args)[0]!r}: a solution may not touch files")
        else:
            self.refuse(f"the solution {REFUSED_EVENTS.get(event, 'starts a process')} ({event}): a solution "
                        f"computes its functions and nothing else")

    def _solution_running(self) -> bool:
        """Whether a frame of the solution's files is on the stack."""
        frame = sys._getframe(2)
        while frame is not None:
            if frame.f_code.co_filename in self.files:
                return True
            frame = frame.f_back
        return False

    def tampered(self) -> str:
        """'' when numpy, math, taichi and the builtins are as they were when armed, else what changed."""
        now = _fingerprint()
        for module, before in self.snapshot.items():
            after = now.get(module, {})
            for key, ident in before.items():
                if after.get(key) != ident:
                    return f"the solution changed {module}.{key}: a solution may not change the libraries"
        return ""


def limit_child(grader_pid: int, cpu_seconds: float, memory_bytes: int | None) -> None:
    """In the grading child: end with the grader (PR_SET_PDEATHSIG, Linux; and at once if the
    grader ``grader_pid`` is already gone) and cap its CPU time and address space."""
    import resource
    import signal
    try:
        import ctypes
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGKILL)   # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass
    if os.getppid() != grader_pid:   # the grader is already gone
        os._exit(1)
    if cpu_seconds and cpu_seconds > 0:
        soft = int(cpu_seconds) + 1
        resource.setrlimit(resource.RLIMIT_CPU, (soft, soft + 5))
    if memory_bytes:
        resource.setrlimit(resource.RLIMIT_AS, (memory_bytes, memory_bytes))
