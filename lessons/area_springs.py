"""Lesson ``area-springs``: springs in 2D and 3D scaled by the area or volume they stand for.

The notes' multi-dimensional spring potential W_ij = 1/2 E (|x_i - x_j|/L_ij - 1)^2 A_ij, with
A_ij = engine.mesh.edge_measure (a third of each neighbouring triangle, a sixth of each
neighbouring tet), is the engine's SpringEnergy with c_e = E A_e. This module builds meshes,
runs standing waves and a static stretch through the engine, measures speeds and moduli
and compares them with the long-wavelength theory of engine.waves (Cauchy-Born sum and
Christoffel equation).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from engine import mesh as M
from engine.errors import ParameterError
from engine.integrators.explicit import stable_dt_estimate
from engine.model import Model
from engine.waves import (ModeProbe, cauchy_born_tensor, christoffel, max_speed, phase_frequency,
                          relaxed_stiffness_2d, young_poisson)

from ._framework import Experiment, Lesson, Stage, param
from ._measure import be_damping_rate, damped_frequency, edge_strain, vertex_strain
from ._scene import simulate

RUN_PERIODS = 0.3   # each standing-wave run lasts this fraction of a period (phase 0 -> 1.9 rad)
BOX_LENGTH = 1.0    # m, the tet box of stage 1 and the cell size unit of stage 4
SMALL_JITTER = 0.1  # a mild jitter whose affine prediction is still close
BE_PHASE_STEP = 0.05  # w dt of the backward-Euler runs: phase lag 1 - arctan(w dt)/(w dt) = 8.3e-4
BE_PHASE_LAG = 1e-3   # the bound on that lag, a tenth of the tightest tolerance (1e-2) of the speeds
BE_DAMPING_TOL = 0.03  # fitted / predicted decay rate: the decay over a run is only ~5%, and the probe
                       # also sees a little of other motion (up to 1.7% measured on the regular meshes)


@dataclass
class AreaSpringsConfig:
    E: float = param(1.0, "Young's modulus E in W = 1/2 E (l/L-1)^2 A (sheets: N/m, the box: Pa)", "N/m | Pa", gt=0)
    rho: float = param(1.0, "density (sheets: kg/m^2 per area, the box: kg/m^3)", "kg/m^2 | kg/m^3", gt=0)
    wavelength: int = param(48, "wavelength of the 2D standing waves, in lattice spacings", ge=16, le=160)
    box_cells: int = param(8, "cells along the coarsest 1 m tet box (stage 1 refines it x2 and x4)", ge=6, le=12)
    box_wavelength: int = param(20, "wavelength of the 3D waves of stage 4 on the coarse box, in cells", ge=8, le=24)
    jitter: float = param(0.25, "jitter amplitude of stage 3 (fraction of the local edge length)", gt=0, le=0.25)
    jitter_seeds: int = param(3, "jittered meshes (random seeds) in stage 3", ge=1, le=8)
    strain: float = param(1e-3, "peak strain of the waves and the stretch of stage 5", gt=0, le=0.01)
    strip_cells: int = param(80, "length of the stage-5 strip in lattice spacings (width: a quarter)", ge=40, le=240)
    cfl: float = param(0.5, "time step as a fraction of the engine's Gershgorin CFL estimate", gt=0, le=1)
    frames: int = param(5, "geometry frames recorded per displayed run", ge=1, le=12)


# ----------------------------------------------------------------------------- helpers

def area_model(mesh3: M.Mesh, E: float, rho: float, pinned=None) -> tuple[Model, np.ndarray, np.ndarray]:
    """Area/volume-scaled springs on a 3D-embedded mesh: (model, c_e = E A_e, lumped masses)."""
    c = E * M.edge_measure(mesh3)
    mass = M.lumped_masses(mesh3, rho)
    return Model.from_springs(mesh3.vertices, mesh3.edges, c=c, mass=mass, pinned=pinned), c, mass


def bulk_tensor(mesh: M.Mesh, c: np.ndarray, h: float) -> np.ndarray:
    """Cauchy-Born C of the infinite lattice from the springs of 3 x 3 x 3 interior cells of a
    tet box (midpoints in a window offset by h/4, so every spring class is counted once per
    cell), for any coefficients c (also the constant-k springs)."""
    X, e = mesh.vertices, mesh.edges
    mid = 0.5 * (X[e[:, 0]] + X[e[:, 1]])
    lo = X.min(axis=0) + 1.25 * h
    inside = np.all((mid >= lo) & (mid < lo + 3 * h), axis=1)
    return cauchy_born_tensor(X, e[inside], c[inside], 27 * h ** 3)


def standing_wave(ctx, name: str, model: Model, mass: np.ndarray, direction, polarization, k: float,
                  origin, region: np.ndarray, c_guess: float, draw=None, fits: list | None = None) -> float:
    """Start u = A cos(k (X - origin).n) p from rest, run RUN_PERIODS of a period (sized with
    ``c_guess``; the measurement does not use it) with velocity Verlet (or the integrator of
    ``--integrator``), and return the measured phase speed w/k from the amplitude over ``region``
    (engine.waves).

    Under backward Euler (stable at any step) the step is BE_PHASE_STEP/(k c_guess), whatever the
    CFL limit, so that the scheme's phase lag 1 - arctan(w dt)/(w dt) is the same 8e-4 in every
    run, and the amplitude, which the scheme damps, is fitted as a(0) exp(-gamma t) cos(w t); the
    fit (dt, w, gamma) is appended to ``fits``."""
    cfg = ctx.cfg
    X = model.X
    probe = ModeProbe(X, mass, direction, polarization, k, origin, region)
    A = cfg.strain / k  # peak strain k A
    state = model.make_state(X + probe.displacement(A))
    implicit = ctx.integrator_name("velocity-verlet") == "backward-euler"
    dt = BE_PHASE_STEP / (k * c_guess) if implicit else cfg.cfl * stable_dt_estimate(model)
    n_steps = max(8, int(math.ceil(RUN_PERIODS * 2 * math.pi / (k * c_guess) / dt)))
    times, amps = [], []

    def observe(step, st):
        times.append(step * dt)
        amps.append(probe.amplitude(st.x.to_numpy()))

    log = None
    if draw is not None and ctx.rec.enabled:
        every = max(1, n_steps // cfg.frames)

        def log(rec, st):
            step = int(round(st.t / dt))
            if step % every == 0 or step == n_steps:
                draw(rec, st.x.to_numpy().astype(np.float64), A)

    W0 = model.potential_energy(state.x)
    stepping = ctx.stepping
    if implicit and stepping.solver == "cholesky" and np.ptp(X[:, 2]) > 0:
        # a direct LL^T of a 3D lattice fills in far more than a sheet's: Eigen's simplicial
        # factorisation (one per step) takes ~1 s for the smallest box here (3249 vertices) and
        # ~40 s at 10^4; the boxes go up to 107217 vertices
        ctx.progress(f"{name}: --solver cholesky is impractical for this 3D box ({model.n} vertices; a direct "
                     f"LL^T of a 3D lattice fills in: ~1 s per step at 3249 vertices, ~40 s at 10^4): this run "
                     f"uses pcg")
        ctx.stepping = dataclasses.replace(stepping, solver="pcg")
    try:
        simulate(ctx, name, model, state, dt, n_steps, integrator="velocity-verlet", every=1,
                 energy_bound=10 * W0, observe=observe, log=log, energy_every=4)
    finally:
        ctx.stepping = stepping
    if not implicit:
        return phase_frequency(np.asarray(times), np.asarray(amps)) / k
    w, gamma = damped_frequency(np.asarray(times), np.asarray(amps))
    if fits is not None:
        fits.append(dict(name=name, dt=dt, w=w, gamma=gamma))
    ctx.progress(f"{name}: backward Euler, dt = {dt:.4g} s (w dt = {w * dt:.4f}), fitted damping "
                 f"{gamma:.4g} 1/s, the scheme's {be_damping_rate(w, dt):.4g} 1/s")
    return w / k


def be_experiments(ctx, fits: list, jittered: list = ()) -> list:
    """Under backward Euler (``fits`` not empty): the fitted damping of the runs on regular meshes
    (``fits``) against the scheme's own, and the largest phase lag of all runs."""
    if not fits:
        return []
    ratios = [f["gamma"] / be_damping_rate(f["w"], f["dt"]) for f in fits]
    worst = max(ratios, key=lambda q: abs(q - 1))
    every = list(fits) + list(jittered)
    phase = max(1 - f["w"] * f["dt"] / math.tan(f["w"] * f["dt"]) for f in every)
    ctx.progress(f"backward Euler: fitted damping / the scheme's on the regular meshes: "
                 + ", ".join(f"{q:.4f}" for q in ratios) + "; largest phase lag 1 - arctan(W dt)/(W dt) = "
                 f"{phase:.2e} ({len(every)} runs)")
    return [
        Experiment(f"backward Euler damps each wave by 1/sqrt(1 + (W dt)^2) per step: fitted / scheme's decay "
                   f"rate (worst of {len(fits)} runs)", 1.0, worst, BE_DAMPING_TOL),
        Experiment(f"backward Euler's phase lag 1 - arctan(W dt)/(W dt) at the chosen dt (largest of {len(every)})",
                   BE_PHASE_LAG, phase, 0, "<="),
    ]


def _colors(strain, scale):
    from engine.recorder import strain_colors  # rerun only when recording
    return strain_colors(strain, scale)


def sheet_drawer(mesh3: M.Mesh, spacing: float, k: float):
    """Draw a sheet: triangles with per-vertex strain colours and strain-coloured springs;
    displacements magnified so the wave's amplitude shows as a quarter spacing."""
    X, E, L, T = mesh3.vertices, mesh3.edges, mesh3.rest_lengths, mesh3.triangles

    def draw(rec, x, amplitude):
        s = edge_strain(x, E, L)
        scale = k * amplitude
        xd = X + (0.25 * spacing / amplitude) * (x - X)
        rec.mesh(xd, T, vertex_colors=_colors(vertex_strain(len(X), E, s), scale))
        rec.springs(xd, E, s, scale=scale)
    return draw


def solid_drawer(mesh: M.Mesh, spacing: float, k: float, springs: bool = True):
    """Draw a tet box by its surface (vertex strain colours) and the springs on it."""
    faces = M.boundary_faces(mesh)
    verts, inv = np.unique(faces, return_inverse=True)
    faces_local = inv.reshape(-1, 3)
    pairs = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    surf = np.unique(pairs, axis=0)
    X, E, L = mesh.vertices, mesh.edges, mesh.rest_lengths
    Ls = np.linalg.norm(X[surf[:, 1]] - X[surf[:, 0]], axis=1)

    def draw(rec, x, amplitude):
        scale = k * amplitude
        xd = X + (0.25 * spacing / amplitude) * (x - X)
        vs = vertex_strain(len(X), E, edge_strain(x, E, L))
        rec.mesh(xd[verts], faces_local, vertex_colors=_colors(vs[verts], scale))
        if springs:
            rec.springs(xd, surf, edge_strain(x, surf, Ls), scale=scale)
    return draw


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def square_domain_cells(half: float, spacing: float) -> int:
    return 2 * int(math.ceil(half / spacing))


# ---------------------------------------------------------------------------- stage 1

S1_TEXT = """
In 2D and 3D the rod's spring energy is kept edge by edge, W_ij = 1/2 E (l/L - 1)^2 A_ij, but
the rod's length factor h is replaced by the area (2D) or volume (3D) A_ij that the spring
stands for: each triangle hands a third of its area to each of its edges, each tet a sixth of
its volume. The sum over springs then approximates the integral of an energy density over
the body, and E and rho are properties of the material, not of the mesh. In the engine this is
SpringEnergy with coefficient c_e = E A_e and lumped masses (a quarter of each tet's mass per
corner).

Why bother? Take the notes' plain spring with the same constant k for every spring,
W = 1/2 k (l/L - 1)^2 L. A wave crosses a spring of length L and mass m in a time of order
sqrt(m L / k), so c ~ sqrt(k L / m). Refining a 3D mesh halves L and divides every mass by 8
(m ~ rho h^3): c ~ sqrt(k h / (rho h^3)) ~ 1/h. The same k on a finer mesh is a stiffer
material: the predicted speeds at h/2 and h/4 are 2 and 4 times the speed at h. With
c_e = E A_e the coefficient shrinks like h^3, exactly as the masses do, and the speed stays.

We measure on a tet box 1 m long (six Kuhn tets per cubic cell), refined from h to h/2 and
h/4, with a standing compression wave u = A cos(pi x / 1 m) p along x started from rest. Its
angular frequency w gives the speed c = w/k. On this lattice the free ends at x = 0 and 1 m
fit that wave exactly (the end layers have half the mass and the springs of one side), and
the box is wide enough that nothing from its sides reaches the centre line, where the
amplitude is read, during the run (0.3 of a period). Velocity Verlet is used because,
started from rest, its samples are symmetric about t = 0, so the phase fit has no half-step
offset. The constant k is tuned on the coarsest box so that both laws agree there.

Every standing-wave run of this lesson is a scene run: --integrator replaces velocity Verlet
(no run is fixed; stage 5 is static and has no time step). Symplectic Euler advances the phase
exactly as Verlet does (sin(w dt/2) = W dt/2 for a mode of true frequency W: the speed comes out
high by (W dt)^2/24, at most about 1e-3 here); started from rest its samples are shifted by
half a step, which the phase fit, leaving out the first samples (a/a(0) > 0.97), barely sees.
Forward Euler feeds energy into every oscillation and is stopped by the energy check. Backward
Euler is stable at any step, but per step it turns the phase of a mode by only arctan(W dt) and
multiplies its amplitude by 1/sqrt(1 + (W dt)^2): a wave is slowed by arctan(W dt)/(W dt) and
damped. Under it we therefore choose the step from the phase, not from the CFL limit: W dt = 0.05
with W = k times the predicted speed, so the slowdown is 8.3e-4 in every run, below a tenth of
the tightest tolerance (1e-2) and the same in every run, so it cancels from the speed ratios.
The amplitude is then fitted as a(0) exp(-gamma t) cos(w t), and each wave stage adds two
experiments on the scheme itself: gamma against the scheme's own decay rate -ln(cos(w dt))/dt
(the amplitude factor per step is the cosine of the phase step; within 3%), and the bound on
the phase lag. With --solver cholesky the 3D boxes (stages 1 and 4) use pcg instead: a direct
factorisation of a 3D lattice, one per step, takes about a second at 3249 vertices and far
longer on the larger boxes; the stage's integrators line shows what ran.
"""


def stage_refinement(ctx):
    cfg = ctx.cfg
    levels = [cfg.box_cells * 2 ** i for i in range(3)]
    k = math.pi / BOX_LENGTH
    speeds = {"area": [], "k": []}
    fits = []
    k_spring = None
    for level, nc in enumerate(levels):
        h = BOX_LENGTH / nc
        probe_mesh = M.tet_box(6, 6, 6, size=5 * h)  # the same lattice, for the bulk tensors
        C_area = bulk_tensor(probe_mesh, cfg.E * probe_mesh.edge_measure, h)
        if k_spring is None:  # k = 1 N gives C proportional to k: scale k to match the area law
            s_area = christoffel(C_area, [1, 0, 0], cfg.rho)[0][-1]
            s_one = christoffel(bulk_tensor(probe_mesh, probe_mesh.rest_lengths, h), [1, 0, 0], cfg.rho)[0][-1]
            k_spring = (s_area / s_one) ** 2
            ctx.progress(f"constant spring stiffness tuned on the coarse box: k = {k_spring:.6g} N")
        laws = {"area": (C_area, lambda m: cfg.E * m.edge_measure),
                "k": (bulk_tensor(probe_mesh, k_spring * probe_mesh.rest_lengths, h), lambda m: k_spring * m.rest_lengths)}
        ratio = max(max_speed(C, cfg.rho) / christoffel(C, [1, 0, 0], cfg.rho)[0][-1] for C, _ in laws.values())
        half = 2 * h + RUN_PERIODS * 2 * BOX_LENGTH * ratio  # lateral half-width: no reflection reaches the centre
        ny = square_domain_cells(half, h) + 1
        mesh = M.tet_box(nc + 1, ny, ny, size=(BOX_LENGTH, (ny - 1) * h, (ny - 1) * h))
        X = mesh.vertices
        mass = M.lumped_masses(mesh, cfg.rho)
        yc = 0.5 * (ny - 1) * h
        band = (np.abs(X[:, 1] - yc) <= 1.01 * h) & (np.abs(X[:, 2] - yc) <= 1.01 * h)
        draw = solid_drawer(mesh, h, k, springs=level == 0) if level < 2 else None
        ctx.progress(f"h = {h:.4g} m: {mesh.n_vertices} vertices, {len(mesh.edges)} springs")
        for law, (C, coef) in laws.items():
            speeds_th, pol = christoffel(C, [1, 0, 0], cfg.rho)
            model = Model.from_springs(X, mesh.edges, c=coef(mesh), mass=mass)
            c = standing_wave(ctx, f"{law}_h{nc}", model, mass, [1, 0, 0], pol[:, -1], k, (0.0, 0.0, 0.0),
                              band, speeds_th[-1], draw, fits)
            speeds[law].append(c)
            ctx.progress(f"  {law:4s}: measured {c:.5f} m/s, Cauchy-Born {speeds_th[-1]:.5f} m/s")
    a, kk = speeds["area"], speeds["k"]
    return [
        Experiment("one k for all springs: speed ratio c(h/2)/c(h) = 2 (c ~ 1/h)", 2.0, kk[1] / kk[0], 2e-2),
        Experiment("one k for all springs: speed ratio c(h/4)/c(h) = 4 (c ~ 1/h)", 4.0, kk[2] / kk[0], 2e-2),
        Experiment("k tuned on the coarse box: same speed as E*A springs there", 1.0, kk[0] / a[0], 1e-2),
        Experiment("volume-scaled springs: speed ratio c(h/2)/c(h) = 1", 1.0, a[1] / a[0], 1e-2),
        Experiment("volume-scaled springs: speed ratio c(h/4)/c(h) = 1", 1.0, a[2] / a[0], 1e-2),
    ] + be_experiments(ctx, fits)


# ---------------------------------------------------------------------------- stage 2

S2_TEXT = """
What material does a spring network make? Stretch it by a small uniform strain eps: a spring
along the unit vector n changes its strain by n.eps.n, so the network stores
W = 1/2 sum_e c_e (n.eps.n)^2. A continuum with stiffness tensor C stores 1/2 A C:eps:eps, so
the two agree for C_ijkl = (1/A) sum_e c_e n_i n_j n_k n_l (the Cauchy-Born sum), which is
the long-wavelength limit of the network when every vertex is a centre of symmetry of its
springs (a uniform strain is then in equilibrium everywhere).

On the equilateral lattice each of the three edge directions (0, 60, 120 degrees) carries a
third of the area, so C = (E/3) sum over the three directions of n n n n. Averaging n n n n
over three directions 60 degrees apart gives (1/8)(d_ij d_kl + d_ik d_jl + d_il d_jk), so
C = (E/8)(d_ij d_kl + d_ik d_jl + d_il d_jk): an isotropic sheet with Lame constants
lambda = mu = E/8. Waves follow: P (displacement along the travel direction) at
sqrt((lambda + 2 mu)/rho) = sqrt(3/8) c0 = 0.612 c0 and S (displacement across it) at
sqrt(mu/rho) = sqrt(1/8) c0 = 0.354 c0, with c0 = sqrt(E/rho) and rho the mass per area.
Their ratio is sqrt(3) exactly because lambda = mu.

We check this with standing waves cos(k (x - x_c).n) p of a long wavelength (48 spacings by
default: the theory is the limit of wavelength >> spacing) along the x axis (an edge
direction) and the y axis (across the edges), read in a disc at the centre of a sheet large
enough that no disturbance from its free edges arrives there during the run. The colours show
the strain of each spring (red stretched, blue compressed); displacements are drawn magnified.
"""


def eq_sheet(cfg, half_cells: float, spacing: float = 1.0) -> M.Mesh:
    """An equilateral lattice about 2*half_cells spacings on a side."""
    nx = square_domain_cells(half_cells * spacing, spacing) + 1
    ny = square_domain_cells(half_cells * spacing, spacing * math.sqrt(3) / 2) + 1
    return M.equilateral_lattice(nx, ny, spacing)


def stage_equilateral(ctx):
    cfg = ctx.cfg
    lam = float(cfg.wavelength)  # spacing 1 m
    k = 2 * math.pi / lam
    c0 = math.sqrt(cfg.E / cfg.rho)
    cP, cS = math.sqrt(3 / 8) * c0, math.sqrt(1 / 8) * c0
    r = 0.15 * lam
    half = r + RUN_PERIODS * lam * (cP / cS) * 1.05 + 2.0
    m2 = eq_sheet(cfg, half)
    m3 = M.embed_3d(m2)
    model, c, mass = area_model(m3, cfg.E, cfg.rho)
    C = cauchy_born_tensor(m2.vertices, m2.edges, c, m2.total_measure)
    ctx.progress(f"sheet: {m2.n_vertices} vertices, {len(m2.edges)} springs; Cauchy-Born C_xxxx = "
                 f"{C[0, 0, 0, 0]:.5f}, C_xxyy = {C[0, 0, 1, 1]:.5f}, C_xyxy = {C[0, 1, 0, 1]:.5f} (3E/8, E/8, E/8)")
    V = m2.vertices
    ctr = 0.5 * (V.min(axis=0) + V.max(axis=0))
    region = np.linalg.norm(V - ctr, axis=1) <= r
    draw = sheet_drawer(m3, 1.0, k)
    out, fits = {}, []
    for label, d in (("x", [1.0, 0.0]), ("y", [0.0, 1.0])):
        n = _unit(d)
        for wave, p, guess in (("P", n, cP), ("S", np.array([-n[1], n[0]]), cS)):
            out[wave, label] = standing_wave(ctx, f"{wave}_along_{label}", model, mass, n, p, k, ctr, region,
                                             guess, draw if label == "x" else None, fits)
            ctx.progress(f"{wave} along {label}: {out[wave, label]:.5f} m/s")
    ratio = 0.5 * (out["P", "x"] / out["S", "x"] + out["P", "y"] / out["S", "y"])
    return [
        Experiment("P wave along x (an edge direction) = sqrt(3/8) c0", cP, out["P", "x"], 2e-2, "rel", "m/s"),
        Experiment("P wave along y (across the edges) = sqrt(3/8) c0", cP, out["P", "y"], 2e-2, "rel", "m/s"),
        Experiment("S wave along x = sqrt(mu/rho) = sqrt(1/8) c0", cS, out["S", "x"], 2e-2, "rel", "m/s"),
        Experiment("S wave along y = sqrt(1/8) c0", cS, out["S", "y"], 2e-2, "rel", "m/s"),
        Experiment("c_P/c_S = sqrt(3), i.e. lambda = mu (Cauchy relation)", math.sqrt(3), ratio, 1e-2),
        Experiment("isotropy: P speed along y / along x = 1", 1.0, out["P", "y"] / out["P", "x"], 1e-2),
    ] + be_experiments(ctx, fits)


# ---------------------------------------------------------------------------- stage 3

S3_TEXT = """
Area scaling removes the dependence on resolution for a fixed pattern. It does not remove the
dependence on the pattern: the Cauchy-Born sum C_ijkl = (1/A) sum_e E A_e n_i n_j n_k n_l
depends on which directions the springs take. A P wave travelling along n has speed c with
rho c^2 the largest eigenvalue of Gamma_ik = C_ijkl n_j n_l (the Christoffel equation).

Right-triangle grids of square cells h x h, every edge of the first two carrying A_e = h^2/3.

One-way diagonals (all along (1,1)): C = (E/3)(x x x x + y y y y + d d d d). Along x,
Gamma = (E/12)[[5, 1], [1, 1]], a quasi-P wave at sqrt((3 + sqrt5)/12) c0 = 0.661 c0; along
the diagonals sqrt(1/2) c0 = 0.707 c0; across them sqrt(1/6) c0 = 0.408 c0. The same sheet
is 1.73 times faster in one diagonal direction than in the other.

Alternating diagonals (half (1,1), half (1,-1)): along x sqrt(5/12) c0 = 0.645 c0, along
either diagonal sqrt(1/3) c0 = 0.577 c0.

Crossed (four triangles per cell around a centre vertex; axis edges and half-diagonals all
carry h^2/6): along x sqrt(1/3) c0, along a diagonal sqrt(5/12) c0, the alternating grid's
numbers turned by 45 degrees.

None of them is isotropic, and none matches the equilateral sheet of stage 2 made of the
same E and rho. For jittered meshes the sum runs over the actual, irregular springs, so it
still predicts a number; but a jittered vertex is no longer a centre of symmetry, a uniform
strain is not in equilibrium, the vertices relax and the sheet is softer than that sum: the
affine sum is an upper bound, close for mild jitter (0.1) and a few per cent high for strong
jitter (0.25). We also compute the relaxed stiffness: the boundary vertices follow a uniform
strain, the interior settles into equilibrium (a sparse linear solve, with scipy, of the
engine's rest Hessian), and the energy density in the measuring disc gives C. (Under backward
Euler the damping check leaves the jittered meshes out: their affine start is not a normal
mode, it also sets off the fast non-affine relaxation of the vertices, which the scheme damps
much harder, so the fitted decay comes out 2-20% above the single-mode rate; the speeds are
not affected.)

So: area scaling fixes resolution dependence for a given pattern. It does not fix pattern
dependence (anisotropy, different speeds for the same E), and no choice of E or pattern frees
Poisson's ratio: pair springs always obey the Cauchy relation C_xxyy = C_xyxy, so an
isotropic spring network has lambda = mu, Poisson's ratio 1/3 in 2D and 1/4 in 3D. A rubber
sheet (nearly incompressible) cannot be built from springs alone.
"""


def stage_patterns(ctx):
    cfg = ctx.cfg
    lam = float(cfg.wavelength)
    k = 2 * math.pi / lam
    c0 = math.sqrt(cfg.E / cfg.rho)
    r = 0.15 * lam
    dirs = {"x": [1.0, 0.0], "y": [0.0, 1.0], "diagonal (1,1)": [1.0, 1.0], "diagonal (1,-1)": [1.0, -1.0]}
    exps = []
    half = r + RUN_PERIODS * lam * math.sqrt(3) * 1.05 + 2.0  # the slowest wave here is 1/sqrt(3) of the fastest
    n = square_domain_cells(half, 1.0) + 1
    measured, fits = {}, []
    for pattern in ("one-way", "alternating", "crossed"):
        m2 = M.right_triangle_grid(n, n, n - 1.0, n - 1.0, pattern)
        m3 = M.embed_3d(m2)
        model, c, mass = area_model(m3, cfg.E, cfg.rho)
        C = cauchy_born_tensor(m2.vertices, m2.edges, c, m2.total_measure)
        ctr = np.full(2, 0.5 * (n - 1))
        region = np.linalg.norm(m2.vertices - ctr, axis=1) <= r
        for label, d in dirs.items():
            speeds, pol = christoffel(C, d, cfg.rho)
            draw = sheet_drawer(m3, 1.0, k) if label == "x" else None
            v = standing_wave(ctx, f"{pattern}_{label}", model, mass, _unit(d), pol[:, -1], k, ctr, region,
                              speeds[-1], draw, fits)
            measured[pattern, label] = (v, speeds[-1])
            ctx.progress(f"{pattern}, P along {label}: measured {v:.5f}, Cauchy-Born {speeds[-1]:.5f} m/s")
            exps.append(Experiment(f"{pattern} grid: P wave along {label} = Cauchy-Born ({speeds[-1] / c0:.4f} c0)",
                                   speeds[-1], v, 2e-2, "rel", "m/s"))
    v1, t1 = measured["one-way", "diagonal (1,1)"]
    v2, t2 = measured["one-way", "diagonal (1,-1)"]
    exps.append(Experiment("one-way grid is anisotropic: speed along / across its diagonals", t1 / t2, v1 / v2, 2e-2))
    jittered = []
    exps += _jitter_experiments(ctx, n, k, lam, jittered)
    return exps + be_experiments(ctx, fits, jittered)


def _jitter_experiments(ctx, n, k, lam, fits):
    cfg = ctx.cfg
    base = M.right_triangle_grid(n, n, n - 1.0, n - 1.0, "one-way")
    ctr = np.full(2, 0.5 * (n - 1))
    r = 0.25 * lam  # a larger disc averages over more of the disorder
    exps, speeds, bound = [], [], []
    cases = [(cfg.jitter, seed) for seed in range(cfg.jitter_seeds)] + [(SMALL_JITTER, 100)]
    for amp, seed in cases:
        m2 = M.jitter(base, amp, seed)
        m3 = M.embed_3d(m2)
        model, c, mass = area_model(m3, cfg.E, cfg.rho)
        C_affine = cauchy_born_tensor(m2.vertices, m2.edges, c, m2.total_measure)
        region = np.linalg.norm(m2.vertices - ctr, axis=1) <= r
        window = np.linalg.norm(m2.vertices[m2.triangles].mean(axis=1) - ctr, axis=1) <= r
        blocks = model.springs.hessian_blocks_numpy(model.X_nd, psd=False)
        C_relaxed, _ = relaxed_stiffness_2d(m2, blocks, c, window)
        rho_eff = mass.sum() / m2.total_measure
        for label, d in (("x", [1.0, 0.0]), ("y", [0.0, 1.0])):
            s_aff, _ = christoffel(C_affine, d, rho_eff)
            s_rel, pol = christoffel(C_relaxed, d, rho_eff)
            first = amp == cfg.jitter and seed == 0 and label == "x"
            v = standing_wave(ctx, f"jitter{amp:g}_seed{seed}_{label}", model, mass, d, pol[:, -1], k, ctr,
                              region, s_rel[-1], sheet_drawer(m3, 1.0, k) if first else None, fits)
            ctx.progress(f"jitter {amp:g} seed {seed}, P along {label}: measured {v:.5f}, relaxed {s_rel[-1]:.5f}, "
                         f"affine Cauchy-Born {s_aff[-1]:.5f} m/s ({v / s_aff[-1] - 1:+.2%})")
            if amp == cfg.jitter:
                speeds.append(v)
                bound.append(v / s_aff[-1])
                exps.append(Experiment(f"jitter {amp:g} (seed {seed}): P along {label} = relaxed-network prediction",
                                       s_rel[-1], v, 2e-2, "rel", "m/s"))
            else:
                exps.append(Experiment(f"mild jitter {amp:g}: P along {label} = Cauchy-Born sum over its springs",
                                       s_aff[-1], v, 2e-2, "rel", "m/s"))
    speeds = np.asarray(speeds)
    exps += [
        Experiment(f"jitter {cfg.jitter:g}: the affine Cauchy-Born sum is an upper bound (max measured/sum)",
                   1.0, max(bound), 0, "<="),
        Experiment(f"jitter {cfg.jitter:g}: spread of the x and y speeds over {cfg.jitter_seeds} meshes, (max-min)/mean",
                   0.02, float(np.ptp(speeds) / speeds.mean()), 0, "<="),
    ]
    ctx.progress(f"jitter {cfg.jitter:g}: speeds {np.round(speeds, 5).tolist()}, mean {speeds.mean():.5f}, "
                 f"std {speeds.std():.2g}; affine sum over-predicts by {1 / np.mean(bound) - 1:.2%} on average")
    return exps


# ---------------------------------------------------------------------------- stage 4

S4_TEXT = """
The same sum works in 3D with volumes. A cubic cell of the tet box is split into six Kuhn
tets along its (1,1,1) diagonal; every tet has three axis edges, two face diagonals and the
body diagonal, each receiving a sixth of the tet's volume. Per cell this gives the axis
springs h^3/6 per direction, the face diagonals (1,1,0), (0,1,1), (1,0,1) (only those three:
the split picks one diagonal per face) h^3/9 each, and the body diagonal h^3/6:

C = E [ (1/6) sum_axes a a a a + (1/9) sum_faces f f f f + (1/6) b b b b ].

Along the body diagonal (1,1,1)/sqrt3 the P wave is purely longitudinal (three-fold
symmetry) and rho c^2 = C_nnnn = E (1/18 + 4/27 + 1/6) = 10/27 E: c = 0.609 c0, the fastest
direction. Along (1,1,-1) the quasi-P speed is only 0.378 c0, along x 0.512 c0. The box is
strongly anisotropic: its Young's modulus along x is 0.17 E with Poisson's ratio 0.03. An
isotropic pair-spring solid would have lambda = mu and Poisson's ratio 1/4.

We measure standing waves in a cube of tets, read in a ball at its centre, on the coarse box
and (along (1,1,1)) on the box refined once, which must give the same speed.
"""


def stage_tet_box(ctx):
    cfg = ctx.cfg
    h0 = BOX_LENGTH / cfg.box_cells
    lam = cfg.box_wavelength * h0
    k = 2 * math.pi / lam
    r = 0.15 * lam
    probe_mesh = M.tet_box(6, 6, 6, size=5.0)
    C_unit = bulk_tensor(probe_mesh, cfg.E * probe_mesh.edge_measure, 1.0)  # the same for every h
    cmax = max_speed(C_unit, cfg.rho)
    runs = [("(1,1,1)", [1, 1, 1], 1), ("(1,1,1)", [1, 1, 1], 2), ("(1,1,-1)", [1, 1, -1], 1), ("x", [1, 0, 0], 1)]
    out, fits = {}, []
    for refine in (1, 2):
        h = h0 / refine
        todo = [(label, d) for label, d, rf in runs if rf == refine]
        ratio = cmax / min(christoffel(C_unit, d, cfg.rho)[0][-1] for _, d in todo)
        half = r + RUN_PERIODS * lam * ratio * 1.05 + h
        cells = square_domain_cells(half, h)
        mesh = M.tet_box(cells + 1, cells + 1, cells + 1, size=cells * h)
        model, c, mass = area_model(mesh, cfg.E, cfg.rho)
        ctr = np.full(3, 0.5 * cells * h)
        region = np.linalg.norm(mesh.vertices - ctr, axis=1) <= r
        ctx.progress(f"cube h = {h:.4g} m: {mesh.n_vertices} vertices, {len(mesh.edges)} springs")
        draw = solid_drawer(mesh, h, k) if refine == 1 else None
        for label, d in todo:
            speeds, pol = christoffel(C_unit, d, cfg.rho)
            v = standing_wave(ctx, f"P_{label}_h{refine}", model, mass, _unit(d), pol[:, -1], k, ctr, region,
                              speeds[-1], draw if label == "(1,1,1)" else None, fits)
            out[label, refine] = (v, speeds[-1])
            ctx.progress(f"  P along {label}: measured {v:.5f}, Cauchy-Born {speeds[-1]:.5f} m/s")
    (a1, t1), (a2, _), (b1, tb), (x1, tx) = (out["(1,1,1)", 1], out["(1,1,1)", 2], out["(1,1,-1)", 1], out["x", 1])
    E_x, nu_x = young_poisson(C_unit, 0)
    ctx.progress(f"tet box Cauchy-Born: Young's modulus along x {E_x:.4f} E, Poisson ratio {nu_x:.4f}")
    return [
        Experiment("tet box, h: P along (1,1,1) = Cauchy-Born sqrt(10/27) c0", t1, a1, 2e-2, "rel", "m/s"),
        Experiment("tet box, h/2: P along (1,1,1) = Cauchy-Born", t1, a2, 2e-2, "rel", "m/s"),
        Experiment("refinement leaves the (1,1,1) speed unchanged: c(h/2)/c(h)", 1.0, a2 / a1, 1e-2),
        Experiment("tet box: quasi-P along (1,1,-1) = Cauchy-Born", tb, b1, 2e-2, "rel", "m/s"),
        Experiment("tet box: quasi-P along x = Cauchy-Born", tx, x1, 2e-2, "rel", "m/s"),
        Experiment("tet box is anisotropic: speed (1,1,1) / (1,1,-1)", t1 / tb, a1 / b1, 2e-2),
    ] + be_experiments(ctx, fits)


# ---------------------------------------------------------------------------- stage 5

S5_TEXT = """
A static test of the same constants. A strip of the equilateral sheet, four times longer than
wide, is held by its two end columns (pinned vertices), which are moved apart by a small
strain; the long sides are free. The engine's static solver (Newton on the total energy,
engine.statics) finds the equilibrium and the force each pin must supply. Near the clamped
ends the strip cannot narrow, but in the middle it is in uniaxial stress: there we fit the
strains eps_xx and eps_yy from the displacements, and take the stress from the total pin
force F over the width w: sigma = F/w.

Theory from the Cauchy-Born C with lambda = mu = E/8: the 2D Young's modulus
E_eff = 4 mu (lambda + mu)/(lambda + 2 mu) = E/3 (equivalently (8/9) (3/8) E, the P-wave
modulus 3E/8 times 1 - nu^2), and Poisson's ratio nu = lambda/(lambda + 2 mu) = 1/3.
The alternating right-triangle grid, pulled along x, is another material: its C gives
C_xxxx = 5E/12, C_xxyy = E/12, so nu = C_xxyy/C_yyyy = 1/5 and E_x = C_xxxx - C_xxyy^2/C_yyyy
= 2E/5. The Poisson ratio of a spring sheet is set by its pattern, not chosen.
"""


def _pull(ctx, name: str, m2: M.Mesh, end_width: float):
    """Clamp the ends (vertices within end_width of x_min/x_max), stretch by cfg.strain,
    solve the statics; returns (nu, E_eff in the middle, F/(w * nominal strain))."""
    from engine.statics import solve_static

    cfg = ctx.cfg
    m3 = M.embed_3d(m2)
    X = m3.vertices
    x0, x1 = X[:, 0].min(), X[:, 0].max()
    left, right = X[:, 0] <= x0 + end_width, X[:, 0] >= x1 - end_width
    model, c, mass = area_model(m3, cfg.E, cfg.rho, pinned=np.flatnonzero(left | right))
    start = X.copy()
    start[:, 0] = x0 + (X[:, 0] - x0) * (1 + cfg.strain)
    res = solve_static(model, x0=start, tol=1e-8, max_iter=60)
    u = res.x - X
    length, width = x1 - x0, X[:, 1].max() - X[:, 1].min()
    mid = np.abs(X[:, 0] - 0.5 * (x0 + x1)) <= 0.1 * length
    A = np.stack([np.ones(mid.sum()), X[mid, 0], X[mid, 1]], axis=1)
    exx = np.linalg.lstsq(A, u[mid, 0], rcond=None)[0][1]
    eyy = np.linalg.lstsq(A, u[mid, 1], rcond=None)[0][2]
    F = res.reactions[right, 0].sum()
    ctx.progress(f"{name}: {res.iterations} Newton steps, residual {res.residual:.2g}; eps_xx {exx:.6g} in the middle "
                 f"(nominal {cfg.strain:g}), eps_yy {eyy:.6g}, pin force {F:.6g} N")
    if ctx.rec.enabled:
        rec = ctx.rec
        rec.run(name)
        rec.set_time(0, 0.0)
        s = edge_strain(res.x, m3.edges, m3.rest_lengths)
        xd = X + (2.0 / (cfg.strain * length)) * u  # the end displacement drawn as 2 spacings
        rec.mesh(xd, m3.triangles, vertex_colors=_colors(vertex_strain(len(X), m3.edges, s), 1.5 * cfg.strain))
        rec.springs(xd, m3.edges, s, scale=1.5 * cfg.strain)
    return -eyy / exx, F / (width * exx), F / (width * cfg.strain)


def stage_stretch(ctx):
    cfg = ctx.cfg
    n = cfg.strip_cells
    w = max(4, n // 4)
    eq = M.equilateral_lattice(n + 1, int(round(w / (math.sqrt(3) / 2))) + 1, 1.0)
    nu_eq, E_eq, E_nominal = _pull(ctx, "equilateral_strip", eq, 0.5 + 1e-9)
    grid = M.right_triangle_grid(n + 1, w + 1, float(n), float(w), "alternating")
    C = cauchy_born_tensor(grid.vertices, grid.edges, cfg.E * grid.edge_measure, grid.total_measure)
    E_alt, nu_alt_th = young_poisson(C, 0)
    nu_alt, E_alt_m, _ = _pull(ctx, "alternating_strip", grid, 1e-9)
    return [
        Experiment("equilateral sheet: Poisson's ratio = 1/3", 1 / 3, nu_eq, 2e-2),
        Experiment("equilateral sheet: Young's modulus E_eff = E/3", cfg.E / 3, E_eq, 2e-2, "rel", "N/m"),
        Experiment("clamped ends stiffen the strip: F/(w * nominal strain) exceeds E/3", cfg.E / 3, E_nominal, 0,
                   ">=", "N/m"),
        Experiment("alternating grid, pulled along x: Poisson's ratio (Cauchy-Born, 1/5)", nu_alt_th, nu_alt, 2e-2),
        Experiment("alternating grid, pulled along x: Young's modulus (Cauchy-Born, 2E/5)", E_alt, E_alt_m, 2e-2,
                   "rel", "N/m"),
    ]


def _validate(cfg):
    if cfg.strain * cfg.strip_cells > 1.0:
        raise ParameterError(f"--strain {cfg.strain:g} stretches the {cfg.strip_cells}-spacing strip by more "
                             "than a spacing; use a smaller strain")


LESSON = Lesson(
    id="area-springs",
    title="Area- and volume-scaled springs in 2D and 3D",
    summary="Springs weighted by the area/volume they represent: resolution-independent wave speeds, "
            "the Cauchy-Born stiffness of a spring network, P and S waves, anisotropy of mesh patterns, "
            "and a static stretch test of Young's modulus and Poisson's ratio.",
    config=AreaSpringsConfig,
    stages=[
        Stage("one k for every spring versus volume-scaled springs", S1_TEXT, stage_refinement),
        Stage("the equilateral sheet: P and S waves", S2_TEXT, stage_equilateral),
        Stage("the pattern matters: grids, anisotropy, jitter", S3_TEXT, stage_patterns),
        Stage("3D: waves in the tet box", S4_TEXT, stage_tet_box),
        Stage("static stretch: Young's modulus and Poisson's ratio", S5_TEXT, stage_stretch),
    ],
    order=3,
    validate=_validate,
)
