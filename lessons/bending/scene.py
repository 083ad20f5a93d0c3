"""The scene of ``bending``: what its stages measure on (hinges, analytic or random, with the
engine's angle gradient and Bridson's u vectors on them; flat sheets wrapped on cylinders and
the continuum's energy there; the arch-shaped shell) and how the hinges, sheets, cloths and the
shell are drawn.

The lesson has no estimates of its stages' time and no budget check, so this file has no
budget section.
"""
import math

import numpy as np
import taichi as ti

from engine import mesh as meshes
from engine.energies.bending import BendingEnergy, bridson_u_kernel, theta_gradient_kernel
from engine.fields import vec3_ndarray
from engine.model import Model
from lessons.views import RunView

from .._measure import random_rotation

# ------------------------------------------------------------------ builders: hinges, sheets, the shell

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


def edge_family_folds(flat, angle_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """On a right-triangle grid turned by a against the cylinder axis (from :func:`sheet`), each
    hinge's small-bend fold angle in units of h/R, by its edge's family (stage 3's narrative):
    (cos^2 a - cos a sin a) along the axis at a = 0, (sin^2 a - cos a sin a) around it and
    sqrt2 cos a sin a on the diagonals. Returns (family index 0..2 per hinge, predicted theta R/h)."""
    H, V = flat.hinges, flat.vertices
    d = V[H[:, 1]] - V[H[:, 0]]
    eighth = np.round((np.degrees(np.arctan2(d[:, 1], d[:, 0])) - angle_deg) / 45.0).astype(int) % 4
    c, s = math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))
    family = np.array([1, 2, 0, 2])[eighth]  # edges at 0, 45, 90, 135 degrees from the grid's rows
    return family, np.array([c * c - c * s, s * s - c * s, math.sqrt(2) * c * s])[family]


def continuum_energy(B, R, area):
    """1/2 B H^2 * area with the mean curvature H = 1/(2R) of a cylinder."""
    return 0.5 * B * (1.0 / (2.0 * R)) ** 2 * area


SHELL_RADIUS = 0.5  # m


class Shell:
    """Half a cylinder (an arch of radius 0.5 m and length 1 m) standing on its pinned straight
    edges, with rest angles from its curved mesh."""

    R, length = SHELL_RADIUS, 1.0

    def __init__(self, cfg):
        self.cfg = cfg
        self.mesh = meshes.half_cylinder(17, 17, self.R, self.length)
        self.X = np.asarray(self.mesh.vertices)
        self.feet = np.flatnonzero(self.X[:, 2] < 1e-9 * self.R)
        self.masses = meshes.lumped_masses(self.mesh, cfg.shell_rho)

    def under(self, g: float):
        """(model, bending energy) of the shell under gravity g."""
        cfg, m = self.cfg, self.mesh
        model = Model.from_springs(self.X, m.edges, c=cfg.shell_E * m.edge_measure, mass=self.masses,
                                   pinned=self.feet, gravity=[0.0, 0.0, -g])
        energy = model.add_energy(BendingEnergy.from_mesh(m, cfg.shell_B, cfg.bending, from_rest=True))
        return model, energy


# ------------------------------------------------------------------ drawing

CONTINUUM_KEY = "energy density / continuum"


def log_sheet(ctx, name, label, x, triangles, energy: BendingEnergy, B: float = 1.0):
    """One frame of a wrapped sheet in its own view, coloured by its bending energy density over
    the continuum's 1/2 B H^2 on the cylinder of radius cfg.radius (yellow: the continuum's
    value; nothing if not recording)."""
    rec = ctx.rec
    if not rec.enabled:
        return
    R = ctx.cfg.radius
    rec.run(name, RunView(label=label, camera="outside", energy=None))
    rec.set_time(0, 0.0)
    density = energy.energy_density(x) / (0.5 * B / (2.0 * R) ** 2)
    rec.mesh(np.asarray(x), triangles, rec.colors(density, "magnitude", CONTINUUM_KEY, 1.0))


ENERGY_KEY = "bending energy density (J/m²)"


def draw_opening_hinge(rec, notes, frames: int = 121):
    """The hinge opening from flat to 3 rad (the progress timeline is theta / 3 rad), coloured by
    its energy density on the scale of the fully opened hinge, with its forces as lines."""
    tris = np.array([[0, 1, 2], [1, 0, 3]])
    top = analytic_hinge(3.0)
    scale = float(notes.energy_density(top).max())
    gain = 0.3 / float(np.linalg.norm(notes.forces(top), axis=1).max())  # the largest force: 0.3 m
    rec.run("hinge", RunView(label=f"one hinge folding from theta = 0 to 3 rad; lines: its forces -dW/dx "
                                   f"({gain:.2g} m per N)", camera="outside", energy=None),
            n_steps=frames - 1, dt=3.0 / (frames - 1))
    for k, th in enumerate(np.linspace(0.0, 3.0, frames)):
        x = analytic_hinge(th)
        rec.set_time(k, th)
        if k == 0:  # static names of the parts that stay put
            rec.labels("names", [0.5 * (x[0] + x[1]) + [0, 0, 0.04], x[2] + [0, 0, 0.04]],
                       ["the shared edge e", "fixed wing"])
        rec.mesh(x, tris, rec.colors(notes.energy_density(x), "magnitude", ENERGY_KEY, scale))
        fx = notes.forces(x)
        rec.line_strips("force", np.stack([x, x + gain * fx], axis=1), colors=[[255, 140, 40]], radii=0.006)


def mesh_logger(triangles, energy: BendingEnergy, scale: float):
    """log(rec, state) for simulate(): the mesh coloured by its bending energy density (yellow at
    ``scale`` J/m^2)."""
    def log(rec, state):
        x = state.x.to_numpy().astype(np.float64)
        rec.mesh(x, triangles, rec.colors(energy.energy_density(x), "magnitude", ENERGY_KEY, scale))
    return log


def displacement_logger(triangles, X, scale: float):
    """log(rec, state) for simulate(): the mesh coloured by each vertex's distance from the rest
    shape X (yellow at ``scale`` m)."""
    def log(rec, state):
        x = state.x.to_numpy().astype(np.float64)
        rec.mesh(x, triangles, rec.colors(np.linalg.norm(x - X, axis=1), "magnitude",
                                          "displacement (m)", scale))
    return log


def log_static(ctx, text, x, colors, triangles, step, time):
    """The static equilibrium x as the current run's frame at (step, time), marked with ``text``."""
    if ctx.rec.enabled:
        ctx.rec.set_time(step, time)
        ctx.rec.mesh(x, triangles, colors)
        ctx.rec.mark(text, level="INFO")
