"""One Taichi initialisation per process.

Every kernel in the engine is a module-level ``@ti.kernel`` that takes ``ti.ndarray``
arguments, so nothing Taichi-related happens at import time; call :func:`init` once
(the lesson runner, the benchmarks and the test fixtures do) before the first kernel.

Defaults: CPU, 2 threads, f64, ``fast_math`` off, kernel cache in ``.ti_cache/`` at the
project root, version check off. Environment overrides (read by :func:`init` when the
corresponding argument is not given; a bad value is a :class:`RuntimeConfigError` naming the
variable):

``ELASTIC_ARCH``      cpu | cuda | vulkan (default: ``TI_ARCH`` if set, else cpu)
``ELASTIC_THREADS``   CPU threads (default 2)
``ELASTIC_FP``        64 | 32 (default 64)
``ELASTIC_PIN``       auto | off (default auto): on the CPU, bind each of Taichi's pool threads to
                      its own CPU (engine.pinning: left free, the scheduler often put both on one
                      CPU, and a parallel loop then ran on one thread); auto does it when the
                      threads are as many as the CPUs this process may use, off never
``ELASTIC_CACHE_DIR`` kernel cache directory (default ``<project>/.ti_cache``); one that cannot
                      be created or written is not used (one warning line; kernels then
                      compile in every process)
``TI_LOG_LEVEL``      Taichi's log level: trace, debug, info, warn, error (default), critical, off

Taichi's other ``TI_*`` variables still work. ``TI_ARCH`` is only a default here: Taichi itself
would let it override the arch asked for, so it is set aside while Taichi starts and the arch
chosen above is the one used. What Taichi actually runs on is read back after it starts
(:attr:`RuntimeInfo.backend`, :attr:`RuntimeInfo.precision`, :func:`describe`).

A process without ``HOME`` gets one (the user's home directory from the password database, or
the temporary directory) before Taichi is imported: Taichi's import aborts without it.
"""
from __future__ import annotations

import atexit
import contextlib
import dataclasses
import io
import os
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

# Silence Taichi's import banner; must happen before taichi is imported anywhere.
os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "0")
os.environ.setdefault("TI_SKIP_VERSION_CHECK", "ON")
LOG_LEVELS = ("trace", "debug", "info", "warn", "error", "critical", "off")


def prepare_environment() -> None:
    """What Taichi's import needs from the environment: ``HOME`` (its import aborts with a C++
    assertion without one; given the user's home directory from the password database, or the
    temporary directory) and a valid ``TI_LOG_LEVEL`` (read at import; a bad one raises
    RuntimeConfigError naming it). Called here before taichi is imported, and by
    ``python -m lessons`` before anything else is."""
    if "HOME" not in os.environ:
        home = os.path.expanduser("~")
        os.environ["HOME"] = home if home != "~" and os.path.isdir(home) else tempfile.gettempdir()
    level = os.environ.get("TI_LOG_LEVEL", "").strip()
    if level and level.lower() not in LOG_LEVELS:
        raise RuntimeConfigError(f"TI_LOG_LEVEL must be one of {', '.join(LOG_LEVELS)} (got {level!r})")


class RuntimeConfigError(ValueError):
    """A bad runtime option (arch, threads, precision, log level); the message is one line and
    names the option or environment variable it came from."""


prepare_environment()

import taichi as ti  # noqa: E402

from engine import pinning  # noqa: E402

PROJECT_ROOT = Path(__file__).resolve().parent.parent
ARCHES = ("cpu", "cuda", "vulkan")
MAX_THREADS = 256
PIN_CHOICES = ("auto", "off")
@dataclass(frozen=True)
class RuntimeInfo:
    """What was asked (arch, threads, fp, cache_dir) and, read back from Taichi once it runs,
    what it runs on: ``backend`` (Taichi's arch name: x64, arm64, cuda, vulkan), ``precision``
    (f64 or f32), ``cpu_threads`` (None on a GPU) and whether the offline kernel cache is used."""

    arch: str
    threads: int
    fp: int
    cache_dir: str
    pin: str = "auto"
    backend: str = field(default="", compare=False)
    precision: str = field(default="", compare=False)
    cpu_threads: int | None = field(default=None, compare=False)
    offline_cache: bool = field(default=True, compare=False)
    pinned: tuple | None = field(default=None, compare=False)   # the pool threads' CPUs, or None
    unpinned_why: str = field(default="", compare=False)

    def describe(self) -> str:
        """One line: 'cpu (x64), f64, 2 threads, kernel cache /path' as Taichi reports it."""
        where = self.arch if self.backend in ("", self.arch) else f"{self.arch} ({self.backend})"
        threads = f"{self.cpu_threads} CPU threads" if self.cpu_threads else "GPU"
        if self.pinned:
            threads += f" on CPUs {', '.join(map(str, self.pinned))}"
        cache = f"kernel cache {self.cache_dir}" if self.offline_cache else "no kernel cache"
        return f"{where}, {self.precision or f'f{self.fp}'}, {threads}, {cache}"

    def as_dict(self) -> dict:
        return dict(arch=self.arch, backend=self.backend, precision=self.precision,
                    threads=self.cpu_threads, offline_cache=self.cache_dir if self.offline_cache else None,
                    pinned=list(self.pinned) if self.pinned else None)


_current: RuntimeInfo | None = None


def _env(name: str, default: str) -> str:
    value = os.environ.get(name, "").strip()
    return value if value else default


def _pick(value, flag: str, env_names: tuple[str, ...], default: str) -> tuple[str, str]:
    """(the value, where it came from): the argument, else the first environment variable set,
    else the default."""
    if value is not None:
        return str(value), flag
    for name in env_names:
        if os.environ.get(name, "").strip():
            return os.environ[name].strip(), name
    return default, "default"


def _usable_cache(path: str) -> str | None:
    """Why the kernel cache directory cannot be used (None: it can): it must exist or be creatable
    and take a file. Taichi would otherwise crash when it writes the cache at exit."""
    if os.path.exists(path) and not os.path.isdir(path):
        return "it is a file, not a directory"
    try:
        Path(path).mkdir(parents=True, exist_ok=True)
        probe = Path(path) / f".probe-{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        return exc.strerror or str(exc)
    return None


def init(arch: str | None = None, threads: int | None = None, fp: int | None = None,
         cache_dir: str | os.PathLike | None = None, warn=None) -> RuntimeInfo:
    """Initialise Taichi once; a second call with the same options is a no-op.

    A second call with different options raises: Taichi kernels compiled for one
    configuration must not silently run under another. ``warn(line)`` receives a warning
    (default: printed to stderr), e.g. that the kernel cache directory cannot be used.
    """
    global _current
    arch_text, arch_from = _pick(arch, "--arch", ("ELASTIC_ARCH", "TI_ARCH"), "cpu")
    arch = arch_text.lower()
    if arch not in ARCHES:
        raise RuntimeConfigError(f"{arch_from} must be one of {', '.join(ARCHES)} (got {arch_text!r})")
    threads_text, threads_from = _pick(threads, "--threads", ("ELASTIC_THREADS",), "2")
    try:
        threads = int(threads_text)
    except ValueError:
        raise RuntimeConfigError(f"{threads_from} must be an integer in 1..{MAX_THREADS} (got {threads_text!r})") from None
    if not 1 <= threads <= MAX_THREADS:
        raise RuntimeConfigError(f"{threads_from} must be an integer in 1..{MAX_THREADS} (got {threads})")
    fp_text, fp_from = _pick(fp, "fp", ("ELASTIC_FP",), "64")
    try:
        fp = int(fp_text)
    except ValueError:
        raise RuntimeConfigError(f"{fp_from} must be 32 or 64 (got {fp_text!r})") from None
    if fp not in (32, 64):
        raise RuntimeConfigError(f"{fp_from} must be 32 or 64 (got {fp})")
    log_level = _env("TI_LOG_LEVEL", "error")
    if log_level.lower() not in LOG_LEVELS:
        raise RuntimeConfigError(f"TI_LOG_LEVEL must be one of {', '.join(LOG_LEVELS)} (got {log_level!r})")
    cache_text, cache_from = _pick(cache_dir, "cache_dir", ("ELASTIC_CACHE_DIR",), str(PROJECT_ROOT / ".ti_cache"))
    cache = str(Path(cache_text).resolve())
    pin_text, pin_from = _pick(None, "", ("ELASTIC_PIN",), "auto")
    pin = pin_text.lower()
    if pin not in PIN_CHOICES:
        raise RuntimeConfigError(f"{pin_from} must be one of {', '.join(PIN_CHOICES)} (got {pin_text!r})")

    wanted = RuntimeInfo(arch, threads, fp, cache, pin)
    if _current is not None:
        if _current != wanted:
            raise RuntimeConfigError(
                f"Taichi is already initialised as {_current}; cannot re-initialise as {wanted} in one process"
            )
        return _current

    problem = _usable_cache(cache)
    if problem is not None:
        line = (f"warning: {cache_from + '=' if cache_from != 'default' else 'kernel cache '}{cache_text}: cannot "
                f"use it as the kernel cache ({problem}); running without it (kernels compile in every run)")
        (warn or (lambda text: print(text, file=sys.stderr, flush=True)))(line)

    ti_arch = {"cpu": ti.cpu, "cuda": ti.cuda, "vulkan": ti.vulkan}[arch]
    kwargs = dict(
        arch=ti_arch,
        default_fp=ti.f64 if fp == 64 else ti.f32,
        default_ip=ti.i32,
        fast_math=False,
        offline_cache=problem is None,
        enable_fallback=False,
        log_level=log_level.lower(),
    )
    if problem is None:
        kwargs["offline_cache_file_path"] = cache
    if arch == "cpu":
        kwargs["cpu_max_num_threads"] = threads
    banner = io.StringIO()
    ti_arch_env = os.environ.pop("TI_ARCH", None)  # Taichi lets TI_ARCH override the arch argument
    before = pinning.thread_ids()   # Taichi's pool threads are among those that appear now
    try:
        with contextlib.redirect_stdout(banner):  # ti.init prints "[Taichi] Starting on arch=..."
            ti.init(**kwargs)
    except RuntimeError as exc:
        raise RuntimeConfigError(
            f"{arch_from if arch_from != 'default' else '--arch'} {arch} is not available on this machine "
            f"({exc}); use --arch cpu"
        ) from None
    finally:
        if ti_arch_env is not None:
            os.environ["TI_ARCH"] = ti_arch_env
    _current = _read_back(wanted, problem is None)
    if _current.cpu_threads:
        pinned, why = pinning.pin_pool(before, _current.cpu_threads) if pin == "auto" else (None, "ELASTIC_PIN=off")
        _current = dataclasses.replace(_current, pinned=pinned, unpinned_why=why)
    # Taichi writes its offline kernel cache when the program is finalised; a script that just
    # exits never finalises it, so every process would compile every kernel again.
    atexit.register(_finalise)
    return _current


def _read_back(wanted: RuntimeInfo, cache_on: bool) -> RuntimeInfo:
    """``wanted`` completed with what the started Taichi program reports it runs on."""
    from taichi.lang import impl
    try:
        cfg = impl.get_runtime().prog.config()
    except Exception:  # pragma: no cover - older Taichi: the Python-side copy of the config
        cfg = impl.current_cfg()
    backend = ti._lib.core.arch_name(cfg.arch)
    precision = {"f64": "f64", "f32": "f32", "float64": "f64", "float32": "f32"}.get(
        str(cfg.default_fp).split(".")[-1], str(cfg.default_fp))
    is_cpu = backend in ("x64", "arm64")
    return RuntimeInfo(wanted.arch, wanted.threads, 64 if precision == "f64" else 32, wanted.cache_dir, wanted.pin,
                       backend=backend, precision=precision,
                       cpu_threads=int(cfg.cpu_max_num_threads) if is_cpu else None,
                       offline_cache=bool(cfg.offline_cache) and cache_on)


def _finalise() -> None:
    global _current
    if _current is not None:
        _current = None
        try:
            ti.reset()
        except Exception:  # exiting anyway; a failed cache write only costs compile time next run
            pass


def current() -> RuntimeInfo | None:
    """The active runtime configuration, or None before :func:`init`."""
    return _current


def threads(default: int) -> int:
    """The CPU threads asked of the active runtime, or ``default`` before :func:`init`."""
    return default if _current is None else int(_current.threads)
