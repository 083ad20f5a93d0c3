"""The stages of ``membranes``: the triangle energies' derivatives and the constant-strain patch
test, the static stretch that measures Young's modulus and Poisson's ratio on two meshes, wave
speeds in four directions on the mesh where springs are anisotropic, and a hanging cloth under
Baraff and Witkin's model stepped by backward Euler at large steps."""
import math

import numpy as np

from engine import mesh as M
from engine.energies.membrane import MembraneEnergy, lame
from engine.stability import stable_dt_estimate
from engine.theory.schemes import backward_euler_damped_sequence, velocity_verlet_damped_rates
from engine.waves import cauchy_born_tensor, christoffel
from lessons.views import RunView

from .._framework import Experiment
from .._scene import simulate
from .._waves import RUN_PERIODS, sheet_drawer, square_domain_cells, standing_wave, unit, wave_grid, wave_steps
from .scene import (STRIPS, announce, cloth_logger, draw_patch, hanging_cloth, lattice_modes, lattice_speed,
                    lattice_wave, membrane_model, plane_speeds, pull, springs_for, strip, triangle_stretch,
                    uniaxial_theory, vertex_mean)


# ---------------------------------------------------------------------------- stage 1

MODELS = {"stvk": "St. Venant-Kirchhoff triangle", "baraff-witkin": "Baraff-Witkin stretch + shear"}


def _patch(seed: int = 4):
    """A jittered 4 x 4 right-triangle patch (m), 3D-embedded: the mesh every derivative check runs on."""
    return M.embed_3d(M.jitter(M.right_triangle_grid(4, 4, 0.3, 0.3, "alternating"), 0.2, seed=seed))


def _params(cfg, model: str) -> dict:
    return dict(Y=cfg.Y, nu=cfg.nu) if model == "stvk" else dict(k_stretch=cfg.Y, k_shear=0.5 * cfg.Y)


def _psi(model: str, F: np.ndarray, p: dict) -> float:
    """The energy per rest area of the homogeneous deformation F (3x2): (M1) or (M2) written out."""
    if model == "stvk":
        mu, lam = lame(p["Y"], p["nu"])
        E = 0.5 * (F.T @ F - np.eye(2))
        return mu * np.sum(E * E) + 0.5 * lam * np.trace(E) ** 2
    lu, lv, s = np.linalg.norm(F[:, 0]), np.linalg.norm(F[:, 1]), F[:, 0] @ F[:, 1]
    return 0.5 * p["k_stretch"] * ((lu - 1) ** 2 + (lv - 1) ** 2) + 0.5 * p["k_shear"] * s * s


def stage_triangles(ctx):
    cfg = ctx.cfg
    rng = np.random.default_rng(1)
    m3 = _patch()
    X = m3.vertices
    exps = []
    for model, title in MODELS.items():
        p = _params(cfg, model)
        energy = MembraneEnergy.from_mesh(m3, model, **p)
        x = X + 0.05 * rng.standard_normal(X.shape)   # stretched here, compressed there
        f = energy.forces(x)
        eps = 1e-7
        grad = np.zeros_like(x)
        for i in range(len(x)):
            for j in range(3):
                xp, xm = x.copy(), x.copy()
                xp[i, j] += eps
                xm[i, j] -= eps
                grad[i, j] = (energy.energy(xp) - energy.energy(xm)) / (2 * eps)
        H = energy.dense_hessian(x, psd=False)
        Hfd = np.zeros_like(H)
        for c in range(H.shape[0]):
            xp, xm = x.reshape(-1).copy(), x.reshape(-1).copy()
            xp[c] += eps
            xm[c] -= eps
            Hfd[:, c] = -(energy.forces(xp.reshape(-1, 3)) - energy.forces(xm.reshape(-1, 3))).reshape(-1) / (2 * eps)
        exact = np.linalg.eigvalsh(H)
        psd = np.linalg.eigvalsh(energy.dense_hessian(x, psd=True))
        # constant strain is exact: an affine map X -> F X_uv + b gives W = A psi(F) on any triangles
        F = np.eye(3)[:, :2] + 0.2 * rng.standard_normal((3, 2))
        b = rng.standard_normal(3)
        W_affine = energy.energy(X[:, :2] @ F.T + b)
        W_theory = m3.total_measure * _psi(model, F, p)
        Q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
        slug = "stvk" if model == "stvk" else "bw"
        if ctx.rec.enabled:
            draw_patch(ctx.rec, f"{slug}_patch", f"{title}: the randomly deformed patch", m3, x, energy)
        ctx.progress(f"{title}: exact Hessian's eigenvalues {exact.min():.3g} .. {exact.max():.3g}, PSD variant's "
                     f"from {psd.min():.3g}")
        exps += [
            Experiment(f"{title}: force = -dW/dx (central differences, max rel. error)", 0,
                       np.abs(f + grad).max() / np.abs(grad).max(), 1e-6, "abs", id=f"{slug}-force-is-gradient"),
            Experiment(f"{title}: Hessian = -df/dx (central differences, max rel. error)", 0,
                       np.abs(H - Hfd).max() / np.abs(Hfd).max(), 1e-6, "abs", id=f"{slug}-hessian-is-jacobian"),
            Experiment(f"{title}: the exact Hessian of a compressed patch is indefinite (lowest eigenvalue / "
                       f"largest, clearly below the rigid motions' 0)", -1e-3, exact.min() / exact.max(), 0, "<=",
                       id=f"{slug}-exact-hessian-indefinite"),
            Experiment(f"{title}: the PSD variant has no negative eigenvalue (lowest / largest)", -1e-12,
                       psd.min() / psd.max(), 0, ">=", id=f"{slug}-psd-hessian"),
            Experiment(f"{title}: an affine deformation of a jittered patch stores area x psi(F) (rel. error)",
                       W_theory, W_affine, 1e-12, id=f"{slug}-patch-test"),
            Experiment(f"{title}: energy unchanged by a rigid motion (rel. change)", 0,
                       abs(energy.energy(x @ Q.T + b) - energy.energy(x)) / energy.energy(x), 1e-12, "abs",
                       id=f"{slug}-rigid-invariance"),
        ]
    return exps


# ---------------------------------------------------------------------------- stage 2

POISSON_SWEEP = (0.0, 0.45)   # besides --nu: the ends of the range the lesson claims
STRETCH_TOL_NU = 1e-3   # absolute, on Poisson's ratio: the clamped ends disturb the middle fifth by 0.6e-4 .. 2.4e-4
                        # (measured over --strain 1e-6 .. 0.01, --strip-cells 24 .. 160, nu 0 .. 0.45)
STRETCH_TOL_E = 3e-4    # relative, on the modulus (measured 1.5e-5 .. 1.2e-4 there): resolves the finite-strain
                        # factor (1 + eps)(1 + eps/2), 1.5e-3 at the default strain
FINITE_STRAIN = 0.1     # the further pull, where Poisson's ratio's finite-strain correction is large
FINITE_NU = 0.45        # ... on the material where it is largest: 0.485 instead of 0.45
FINITE_TOL_NU = 2e-3    # absolute (measured 4e-4 .. 6.4e-4; the small-strain 0.45 is 3.5e-2 off)
FINITE_TOL_E = 1e-3     # relative (measured 1.3e-4 .. 1.9e-4; the small-strain Y is 0.158 off)


def stage_stretch(ctx):
    cfg = ctx.cfg
    announce(ctx, 2)
    exps, unsolved = [], []
    sweep = sorted({cfg.nu, *POISSON_SWEEP})
    for kind, label in STRIPS.items():
        m3 = strip(kind, cfg.strip_cells)
        for nu in sweep:
            def build(mesh, pinned, nu=nu):
                return membrane_model(mesh, cfg.rho, "stvk", pinned=pinned, Y=cfg.Y, nu=nu)[0]
            shown = kind == "equilateral" or nu == cfg.nu   # the sweep side by side on one mesh
            nu_m, E_m, exx = pull(ctx, f"stvk_{kind}_nu{nu:g}", f"{label}, St. Venant-Kirchhoff, nu = {nu:g}", m3, kind,
                                  build, unsolved, draw=shown)
            nu_t, E_t = uniaxial_theory("stvk", cfg.Y, nu, exx)
            slug = f"{kind}-nu{nu:g}"
            exps += [Experiment(f"{label}, St. Venant-Kirchhoff set to nu = {nu:g}: Poisson's ratio", nu_t, nu_m,
                                STRETCH_TOL_NU, "abs", id=f"stvk-poisson-{slug}"),
                     Experiment(f"{label}, nu = {nu:g}: Young's modulus F/(w eps) = Y (1 + eps)(1 + eps/2)", E_t, E_m,
                                STRETCH_TOL_E, "rel", "N/m", id=f"stvk-young-{slug}")]
        def build(mesh, pinned):
            return membrane_model(mesh, cfg.rho, "stvk", pinned=pinned, Y=cfg.Y, nu=FINITE_NU)[0]
        nu_m, E_m, exx = pull(ctx, f"stvk_{kind}_finite", f"{label}, St. Venant-Kirchhoff, nu = {FINITE_NU:g}", m3, kind,
                              build, unsolved, strain=FINITE_STRAIN)
        nu_t, E_t = uniaxial_theory("stvk", cfg.Y, FINITE_NU, exx)
        exps += [Experiment(f"{label}, nu = {FINITE_NU:g} pulled by {100 * FINITE_STRAIN:g}%: Poisson's ratio -eps_yy/eps_xx "
                            f"of the exact uniaxial response (small strain: {FINITE_NU:g})", nu_t, nu_m, FINITE_TOL_NU,
                            "abs", id=f"stvk-finite-poisson-{kind}"),
                 Experiment(f"{label}, nu = {FINITE_NU:g} pulled by {100 * FINITE_STRAIN:g}%: F/(w eps) = "
                            f"Y (1 + eps)(1 + eps/2) (small strain: Y)", E_t, E_m, FINITE_TOL_E, "rel", "N/m",
                            id=f"stvk-finite-young-{kind}")]
        nu_s, E_s, _ = pull(ctx, f"springs_{kind}", f"{label}, area springs", m3, kind,
                            lambda mesh, pinned: springs_for(mesh, cfg.Y, cfg.rho, pinned), unsolved,
                            draw=kind == "equilateral")
        if kind == "equilateral":
            exps.append(Experiment(f"{label}, area springs: Poisson's ratio is 1/3 whatever the material's",
                                   1 / 3, nu_s, 2e-2, id="springs-poisson-equilateral"))
        else:
            m2 = M.right_triangle_grid(9, 9, 8.0, 8.0, kind)
            C = cauchy_born_tensor(m2.vertices, m2.edges, cfg.Y * M.edge_measure(m2), m2.total_measure)
            from engine.waves import young_poisson
            E_cb, nu_cb = young_poisson(C, 0)
            exps.append(Experiment(f"{label}, area springs: Poisson's ratio (Cauchy-Born, {nu_cb:.3g}: the mesh "
                                   f"sets it)", nu_cb, nu_s, 2e-2, id=f"springs-poisson-{kind}"))
        bw = lambda mesh, pinned: membrane_model(mesh, cfg.rho, "baraff-witkin", pinned=pinned, k_stretch=cfg.Y,
                                                 k_shear=0.5 * cfg.Y)[0]
        nu_b, E_b, exx = pull(ctx, f"bw_{kind}", f"{label}, Baraff-Witkin", m3, kind, bw, unsolved,
                              draw=kind == "equilateral")
        exps += [Experiment(f"{label}, Baraff-Witkin: Poisson's ratio 0 (the stretch conditions do not couple u, v)",
                            0.0, nu_b, STRETCH_TOL_NU, "abs", id=f"bw-poisson-{kind}"),
                 Experiment(f"{label}, Baraff-Witkin: modulus F/(w eps) = k_stretch", cfg.Y, E_b, STRETCH_TOL_E, "rel",
                            "N/m", id=f"bw-young-{kind}")]
    for e in exps:
        if unsolved and not e.reason:
            e.reason = "; ".join(unsolved)
    return exps


# ---------------------------------------------------------------------------- stage 3

DIRECTIONS = {"x": ([1.0, 0.0], "x"), "y": ([0.0, 1.0], "y"), "diagonal (1,1)": ([1.0, 1.0], "diagonal-plus"),
              "diagonal (1,-1)": ([1.0, -1.0], "diagonal-minus")}
SPEED_TOL = 2e-2      # against the continuum: the lattice's dispersion is 1.6e-3 .. 2% (--wavelength 96 .. 16)
LATTICE_TOL = 5e-5    # against the grid's own wave under velocity Verlet's step: measured 1.6e-7 .. 7e-7 at
                      # --wavelength 32 .. 96, 8e-6 (a speed) and 1.3e-5 (a ratio of two) at 16, where the disc
                      # read is 2.4 spacings wide
ORDER_WAVELENGTHS = (1, 2, 4, 8)   # the anisotropy's convergence, over these multiples of --wavelength
ORDER_TOL = 0.02      # on the order (measured 1.986 at --wavelength 16 .. 1.9996 at 96; the next term is (k h)^4)


def stage_waves(ctx):
    cfg = ctx.cfg
    announce(ctx, 3)
    lam = float(cfg.wavelength)
    k = 2 * math.pi / lam
    r = 0.15 * lam
    cP, cS = plane_speeds(cfg.Y, cfg.nu, cfg.rho)
    half = r + RUN_PERIODS * lam * (cP / cS) * 1.05 + 2.0   # the fastest wave must not reach the disc from the edge
    if ctx.integrator_name("velocity-verlet") == "backward-euler":
        half = 2 * half   # its step couples the whole sheet: the edges would disturb the disc by 1e-4 (5e-6 at twice)
    n = square_domain_cells(half, 1.0) + 1
    m2, m3, ctr, region = wave_grid(n, "one-way", r)
    def build(mesh):   # the continuum triangle, on the run's sheet and on the Bloch patch alike
        return membrane_model(mesh, cfg.rho, "stvk", Y=cfg.Y, nu=cfg.nu)
    model, _ = build(m3)
    mass = model.mass
    exps, measured, predicted, fits = [], {}, {}, []
    span = RUN_PERIODS * lam / cS
    method = ctx.integrator_name("velocity-verlet")
    grid = lattice_modes("one-way", build)
    for label, (d, slug) in DIRECTIONS.items():
        for wave, c_theory in (("P", cP), ("S", cS)):
            if wave == "S" and label not in ("x", "diagonal (1,1)"):
                continue
            n_dir = unit(d)
            pol = n_dir if wave == "P" else np.array([-n_dir[1], n_dir[0]])
            view = RunView(label=f"St. Venant-Kirchhoff, one-way grid: {wave} wave along {label}", camera="top",
                           span=span) if wave == "P" and label in ("diagonal (1,1)", "diagonal (1,-1)") else None
            v = standing_wave(ctx, f"stvk_{wave}_{slug}", model, mass, n_dir, pol, k, ctr, region, c_theory,
                              sheet_drawer(m3) if view else None, fits, view=view)
            measured[wave, label] = v
            dt = wave_steps(ctx, model, k, c_theory)[1]
            predicted[wave, label] = lattice_speed(grid, k, n_dir, pol, method, dt)
            ctx.progress(f"{wave} along {label}: measured {v:.7f} m/s, the grid's own wave under {method} "
                         f"{predicted[wave, label]:.7f} m/s, the continuum's {c_theory:.5f} m/s")
            exps.append(Experiment(f"St. Venant-Kirchhoff on the one-way grid: {wave} wave along {label} = "
                                   f"{'sqrt(Y/((1 - nu^2) rho))' if wave == 'P' else 'sqrt(mu/rho)'}", c_theory, v,
                                   SPEED_TOL, "rel", "m/s", id=f"stvk-{wave.lower()}-wave-{slug}"))
    reason = "" if method in ("velocity-verlet", "backward-euler") else (
        f"--integrator {method} starts each standing wave with a phase offset of order (w dt)^2, which the "
                "fitted frequency takes in; the grid's own wave is resolved under velocity Verlet, whose q_n is "
                "exactly cos(n w dt) from rest")
    worst = max(abs(measured[key] / predicted[key] - 1) for key in measured)
    exps.append(Experiment(f"each of the {len(measured)} speeds is the grid's own: its plane wave at this k (from the "
                           f"engine's Hessian, real masses) under {method}'s step (max |measured / predicted - 1|)",
                           0, worst, LATTICE_TOL, "abs", id="stvk-lattice-speeds", reason=reason))

    def spread(values):
        return max(values) / min(values) - 1
    p_dirs = list(DIRECTIONS)
    exps.append(Experiment("the P speeds of the four directions differ by the grid's own spread (max/min - 1; "
                           "the continuum's is 0)", spread([predicted["P", d] for d in p_dirs]),
                           spread([measured["P", d] for d in p_dirs]), LATTICE_TOL, "abs", id="stvk-p-spread",
                           reason=reason))
    s_ratio = measured["S", "x"] / measured["S", "diagonal (1,1)"] - 1
    exps.append(Experiment("S along x over S along the diagonal, minus 1: the grid's own value (the continuum's is 0)",
                           predicted["S", "x"] / predicted["S", "diagonal (1,1)"] - 1, s_ratio, LATTICE_TOL, "abs",
                           id="stvk-s-anisotropy", reason=reason))
    # the anisotropy vanishes as h -> 0: the grid's own waves (no time step) at longer and longer wavelengths
    lams = [lam * m for m in ORDER_WAVELENGTHS]
    gaps = [abs(lattice_speed(grid, 2 * math.pi / L, unit([1.0, 0.0]), unit([0.0, 1.0])) /
                lattice_speed(grid, 2 * math.pi / L, unit([1.0, 1.0]), unit([-1.0, 1.0])) - 1) for L in lams]
    order = -float(np.polyfit(np.log(lams), np.log(gaps), 1)[0])
    ctx.progress(f"the grid's S anisotropy at wavelengths {', '.join(f'{L:g}' for L in lams)}: "
                 f"{', '.join(f'{g:.3g}' for g in gaps)} (order {order:.4f})")
    exps.append(Experiment(f"isotropy returns as h -> 0: the grid's S anisotropy falls as (h/wavelength)^2 (fitted "
                           f"order over {lams[0]:g} .. {lams[-1]:g} spacings; {gaps[0]:.2g} at {lams[0]:g}, "
                           f"{gaps[-1]:.2g} at {lams[-1]:g})", 2.0, order, ORDER_TOL, "abs", id="stvk-isotropy-order"))
    # the same grid with area springs: Cauchy-Born's anisotropy, measured along both diagonals
    springs = springs_for(m3, cfg.Y, cfg.rho)
    C = cauchy_born_tensor(m2.vertices, m2.edges, cfg.Y * M.edge_measure(m2), m2.total_measure)
    ratio_t = christoffel(C, DIRECTIONS["diagonal (1,1)"][0], cfg.rho)[0][-1] / \
        christoffel(C, DIRECTIONS["diagonal (1,-1)"][0], cfg.rho)[0][-1]
    speeds = {}
    for label in ("diagonal (1,1)", "diagonal (1,-1)"):   # drawn beside the continuum's, on the same timeline
        d, slug = DIRECTIONS[label]
        view = RunView(label=f"area springs, the same grid: P wave along {label}", camera="top", span=span)
        speeds[label] = standing_wave(ctx, f"springs_P_{slug}", springs, springs.mass, unit(d), unit(d), k, ctr,
                                      region, cP, sheet_drawer(m3), fits, view=view)
    v_plus, v_minus = speeds["diagonal (1,1)"], speeds["diagonal (1,-1)"]
    exps.append(Experiment(f"area springs on the same grid: P speed along / across its diagonals (Cauchy-Born "
                           f"{ratio_t:.3f})", ratio_t, v_plus / v_minus, SPEED_TOL, id="springs-anisotropic"))
    return exps


# ---------------------------------------------------------------------------- stage 4

METHOD_LABELS = {"backward-euler": "backward Euler", "symplectic-euler": "symplectic Euler",
                 "velocity-verlet": "velocity Verlet", "forward-euler": "forward Euler"}
SETTLED_TOL = 1e-6   # distance to the static equilibrium, as a fraction of the cloth's size


def stage_hanging(ctx):
    from engine.statics import solve_static

    cfg = ctx.cfg
    announce(ctx, 4)
    model, m3 = hanging_cloth(cfg)
    ref = solve_static(model, tol=1e-10, max_iter=80)
    ref_energy = model.potential_energy(ref.x)
    rest_stretch = float(vertex_mean(m3.triangles, m3.n_vertices, triangle_stretch(model.energies[0], ref.x)).max())
    dt_explicit = stable_dt_estimate(model)
    method = ctx.integrator_name("backward-euler")
    label = METHOD_LABELS.get(method, method)
    reason = "" if method == "backward-euler" else (
        f"these are backward Euler's claims, and --integrator {method} stepped the cloth: an explicit method "
        "neither damps the cloth's vibration nor keeps its energy from rising and falling")
    exps = []
    for factor in (1, cfg.large_step):
        dt = factor / 60.0
        n_steps = max(1, int(round(cfg.settle_time / dt)))
        state = model.make_state()
        totals, distances = [], []

        def observe(step, st):
            x, v, _ = st.numpy()
            totals.append(model.potential_energy(st.x) + 0.5 * float(np.sum(model.mass[:, None] * v * v)))
            distances.append(float(np.abs(x - ref.x).max()) / cfg.cloth_size)
        name = f"bw_backward_euler_dt{factor}"
        view = RunView(label=f"Baraff-Witkin cloth, {label}, dt = {factor}/60 s", camera="front", span=cfg.settle_time,
                       plot=("settling", "log10: distance to equilibrium / size (orange), energy above it (white)"))
        simulate(ctx, name, model, state, dt, n_steps, integrator="backward-euler", every=1, observe=observe,
                 log=cloth_logger(m3, model.energies[0], 2 * rest_stretch), view=view, solver="cholesky")
        # what settles, on a log scale: the cloth stops moving on screen long before it reaches the equilibrium
        excess = (np.asarray(totals) - ref_energy) / (totals[0] - ref_energy)
        steps = np.arange(len(totals))
        ctx.rec.scalar_series("settling/log10_distance", np.log10(np.maximum(distances, 1e-16)), steps)
        ctx.rec.scalar_series("settling/log10_excess", np.log10(np.maximum(excess, 1e-16)), steps)
        x = state.numpy().x
        gap = float(np.abs(x - ref.x).max()) / cfg.cloth_size
        rise = max(0.0, max(b - a for a, b in zip(totals, totals[1:]))) / abs(totals[0] - min(totals))
        ctx.progress(f"dt = {factor}/60 s ({dt / dt_explicit:.3g} x the explicit limit {dt_explicit:.3g} s): "
                     f"{n_steps} steps, distance to the static equilibrium {gap:.3g} x size, largest energy rise "
                     f"{rise:.3g} of the energy lost")
        exps += [
            Experiment(f"{label} at dt = {factor}/60 s = {dt / dt_explicit:.0f} x the explicit limit settles on the "
                       f"static equilibrium (max distance / size after {cfg.settle_time:g} s)", SETTLED_TOL, gap, 0,
                       "<=", id=f"bw-settles-dt{factor}", reason=reason),
            Experiment(f"{label} at dt = {factor}/60 s: the energy never rises from step to step (largest rise / "
                       f"energy lost)", 1e-9, rise, 0, "<=", id=f"bw-energy-decreases-dt{factor}", reason=reason),
        ]
    return exps


# ---------------------------------------------------------------------------- stage 5

DECAY_TOL = 1e-7      # relative, on the fitted decay rate (measured 1e-11 .. 4e-10 over the options' ranges)
FREQUENCY_TOL = 1e-7  # relative, on the fitted frequency (measured 1e-12 .. 7e-11)
BE_OMEGA_DT = 0.5     # the backward-Euler run's w dt: its own damping is then about 5x the physical one
BE_STEPS = 4          # backward Euler's steps, read one by one (later the sheet's edges reach the disc: the
                      # implicit solve couples the whole sheet at every step)
BE_SEQUENCE_TOL = 1e-6  # absolute, on a_n/a_0 (measured 6e-9 .. 3e-8; the Newton tolerance 1e-8)


def stage_damping(ctx):
    from .scene import damped_margin, damped_wave, fit_decay

    cfg = ctx.cfg
    announce(ctx, 5)
    lam = float(cfg.wavelength)
    k = 2 * math.pi / lam
    r = 0.15 * lam
    ks, rho = cfg.Y, cfg.rho
    w0 = k * math.sqrt(ks / rho)                      # the undamped P wave along the warp: nu = 0, modulus k_s
    kd = 2 * cfg.damping_ratio * math.sqrt(ks * rho) / k   # k_d giving the damping ratio asked for at this k
    gamma = kd * k * k / (2 * rho)                    # (M3) on this wave: rho u'' = k_s u_xx + k_d u_xx'
    half = r + damped_margin(lam, cfg.damping_ratio) + 2.0   # the free edges' disturbance stays out of the disc
    n = square_domain_cells(half, 1.0) + 1
    _, m3, ctr, region = wave_grid(n, "alternating", r)
    def build(mesh):   # the damped sheet's material, on the run's sheet and on the Bloch patch alike
        return membrane_model(mesh, rho, "baraff-witkin", k_stretch=ks, k_shear=0.5 * ks, damping_stretch=kd,
                              damping_shear=0.5 * kd)
    model, _ = build(m3)
    ctx.progress(f"k_d = {kd:.4g} N s/m for a damping ratio {cfg.damping_ratio:g} at the wavelength {lam:g} m: "
                 f"decay rate {gamma:.4g} 1/s, w0 = {w0:.4g} rad/s")
    # the wave on this lattice, with its real lumped masses (4/3 and 2/3 of rho h^2 on the alternating grid)
    w2h, ch, profile = lattice_wave("alternating", [k, 0.0], [1.0, 0.0], build)
    shape = profile(m3.vertices)
    damper = model.dampers[0]
    c_max = float((damper.damping_row_sums(model.X) / model.mass[:, None]).max())   # the fastest-damped mode's c
    dt_stiff = stable_dt_estimate(model)
    dt = cfg.cfl * min(dt_stiff, 2.0 / c_max)
    if 2.0 / c_max < dt_stiff:
        ctx.progress(f"the damping of the shortest waves (c up to {c_max:.3g} 1/s) limits the explicit step to "
                     f"{2.0 / c_max:.3g} s, below the stiffness' {dt_stiff:.3g} s")
    n_steps = int(math.ceil(2 * math.pi / w0 / dt))
    t, a = damped_wave(ctx, "damped_verlet", model, m3, k, ctr, region, dt, n_steps, "velocity-verlet",
                       f"Baraff-Witkin sheet, damping ratio {cfg.damping_ratio:g}: P wave along the warp, velocity "
                       "Verlet", shape)
    w_m, g_m = fit_decay(t, a, w0)
    w_s, g_s = velocity_verlet_damped_rates(w2h, ch, dt)
    dt_be = BE_OMEGA_DT / w0
    t2, a2 = damped_wave(ctx, "damped_backward_euler", model, m3, k, ctr, region, dt_be, BE_STEPS, "backward-euler",
                         f"the same wave, backward Euler at w dt = {BE_OMEGA_DT:g}", shape)
    predicted = backward_euler_damped_sequence(w2h, ch, dt_be, BE_STEPS)
    undamped = backward_euler_damped_sequence(w2h, 0.0, dt_be, BE_STEPS)
    seen = a2 / a2[0]
    dev = float(np.abs(seen - predicted).max())
    ctx.progress(f"velocity Verlet: fitted w {w_m:.6g} rad/s (its map {w_s:.6g}), decay {g_m:.5g} 1/s (its map "
                 f"{g_s:.5g}, the continuum {gamma:.5g}); backward Euler at dt = {dt_be:.3g} s, amplitude after "
                 f"each step: {np.round(seen[1:], 5).tolist()}, predicted {np.round(predicted[1:], 5).tolist()} "
                 f"(undamped {np.round(undamped[1:], 5).tolist()})")
    return [
        Experiment(f"damping ratio {cfg.damping_ratio:g}: the wave decays as velocity Verlet's map predicts for this "
                   f"mode (continuum k_d k^2 / (2 rho) = {gamma:.4g} 1/s; the scheme takes the damping at the "
                   "half-kicked velocity)", g_s, g_m, DECAY_TOL, "rel", "1/s", id="damping-decay-rate"),
        Experiment("the damped wave's frequency is the map's (about sqrt(w0^2 - gamma^2) on the lattice)", w_s, w_m,
                   FREQUENCY_TOL, "rel", "rad/s", id="damped-frequency"),
        Experiment(f"backward Euler at w dt = {BE_OMEGA_DT:g}: the first {BE_STEPS} steps follow its damped map "
                   f"(M + dt C + dt^2 K) v+ = M v - dt K x (max |a_n/a_0 - predicted|; undamped it would be off by "
                   f"{float(np.abs(undamped - predicted).max()):.2g})", 0.0, dev, BE_SEQUENCE_TOL, "abs",
                   id="damping-backward-euler"),
    ]
