"""Stages 2 and 3 of ``explicit-vs-implicit``, what backward Euler costs and what it buys (their
narratives are in narrative.md): a mode's numerical damping and each method's order of accuracy
(stage 2), and the wall-clock per simulated second over a sweep of stiffnesses with where implicit
starts to pay (stage 3). Stage 1, the CFL limit, is in :mod:`.stages`; the cloth's modes, the
watched backward-Euler integrator, the drawings and the estimates of each stage's time are in
:mod:`.scene`.

Every run of this lesson is fixed: each claim is about one particular integrator, so
``--integrator/--solver/--tol`` leave them alone. numpy is used for set-up, eigen-analysis and
the reference formulas.
"""
import math
import time

import numpy as np

from engine import diagnostics
from engine.analysis import fit_slope
from engine.errors import BlowUpError
from engine.integrators import make_integrator
from engine.stability import lambda_max_power
from lessons.views import RunView
from engine.scenes import cloth

from .._framework import Experiment
from .._measure import edge_strain, vertex_strain
from .._scene import simulate
from .scene import Watched, announce, cloth_logger, draw_cost_curves, free_modes, timings_table

EXPLICIT_CHUNK = 50            # stage 3: explicit steps per timed launch (about a 60 fps frame's at 3e-4 s)


# ------------------------------------------------------------------------- stage 2

def stage_accuracy(ctx):
    announce(ctx, 2)
    return _mode_damping(ctx) + _convergence_orders(ctx)


def _mode_damping(ctx):
    """One in-plane eigenmode of a small cloth without gravity, three backward-Euler steps with
    Newton converged: the energy factor per step against 1/(1 + w^2 dt^2), w dt from 0.1 to 30."""
    cfg = ctx.cfg
    exps = []
    scene = cloth(cfg.mode_n, 1.0, E=cfg.E, rho=cfg.rho, B=cfg.B, gravity=0.0)
    model, X = scene.model, scene.model.X
    w, _, shapes = free_modes(model, X, planar=True)
    order = np.argsort(w)
    low, mid, top = order[0], order[len(order) // 2], order[-1]
    which = {low: "slowest", mid: "middle", top: "fastest"}
    amplitude = 1e-6
    cases = [(low, 0.1), (low, 1.0), (mid, 0.3), (mid, 3.0), (top, 30.0)]
    gain = 0.05 / amplitude  # the mode drawn 5 cm out of shape
    for mode, wdt in cases:
        dt = wdt / w[mode]
        u = shapes[mode] * (amplitude / np.abs(shapes[mode]).max())
        state = model.make_state(X + u)
        E0 = diagnostics.total_energy(model, state)  # the rest shape has zero energy (no gravity)
        be = make_integrator("backward-euler", solver="cholesky", tol=1e-12, newton_iterations=5, newton_tol=1e-12)
        theory = 1.0 / (1.0 + wdt * wdt)
        view = RunView(label=f"w dt = {wdt:g}, {which[mode]} mode ({mode}), drawn ×{gain:g}")
        steps, K, W = simulate(ctx, f"mode{mode}_wdt{wdt:g}", model, state, dt, 3, be, every=1, fixed=True,
                               log=cloth_logger(scene, float(np.abs(_vertex_strain(scene, X + u)).max()), gain),
                               view=view)
        factor = float(((K[-1] + W[-1]) / E0) ** (1.0 / 3.0))
        ctx.progress(f"mode {mode} (w = {w[mode]:.4g} rad/s), w dt = {wdt:g}: energy factor per step {factor:.6f}, "
                     f"theory {theory:.6f}; amplitude factor {math.sqrt(factor):.6f}")
        exps.append(Experiment(f"backward Euler: energy factor per step of a mode at w dt = {wdt:g} is "
                               "1/(1 + w^2 dt^2)", theory, factor, 1e-4, "rel", id=f"damping-wdt{wdt:g}"))
    return exps


def _vertex_strain(scene, x) -> np.ndarray:
    sp = scene.springs
    return vertex_strain(len(x), sp.edges_np, edge_strain(x, sp.edges_np, sp.L_np))


def _convergence_orders(ctx):
    """A small cloth falls from rest for conv_time: each method's final positions against a
    Richardson-extrapolated Verlet reference at three step sizes; the orders from the finest pair,
    and symplectic Euler from the half-step velocity against Verlet."""
    cfg = ctx.cfg
    scene = cloth(cfg.conv_n, 1.0, E=cfg.E, rho=cfg.rho, B=cfg.B)
    model, X = scene.model, scene.model.X
    T = cfg.conv_time
    dt_limit = 2.0 / math.sqrt(abs(lambda_max_power(model)))
    n0 = max(20, int(math.ceil(T / (0.3 * dt_limit))))  # coarsest level: dt <= 0.3 x the explicit limit
    levels = [n0, 2 * n0, 4 * n0]

    def run(name, integ, n_steps, v0=None):  # measurements only: nothing drawn
        state = model.make_state(X, v0)
        simulate(ctx, name, model, state, T / n_steps, n_steps, integ, every=n_steps, energy_every=n_steps,
                 fixed=True)
        return state.numpy().x

    ref_fine = run("reference_verlet_fine", "velocity-verlet", 8 * levels[-1])
    ref_coarse = run("reference_verlet_coarse", "velocity-verlet", 4 * levels[-1])
    ref = (4.0 * ref_fine - ref_coarse) / 3.0  # Richardson: removes Verlet's dt^2 term
    ref_err = float(np.abs(ref_fine - ref).max())
    errors, finals = {}, {}
    be = make_integrator("backward-euler", solver="cholesky", tol=1e-12, newton_iterations=20, newton_tol=1e-9)
    for name, integ in (("symplectic-euler", "symplectic-euler"), ("velocity-verlet", "velocity-verlet"),
                        ("backward-euler", be)):
        finals[name] = [run(f"{name}_N{n}", integ, n) for n in levels]
        errors[name] = [float(np.abs(x - ref).max()) for x in finals[name]]
    # symplectic Euler started half a step earlier: v0 - dt a(x0)/2, a(x0) = g on the free vertices at rest
    n = levels[-1]
    v_half = np.where(model.free[:, None], -0.5 * (T / n) * model.gravity[None, :], 0.0)
    x_shifted = run(f"symplectic-euler_half-step-start_N{n}", "symplectic-euler", n, v_half)
    same = float(np.abs(x_shifted - finals["velocity-verlet"][-1]).max()) / errors["velocity-verlet"][-1]
    orders = {}
    dts = T / np.asarray(levels, dtype=float)
    for name in errors:
        ratios = np.asarray(errors[name][:-1]) / np.asarray(errors[name][1:])
        orders[name] = math.log2(ratios[-1])  # from the two finest levels
        ctx.progress(f"{name}: dt = {', '.join(f'{d * 1e3:.3g}' for d in dts)} ms -> max position error "
                     f"{', '.join(f'{e:.3e}' for e in errors[name])} m "
                     f"(ratios {', '.join(f'{r:.3f}' for r in ratios)}), "
                     f"order {orders[name]:.3f} from the finest pair")
    ctx.progress(f"reference: Richardson correction {ref_err:.1e} m; symplectic Euler from the half-step velocity "
                 f"vs Verlet: {same:.1e} of Verlet's error")
    # the two runs agree in exact arithmetic; in f64 each of their n steps rounds the positions (|x| ~ 1 m) by
    # eps |x|, a random walk: their difference is good to about sqrt(n) eps max|x| (measured: 0.2-0.4 of that),
    # which on a stiff cloth (many small steps, a tiny Verlet error) can exceed 1e-6 of Verlet's error
    same_tol = max(1e-6, 4 * math.sqrt(n) * np.finfo(np.float64).eps * float(np.abs(x_shifted).max())
                   / errors["velocity-verlet"][-1])

    def pre_asymptotic(name):
        r = np.asarray(errors[name][:-1]) / np.asarray(errors[name][1:])
        return (f"not yet asymptotic: the error ratios per halving of dt are {', '.join(f'{q:.3f}' for q in r)} (an order "
                f"p gives 2^p), at w_max dt = {2 * dts[-2] / dt_limit:.2g} and {2 * dts[-1] / dt_limit:.2g} on the finest "
                "pair: the stiff modes the release excites are not resolved by these steps; a larger --rho or a softer "
                "--E (fewer, slower modes per step) brings the fast modes' share down")
    return [
        Experiment("backward Euler converges at first order in dt (log2 of the error ratio, finest halving)", 1.0,
                   orders["backward-euler"], 0.1, "abs", id="backward-euler-first-order",
                   reason=pre_asymptotic("backward-euler")),
        Experiment("symplectic Euler (from rest under gravity) converges at first order", 1.0,
                   orders["symplectic-euler"], 0.1, "abs", id="symplectic-euler-first-order",
                   reason=pre_asymptotic("symplectic-euler")),
        Experiment("velocity Verlet converges at second order", 2.0, orders["velocity-verlet"], 0.15, "abs",
                   id="velocity-verlet-second-order", reason=pre_asymptotic("velocity-verlet")),
        Experiment("symplectic Euler started from v0 - dt a(x0)/2 has Verlet's positions (difference / Verlet's "
                   "error)", 0.0, same, same_tol, "abs", id="half-step-start-is-verlet"),
        Experiment("the reference's Verlet run has 1/64 of the finest run's error (8x smaller dt, second order; "
                   "Richardson correction / finest error)", 1.0 / 64.0, ref_err / errors["velocity-verlet"][-1], 0.05,
                   "rel", id="reference-error-one-64th"),
    ]


# ------------------------------------------------------------------------- stage 3

def _crossover(Es, t_explicit, t_implicit):
    """E where the explicit/implicit cost ratio crosses 1 (log-linear interpolation), or None."""
    r = np.log(np.asarray(t_explicit) / np.asarray(t_implicit))
    logE = np.log(np.asarray(Es))
    for i in range(len(r) - 1):
        if r[i] < 0 <= r[i + 1] or r[i] >= 0 > r[i + 1]:
            f = r[i] / (r[i] - r[i + 1])
            return float(math.exp(logE[i] + f * (logE[i + 1] - logE[i])))
    return None


def stage_speed(ctx):
    cfg = ctx.cfg
    Es = np.geomspace(cfg.E_soft, cfg.E_stiff, cfg.E_values)
    rows, blown = [], []
    be_energy_excess = -math.inf
    for k, E in enumerate(Es):
        row, excess = _timed_runs(ctx, k, float(E), blown)
        rows.append(row)
        be_energy_excess = max(be_energy_excess, excess)
    steps_exp = np.array([r["steps_exp"] for r in rows])
    cg = np.array([r["cg_pcg"] for r in rows])
    slope_exp = fit_slope(np.log(Es), np.log(steps_exp))
    slope_cg = fit_slope(np.log(Es), np.log(cg))
    slope_cond = fit_slope(np.log(Es), np.log([r["sqrt_cond"] for r in rows]))
    summary = _crossovers(ctx, Es, rows, steps_exp, cg)
    ctx.progress(f"explicit steps per simulated second ~ E^{slope_exp:.3f}; PCG iterations per step ~ E^{slope_cg:.3f} "
                 f"(sqrt(1 + w_max^2 dt^2) ~ E^{slope_cond:.3f})")
    if ctx.rec.enabled:
        draw_cost_curves(ctx.rec, rows, cfg.frame_dt)
    ctx.result_notes.append("## Wall-clock per simulated second (timed on this run's machine; noisy)\n\n"
                            + timings_table(rows) + "\n\n" + "\n\n".join(summary)
                            + f"\n\nExplicit steps per simulated second ~ E^{slope_exp:.3f}; PCG iterations per step "
                              f"~ E^{slope_cg:.3f}; sqrt(1 + w_max^2 dt^2) ~ E^{slope_cond:.3f}.")
    return [
        Experiment(f"every timed run stayed bounded over the {cfg.frames} frames after the release (runs that "
                   "blew up)", 0, len(blown), 0, "abs", id="timed-runs-bounded"),
        Experiment("explicit steps per simulated second grow like E^(1/2) (log-log slope over the sweep)", 0.5,
                   slope_exp, 0.02, "rel", id="explicit-steps-grow-like-sqrt-e"),
        Experiment(f"backward Euler keeps dt = {cfg.frame_dt:.4g} s at every E: energy never exceeds the start "
                   "(largest excess over the sweep)", 0.0, be_energy_excess, 0, "<=", "J",
                   id="backward-euler-energy-bounded-at-every-e"),
        Experiment("PCG iterations per step grow with E (stiffest / softest)", 1.0, cg[-1] / cg[0], 0, ">=",
                   id="pcg-iterations-grow"),
        Experiment("PCG iterations per step grow no faster than sqrt(1 + w_max^2 dt^2), the square root of the "
                   "condition-number bound (log-log slopes over the sweep)", slope_cond, slope_cg, 0, "<=",
                   id="pcg-iterations-below-condition-bound"),
    ]


def _timed_runs(ctx, k: int, E: float, blown: list):
    """The k-th cloth of the sweep (modulus E), timed over the same frames after the release:
    symplectic Euler at 0.9 x its limit at rest, backward Euler (one Newton iteration) with pcg
    and with the fastest direct solver installed ("direct": MKL PARDISO, else Eigen's LL^T) at
    the frame step. Returns (the row of counts and times, backward Euler's
    largest energy excess over the start); runs that blew up are appended to ``blown``."""
    cfg = ctx.cfg
    window = cfg.frames * cfg.frame_dt  # every run covers the same simulated time from the same release
    scene = cloth(cfg.speed_n, 1.0, E=E, rho=cfg.rho, B=cfg.B)
    model, X = scene.model, scene.model.X
    dt_limit = 2.0 / math.sqrt(abs(lambda_max_power(model, rtol=1e-6)))
    E0 = diagnostics.total_energy(model, model.make_state(X))
    bound = E0 + float(model.mass.sum()) * float(np.linalg.norm(model.gravity)) * 1.0  # + weight x 1 m
    row = dict(E=E, sqrt_cond=math.sqrt(1.0 + (2.0 / dt_limit * cfg.frame_dt) ** 2))
    runs = [("symplectic", "symplectic-euler", 0.9 * dt_limit, int(math.ceil(window / (0.9 * dt_limit))))]
    runs += [(f"backward_euler_{solver}", Watched(make_integrator("backward-euler", solver=solver, tol=1e-8,
                                                                newton_iterations=1, max_iter=100000)),
              cfg.frame_dt, cfg.frames) for solver in ("pcg", "direct")]
    be_energy_excess = -math.inf
    for j, (label, integ, dt, n) in enumerate(runs):
        stamps = []
        state = model.make_state(X)
        name = f"E{E:.3g}_{label}"
        # explicit steps are timed in chunks of up to EXPLICIT_CHUNK steps, as a run between two
        # displayed frames takes them (one launch each); a backward-Euler step is one frame's step
        chunk = max(1, min(EXPLICIT_CHUNK, n // 20)) if j == 0 else 1
        try:
            # timed and measured only: nothing drawn (drawing would be timed with the steps)
            steps, K, W = simulate(ctx, name, model, state, dt, n, integ, every=chunk, energy_every=n,
                                   energy_bound=bound, fixed=True,
                                   observe=lambda s, st: stamps.append(time.perf_counter()))
        except BlowUpError as exc:
            blown.append(name)
            ctx.progress(f"{name}: {exc}")
            K = W = np.array([math.inf])
        # the first chunk (compilation, caches) left out
        per_step = float(np.median(np.diff(stamps[1:]))) / chunk if len(stamps) > 2 else math.nan
        row[f"t_{label}"] = per_step / dt  # wall-clock seconds per simulated second
        if j == 0:
            row.update(dt_exp=dt, steps_exp=1.0 / dt)
        else:
            be_energy_excess = max(be_energy_excess, float((K + W).max() - E0))
            row[f"cg_{label}"] = float(np.mean(integ.iterations)) if integ.iterations else math.nan
    row["t_exp"], row["t_pcg"], row["t_direct"] = (row["t_symplectic"], row["t_backward_euler_pcg"],
                                                   row["t_backward_euler_direct"])
    row["cg_pcg"] = row["cg_backward_euler_pcg"]
    row["direct_name"] = runs[2][1].solver.name
    ctx.progress(f"E = {E:.3g} N/m: explicit dt {row['dt_exp'] * 1e6:.1f} us, {row['steps_exp']:.0f} steps/s, "
                 f"{row['t_exp']:.2f} s per simulated s; backward Euler dt {cfg.frame_dt * 1e3:.2f} ms: pcg "
                 f"{row['cg_pcg']:.0f} CG iterations/step, {row['t_pcg']:.2f} s per simulated s; "
                 f"{row['direct_name']} {row['t_direct']:.2f} s per simulated s")
    return row, be_energy_excess


def _crossovers(ctx, Es, rows, steps_exp, cg) -> list[str]:
    """Where implicit stepping becomes cheaper than explicit: in wall-clock per solver, and in
    sweeps over the mesh per simulated second (explicit: one force evaluation per step; PCG: one
    Hessian product per CG iteration plus one force evaluation per step). Printed; returned as text."""
    cfg = ctx.cfg
    count_cross = _crossover(Es, steps_exp, (cg + 1.0) / cfg.frame_dt)
    summary = []
    best = [min(r["t_pcg"], r["t_direct"]) for r in rows]
    for solver, times in (("pcg", [r["t_pcg"] for r in rows]), (rows[0]["direct_name"], [r["t_direct"] for r in rows]),
                          ("the faster of the two", best)):
        cross = _crossover(Es, [r["t_exp"] for r in rows], times)
        if cross is None:
            faster = "backward Euler" if times[0] < rows[0]["t_exp"] else "symplectic Euler"
            text = (f"backward Euler ({solver}) vs symplectic Euler on the {cfg.speed_n}^2 cloth: no crossover in "
                    f"the sweep ({faster} faster throughout)")
        else:
            text = (f"backward Euler ({solver}) vs symplectic Euler on the {cfg.speed_n}^2 cloth: wall-clock "
                    f"crossover at E ~ {cross:.3g} N/m (explicit cheaper below, implicit above)")
        summary.append(text)
        ctx.progress(text)
    counts = ("in sweeps over the mesh per simulated second (explicit: 1 per step; PCG: 1 per CG iteration + 1 per "
              "step) the crossover is " + (f"at E ~ {count_cross:.3g} N/m" if count_cross else "outside the sweep"))
    summary.append(counts)
    ctx.progress(counts)
    return summary
