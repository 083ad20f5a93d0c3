"""Long runs: 10^5 explicit steps of the 64 x 64 cloth keep memory flat and compile nothing new.

A fresh process builds the hanging cloth of engine/scenes.cloth (64 x 64 vertices, area springs
+ notes bending + gravity, two pinned corners) and takes 10^5 symplectic-Euler steps at 0.9x the
engine's CFL estimate with the engine integrator's ``step(model, state, dt, 1000)``, in chunks.
After every chunk it records:

- the resident memory, VmRSS from /proc/self/status;
- the number of compiled kernel instances: Taichi 1.7.4 keeps every ``@ti.kernel`` as a
  ``taichi.lang.kernel_impl.Kernel`` in ``impl.get_runtime().kernels``, and each one holds a
  dict ``compiled_kernels`` with one entry per specialisation it has compiled (materialised);
  their total count rises exactly when something is (re)compiled;
- the total energy (the run must stay physical, not merely alive).

Asserted: after a warm-up of 5 chunks the RSS grows by less than 5%; no kernel is compiled after
the first chunk; the energy stays finite and within 1e-3 of m g L (total weight times the cloth
size) of its start (symplectic Euler's energy error is bounded, it does not drift).
"""
import json
import os
import subprocess
import sys

from tests.helpers import ROOT

SCRIPT = r"""
import json, sys, time
from engine import runtime
runtime.init()
from taichi.lang import impl
from engine import diagnostics, scenes
from engine.integrators import Stepper, make_integrator, stable_dt_estimate

N_STEPS, CHUNK = int(sys.argv[1]), int(sys.argv[2])


def rss_kb():
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return int(line.split()[1])


def compiled():
    kernels = impl.get_runtime().kernels
    return len(kernels), sum(len(k.compiled_kernels) for k in kernels)


cloth = scenes.cloth(64)
model = cloth.model
state = model.make_state()
dt = 0.9 * stable_dt_estimate(model)
stepper = Stepper(model, make_integrator("symplectic-euler"))  # one stepper for the run: it plans once
energy = lambda: diagnostics.kinetic_energy(model, state) + model.potential_energy(state.x)
E0 = energy()
rows = [dict(steps=0, rss_kb=rss_kb(), kernels=compiled(), energy=E0, seconds=0.0)]
t0 = time.perf_counter()
done = 0
while done < N_STEPS:
    stepper.step(state, dt, CHUNK)
    done += CHUNK
    rows.append(dict(steps=done, rss_kb=rss_kb(), kernels=compiled(), energy=energy(),
                     seconds=time.perf_counter() - t0))
weight = float(model.mass[model.free].sum()) * 9.81
print(json.dumps(dict(dt=dt, n=model.n, weight=weight, rows=rows)))
"""

N_STEPS, CHUNK, WARM_CHUNKS = 100_000, 1000, 5


def test_hundred_thousand_cloth_steps_keep_memory_flat_and_compile_nothing_new():
    env = dict(os.environ, PYTHONPATH=str(ROOT), ELASTIC_CACHE_DIR=str(ROOT / ".ti_cache"))
    r = subprocess.run([sys.executable, "-c", SCRIPT, str(N_STEPS), str(CHUNK)], cwd=ROOT, env=env,
                       capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout.strip().splitlines()[-1])
    rows = out["rows"]
    assert out["n"] == 64 * 64 and rows[-1]["steps"] == N_STEPS

    # memory: flat after the warm-up
    base = rows[WARM_CHUNKS]["rss_kb"]
    peak = max(row["rss_kb"] for row in rows[WARM_CHUNKS:])
    growth = peak / base - 1.0
    print(f"\nsoak: {N_STEPS} steps in {rows[-1]['seconds']:.1f} s; RSS {rows[0]['rss_kb'] / 1024:.1f} MiB at "
          f"start, {base / 1024:.1f} MiB after warm-up, peak {peak / 1024:.1f} MiB (growth {100 * growth:.2f}%); "
          f"kernels/compiled instances {rows[1]['kernels']} after the first chunk, {rows[-1]['kernels']} at the end")
    assert growth < 0.05, [row["rss_kb"] for row in rows]

    # compilation: everything the loop needs is compiled during the first chunk, nothing after
    after_first = rows[1]["kernels"]
    assert all(row["kernels"] == after_first for row in rows[1:]), [row["kernels"] for row in rows]

    # the run stayed physical: bounded energy error, no drift
    scale = out["weight"] * 1.0  # m g L, L = 1 m
    E0 = rows[0]["energy"]
    worst = max(abs(row["energy"] - E0) for row in rows)
    print(f"soak: energy error at most {worst:.3g} J ({worst / scale:.2e} m g L)")
    assert worst <= 1e-3 * scale
