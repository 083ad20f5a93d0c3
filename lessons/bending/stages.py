"""The stages of ``bending`` that measure the discrete energy itself (their narratives are in
narrative.md): the hinge and its derivatives (stage 1), the curvature estimate on a cylinder
(stage 2) and the energy against the continuum (stage 3). The stages that put it to work in a
hanging cloth and a curved shell (4 and 5) are in :mod:`.stages_structures`; the hinges, sheets,
cylinders and the shell they measure on, and the drawings, are in :mod:`.scene`.

Each stage keeps the measurement helpers only it uses next to it (stage 3 alone, about 150
lines, compares seven regular meshes, their Discrete Shells variants and two jittered ones with
the continuum).
"""
import math

import numpy as np

from engine import mesh as meshes
from engine.analysis import convergence_order, fit_slope
from engine.energies.bending import BendingEnergy

from .._framework import Experiment
from .._measure import per_hinge_fd, random_rotation
from .scene import (analytic_hinge, around, bridson_u, continuum_energy, draw_opening_hinge, edge_family_folds,
                    log_sheet, random_hinges, sheet, theta_gradient)


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
