"""Runs are right on every backend and precision they accept, and refused up front elsewhere.

* A rod run whose energy overflows to +inf is a blow-up at that step, bound or not (in-process).
* ELASTIC_FP=32: the lessons refuse it (exit 2, one line naming ELASTIC_FP, nothing written);
  the engine paths the benchmarks time in f32 still run and still catch a blow-up.
* --arch vulkan (where a Vulkan device exists: Mesa's lavapipe on CI machines): the rod's physics
  is the CPU's (every integrator against its modal theory, a pulse at c, a blow-up at its step,
  across the launches the device's loop limit forces), and the lessons that cannot run there are
  refused with the reason. Skipped, with that reason, only where no Vulkan device exists.
"""
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from engine.errors import BlowUpError
from engine.scenes import Rod

ROOT = Path(__file__).resolve().parents[2]
NO_DEVICE = 77  # exit code of the vulkan probe script where Taichi finds no Vulkan device


def _python(code: str, cwd, **env) -> subprocess.CompletedProcess:
    full = dict(os.environ, PYTHONPATH=str(ROOT), **env)
    for name in ("ELASTIC_ARCH", "TI_ARCH", "ELASTIC_FP"):
        if name not in env:
            full.pop(name, None)
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], cwd=cwd, env=full, capture_output=True,
                          text=True, timeout=300)


def _lessons(args, cwd, **env) -> subprocess.CompletedProcess:
    return _python(f"import sys; from lessons.app.cli import main; sys.exit(main({list(args)!r}))", cwd, **env)


# ------------------------------------------------------------------------------ blow-ups


def test_energy_overflowing_to_inf_without_a_bound_is_a_blow_up_at_that_step():
    """At nu = 1.0001 the top mode grows by 1.06 per step; the rod is linear, so its positions
    stay finite while its energy overflows to +inf (after about 13000 steps from 1e-9 m of noise).
    Without an energy bound the run used to go on for all 20000 steps (displacements of 1e236 m);
    now it stops at the first step whose total is not finite."""
    rod = Rod.uniform(101)
    rng = np.random.default_rng(7)
    st = rod.new_state(1e-9 * rng.standard_normal(rod.n))
    dt = 1.0001 * rod.h[0]
    with pytest.raises(BlowUpError, match="is not finite") as info:
        rod.run(st, dt, 20_000)
    exc = info.value
    with np.errstate(over="ignore"):
        E = exc.kinetic + exc.potential
    assert exc.kinetic.size == exc.step + 1 < 20_000
    assert not np.isfinite(E[-1]) and np.all(np.isfinite(E[:-1]))  # the first non-finite step
    assert st.t == pytest.approx((exc.step + 1) * dt, rel=1e-12)  # the state stopped there
    assert np.all(np.isfinite(st.positions()))


def test_blow_up_across_chunks_counts_the_steps_of_the_run():
    """A run continued in chunks (step_offset) reports the step from the run's start."""
    rod = Rod.uniform(101)
    st = rod.new_state(1e-9 * np.random.default_rng(3).standard_normal(rod.n))
    dt = 1.5 * rod.h[0]
    done = 0
    with pytest.raises(BlowUpError) as info:
        while True:
            rod.run(st, dt, 50, step_offset=done)
            done += 50
    assert info.value.step >= done and info.value.kinetic.size == info.value.step - done + 1


# ------------------------------------------------------------------------------ precision


def test_lessons_refuse_f32_up_front(tmp_path):
    r = _lessons(["run", "springs", "--results", "out.json", "--record", "rec.rrd"], tmp_path, ELASTIC_FP="32")
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "ELASTIC_FP=32" in lines[0] and "f64" in lines[0] and "ELASTIC_FP=64" in lines[0]
    assert list(tmp_path.iterdir()) == []  # nothing written
    assert "experiments" not in r.stdout


def test_the_benchmarks_f32_paths_still_run_and_catch_blow_ups(tmp_path):
    """bench's t2-f32 configuration sets ELASTIC_FP=32 and times engine kernels (it runs no lesson):
    the rod still steps in f32, and its blow-up check uses f32's largest float as the bound."""
    r = _python("""
        import json, numpy as np
        from engine import runtime
        info = runtime.init()
        from engine.errors import BlowUpError
        from engine.scenes import Rod
        rod = Rod.uniform(101)
        st = rod.new_state(0.05 * np.sin(np.pi * rod.p))
        K, W = rod.run(st, 0.25 * rod.h[0], 800)
        blew = None
        try:
            rod.run(rod.new_state(1e-6 * np.random.default_rng(0).standard_normal(101)), 1.5 * rod.h[0], 5000)
        except BlowUpError as exc:
            blew = exc.step
        print(json.dumps(dict(fp=info.fp, dtype=str(st.x.to_numpy().dtype), drift=float(np.ptp(K + W) / (K + W)[0]),
                              blew=blew)))
    """, tmp_path, ELASTIC_FP="32")
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout.strip().splitlines()[-1])
    assert out["fp"] == 32 and out["dtype"] == "float32"
    rod = Rod.uniform(101)  # the same run in f64, in this process
    K, W = rod.run(rod.new_state(0.05 * np.sin(np.pi * rod.p)), 0.25 * rod.h[0], 800)
    # symplectic Euler's energy wobble (1.55e-2 of E) is the f64 one; f32 round-off of the strains
    # (1e-7 / h = 1e-5 against strains of 0.15) moves it by about 1e-4 of itself
    assert out["drift"] == pytest.approx(float(np.ptp(K + W) / (K + W)[0]), rel=2e-3)
    assert out["blew"] is not None and out["blew"] < 5000


# ------------------------------------------------------------------------------ vulkan

VULKAN_ROD = """
    import json, math, sys
    import numpy as np
    from engine import runtime
    try:
        runtime.init(arch="vulkan")
    except runtime.RuntimeConfigError as exc:
        print(exc, file=sys.stderr)
        sys.exit(%d)
    from engine.errors import BlowUpError
    from engine.scenes import Rod, backend_name, rod_max_nodes, serial_loop_limit
    from engine.theory.schemes import ModalReference
    out = dict(backend=backend_name(), limit=serial_loop_limit(), max_nodes=rod_max_nodes())
    rng = np.random.default_rng(8)
    h = rng.uniform(0.5, 1.5, 1000)
    p = np.concatenate([[0.0], np.cumsum(h)]) / h.sum()
    rod = Rod(p, rng.uniform(0.5, 2.0, 1000), rng.uniform(0.5, 2.0, 1000), pinned=(0,))
    u0, v0 = 1e-3 * rng.standard_normal(rod.n), 1e-3 * rng.standard_normal(rod.n)
    u0[0] = v0[0] = 0.0
    dt = 0.8 * rod.stable_dt()
    errors = {}
    for method in ("forward-euler", "symplectic-euler", "velocity-verlet", "backward-euler"):
        st = rod.new_state(u0, v0)
        rod.run(st, dt, 60, method)
        ref = ModalReference(rod, u0, v0, dt, method)
        u = ref.displacement(60)
        errors[method] = float(np.max(np.abs(st.displacement(rod) - u)) / np.max(np.abs(u)))
    out["modal_errors"] = errors
    out["dtype"] = str(rod.new_state(u0).x.to_numpy().dtype)
    uni = Rod.uniform(1001)
    hh, sigma, A = uni.h[0], 10 * uni.h[0], 1e-3
    g = A * np.exp(-0.5 * ((uni.p - 0.25) / sigma) ** 2)
    st = uni.new_state(g, (uni.p - 0.25) / sigma ** 2 * g)  # moving right at c = 1
    uni.run(st, 0.5 * hh, 800)
    u = st.displacement(uni)
    k = int(np.argmax(u))
    out["peak"] = float(np.dot(uni.p[k - 3:k + 4], u[k - 3:k + 4]) / u[k - 3:k + 4].sum())
    out["t"] = st.t
    st = uni.new_state(1e-9 * rng.standard_normal(uni.n))
    try:
        uni.run(st, 1.5 * hh, 5000)
        out["blow_up"] = None
    except BlowUpError as exc:
        E = exc.kinetic + exc.potential
        out["blow_up"] = dict(step=exc.step, n=int(E.size), last_finite=bool(np.isfinite(E[-1])),
                              before_finite=bool(np.all(np.isfinite(E[:-1]))))
    print(json.dumps(out))
""" % NO_DEVICE


@pytest.fixture(scope="module")
def vulkan_rod(tmp_path_factory):
    r = _python(VULKAN_ROD, tmp_path_factory.mktemp("vulkan"))
    if r.returncode == NO_DEVICE:
        pytest.skip(f"no Vulkan device here: {r.stderr.strip()[:200]}")
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout.strip().splitlines()[-1])


def test_vulkan_rod_physics_is_the_cpus(vulkan_rod):
    out = vulkan_rod
    assert out["backend"] == "vulkan" and out["dtype"] == "float64"  # f64, as reported
    if out["limit"] is not None:  # lavapipe: 65535 loop iterations per kernel, so 11 steps per launch here
        assert out["max_nodes"] >= 1001
    for method, err in out["modal_errors"].items():  # 60 steps: several launches on lavapipe
        assert err < 1e-11, (method, err)
    assert out["peak"] == pytest.approx(0.25 + out["t"], abs=1e-3)  # the pulse moved at c = 1 m/s
    b = out["blow_up"]
    assert b is not None and b["n"] == b["step"] + 1 and b["before_finite"]


def test_vulkan_refuses_the_lessons_it_cannot_run(tmp_path, vulkan_rod):
    r = _lessons(["run", "all", "--arch", "vulkan", "--no-record", "--results", "out.json"], tmp_path)
    assert r.returncode == 2, r.stderr
    line = r.stderr.strip()
    assert "\n" not in line and "--arch vulkan cannot run springs, area-springs, bending, explicit-vs-implicit" in line
    assert "atan2" in line and "sparse solver" in line and "rod-waves alone" in line
    assert list(tmp_path.iterdir()) == []
    if vulkan_rod["limit"] is not None:
        too_long = str(vulkan_rod["max_nodes"] + 1)
        r = _lessons(["run", "rod-waves", "--arch", "vulkan", "--nodes", too_long, "--no-record"], tmp_path)
        assert r.returncode == 2 and f"--nodes must be <= {vulkan_rod['max_nodes']}" in r.stderr
