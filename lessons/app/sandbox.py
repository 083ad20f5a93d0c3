"""What a student's module may do, and the guard that holds it to that in the grading child.

The grader runs student code, which may be wrong, slow or hostile. Three layers keep a solution
from passing without computing the physics, and from touching the grading:

1. :func:`policy_problems` reads the module (and every module of the solution folder it imports)
   before anything runs: it may import only numpy, math, cmath, taichi and its own modules, may
   not name the builtins that reach other code or files (``open``, ``exec``, ``getattr``,
   ``__import__``, ...), may not read a private or dunder attribute (``x.__globals__``,
   ``np._core``) nor an attribute that leads to the interpreter, files or processes (``np.sys``,
   ``.modules``, ``np.save``, ``np.fromfile``, ``ti.tools``), and may not assign to a module's
   attribute (``np.abs = ...``). Each problem is one line with the file, the line number and what
   to do instead. ``ti.init``/``ti.reset`` is not a problem but a note: the grader ignores it.
2. :func:`load_guarded` executes the modules with restricted builtins (no ``open``, ``exec``,
   ``eval``, ``compile``, ``getattr`` ..., an ``__import__`` that refuses every other module, even
   one already loaded), and checks that each function the lesson asks for is defined in the
   solution folder (not an alias of the engine's function).
3. :class:`Guard` (armed before the student's module is imported, never disarmed in that process):
   a Python audit hook that ends the process, saying why on the grading channel, when the
   solution's code (a frame of its files on the stack) tries to write a file, start a process,
   send a signal, open a socket, load a C library or walk the garbage collector's objects, or when
   a thread other than the main one starts a process; and a fingerprint of numpy's, math's and
   taichi's module attributes, compared after every piece of student code ran, so that a patched
   ``np.max`` is found even when reached through an alias. ``ti.init``/``ti.reset`` become
   callables with no Python globals behind them.

The reading refuses what reaches attributes by a name it cannot see: ``match`` class patterns,
``operator.attrgetter``/``methodcaller`` and ``functools`` (found re-exported in numpy's public
modules), private submodules (``numpy.linalg._linalg``). The module is compiled from its source,
never from a ``__pycache__`` file.

The child also ends itself when the grader ends (``PR_SET_PDEATHSIG``), and runs under a CPU-time
and an address-space limit (``resource``). None of this makes student code safe to run on a
machine with secrets: the README says to grade in a container or a separate account.

This module holds the reading (1) and :func:`copied_from`; the loading (2), the guard (3) and
the child's limits are in lessons.app.sandbox_guard.
"""
from __future__ import annotations

import ast
import importlib.util
import types
from dataclasses import dataclass, field
from pathlib import Path

ALLOWED_MODULES = ("numpy", "math", "cmath", "taichi")
BANNED_NAMES = {
    "__import__": "imports a module by name", "open": "opens a file", "exec": "executes a string as code",
    "eval": "evaluates a string as code", "compile": "compiles a string to code", "globals": "reads the module's "
    "globals", "locals": "reads the frame's locals", "vars": "reads an object's namespace", "getattr": "reaches an "
    "attribute by a computed name", "setattr": "sets an attribute by a computed name", "delattr": "deletes an "
    "attribute", "breakpoint": "starts a debugger", "input": "reads the terminal", "help": "starts the help system",
    "exit": "ends the process", "quit": "ends the process", "memoryview": "reaches raw memory",
    "__builtins__": "reaches the builtins", "__loader__": "reaches the module loader", "__spec__": "reaches the "
    "module spec", "__file__": "reads where the module lies",
    "get_ipython": "reaches the notebook's kernel (its magics and shell commands)",
}
# attributes that lead to the interpreter, other modules, files or processes (read access refused)
BANNED_ATTRIBUTES = {
    "sys", "os", "modules", "builtins", "importlib", "subprocess", "gc", "inspect", "ctypes", "ctypeslib",
    "f_globals", "f_locals", "f_back", "f_builtins", "f_code", "gi_frame", "cr_frame", "ag_frame", "tb_frame",
    "tb_next", "load", "save", "savez", "savez_compressed", "savetxt", "loadtxt", "genfromtxt", "fromfile",
    "tofile", "memmap", "fromregex", "DataSource", "open_memmap", "tools", "imwrite", "imread", "system",
    "popen", "spawn", "fork", "kill", "environ", "getenv", "putenv", "threading", "multiprocessing", "signal",
    "socket", "shutil", "pathlib", "io", "pickle", "marshal", "runpy", "platform", "site",
    # attribute access by a string (operator.attrgetter("a.__b__")) and the modules that offer it
    "operator", "functools", "attrgetter", "methodcaller", "itemgetter", "weakref", "copyreg",
    "contextlib", "traceback", "linecache", "warnings", "abc", "collections", "itertools", "codecs", "builtin",
}
IGNORED_CALLS = ("init", "reset")   # ti.init / ti.reset: noted, and neutralised in the grading child


class PolicyError(Exception):
    """The solution breaks the rules of what a solution may contain or do (one line)."""


@dataclass
class Reading:
    """What :func:`policy_problems` found: ``problems`` (each refuses the module) and ``notes``
    (told to the student, nothing refused), one line each; the solution's files read."""
    problems: list = field(default_factory=list)
    notes: list = field(default_factory=list)
    files: list = field(default_factory=list)


def _root_name(node) -> str | None:
    while isinstance(node, ast.Attribute):
        node = node.value
    return node.id if isinstance(node, ast.Name) else None


def sibling_module(folder: Path, dotted: str) -> Path | None:
    """The solution folder's own module ``dotted`` (its first part a file in the folder), or None."""
    first = dotted.split(".")[0]
    path = folder / f"{first}.py"
    return path if first and path.is_file() else None


def allowed(dotted: str, strict: bool = True) -> bool:
    """numpy, math, cmath, taichi and (``strict``: what the student's source may name) their public
    submodules, no part private or banned. At run time (not ``strict``) the libraries' own lazy
    imports pass through the module's ``__import__`` too (``ndarray.dump`` imports
    ``numpy._core._methods``), so any of their submodules is let through there."""
    parts = dotted.split(".")
    return parts[0] in ALLOWED_MODULES and (not strict or not any(p.startswith("_") or p in BANNED_ATTRIBUTES
                                                                  for p in parts[1:]))


# the library modules a solution may use, and through which it may reach names
LIBRARY_MODULES = ("numpy", "numpy.linalg", "math", "cmath", "taichi", "taichi.math", "taichi.types")
LIBRARY_HOMES = ("numpy", "taichi", "math", "cmath", "builtins")


def _library(dotted: str):
    """The library module ``dotted`` when a solution may use it, else None."""
    if dotted not in LIBRARY_MODULES:
        return None
    try:
        return importlib.import_module(dotted)
    except ImportError:
        return None


def _library_value(module, attr: str) -> tuple[object, str]:
    """What ``module.attr`` is, and '' when a solution may use it, else why not: an allowed module,
    or a function, class, ufunc or number that the library itself defines (not a re-export of
    another module's function, which is how eval and attrgetter hid in numpy and taichi)."""
    try:
        value = getattr(module, attr)
    except Exception:  # noqa: BLE001 - a name the library does not offer (or a lazy import that fails)
        return None, f"{module.__name__} has no public {attr}"
    if isinstance(value, types.ModuleType):
        return value, ("" if value.__name__ in LIBRARY_MODULES else
                       f"{module.__name__}.{attr} is the module {value.__name__}, which a solution may not use")
    if isinstance(value, (int, float, complex, str, bool, type(None))):
        return value, ""
    home = getattr(value, "__module__", None) or getattr(type(value), "__module__", "") or ""
    if not isinstance(home, str) or home.split(".")[0] not in LIBRARY_HOMES:
        return value, f"{module.__name__}.{attr} comes from {home or 'elsewhere'}, not from the library"
    return value, ""


def _library_chain(node: ast.Name, module, parents: dict, refuse) -> None:
    """``np.a.b ...``: each step resolved against the real library; a module may only be the base of
    a further attribute (never passed, bound or returned: what it leads to could not be read), and
    every name reached must be one the library itself defines."""
    here, value = node, module
    while isinstance(value, types.ModuleType):
        parent = parents.get(here)
        if not (isinstance(parent, ast.Attribute) and parent.value is here):
            refuse(here, f"uses the module {value.__name__} as a value",
                   "use its functions by name (np.linalg.norm(...)), not the module itself")
            return
        if parent.attr.startswith("_") or parent.attr in BANNED_ATTRIBUTES:
            return   # refused as an attribute
        value, why = _library_value(value, parent.attr)
        if why:
            refuse(parent, f"reaches {ast.unparse(parent)}", f"{why}; use numpy's and taichi's math")
            return
        here = parent


def _read_one(path: Path, reading: Reading, queue: list, folder: Path) -> None:
    name = path.name
    if path.resolve().parent != folder.resolve():
        reading.problems.append(f"{name}: is a link to {path.resolve()}, outside the solution folder: a solution's "
                                f"modules are its own files")
        return
    try:
        text = path.read_text(encoding="utf-8")
        tree = ast.parse(text, filename=str(path))
    except SyntaxError as exc:
        reading.problems.append(f"{name}: line {exc.lineno}: {exc.msg}")
        return
    except (OSError, UnicodeDecodeError, ValueError, RecursionError, MemoryError) as exc:
        reading.problems.append(f"{name}: cannot be read: {type(exc).__name__}")
        return
    folder = path.parent
    modules: set[str] = set()          # names bound to a module (np, ti, math, helpers)
    library: dict[str, object] = {}    # those bound to a library module: name -> the module
    parents = {child: parent for parent in ast.walk(tree) for child in ast.iter_child_nodes(parent)}

    def refuse(node, what: str, instead: str) -> None:
        reading.problems.append(f"{name}: line {getattr(node, 'lineno', '?')}: {what}: {instead}")

    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if allowed(alias.name) and _library(alias.name) is not None:
                    bound = alias.asname or alias.name.split(".")[0]
                    modules.add(bound)
                    library[bound] = _library(alias.name if alias.asname else alias.name.split(".")[0])
                elif sibling_module(folder, alias.name):
                    modules.add((alias.asname or alias.name).split(".")[0])
                    queue.append(sibling_module(folder, alias.name))
                else:
                    refuse(node, f"imports {alias.name}", "a solution may import only numpy, math, cmath, taichi "
                           "and its own modules beside it; write the function yourself")
        elif isinstance(node, ast.ImportFrom):
            dotted = node.module or ""
            if node.level:
                for alias in node.names:
                    target = sibling_module(folder, dotted or alias.name)
                    if target is None:
                        refuse(node, f"imports {'.' * node.level}{dotted or alias.name}",
                               "a relative import must name a module of the solution folder")
                    else:
                        queue.append(target)
            elif allowed(dotted) and _library(dotted) is not None:
                for alias in node.names:
                    if alias.name != "*" and not alias.name.startswith("_"):
                        value, why = _library_value(_library(dotted), alias.name)
                        if why:
                            refuse(node, f"imports {dotted}.{alias.name}", f"{why}; use numpy's and taichi's math")
                        elif isinstance(value, types.ModuleType):
                            modules.add(alias.asname or alias.name)
                            library[alias.asname or alias.name] = value
                    if alias.name in IGNORED_CALLS and dotted.split(".")[0] == "taichi":
                        reading.notes.append(f"{name}: line {node.lineno}: imports taichi's {alias.name}: the grader "
                                             f"ignores it (the engine starts Taichi: f64, 2 CPU threads)")
                    if alias.name.startswith("_") or alias.name in BANNED_ATTRIBUTES:
                        refuse(node, f"imports {dotted}.{alias.name}", "that name leads outside the physics; "
                               "use numpy's and taichi's public math")
                    if alias.name == "*":
                        refuse(node, f"imports * from {dotted}", "import the names you use")
            elif sibling_module(folder, dotted):
                queue.append(sibling_module(folder, dotted))
            else:
                refuse(node, f"imports from {dotted}", "a solution may import only numpy, math, cmath, taichi and "
                       "its own modules beside it; write the function yourself")
        elif isinstance(node, ast.Name) and node.id in BANNED_NAMES:
            refuse(node, f"uses {node.id} ({BANNED_NAMES[node.id]})", "a solution computes with its arguments only")
        elif isinstance(node, ast.Name) and node.id in library and isinstance(node.ctx, ast.Load):
            _library_chain(node, library[node.id], parents, refuse)
        elif isinstance(node, ast.Attribute):
            if node.attr.startswith("_"):
                refuse(node, f"reaches the private attribute .{node.attr}", "use the public names of numpy, math "
                       "and taichi")
            elif node.attr in BANNED_ATTRIBUTES:
                refuse(node, f"reaches .{node.attr}", "that leads to files, processes or other modules, which a "
                       "solution does not need")
            elif isinstance(node.ctx, (ast.Store, ast.Del)) and _root_name(node) in modules:
                refuse(node, f"changes {ast.unparse(node)}", "a solution may not change numpy, math, taichi or "
                       "its modules; compute with local names")
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr in IGNORED_CALLS:
            if _root_name(node.func) in modules:
                reading.notes.append(f"{name}: line {node.lineno}: calls {ast.unparse(node.func)}(...): the grader "
                                     f"ignores it (the engine starts Taichi itself: f64, 2 CPU threads); remove it")
        elif isinstance(node, (ast.arg, ast.FunctionDef, ast.AsyncFunctionDef, ast.AnnAssign)) and any(
                isinstance(a, ast.Constant) and isinstance(a.value, str) for a in
                (getattr(node, "annotation", None), getattr(node, "returns", None))):
            refuse(node, "has a string as an annotation (it would be evaluated as code)", "annotate with a type, "
                   "or not at all")
        elif isinstance(node, (ast.Match, ast.MatchClass)):
            refuse(node, "uses a match statement (its class patterns read attributes by name)",
                   "a solution does not need one; use if")
    for node in ast.walk(tree):   # a module bound to another name and changed through it
        if isinstance(node, ast.Assign) and isinstance(node.value, ast.Name) and node.value.id in modules:
            refuse(node, f"binds the module {node.value.id} to another name", "use the module by its own name")


def policy_problems(path: Path) -> Reading:
    """Read the student's module ``path`` and every module of its folder that it imports (no code
    runs): the problems that refuse it and the notes, one line each (see the module docstring)."""
    reading = Reading()
    folder = Path(path).parent
    queue, seen = [Path(path)], set()
    while queue:
        p = queue.pop(0)
        if p.resolve() in seen:
            continue
        seen.add(p.resolve())
        reading.files.append(p.resolve())
        _read_one(p, reading, queue, folder)
    return reading


def _shape(func: ast.FunctionDef) -> str:
    """A function's syntax tree without its docstring, names of locals kept: what a copy keeps."""
    body = func.body[1:] if func.body and isinstance(func.body[0], ast.Expr) and \
        isinstance(func.body[0].value, ast.Constant) and isinstance(func.body[0].value.value, str) else func.body
    return ast.dump(ast.Module(body=body, type_ignores=[]), annotate_fields=False, include_attributes=False)


def copied_from(path: Path, reference: Path, names: list) -> bool:
    """Whether every function ``names`` of the student's module has the syntax tree of the reference
    solution's (docstrings aside): the shipped solution handed in. One short function can match by
    chance; a whole module does not."""
    def shapes(p: Path) -> dict:
        try:
            tree = ast.parse(Path(p).read_text(encoding="utf-8"))
            return {n.name: _shape(n) for n in tree.body if isinstance(n, ast.FunctionDef)}
        except (OSError, SyntaxError, UnicodeDecodeError, ValueError, RecursionError, MemoryError):
            return {}
    mine, theirs = shapes(path), shapes(reference)
    return bool(names) and all(n in mine and mine[n] == theirs.get(n) for n in names)
