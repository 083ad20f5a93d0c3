"""Timed: one backward-Euler cloth step (Baraff-Witkin: one Newton iteration, no line search) at
dt = 1/60 s with the engine's solvers (PCG, Eigen's LL^T "cholesky", MKL PARDISO "pardiso"),
against what a user installs with pip (bench/peers/sparse.py: scipy CG, pyamg + CG, PARDISO,
CHOLMOD; the numpy assembly into a precomputed pattern of bench/baseline.py), and over 60
consecutive steps of the hanging cloth (work the engine can reuse across steps is counted).

Every timed single step starts from the same state (config.cloth_start_state, reset outside the
clock).  Iterative solvers run at the relative residual tol (1e-5 and 1e-8 in f64; in f32, which
cannot reach 1e-5, the first of 1e-4, 3e-4, 1e-3 that it reaches; recorded); direct solvers reach
~1e-13 whatever tol, so they are timed once.  The peers are f64 and timed in the 2-thread f64
process only.  What every contender computes is checked in bench/test_correctness.py.
"""
import numpy as np
import pytest

from bench import config, traffic
from bench.baseline import NumpyCloth
from bench.peers import sparse as peers
from bench.timing import measure, sync
from engine import runtime
from engine.fields import float_dtype
from engine.linalg import pardiso_available

SIZES = config.sizes("implicit")
SEQ_SIZES = config.sizes("sequence")
DT = config.IMPLICIT_DT
TOLS = (1e-5, 1e-8)
ENGINE = ("pcg", "cholesky", "pardiso")
ITERATIVE = {"engine-pcg", "scipy", "peer-pyamg-cg"}
PEER_IMPLS = ("scipy", "peer-pyamg-cg", "peer-pardiso", "peer-pardiso-spsolve", "peer-cholmod")
_seconds: dict = {}  # (impl, tol) -> {side: seconds per step}, to extrapolate the next size


def _info(c):
    return dict(side=int(round(np.sqrt(c.model.n))), n=c.model.n, m=c.springs.m, h=c.bending.n_hinges,
                dt=DT, E=config.CLOTH_E, model="springs+bending")


def _expect(impl, tol, side):
    done = _seconds.get((impl, tol), {})
    prev = max((k for k in done if k < side), default=None)
    return None if prev is None else done[prev] * (side / prev) ** 3  # pessimistic: iterations ~ side, work ~ side^2


def _skip_unless_t2_f64():
    if config.config_name() != "t2-f64" and config.profile() != "smoke":
        pytest.skip("the peers are timed in the 2-thread f64 process only")


@pytest.mark.parametrize("tol", TOLS)
@pytest.mark.parametrize("impl", ["engine-" + s for s in ENGINE] + list(PEER_IMPLS))
@pytest.mark.parametrize("side", SIZES)
def test_backward_euler_step(benchmark, side, impl, tol):
    """The engine's solvers and the peers for the same cloth, run back to back (adjacent in time,
    so that a shared machine's load changes little between them)."""
    if tol != TOLS[0] and impl not in ITERATIVE:
        pytest.skip("a direct solve reaches ~1e-13 whatever the tolerance: timed once, at tol 1e-5")
    if impl.startswith("engine-"):
        return _engine_step(benchmark, side, impl[len("engine-"):], tol)
    return _peer_step(benchmark, side, impl, tol)


def _engine_step(benchmark, side, solver, tol):
    if solver == "pardiso" and not pardiso_available():
        pytest.skip("MKL PARDISO not installed (pip install -e '.[fast]')")
    if runtime.current().fp == 32 and tol != TOLS[0]:
        pytest.skip("f32 cannot reach 1e-8")
    c = config.cloth_scene(side, True)
    x0, v0 = config.cloth_start_state(c)
    st = c.model.make_state(x0, v0)
    iters, split = [], []

    def reset():
        st.assign(x0, v0, 0.0)
    reset.state = st
    be, tol, failed = config.backward_euler_for(c.model, reset, DT, solver, runtime.current().fp, tol=tol)
    if be is None:
        pytest.skip(f"{solver} reached none of the relative tolerances {failed} in f32")

    def run():
        be.advance(c.model, st, DT)
        sync()
        iters.append(be.last_info.linear_iterations[0])
        split.append(getattr(be.solver, "last_timings", {}))

    info = _info(c)
    key = ("engine-" + solver, tol)
    # one warm-up step at every size: it compiles, and it does what the engine does once per model
    # (the pattern, the symbolic analysis), as each peer's first step outside the clock does
    measure(benchmark, run, setup=reset, group="cloth-implicit-step", impl="engine-" + solver, solver=solver,
            tol=tol, tol_failed=failed, expect_s=_expect(*key, side), warmup=1, **info)
    timed = benchmark.stats.stats.rounds if benchmark.stats else len(split)
    iters, split = iters[-timed:], split[-timed:]   # the timed rounds only, not the warm-up calls
    it = int(np.median(iters))
    benchmark.extra_info["linear_iterations"] = it
    if split and split[-1]:
        for k in ("assembly", "factorization", "solve"):
            benchmark.extra_info[k + "_s"] = float(np.median([s.get(k, 0.0) for s in split]))
    if solver == "pcg":
        fb = np.dtype(float_dtype()).itemsize
        benchmark.extra_info["bytes"] = traffic.implicit_step_bytes(info["n"], info["m"], info["h"], it, fb)
        benchmark.extra_info["bytes_per_iteration"] = traffic.kernel_bytes("cg_iteration", info["n"], info["m"],
                                                                           info["h"], fb)
    _seconds.setdefault(key, {})[side] = benchmark.stats.stats.median if benchmark.stats else 0.0
    assert np.all(np.isfinite(st.numpy().x))


def _peer_step(benchmark, side, impl, tol):
    _skip_unless_t2_f64()
    name = "scipy-cg" if impl == "scipy" else impl[len("peer-"):]
    reason = peers.available(name)
    if reason:
        pytest.skip(reason)
    cap = config.PEER_MAX_SIDE[config.profile()].get(name, 10 ** 9)
    if side > cap:
        pytest.skip(f"{name} not timed above {cap}^2 in this profile (one step takes too long)")
    c = config.cloth_scene(side, True)
    base = NumpyCloth(c.model, c.springs, c.bending)
    peer = peers.SparsePeer(name, base, tol=tol)
    x0, v0 = config.cloth_start_state(c)
    x, v = x0.copy(), v0.copy()
    split = []

    def reset():
        x[...] = x0
        v[...] = v0

    def run():
        peer.step(x, v, DT)
        split.append(dict(peer.last))

    reset()
    peer.step(x, v, DT)  # the pattern (and PARDISO's analysis) once, outside the clock, as the engine's
    key = (impl, tol)
    measure(benchmark, run, setup=reset, warmup=0, expect_s=_expect(*key, side) or sum(
        peer.last[k] for k in ("assembly_s", "setup_s", "solve_s")), group="cloth-implicit-step", impl=impl,
            solver=name, tol=tol, **_info(c))
    med = {k: float(np.median([s[k] for s in split])) for k in ("assembly_s", "setup_s", "solve_s", "residual")}
    benchmark.extra_info.update(med, linear_iterations=int(np.median([s["iterations"] for s in split])))
    _seconds.setdefault(key, {})[side] = med["assembly_s"] + med["setup_s"] + med["solve_s"]
    assert np.all(np.isfinite(x))


SEQ_STEPS = 60


@pytest.mark.parametrize("impl", ["engine-pardiso", "engine-pcg", "peer-pardiso", "peer-pyamg-cg"])
@pytest.mark.parametrize("side", SEQ_SIZES)
def test_backward_euler_sequence(benchmark, side, impl):
    """60 consecutive steps of the hanging cloth from the start state (the matrix changes from step
    to step as the cloth moves; what an engine keeps between steps counts), tol 1e-5."""
    steps = SEQ_STEPS if config.profile() != "smoke" else 2
    c = config.cloth_scene(side, True)
    x0, v0 = config.cloth_start_state(c)
    if impl.startswith("engine-"):
        solver = impl[len("engine-"):]
        if solver == "pardiso" and not pardiso_available():
            pytest.skip("MKL PARDISO not installed (pip install -e '.[fast]')")
        if runtime.current().fp == 32:
            pytest.skip("the sequence is timed in f64")
        st = c.model.make_state(x0, v0)

        def reset():
            st.assign(x0, v0, 0.0)
        reset.state = st
        be, tol, _ = config.backward_euler_for(c.model, reset, DT, solver, 64, tol=TOLS[0])
        be.advance(c.model, st, DT)  # compile and analyse outside the clock

        def run():
            for _ in range(steps):
                be.advance(c.model, st, DT)
            sync()
        final = lambda: st.numpy().x
    else:
        _skip_unless_t2_f64()
        name = impl[len("peer-"):]
        reason = peers.available(name)
        if reason:
            pytest.skip(reason)
        base = NumpyCloth(c.model, c.springs, c.bending)
        peer = peers.SparsePeer(name, base, tol=TOLS[0])
        x, v = x0.copy(), v0.copy()
        peer.step(x, v, DT)

        def reset():
            x[...] = x0
            v[...] = v0

        def run():
            for _ in range(steps):
                peer.step(x, v, DT)
        final = lambda: x
    measure(benchmark, run, setup=reset, warmup=0, expect_s=1e9, steps=steps, group="cloth-implicit-sequence",
            impl=impl, tol=TOLS[0], **_info(c))
    assert np.all(np.isfinite(final()))
