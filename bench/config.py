"""What the benchmarks run: profiles (sizes, time budgets), the shared scenes and their inputs.

Profile (``ELASTIC_BENCH_PROFILE``): ``smoke`` (default when pytest-benchmark is disabled, as in
the plain ``pytest`` run: tiny sizes, every body once), ``quick`` (default with
``--benchmark-enable``; ``python -m bench --quick``) or ``full`` (``python -m bench``).
Sizes may be overridden with comma lists in ``ELASTIC_BENCH_CLOTH`` (vertices per side),
``ELASTIC_BENCH_IMPLICIT`` (vertices per side for the backward-Euler steps) and
``ELASTIC_BENCH_ROD`` (rod nodes).

The configuration (threads, precision) is the runtime's: ``ELASTIC_THREADS``, ``ELASTIC_FP``
(engine/runtime.py); one process per configuration.

Scenes: the cloth is :func:`engine.scenes.cloth` (the lessons' scene) with E = 1e3 N/m,
rho = 0.1 kg/m^2, B = 1e-4 N m; the rod is :class:`engine.scenes.Rod` with E = 1 N, rho = 1 kg/m,
length 1 m, node 0 pinned.  Every step starts from the same deterministic, moving, deformed
state (:func:`cloth_start_state`), so the engine and the baselines get the same input and the
implicit solvers see stretched springs and bent hinges, not the trivial rest state.
"""
import os

import numpy as np
from typing import NamedTuple

CLOTH_E, CLOTH_RHO, CLOTH_B = 1e3, 0.1, 1e-4
IMPLICIT_DT = 1.0 / 60.0
IMPLICIT_TOL = {64: 1e-5, 32: 1e-4}   # relative residual by precision (f32 cannot reach 1e-5: see report)
F32_TOL_FALLBACK = (1e-4, 3e-4, 1e-3)  # f32: the first of these that the solver reaches is used (and recorded)
EXPLICIT_BLOCK = 10    # steps per call of the explicit "block" rows (the lessons step many times per launch)
ROD_E, ROD_RHO = 1.0, 1.0
ROD_IMPLICIT_NU = 10.0                # rod backward-Euler dt = 10 h/c (10x the explicit limit)

QUICK_SKIPS = ("t1-f64", "t2-f32")   # the configurations python -m bench --quick does not run (no rows below)
# per profile: sizes per configuration ("t2-f64", "t1-f64", "t2-f32"), time budget per benchmark
PROFILES = {
    "smoke": dict(budget=0.0, max_rounds=1, sizes={
        "*": dict(cloth=[16], implicit=[16], rod=[1000], sequence=[16])}),
    # quick: the 2-thread f64 process only (python -m bench --quick runs no other), the full run's
    # rows up to 128^2 with the same time budget per row, so that its ratios are the full run's
    "quick": dict(budget=0.25, max_rounds=40, sizes={
        "t2-f64": dict(cloth=[64, 128], implicit=[64, 128], rod=[10000], sequence=[64]),
        "t1-f64": dict(cloth=[], implicit=[], rod=[], sequence=[]),
        "t2-f32": dict(cloth=[], implicit=[], rod=[], sequence=[]),
    }),
    "full": dict(budget=0.6, max_rounds=100, sizes={
        "t2-f64": dict(cloth=[32, 64, 128, 256], implicit=[32, 64, 128, 256], rod=[1000, 10000, 100000],
                       sequence=[64, 128]),
        "t1-f64": dict(cloth=[32, 64, 128, 256], implicit=[32, 64, 128], rod=[1000, 10000, 100000], sequence=[]),
        "t2-f32": dict(cloth=[32, 64, 128, 256], implicit=[32, 64, 128], rod=[1000, 10000, 100000], sequence=[]),
    }),
}
# interleaved comparison rows (bench/interleave.py): per profile and kind of row, (seconds of timing
# per row, fewest rounds, most rounds); a round times every contender of the row once
ROW_BUDGETS = {
    "smoke": {k: (0.0, 1, 1) for k in ("explicit", "direct", "iterative", "sequence")},
    "quick": dict(explicit=(1.5, 9, 60), direct=(8.0, 7, 30), iterative=(0.0, 3, 3), sequence=(0.0, 5, 5)),
    "full": dict(explicit=(1.5, 9, 60), direct=(8.0, 7, 30), iterative=(0.0, 3, 3), sequence=(0.0, 5, 5)),
}


def config_name() -> str:
    threads = os.environ.get("ELASTIC_THREADS", "").strip() or "2"
    fp = os.environ.get("ELASTIC_FP", "").strip() or "64"
    return f"t{threads}-f{fp}"


_profile = None


def set_default_profile(benchmarks_enabled: bool) -> None:
    """Called by conftest: the profile when ELASTIC_BENCH_PROFILE is not set."""
    global _profile
    _profile = "quick" if benchmarks_enabled else "smoke"


def profile() -> str:
    p = os.environ.get("ELASTIC_BENCH_PROFILE", "").strip() or _profile or "smoke"
    if p not in PROFILES:
        raise ValueError(f"ELASTIC_BENCH_PROFILE must be one of {', '.join(PROFILES)} (got {p!r})")
    return p


def sizes(kind: str) -> list:
    """Sizes of one kind ("cloth", "implicit", "rod") for this profile and configuration."""
    env = os.environ.get({"cloth": "ELASTIC_BENCH_CLOTH", "implicit": "ELASTIC_BENCH_IMPLICIT",
                          "rod": "ELASTIC_BENCH_ROD", "sequence": "ELASTIC_BENCH_SEQUENCE"}[kind], "").strip()
    if env:
        return [int(s) for s in env.split(",") if s.strip()]
    table = PROFILES[profile()]["sizes"]
    row = table.get(config_name()) or table.get("*") or table["t2-f64"]
    return list(row[kind])


def row_budget(kind: str) -> tuple:
    """(seconds of timing, fewest rounds, most rounds) of an interleaved row of ``kind``
    ("explicit", "direct", "iterative", "sequence")."""
    table = ROW_BUDGETS[profile()]
    if kind not in table:
        raise ValueError(f"row budget kind must be one of {', '.join(table)} (got {kind!r})")
    return table[kind]


def budget() -> tuple:
    """(seconds of timing per benchmark, max rounds)."""
    p = PROFILES[profile()]
    return p["budget"], p["max_rounds"]


# --------------------------------------------------------------------------------------------
# Scenes (cached per process: building a 256^2 cloth takes about a second)
# --------------------------------------------------------------------------------------------

_cloths: dict = {}
_rods: dict = {}


def cloth_scene(n: int, bending: bool = True, E: float = CLOTH_E):
    """The lessons' cloth (engine.scenes.cloth), n x n vertices; cached."""
    from engine.scenes import cloth
    key = (n, bending, E)
    if key not in _cloths:
        _cloths[key] = cloth(n, E=E, rho=CLOTH_RHO, B=CLOTH_B if bending else 0.0)
    return _cloths[key]


MEMBRANE_MODEL = "membrane (Baraff-Witkin)"   # the model name of the membrane rows (bench/test_bench_explicit.py)
MEMBRANE_IMPLICIT_GROUP = "membrane-implicit-step"   # the membrane's backward-Euler rows (bench/test_bench_implicit.py)


class MembraneCloth(NamedTuple):
    model: object
    membrane: object


def membrane_scene(n: int, E: float = CLOTH_E) -> MembraneCloth:
    """The lessons' cloth (the mesh, masses, pins and gravity of :func:`cloth_scene`) with a
    Baraff-Witkin membrane instead of springs: k_stretch = E, k_shear = E/2 (N/m); cached."""
    key = ("membrane", n, E)
    if key not in _cloths:
        from engine.energies.membrane import MembraneEnergy
        from engine.model import Model
        c = cloth_scene(n, False, E)
        model = Model(c.model.X, mass=c.model.mass, pinned=np.flatnonzero(c.model.pinned), gravity=c.model.gravity)
        membrane = model.add_energy(MembraneEnergy.from_mesh(c.mesh, "baraff-witkin", k_stretch=E, k_shear=0.5 * E))
        _cloths[key] = MembraneCloth(model, membrane)
    return _cloths[key]


def cloth_start_state(c) -> tuple:
    """A deterministic moving, deformed state (x0, v0) of the cloth (numpy (n, 3)): the sheet is
    stretched 0.5% downwards from its top edge, bulged out of its plane by up to 5 cm and swinging
    out of plane at up to 0.2 m/s; the top edge (and so the pins) stays where it is."""
    X = np.asarray(c.model.X, dtype=np.float64)
    x0 = X.copy()
    top = X[:, 2].max()
    depth = (top - X[:, 2]) / max(top - X[:, 2].min(), 1e-300)   # 0 at the top edge, 1 at the bottom
    x0[:, 2] = top - (top - X[:, 2]) * 1.005
    x0[:, 1] += 0.05 * np.sin(np.pi * X[:, 0] / max(X[:, 0].max(), 1e-300)) * depth
    v0 = np.zeros_like(X)
    v0[:, 1] = 0.2 * depth
    v0[c.model.pinned] = 0.0
    x0[c.model.pinned] = X[c.model.pinned]
    return x0, v0


def rod_scene(nodes: int):
    """The rod of engine.rod (E = 1 N, rho = 1 kg/m, 1 m, node 0 pinned) and its start state
    (a Gaussian displacement pulse 10 node spacings wide); cached."""
    from engine.scenes import Rod
    if nodes not in _rods:
        rod = Rod.uniform(nodes, 1.0, E=ROD_E, rho=ROD_RHO, pinned=[0])
        h = 1.0 / (nodes - 1)
        u0 = 1e-3 * np.exp(-0.5 * ((rod.p - 0.5) / (10 * h)) ** 2)
        _rods[nodes] = (rod, u0)
    return _rods[nodes]


def backward_euler_for(model, state_reset, dt, solver, fp, tol=None):
    """A BackwardEuler (one Newton iteration, no line search) at the benchmark tolerance: 1e-5 in
    f64; in f32 the first tolerance of F32_TOL_FALLBACK that one step from the reset state reaches
    (f32 round-off puts a floor of ~1e-5..1e-4 under the relative residual).  Returns
    (integrator, tol, tolerances that failed); integrator None if none was reached."""
    from engine.integrators import BackwardEuler, SolverError, Stepper
    if fp == 64:
        tol = IMPLICIT_TOL[64] if tol is None else float(tol)
        return BackwardEuler(solver=solver, tol=tol, newton_iterations=1, line_search=False,
                             max_iter=100000), tol, []
    failed = []
    for tol in F32_TOL_FALLBACK:
        be = BackwardEuler(solver=solver, tol=tol, newton_iterations=1, line_search=False, max_iter=100000)
        state_reset()
        try:
            Stepper(model, be).advance(state_reset.state, dt)
        except SolverError:
            failed.append(tol)
            continue
        return be, tol, failed
    return None, None, failed
