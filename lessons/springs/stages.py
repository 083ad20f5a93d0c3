"""The stages of ``springs`` that do not step in time (their narratives are in narrative.md): one
spring's energy and force (stage 1), the discrete energy's gradient as the PDE's stencil on three
kinds of grid (stage 3) and the hanging rod's static equilibrium (stage 5). The stages that run in
time (2 and 4) are in :mod:`.stages_dynamics`; the scenes they build, how those are drawn and what
each stage costs are in scene.py.

numpy is used only for set-up, analysis and the reference formulas the engine is compared with.
"""
from __future__ import annotations

import math
import time

import numpy as np

from engine.analysis import convergence_order
from engine.constants import G
from engine.statics import solve_static

from .._framework import Experiment
from .._measure import central_difference, central_gradient, random_rotation
from .scene import (OneSpring, draw_force_density, draw_hanging, draw_one_spring, force_density_exact, grid,
                    hanging_rod, rod_on, u)


# ------------------------------------------------------------------------- stage 1

def stage_one_spring(ctx):
    cfg = ctx.cfg
    rng = np.random.default_rng(11)
    spring = OneSpring(cfg.k, rng)
    configs = [spring.placed(rng, stretch) for stretch in (1.3, 0.8)]  # stretched by 30%, compressed by 20%
    fd_err, dir_err, closed_err, par_err, third_err = _derivative_errors(spring, configs, rng)
    rest_force = float(np.abs(spring.force(spring.X)).max()) / cfg.k
    x = configs[0]
    W0, rigid_err, rot_force_err = _rigid_motion_errors(spring, x, rng)
    W_formula = 0.5 * cfg.k * (np.linalg.norm(x[0] - x[1]) / spring.L - 1.0) ** 2 * spring.L
    if ctx.rec.enabled:
        draw_one_spring(ctx.rec, spring, configs)
    return [
        Experiment("energy W equals 1/2 k (l/L - 1)^2 L", W_formula, W0, 1e-13, "rel", "J", id="energy-formula"),
        Experiment("force equals -dW/dx_i by central differences (rel. error, eps = 1e-6)", 0.0, fd_err, 1e-7, "abs",
                   id="force-is-energy-gradient"),
        Experiment("directional derivative g'(0) = grad W . q for random q (rel. error)", 0.0, dir_err, 1e-7, "abs",
                   id="directional-derivative"),
        Experiment("no force at the rest length (max |f| / k)", 0.0, rest_force, 1e-14, "abs", id="no-force-at-rest"),
        Experiment("force is parallel to the spring: |f x d| / (|f||d|) = sin(angle)", 0.0, par_err, 1e-14, "abs",
                   id="force-along-spring"),
        Experiment("equal and opposite forces on the two ends: |f_i + f_j| / |f_i|", 0.0, third_err, 1e-15, "abs",
                   id="equal-and-opposite"),
        Experiment("energy unchanged by a rigid rotation + translation (rel. change)", 0.0, rigid_err, 1e-12, "abs",
                   id="rigid-motion-energy"),
        Experiment("force turns with the rigid rotation: |f(Rx+t) - R f(x)| / |f|", 0.0, rot_force_err, 1e-12, "abs",
                   id="rigid-motion-force"),
        Experiment("engine force equals the closed form -k (l/L - 1)(x_i - x_j)/l (rel. error)",
                   0.0, closed_err, 1e-13, "abs", id="closed-form-force"),
    ]


def _derivative_errors(spring: OneSpring, configs, rng, eps: float = 1e-6):
    """Largest errors over ``configs`` of: the force against central differences of W, the
    directional derivative along 5 random q against grad W . q, the force against the closed
    form, the force's angle to the spring, and the two ends' force balance."""
    fd_err, dir_err, closed_err, par_err, third_err = 0.0, 0.0, 0.0, 0.0, 0.0
    for x in configs:
        f = spring.force(x)
        fd = -central_gradient(spring.W, x, eps)
        fd_err = max(fd_err, np.linalg.norm(fd - f) / np.linalg.norm(f))
        grad = -f
        for _ in range(5):
            q = rng.standard_normal((2, 3))
            dq = central_difference(spring.W, x, q, eps)  # g'(0)
            dir_err = max(dir_err, abs(dq - np.sum(grad * q)) / (np.linalg.norm(grad) * np.linalg.norm(q)))
        cf = spring.closed_form(x)
        closed_err = max(closed_err, np.linalg.norm(f[0] - cf) / np.linalg.norm(cf))
        d = x[0] - x[1]
        par_err = max(par_err, np.linalg.norm(np.cross(f[0], d)) / (np.linalg.norm(f[0]) * np.linalg.norm(d)))
        third_err = max(third_err, np.linalg.norm(f[0] + f[1]) / np.linalg.norm(f[0]))
    return fd_err, dir_err, closed_err, par_err, third_err


def _rigid_motion_errors(spring: OneSpring, x, rng):
    """(W(x), relative change of W, and of the force against the rotated force) under a random
    rotation and translation."""
    R, t = random_rotation(rng, negate_all=True), rng.standard_normal(3)
    W0, f0 = spring.W(x), spring.force(x)
    xr = x @ R.T + t
    return W0, abs(spring.W(xr) - W0) / W0, np.linalg.norm(spring.force(xr) - f0 @ R.T) / np.linalg.norm(f0)


# ------------------------------------------------------------------------- stage 3

def stage_variational(ctx):
    exps = [_gradient_is_stencil(kind) for kind in ("graded", "random")]
    exps.append(_directional_derivative())
    for kind, theory, tol in (("uniform", 2.0, 0.1), ("graded", 2.0, 0.1), ("random", 1.0, 0.15)):
        exps += _force_density_order(ctx, kind, theory, tol)
    return exps


def _gradient_is_stencil(kind):
    """-grad W equals the nodal length times the FD stencil of d/dp(E(x'-1)), on a 401-node grid."""
    p = grid(kind, 401)
    rod = rod_on(p)
    h = rod.h
    x = p + u(p)
    f = rod.forces(x)
    F = rod.E * (np.diff(x) / h - 1.0)  # tension E (dx/dp - 1) per segment
    stencil = (F[1:] - F[:-1]) / (0.5 * (h[1:] + h[:-1]))
    ell = 0.5 * (h[1:] + h[:-1])
    diff = np.max(np.abs(f[1:-1] - ell * stencil)) / np.max(np.abs(f[1:-1]))
    return Experiment(f"{kind} grid: -grad W = nodal length x FD stencil of d/dp(E(x'-1)) (max rel. diff.)", 0.0,
                      diff, 1e-13, "abs", id=f"{kind}-gradient-is-stencil")


def _directional_derivative():
    """The discrete energy's derivative along a smooth test function q is -sum_i f_i q_i."""
    p = grid("graded", 401)
    rod = rod_on(p)
    x = p + u(p)
    q = np.sin(2 * np.pi * p) * p
    dq = central_difference(rod.energy, x, q, 1e-6)
    fq = -float(np.dot(rod.forces(x), q))
    return Experiment("discrete D_q W (central differences in eps) = -sum_i f_i q_i", fq, dq, 1e-7, "rel", "J",
                      id="rod-directional-derivative")


def _force_density_order(ctx, kind, theory, tol):
    """The force density (nodal force / nodal length) against the exact d/dp(E(x'-1)) on five
    refinements: the order of its rms error (and, on the graded grid, of its max error)."""
    sizes = np.array([101, 201, 401, 801, 1601])
    err_rms, err_max = [], []
    for n in sizes:
        p = grid(kind, n)
        rod = rod_on(p)
        h = rod.h
        ell = np.zeros(n)
        ell[:-1] += 0.5 * h
        ell[1:] += 0.5 * h
        dens = rod.forces(p + u(p)) / ell
        e = (dens - force_density_exact(p))[1:-1]  # interior nodes (the ends carry boundary terms)
        err_rms.append(math.sqrt(np.sum(ell[1:-1] * e * e)))
        err_max.append(np.max(np.abs(e)))
        if ctx.rec.enabled and n == sizes[0]:
            draw_force_density(ctx.rec, kind, p, dens)
    h = 1.0 / (sizes - 1)
    o_rms = convergence_order(h, np.array(err_rms))
    ctx.progress(f"{kind}: rms errors {np.array(err_rms)}, order {o_rms:.3f}")
    exps = [Experiment(f"{kind} grid: force density -> d/dp(E(x'-1)), order of the rms error",
                       theory, o_rms, tol, "abs", id=f"{kind}-force-density-order")]
    if kind == "graded":
        exps.append(Experiment("graded grid: order of the max error", theory,
                               convergence_order(h, np.array(err_max)), tol, "abs", id="graded-force-density-max-order"))
    return exps


# ------------------------------------------------------------------------- stage 5

def stage_hanging(ctx):
    exps = []
    for kind in ("uniform", "graded"):
        exps += _hanging(ctx, kind)
    return exps


HANG_TOL = 1e-10      # the static solve's residual (net force / a node's weight), unless round-off forbids it
HANG_TOL_MAX = 1e-6   # past this the forces' round-off swamps the weight: the claims fail, saying so


def force_roundoff(model, sag: float) -> float:
    """The round-off floor of the static residual r = max |f + m g| / max |m g| of a chain: a spring's
    tension c/L (l/L - 1) is computed from positions known to eps max|x| (x within ``sag`` of the rest
    shape), so each tension is uncertain by (c/L) eps (2 max|x| / L + 2), and a node's net force by
    twice that (measured floors: 0.3-0.4 of this, hanging rods of 50..5000 nodes)."""
    sp = model.springs
    eps = np.finfo(np.float64).eps
    xmax = float(np.abs(model.X).max()) + sag
    dT = sp.c_np / sp.L_np * eps * (2 * xmax / sp.L_np + 2)
    weight = float(np.max(model.mass[model.free] * np.linalg.norm(model.gravity)))
    return 2 * float(dT.max()) / weight


def _hanging(ctx, kind, tol=HANG_TOL):
    """The static equilibrium of the hanging rod on a ``kind`` grid against u = (rho g/E)(L p - p^2/2),
    and the pin's reaction against the weight. The solve's tolerance is HANG_TOL, or twice the residual's
    round-off floor (:func:`force_roundoff`) where that is larger (a long or stiff rod); past HANG_TOL_MAX
    the claims cannot be checked in f64 and fail with that reason."""
    cfg = ctx.cfg
    model, p = hanging_rod(cfg, kind)
    floor = force_roundoff(model, cfg.rho * G / (2 * cfg.E))
    tol = min(max(tol, 2 * floor), HANG_TOL_MAX)
    reason = "" if 2 * floor <= HANG_TOL_MAX else (
        f"round-off: the rod's spring forces are known only to {floor:.1e} of a node's weight (E / (rho g h^2) = "
        f"{cfg.E / (cfg.rho * G * float(np.max(np.diff(p))) ** 2):.2g}; positions carry 1e-16 m), so its sag cannot be "
        f"resolved to {HANG_TOL_MAX:g}; use a smaller --E/--rho or fewer --hang-nodes")
    t0 = time.perf_counter()
    res = solve_static(model, tol=tol, raise_on_failure=False, max_iter=max(100, 4 * int(math.log2(cfg.hang_nodes)) + 50))
    ctx.progress(f"{kind}: Newton {res.iterations} iterations, residual {res.residual:.3g} "
                 f"({time.perf_counter() - t0:.2f} s)")
    x = np.asarray(res.x)
    u = -(x[:, 2] - model.X[:, 2])
    u_exact = cfg.rho * G / cfg.E * (p - 0.5 * p * p)
    err = float(np.max(np.abs(u - u_exact)) / np.max(np.abs(u_exact)))
    weight = cfg.rho * G * 1.0
    if ctx.rec.enabled:
        draw_hanging(ctx.rec, kind, model, x, cfg.rho * G / cfg.E)
    return [
        Experiment(f"{kind} grid: static solver converged (net-force residual <= tol)", tol, res.residual, 0, "<=",
                   id=f"hanging-{kind}-converged", reason=reason or res.message),
        # a residual r leaves each tension wrong by at most (n - 1) r max(m g), hence u by at most
        # (n - 1) r max(m) g L / E = 2 (n - 1) max(m) / (rho L) r u_max
        Experiment(f"{kind} grid: nodal displacement = (rho g/E)(L p - p^2/2) (max rel. error)",
                   0.0, err, 2 * (cfg.hang_nodes - 1) * model.mass.max() / cfg.rho * tol, "abs",
                   id=f"hanging-{kind}-displacement", reason=reason),
        # R - weight = sum of the free nodes' residual forces: at most (n - 1) r max(m g)
        Experiment(f"{kind} grid: pin reaction carries the whole weight rho g L", weight,
                   float(res.reactions[0, 2]), (cfg.hang_nodes - 1) * tol, "rel", "N", id=f"hanging-{kind}-pin-reaction",
                   reason=reason),
    ]
