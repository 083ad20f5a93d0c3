"""Timed: one backward-Euler cloth step (Baraff-Witkin: one Newton iteration, no line search) at
dt = 1/60 s with the engine's solvers (PCG, Eigen's LL^T "cholesky", MKL PARDISO "pardiso"),
against what a user installs with pip (bench/peers/sparse.py: scipy CG, pyamg + CG, PARDISO,
CHOLMOD; the numpy assembly of bench/baseline.py), and over 60 consecutive steps of the hanging
cloth (work the engine can reuse across steps is counted).

Each test is one comparison row, its contenders timed interleaved in rounds (bench/interleave.py):

* ``test_backward_euler_direct``: the direct solvers at one size: engine PARDISO (mixed precision:
  f32 factorisation refined in f64 to the tolerance; and ``pardiso-double``, f64 only, which
  answers the 1e-8 comparisons too) and Eigen LL^T, numpy + PARDISO (analysis
  once), ``pypardiso.spsolve``, CHOLMOD, and PARDISO's numeric factorisation + solve of the same
  matrix alone, in f64 (``pardiso-factor``: no assembly, no check) and with the engine's technique
  (``pardiso-factor-mixed``: f32 factorisation, f64 refinement to the same tolerance);
* ``test_backward_euler_iterative``: engine PCG, scipy CG and pyamg + CG at one tolerance;
* ``test_backward_euler_sequence``: 60 consecutive steps, engine PARDISO and numpy + PARDISO;
* ``test_membrane_direct``, ``test_membrane_iterative``: the same step of the cloth's mesh with a
  Baraff-Witkin membrane instead of springs and hinges (config.membrane_scene; the numpy assembly
  of bench/baseline.NumpyMembrane), the direct solvers and, at tol 1e-5, the iterative ones.

Every timed single step starts from the same state (config.cloth_start_state, reset outside the
clock) after one untimed step of the same contender (compilation, the pattern, PARDISO's symbolic
analysis: what a run does once per model).  Iterative solvers run at the relative residual tol
(1e-5 and 1e-8 in f64; in f32, which cannot reach 1e-5, the first of 1e-4, 3e-4, 1e-3 that it
reaches; recorded); the f64 direct solvers reach ~1e-13 whatever tol, the engine's PARDISO
(mixed precision) refines to the tolerance.  The peers are f64 and timed in the
2-thread f64 process only.  What every contender computes is checked in bench/test_correctness.py.
"""
import numpy as np
import pytest

from bench import config, traffic
from bench.baseline import NumpyCloth, NumpyMembrane
from bench.interleave import Contender, measure_row
from bench.peers import sparse as peers
from bench.timing import sync
from engine import runtime
from engine.fields import float_dtype
from engine.integrators import Stepper
from engine.solvers import pardiso_available

SIZES = config.sizes("implicit")
SEQ_SIZES = config.sizes("sequence")
DT = config.IMPLICIT_DT
TOLS = (1e-5, 1e-8)
# the largest cloth each contender is timed on, per profile, where one step takes seconds (measured
# at 256^2: Eigen LL^T 17 s, PCG 16 s, pyamg 6 s; at 128^2 scipy CG 2-4 s): every contender of a row
# runs in every round
_SLOW = ("engine-cholesky", "peer-cholmod", "engine-pcg", "scipy", "peer-pyamg-cg")
MAX_SIDE = {"smoke": {}, "quick": {k: 64 for k in _SLOW}, "full": {k: 128 for k in _SLOW}}


def _membrane(c) -> bool:
    return isinstance(c, config.MembraneCloth)


def _info(c):
    side = int(round(np.sqrt(c.model.n)))
    if _membrane(c):
        return dict(side=side, n=c.model.n, triangles=c.membrane.n_elements, dt=DT, E=config.CLOTH_E,
                    model=config.MEMBRANE_MODEL)
    return dict(side=side, n=c.model.n, m=c.springs.m, h=c.bending.n_hinges, dt=DT, E=config.CLOTH_E,
                model="springs+bending")


def _baseline(c):
    """The numpy model of the scene: NumpyCloth (springs + hinges) or NumpyMembrane."""
    return NumpyMembrane(c.model, c.membrane) if _membrane(c) else NumpyCloth(c.model, c.springs, c.bending)


def _peers_here() -> str | None:
    """None when the sparse peers are timed in this process, else why not."""
    if config.config_name() != "t2-f64" and config.profile() != "smoke":
        return "the peers are timed in the 2-thread f64 process only"
    return None


def _too_big(impl, side):
    cap = MAX_SIDE[config.profile()].get(impl)
    if cap is not None and side > cap:
        return f"not timed above {cap}^2 (one step takes seconds; every round would run it)"
    return None


def _engine(c, solver, tol, steps=1):
    """A Contender for the engine's backward Euler with ``solver`` (None and the reason when it
    cannot run here)."""
    impl = "engine-" + solver
    if solver.startswith("pardiso") and not pardiso_available():
        return None, "MKL PARDISO not installed (pip install -e '.[fast]')"
    fp = runtime.current().fp
    if fp == 32 and tol != TOLS[0]:
        return None, "f32 cannot reach 1e-8"
    if fp == 32 and solver == "pardiso-double":
        return None, "the f64-only PARDISO row is timed in the f64 processes"
    x0, v0 = config.cloth_start_state(c)
    st = c.model.make_state(x0, v0)

    def reset():
        st.assign(x0, v0, 0.0)
    reset.state = st
    if solver == "pardiso-double":   # the engine's PARDISO in f64 only: ~1e-13, so it answers every tolerance
        from engine.solvers import PardisoSolver
        solver = PardisoSolver(TOLS[0] if tol is None else tol, 100000, precision="double")
    be, tol, failed = config.backward_euler_for(c.model, reset, DT, solver, fp, tol=tol)
    if be is None:
        return None, f"{solver} reached none of the relative tolerances {failed} in f32"

    stepper = Stepper(c.model, be)  # the solver's pattern and analysis are made at the first (untimed) call

    def run():
        for _ in range(steps):
            stepper.advance(st, DT)
        sync()

    def after():
        d = dict(linear_iterations=int(stepper.last_info.linear_iterations[0]))
        d.update({k + "_s": float(v) for k, v in getattr(stepper.solver, "last_timings", {}).items()})
        return d

    info = dict(solver=be.solver.name, tol=tol, tol_failed=failed)
    if be.solver.name == "pardiso":
        info["precision"] = be.solver.precision
    if info["solver"] == "pcg" and not _membrane(c):   # the traffic model counts springs and hinges
        fb = np.dtype(float_dtype()).itemsize
        i = _info(c)
        info["bytes_per_iteration"] = traffic.kernel_bytes("cg_iteration", i["n"], i["m"], i["h"], fb)
    return Contender(impl, run, setup=reset, after=after, info=info), None


def _peer(c, impl, tol, steps=1):
    name = "scipy-cg" if impl == "scipy" else impl[len("peer-"):]
    reason = peers.available(name)
    if reason:
        return None, reason
    base = _baseline(c)
    x0, v0 = config.cloth_start_state(c)
    if name in ("pardiso-factor", "pardiso-factor-mixed"):
        precision = "mixed" if name.endswith("mixed") else "double"
        f = peers.FactorOnly(base, x0, v0, DT, precision=precision, tol=tol)
        after = (lambda: {"residual": f.last["residual"], "linear_iterations": f.last["iterations"]}) \
            if precision == "mixed" else None
        return Contender(impl, f.run, after=after,
                         info=dict(solver="pardiso", precision=precision, tol=tol, library_only=True)), None
    peer = peers.SparsePeer(name, base, tol=tol)
    x, v = x0.copy(), v0.copy()

    def reset():
        x[...] = x0
        v[...] = v0

    def run():
        for _ in range(steps):
            peer.step(x, v, DT)

    def after():
        d = {k: peer.last[k] for k in ("assembly_s", "setup_s", "solve_s", "residual")}
        d["linear_iterations"] = int(peer.last["iterations"])
        return d
    info = dict(solver=name, tol=tol)
    if name in peers.REANALYSES:
        info["note"] = peers.REANALYSES[name]
    return Contender(impl, run, setup=reset, after=after, info=info), None


def _row(c, wanted, tol, steps=1):
    """The contenders of a row that can run here, and the reasons for those left out."""
    side = int(round(np.sqrt(c.model.n)))
    out, left = [], {}
    for impl in wanted:
        why = _too_big(impl, side)
        if why is None and not impl.startswith("engine-"):
            why = _peers_here()
        if why is None:
            if impl.startswith("engine-"):
                cont, why = _engine(c, impl[len("engine-"):], tol, steps)
            else:
                cont, why = _peer(c, impl, tol, steps)
        if why is None:
            out.append(cont)
        else:
            left[impl] = why
    return out, left


def _pcg_traffic(row, info):
    """The traffic model of a whole PCG step (the report's floor column), from its iterations."""
    r = row.get("engine-pcg")
    if r:
        fb = np.dtype(float_dtype()).itemsize
        it = int(r["info"].get("linear_iterations", 0))
        r["info"]["bytes"] = traffic.implicit_step_bytes(info["n"], info["m"], info["h"], it, fb)


DIRECT = ("engine-pardiso", "engine-pardiso-double", "engine-cholesky", "peer-pardiso", "peer-pardiso-factor", "peer-pardiso-factor-mixed",
          "peer-pardiso-spsolve", "peer-cholmod")
ITERATIVE = ("engine-pcg", "scipy", "peer-pyamg-cg")


@pytest.mark.parametrize("side", SIZES)
def test_backward_euler_direct(benchmark, side):
    """The direct solvers for the same cloth and step, interleaved in rounds."""
    c = config.cloth_scene(side, True)
    contenders, left = _row(c, DIRECT, TOLS[0])
    if not contenders:
        pytest.skip("; ".join(f"{k}: {v}" for k, v in left.items()))
    row = measure_row(benchmark, contenders, group="cloth-implicit-step", budget="direct", left_out=left,
                      row="direct", **_info(c))
    _check(row)


@pytest.mark.parametrize("tol", TOLS)
@pytest.mark.parametrize("side", SIZES)
def test_backward_euler_iterative(benchmark, side, tol):
    """The iterative solvers for the same cloth and step at relative residual ``tol``, interleaved."""
    c = config.cloth_scene(side, True)
    contenders, left = _row(c, ITERATIVE, tol)
    if not contenders:
        pytest.skip("; ".join(f"{k}: {v}" for k, v in left.items()))
    info = _info(c)
    row = measure_row(benchmark, contenders, group="cloth-implicit-step", budget="iterative", left_out=left,
                      warmup=1, row="iterative", tol=tol, **info)
    _pcg_traffic(row, info)
    _check(row)


def _check(row):
    for impl, r in row.items():
        res = r["info"].get("residual")
        if res is not None:
            assert res <= max(1e-5, r["info"].get("tol") or 0.0) * 1.0001, (impl, res)
        assert len(r["round_s"]) >= 1 and all(t > 0 for t in r["round_s"])


SEQ_STEPS = 60


@pytest.mark.parametrize("side", SEQ_SIZES)
def test_backward_euler_sequence(benchmark, side):
    """60 consecutive steps of the hanging cloth from the start state (the matrix changes from step
    to step as the cloth moves; what an engine keeps between steps counts), tol 1e-5, engine
    PARDISO and numpy + PARDISO interleaved.  (PCG and pyamg take 10x longer per step in the
    single-step rows: three rounds of 60 of their steps would take minutes.)"""
    steps = SEQ_STEPS if config.profile() != "smoke" else 2
    c = config.cloth_scene(side, True)
    if runtime.current().fp == 32:
        pytest.skip("the sequence is timed in f64")
    contenders, left = _row(c, ("engine-pardiso", "peer-pardiso"), TOLS[0], steps)
    if not contenders:
        pytest.skip("; ".join(f"{k}: {v}" for k, v in left.items()))
    for k in contenders:
        k.after = None   # the split of the last of 60 steps means little
    row = measure_row(benchmark, contenders, group="cloth-implicit-sequence", budget="sequence", steps=steps,
                      left_out=left, warmup=1, warm=False, tol=TOLS[0], **_info(c))
    _check(row)


def _membrane_row(benchmark, side, wanted, kind, tol):
    if config.config_name() != "t2-f64" and config.profile() != "smoke":
        pytest.skip("the membrane rows are timed in the 2-thread f64 process only (they are there for the peers)")
    c = config.membrane_scene(side)
    contenders, left = _row(c, wanted, tol)
    if not contenders:
        pytest.skip("; ".join(f"{k}: {v}" for k, v in left.items()))
    extra = dict(warmup=1, tol=tol) if kind == "iterative" else {}
    row = measure_row(benchmark, contenders, group=config.MEMBRANE_IMPLICIT_GROUP, budget=kind, left_out=left, row=kind,
                      **extra, **_info(c))
    _check(row)


@pytest.mark.parametrize("side", SIZES)
def test_membrane_direct(benchmark, side):
    """The direct solvers for one step of the Baraff-Witkin membrane (config.membrane_scene), the
    peers assembling it in numpy (bench/baseline.NumpyMembrane), interleaved in rounds."""
    _membrane_row(benchmark, side, ("engine-pardiso", "engine-cholesky", "peer-pardiso", "peer-pardiso-spsolve",
                                    "peer-cholmod"), "direct", TOLS[0])


@pytest.mark.parametrize("side", SIZES)
def test_membrane_iterative(benchmark, side):
    """The iterative solvers for the same membrane step at relative residual 1e-5, interleaved."""
    _membrane_row(benchmark, side, ITERATIVE, "iterative", TOLS[0])
