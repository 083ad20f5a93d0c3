"""The explicit peers (bench/peers: Numba and Warp-on-CPU versions of the engine's symplectic-Euler
cloth step) compute what the engine computes, and their timed bodies.

Correctness (always run, small cloths): each peer's forces equal the engine's ``Model.forces`` and
its steps the engine's symplectic-Euler steps, with and without bending, in float64 (relative 1e-12)
and float32 (see :func:`_f32_force_bound` for what float32 can resolve).  The peers' own packages
are optional: without numba or warp their tests are skipped with the reason.

They are timed beside the engine, interleaved in the same rounds, in bench/test_bench_explicit.py.
"""
import numpy as np
import pytest

from bench import config, peers
from engine.fields import float_dtype, vec3_ndarray
from engine.integrators import Stepper, get as integrator

MISSING = {name: peers.missing(name) for name in peers.PACKAGES}
PEERS = [pytest.param(name, id=name, marks=pytest.mark.skipif(MISSING[name] is not None,
                                                               reason=MISSING[name] or ""))
         for name in ("numba", "warp")]
EPS32 = float(np.finfo(np.float32).eps)
DT = 1e-5  # the engine body's dt (bench/test_bench_explicit.py)


@pytest.fixture
def engine_f64():
    """The correctness checks compare with the engine in float64 (an ELASTIC_FP=32 run times only)."""
    if np.dtype(float_dtype()) != np.float64:
        pytest.skip("the peers' checks compare with the engine in float64; this run has ELASTIC_FP=32")


_peer = peers.explicit_peer


def _engine_forces(c, x):
    f = vec3_ndarray(c.model.n)
    c.model.forces(vec3_ndarray(c.model.n, x), f)
    return f.to_numpy()


def _random_state(c, seed=0, amp=0.01):
    """X + 1 cm of noise: strains of ~10-20% on these cloths, bent hinges."""
    return c.model.X + amp * np.random.default_rng(seed).standard_normal((c.model.n, 3))


def _f32_force_bound(c, bending):
    """Per-vertex bound on a float32 force's round-off, (n,): 4 eps32 sum_{e ~ i} c_e/L_e.

    Why: the spring force is (c/L)(1 - L/l)(x_i - x_j); float32 resolves the strain l/L - 1 only to
    ~eps32, so each incident spring contributes ~eps32 c_e/L_e of round-off (measured: at most 0.7 of
    the bound's eps32 sum c/L).  Relative to max |f| that is ~eps32/strain: 1.2e-5 at the bench's start
    state (0.5% stretch), above 1e-5, while a 10% strain gives ~1e-7.  The hinge and weight terms carry
    relative eps32 of forces far below the springs' (B = 1e-4 N m)."""
    a = peers.cloth_arrays(c.model, c.springs, c.bending if bending else None, np.float64)
    per_vertex = np.add.reduceat(a["inc_c_over_L"], a["offsets"][:-1])
    per_vertex[np.diff(a["offsets"]) == 0] = 0.0
    return 4.0 * EPS32 * per_vertex


# -- forces ---------------------------------------------------------------------------------------

@pytest.mark.parametrize("bending", [True, False], ids=["springs+bending", "springs"])
@pytest.mark.parametrize("side", [8, 16])
@pytest.mark.parametrize("peer", PEERS)
def test_peer_forces_equal_engine_forces(peer, side, bending, engine_f64):
    c = config.cloth_scene(side, bending)
    x_start, _ = config.cloth_start_state(c)
    for x in (x_start, _random_state(c)):
        # float64: the same formulas in the same order as the engine, so round-off only
        ref = _engine_forces(c, x)
        got = _peer(peer, c, bending, np.float64).forces(x)
        assert got.dtype == np.float64
        assert np.max(np.abs(got - ref)) <= 1e-12 * np.max(np.abs(ref)), (peer, side, bending)
        # float32, against the engine (float64) at the same float32-rounded positions
        x32 = x.astype(np.float32)
        ref = _engine_forces(c, x32.astype(np.float64))
        got = _peer(peer, c, bending, np.float32).forces(x32)
        assert got.dtype == np.float32
        err = np.max(np.abs(got.astype(np.float64) - ref), axis=1)
        assert np.all(err <= _f32_force_bound(c, bending) + 4.0 * EPS32 * np.max(np.abs(ref), axis=1)), \
            (peer, side, bending, float(np.max(err)))
        assert np.max(err) > 1e-9 * np.max(np.abs(ref)), "the float32 peer computes in float64"
        if x is not x_start:  # strains of ~10%: float32 meets relative 1e-5 (see _f32_force_bound)
            assert np.max(err) <= 1e-5 * np.max(np.abs(ref)), (peer, side, bending)


def test_peer_bending_forces_are_the_engines_hinge_forces(engine_f64):
    """The bending part alone (the forces above are dominated by the springs): peer forces with and
    without bending differ by the engine's bending forces."""
    avail = [p.values[0] for p in PEERS if MISSING[p.values[0]] is None]
    if not avail:
        pytest.skip("; ".join(m for m in MISSING.values() if m))
    c = config.cloth_scene(8, True)
    x = _random_state(c, seed=3)
    ref = c.bending.forces(x)
    assert np.max(np.abs(ref)) > 0
    for name in avail:
        with_b = _peer(name, c, True, np.float64).forces(x)
        without = _peer(name, c, False, np.float64).forces(x)
        got = (with_b - without)[c.model.free]
        r = ref[c.model.free]
        # the spring part (~1e3 larger) cancels in the difference: round-off of the totals remains
        scale = np.max(np.abs(with_b))
        assert np.max(np.abs(got - r)) <= 1e-12 * scale, name
        assert np.max(np.abs(got - r)) <= 1e-6 * np.max(np.abs(r)), name


# -- steps ----------------------------------------------------------------------------------------

@pytest.mark.parametrize("bending", [True, False], ids=["springs+bending", "springs"])
@pytest.mark.parametrize("peer", PEERS)
def test_peer_steps_equal_engine_steps(peer, bending, engine_f64):
    c = config.cloth_scene(16, bending)
    x0, v0 = config.cloth_start_state(c)
    dt = 1e-4
    for n_steps in (1, 3):
        st = c.model.make_state(x0, v0)
        Stepper(c.model, integrator("symplectic-euler")).step(st, dt, n_steps)
        ref = st.numpy()
        x, v = x0.copy(), v0.copy()
        _peer(peer, c, bending, np.float64).step(x, v, dt, n_steps)
        moved = np.max(np.abs(ref.x - x0))
        assert moved > 0 and np.max(np.abs(ref.v - v0)) > 0
        assert np.max(np.abs(x - ref.x)) <= 1e-12 * moved, (peer, n_steps)
        assert np.max(np.abs(v - ref.v)) <= 1e-12 * np.max(np.abs(ref.v)), (peer, n_steps)
        assert np.all(x[c.model.pinned] == x0[c.model.pinned]) and np.all(v[c.model.pinned] == 0.0)
    # float32, one step from the float32-rounded state: the velocity is off by at most the force bound
    # times dt/m plus its own storage round-off, the position by dt times that plus its storage round-off
    x32, v32 = x0.astype(np.float32), v0.astype(np.float32)
    st = c.model.make_state(x32.astype(np.float64), v32.astype(np.float64))
    Stepper(c.model, integrator("symplectic-euler")).step(st, dt, 1)
    ref = st.numpy()
    _peer(peer, c, bending, np.float32).step(x32, v32, dt, 1)
    assert x32.dtype == np.float32 and v32.dtype == np.float32
    inv_m = np.where(c.model.pinned, 0.0, 1.0 / c.model.mass)
    dv = dt * inv_m * (_f32_force_bound(c, bending) + 4 * EPS32 * np.max(np.abs(_engine_forces(c, ref.x)), axis=1))
    dv += 2 * EPS32 * np.max(np.abs(ref.v), axis=1)
    dx = dt * dv + 2 * EPS32 * np.max(np.abs(ref.x), axis=1)
    assert np.all(np.max(np.abs(v32 - ref.v), axis=1) <= dv), peer
    assert np.all(np.max(np.abs(x32 - ref.x), axis=1) <= dx), peer


@pytest.mark.skipif(MISSING["numba"] is not None, reason=MISSING["numba"] or "")
def test_numba_peer_is_deterministic_across_thread_counts():
    """Each vertex sums its own terms in a fixed order: one and two threads give the same bits."""
    from bench.peers.numba_cloth import NumbaCloth
    c = config.cloth_scene(16, True)
    x0, v0 = config.cloth_start_state(c)
    out = []
    for threads in (1, 2):
        x, v = x0.copy(), v0.copy()
        NumbaCloth(c.model, c.springs, c.bending, threads=threads).step(x, v, 1e-4, 3)
        out.append((x, v))
    assert np.array_equal(out[0][0], out[1][0]) and np.array_equal(out[0][1], out[1][1])


@pytest.mark.parametrize("peer", PEERS)
def test_peer_rejects_bad_input_in_one_line(peer, monkeypatch):
    c = config.cloth_scene(8, True)
    p = _peer(peer, c, True, np.float64)
    x, v = config.cloth_start_state(c)
    for args, word in (((x, v, -1.0), "dt"), ((x, v, float("nan")), "dt"), ((x[:3], v, 1e-4), "x"),
                       ((x, v, 1e-4, -1), "n_steps")):
        with pytest.raises(ValueError, match=word):
            p.step(*args)
    with pytest.raises(ValueError, match="dtype"):
        _peer(peer, c, True, np.int32)
    if peer == "numba":
        monkeypatch.setenv("ELASTIC_THREADS", "zero")
        with pytest.raises(ValueError, match=r"ELASTIC_THREADS must be an integer in 1\.\.\d+ \(got 'zero'\)"):
            _peer(peer, c, True, np.float64)


# -- the membrane (bench/peers/warp_membrane.py) -----------------------------------------------------

@pytest.mark.skipif(MISSING["warp"] is not None, reason=MISSING["warp"] or "")
def test_warp_membrane_forces_and_steps_equal_the_engines(engine_f64):
    """The Baraff-Witkin membrane written in Warp: -grad W equals the engine's MembraneEnergy forces
    at a strained state, and its symplectic-Euler steps the engine's (float64, relative 1e-12)."""
    from bench.peers.warp_membrane import WarpMembrane
    c = config.membrane_scene(16)
    peer = WarpMembrane(c.model, c.membrane, np.float64)
    x = _random_state(c)
    ref = c.membrane.forces(x)
    assert np.max(np.abs(peer.elastic_forces(x) - ref)) <= 1e-12 * np.max(np.abs(ref))
    x0, v0 = config.cloth_start_state(c)
    for n_steps in (1, 3):
        st = c.model.make_state(x0, v0)
        Stepper(c.model, integrator("symplectic-euler")).step(st, 1e-4, n_steps)
        want = st.numpy()
        xs, vs = x0.copy(), v0.copy()
        peer.step(xs, vs, 1e-4, n_steps)
        moved = np.max(np.abs(want.x - x0))
        assert moved > 0
        assert np.max(np.abs(xs - want.x)) <= 1e-12 * moved
        assert np.max(np.abs(vs - want.v)) <= 1e-12 * np.max(np.abs(want.v))
