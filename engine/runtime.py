"""One Taichi initialisation per process.

Every kernel in the engine is a module-level ``@ti.kernel`` that takes ``ti.ndarray``
arguments, so nothing Taichi-related happens at import time; call :func:`init` once
(the lesson runner, the benchmarks and the test fixtures do) before the first kernel.

Defaults: CPU, 2 threads, f64, ``fast_math`` off, kernel cache in ``.ti_cache/`` at the
project root, version check off. Environment overrides (read by :func:`init` when the
corresponding argument is not given):

``ELASTIC_ARCH``      cpu | cuda | vulkan (default cpu)
``ELASTIC_THREADS``   CPU threads (default 2)
``ELASTIC_FP``        64 | 32 (default 64)
``ELASTIC_CACHE_DIR`` kernel cache directory (default ``<project>/.ti_cache``)

Taichi's own ``TI_*`` variables still work for everything else (e.g. ``TI_LOG_LEVEL``).
"""
from __future__ import annotations

import atexit
import contextlib
import io
import os
from dataclasses import dataclass
from pathlib import Path

# Silence Taichi's import banner; must happen before taichi is imported anywhere.
os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "0")
os.environ.setdefault("TI_SKIP_VERSION_CHECK", "ON")

import taichi as ti  # noqa: E402

PROJECT_ROOT = Path(__file__).resolve().parent.parent
ARCHES = ("cpu", "cuda", "vulkan")
MAX_THREADS = 256


class RuntimeConfigError(ValueError):
    """A bad runtime option (arch, threads, precision); the message is one line."""


@dataclass(frozen=True)
class RuntimeInfo:
    arch: str
    threads: int
    fp: int
    cache_dir: str


_current: RuntimeInfo | None = None


def _env(name: str, default: str) -> str:
    value = os.environ.get(name, "").strip()
    return value if value else default


def init(arch: str | None = None, threads: int | None = None, fp: int | None = None,
         cache_dir: str | os.PathLike | None = None) -> RuntimeInfo:
    """Initialise Taichi once; a second call with the same options is a no-op.

    A second call with different options raises: Taichi kernels compiled for one
    configuration must not silently run under another.
    """
    global _current
    arch = (arch or _env("ELASTIC_ARCH", "cpu")).lower()
    if arch not in ARCHES:
        raise RuntimeConfigError(f"--arch must be one of {', '.join(ARCHES)} (got {arch!r})")
    try:
        threads = int(threads if threads is not None else _env("ELASTIC_THREADS", "2"))
    except ValueError:
        raise RuntimeConfigError(
            f"--threads must be an integer in 1..{MAX_THREADS} (got {os.environ.get('ELASTIC_THREADS')!r})"
        ) from None
    if not 1 <= threads <= MAX_THREADS:
        raise RuntimeConfigError(f"--threads must be an integer in 1..{MAX_THREADS} (got {threads})")
    try:
        fp = int(fp if fp is not None else _env("ELASTIC_FP", "64"))
    except ValueError:
        raise RuntimeConfigError(f"ELASTIC_FP must be 32 or 64 (got {os.environ.get('ELASTIC_FP')!r})") from None
    if fp not in (32, 64):
        raise RuntimeConfigError(f"floating-point precision must be 32 or 64 (got {fp})")
    cache = str(Path(cache_dir or _env("ELASTIC_CACHE_DIR", str(PROJECT_ROOT / ".ti_cache"))).resolve())

    wanted = RuntimeInfo(arch, threads, fp, cache)
    if _current is not None:
        if _current != wanted:
            raise RuntimeConfigError(
                f"Taichi is already initialised as {_current}; cannot re-initialise as {wanted} in one process"
            )
        return _current

    ti_arch = {"cpu": ti.cpu, "cuda": ti.cuda, "vulkan": ti.vulkan}[arch]
    kwargs = dict(
        arch=ti_arch,
        default_fp=ti.f64 if fp == 64 else ti.f32,
        default_ip=ti.i32,
        fast_math=False,
        offline_cache=True,
        offline_cache_file_path=cache,
        enable_fallback=False,
        log_level=_env("TI_LOG_LEVEL", "error"),
    )
    if arch == "cpu":
        kwargs["cpu_max_num_threads"] = threads
    banner = io.StringIO()
    try:
        with contextlib.redirect_stdout(banner):  # ti.init prints "[Taichi] Starting on arch=..."
            ti.init(**kwargs)
    except RuntimeError as exc:
        raise RuntimeConfigError(
            f"--arch {arch} is not available on this machine ({exc}); use --arch cpu"
        ) from None
    _current = wanted
    # Taichi writes its offline kernel cache when the program is finalised; a script that just
    # exits never finalises it, so every process would compile every kernel again.
    atexit.register(_finalise)
    return _current


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
