"""The scene of ``membranes``: membrane models on triangle meshes (the constant-strain St.
Venant-Kirchhoff triangle and Baraff and Witkin's conditions, engine.energies.membrane), the
stretched strip that measures Young's modulus and Poisson's ratio, the hanging cloth, how they are
drawn, and the estimates of each stage's time.

The standing-wave run is lessons._waves', as in area-springs: the same probe, the same integrator
choices, so that the speeds of the two lessons compare run for run.
"""
import math

import numpy as np

from engine import mesh as M
from engine.energies.membrane import MembraneEnergy, lame
from engine.model import Model
from engine.waves import bloch_modes
from lessons.views import RunView

from .._budget import StageCost, announce as announce_budget, check_stages
from .._measure import stretch_strip
from ..area_springs.scene import area_model

STRETCH_TOL = 1e-9   # the static stretch's residual (net force / weight scale)
STRIPS = {"equilateral": "equilateral strip", "alternating": "right-triangle strip (alternating diagonals)"}


# ------------------------------------------------------------------ builders

def membrane_model(m3: M.Mesh, rho: float, model: str, pinned=None, gravity=(0.0, 0.0, 0.0), **params):
    """(Model, its MembraneEnergy) on a 3D-embedded triangle mesh, lumped masses of areal density rho."""
    energy = MembraneEnergy.from_mesh(m3, model, **params)
    m = Model(m3.vertices, mass=M.lumped_masses(m3, rho), pinned=pinned, gravity=gravity)
    m.add_energy(energy)
    return m, energy


def strip(kind: str, cells: int) -> M.Mesh:
    """A strip ``cells`` spacings long and about a quarter as wide, 3D-embedded at z = 0."""
    width = max(4, cells // 4)
    if kind == "equilateral":
        m2 = M.equilateral_lattice(cells + 1, int(round(width / (math.sqrt(3) / 2))) + 1, 1.0)
    else:
        m2 = M.right_triangle_grid(cells + 1, width + 1, float(cells), float(width), kind)
    return M.embed_3d(m2)


def end_width(kind: str) -> float:
    """How far from each end the clamped vertices reach (the equilateral lattice's rows are
    staggered by half a spacing)."""
    return 0.5 + 1e-9 if kind == "equilateral" else 1e-9


def uniaxial_theory(model: str, Y_or_ks: float, nu: float, exx: float) -> tuple:
    """(Poisson's ratio, F/(w exx)) a homogeneous strip pulled to the engineering strain exx in
    uniaxial stress shows, exactly (no small-strain approximation).
    stvk: S_yy = 0 gives the Green strains E_yy = -nu E_xx, E_xx = exx + exx^2/2, and the nominal
    stress P_xx = (1 + exx) Y E_xx; baraff-witkin: the stretch conditions do not couple the axes, so
    the width keeps its length (Poisson 0) and P_xx = k_s exx."""
    if model == "baraff-witkin":
        return 0.0, Y_or_ks
    Exx = exx + 0.5 * exx * exx
    eyy = math.sqrt(1.0 - 2.0 * nu * Exx) - 1.0
    return -eyy / exx + 0.0, (1.0 + exx) * Y_or_ks * Exx / exx   # + 0.0: no "-0" in the tables


def pull(ctx, name: str, label: str, m3: M.Mesh, kind: str, build, unsolved: list, draw: bool = False,
         strain: float | None = None):
    """Clamp the strip's ends, stretch it by ``strain`` (default cfg.strain), solve the statics; returns
    (nu, the measured modulus F/(w eps_xx), eps_xx). ``build(m3, pinned)`` makes the model."""
    cfg = ctx.cfg
    strain = cfg.strain if strain is None else strain
    s = stretch_strip(m3, build, strain, end_width(kind), STRETCH_TOL)
    res, exx, eyy, F, width = s["res"], s["exx"], s["eyy"], s["F"], s["width"]
    if not res.converged:
        unsolved.append(f"{label}: the static solve stopped at residual {res.residual:.2g} > {STRETCH_TOL:g} after "
                        f"{res.iterations} Newton steps ({res.message})")
    ctx.progress(f"{label}: {res.iterations} Newton steps, eps_xx {exx:.6g}, eps_yy {eyy:.6g}, pull {F:.6g} N")
    if draw and ctx.rec.enabled:
        draw_strip(ctx.rec, name, label, m3, m3.vertices + s["u"], s["u"], strain)
    return -eyy / exx + 0.0, F / (width * exx), exx


def hanging_cloth(cfg, model: str = "baraff-witkin"):
    """A square cloth cfg.cloth_size on a side in the x-z plane, cfg.cloth_n vertices a side, its top
    edge pinned, under gravity: (Model, mesh)."""
    n = cfg.cloth_n
    m2 = M.right_triangle_grid(n, n, cfg.cloth_size, cfg.cloth_size, "alternating")
    m3 = M.embed_3d(m2, plane="xz")
    X = m3.vertices
    top = np.flatnonzero(X[:, 2] >= X[:, 2].max() - 1e-9)
    params = (dict(k_stretch=cfg.k_stretch, k_shear=cfg.k_shear) if model == "baraff-witkin"
              else dict(Y=cfg.k_stretch, nu=cfg.nu))
    built, _ = membrane_model(m3, cfg.cloth_rho, model, pinned=top, gravity=(0.0, 0.0, -9.81), **params)
    return built, m3


PERIODS = {"one-way": np.eye(2), "alternating": 2.0 * np.eye(2)}   # the grids' translations (spacing 1 m)


def lattice_modes(pattern: str, build):
    """k_vec -> engine.waves.BlochModes of the infinite right-triangle grid of ``pattern`` (spacing
    1 m) at wavevector k_vec (1/m), with the grid's real lumped masses, read from one 9 x 9 patch that
    ``build(m3)`` -> (Model, MembraneEnergy) turns into the stage's material (damped when it is)."""
    m3 = M.embed_3d(M.right_triangle_grid(9, 9, 8.0, 8.0, pattern))
    model, energy = build(m3)
    X = m3.vertices
    stiffness = energy.dense_hessian(X, psd=False)
    damping = energy.dense_damping(X) if model.dampers else None
    return lambda k_vec: bloch_modes(X, model.mass, PERIODS[pattern], k_vec, stiffness, damping)


def lattice_wave(pattern: str, k_vec, polarization, build) -> tuple:
    """(w^2, c, profile) of the plane wave of wavevector ``k_vec`` on the grid of ``pattern``
    (:func:`lattice_modes`) whose motion is closest to ``polarization``: its Bloch branch. c, the
    branch's damping per unit mass, is 0 without damping; profile(X) gives the mode's relative
    amplitude at each vertex of a larger sheet of the same grid (ModeProbe's profile)."""
    modes = lattice_modes(pattern, build)(k_vec)
    b = modes.branch(polarization)
    return float(modes.w2[b]), float(modes.c[b]), lambda Xs: modes.profile(Xs, b, polarization)


def lattice_speed(grid, k: float, direction, polarization, method: str | None = None, dt: float = 0.0) -> float:
    """The phase speed w/k of the grid's plane wave (``grid``: :func:`lattice_modes`) of wavenumber k
    along ``direction`` whose motion is closest to ``polarization``; under ``method``'s step dt
    (engine.theory.schemes.scheme_frequency) when given, else the grid's own."""
    from engine.theory.schemes import scheme_frequency

    modes = grid(k * np.asarray(direction, dtype=np.float64))
    w2 = float(modes.w2[modes.branch(polarization)])
    return (scheme_frequency(method, w2, dt) if method else math.sqrt(w2)) / k


def plane_speeds(Y: float, nu: float, rho: float) -> tuple:
    """(c_P, c_S) of the isotropic plane-stress membrane: sqrt(Y/((1 - nu^2) rho)), sqrt(mu/rho)."""
    mu, lam = lame(Y, nu)
    return math.sqrt((lam + 2 * mu) / rho), math.sqrt(mu / rho)


def springs_for(m3: M.Mesh, E: float, rho: float, pinned=None) -> Model:
    """Area-scaled springs c_e = E A_e on the same mesh (area-springs' model), for contrast."""
    return area_model(m3, E, rho, pinned=pinned)[0]


# ------------------------------------------------------------------ drawing

def draw_strip(rec, name: str, label: str, m3: M.Mesh, x, u, strain: float) -> None:
    """The stretched strip (one frame), the displacements magnified so that the end moves a quarter
    of the strip's length, each vertex coloured by its sideways displacement u_y (the narrowing
    that Poisson's ratio measures) on the scale of strain x the half width."""
    X = m3.vertices
    gain = 0.25 / strain
    rec.run(name, RunView(label=f"{label} stretched by {100 * strain:.2g}%, clamped ends, displacement x{gain:.0f}",
                          camera="top", energy=None))
    rec.set_time(0, 0.0)
    half = 0.5 * np.ptp(X[:, 1])
    rec.mesh(X + gain * u, m3.triangles, vertex_colors=rec.colors(u[:, 1], "signed", "u_y (m)", strain * half))


def draw_patch(rec, name: str, label: str, m3: M.Mesh, x, energy) -> None:
    """One frame: the deformed patch, each vertex coloured by the energy per rest area of the
    triangles around it (J/m^2)."""
    T = m3.triangles
    per_vertex = vertex_mean(T, len(x), energy.triangle_energies(x) / energy.area_np)
    rec.run(name, RunView(label=label, camera="top", energy=None))
    rec.set_time(0, 0.0)
    rec.mesh(x, T, vertex_colors=rec.colors(per_vertex, "magnitude", "W/A (J/m^2)", float(per_vertex.max())))


def triangle_stretch(energy, x: np.ndarray) -> np.ndarray:
    """(m,) each triangle's larger stretch along the warp and the weft, max(|w_u|, |w_v|) - 1 (the
    lengths of F's columns, (F1) of engine.energies.triangle), from numpy positions x."""
    T, Di = energy.triangles_np, energy.Dinv_np
    d1, d2 = x[T[:, 1]] - x[T[:, 0]], x[T[:, 2]] - x[T[:, 0]]
    wu = d1 * Di[:, 0, 0, None] + d2 * Di[:, 1, 0, None]
    wv = d1 * Di[:, 0, 1, None] + d2 * Di[:, 1, 1, None]
    return np.maximum(np.linalg.norm(wu, axis=1), np.linalg.norm(wv, axis=1)) - 1.0


def vertex_mean(T: np.ndarray, n: int, values: np.ndarray) -> np.ndarray:
    """(n,) the mean of ``values`` (one per triangle) over the triangles around each vertex."""
    return (np.bincount(T.ravel(), weights=np.repeat(values, 3), minlength=n)
            / np.maximum(np.bincount(T.ravel(), minlength=n), 1))


def cloth_logger(m3: M.Mesh, energy, scale: float):
    """log(rec, state): the cloth's triangles coloured by their stretch (the larger of warp and weft,
    averaged at each vertex) on the fixed ``scale``, the hanging cloth's largest at rest."""
    T, n = m3.triangles, m3.n_vertices

    def log(rec, st):
        x = st.x.to_numpy().astype(np.float64)
        stretch = vertex_mean(T, n, triangle_stretch(energy, x))
        rec.mesh(x, T, vertex_colors=rec.colors(stretch, "magnitude", "stretch", scale))
    return log


# ------------------------------------------------------------------ the damped sheet's size (stage 5)

EDGE_DECAY = 23.0   # the free edges' disturbance reaches the disc damped by exp(-23) = 1e-10


def damped_margin(wavelength: float, damping_ratio: float) -> float:
    """How far stage 5's sheet reaches beyond the disc (m, spacing 1 m). A free edge disturbs the
    wave from the start; undamped, the disturbance travels a wavelength per period, and the margin of
    two wavelengths keeps it out for the run (one period). Baraff-Witkin's damping k_d u_xx' also
    diffuses it, with diffusivity k_d/rho = 2 ratio c/k, over the period T = 2 pi/(c k): to depth d
    with weight exp(-d^2/(4 k_d T/rho)) = exp(-d^2 pi/(4 ratio wavelength^2)); the margin keeps that
    below exp(-EDGE_DECAY): d = wavelength sqrt(4 EDGE_DECAY ratio/pi), 1.9 wavelengths at the
    default ratio 0.05, 3.8 at 0.5."""
    return wavelength * max(2.0, math.sqrt(4.0 * EDGE_DECAY * damping_ratio / math.pi))


def damped_run_size(cfg) -> tuple[int, int]:
    """(vertices per side, about how many velocity-Verlet steps) of stage 5's run: the explicit step
    is cfl times the smaller of the stiffness' limit, about 0.577 sqrt(rho/k_s), and the damping's
    2/c_max, with c_max about 12 k_d/rho on the alternating grid (measured 12.0), for one period."""
    lam, k = float(cfg.wavelength), 2 * math.pi / cfg.wavelength
    kd = 2 * cfg.damping_ratio * math.sqrt(cfg.Y * cfg.rho) / k
    dt = cfg.cfl * min(0.577 * math.sqrt(cfg.rho / cfg.Y), 2.0 / (12.0 * kd / cfg.rho))
    n = 2 * int(math.ceil(0.15 * lam + damped_margin(lam, cfg.damping_ratio) + 2.0)) + 1
    return n, int(math.ceil(lam * math.sqrt(cfg.rho / cfg.Y) / dt))


# ------------------------------------------------------------------ estimates and budget

# seconds of each stage at the defaults on the reference 2-thread CPU, and how they scale
STAGE_SECONDS = {1: 1.0, 2: 2.0, 3: 4.0, 4: 3.0, 5: 9.5}


def stage_seconds(cfg, stage: int) -> float:
    """An estimate of stage ``stage``'s time on the reference CPU, scaled from its time at the defaults."""
    d = type(cfg)()
    if stage == 2:   # strips of cells x cells/4 vertices, a few Newton steps each
        return STAGE_SECONDS[2] * (cfg.strip_cells / d.strip_cells) ** 2
    if stage == 3:   # sheets of (wavelength)^2 vertices, steps ~ wavelength / cfl
        return STAGE_SECONDS[3] * (cfg.wavelength / d.wavelength) ** 3 * d.cfl / cfg.cfl
    if stage == 4:   # backward-Euler steps over the settling time on an n x n cloth
        return STAGE_SECONDS[4] * (cfg.cloth_n / d.cloth_n) ** 2 * cfg.settle_time / d.settle_time
    if stage == 5:   # the damped sheet's vertices times its steps
        (n, steps), (n0, steps0) = damped_run_size(cfg), damped_run_size(d)
        return STAGE_SECONDS[5] * (n * n * steps) / (n0 * n0 * steps0)
    return STAGE_SECONDS.get(stage, 0.0)


BUDGET = {2: StageCost("--strip-cells", "use fewer --strip-cells"),
          3: StageCost("--wavelength, --cfl", "use a shorter --wavelength or a larger --cfl"),
          4: StageCost("--cloth-n, --settle-time", "use a smaller --cloth-n or a shorter --settle-time"),
          5: StageCost("--wavelength, --cfl, --damping-ratio",
                       "use a shorter --wavelength, a larger --cfl or a smaller --damping-ratio")}


def check_work(cfg) -> None:
    check_stages(cfg, stage_seconds, BUDGET)


def announce(ctx, stage: int) -> None:
    announce_budget(ctx, stage_seconds(ctx.cfg, stage))


# ------------------------------------------------------------------ the damped wave (stage 5)

def fit_decay(t: np.ndarray, a: np.ndarray, w0: float) -> tuple:
    """(w, gamma) of a(t) = a(0) exp(-gamma t) (cos w t + b sin w t), least squares over all samples
    from the guess w0 (b free: a damped mode started from rest has b = gamma/w, a scheme's discrete
    map its own)."""
    from scipy.optimize import least_squares

    r = a / a[0]

    def resid(p):
        return np.exp(-p[1] * t) * (np.cos(p[0] * t) + p[2] * np.sin(p[0] * t)) - r

    sol = least_squares(resid, [w0, 0.0, 0.0], x_scale=[w0, w0, 1.0], xtol=1e-14, ftol=1e-14, gtol=1e-14)
    return float(sol.x[0]), float(sol.x[1])


def damped_wave(ctx, name: str, model: Model, m3: M.Mesh, k: float, ctr, region, dt: float, n_steps: int,
                integrator: str, label: str, profile=None) -> tuple:
    """A standing P wave along x (the warp u) started from rest on a damped Baraff-Witkin sheet, each
    vertex's displacement times ``profile`` (the lattice mode's, lattice_wave); returns (times,
    amplitudes) read over ``region`` by engine.waves.ModeProbe."""
    from engine.waves import ModeProbe

    from .._scene import simulate
    from .._waves import DRAWN_AMPLITUDE, sheet_drawer

    cfg = ctx.cfg
    probe = ModeProbe(model.X, model.mass, np.array([1.0, 0.0]), np.array([1.0, 0.0]), k, ctr, region, profile)
    A = cfg.strain / k
    state = model.make_state(model.X + probe.displacement(A))
    times, amps = [], []

    def observe(step, st):
        times.append(step * dt)
        amps.append(probe.amplitude(st.x.to_numpy()))
    draw = sheet_drawer(m3)
    gain = DRAWN_AMPLITUDE * (2 * math.pi / k) / A
    log = lambda rec, st: draw(rec, st.x.to_numpy().astype(np.float64), gain, np.array([1.0, 0.0, 0.0]), "u_x (m)", A)
    simulate(ctx, name, model, state, dt, n_steps, integrator=integrator, every=1, observe=observe, log=log,
             energy_every=1, fixed=True, view=RunView(label=label, camera="top", span=n_steps * dt),
             **({"solver": "cholesky"} if integrator == "backward-euler" else {}))
    return np.asarray(times), np.asarray(amps)
