"""The stages of ``area-springs`` (their narratives are in narrative.md) and what they measure;
the meshes and models, the standing-wave run, the drawings and the estimates of each stage's time
are in :mod:`.scene`.

Every standing-wave run is a scene run: velocity Verlet unless ``--integrator`` chooses another
integrator. Under backward Euler the step is chosen from the phase (see :func:`lessons._waves.standing_wave`)
and each wave stage adds the experiments of :func:`be_experiments` on the scheme's own damping.
"""
from __future__ import annotations

import math

import numpy as np

from engine import mesh as M
from engine.model import Model
from lessons.views import RunView
from engine.waves import cauchy_born_tensor, christoffel, max_speed, relaxed_stiffness_2d, young_poisson
from engine.theory.schemes import backward_euler_damping_rate as be_damping_rate

from .._framework import Experiment
from .._measure import stretch_strip
from .._waves import RUN_PERIODS, sheet_drawer, solid_drawer, square_domain_cells, standing_wave, unit, wave_grid, \
    wave_time
from .scene import STRIPS, announce, area_model, bulk_tensor, draw_strip, eq_sheet

BOX_LENGTH = 1.0    # m, the tet box of stage 1 and the cell size unit of stage 4
SMALL_JITTER = 0.1  # a mild jitter whose affine prediction is still close
BE_PHASE_LAG = 1e-3   # the bound on the phase lag at _waves.BE_PHASE_STEP (8.3e-4), a tenth of the tightest
                      # tolerance (1e-2) of the speeds
BE_DAMPING_TOL = 0.03  # fitted / predicted decay rate: the decay over a run is only ~5%, and the probe
                       # also sees a little of other motion (up to 1.7% measured on the regular meshes)


# ---------------------------------------------------------------------------- stage 1

def stage_refinement(ctx):
    cfg = ctx.cfg
    announce(ctx, 1)
    speeds = {"area": [], "k": []}
    fits = []
    k_spring = None
    shown = {}  # the span of the drawn runs' views (set by the first)
    for level, nc in enumerate(cfg.box_cells * 2 ** i for i in range(3)):
        k_spring = _refinement_level(ctx, level, nc, k_spring, speeds, fits, shown)
    a, kk = speeds["area"], speeds["k"]
    exps = [
        Experiment("one k for all springs: speed ratio c(h/2)/c(h) = 2 (c ~ 1/h)", 2.0, kk[1] / kk[0], 2e-2,
                   id="one-k-ratio-h2"),
        Experiment("one k for all springs: speed ratio c(h/4)/c(h) = 4 (c ~ 1/h)", 4.0, kk[2] / kk[0], 2e-2,
                   id="one-k-ratio-h4"),
        Experiment("k tuned on the coarse box: same speed as E*A springs there", 1.0, kk[0] / a[0], 1e-2,
                   id="one-k-tuned-on-coarse-box"),
        Experiment("volume-scaled springs: speed ratio c(h/2)/c(h) = 1", 1.0, a[1] / a[0], 1e-2,
                   id="volume-scaled-ratio-h2"),
        Experiment("volume-scaled springs: speed ratio c(h/4)/c(h) = 1", 1.0, a[2] / a[0], 1e-2,
                   id="volume-scaled-ratio-h4"),
    ] + be_experiments(ctx, "refinement", fits)
    # the standing wave is 2 m long: 2 box_cells spacings on the coarse box, where dispersion is largest
    return with_reason(exps, dispersion_reason(2 * BOX_LENGTH * cfg.box_cells, 1e-2))


LAWS = {"area": "volume-scaled springs", "k": "one k for every spring"}


def _refinement_level(ctx, level: int, nc: int, k_spring, speeds: dict, fits: list, shown: dict):
    """The standing compression wave on the 1 m box of ``nc`` cells, once with volume-scaled
    springs and once with one constant k for every spring (tuned on the coarsest box so that
    both laws agree there: returned, to be passed to the finer levels); the speeds are appended
    to ``speeds``. The two coarser levels are drawn, all four views over the time of the first
    run (``shown["span"]``): the one-k wave on the finer box, twice as fast, gets there in half."""
    cfg = ctx.cfg
    k = math.pi / BOX_LENGTH
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
    draw = solid_drawer(mesh) if level < 2 and ctx.rec.enabled else None
    ctx.progress(f"h = {h:.4g} m: {mesh.n_vertices} vertices, {len(mesh.edges)} springs")
    for law, (C, coef) in laws.items():
        speeds_th, pol = christoffel(C, [1, 0, 0], cfg.rho)
        model = Model.from_springs(X, mesh.edges, c=coef(mesh), mass=mass)
        view = None
        if draw is not None:
            if shown.get("span") is None:
                shown["span"] = wave_time(ctx, model, k, speeds_th[-1])
            view = RunView(label=f"{LAWS[law]}, h = 1/{nc} m", camera="outside", span=shown["span"])
        c = standing_wave(ctx, f"{law}_h{nc}", model, mass, [1, 0, 0], pol[:, -1], k, (0.0, 0.0, 0.0),
                          band, speeds_th[-1], draw, fits, view=view)
        speeds[law].append(c)
        ctx.progress(f"  {law:4s}: measured {c:.5f} m/s, Cauchy-Born {speeds_th[-1]:.5f} m/s")
    return k_spring


# ---------------------------------------------------------------------------- stage 2

def stage_equilateral(ctx):
    cfg = ctx.cfg
    announce(ctx, 2)
    c0 = math.sqrt(cfg.E / cfg.rho)
    cP, cS = math.sqrt(3 / 8) * c0, math.sqrt(1 / 8) * c0
    fits = []
    out = _equilateral_speeds(ctx, cP, cS, fits)
    ratio = 0.5 * (out["P", "x"] / out["S", "x"] + out["P", "y"] / out["S", "y"])
    exps = [
        Experiment("P wave along x (an edge direction) = sqrt(3/8) c0", cP, out["P", "x"], 2e-2, "rel", "m/s",
                   id="p-wave-x"),
        Experiment("P wave along y (across the edges) = sqrt(3/8) c0", cP, out["P", "y"], 2e-2, "rel", "m/s",
                   id="p-wave-y"),
        Experiment("S wave along x = sqrt(mu/rho) = sqrt(1/8) c0", cS, out["S", "x"], 2e-2, "rel", "m/s",
                   id="s-wave-x"),
        Experiment("S wave along y = sqrt(1/8) c0", cS, out["S", "y"], 2e-2, "rel", "m/s", id="s-wave-y"),
        Experiment("c_P/c_S = sqrt(3), i.e. lambda = mu (Cauchy relation)", math.sqrt(3), ratio, 1e-2,
                   id="p-over-s-sqrt3"),
        Experiment("isotropy: P speed along y / along x = 1", 1.0, out["P", "y"] / out["P", "x"], 1e-2,
                   id="p-wave-isotropy"),
    ] + be_experiments(ctx, "equilateral", fits)
    return with_reason(exps, dispersion_reason(cfg.wavelength, 1e-2))


def _equilateral_speeds(ctx, cP: float, cS: float, fits: list) -> dict:
    """{(wave, axis): measured speed} for the P and S standing waves along x and y, read in a disc
    at the centre of a sheet large enough that nothing from its free edges arrives there."""
    cfg = ctx.cfg
    lam = float(cfg.wavelength)  # spacing 1 m
    k = 2 * math.pi / lam
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
    draw = sheet_drawer(m3) if ctx.rec.enabled else None
    span = wave_time(ctx, model, k, cS) if draw is not None else None  # the S waves' time: P's are sqrt(3) faster
    out = {}
    for label, d in (("x", [1.0, 0.0]), ("y", [0.0, 1.0])):
        n = unit(d)
        for wave, p, guess in (("P", n, cP), ("S", np.array([-n[1], n[0]]), cS)):
            where = "an edge direction" if label == "x" else "across the edges"
            view = RunView(label=f"{wave} wave along {label} ({where})", camera="top", span=span)
            out[wave, label] = standing_wave(ctx, f"{wave}_along_{label}", model, mass, n, p, k, ctr, region,
                                             guess, draw, fits, view=view)
            ctx.progress(f"{wave} along {label}: {out[wave, label]:.5f} m/s")
    return out


# ---------------------------------------------------------------------------- stage 3

DIRECTIONS = {"x": ([1.0, 0.0], "x"), "y": ([0.0, 1.0], "y"), "diagonal (1,1)": ([1.0, 1.0], "diagonal-plus"),
              "diagonal (1,-1)": ([1.0, -1.0], "diagonal-minus")}  # label: (direction, id slug)


def stage_patterns(ctx):
    cfg = ctx.cfg
    announce(ctx, 3)
    lam = float(cfg.wavelength)
    k = 2 * math.pi / lam
    r = 0.15 * lam  # the disc the amplitude is read in
    half = r + RUN_PERIODS * lam * math.sqrt(3) * 1.05 + 2.0  # the slowest wave is 1/sqrt(3) of the fastest
    n = square_domain_cells(half, 1.0) + 1
    exps, measured, fits = [], {}, []
    shown = {}  # the span of the drawn runs' views (set by the first pattern)
    for pattern in ("one-way", "alternating", "crossed"):
        exps += _pattern_speeds(ctx, pattern, n, k, r, measured, fits, shown)
    v1, t1 = measured["one-way", "diagonal (1,1)"]
    v2, t2 = measured["one-way", "diagonal (1,-1)"]
    exps.append(Experiment("one-way grid is anisotropic: speed along / across its diagonals", t1 / t2, v1 / v2, 2e-2,
                           id="one-way-anisotropic"))
    jittered = []
    exps += _jitter_experiments(ctx, n, k, lam, jittered, shown.get("span"))
    return with_reason(exps + be_experiments(ctx, "patterns", fits, jittered), dispersion_reason(cfg.wavelength))


SHOWN_PATTERN_RUNS = (("one-way", "diagonal (1,1)"), ("one-way", "diagonal (1,-1)"), ("alternating", "x"))


def _pattern_speeds(ctx, pattern: str, n: int, k: float, r: float, measured: dict, fits: list, shown: dict):
    """The P wave along x, y and both diagonals of a right-triangle grid of ``pattern`` against
    the Cauchy-Born prediction, read in a disc of radius ``r`` (the measured and predicted speeds
    also go to ``measured``). The runs of SHOWN_PATTERN_RUNS are drawn, over the time of the first
    pattern's longest run (``shown["span"]``: the one-way grid across its diagonals, the stage's
    slowest wave), so the one-way grid's fast and slow diagonal play side by side."""
    cfg = ctx.cfg
    c0 = math.sqrt(cfg.E / cfg.rho)
    m2, m3, ctr, region = wave_grid(n, pattern, r)
    model, c, mass = area_model(m3, cfg.E, cfg.rho)
    C = cauchy_born_tensor(m2.vertices, m2.edges, c, m2.total_measure)
    if ctx.rec.enabled and shown.get("span") is None:
        shown["span"] = max(wave_time(ctx, model, k, christoffel(C, d, cfg.rho)[0][-1]) for d, _ in DIRECTIONS.values())
    exps = []
    for label, (d, slug) in DIRECTIONS.items():
        speeds, pol = christoffel(C, d, cfg.rho)
        draw = view = None
        if ctx.rec.enabled and (pattern, label) in SHOWN_PATTERN_RUNS:
            draw = sheet_drawer(m3)
            view = RunView(label=f"{pattern} grid, P wave along {label}", camera="top", span=shown["span"])
        v = standing_wave(ctx, f"{pattern}_{label}", model, mass, unit(d), pol[:, -1], k, ctr, region,
                          speeds[-1], draw, fits, view=view)
        measured[pattern, label] = (v, speeds[-1])
        ctx.progress(f"{pattern}, P along {label}: measured {v:.5f}, Cauchy-Born {speeds[-1]:.5f} m/s")
        exps.append(Experiment(f"{pattern} grid: P wave along {label} = Cauchy-Born ({speeds[-1] / c0:.4f} c0)",
                               speeds[-1], v, 2e-2, "rel", "m/s", id=f"{pattern}-p-wave-{slug}"))
    return exps


def _jitter_experiments(ctx, n, k, lam, fits, span=None):
    """Jittered one-way grids: strong jitter (cfg.jitter, several seeds) against the relaxed
    network's prediction, mild jitter against the affine Cauchy-Born sum; the affine sum is an
    upper bound, and the speeds scatter little between meshes. The first (strong jitter, seed 0,
    along x) is drawn, its view spanning ``span``."""
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
            draw = view = None
            if ctx.rec.enabled and amp == cfg.jitter and seed == 0 and label == "x":
                draw = sheet_drawer(m3)
                view = RunView(label=f"one-way grid jittered by {amp:g} (seed {seed}), P wave along x", camera="top",
                               span=span)
            v = standing_wave(ctx, f"jitter{amp:g}_seed{seed}_{label}", model, mass, d, pol[:, -1], k, ctr,
                              region, s_rel[-1], draw, fits, view=view)
            ctx.progress(f"jitter {amp:g} seed {seed}, P along {label}: measured {v:.5f}, relaxed {s_rel[-1]:.5f}, "
                         f"affine Cauchy-Born {s_aff[-1]:.5f} m/s ({v / s_aff[-1] - 1:+.2%})")
            if amp == cfg.jitter:
                speeds.append(v)
                bound.append(v / s_aff[-1])
                exps.append(Experiment(f"jitter {amp:g} (seed {seed}): P along {label} = relaxed-network prediction",
                                       s_rel[-1], v, 2e-2, "rel", "m/s", id=f"jitter-seed{seed}-p-wave-{label}"))
            else:
                exps.append(Experiment(f"mild jitter {amp:g}: P along {label} = Cauchy-Born sum over its springs",
                                       s_aff[-1], v, 2e-2, "rel", "m/s", id=f"mild-jitter-p-wave-{label}"))
    scatter = (f"disorder: the wave is {lam:g} spacings long on a mesh jittered by {cfg.jitter:g} of its spacing; the "
               "relaxed network's speed is the long-wavelength limit of the disordered network, and the closer the "
               "wavelength comes to the scale of the disorder the more the mesh scatters it (and the more each mesh "
               "differs from the next); use a longer --wavelength")
    for e in exps:
        e.reason = scatter
    speeds = np.asarray(speeds)
    exps += [
        Experiment(f"jitter {cfg.jitter:g}: the affine Cauchy-Born sum is an upper bound (max measured/sum)",
                   1.0, max(bound), 0, "<=", id="jitter-affine-sum-upper-bound"),
        Experiment(f"jitter {cfg.jitter:g}: spread of the x and y speeds over {cfg.jitter_seeds} meshes, (max-min)/mean",
                   0.02, float(np.ptp(speeds) / speeds.mean()), 0, "<=", id="jitter-speed-spread", reason=scatter),
    ]
    ctx.progress(f"jitter {cfg.jitter:g}: speeds {np.round(speeds, 5).tolist()}, mean {speeds.mean():.5f}, "
                 f"std {speeds.std():.2g}; affine sum over-predicts by {1 / np.mean(bound) - 1:.2%} on average")
    return exps


# ---------------------------------------------------------------------------- stage 4

def stage_tet_box(ctx):
    cfg = ctx.cfg
    announce(ctx, 4)
    probe_mesh = M.tet_box(6, 6, 6, size=5.0)
    C_unit = bulk_tensor(probe_mesh, cfg.E * probe_mesh.edge_measure, 1.0)  # the same for every h
    fits = []
    out = _tet_box_speeds(ctx, C_unit, fits)
    (a1, t1), (a2, _), (b1, tb), (x1, tx) = (out["(1,1,1)", 1], out["(1,1,1)", 2], out["(1,1,-1)", 1], out["x", 1])
    E_x, nu_x = young_poisson(C_unit, 0)
    ctx.progress(f"tet box Cauchy-Born: Young's modulus along x {E_x:.4f} E, Poisson ratio {nu_x:.4f}")
    exps = [
        Experiment("tet box, h: P along (1,1,1) = Cauchy-Born sqrt(10/27) c0", t1, a1, 2e-2, "rel", "m/s",
                   id="box-p-wave-111"),
        Experiment("tet box, h/2: P along (1,1,1) = Cauchy-Born", t1, a2, 2e-2, "rel", "m/s",
                   id="box-p-wave-111-refined"),
        Experiment("refinement leaves the (1,1,1) speed unchanged: c(h/2)/c(h)", 1.0, a2 / a1, 1e-2,
                   id="box-refinement-keeps-speed"),
        Experiment("tet box: quasi-P along (1,1,-1) = Cauchy-Born", tb, b1, 2e-2, "rel", "m/s",
                   id="box-p-wave-11minus1"),
        Experiment("tet box: quasi-P along x = Cauchy-Born", tx, x1, 2e-2, "rel", "m/s", id="box-p-wave-x"),
        Experiment("tet box is anisotropic: speed (1,1,1) / (1,1,-1)", t1 / tb, a1 / b1, 2e-2, id="box-anisotropic"),
    ] + be_experiments(ctx, "tet-box", fits)
    return with_reason(exps, dispersion_reason(cfg.box_wavelength))


def _tet_box_speeds(ctx, C_unit: np.ndarray, fits: list) -> dict:
    """{(direction label, refinement): (measured, Cauchy-Born speed)} of standing P waves in a
    cube of tets, read in a ball at its centre: along (1,1,1), (1,1,-1) and x on the coarse box,
    along (1,1,1) again on the box refined once."""
    cfg = ctx.cfg
    h0 = BOX_LENGTH / cfg.box_cells
    lam = cfg.box_wavelength * h0
    k = 2 * math.pi / lam
    r = 0.15 * lam
    cmax = max_speed(C_unit, cfg.rho)
    runs = [("(1,1,1)", [1, 1, 1], 1), ("(1,1,1)", [1, 1, 1], 2), ("(1,1,-1)", [1, 1, -1], 1), ("x", [1, 0, 0], 1)]
    out = {}
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
        draw = span = None
        if refine == 1 and ctx.rec.enabled:  # the coarse box's three runs are drawn, over the slowest one's time
            draw = solid_drawer(mesh)
            span = max(wave_time(ctx, model, k, christoffel(C_unit, d, cfg.rho)[0][-1]) for _, d in todo)
        for label, d in todo:
            speeds, pol = christoffel(C_unit, d, cfg.rho)
            view = RunView(label=f"{'P' if label == '(1,1,1)' else 'quasi-P'} wave along {label}, "
                                 f"h = 1/{cfg.box_cells * refine} m",
                           camera="outside", span=span)
            v = standing_wave(ctx, f"P_{label}_h{refine}", model, mass, unit(d), pol[:, -1], k, ctr, region,
                              speeds[-1], draw, fits, view=view)
            out[label, refine] = (v, speeds[-1])
            ctx.progress(f"  P along {label}: measured {v:.5f}, Cauchy-Born {speeds[-1]:.5f} m/s")
    return out


# ---------------------------------------------------------------------------- stage 5

STRETCH_TOL = 1e-8      # the static stretch's residual


def stage_stretch(ctx):
    cfg = ctx.cfg
    n = cfg.strip_cells
    w = max(4, n // 4)
    eq = M.equilateral_lattice(n + 1, int(round(w / (math.sqrt(3) / 2))) + 1, 1.0)
    unsolved = []  # why a static solve stopped short, if one did
    nu_eq, E_eq, E_nominal = _pull(ctx, "equilateral_strip", eq, 0.5 + 1e-9, unsolved)
    grid = M.right_triangle_grid(n + 1, w + 1, float(n), float(w), "alternating")
    C = cauchy_born_tensor(grid.vertices, grid.edges, cfg.E * grid.edge_measure, grid.total_measure)
    E_alt, nu_alt_th = young_poisson(C, 0)
    nu_alt, E_alt_m, _ = _pull(ctx, "alternating_strip", grid, 1e-9, unsolved)
    return with_reason([
        Experiment("equilateral sheet: Poisson's ratio = 1/3", 1 / 3, nu_eq, 2e-2, id="equilateral-poisson-ratio"),
        Experiment("equilateral sheet: Young's modulus E_eff = E/3", cfg.E / 3, E_eq, 2e-2, "rel", "N/m",
                   id="equilateral-young-modulus"),
        Experiment("clamped ends stiffen the strip: F/(w * nominal strain) exceeds E/3", cfg.E / 3, E_nominal, 0,
                   ">=", "N/m", id="clamped-ends-stiffen"),
        Experiment("alternating grid, pulled along x: Poisson's ratio (Cauchy-Born, 1/5)", nu_alt_th, nu_alt, 2e-2,
                   id="alternating-poisson-ratio"),
        Experiment("alternating grid, pulled along x: Young's modulus (Cauchy-Born, 2E/5)", E_alt, E_alt_m, 2e-2,
                   "rel", "N/m", id="alternating-young-modulus"),
    ], "; ".join(unsolved))


def _pull(ctx, name: str, m2: M.Mesh, end_width: float, unsolved: list):
    """Clamp the ends (vertices within end_width of x_min/x_max), stretch by cfg.strain,
    solve the statics; returns (nu, E_eff in the middle, F/(w * nominal strain)). A solve that stops
    short of its tolerance appends why to ``unsolved`` (the measurements are then of its last iterate)."""
    cfg = ctx.cfg
    m3 = M.embed_3d(m2)
    s = stretch_strip(m3, lambda mesh, pinned: area_model(mesh, cfg.E, cfg.rho, pinned=pinned)[0], cfg.strain,
                      end_width, STRETCH_TOL)
    res, exx, eyy, F, width = s["res"], s["exx"], s["eyy"], s["F"], s["width"]
    if not res.converged:
        unsolved.append(f"{STRIPS[name]}: the static solve stopped at residual {res.residual:.2g} > {STRETCH_TOL:g} "
                        f"after {res.iterations} Newton steps ({res.message})")
    ctx.progress(f"{name}: {res.iterations} Newton steps, residual {res.residual:.2g}; eps_xx {exx:.6g} in the middle "
                 f"(nominal {cfg.strain:g}), eps_yy {eyy:.6g}, pin force {F:.6g} N")
    if ctx.rec.enabled:
        draw_strip(ctx.rec, name, m3, res.x, s["u"], cfg.strain)
    return -eyy / exx, F / (width * exx), F / (width * cfg.strain)


# ---------------------------------------------------- shared by the stages: reasons, backward Euler's claims

def dispersion_reason(cells: float, tol: float = 2e-2) -> str:
    """Why a wave speed measured on a lattice misses its long-wavelength value: a wave only ``cells``
    lattice spacings long is slower by about (k a)^2/24 (k a = 2 pi / cells), the lattice's dispersion.
    Empty when that is under a quarter of ``tol``."""
    ka = 2 * math.pi / cells
    slow = ka * ka / 24
    if slow <= 0.25 * tol:
        return ""
    return (f"lattice dispersion: the wave is only {cells:.3g} spacings long, and a lattice's waves that short are "
            f"slower than the long-wavelength (Cauchy-Born) value by about (k a)^2/24 = {slow:.2%}; use a longer "
            "wavelength")


def with_reason(exps: list, reason: str) -> list:
    """``exps`` with ``reason`` given to every experiment that has none."""
    for e in exps:
        if not e.reason:
            e.reason = reason
    return exps


def be_experiments(ctx, where: str, fits: list, jittered: list = ()) -> list:
    """Under backward Euler (``fits`` not empty): the fitted damping of the runs on regular meshes
    (``fits``) against the scheme's own, and the largest phase lag of all runs. ``where`` prefixes
    the experiments' ids (every wave stage has these two)."""
    if not fits:
        return []
    ratios = [f["gamma"] / be_damping_rate(f["w"], f["dt"]) for f in fits]
    worst = max(ratios, key=lambda q: abs(q - 1))
    every = list(fits) + list(jittered)
    phase = max(1 - f["w"] * f["dt"] / math.tan(f["w"] * f["dt"]) for f in every)
    ctx.progress("backward Euler: fitted damping / the scheme's on the regular meshes: "
                 + ", ".join(f"{q:.4f}" for q in ratios) + "; largest phase lag 1 - arctan(W dt)/(W dt) = "
                 f"{phase:.2e} ({len(every)} runs)")
    return [
        Experiment(f"backward Euler damps each wave by 1/sqrt(1 + (W dt)^2) per step: fitted / scheme's decay "
                   f"rate (worst of {len(fits)} runs)", 1.0, worst, BE_DAMPING_TOL,
                   id=f"{where}-backward-euler-damping"),
        Experiment(f"backward Euler's phase lag 1 - arctan(W dt)/(W dt) at the chosen dt (largest of {len(every)})",
                   BE_PHASE_LAG, phase, 0, "<=", id=f"{where}-backward-euler-phase-lag"),
    ]
