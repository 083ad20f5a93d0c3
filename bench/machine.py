"""What machine a benchmark ran on: CPU model, cores, caches, memory, load, versions."""
import os
import platform
import subprocess
import sys
from importlib import metadata
from pathlib import Path

PROJECT_ROOT = Path(__file__).resolve().parent.parent


def _read(path: str) -> str:
    try:
        return Path(path).read_text().strip()
    except OSError:
        return ""


def _cpu_model() -> str:
    for line in _read("/proc/cpuinfo").splitlines():
        if line.startswith("model name"):
            return line.split(":", 1)[1].strip()
    return platform.processor() or platform.machine()


def _size_bytes(text: str) -> int:
    text = text.strip().upper()
    if not text:
        return 0
    mult = {"K": 1024, "M": 1024 ** 2, "G": 1024 ** 3}.get(text[-1], 1)
    try:
        return int(float(text.rstrip("KMGB")) * mult)
    except ValueError:
        return 0


def last_level_cache_bytes() -> int:
    """Size of the largest cache level of CPU 0 (L3 here), 0 if unknown."""
    best = 0
    base = Path("/sys/devices/system/cpu/cpu0/cache")
    if base.is_dir():
        for idx in base.glob("index*"):
            best = max(best, _size_bytes(_read(str(idx / "size"))))
    return best


def _version(pkg: str) -> str:
    try:
        return metadata.version(pkg)
    except metadata.PackageNotFoundError:
        return "not installed"


def _git_commit() -> str:
    try:
        out = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=PROJECT_ROOT, capture_output=True,
                             text=True, timeout=10)
        dirty = subprocess.run(["git", "status", "--porcelain"], cwd=PROJECT_ROOT, capture_output=True, text=True,
                               timeout=10)
        return out.stdout.strip() + ("+changes" if dirty.stdout.strip() else "") if out.returncode == 0 else ""
    except (OSError, subprocess.SubprocessError):
        return ""


def load_average() -> list:
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except OSError:
        return []


def machine_info() -> dict:
    mem = 0
    for line in _read("/proc/meminfo").splitlines():
        if line.startswith("MemTotal:"):
            mem = int(line.split()[1]) * 1024
    return dict(
        cpu=_cpu_model(),
        cores=os.cpu_count(),
        affinity=len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
        last_level_cache_bytes=last_level_cache_bytes(),
        memory_bytes=mem,
        system=f"{platform.system()} {platform.release()}",
        python=sys.version.split()[0],
        versions={p: _version(p) for p in ("taichi", "numpy", "scipy", "pytest-benchmark", "matplotlib")},
        commit=_git_commit(),
        load_average=load_average(),
        # what every configuration's process does with Taichi's CPU pool threads (engine.pinning)
        elastic_pin=(os.environ.get("ELASTIC_PIN") or "auto").strip().lower(),
        thread_waits=thread_waits(),
    )


def thread_waits() -> dict:
    """How long MKL's OpenMP threads (KMP_BLOCKTIME, ms) and OpenBLAS's (OPENBLAS_THREAD_TIMEOUT)
    wait awake after their work in the benchmark's processes: the engine's settings (engine/__init__.py,
    engine.solvers.pardiso.quiet_openmp), or the values set before the run, which they keep."""
    import engine  # noqa: F401  (sets OPENBLAS_THREAD_TIMEOUT unless set)
    from engine.solvers.pardiso import MKL_BLOCKTIME_MS
    return dict(KMP_BLOCKTIME=os.environ.get("KMP_BLOCKTIME", MKL_BLOCKTIME_MS),
                OPENBLAS_THREAD_TIMEOUT=os.environ.get("OPENBLAS_THREAD_TIMEOUT"))
