"""The stages of ``bending`` that put the energy to work in structures (their narratives are in
narrative.md): a hanging cloth whose folds coarsen as B grows (stage 4) and a curved shell that
keeps its shape and springs back (stage 5), with the static solves and runs only they make. The
stages that measure the energy itself (1 to 3) are in :mod:`.stages`; the cloth's and the shell's
builders and drawings are in :mod:`.scene`.
"""
import math

import numpy as np

from engine.constants import G
from engine.energies.bending import BendingEnergy
from engine.integrators import make_integrator
from lessons.views import RunView
from engine.scenes import cloth
from engine.statics import solve_static

from .._framework import Experiment
from .._scene import simulate
from .scene import ENERGY_KEY, Shell, displacement_logger, log_static, mesh_logger


# ------------------------------------------------------------------------- stage 4

def fold_count(mesh3d, energy: BendingEnergy, x, n, threshold=0.1) -> list:
    """Runs of one sign of theta on the vertical edges crossing three horizontal lines."""
    X, H = mesh3d.vertices, mesh3d.hinges
    d = X[H[:, 1]] - X[H[:, 0]]
    vertical = np.abs(d[:, 0]) < 1e-9 * np.linalg.norm(d, axis=1)
    z_mid = 0.5 * (X[H[:, 0], 2] + X[H[:, 1], 2])
    h = (X[:, 2].max() - X[:, 2].min()) / (n - 1)
    theta = energy.angles(x)
    counts = []
    for frac in (0.25, 0.5, 0.75):
        z = X[:, 2].min() + (round(frac * (n - 1) - 0.5) + 0.5) * h
        idx = np.flatnonzero(vertical & (np.abs(z_mid - z) < 1e-6 * h))
        t = theta[idx[np.argsort(X[H[idx, 0], 0])]]
        t = t[np.abs(t) > threshold * np.abs(t).max()]
        counts.append(int(np.count_nonzero(np.sign(t[1:]) != np.sign(t[:-1]))) + 1)
    return counts


CLOTHS = ("soft", "mid", "stiff")  # the sweep B/10, B, 10 B, in the experiments' ids


def stage_cloth(ctx):
    cfg = ctx.cfg
    exps, folds = [], []
    Bs = (cfg.cloth_B / 10, cfg.cloth_B, cfg.cloth_B * 10)
    for k, B in enumerate(Bs):
        scene, res = _fall_and_settle(ctx, k, B)
        exps.append(Experiment(f"B = {B:.3g}: static equilibrium reached (residual)", cfg.static_tol, res.residual,
                               0, "<=", id=f"cloth-{CLOTHS[k]}-equilibrium",
                               reason="" if res.converged else f"the static solve stopped: {res.message}"))
        if not res.converged:
            ctx.progress(f"B = {B:.3g}: {res.message}")
        steps = int(round(1.0 / cfg.dt))
        if ctx.rec.enabled:  # the equilibrium drawn over the fall's last frame
            log_static(ctx, f"B = {B:.3g} N m: static equilibrium after {res.iterations} Newton iterations", res.x,
                       ctx.rec.colors(scene.bending.energy_density(res.x), "magnitude", ENERGY_KEY),
                       scene.mesh.triangles, steps + 1, steps * cfg.dt)
        count = fold_count(scene.mesh, scene.bending, res.x, cfg.cloth_n)
        folds.append(float(np.mean(count)))
        ctx.progress(f"B = {B:.3g} N m: folds along the three lines {count}, Newton {res.iterations} iterations, "
                     f"residual {res.residual:.2e}")
        if k == 1:
            exps += _pin_reactions(cfg, scene.model, res, B)
    labels = [f"{B:.3g}" for B in Bs]
    exps += [
        Experiment(f"folds at B = {labels[0]} >= folds at B = {labels[1]} (mean over three lines)", folds[1], folds[0],
                   0, ">=", id="folds-soft-vs-mid"),
        Experiment(f"folds at B = {labels[1]} >= folds at B = {labels[2]}", folds[2], folds[1], 0, ">=",
                   id="folds-mid-vs-stiff"),
        Experiment(f"folds at B = {labels[0]} exceed those at B = {labels[2]} by at least one", folds[2] + 1, folds[0],
                   0, ">=", id="folds-soft-exceed-stiff"),
    ]
    return exps


def _fall_and_settle(ctx, k: int, B: float):
    """The k-th cloth of the sweep (bending modulus B) falls for a second from a squeezed, rumpled
    flat start under backward Euler (fixed to it when --integrator names an explicit method), then
    Newton finds the static equilibrium nearby. Returns (scene, the static solve)."""
    cfg = ctx.cfg
    n = cfg.cloth_n
    steps = int(round(1.0 / cfg.dt))
    explicit = ctx.integrator_name("backward-euler") != "backward-euler"  # an explicit --integrator
    scene = cloth(n, 1.0, E=cfg.cloth_E, rho=cfg.cloth_rho, B=B, variant=cfg.bending)
    model, X = scene.model, scene.model.X
    rng = np.random.default_rng(cfg.seed)
    x0 = X.copy()
    x0[:, 0] = 0.5 + (X[:, 0] - 0.5) * cfg.cloth_gap
    x0[model.free, 1] += 1e-3 * rng.standard_normal(int(model.free.sum()))
    state = model.make_state(x0)
    integ = make_integrator("backward-euler", solver="cholesky")
    if explicit and k == 0:
        ctx.progress(f"the falls are damped relaxations: they stay backward Euler under --integrator "
                     f"{ctx.stepping.integrator} (fixed)")
    # one colour scale for the sweep: 1/2 B k^2 at the middle B for a fold of radius 1/k = its bending
    # length (B/(rho g))^(1/3) (about 0.07 J/m^2 at the defaults)
    B_mid = cfg.cloth_B
    scale = 0.5 * B_mid / (B_mid / (cfg.cloth_rho * G)) ** (2.0 / 3.0)
    # a 1 s fall under backward Euler, then Newton's static equilibrium (marked); no energy plot: the fall is
    # a damped relaxation, not a motion we measure
    view = RunView(label=f"cloth, B = {B:.3g} N m", camera="front", energy=None)
    simulate(ctx, f"cloth_B{B:.3g}", model, state, cfg.dt, steps, integ, every=cfg.record_every,
             log=mesh_logger(scene.mesh.triangles, scene.bending, scale), fixed=explicit, view=view)
    res = solve_static(model, state.x.to_numpy().astype(np.float64), tol=cfg.static_tol,
                       max_iter=newton_cap(cfg), raise_on_failure=False)
    return scene, res


def newton_cap(cfg) -> int:
    """Newton steps allowed for a cloth's static solve: 400 up to the default stiffness against weight
    E/(rho g L) (1019), then growing like its square root. The steps a stiff sheet needs grow with it
    (measured for the softest cloth of the sweep: 103 steps at 1019, 786 at 1.0e5, about its 0.44th
    power), so the fixed cap of 400 made --cloth-E 1e5 fail; this one keeps 5x headroom there."""
    stiffness = cfg.cloth_E / (cfg.cloth_rho * G)
    return int(400 * max(1.0, math.sqrt(stiffness / (1e3 / (0.1 * G)))))


def _pin_reactions(cfg, model, res, B):
    """The hooks carry the weight (the sum of the pin reactions), up to the free vertices' residual
    forces: at most (free vertices) x tol x (largest vertex weight)."""
    weight = float(model.mass.sum()) * G
    free_w = float(model.mass[model.free].max()) * G
    bound = int(model.free.sum()) * cfg.static_tol * free_w / weight
    R = res.reactions.sum(axis=0)
    return [
        Experiment(f"B = {B:.3g}: vertical pin reactions / total weight (bound: N tol m_max g / W)",
                   1.0, R[2] / weight, bound, "abs", id="cloth-mid-vertical-reactions"),
        Experiment(f"B = {B:.3g}: horizontal pin reactions cancel (|R_x, R_y| / W)", 0.0,
                   float(np.hypot(R[0], R[1])) / weight, bound, "abs", id="cloth-mid-horizontal-reactions"),
    ]


# ------------------------------------------------------------------------- stage 5

def stage_shell(ctx):
    cfg = ctx.cfg
    shell = Shell(cfg)
    exps = _rest_shape(cfg, shell)
    solves = []
    exps += _linear_response(ctx, shell, solves)
    # the push, then the release (a run without load: backward Euler unless --integrator says otherwise)
    model, energy = shell.under(cfg.push * G)
    pushed = solve_static(model, tol=cfg.static_tol, max_iter=200, raise_on_failure=False)
    solves.append(pushed)
    stopped = [r.message for r in solves if not r.converged]
    push_d = float(np.linalg.norm(pushed.x - shell.X, axis=1).max()) / shell.R
    exps += [
        Experiment("static solves (weight, 2x weight, push) reached the tolerance (max residual)", cfg.static_tol,
                   max(r.residual for r in solves), 0, "<=", id="static-solves-converged",
                   reason=f"a static solve stopped: {stopped[0]}" if stopped else ""),
        Experiment(f"the push ({cfg.push:g} x weight) deforms visibly (max displacement / R)", 1e-2, push_d, 0, ">=",
                   id="push-deforms"),
    ]
    return _release(ctx, shell, pushed.x, push_d, exps)


def _rest_shape(cfg, shell: Shell):
    """With rest angles from the curved mesh the rest shape carries no force; with theta_bar = 0
    the bending energy pushes it."""
    model, energy = shell.under(G)
    vertex_weight = float(shell.masses[model.free].max()) * G
    rest_force = np.abs(energy.forces(shell.X)[model.free]).max() / vertex_weight
    flat_rest = BendingEnergy.from_mesh(shell.mesh, cfg.shell_B, cfg.bending)
    flat_force = np.abs(flat_rest.forces(shell.X)[model.free]).max() / vertex_weight
    return [
        Experiment("rest angles from the curved mesh: no force at rest (max |f| / vertex weight)", 0.0, rest_force,
                   1e-9, "abs", id="curved-rest-no-force"),
        Experiment("with theta_bar = 0 the rest shape is pushed (max bending |f| / vertex weight)", 1.0, flat_force,
                   0, ">=", id="flat-rest-pushes"),
    ]


def _linear_response(ctx, shell: Shell, solves: list):
    """The shell under its own weight and twice it: a small displacement, the pins carry the
    weight, and twice the load gives twice the displacement (the static solves go to ``solves``).
    Drawn with the displacement magnified, both on the scale of the larger one."""
    cfg = ctx.cfg
    exps, d, shapes = [], [], []
    for factor in (1.0, 2.0):
        model, energy = shell.under(factor * G)
        res = solve_static(model, tol=cfg.static_tol, max_iter=200, raise_on_failure=False)
        solves.append(res)
        d.append(float(np.linalg.norm(res.x - shell.X, axis=1).max()))
        shapes.append(res.x)
        if factor == 1.0:
            weight = float(shell.masses.sum()) * G
            vertex_weight = float(shell.masses[model.free].max()) * G
            bound = int(model.free.sum()) * cfg.static_tol * vertex_weight / weight
            exps += [
                Experiment("own weight: max displacement / radius is small", 1e-2, d[0] / shell.R, 0, "<=",
                           id="own-weight-small-displacement"),
                Experiment("own weight: pin reactions / total weight (bound: N tol m_max g / W)", 1.0,
                           res.reactions[:, 2].sum() / weight, bound, "abs", id="own-weight-pin-reactions"),
            ]
    exps.append(Experiment("twice the weight gives twice the displacement (ratio)", 2.0, d[1] / d[0], 3e-2, "rel",
                           id="linear-response"))
    ctx.progress(f"displacements {d[0]:.3e} m, {d[1]:.3e} m (ratio {d[1] / d[0]:.4f})")
    if ctx.rec.enabled:
        gain = float(f"{0.1 * shell.R / d[1]:.1g}")  # twice the weight drawn 10% of R out of shape
        for factor, x, dmax in zip((1.0, 2.0), shapes, d):
            ctx.rec.run(f"weight_x{factor:g}", RunView(label=f"{'own' if factor == 1 else 'twice its'} weight, "
                                                             f"displacement ×{gain:g}", energy=None))
            u = np.linalg.norm(x - shell.X, axis=1)
            log_static(ctx, f"weight x{factor:g}: max displacement {dmax:.3g} m", shell.X + gain * (x - shell.X),
                       ctx.rec.colors(u, "magnitude", "displacement (m)", d[1]), shell.mesh.triangles, 0, 0.0)
    return exps


def _release(ctx, shell: Shell, x_pushed, push_d, exps):
    """Release the pushed shell without load for 2 s (a scene run: backward Euler unless
    --integrator says otherwise). Backward Euler damps it back to rest; an explicit symplectic
    method keeps the push's energy, and the shell oscillates about its rest shape (virial
    theorem). Returns ``exps`` with those experiments."""
    cfg = ctx.cfg
    X, masses = shell.X, shell.masses
    free_model, _ = shell.under(0.0)
    state = free_model.make_state(x_pushed)
    steps = int(round(2.0 / cfg.dt))
    W0 = free_model.potential_energy(state.x)
    method = ctx.integrator_name("backward-euler")
    motion = np.zeros(2)  # explicit methods: sums of M|x - X|^2 and M|v|^2 over the sampled steps

    def observe(step, st):
        if step:
            motion[0] += float((masses[:, None] * (st.x.to_numpy() - X) ** 2).sum())
            motion[1] += float((masses[:, None] * st.v.to_numpy() ** 2).sum())

    view = RunView(label=f"{cfg.push:g}x push, released ({method})")
    _, kin, pot = simulate(ctx, "release", free_model, state, cfg.dt, steps,
                           make_integrator("backward-euler", solver="cholesky"), every=cfg.record_every,
                           observe=None if method == "backward-euler" else observe,
                           log=displacement_logger(shell.mesh.triangles, X, push_d * shell.R), energy_bound=10 * W0,
                           view=view)
    back = float(np.abs(state.x.to_numpy() - X).max()) / shell.R
    ctx.progress(f"push: max displacement {push_d:.3e} R; {steps * cfg.dt:g} s after the release: {back:.2e} R")
    if method == "backward-euler":
        exps.append(Experiment("2 s after the release the shell is back at rest (max |x - X| / R)", 1e-6, back, 0,
                               "<=", id="release-back-at-rest"))
        return exps
    drift = float(np.abs(kin + pot - W0).max()) / W0
    virial = float(kin.mean() / pot.mean())
    ctx.progress(f"{method}: energy {W0:.4g} J at the release, largest deviation {drift:.2e} of it; mean kinetic / "
                 f"mean elastic energy {virial:.4f} ({len(kin)} samples); rms frequency of the motion "
                 f"sqrt(<M v^2>/<M u^2>) = {math.sqrt(motion[1] / motion[0]):.4g} rad/s")
    exps += [
        Experiment(f"{method} does not damp: total energy after the release = the push's elastic energy "
                   f"(max |E - W0| / W0)", 0.0, drift, 1e-2, "abs", id="release-keeps-energy"),
        Experiment(f"{method}: the shell oscillates about its rest shape: mean kinetic / mean elastic energy = 1 "
                   f"(virial theorem)", 1.0, virial, 5e-2, "rel", id="release-virial"),
    ]
    return exps
