"""Lesson ``bending``: dihedral-angle bending energy on triangle meshes.

The notes' discrete energy W = sum_e 1/2 B |e|^2/(36 A_e) theta_e^2 (A_e = |e|(h1+h2)/6, all
factors but theta from the rest mesh): the hinge and its derivatives, the curvature estimate
on a cylinder, the energy against the continuum (and why it lands on a third of it on regular
meshes), a hanging cloth that folds, and a curved shell that keeps its shape.

Physics lives in :mod:`engine.energies.bending`, :mod:`engine.mesh`, :mod:`engine.statics`
and the integrators; this module builds scenes, runs them, measures and narrates.
"""
import math
from dataclasses import dataclass

import numpy as np
import taichi as ti

from engine import mesh as meshes
from engine.analysis import convergence_order, fit_slope
from engine.constants import G
from engine.energies.bending import VARIANTS, BendingEnergy, bridson_u_kernel, theta_gradient_kernel
from engine.errors import ParameterError
from engine.integrators import make_integrator
from engine.model import Model, vec3_ndarray
from engine.scenes import cloth
from engine.statics import solve_static

from ._framework import Experiment, Lesson, Stage, param
from ._measure import per_hinge_fd, random_rotation
from ._scene import simulate


@dataclass
class BendingConfig:
    bending: str = param("notes", "bending energy: the notes' theta^2 weight |e|^2/(36 A_e), Bridson's "
                         "sin(theta/2) force with that weight, or Discrete Shells' weight 3|e|^2/(A1+A2) "
                         "(used by the cloth, the shell and the 1/R^2 scaling)", choices=VARIANTS)
    radius: float = param(1.0, "cylinder radius R for the curvature and energy measurements (sheets are 1 m wide)",
                          "m", ge=0.5, le=100.0)
    finest: int = param(129, "vertices per side of the finest sheet in the refinement studies "
                             "(levels finest, (finest+1)/2, (finest+3)/4)", ge=33, le=257)
    jitter: float = param(0.25, "random displacement of interior vertices for the irregular meshes, "
                                "in units of the local edge length", ge=0.1, le=0.25)
    seed: int = param(1, "random seed for the jittered meshes and the random hinges", ge=0)
    cloth_n: int = param(21, "cloth vertices per side (a 1 m x 1 m right-triangle grid)", ge=11, le=41)
    cloth_E: float = param(1e3, "cloth stretching modulus (Young's modulus times thickness)", "N/m", gt=0)
    cloth_rho: float = param(0.1, "cloth areal density", "kg/m^2", gt=0)
    cloth_B: float = param(3e-3, "middle bending modulus of the cloth sweep (B/10, B, 10 B)", "N m", gt=0)
    cloth_gap: float = param(0.5, "distance between the two hooks, as a fraction of the cloth width", ge=0.3, le=0.8)
    shell_E: float = param(1e4, "shell stretching modulus", "N/m", gt=0)
    shell_B: float = param(1.0, "shell bending modulus", "N m", gt=0)
    shell_rho: float = param(0.005, "shell areal density (its own weight is the small load)", "kg/m^2", gt=0)
    push: float = param(40.0, "the push: this many times the shell's own weight, then released", ge=2, le=100)
    static_tol: float = param(1e-5, "Newton residual for static equilibria (net force / largest vertex weight)",
                              gt=0, le=1e-3)
    dt: float = param(0.01, "time step of the backward-Euler runs", "s", gt=0, le=0.05)
    record_every: int = param(2, "log the geometry every k-th time step", ge=1)

    def validate(self):
        if (self.finest - 1) % 4:
            raise ParameterError(f"--finest must be 4k + 1 so that the coarser levels nest (got {self.finest})")


# ------------------------------------------------------------------ shared machinery

def _hinge_array(H):
    a = ti.ndarray(dtype=ti.i32, shape=(len(H), 4))
    a.from_numpy(np.asarray(H, dtype=np.int32))
    return a


def theta_gradient(X, H) -> np.ndarray:
    """(h, 4, 3) dtheta/dx per hinge slot, from the engine's kernel (G1)-(G3)."""
    g = ti.ndarray(dtype=ti.math.vec3, shape=(len(H), 4))
    theta_gradient_kernel(vec3_ndarray(len(X), X), _hinge_array(H), g)
    return g.to_numpy().astype(np.float64)


def bridson_u(X, H) -> np.ndarray:
    """(h, 4, 3) Bridson et al.'s u vectors in slot order (v0, v1, w0, w1), from the engine."""
    u = ti.ndarray(dtype=ti.math.vec3, shape=(len(H), 4))
    bridson_u_kernel(vec3_ndarray(len(X), X), _hinge_array(H), u)
    return u.to_numpy().astype(np.float64)


def analytic_hinge(theta, L=1.0, p0=0.35, r0=0.8, p1=0.7, r1=0.6):
    """Edge (0,0,0)-(L,0,0); wing w0 in the z = 0 plane; wing w1 turned about the edge so that
    the dihedral angle is theta (positive: convex on the side the normals point to)."""
    return np.array([[0.0, 0.0, 0.0], [L, 0.0, 0.0], [p0, r0, 0.0],
                     [p1, -r1 * math.cos(theta), -r1 * math.sin(theta)]])


def random_hinges(rng, m, max_angle=2.5):
    """m unconnected hinges (vertices 4i..4i+3), random shape, angle, rotation and position,
    with rest shapes that are flat (the same hinge at theta = 0)."""
    bent, flat = [], []
    for _ in range(m):
        L = rng.uniform(0.6, 1.5)
        kw = dict(L=L, p0=rng.uniform(-0.3, 1.3) * L, r0=rng.uniform(0.3, 1.2) * L,
                  p1=rng.uniform(-0.3, 1.3) * L, r1=rng.uniform(0.3, 1.2) * L)
        Q, t = random_rotation(rng), rng.normal(size=3)
        bent.append(analytic_hinge(rng.uniform(-max_angle, max_angle), **kw) @ Q.T + t)
        flat.append(analytic_hinge(0.0, **kw) @ Q.T + t)
    return np.concatenate(bent), np.concatenate(flat), np.arange(4 * m).reshape(m, 4)


def centred(mesh2d):
    return meshes.Mesh(mesh2d.vertices - mesh2d.vertices.mean(axis=0), triangles=mesh2d.triangles)


# Sheets of side 1 m; "axis" is the cylinder axis of cylinder_wrap ("y": x runs around it).
def sheet(kind: str, n: int, angle_deg: float = 0.0, jitter: float = 0.0, seed: int = 0):
    """A flat 2D sheet of about 1 m x 1 m with n vertices per side, rotated by angle_deg
    (counter-clockwise) about its centre, optionally jittered; returns (mesh, axis)."""
    if kind == "grid":
        m, axis = meshes.right_triangle_grid(n, n, 1.0, 1.0), "y"
    else:  # equilateral lattice, rows along x; wrapped about the x axis so rows run along it
        m, axis = meshes.equilateral_lattice(n, n, 1.0 / (n - 1)), "x"
    if jitter:
        m = meshes.jitter(m, jitter, seed)
    m = centred(m)
    if angle_deg:
        m = meshes.rotate_2d(m, math.radians(angle_deg))
    return m, axis


def around(axis: str) -> int:
    """Index of the flat coordinate that runs around the cylinder."""
    return 0 if axis == "y" else 1


def continuum_energy(B, R, area):
    """1/2 B H^2 * area with the mean curvature H = 1/(2R) of a cylinder."""
    return 0.5 * B * (1.0 / (2.0 * R)) ** 2 * area


def log_sheet(ctx, name, x, triangles, energy: BendingEnergy, offset=(0.0, 0.0, 0.0)):
    """One frame of a sheet coloured by bending energy density (nothing if not recording)."""
    rec = ctx.rec
    if not rec.enabled:
        return
    from engine.recorder import magnitude_colors
    rec.run(name)
    rec.set_time(0, 0.0)
    rec.mesh(np.asarray(x) + np.asarray(offset), triangles, magnitude_colors(energy.energy_density(x)))


# ------------------------------------------------------------------------- stage 1

S1_TEXT = """
A hinge is two triangles sharing an edge e = (x3, x4), with wing vertices x1 and x2 on either
side. Its dihedral angle theta is the angle between the two triangle normals: zero when the
pair is flat, positive when it folds towards the side its normals point to. We compute it with
atan2 of the sine and cosine parts, which stays accurate near 0 and near +-pi where an arccos
would lose digits.

The notes' energy for one hinge is 1/2 k_e theta^2 with k_e = B |e|^2/(36 A_e) frozen on the
rest mesh, so the force is -k_e theta grad(theta). Moving a wing along its own unit normal n
turns its triangle about the edge at the rate 1/h (h its height above the edge) and lowers
theta, so the wing's gradient is -n/h; the two edge vertices take the combinations of the wing gradients that make the
four sum to zero, weighted by where each wing's foot lands along the edge. These are exactly
Bridson et al.'s u1..u4 (with the opposite sign). We check the gradient against central
finite differences, and Bridson's formula against ours, on randomly shaped and placed hinges.

Because theta only depends on the shape of the hinge, the forces carry no net force and no
net torque, and moving the hinge rigidly changes neither the energy nor (apart from rotating
them) the forces.

Bridson et al. replace theta in the force by 2 sin(theta/2), which needs no inverse
trigonometry. Both have the same slope at theta = 0, so small bends see the same stiffness;
at larger angles the force is smaller by the factor 2 sin(theta/2)/theta. Its Taylor series
is 1 - theta^2/24 + theta^4/1920 - ..., an alternating series with shrinking terms, so the
two-term approximation 1 - theta^2/24 is off by less than theta^4/1920 (3.3e-5 at 0.5 rad,
5.2e-4 at 1 rad). That bound, not zero, is the tolerance of the comparison.
"""


def stage_hinge(ctx):
    cfg = ctx.cfg
    rng = np.random.default_rng(cfg.seed)
    H1 = np.array([[0, 1, 2, 3]])
    # 1. angle of the analytic hinge over (-pi, pi)
    angles = np.linspace(-3.1, 3.1, 63)
    probe = BendingEnergy(analytic_hinge(0.0), H1, 1.0)
    theta_err = max(abs(probe.angles(analytic_hinge(t))[0] - t) for t in angles)
    # 2. gradient against finite differences; 3. Bridson's u = -grad theta
    X, Xflat, H = random_hinges(rng, 12)
    probe = BendingEnergy(Xflat, H, 1.0)
    g = theta_gradient(X, H)
    g_fd = per_hinge_fd(probe.angles, X)
    grad_err = np.linalg.norm(g - g_fd) / np.linalg.norm(g)
    u = bridson_u(X, H)
    u_err = np.abs(u + g).max() / np.abs(g).max()
    # force = -dW/dx of the chosen variant, by finite differences of the per-hinge energies
    energy = BendingEnergy(Xflat, H, 0.7, cfg.bending)
    f = energy.hinge_forces(X)
    f_fd = -per_hinge_fd(energy.hinge_energies, X)
    force_err = np.linalg.norm(f - f_fd) / np.linalg.norm(f)
    # 4. zero net force and torque per hinge
    xs = X[H]
    net_f = (np.linalg.norm(f.sum(axis=1), axis=1) / np.linalg.norm(f, axis=2).sum(axis=1)).max()
    lever = np.linalg.norm(xs - xs.mean(axis=1, keepdims=True), axis=2)
    net_tau = (np.linalg.norm(np.cross(xs, f).sum(axis=1), axis=1)
               / (np.linalg.norm(f, axis=2) * (np.linalg.norm(xs, axis=2) + lever)).sum(axis=1)).max()
    # 5. rigid motions
    W0 = energy.energy(X)
    dW, df = 0.0, 0.0
    for _ in range(3):
        Q, t = random_rotation(rng), 5.0 * rng.normal(size=3)
        Y = X @ Q.T + t
        dW = max(dW, abs(energy.energy(Y) - W0) / W0)
        df = max(df, np.abs(energy.hinge_forces(Y) - f @ Q.T).max() / np.abs(f).max())
    exps = [
        Experiment("theta of an analytic hinge over [-3.1, 3.1] rad (max |error|)", 0.0, theta_err, 1e-13, "abs",
                   "rad"),
        Experiment("dtheta/dx equals central finite differences (rel. error, 12 random hinges)", 0.0, grad_err,
                   1e-7, "abs"),
        Experiment("Bridson's u1..u4 equal -dtheta/dx (max difference / max |grad|)", 0.0, u_err, 1e-13, "abs"),
        Experiment(f"{cfg.bending} force equals -dW/dx by central differences (rel. error)", 0.0, force_err,
                   1e-7, "abs"),
        Experiment("zero net force per hinge (max |sum f| / sum |f|)", 0.0, net_f, 1e-13, "abs"),
        Experiment("zero net torque per hinge (max |sum x cross f| / sum |f||x|)", 0.0, net_tau, 1e-13, "abs"),
        Experiment("rigid motion leaves the energy unchanged (max rel. change)", 0.0, dW, 1e-12, "abs"),
        Experiment("rigid motion rotates the forces with the hinge (max rel. difference)", 0.0, df, 1e-12, "abs"),
    ]
    # 6. sin(theta/2) against theta
    rest = analytic_hinge(0.0)
    notes = BendingEnergy(rest, H1, 1.0, "notes")
    bridson = BendingEnergy(rest, H1, 1.0, "bridson")
    for th in (0.5, 1.0):
        x = analytic_hinge(th)
        fn, fb = notes.hinge_forces(x)[0], bridson.hinge_forces(x)[0]
        ratio = float((fb * fn).sum() / (fn * fn).sum())
        exps += [
            Experiment(f"theta = {th}: Bridson/notes force ratio equals 2 sin(theta/2)/theta",
                       2 * math.sin(th / 2) / th, ratio, 1e-12, "rel"),
            Experiment(f"theta = {th}: force ratio equals 1 - theta^2/24 within the truncation error theta^4/1920",
                       1 - th ** 2 / 24, ratio, th ** 4 / 1920, "abs"),
        ]
    if ctx.rec.enabled:  # the hinge opening from flat to 3 rad, coloured by its energy density
        from engine.recorder import magnitude_colors
        ctx.rec.run("hinge")
        scale = float(notes.energy_density(analytic_hinge(3.0)).max())
        for k, th in enumerate(np.linspace(0.0, 3.0, 31)):
            x = analytic_hinge(th)
            ctx.rec.set_time(k, th)
            ctx.rec.mesh(x, np.array([[0, 1, 2], [1, 0, 3]]), magnitude_colors(notes.energy_density(x), scale))
            fx = notes.forces(x)
            ctx.rec.line_strips("force", np.stack([x, x + 0.1 * fx], axis=1))
    return exps


# ------------------------------------------------------------------------- stage 2

S2_TEXT = """
Roll a flat sheet onto a cylinder of radius R. Its curvature is 1/R around the cylinder and
0 along the axis; the mean curvature, the average of the two, is H = 1/(2R), and the
continuum bending energy per unit area is 1/2 B H^2.

Look at a hinge whose edge runs along the axis, with wings at distances h1 and h2 around the
cylinder. Each triangle is a flat facet between two lines of the cylinder, and its normal
points to the middle of its arc; so the two normals differ by half the angle the wings
subtend, theta = (h1 + h2)/(2R) when h1 and h2 are measured along the surface, and
theta/(h1 + h2) = 1/(2R): the notes' curvature estimate. If the heights are
measured as straight lines in the bent hinge (the altitudes of its triangles), they are chords,
slightly shorter than the arcs; the estimate is then too large by phi/sin(phi) - 1 ~ phi^2/6
with phi = h/(2R), an error that shrinks as h^2 when the mesh is refined. We measure it on
right-triangle grids and on equilateral lattices at three refinements and fit the order.

The energy itself freezes |e|, h1 and h2 at the flat rest mesh (the notes' rule), so with those
arc-length heights the estimate is exact on the edges along the axis. Since every hinge's
angle is proportional to 1/R for small bends (up to corrections of order (h/R)^2), the energy
goes as 1/R^2. We fit that exponent on a jittered mesh, where every hinge bends a little and
nothing is aligned.

On these aligned meshes the other two edges of each triangle join facets lying between the
same two lines of the cylinder: such a pair is coplanar, theta = 0. Keep that in mind for the
next stage.
"""


def _aligned_edges(flat, axis):
    """Hinges whose flat edge is parallel to the cylinder axis."""
    H = flat.hinges
    d = flat.vertices[H[:, 1]] - flat.vertices[H[:, 0]]
    return np.abs(d[:, around(axis)]) < 1e-9 * np.linalg.norm(d, axis=1)


def stage_curvature(ctx):
    cfg = ctx.cfg
    R = cfg.radius
    exps = []
    levels = (9, 17, 33)
    for kind, label in (("grid", "right-triangle grid"), ("lattice", "equilateral lattice")):
        chord_err, hs = [], []
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
                               1 / (2 * R), float(est_bent.mean()), 1e-3, "rel", "1/m"),
                    Experiment(f"{label}, n = {n}: with the rest heights the estimate is exact (max rel. error)",
                               0.0, float(np.abs(est_rest * 2 * R - 1).max()), 1e-12, "abs"),
                    Experiment(f"{label}: the other hinges are flat (max |theta|)", 0.0,
                               float(np.abs(theta[~across]).max()), 1e-12, "abs", "rad"),
                ]
                log_sheet(ctx, f"{kind}_n{n}", wrapped.vertices, flat.triangles, energy,
                          (0.0 if kind == "grid" else 2.5, 0.0, 0.0))
            phi = hs[-1] / (2 * R)
            ctx.progress(f"{label} n={n}: max error of theta/(h1+h2) (chord heights) {chord_err[-1]:.3e}, "
                         f"phi/sin(phi) - 1 = {phi / math.sin(phi) - 1:.3e}")
        exps.append(Experiment(f"{label}: chord-height estimate converges at order 2 in h", 2.0,
                               convergence_order(np.array(hs), np.array(chord_err)), 0.05, "abs"))
    # W ~ 1/R^2 on a jittered sheet
    flat, axis = sheet("grid", 33, jitter=cfg.jitter, seed=cfg.seed)
    energy = BendingEnergy(meshes.embed_3d(flat).vertices, flat.hinges, 1.0, cfg.bending)
    radii = np.array([R / 2, R, 2 * R])
    W = np.array([energy.energy(meshes.cylinder_wrap(flat, r, axis).vertices) for r in radii])
    exps.append(Experiment("jittered sheet: total energy ~ R^p, fitted exponent p (R/2, R, 2R)", -2.0,
                           fit_slope(np.log(radii), np.log(W)), 1e-3, "abs"))
    return exps


# ------------------------------------------------------------------------- stage 3

S3_TEXT = """
Compare the whole sheet's energy with the continuum 1/2 B (1/(2R))^2 * area.

Why a third on regular meshes. For a hinge across the bend, theta = (h1 + h2)/(2R) exactly,
and then its energy is 1/2 B |e|^2/(36 A_e) theta^2 = 1/2 B |e|(h1 + h2)/6 * (1/(2R))^2
= 1/2 B H^2 A_e: exactly the continuum energy of its region A_e. But A_e hands each edge a
third of each neighbouring triangle, and of the three edges of every triangle only the one
along the axis bends; the other two are flat hinges (stage 2) although the surface around
them is just as curved. So the sum collects the continuum density on one third of the area:
the ratio tends to 1/3. (It approaches it from below, with an error of order h: along the free
edges parallel to the axis a strip half a cell wide belongs to no bending hinge.)

Discrete Shells weighs a hinge by 3|e|^2/(A1 + A2) instead. Since A1 + A2 = 3 A_e, that is
three times the notes' |e|^2/(36 A_e) up to a constant; choosing the constant so that B is the
same bending modulus, W_e = B |e|^2 theta^2/(8 (A1 + A2)), exactly three times the notes'
hinge energy. Each bending hinge then carries the continuum energy of three edge regions,
its own and in effect those of the two flat hinges beside it, which restores the continuum
value on these aligned meshes (and makes everything else three times larger too).

The third is not universal. For small bends theta is a second difference of the surface
height over the four hinge vertices: theta ~ sum_i c_i z_i with fixed weights c_i (the rest
gradient of theta), and on a cylinder z = -(u.x)^2/(2R) with u the direction around it. On a
right-triangle grid whose cells are turned by alpha against the axis this gives, per cell,
theta = (cos^2 a - cos a sin a) h/R, (cos a sin a - sin^2 a) h/R and sqrt2 cos a sin a h/R for
the three edge families, and summing 1/2 k_e theta^2:

    W / W_continuum = (1 - sin 2a + sin^2 2a) / 3.

That is 1/3 at alpha = 0 and at 45 degrees (diagonals along the axis), 1/4 at 15 degrees, 0.295
at 30 degrees, but 1 at -45 degrees, where the diagonals run around the cylinder and every edge
reports the full curvature. On the equilateral lattice the three edge families are copies of
one another turned by 60 degrees; each family's theta is a constant plus a cos(2a + phase)
term, the three phases are 120 degrees apart, and the sum of the three squares does not depend
on alpha: the lattice is isotropic and gives 1/3 at every orientation.
We measure each ratio on three nested refinements and extrapolate the O(h) boundary strip
away (Richardson: 2 r(h) - r(2h)).

On jittered meshes there is no closed form. The hinges are no longer coplanar pairs: every
edge picks up a scattered share of the curvature, and because the energy sums squares the
scatter adds energy, so the ratio rises above the regular mesh's value, by an amount that
depends on the mesh. What can be predicted is the value for a given mesh: summing
1/2 k_e (sum_i c_i z_i)^2 with the rest gradients (computed by the engine on the flat mesh),
which must match the measured energy up to the small-angle error, O((h/R)^2).
"""


def closed_form_ratio(kind: str, angle_deg: float) -> float:
    """Small-bend limit of W_notes / W_continuum for a regular mesh (see S3_TEXT)."""
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


def stage_continuum(ctx):
    cfg = ctx.cfg
    nf = cfg.finest
    levels = (nf, (nf + 1) // 2, (nf + 3) // 4)
    exps = []
    cases = [("grid", 0.0, "right-triangle grid at 0 deg"),
             ("grid", 45.0, "right-triangle grid at 45 deg (diagonals along the axis)"),
             ("lattice", 0.0, "equilateral lattice at 0 deg"),
             ("lattice", 15.0, "equilateral lattice at 15 deg"),
             ("grid", 15.0, "right-triangle grid at 15 deg"),
             ("grid", 30.0, "right-triangle grid at 30 deg"),
             ("grid", -45.0, "right-triangle grid at -45 deg (diagonals around the cylinder)")]
    shown = 0
    for kind, angle, label in cases:
        r = [sheet_ratio(cfg, kind, n, angle)[0] for n in levels]
        extrapolated = 2 * r[0] - r[1]
        theory = closed_form_ratio(kind, angle)
        ctx.progress(f"{label}: W/W_cont = " + ", ".join(f"{v:.5f} (n={n})" for v, n in zip(r, levels))
                     + f"; extrapolated {extrapolated:.5f}; closed form {theory:.5f}")
        exps.append(Experiment(f"{label}: notes / continuum, extrapolated to h -> 0", theory, extrapolated,
                               1e-3, "rel"))
        if kind == "grid" and angle == 0.0:
            exps.append(Experiment(f"{label}: notes / continuum at the finest level (n = {nf})", 1 / 3, r[0],
                                   1e-2, "rel"))
            h = np.array([1.0 / (n - 1) for n in levels])
            exps.append(Experiment(f"{label}: the ratio's error shrinks at order 1 (the free-edge strip)", 1.0,
                                   convergence_order(h, np.abs(np.array(r) - theory)), 0.05, "abs"))
        if (kind, angle) in (("grid", 0.0), ("grid", 45.0), ("lattice", 0.0)):
            ds, flat, energy, x = sheet_ratio(cfg, kind, nf, angle, variant="discrete-shells")
            exps.append(Experiment(f"{label}: Discrete Shells / continuum at the finest level (n = {nf})", 1.0, ds,
                                   1e-2, "rel"))
            if ctx.rec.enabled:
                log_sheet(ctx, f"{kind}_{angle:g}deg", x, flat.triangles, energy, (2.5 * shown, 0.0, 0.0))
                shown += 1
    # jittered meshes: no closed form; compare with the regular mesh and the linearised sum
    n = levels[1]
    for kind, label in (("grid", "jittered right-triangle grid"), ("lattice", "jittered equilateral lattice")):
        regular = sheet_ratio(cfg, kind, n)[0]
        r, flat, energy, x, pred = sheet_ratio(cfg, kind, n, jitter=cfg.jitter, seed=cfg.seed, with_prediction=True)
        ctx.progress(f"{label} (amplitude {cfg.jitter}, n={n}): W/W_cont = {r:.5f}, regular mesh {regular:.5f}, "
                     f"linearised prediction {pred:.5f}")
        exps += [
            Experiment(f"{label}, n = {n}: ratio equals the small-bend sum of its own hinges", pred, r, 1e-3, "rel"),
            Experiment(f"{label}, n = {n}: ratio / regular mesh's ratio exceeds 1.01 (mesh-dependent)", 1.01,
                       r / regular, 0.0, ">="),
        ]
        if ctx.rec.enabled:
            log_sheet(ctx, f"{kind}_jittered", x, flat.triangles, energy, (2.5 * shown, 0.0, 0.0))
            shown += 1
    return exps


# ------------------------------------------------------------------------- stage 4

S4_TEXT = """
Now a cloth: a 1 m square sheet with area-scaled springs (c_e = E A_e, stretching modulus E
in N/m), the bending energy chosen with --bending, and its own weight (areal density rho).
It hangs from two hooks at its top corners, brought together to a fraction of its width,
so that the sheet has more width than room and must fold. We start it flat, squeezed
sideways and rumpled by a millimetre of random noise (a perfectly flat start would stay
flat by symmetry), let it fall for a second with backward Euler (stable at any time step;
an explicit step for these stiff springs would have to be tiny), and then let Newton's method
find the static equilibrium nearby: the minimum of elastic plus gravitational energy with the
hooks held.

The fall is a damped relaxation, not a motion we measure: squeezing the sheet to half its width
stores about 49 J in its springs, while its weight (1 N) can do only about half a joule of work
on the way down, and that energy has to go before Newton can start near an equilibrium.
Backward Euler's numerical damping takes it away; an undamped explicit integrator keeps it. We
tried: velocity Verlet at 0.9 of the CFL estimate blows up at t = 0.21 s as the flailing
sheet's triangles collapse; at half of it the sheet still flails with its ~49 J after a second,
at B = 0.03 N m the energy grows a hundredfold, and Newton does not converge from where
velocity Verlet leaves the two stiffer sheets. So the three falls are fixed to backward Euler
when --integrator names an explicit method (marked [fixed]); --integrator backward-euler with
--solver, --tol and --newton-iterations does apply to them.

Bending costs energy per unit of squared curvature, so a stiffer sheet prefers a few wide,
gently curved folds over many tight ones: the balance of bending against the weight that
pulls the sheet taut sets a fold width that grows with B. (Dimensional analysis suggests a
bending length (B/(rho g))^(1/3), about 7, 15 and 31 cm for the default sweep; three fold
counts are too coarse to measure that exponent, so we do not claim it. At the softest B that
length approaches the 5 cm mesh spacing, so there the mesh also limits how fine the folds can
be.) We count folds along three horizontal lines of the sheet (at a
quarter, half and three quarters of its height) as the number of runs of one sign of the
dihedral angle on the vertical edges crossing the line, ignoring angles below a tenth of the
line's largest: a sheet bowed as a whole counts as one. The sweep B/10, B, 10 B must give
monotonically fewer folds, with a strict drop from the softest to the stiffest. Which local
equilibrium Newton finds depends on the start, so we claim only that order, not exact counts.

At equilibrium the hooks carry the cloth: the sum of the pin reactions equals the total
weight. The net elastic force on the sheet is exactly zero (every spring and hinge pushes
and pulls in balance), so the only difference is the sum of the leftover residual forces at
the free vertices, at most (number of free vertices) x tol x (largest vertex weight).
"""


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


def mesh_logger(triangles, energy: BendingEnergy, offset=(0.0, 0.0, 0.0)):
    """log(rec, state) for simulate(): the mesh coloured by bending energy density."""
    from engine.recorder import magnitude_colors

    def log(rec, state):
        x = state.x.to_numpy().astype(np.float64)
        rec.mesh(x + np.asarray(offset), triangles, magnitude_colors(energy.energy_density(x)))
    return log


def log_static(ctx, name_step, x, triangles, energy, offset, step, time):
    if ctx.rec.enabled:
        from engine.recorder import magnitude_colors
        ctx.rec.set_time(step, time)
        ctx.rec.mesh(x + np.asarray(offset), triangles, magnitude_colors(energy.energy_density(x)))
        ctx.rec.mark(name_step, level="INFO")


def stage_cloth(ctx):
    cfg = ctx.cfg
    n = cfg.cloth_n
    steps = int(round(1.0 / cfg.dt))
    exps, folds = [], []
    explicit = ctx.integrator_name("backward-euler") != "backward-euler"  # an explicit --integrator
    Bs = (cfg.cloth_B / 10, cfg.cloth_B, cfg.cloth_B * 10)
    for k, B in enumerate(Bs):
        scene = cloth(n, 1.0, E=cfg.cloth_E, rho=cfg.cloth_rho, B=B, variant=cfg.bending)
        model, X = scene.model, scene.model.X
        rng = np.random.default_rng(cfg.seed)
        x0 = X.copy()
        x0[:, 0] = 0.5 + (X[:, 0] - 0.5) * cfg.cloth_gap
        x0[model.free, 1] += 1e-3 * rng.standard_normal(int(model.free.sum()))
        state = model.make_state(x0)
        offset = (1.2 * k, 0.0, 0.0)
        name = f"cloth_B{B:.3g}"
        integ = make_integrator("backward-euler", solver="cholesky")
        if explicit and k == 0:
            ctx.progress(f"the falls are damped relaxations: they stay backward Euler under --integrator "
                         f"{ctx.stepping.integrator} (fixed)")
        simulate(ctx, name, model, state, cfg.dt, steps, integ, every=cfg.record_every,
                 log=mesh_logger(scene.mesh.triangles, scene.bending, offset), fixed=explicit)
        res = solve_static(model, state.x.to_numpy().astype(np.float64), tol=cfg.static_tol, max_iter=400,
                           raise_on_failure=False)
        exps.append(Experiment(f"B = {B:.3g}: static equilibrium reached (residual)", cfg.static_tol, res.residual,
                               0, "<="))
        if not res.converged:
            ctx.progress(f"B = {B:.3g}: {res.message}")
        log_static(ctx, f"{name}: static equilibrium after {res.iterations} Newton iterations", res.x,
                   scene.mesh.triangles, scene.bending, offset, steps + 1, steps * cfg.dt)
        count = fold_count(scene.mesh, scene.bending, res.x, n)
        folds.append(float(np.mean(count)))
        ctx.progress(f"B = {B:.3g} N m: folds along the three lines {count}, Newton {res.iterations} iterations, "
                     f"residual {res.residual:.2e}")
        if k == 1:
            weight = float(model.mass.sum()) * G
            free_w = float(model.mass[model.free].max()) * G
            bound = int(model.free.sum()) * cfg.static_tol * free_w / weight
            R = res.reactions.sum(axis=0)
            exps += [
                Experiment(f"B = {B:.3g}: vertical pin reactions / total weight (bound: N tol m_max g / W)",
                           1.0, R[2] / weight, bound, "abs"),
                Experiment(f"B = {B:.3g}: horizontal pin reactions cancel (|R_x, R_y| / W)", 0.0,
                           float(np.hypot(R[0], R[1])) / weight, bound, "abs"),
            ]
    labels = [f"{B:.3g}" for B in Bs]
    exps += [
        Experiment(f"folds at B = {labels[0]} >= folds at B = {labels[1]} (mean over three lines)", folds[1], folds[0],
                   0, ">="),
        Experiment(f"folds at B = {labels[1]} >= folds at B = {labels[2]}", folds[2], folds[1], 0, ">="),
        Experiment(f"folds at B = {labels[0]} exceed those at B = {labels[2]} by at least one", folds[2] + 1, folds[0],
                   0, ">="),
    ]
    return exps


# ------------------------------------------------------------------------- stage 5

S5_TEXT = """
A shell that is curved at rest: half a cylinder (an arch of radius 0.5 m and length 1 m),
standing on its two straight edges, which are pinned. If the bending energy measured theta
from zero, this rest shape would be under stress: every hinge would try to flatten. Instead
each hinge gets its own rest angle theta_bar, measured on the rest mesh, and the energy is
1/2 k_e (theta - theta_bar)^2: the curved shape is now the unstressed one, and we check that
it carries no force at all (and how hard theta_bar = 0 would push it).

Under a small load, its own weight, the shell barely moves, and it responds linearly: twice
the weight gives twice the displacement, to within a few percent (a residue of geometric
nonlinearity; the closer the load comes to the arch's buckling load, the larger it gets).
Then we push it with many times its weight, take the load away and let it go with backward
Euler: an elastic shell has a single unstressed shape near the rest shape, and it returns
there, to a millionth of its size after two seconds (backward Euler's numerical damping does
the settling).

The release is a scene run: --integrator replaces backward Euler (an explicit method takes
sub-steps below its CFL estimate, about 160 per 10 ms step here). An explicit symplectic
method has no numerical damping, so the shell does not settle, and the last claim is replaced
by what such a method predicts: the energy of the push stays in the shell (the total energy
over the run differs from the pushed shape's elastic energy by at most 1%: a symplectic
integrator's energy error does not grow, it wobbles with an amplitude of about w h/2 for
symplectic Euler and (w h)^2/4 for Verlet on a mode of frequency w at the sub-step h; here the
motion's rms frequency is about 110 rad/s and h = 6e-5 s, so w h ~ 0.007: a few 1e-3 for
symplectic Euler, a few 1e-5 for Verlet), and the shell oscillates about its rest shape:
averaged over the run, kinetic and elastic energy are equal, as the virial theorem says for
small oscillations about a minimum of the energy (within 5%: the average over a finite run and
the shell's slight nonlinearity). Forward Euler gains energy every step and is stopped by the
energy check.
"""


def stage_shell(ctx):
    cfg = ctx.cfg
    R, length = 0.5, 1.0
    m = meshes.half_cylinder(17, 17, R, length)
    X = np.asarray(m.vertices)
    feet = np.flatnonzero(X[:, 2] < 1e-9 * R)
    masses = meshes.lumped_masses(m, cfg.shell_rho)

    def shell(g):
        model = Model.from_springs(X, m.edges, c=cfg.shell_E * m.edge_measure, mass=masses, pinned=feet,
                                   gravity=[0.0, 0.0, -g])
        energy = model.add_energy(BendingEnergy.from_mesh(m, cfg.shell_B, cfg.bending, from_rest=True))
        return model, energy

    model, energy = shell(G)
    vertex_weight = float(masses[model.free].max()) * G
    rest_force = np.abs(energy.forces(X)[model.free]).max() / vertex_weight
    flat_rest = BendingEnergy.from_mesh(m, cfg.shell_B, cfg.bending)
    flat_force = np.abs(flat_rest.forces(X)[model.free]).max() / vertex_weight
    exps = [
        Experiment("rest angles from the curved mesh: no force at rest (max |f| / vertex weight)", 0.0, rest_force,
                   1e-9, "abs"),
        Experiment("with theta_bar = 0 the rest shape is pushed (max bending |f| / vertex weight)", 1.0, flat_force,
                   0, ">="),
    ]
    d, residuals = [], []
    for factor in (1.0, 2.0):
        model, energy = shell(factor * G)
        res = solve_static(model, tol=cfg.static_tol, max_iter=200, raise_on_failure=False)
        residuals.append(res.residual)
        d.append(float(np.linalg.norm(res.x - X, axis=1).max()))
        if ctx.rec.enabled:
            ctx.rec.run(f"weight_x{factor:g}")
            log_static(ctx, f"weight x{factor:g}: max displacement {d[-1]:.3g} m", res.x, m.triangles, energy,
                       (0.0, 0.0, 0.0), 0, 0.0)
        if factor == 1.0:
            weight = float(masses.sum()) * G
            bound = int(model.free.sum()) * cfg.static_tol * vertex_weight / weight
            exps += [
                Experiment("own weight: max displacement / radius is small", 1e-2, d[0] / R, 0, "<="),
                Experiment("own weight: pin reactions / total weight (bound: N tol m_max g / W)", 1.0,
                           res.reactions[:, 2].sum() / weight, bound, "abs"),
            ]
    exps.append(Experiment("twice the weight gives twice the displacement (ratio)", 2.0, d[1] / d[0], 3e-2, "rel"))
    ctx.progress(f"displacements {d[0]:.3e} m, {d[1]:.3e} m (ratio {d[1] / d[0]:.4f})")
    # the push, then the release (a run without load: backward Euler unless --integrator says otherwise)
    model, energy = shell(cfg.push * G)
    pushed = solve_static(model, tol=cfg.static_tol, max_iter=200, raise_on_failure=False)
    residuals.append(pushed.residual)
    push_d = float(np.linalg.norm(pushed.x - X, axis=1).max()) / R
    free_model, free_energy = shell(0.0)
    state = free_model.make_state(pushed.x)
    steps = int(round(2.0 / cfg.dt))
    W0 = free_model.potential_energy(state.x)
    method = ctx.integrator_name("backward-euler")
    motion = np.zeros(2)  # explicit methods: sums of M|x - X|^2 and M|v|^2 over the sampled steps

    def observe(step, st):
        if step:
            motion[0] += float((masses[:, None] * (st.x.to_numpy() - X) ** 2).sum())
            motion[1] += float((masses[:, None] * st.v.to_numpy() ** 2).sum())

    _, kin, pot = simulate(ctx, "release", free_model, state, cfg.dt, steps,
                           make_integrator("backward-euler", solver="cholesky"), every=cfg.record_every,
                           observe=None if method == "backward-euler" else observe,
                           log=mesh_logger(m.triangles, free_energy, (1.5, 0.0, 0.0)), energy_bound=10 * W0)
    back = float(np.abs(state.x.to_numpy() - X).max()) / R
    ctx.progress(f"push: max displacement {push_d:.3e} R; {steps * cfg.dt:g} s after the release: {back:.2e} R")
    exps += [
        Experiment("static solves (weight, 2x weight, push) reached the tolerance (max residual)", cfg.static_tol,
                   max(residuals), 0, "<="),
        Experiment(f"the push ({cfg.push:g} x weight) deforms visibly (max displacement / R)", 1e-2, push_d, 0, ">="),
    ]
    if method == "backward-euler":
        exps.append(Experiment("2 s after the release the shell is back at rest (max |x - X| / R)", 1e-6, back, 0,
                               "<="))
        return exps
    drift = float(np.abs(kin + pot - W0).max()) / W0
    virial = float(kin.mean() / pot.mean())
    ctx.progress(f"{method}: energy {W0:.4g} J at the release, largest deviation {drift:.2e} of it; mean kinetic / "
                 f"mean elastic energy {virial:.4f} ({len(kin)} samples); rms frequency of the motion "
                 f"sqrt(<M v^2>/<M u^2>) = {math.sqrt(motion[1] / motion[0]):.4g} rad/s")
    exps += [
        Experiment(f"{method} does not damp: total energy after the release = the push's elastic energy "
                   f"(max |E - W0| / W0)", 0.0, drift, 1e-2, "abs"),
        Experiment(f"{method}: the shell oscillates about its rest shape: mean kinetic / mean elastic energy = 1 "
                   f"(virial theorem)", 1.0, virial, 5e-2, "rel"),
    ]
    return exps


LESSON_STAGES = [
    Stage("the hinge", S1_TEXT, stage_hinge),
    Stage("curvature on a cylinder", S2_TEXT, stage_curvature),
    Stage("energy against the continuum", S3_TEXT, stage_continuum),
    Stage("a hanging cloth folds", S4_TEXT, stage_cloth),
    Stage("a curved shell keeps its shape", S5_TEXT, stage_shell),
]

LESSON = Lesson(
    id="bending",
    title="Dihedral bending: hinge, curvature, the one-third ratio, cloth folds, curved shells",
    summary="The notes' dihedral-angle bending energy: its gradient (Bridson's u vectors), the "
            "cylinder curvature estimate, why regular meshes get a third of the continuum energy "
            "(and Discrete Shells' fix), a hanging cloth that folds, and a curved shell that keeps its shape.",
    config=BendingConfig,
    stages=LESSON_STAGES,
    order=4,
)
