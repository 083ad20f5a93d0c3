"""The stages of ``bending`` (their narratives are in narrative.md) and what they measure; the
hinges, sheets, cylinders and the shell they measure on, and the drawings, are in :mod:`.scene`.

This file is longer than the suite's usual 500 lines: each of the five stages keeps the
measurement helpers only it uses next to it (stage 3 alone, about 150 lines, compares seven
regular meshes, their Discrete Shells variants and two jittered ones with the continuum).
"""
import math

import numpy as np

from engine import mesh as meshes
from engine.analysis import convergence_order, fit_slope
from engine.constants import G
from engine.energies.bending import BendingEnergy
from engine.integrators import make_integrator
from lessons.views import RunView
from engine.scenes import cloth
from engine.statics import solve_static

from .._framework import Experiment
from .._measure import per_hinge_fd, random_rotation
from .._scene import simulate
from .scene import (ENERGY_KEY, Shell, analytic_hinge, around, bridson_u, continuum_energy, displacement_logger,
                    draw_opening_hinge, edge_family_folds, log_sheet, log_static, mesh_logger, random_hinges, sheet,
                    theta_gradient)


# ------------------------------------------------------------------------- stage 1

def stage_hinge(ctx):
    cfg = ctx.cfg
    rng = np.random.default_rng(cfg.seed)
    theta_err = _analytic_angle_error()
    X, Xflat, H = random_hinges(rng, 12)
    grad_err, u_err = _gradient_errors(X, Xflat, H)
    energy = BendingEnergy(Xflat, H, 0.7, cfg.bending)
    f = energy.hinge_forces(X)
    f_fd = -per_hinge_fd(energy.hinge_energies, X)  # -dW/dx of the chosen variant, hinge by hinge
    force_err = np.linalg.norm(f - f_fd) / np.linalg.norm(f)
    net_f, net_tau = _net_force_and_torque(X[H], f)
    dW, df = _rigid_motion_errors(energy, X, f, rng)
    exps = [
        Experiment("theta of an analytic hinge over [-3.1, 3.1] rad (max |error|)", 0.0, theta_err, 1e-13, "abs",
                   "rad", id="theta-analytic-hinge"),
        Experiment("dtheta/dx equals central finite differences (rel. error, 12 random hinges)", 0.0, grad_err,
                   1e-7, "abs", id="theta-gradient-fd"),
        Experiment("Bridson's u1..u4 equal -dtheta/dx (max difference / max |grad|)", 0.0, u_err, 1e-13, "abs",
                   id="bridson-u-is-gradient"),
        Experiment(f"{cfg.bending} force equals -dW/dx by central differences (rel. error)", 0.0, force_err,
                   1e-7, "abs", id="force-is-energy-gradient"),
        Experiment("zero net force per hinge (max |sum f| / sum |f|)", 0.0, net_f, 1e-13, "abs", id="zero-net-force"),
        Experiment("zero net torque per hinge (max |sum x cross f| / sum |f||x|)", 0.0, net_tau, 1e-13, "abs",
                   id="zero-net-torque"),
        Experiment("rigid motion leaves the energy unchanged (max rel. change)", 0.0, dW, 1e-12, "abs",
                   id="rigid-motion-energy"),
        Experiment("rigid motion rotates the forces with the hinge (max rel. difference)", 0.0, df, 1e-12, "abs",
                   id="rigid-motion-force"),
    ]
    notes = BendingEnergy(analytic_hinge(0.0), np.array([[0, 1, 2, 3]]), 1.0, "notes")
    exps += _half_angle_experiments(notes)
    if ctx.rec.enabled:
        draw_opening_hinge(ctx.rec, notes)
    return exps


def _analytic_angle_error() -> float:
    """Max |theta - the built-in angle| of the analytic hinge over (-pi, pi)."""
    probe = BendingEnergy(analytic_hinge(0.0), np.array([[0, 1, 2, 3]]), 1.0)
    return max(abs(probe.angles(analytic_hinge(t))[0] - t) for t in np.linspace(-3.1, 3.1, 63))


def _gradient_errors(X, Xflat, H):
    """(the engine's dtheta/dx against central differences, Bridson's u against -dtheta/dx)."""
    probe = BendingEnergy(Xflat, H, 1.0)
    g = theta_gradient(X, H)
    g_fd = per_hinge_fd(probe.angles, X)
    u = bridson_u(X, H)
    return np.linalg.norm(g - g_fd) / np.linalg.norm(g), np.abs(u + g).max() / np.abs(g).max()


def _net_force_and_torque(xs, f):
    """Largest net force and net torque per hinge, relative to the sum of the |f| (and |f||x|)."""
    net_f = (np.linalg.norm(f.sum(axis=1), axis=1) / np.linalg.norm(f, axis=2).sum(axis=1)).max()
    lever = np.linalg.norm(xs - xs.mean(axis=1, keepdims=True), axis=2)
    net_tau = (np.linalg.norm(np.cross(xs, f).sum(axis=1), axis=1)
               / (np.linalg.norm(f, axis=2) * (np.linalg.norm(xs, axis=2) + lever)).sum(axis=1)).max()
    return net_f, net_tau


def _rigid_motion_errors(energy, X, f, rng):
    """Largest relative change of the energy, and of the forces against the rotated forces, over
    three random rigid motions."""
    W0 = energy.energy(X)
    dW, df = 0.0, 0.0
    for _ in range(3):
        Q, t = random_rotation(rng), 5.0 * rng.normal(size=3)
        Y = X @ Q.T + t
        dW = max(dW, abs(energy.energy(Y) - W0) / W0)
        df = max(df, np.abs(energy.hinge_forces(Y) - f @ Q.T).max() / np.abs(f).max())
    return dW, df


def _half_angle_experiments(notes):
    """The bridson variant's sin(theta/2) force against the notes' theta force at 0.5 and 1 rad (both
    from the engine), and the small-angle form of their ratio (an identity once the ratio holds)."""
    bridson = BendingEnergy(analytic_hinge(0.0), np.array([[0, 1, 2, 3]]), 1.0, "bridson")
    exps = []
    for th in (0.5, 1.0):
        x = analytic_hinge(th)
        fn, fb = notes.hinge_forces(x)[0], bridson.hinge_forces(x)[0]
        ratio = float((fb * fn).sum() / (fn * fn).sum())
        exps += [
            Experiment(f"theta = {th}: Bridson/notes force ratio equals 2 sin(theta/2)/theta",
                       2 * math.sin(th / 2) / th, ratio, 1e-12, "rel", id=f"bridson-ratio-theta{th}"),
            Experiment(f"theta = {th}: identity (Taylor, once the ratio above holds): that ratio is "
                       f"1 - theta^2/24 within theta^4/1920", 1 - th ** 2 / 24, ratio, th ** 4 / 1920, "abs",
                       id=f"bridson-ratio-series-theta{th}"),
        ]
    return exps


# ------------------------------------------------------------------------- stage 2

def _aligned_edges(flat, axis):
    """Hinges whose flat edge is parallel to the cylinder axis."""
    H = flat.hinges
    d = flat.vertices[H[:, 1]] - flat.vertices[H[:, 0]]
    return np.abs(d[:, around(axis)]) < 1e-9 * np.linalg.norm(d, axis=1)


def stage_curvature(ctx):
    exps = []
    for kind, label in (("grid", "right-triangle grid"), ("lattice", "equilateral lattice")):
        exps += _curvature_estimates(ctx, kind, label)
    exps.append(_energy_scaling(ctx.cfg))
    return exps


def _curvature_estimates(ctx, kind, label, levels=(9, 17, 33)):
    """theta/(h1 + h2) on the hinges along the axis of a sheet wrapped on the cylinder: with the
    bent hinge's (chord) heights, with the rest (arc) heights, the other hinges flat, and the
    chord heights' error order over three refinements."""
    cfg = ctx.cfg
    R = cfg.radius
    exps, chord_err, hs = [], [], []
    for n in levels:
        flat, axis = sheet(kind, n)
        wrapped = meshes.cylinder_wrap(flat, R, axis)
        energy = BendingEnergy(meshes.embed_3d(flat).vertices, flat.hinges, 1.0, cfg.bending)
        theta = energy.angles(wrapped.vertices)
        across = _aligned_edges(flat, axis)
        bent_h = meshes.hinge_heights(wrapped.vertices, flat.hinges).sum(axis=1)
        rest_h = energy.geometry["h0"] + energy.geometry["h1"]
        est_bent = theta[across] / bent_h[across]
        est_rest = theta[across] / rest_h[across]
        chord_err.append(float(np.abs(est_bent * 2 * R - 1).max()))
        hs.append(float(rest_h[across].mean() / 2))
        if n == levels[-1]:
            exps += [
                Experiment(f"{label}, n = {n}: theta/(h1+h2) with the bent hinge's heights -> 1/(2R)",
                           1 / (2 * R), float(est_bent.mean()), 1e-3, "rel", "1/m", id=f"{kind}-curvature-estimate"),
                Experiment(f"{label}, n = {n}: with the rest heights the estimate is exact (max rel. error)",
                           0.0, float(np.abs(est_rest * 2 * R - 1).max()), _rest_heights_tolerance(R, n), "abs",
                           id=f"{kind}-rest-heights-exact"),
                Experiment(f"{label}: the other hinges are flat (max |theta|)", 0.0,
                           float(np.abs(theta[~across]).max()), 1e-12, "abs", "rad", id=f"{kind}-other-hinges-flat"),
            ]
            variant = "" if cfg.bending == "notes" else f", {cfg.bending}"
            log_sheet(ctx, f"{kind}_n{n}", f"{label}, cylinder R = {R:g} m{variant}", wrapped.vertices,
                      flat.triangles, energy)
        phi = hs[-1] / (2 * R)
        ctx.progress(f"{label} n={n}: max error of theta/(h1+h2) (chord heights) {chord_err[-1]:.3e}, "
                     f"phi/sin(phi) - 1 = {phi / math.sin(phi) - 1:.3e}")
    exps.append(Experiment(f"{label}: chord-height estimate converges at order 2 in h", 2.0,
                           convergence_order(np.array(hs), np.array(chord_err)), 0.05, "abs", id=f"{kind}-chord-order"))
    return exps


def _rest_heights_tolerance(R: float, n: int) -> float:
    """Round-off of the exact estimate: theta ~ h/R is a second difference of positions of size R
    (h = 1/(n - 1) the spacing), so its relative round-off is about eps (R/h)^2; 4 eps (R/h)^2, and
    at least 1e-12 (measured: 2.3e-12 .. 2.9e-12 at R = 3, 2.6e-10 .. 3.1e-10 at R = 30, n = 33)."""
    return max(1e-12, 4 * np.finfo(np.float64).eps * (R * (n - 1)) ** 2)


def _energy_scaling(cfg):
    """W ~ 1/R^2 on a jittered sheet: the fitted exponent over R/2, R, 2R."""
    R = cfg.radius
    flat, axis = sheet("grid", 33, jitter=cfg.jitter, seed=cfg.seed)
    energy = BendingEnergy(meshes.embed_3d(flat).vertices, flat.hinges, 1.0, cfg.bending)
    radii = np.array([R / 2, R, 2 * R])
    W = np.array([energy.energy(meshes.cylinder_wrap(flat, r, axis).vertices) for r in radii])
    return Experiment("jittered sheet: total energy ~ R^p, fitted exponent p (R/2, R, 2R)", -2.0,
                      fit_slope(np.log(radii), np.log(W)), 1e-3, "abs", id="jittered-energy-exponent")


# ------------------------------------------------------------------------- stage 3

def closed_form_ratio(kind: str, angle_deg: float) -> float:
    """Small-bend limit of W_notes / W_continuum for a regular mesh (derived in narrative.md,
    stage 3): 1/3 on the equilateral lattice, (1 - sin 2a + sin^2 2a)/3 on a right-triangle grid
    turned by a against the axis."""
    if kind == "lattice":
        return 1.0 / 3.0
    s = math.sin(2 * math.radians(angle_deg))
    return (1 - s + s * s) / 3


def sheet_ratio(cfg, kind, n, angle=0.0, variant="notes", jitter=0.0, seed=0, with_prediction=False):
    """(W / W_continuum, the sheet, the energy, the wrapped positions[, linearised prediction])."""
    R = cfg.radius
    flat, axis = sheet(kind, n, angle, jitter, seed)
    X3 = meshes.embed_3d(flat).vertices
    energy = BendingEnergy(X3, flat.hinges, 1.0, variant)
    x = meshes.cylinder_wrap(flat, R, axis).vertices
    W_cont = continuum_energy(1.0, R, flat.total_measure)
    ratio = energy.energy(x) / W_cont
    if not with_prediction:
        return ratio, flat, energy, x
    # theta_e ~ sum_i c_i z_i, c_i = dtheta/dz_i at the flat rest, z = -(u.(x_i - x_v0))^2/(2R)
    H = flat.hinges
    c = theta_gradient(X3, H)[:, :, 2]
    q = (flat.vertices[H] - flat.vertices[H[:, :1]])[:, :, around(axis)]
    theta_lin = -0.5 / R * np.sum(c * q * q, axis=1)  # z_i = -q_i^2/(2R); affine parts drop out
    pred = 0.5 * float(np.sum(energy.k * theta_lin ** 2)) / W_cont
    return ratio, flat, energy, x, pred


REGULAR = [("grid", 0.0, "right-triangle grid at 0 deg", "grid-0deg"),
           ("grid", 45.0, "right-triangle grid at 45 deg (diagonals along the axis)", "grid-45deg"),
           ("lattice", 0.0, "equilateral lattice at 0 deg", "lattice-0deg"),
           ("lattice", 15.0, "equilateral lattice at 15 deg", "lattice-15deg"),
           ("grid", 15.0, "right-triangle grid at 15 deg", "grid-15deg"),
           ("grid", 30.0, "right-triangle grid at 30 deg", "grid-30deg"),
           ("grid", -45.0, "right-triangle grid at -45 deg (diagonals around the cylinder)", "grid-minus45deg")]
# the regular sheets drawn (at the middle level) with the notes' energy; grid 0 deg also with Discrete Shells'
DRAWN = {("grid", 0.0): "grid at 0°", ("grid", -45.0): "grid at −45°"}


def stage_continuum(ctx):
    cfg = ctx.cfg
    nf = cfg.finest
    levels = (nf, (nf + 1) // 2, (nf + 3) // 4)
    exps = []
    for kind, angle, label, slug in REGULAR:
        exps += _regular_ratio(ctx, kind, angle, label, slug, levels)
    for kind, label in (("grid", "jittered right-triangle grid"), ("lattice", "jittered equilateral lattice")):
        exps += _jittered_ratio(ctx, kind, label, levels[1])
    return exps


def _regular_ratio(ctx, kind, angle, label, slug, levels):
    """W_notes / W_continuum on three nested refinements, extrapolated (2 r(h) - r(2h)), against
    the closed form; at 0 deg on the grid also its finest value and error order, and on three
    meshes the Discrete Shells ratio. The DRAWN meshes are drawn at the middle level."""
    cfg = ctx.cfg
    nf = levels[0]
    sheets = [sheet_ratio(cfg, kind, n, angle) for n in levels]
    r = [sh[0] for sh in sheets]
    extrapolated = 2 * r[0] - r[1]
    theory = closed_form_ratio(kind, angle)
    ctx.progress(f"{label}: W/W_cont = " + ", ".join(f"{v:.5f} (n={n})" for v, n in zip(r, levels))
                 + f"; extrapolated {extrapolated:.5f}; closed form {theory:.5f}")
    exps = [Experiment(f"{label}: notes / continuum, extrapolated to h -> 0", theory, extrapolated, 1e-3, "rel",
                       id=f"{slug}-ratio-extrapolated")]
    if kind == "grid" and angle == 0.0:
        exps.append(Experiment(f"{label}: notes / continuum at the finest level (n = {nf})", 1 / 3, r[0],
                               finest_tolerance(nf), "rel", id=f"{slug}-ratio-finest"))
        h = np.array([1.0 / (n - 1) for n in levels])
        exps.append(Experiment(f"{label}: the ratio's error shrinks at order 1 (the free-edge strip)", 1.0,
                               convergence_order(h, np.abs(np.array(r) - theory)), 0.05, "abs",
                               id=f"{slug}-ratio-error-order"))
    if kind == "grid":
        exps.append(_edge_family_folds(cfg, label, slug, angle, levels[1], sheets[1]))
    short = DRAWN.get((kind, angle))
    if short is not None and ctx.rec.enabled:
        _, flat, energy, x = sheets[1]
        log_sheet(ctx, f"{kind}_{angle:g}deg", f"{short}, notes' energy", x, flat.triangles, energy)
    if (kind, angle) in (("grid", 0.0), ("grid", 45.0), ("lattice", 0.0)):
        ds, flat, energy, x = sheet_ratio(cfg, kind, nf, angle, variant="discrete-shells")
        exps.append(Experiment(f"{label}: Discrete Shells / continuum at the finest level (n = {nf})", 1.0, ds,
                               finest_tolerance(nf), "rel", id=f"{slug}-discrete-shells-ratio"))
        if kind == "grid" and angle == 0.0 and ctx.rec.enabled:
            _, flat, energy, x = sheet_ratio(cfg, kind, levels[1], angle, variant="discrete-shells")
            log_sheet(ctx, f"{kind}_{angle:g}deg_discrete-shells", f"{short}, Discrete Shells", x,
                      flat.triangles, energy)
    elif (kind, angle) in DS_TURNED:
        exps += _discrete_shells_turned(ctx, kind, angle, label, slug, sheets, levels)
    return exps


def _edge_family_folds(cfg, label, slug, angle, n, sheet_level):
    """Each hinge's fold angle against its edge family's small-bend value, signs included (the
    narrative's three formulas; at -45 deg the diagonals fold the other way). The next order is
    (h/R)^2 (measured 0.06 (h/R)^2 at -45 deg, 0.004 at 15 deg), so the tolerance is 0.1 (h/R)^2."""
    _, flat, energy, x = sheet_level
    R, h = cfg.radius, 1.0 / (n - 1)
    _, predicted = edge_family_folds(flat, angle)
    deviation = float(np.max(np.abs(energy.angles(x) * R / h - predicted)))
    return Experiment(f"{label}: every hinge's theta R/h against its edge family's (cos^2 a - cos a sin a, "
                      f"sin^2 a - cos a sin a, sqrt2 cos a sin a), signs included (n = {n}, largest deviation)",
                      0.0, deviation, 0.1 * (h / R) ** 2, "abs", id=f"{slug}-edge-family-folds")


def finest_tolerance(n: int) -> float:
    """Tolerance of the finest-level ratios: 1%, or 1.25 h where the free-edge strip, which costs
    the aligned meshes h = 1/(n - 1) of their ratio (stage 3's narrative), is larger (n < 126)."""
    return max(1e-2, 1.25 / (n - 1))


# Discrete Shells on turned meshes: the claim of its fix measured where the aligned meshes cannot tell
DS_TURNED = (("grid", 15.0), ("grid", 30.0), ("grid", -45.0), ("lattice", 15.0))


def _discrete_shells_turned(ctx, kind, angle, label, slug, sheets, levels):
    """Discrete Shells' weight is three times the notes' on every hinge (K2 = 3 x K1), so its ratio
    is three times the notes' closed form on every regular mesh: 1 only where that is 1/3 (the
    aligned grids, the equilateral lattice), 0.75 on the grid at 15 deg and 3 at -45 deg. Measured
    with its own energy on the same three sheets as the notes' ratio, extrapolated the same way."""
    r = [BendingEnergy(meshes.embed_3d(flat).vertices, flat.hinges, 1.0, "discrete-shells").energy(x)
         / continuum_energy(1.0, ctx.cfg.radius, flat.total_measure) for _, flat, _, x in sheets]
    extrapolated = 2 * r[0] - r[1]
    theory = 3 * closed_form_ratio(kind, angle)
    ctx.progress(f"{label}: Discrete Shells W/W_cont = " + ", ".join(f"{v:.5f} (n={n})" for v, n in zip(r, levels))
                 + f"; extrapolated {extrapolated:.5f}; 3 x the notes' closed form {theory:.5f}")
    _, flat, notes, x = sheets[-1]  # the coarsest sheet: the hinge-by-hinge relation behind it
    ds = BendingEnergy(meshes.embed_3d(flat).vertices, flat.hinges, 1.0, "discrete-shells")
    Wn, Wd = notes.hinge_energies(x), ds.hinge_energies(x)
    bent = Wn > 1e-12 * Wn.max()
    exps = [Experiment(f"{label}: Discrete Shells / continuum, extrapolated to h -> 0 (3 x the notes' closed form)",
                       theory, extrapolated, 1e-3, "rel", id=f"{slug}-discrete-shells-ratio-extrapolated")]
    if (kind, angle) == DS_TURNED[0]:
        exps.append(Experiment(f"identity (K2 = 3 K1): Discrete Shells' hinge energy / the notes', every bent hinge "
                               f"of the {label} (n = {levels[-1]}; max |ratio - 3|)", 0.0,
                               float(np.abs(Wd[bent] / Wn[bent] - 3).max()), 1e-12, "abs",
                               id="discrete-shells-three-times-notes-identity"))
    return exps


def _jittered_ratio(ctx, kind, label, n):
    """No closed form on a jittered mesh: the ratio against the linearised sum of its own hinges,
    and above the regular mesh's."""
    cfg = ctx.cfg
    regular = sheet_ratio(cfg, kind, n)[0]
    r, flat, energy, x, pred = sheet_ratio(cfg, kind, n, jitter=cfg.jitter, seed=cfg.seed, with_prediction=True)
    ctx.progress(f"{label} (amplitude {cfg.jitter}, n={n}): W/W_cont = {r:.5f}, regular mesh {regular:.5f}, "
                 f"linearised prediction {pred:.5f}")
    exps = [
        Experiment(f"{label}, n = {n}: ratio equals the small-bend sum of its own hinges", pred, r, 1e-3, "rel",
                   id=f"jittered-{kind}-ratio-predicted"),
        Experiment(f"{label}, n = {n}: ratio / regular mesh's ratio exceeds 1.01 (mesh-dependent)", 1.01,
                   r / regular, 0.0, ">=", id=f"jittered-{kind}-ratio-above-regular"),
    ]
    if kind == "grid" and ctx.rec.enabled:
        log_sheet(ctx, f"{kind}_jittered", "jittered grid, notes' energy", x, flat.triangles, energy)
    return exps


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
