"""The headline: wall-clock seconds per simulated second, explicit against implicit, across an E
sweep from soft to cloth-stiff, for each cloth resolution; where the crossover lies.

For each resolution (the lessons' hanging cloth, engine.scenes.cloth, rho = 0.1 kg/m^2,
B = 1e-4 N m) and each stretching modulus E:

* explicit (symplectic Euler) at dt_exp = s x 2/sqrt(lambda_max), lambda_max of M^-1 H at the
  rest state by power iteration (engine.stability.lambda_max_power), with the safety
  factor s = engine.constants.CFL_SAFETY unless that run is unstable: ``n_check`` steps at
  dt_exp from the benchmark's start state must keep the total energy finite and bounded, else s
  drops by 0.1 (soft cloth stretches under its weight, which stiffens it transversally: its
  limit falls below the rest-state estimate).  The explicit step's cost does not depend on E
  (the same kernels), so it is timed once per resolution (launches of 50 steps, as a run between
  two displayed frames takes them) and divided by each dt_exp.
* backward Euler (one Newton iteration, no line search, PCG at rtol 1e-5 and the fastest direct
  solver installed: engine.solvers "direct", MKL PARDISO with the ``fast`` extra, else Eigen) at
  dt = 1/60 s and at the accuracy-matched dt (below); three consecutive steps are timed from the
  start state (bench.config.cloth_start_state), after one untimed step of the same integrator
  (the direct solver's pattern and symbolic analysis, once per model as in a run), and the median
  per-step cost is divided by dt.  PCG is not
  run where its predicted time per step (from the last E, iterations ~ sqrt(E)) exceeds a cap;
  that is recorded.

Cost per simulated second = (seconds per step) / dt: a few steps timed and scaled, not a full
simulated second.

Accuracy-matched dt.  Backward Euler multiplies the energy of a mode of angular frequency w by
1/(1 + w^2 dt^2) per step, so over one simulated second by (1 + w^2 dt^2)^(-1/dt).  The slowest
motion of the hanging cloth, the one a viewer sees, is the sheet swinging about the line through
its pins; for a sheet stiff enough not to stretch much it is a rigid square plate of side L
swinging about its top edge, w1 = sqrt(m g (L/2) / (m L^2/3)) = sqrt(3 g / (2 L)) (3.84 rad/s for
L = 1 m), independent of E.  The accuracy-matched dt is the largest dt for which backward Euler
removes at most ``ACCURACY_LOSS`` = 10% of that mode's energy per simulated second (about
7.2 ms).  Any other tolerance X scales it, to first order, by -ln(1 - X)/0.105 (and the implicit
cost per simulated second by the inverse).

    python -m bench.headline [--quick] [--json PATH] [--sides 32,64] [--E 10,100,...]
"""
import argparse
import math
import sys
import time

import numpy as np

from bench.output import emit_json
from engine.constants import CFL_SAFETY, G

ACCURACY_LOSS = 0.10
E_SWEEP = {"quick": [1e1, 1e2, 1e3, 1e4, 1e5],
           "full": [1e1, 3e1, 1e2, 3e2, 1e3, 3e3, 1e4, 3e4, 1e5]}
SIDES = {"quick": [32, 64], "full": [32, 64, 128]}
STEPS = {"quick": 3, "full": 3}           # timed backward-Euler steps per point (their median)
PCG_CAP_S = {"quick": 1.5, "full": 4.0}   # skip PCG where one step is predicted to take longer
DIRECT = "direct"                         # engine.solvers: PARDISO when installed, else Eigen's LL^T
CHECK_STEPS = {"quick": 200, "full": 500}


def pendulum_omega(size: float = 1.0, g: float = G) -> float:
    """w1 = sqrt(3 g / (2 L)): a uniform square plate of side L swinging about its top edge."""
    return math.sqrt(1.5 * g / size)


def energy_kept_per_second(omega: float, dt: float) -> float:
    """Fraction of a mode's energy backward Euler keeps over one simulated second,
    (1 + w^2 dt^2)^(-1/dt)."""
    return math.exp(-math.log1p((omega * dt) ** 2) / dt)


def accuracy_matched_dt(omega: float, loss: float = ACCURACY_LOSS) -> float:
    """Largest dt <= 1/omega with energy_kept_per_second(omega, dt) >= 1 - loss (bisection;
    the kept fraction decreases monotonically with dt on (0, 1/omega])."""
    lo, hi = 0.0, 1.0 / omega
    if energy_kept_per_second(omega, hi) >= 1.0 - loss:
        return hi
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if energy_kept_per_second(omega, mid) >= 1.0 - loss:
            lo = mid
        else:
            hi = mid
    return lo


def crossover(E, explicit, implicit):
    """E at which the explicit and implicit costs per simulated second are equal, by log-log
    interpolation between the sweep points around the first sign change of
    log(explicit/implicit); (E, description)."""
    pts = [(e, a, b) for e, a, b in zip(E, explicit, implicit) if a and b and a > 0 and b > 0]
    if len(pts) < 2:
        return None, "not enough points"
    r = [math.log(a / b) for _, a, b in pts]
    for k in range(len(pts) - 1):
        if r[k] == 0.0:
            return pts[k][0], "equal"
        if r[k] * r[k + 1] < 0:
            e0, e1 = math.log(pts[k][0]), math.log(pts[k + 1][0])
            t = r[k] / (r[k] - r[k + 1])
            winner_low = "explicit" if r[k] < 0 else "implicit"
            return math.exp(e0 + t * (e1 - e0)), f"{winner_low} cheaper below"
    if all(x < 0 for x in r):
        return None, f"explicit cheaper over the whole sweep (E = {pts[0][0]:g} .. {pts[-1][0]:g})"
    if all(x > 0 for x in r):
        return None, f"implicit cheaper over the whole sweep (E = {pts[0][0]:g} .. {pts[-1][0]:g})"
    return None, "no single crossover"


def _time_explicit(model, x0, v0, rounds=10, steps=50):
    """Seconds per explicit step, timed over launches of ``steps`` steps (as a run between two
    displayed frames takes them: 50 steps are a 60 fps frame at dt ~ 3e-4 s); the median of
    ``rounds``."""
    import taichi as ti

    from engine.integrators import Stepper
    st = model.make_state(x0, v0)
    se = Stepper(model, "symplectic-euler")
    for _ in range(3):  # untimed: the launch of this many steps compiled and bound for this model, caches warm
        se.step(st, 1e-6, steps)
    ti.sync()
    ts = []
    for _ in range(rounds):
        t = time.perf_counter()
        se.step(st, 1e-6, steps)
        ti.sync()
        ts.append((time.perf_counter() - t) / steps)
    return float(np.median(ts))


SAFETY = tuple(round(CFL_SAFETY - 0.1 * k, 2) for k in range(6))  # 0.9, 0.8, ..., 0.4


def _explicit_point(model, x0, v0, n_check):
    """dt_exp = s x 2/sqrt(lambda_max) with the largest safety factor s in SAFETY for which
    ``n_check`` steps from (x0, v0) keep the total energy finite and bounded."""
    from engine import diagnostics
    from engine.integrators import BlowUpError, run
    from engine.stability import lambda_max_power
    lam = lambda_max_power(model, iters=300, rtol=1e-6)
    scale = float(np.sum(model.mass)) * G * float(np.ptp(model.X[:, 2]) + 1.0)
    failed = []
    for s in SAFETY:
        dt = s * 2.0 / math.sqrt(lam)
        st = model.make_state(x0, v0)
        e0 = diagnostics.total_energy(model, st)
        try:
            run(model, st, dt, n_check, "symplectic-euler", energy_bound=e0 + 100.0 * max(abs(e0), scale),
                check_every=max(1, n_check // 20))
        except BlowUpError as exc:
            failed.append(dict(safety=s, blew_up_at_step=int(exc.step)))
            continue
        return dict(lambda_max=lam, safety=s, dt=dt, stable_check_steps=n_check, stable=True, failed=failed)
    return dict(lambda_max=lam, safety=SAFETY[-1], dt=SAFETY[-1] * 2.0 / math.sqrt(lam), stable_check_steps=n_check,
                stable=False, failed=failed)


def _implicit_point(model, x0, v0, dt, solver, steps):
    """Seconds per backward-Euler step at dt: the median of ``steps`` consecutive steps from the
    start state, after one untimed step from it with the same integrator (a run builds the
    pattern and does the direct solver's symbolic analysis once per model, not per step; for PCG it
    allocates the work arrays)."""
    import taichi as ti

    from engine.integrators import BackwardEuler, SolverError, Stepper
    be = BackwardEuler(solver=solver, tol=1e-5, newton_iterations=1, line_search=False, max_iter=200000)
    stepper = Stepper(model, be)
    st = model.make_state(x0, v0)
    ts, iters = [], []
    try:
        if solver != "pcg":   # PCG analyses nothing: its untimed step would only double its cost here
            stepper.advance(st, dt)
            ti.sync()
            st.assign(x0, v0, 0.0)
        for _ in range(steps):
            t = time.perf_counter()
            stepper.advance(st, dt)
            ti.sync()
            ts.append(time.perf_counter() - t)
            iters.append(stepper.last_info.linear_iterations[0])
    except SolverError as exc:
        return dict(error=str(exc))
    step_s = float(np.median(ts))
    return dict(step_s=step_s, steps_timed=len(ts), iterations=int(np.median(iters)), cost=step_s / dt,
                solver=be.solver.name)


def run_sweep(sides, E_values, steps, pcg_cap, n_check, log=print):
    from bench.config import CLOTH_B, CLOTH_RHO, cloth_start_state
    from engine.scenes import cloth
    # compile every path once outside the clock
    warm = cloth(8, E=1e3, rho=CLOTH_RHO, B=CLOTH_B)
    wx, wv = cloth_start_state(warm)
    _time_explicit(warm.model, wx, wv, rounds=1)
    _explicit_point(warm.model, wx, wv, 10)
    for solver in ("pcg", DIRECT):
        _implicit_point(warm.model, wx, wv, 1.0 / 60.0, solver, 1)
    omega = pendulum_omega(1.0)
    dts = {"1/60": 1.0 / 60.0, "accuracy": accuracy_matched_dt(omega)}
    out = dict(pendulum_omega=omega, accuracy_loss=ACCURACY_LOSS, dts=dts, E=list(E_values), sides={})
    for side in sides:
        t_side = time.perf_counter()
        c = cloth(side, E=1e3, rho=CLOTH_RHO, B=CLOTH_B)
        x0, v0 = cloth_start_state(c)
        # the median of three timings, each from a fresh state: one of them can land in a slow mode
        # (measured at 32^2: now and then a whole call runs at 3-6x, its cause not pinned down), which
        # a median over one call's rounds does not remove
        step_s = float(np.median([_time_explicit(c.model, x0, v0) for _ in range(3)]))
        res = dict(n=c.model.n, explicit_step_s=step_s, points=[])
        last_pcg = {k: None for k in dts}
        for E in E_values:
            c = cloth(side, E=E, rho=CLOTH_RHO, B=CLOTH_B)
            p = dict(E=E, explicit=_explicit_point(c.model, x0, v0, n_check))
            p["explicit"]["cost"] = step_s / p["explicit"]["dt"]
            p["implicit"] = {}
            for name, dt in dts.items():
                d = _implicit_point(c.model, x0, v0, dt, DIRECT, steps)
                r = {d.get("solver", DIRECT): d}
                prev = last_pcg[name]
                predicted = None if prev is None else prev[1] * math.sqrt(E / prev[0])
                if predicted is not None and predicted > pcg_cap:
                    r["pcg"] = dict(skipped=f"predicted {predicted:.1f} s per step > cap {pcg_cap:g} s")
                else:
                    r["pcg"] = _implicit_point(c.model, x0, v0, dt, "pcg", steps)
                    if "step_s" in r["pcg"]:
                        last_pcg[name] = (E, r["pcg"]["step_s"])
                    else:
                        last_pcg[name] = (E, math.inf)
                ok = {k: v["cost"] for k, v in r.items() if "cost" in v}
                r["best"] = min(ok, key=ok.get) if ok else None
                r["best_cost"] = ok[r["best"]] if ok else None
                p["implicit"][name] = r
            res["points"].append(p)
            ex = p["explicit"]
            log(f"  headline {side}^2 E={E:g}: explicit {ex['cost']:.3g} s/s (dt {ex['dt']:.3g}), "
                + ", ".join(f"BE {k} {v['best_cost']:.3g} s/s ({v['best']})" if v["best_cost"] else f"BE {k} failed"
                            for k, v in p["implicit"].items()))
        res["crossover"] = {}
        for name in dts:
            E_c, how = crossover([p["E"] for p in res["points"]], [p["explicit"]["cost"] for p in res["points"]],
                                 [p["implicit"][name]["best_cost"] for p in res["points"]])
            res["crossover"][name] = dict(E=E_c, note=how)
        res["wall_s"] = time.perf_counter() - t_side
        out["sides"][str(side)] = res
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.headline",
                                 description="Explicit vs implicit cost per simulated second across an E sweep.")
    ap.add_argument("--quick", action="store_true", help="fewer resolutions, E values and steps")
    ap.add_argument("--json", help="write the result here (default: stdout)")
    ap.add_argument("--sides", help="comma list of cloth vertices per side")
    ap.add_argument("--E", help="comma list of stretching moduli (N/m)")
    args = ap.parse_args(argv)
    prof = "quick" if args.quick else "full"
    sides = [int(s) for s in args.sides.split(",")] if args.sides else SIDES[prof]
    E_values = [float(s) for s in args.E.split(",")] if args.E else E_SWEEP[prof]

    from engine import runtime
    runtime.init()
    t = time.perf_counter()
    out = run_sweep(sides, E_values, STEPS[prof], PCG_CAP_S[prof], CHECK_STEPS[prof],
                    log=lambda s: print(s, file=sys.stderr, flush=True))
    out["wall_s"] = time.perf_counter() - t
    out["profile"] = prof
    return emit_json(out, args.json)


if __name__ == "__main__":
    sys.exit(main())
