"""What the lessons run on: f64 only, and the Taichi backends that give each lesson its physics.

:func:`check` runs right after ``engine.runtime.init`` and before any lesson work (the command
line calls it); a run it refuses is bad input: one line naming the variable or option and what
to do, exit 2, nothing written. It reads the configuration Taichi really runs with, not only the
one asked for, so a run never reports one backend or precision and uses another.

Precision. Every lesson claim's tolerance is set for f64: round-off floors of 1e-13..1e-15
(exact identities, force = -dW/dx), finite differences with steps chosen for f64's 1e-16, static
residuals of 1e-5 of a vertex weight on stiff sheets, conservation over 1e5 steps. In f32
(unit round-off 6e-8) most of them cannot hold, and loosening each by the ratio would leave
claims that no longer test anything. So ``ELASTIC_FP=32`` is for the benchmarks
(``python -m bench``, which time the same kernels in f32 and run no lesson) and the lessons
refuse it.

Backends (measured with Taichi 1.7.4 and Mesa's software Vulkan, lavapipe). On ``vulkan``
ndarrays and arithmetic are f64, but:

* Taichi's Vulkan code generator has no f64 atan2, sin or cos (it refuses to compile them), and
  the hinge angle of the bending energy needs atan2: ``bending`` and ``explicit-vs-implicit``
  (whose cloth bends) stop with a compile error;
* Taichi's sparse solver (the Cholesky factorisation of static and implicit solves) runs only on
  CPU and CUDA: ``springs`` (the hanging rod), ``area-springs`` (the static stretch), ``bending``,
  ``explicit-vs-implicit`` and ``membranes`` (the static stretch, the implicit cloth) need it;
* lavapipe ends every loop of a kernel after 65535 iterations in all, without an error
  (engine.scenes.serial_loop_limit): the spring models' many-steps kernels then stop part-way
  through each launch and ``springs``' energy and wave-speed claims fail. The rod splits its
  runs into launches below the limit (engine.scenes.Rod.run), so ``rod-waves`` gives the same
  measured values on vulkan as on the CPU, for rods up to engine.scenes.rod_max_nodes nodes.

So on vulkan only ``rod-waves`` runs; the others are refused with these reasons.
"""
from __future__ import annotations

import taichi as ti

from engine import runtime
from engine.runtime import RuntimeConfigError

# What keeps each lesson off vulkan (the module docstring); a lesson not named here runs there.
SPARSE, ATAN2, LOOPS = "sparse", "atan2", "loops"
VULKAN_NEEDS = {
    "springs": (SPARSE, LOOPS),
    "area-springs": (SPARSE,),
    "bending": (ATAN2, SPARSE),
    "explicit-vs-implicit": (ATAN2, SPARSE),
    "membranes": (SPARSE,),
}
_WHY = {
    SPARSE: "Taichi's sparse solver (static and implicit solves) runs only on CPU and CUDA",
    ATAN2: "Taichi's Vulkan backend has no f64 atan2/sin/cos, which the hinge angle needs",
    LOOPS: "this device ends kernel loops after {limit} iterations, which cuts many-steps runs short",
}


def running_fp() -> int:
    """The float precision Taichi runs with (64 or 32)."""
    from taichi.lang import impl
    return 64 if impl.get_runtime().default_fp == ti.f64 else 32


def check(lessons, configs: dict | None = None) -> None:
    """Raise RuntimeConfigError (one line) if the initialised runtime cannot run ``lessons`` (with
    their ``configs``, by lesson id) with the physics their claims are about."""
    from engine.scenes import backend_name, rod_max_nodes, serial_loop_limit

    info = runtime.current()
    if info is None:
        raise RuntimeError("engine.runtime.init() must run before lessons.app.backends.check")
    arch, fp = backend_name(), running_fp()
    if arch != info.arch:  # e.g. a TI_ARCH that Taichi let override the arch it was given
        raise RuntimeConfigError(f"Taichi runs on {arch}, not on the {info.arch} this run was asked for; "
                                 f"unset TI_ARCH and choose the backend with --arch")
    if fp != info.fp:
        raise RuntimeConfigError(f"Taichi runs in f{fp} although f{info.fp} was asked for; unset TI_DEFAULT_FP")
    if fp != 64:
        raise RuntimeConfigError(
            "ELASTIC_FP=32: the lessons run in f64 only (their tolerances, down to 1e-15, are set by f64 "
            "round-off; f32 is for the benchmarks, python -m bench); unset ELASTIC_FP or set ELASTIC_FP=64")
    if arch != "vulkan":
        return
    limit = serial_loop_limit()
    needs = {l.id: [n for n in VULKAN_NEEDS.get(l.id, ()) if n != LOOPS or limit is not None] for l in lessons}
    refused = [i for i, n in needs.items() if n]
    if refused:
        why = []
        for need in (SPARSE, ATAN2, LOOPS):
            who = [i for i in refused if need in needs[i]]
            if who:
                why.append(_WHY[need].format(limit=limit) + f" ({', '.join(who)})")
        runs = [i for i in needs if not needs[i]]
        raise RuntimeConfigError(
            f"--arch vulkan cannot run {', '.join(refused)}: {'; '.join(why)}; use --arch cpu"
            + (f", or run {', '.join(runs)} alone on vulkan" if runs else ""))
    most = rod_max_nodes()
    for l in lessons:
        cfg = (configs or {}).get(l.id)
        nodes = getattr(cfg, "nodes", None)
        if l.id == "rod-waves" and most is not None and nodes is not None and nodes > most:
            raise RuntimeConfigError(
                f"--nodes must be <= {most} on this vulkan device (got {nodes}): it ends kernel loops after "
                f"{limit} iterations and one step of the rod needs about 5 per node; use --arch cpu "
                f"for longer rods")
