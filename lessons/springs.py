"""Lesson ``springs``: forces from potential energy, the variational derivative, energy
conservation, stiffness from the speed of sound, a hanging rod.

Physics lives in the engine (:mod:`engine.energies.springs`, :mod:`engine.model`,
:mod:`engine.integrators.fused`, :mod:`engine.rod`, :mod:`engine.statics`); this module builds
scenes, runs them, measures and narrates. numpy is used only for set-up, analysis and the
reference formulas the engine is compared with.

Runs are *fixed* (stage 2: its claims are about symplectic Euler, velocity Verlet and forward
Euler themselves) or *scene* runs (stage 4's pulses), which use ``--integrator``: the explicit
choices run in the fused kernel, backward Euler through :func:`lessons._scene.simulate` with the
engine's implicit integrator (``--solver/--tol/--newton-iterations`` apply). Stages 1, 3 and 5
do not step in time.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla

from engine import diagnostics
from engine import mesh as meshes
from engine.analysis import convergence_order, fit_slope
from engine.constants import G
from engine.errors import BlowUpError
from engine.integrators import get as get_integrator
from engine.integrators.explicit import stable_dt_estimate
from engine.integrators.fused import METHODS as FUSED_METHODS, run_fused
from engine.model import Model, vec3_ndarray
from engine.rod import Rod
from engine.statics import solve_static

from ._framework import Experiment, Lesson, Stage, param
from ._measure import (central_difference, central_gradient, edge_strain, expect, modal_tracks, observation_steps,
                       random_rotation, rod_node_strain, track_peaks)
from ._scene import run_chunked, simulate as scene_simulate, step_drawer

@dataclass
class SpringsConfig:
    k: float = param(50.0, "stage 1: the notes' spring constant k in W = 1/2 k (l/L - 1)^2 L "
                     "(force per unit strain)", "N", gt=0, le=1e9)
    chain_nodes: int = param(12, "stage 2: nodes of the swinging chain (1 m long, top node pinned)", ge=3, le=200)
    chain_k: float = param(1000.0, "stage 2: spring constant k of every chain link", "N", gt=0, le=1e9)
    frame_k: float = param(100.0, "stage 2: spring constant k of every edge of the tetrahedral frame", "N",
                           gt=0, le=1e9)
    steps: int = param(100_000, "stage 2: steps of each energy-conservation run", ge=1000, le=10**7)
    dt_fraction: float = param(0.1, "stage 2: time step as a fraction of the engine's CFL estimate",
                               gt=0, le=1.0)
    wave_segments: int = param(1500, "stage 4: 1/h, h the shortest segment of the 1 m chains", ge=1000,
                                le=20000)
    E: float = param(100.0, "stages 4-5: Young's modulus of the rod/chain (1D: force per unit strain)", "N",
                     gt=0, le=1e9)
    rho: float = param(1.0, "stages 4-5: linear density", "kg/m", ge=1e-6, le=1e6)
    hang_nodes: int = param(41, "stage 5: nodes of the hanging rod (1 m)", ge=3, le=5000)
    record_every: int = param(1000, "stage 2: log the spring network every k-th step", ge=1)


# ------------------------------------------------------------------ shared machinery

def chain_edges(n: int) -> np.ndarray:
    return np.stack([np.arange(n - 1), np.arange(1, n)], axis=1)


def draw_springs(rec, model: Model, x: np.ndarray, scale: float | None = None) -> None:
    """The spring network as line strips coloured by strain (blue compressed, red stretched)."""
    sp = model.springs
    rec.springs(x, sp.edges_np, edge_strain(x, sp.edges_np, sp.L_np), scale=scale)
    rec.points("nodes", x, colors=np.where(model.pinned[:, None], [[230, 60, 60]], [[200, 200, 200]]),
               radii=0.006)


def simulate_fused(ctx, name: str, model: Model, state, dt: float, n_steps: int, method: str,
                   every: int, energy_bound: float | None = None, observe=None, log=None, fixed: bool = False):
    """Run ``n_steps`` of :func:`run_fused` in chunks of ``every`` steps (one launch each),
    recording the energies of every step and calling ``log(rec, state)`` (when recording) and
    ``observe(step, state)`` after each chunk and at step 0. The run's integrator is noted
    (``fixed`` or not). Returns (kinetic, potential) per step. A blow-up is recorded up to its
    step, marked, and re-raised."""
    rec = ctx.rec
    ctx.note_integrator(name, method, fixed)
    rec.run(name)
    return run_chunked(ctx, name, dt, n_steps, every, draw=step_drawer(rec, dt, state, log, observe),
                       advance=lambda chunk, done: run_fused(model, state, dt, chunk, method, energy_bound,
                                                             step_offset=done))


# ------------------------------------------------------------------------- stage 1

S1_TEXT = """
A spring between nodes i and j stores W = 1/2 k (l/L - 1)^2 L, where l = |x_i - x_j| is its
current length and L its rest length: the squared fractional stretch, weighted by the spring's
stiffness and by the amount of material it stands for. Everything else in this lesson follows
from one rule: the force on a node is minus the gradient of the energy with respect to that
node's position.

We check the engine's spring force against that rule in several independent ways. Nudging each
coordinate of x_i by +-eps and differencing W gives -dW/dx_i numerically. Picking a random
direction q for the whole configuration, the function g(eps) = W(x + eps q) has slope g'(0) =
grad W . q: this directional derivative is the definition of the gradient, and it is also the
idea behind the variational derivative of stage 3. At the rest length the force must vanish;
because W depends on the positions only through the distance l, the force must point along the
spring; and for the same reason W cannot change when the spring is moved rigidly (rotated and
translated), while the force turns with it. Finally the engine's force is compared with the
closed form obtained by differentiating W by hand, f_ij = -k (l/L - 1)(x_i - x_j)/l, for a
stretched and a compressed spring.
"""


def stage_one_spring(ctx):
    cfg = ctx.cfg
    rng = np.random.default_rng(11)
    L = 0.3
    direction = rng.standard_normal(3)
    X = np.array([[0.1, -0.2, 0.05], [0.0, 0.0, 0.0]])
    X[1] = X[0] + L * direction / np.linalg.norm(direction)
    model = Model.from_springs(X, np.array([[0, 1]]), k=cfg.k, mass=1.0)
    L = float(model.springs.L_np[0])
    state = model.make_state()
    f_nd = vec3_ndarray(2)

    def W(x):
        state.assign(x=x)
        return model.potential_energy(state.x)

    def force(x):
        state.assign(x=x)
        model.forces(state.x, f_nd)
        return f_nd.to_numpy().astype(np.float64)

    def closed_form(x):
        d = x[0] - x[1]
        l = np.linalg.norm(d)
        return -cfg.k * (l / L - 1.0) * d / l

    # a stretched (by 30%) and a compressed (by 20%) spring in random orientations
    configs = []
    for stretch in (1.3, 0.8):
        d = rng.standard_normal(3)
        x = np.empty((2, 3))
        x[1] = rng.standard_normal(3) * 0.1
        x[0] = x[1] + stretch * L * d / np.linalg.norm(d)
        configs.append(x)

    eps = 1e-6
    fd_err, dir_err, closed_err, par_err, third_err = 0.0, 0.0, 0.0, 0.0, 0.0
    for x in configs:
        f = force(x)
        fd = -central_gradient(W, x, eps)
        fd_err = max(fd_err, np.linalg.norm(fd - f) / np.linalg.norm(f))
        grad = -f
        for _ in range(5):
            q = rng.standard_normal((2, 3))
            dq = central_difference(W, x, q, eps)  # g'(0)
            dir_err = max(dir_err, abs(dq - np.sum(grad * q)) / (np.linalg.norm(grad) * np.linalg.norm(q)))
        cf = closed_form(x)
        closed_err = max(closed_err, np.linalg.norm(f[0] - cf) / np.linalg.norm(cf))
        d = x[0] - x[1]
        par_err = max(par_err, np.linalg.norm(np.cross(f[0], d)) / (np.linalg.norm(f[0]) * np.linalg.norm(d)))
        third_err = max(third_err, np.linalg.norm(f[0] + f[1]) / np.linalg.norm(f[0]))

    rest_force = float(np.abs(force(X)).max()) / cfg.k

    x = configs[0]
    R, t = random_rotation(rng, negate_all=True), rng.standard_normal(3)
    W0, f0 = W(x), force(x)
    xr = x @ R.T + t
    rigid_err = abs(W(xr) - W0) / W0
    rot_force_err = np.linalg.norm(force(xr) - f0 @ R.T) / np.linalg.norm(f0)
    W_formula = 0.5 * cfg.k * (np.linalg.norm(x[0] - x[1]) / L - 1.0) ** 2 * L

    rec = ctx.rec
    if rec.enabled:
        rec.run("one_spring")  # frame 0: at rest; 1: stretched; 2: compressed (force arrows in green)
        for frame, xs in enumerate([X] + configs):
            rec.set_time(frame, 0.0)
            draw_springs(rec, model, xs, scale=0.3)
            fs = force(xs)
            arrows = np.stack([xs, xs + 0.3 * L * fs / max(np.abs(fs).max(), 1e-300)], axis=1)
            rec.line_strips("force", arrows, colors=[[40, 180, 40]])

    return [
        Experiment("energy W equals 1/2 k (l/L - 1)^2 L", W_formula, W0, 1e-13, "rel", "J"),
        Experiment("force equals -dW/dx_i by central differences (rel. error, eps = 1e-6)", 0.0, fd_err, 1e-7, "abs"),
        Experiment("directional derivative g'(0) = grad W . q for random q (rel. error)", 0.0, dir_err, 1e-7, "abs"),
        Experiment("no force at the rest length (max |f| / k)", 0.0, rest_force, 1e-14, "abs"),
        Experiment("force is parallel to the spring: |f x d| / (|f||d|) = sin(angle)", 0.0, par_err, 1e-14, "abs"),
        Experiment("equal and opposite forces on the two ends: |f_i + f_j| / |f_i|", 0.0, third_err, 1e-15, "abs"),
        Experiment("energy unchanged by a rigid rotation + translation (rel. change)", 0.0, rigid_err, 1e-12, "abs"),
        Experiment("force turns with the rigid rotation: |f(Rx+t) - R f(x)| / |f|", 0.0, rot_force_err, 1e-12, "abs"),
        Experiment("engine force equals the closed form -k (l/L - 1)(x_i - x_j)/l (rel. error)",
                   0.0, closed_err, 1e-13, "abs"),
    ]


# ------------------------------------------------------------------------- stage 2

S2_TEXT = """
When every force is minus the gradient of W, Newton's law conserves the total energy K + W
exactly: the power the forces deliver, f . v, is precisely the rate at which W falls. Whether a
time-stepping method keeps that property is a separate question, and we test it on two small 3D
spring networks: a chain of springs pinned at one end and let go from the horizontal with a small
sideways push, so it swings down under gravity in 3D (and keeps stretching and ringing), and a
free frame made of the edges of twelve tetrahedra, set jiggling, drifting and spinning in empty
space.

Symplectic Euler and velocity Verlet do not conserve the energy exactly, but they do exactly
conserve a slightly perturbed energy; so the measured K + W wobbles around a constant value
forever and does not drift. We run 100,000 steps and compare the mean energy of the last tenth
with that of the first tenth (the chain's total energy is close to zero by our choice of height
origin, so its drift is measured against its peak kinetic energy). The wobble shrinks with the
time step like the method's order: halving dt halves it for symplectic Euler (first order) and
quarters it for Verlet (second order). We measure it over the same simulated time at dt and dt/2,
with dt a tenth of the stability limit; the ratio then differs from 2 or 4 only through
higher-order terms in dt, which we allow 5% for (they turn out to be well below 1%).
Forward Euler has no such perturbed invariant: on every oscillation it multiplies the mode's
energy by 1 + (w dt)^2 per step, and on the small-amplitude frame, where the motion is a sum of
independent modes, a modal analysis of the stiffness matrix predicts the energy growth, and the
step where the blow-up detector trips, exactly.

Springs push equal and opposite along the line between their nodes, so the free frame's linear
and angular momentum are conserved; both symplectic methods keep them to round-off.

100,000 steps driven from Python (several kernel launches per step) would take tens of seconds,
so these runs use the engine's fused kernel, which performs a whole chunk of steps in one launch
with the same spring formula; we first confirm that it reproduces the step-by-step integrators.

Every run of this stage is fixed: each claim is about the named integrator itself, so
--integrator does not change them (they are marked [fixed] in the stage's list of integrators).
Backward Euler's own behaviour, damping every mode by 1/(1 + (w dt)^2) in energy per step, is
measured in the rod-waves lesson.
"""


def swinging_chain(cfg):
    n = cfg.chain_nodes
    X = np.zeros((n, 3))
    X[:, 0] = np.linspace(0.0, 1.0, n)
    m = np.full(n, 1.0 / (n - 1))  # 1 kg chain, lumped from a uniform density
    m[[0, -1]] *= 0.5
    model = Model.from_springs(X, chain_edges(n), k=cfg.chain_k, mass=m, pinned=[0], gravity=(0.0, 0.0, -G))
    v = np.zeros((n, 3))
    v[:, 1] = 0.5 * X[:, 0]  # a sideways push: the chain swings in 3D
    return model, X.copy(), v


def tet_frame(cfg, jiggle=0.01, drift=0.1, spin=3.0, seed=3, rigid=True):
    mesh = meshes.tet_box(3, 2, 2, size=(0.2, 0.1, 0.1))
    X = np.asarray(mesh.vertices)
    model = Model.from_springs(X, mesh.edges, k=cfg.frame_k, mass=0.05)
    rng = np.random.default_rng(seed)
    x0 = X + jiggle * rng.standard_normal(X.shape)
    v0 = 20 * jiggle * rng.standard_normal(X.shape)
    if rigid:
        v0 += np.array([drift, 0.0, 0.0]) + np.cross([0.0, 0.0, spin], X - X.mean(axis=0))
    return model, x0, v0


def _amplitude(ctx, name, model, x0, v0, dt, T, method):
    """Max - min of the total energy over time T (a fixed run of ``method``)."""
    ctx.note_integrator(name, method, fixed=True)
    st = model.make_state(x0, v0)
    E0 = diagnostics.total_energy(model, st)
    K, W = run_fused(model, st, dt, int(round(T / dt)), method)
    E = np.concatenate([[E0], K + W])
    return float(E.max() - E.min())


def stage_conservation(ctx):
    cfg = ctx.cfg
    N = cfg.steps
    exps = []
    order = {"symplectic-euler": 1, "velocity-verlet": 2}

    # The fused kernel against the engine's step-by-step integrators (100 steps, frame with spin).
    model, x0, v0 = tet_frame(cfg)
    dt = cfg.dt_fraction * stable_dt_estimate(model)
    for method in ("symplectic-euler", "velocity-verlet", "forward-euler"):
        a, b = model.make_state(x0, v0), model.make_state(x0, v0)
        K, W = run_fused(model, a, dt, 100, method)
        get_integrator(method).step(model, b, dt, 100)
        ctx.note_integrator(f"fused_vs_stepwise_{method}", method, fixed=True)
        xa, xb = a.numpy().x, b.numpy().x
        E_ref = diagnostics.total_energy(model, b)
        dev = max(np.abs(xa - xb).max() / 0.2, abs(K[-1] + W[-1] - E_ref) / E_ref)
        exps.append(Experiment(f"fused kernel = engine's {method} step by step (100 steps, max rel. diff.)",
                               0.0, dev, 1e-12, "abs"))

    nets = {"chain": swinging_chain(cfg), "frame": tet_frame(cfg)}
    for net, (model, x0, v0) in nets.items():
        dt = cfg.dt_fraction * stable_dt_estimate(model)
        strain_scale = 0.05
        scale = None
        for method in ("symplectic-euler", "velocity-verlet"):
            st = model.make_state(x0, v0)
            E0 = diagnostics.total_energy(model, st)
            P0, J0 = diagnostics.linear_momentum(model, st), diagnostics.angular_momentum(model, st)
            # deviations, and their scales sum m|v| and sum m|x||v| (the frame drifts away from
            # the origin, so the largest |x| seen sets the round-off scale of J)
            dP, dJ, mv, mxv = [0.0], [0.0], [0.0], [0.0]

            def observe(step, s, P0=P0, J0=J0, dP=dP, dJ=dJ, mv=mv, mxv=mxv):
                x, v, _ = s.numpy()
                speed = np.linalg.norm(v, axis=1)
                mv[0] = max(mv[0], float(np.sum(model.mass * speed)))
                mxv[0] = max(mxv[0], float(np.sum(model.mass * np.linalg.norm(x, axis=1) * speed)))
                dP[0] = max(dP[0], float(np.abs(diagnostics.linear_momentum(model, s) - P0).max()))
                dJ[0] = max(dJ[0], float(np.abs(diagnostics.angular_momentum(model, s) - J0).max()))

            log = lambda rec, s: draw_springs(rec, model, s.x.to_numpy(), strain_scale)
            K, W = simulate_fused(ctx, f"{net}_{method}", model, st, dt, N, method, cfg.record_every,
                                  observe=observe if net == "frame" else None, log=log, fixed=True)
            E = K + W
            tenth = N // 10
            if scale is None:  # the energy the drift is measured against
                scale = float(K.max()) if net == "chain" else E0
            what = "peak kinetic energy" if net == "chain" else "initial energy"
            exps.append(Experiment(
                f"{net}, {method}: no drift over {N} steps (|mean E last tenth - first tenth| / {what})",
                0.01, abs(E[-tenth:].mean() - E[:tenth].mean()) / scale, 0, "<="))
            T = 1.0 if net == "chain" else 0.5
            a1 = _amplitude(ctx, f"{net}_{method}_wobble_dt", model, x0, v0, dt, T, method)
            a2 = _amplitude(ctx, f"{net}_{method}_wobble_dt/2", model, x0, v0, dt / 2, T, method)
            ctx.progress(f"{net} {method}: energy wobble over {T} s: {a1:.4g} J at dt, {a2:.4g} J at dt/2")
            exps.append(Experiment(f"{net}, {method}: energy wobble ratio at dt vs dt/2 = 2^order",
                                   2.0 ** order[method], a1 / a2, 0.05, "rel"))
            if net == "frame":
                exps.append(Experiment(f"frame, {method}: linear momentum conserved (max |P - P0| / max sum m|v|)",
                                       0.0, dP[0] / mv[0], 1e-12, "abs"))
                exps.append(Experiment(f"frame, {method}: angular momentum conserved (max |J - J0| / max sum m|x||v|)",
                                       0.0, dJ[0] / mxv[0], 1e-12, "abs"))
        # forward Euler on the chain: it gains a full swing's kinetic energy, detected at the step
        if net == "chain":
            st = model.make_state(x0, v0)
            E0 = diagnostics.total_energy(model, st)
            try:
                simulate_fused(ctx, "chain_forward-euler", model, st, dt, N, "forward-euler", cfg.record_every,
                               energy_bound=E0 + scale, fixed=True,
                               log=lambda rec, s: draw_springs(rec, model, s.x.to_numpy(), strain_scale))
                step = math.inf
            except BlowUpError as exc:
                step = exc.step
                ctx.progress(f"detected: {exc}")
            exps.append(Experiment(f"chain, forward Euler: energy grows by one peak kinetic energy within {N} steps "
                                   "(step detected)", N, step, 0, "<=", "steps"))

    # Forward Euler on a small-amplitude frame at rest (no drift or spin): modal prediction.
    model, x0, _ = tet_frame(cfg, jiggle=1e-5, rigid=False)
    dt = cfg.dt_fraction * stable_dt_estimate(model)
    H = model.dense_hessian(model.X_nd, psd=False)
    M = np.repeat(model.mass, 3)
    w2, Phi = sla.eigh(H, np.diag(M))  # Phi^T M Phi = I
    w2 = np.clip(w2, 0.0, None)  # rigid modes: w = 0
    q0 = Phi.T @ (M * (x0 - model.X).reshape(-1))
    E_modes = 0.5 * w2 * q0 ** 2
    st = model.make_state(x0)
    E0 = diagnostics.total_energy(model, st)
    # the window: as many steps (at most 2000) as keep the predicted growth below 30x, so the
    # amplitude stays small and the motion linear
    steps = np.arange(1, 2001)
    growth = (E_modes[None, :] * (1 + w2[None, :] * dt * dt) ** steps[:, None]).sum(axis=1) / E_modes.sum()
    n_fe = int(steps[max(np.searchsorted(growth, 30.0) - 1, 0)])
    K, W = run_fused(model, st, dt, n_fe, "forward-euler")
    ctx.note_integrator("frame_forward-euler_growth", "forward-euler", fixed=True)
    predicted = float(growth[n_fe - 1])
    exps.append(Experiment("frame, forward Euler: energy growth over n steps = sum_k E_k (1 + w_k^2 dt^2)^n / E0",
                           predicted, (K[-1] + W[-1]) / E0, 1e-3, "rel"))
    factor = min(10.0, 0.5 * predicted)  # 10 E0, crossed inside the window (unless dt is tiny)
    bound = factor * E0
    predicted_step = int(np.argmax(growth * E_modes.sum() > bound))  # 0-based index of the step
    ctx.progress(f"forward Euler window: {n_fe} steps, predicted growth {predicted:.4g}, bound {factor:.3g} E0")
    st = model.make_state(x0)
    try:
        ctx.note_integrator("frame_forward-euler_detect", "forward-euler", fixed=True)
        run_fused(model, st, dt, n_fe, "forward-euler", energy_bound=bound)
        detected = math.inf
    except BlowUpError as exc:
        detected = exc.step
    exps.append(Experiment(f"frame, forward Euler: blow-up (E > {factor:.3g} E0) detected at the step modal theory predicts",
                           predicted_step, detected, 1, "abs", "steps"))
    return exps


# ------------------------------------------------------------------------- stage 3

S3_TEXT = """
For a continuous rod the energy is an integral, W[x] = int 1/2 E(p) (x'(p) - 1)^2 dp, and the
force density is minus its variational derivative: perturb x by eps q(p), differentiate with
respect to eps, integrate by parts, and read off what multiplies q. The result is
f(p) = d/dp( E(p) (x'(p) - 1) ), the right-hand side of the rod's wave equation.

So there are two ways to build a discrete rod: discretise that PDE with finite differences, or
discretise the energy (sum the spring energies of the segments) and take its exact gradient.
They agree: on any grid, even a non-uniform one with E varying from segment to segment, the
gradient of the discrete energy at node i is exactly the centred difference of the tension
E (dx/dp - 1) across the node, times the node's share of the rod, (h_{i-1} + h_i)/2. And the
directional derivative of the discrete energy along a test vector q is -sum_i f_i q_i, the
discrete image of int f q dp.

Dividing the nodal force by that nodal length gives a force density, which we compare with the
exact d/dp(E(x' - 1)) for a smooth x(p) and E(p) while refining the grid. The centred difference
is really centred at the midpoint of the two segment midpoints, which sits (h_i - h_{i-1})/4 away
from the node. If the grid is a smooth stretching of a uniform one (here p = s + 0.2 sin(pi s)),
neighbouring segments differ by O(h^2) and the error is second order. On a grid whose
neighbouring segments differ by O(h) (nodes placed with random spacings), the offset is O(h)
and the force density is only first-order accurate: the energy discretisation is consistent but
the naive pointwise reading of force/length loses an order. Both are measured below.
"""


def _E_of_p(p):
    return 1.0 + 0.5 * np.sin(2 * np.pi * p)


def _dE_of_p(p):
    return np.pi * np.cos(2 * np.pi * p)


def _u(p):
    return 0.01 * np.sin(3 * np.pi * p) + 0.005 * np.cos(2 * np.pi * p + 0.3)


def _du(p):
    return 0.03 * np.pi * np.cos(3 * np.pi * p) - 0.01 * np.pi * np.sin(2 * np.pi * p + 0.3)


def _d2u(p):
    return -0.09 * np.pi ** 2 * np.sin(3 * np.pi * p) - 0.02 * np.pi ** 2 * np.cos(2 * np.pi * p + 0.3)


def _force_density_exact(p):
    # d/dp (E(p) (x'(p) - 1)) with x = p + u: E' u' + E u''
    return _dE_of_p(p) * _du(p) + _E_of_p(p) * _d2u(p)


def _grid(kind: str, n: int) -> np.ndarray:
    s = np.linspace(0.0, 1.0, n)
    if kind == "uniform":
        return s
    if kind == "graded":
        return s + 0.2 * np.sin(np.pi * s)  # smooth, monotone (p'(s) >= 1 - 0.2 pi > 0)
    rng = np.random.default_rng(1000 + n)  # random spacings in [0.5, 1.5] h
    h = rng.uniform(0.5, 1.5, n - 1)
    p = np.concatenate([[0.0], np.cumsum(h)])
    return p / p[-1]


def _rod_on(p):
    mid = 0.5 * (p[1:] + p[:-1])
    return Rod(p, _E_of_p(mid), 1.0)


def stage_variational(ctx):
    rec = ctx.rec
    exps = []
    # (a) gradient = nodal length x PDE stencil, on the graded and the random grid
    for kind in ("graded", "random"):
        p = _grid(kind, 401)
        rod = _rod_on(p)
        h = rod.h
        x = p + _u(p)
        f = rod.forces(x)
        F = rod.E * (np.diff(x) / h - 1.0)  # tension E (dx/dp - 1) per segment
        stencil = (F[1:] - F[:-1]) / (0.5 * (h[1:] + h[:-1]))
        ell = 0.5 * (h[1:] + h[:-1])
        diff = np.max(np.abs(f[1:-1] - ell * stencil)) / np.max(np.abs(f[1:-1]))
        exps.append(Experiment(f"{kind} grid: -grad W = nodal length x FD stencil of d/dp(E(x'-1)) "
                               "(max rel. diff.)", 0.0, diff, 1e-13, "abs"))
    # (b) directional derivative of the discrete energy along a smooth test function
    p = _grid("graded", 401)
    rod = _rod_on(p)
    x = p + _u(p)
    q = np.sin(2 * np.pi * p) * p
    eps = 1e-6
    dq = central_difference(rod.energy, x, q, eps)
    fq = -float(np.dot(rod.forces(x), q))
    exps.append(Experiment("discrete D_q W (central differences in eps) = -sum_i f_i q_i", fq, dq, 1e-7, "rel", "J"))

    # (c) convergence of the force density to the variational derivative
    sizes = np.array([101, 201, 401, 801, 1601])
    for kind, theory, tol in (("uniform", 2.0, 0.1), ("graded", 2.0, 0.1), ("random", 1.0, 0.15)):
        err_rms, err_max = [], []
        for n in sizes:
            p = _grid(kind, n)
            rod = _rod_on(p)
            h = rod.h
            ell = np.zeros(n)
            ell[:-1] += 0.5 * h
            ell[1:] += 0.5 * h
            dens = rod.forces(p + _u(p)) / ell
            e = (dens - _force_density_exact(p))[1:-1]  # interior nodes (the ends carry boundary terms)
            err_rms.append(math.sqrt(np.sum(ell[1:-1] * e * e)))
            err_max.append(np.max(np.abs(e)))
            if rec.enabled and n == sizes[-1]:
                rec.run(f"force_density_{kind}")
                rec.set_time(0, 0.0)
                scale = 0.5 / np.max(np.abs(_force_density_exact(p)))
                rec.line_strips("discrete", [np.stack([p, scale * dens, np.zeros(n)], axis=1)[1:-1]],
                                colors=[[230, 160, 30]])
                rec.line_strips("exact", [np.stack([p, scale * _force_density_exact(p), np.zeros(n)], axis=1)],
                                colors=[[60, 120, 230]])
        h = 1.0 / (sizes - 1)
        o_rms = convergence_order(h, np.array(err_rms))
        ctx.progress(f"{kind}: rms errors {np.array(err_rms)}, order {o_rms:.3f}")
        exps.append(Experiment(f"{kind} grid: force density -> d/dp(E(x'-1)), order of the rms error",
                               theory, o_rms, tol, "abs"))
        if kind == "graded":
            exps.append(Experiment("graded grid: order of the max error", theory,
                                   convergence_order(h, np.array(err_max)), tol, "abs"))
    return exps


# ------------------------------------------------------------------------- stage 4

S4_TEXT = """
Sound in a chain of masses and springs travels at c = sqrt(k L / m), with m/L the chain's
linear density. With the notes' spring energy W = 1/2 k (l/L - 1)^2 L, the tension is k times
the strain, so k is a modulus (a force per unit strain, the 1D Young's modulus E) and does not
depend on how long the spring is. If the node masses come from a fixed linear density rho
(each node gets half of each neighbouring segment), then m = rho L and c = sqrt(k/rho): choosing
k per segment from k_j L_j / m_j = c^2 gives k_j = rho c^2 for every segment length, i.e. E = rho c^2.
In the Hooke form of the same spring, force = kappa (l - L), the constant is kappa_j = k_j / L_j,
and the rule reads kappa_j L_j = rho c^2: shorter springs must be stiffer.

We build chains of many nodes along x with three segment patterns (all segments equal; lengths
alternating h, 2h; lengths growing smoothly from h to 2h), set k_j = rho c^2, release a small
longitudinal bump and follow the peak of its right-moving half: all three travel at c.

Then we do what a naive mass-spring model does: give every spring the same Hooke constant kappa.
Springs in series add their compliances, so over a repeating pattern of N segments of total
length P the effective modulus is kappa P / N = kappa L_mean, and the sound speed becomes
sqrt(kappa L_mean / rho), i.e. sqrt(k L / m) with the effective k = kappa L_mean and the mean
segment length and node mass. The same kappa therefore gives different speeds on different
patterns: the material's behaviour would depend on how it was meshed.

These are scene runs: they follow --integrator (symplectic Euler by default; velocity Verlet has
the same dispersion, so the same speeds are expected). Backward Euler damps each mode and turns
it by atan(w dt) instead of w dt per step, so the pulse flattens and is slightly slowed; its
speeds are therefore compared with the scheme's own prediction. Moving along its axis, the chain
is exactly a linear 1D rod with E_j = k_j and the same node masses, so the prediction is cheap:
split the initial bump into that rod's normal modes, advance each with backward Euler's 2x2 step
matrix (numpy), sum, and fit the peak the same way. At this dt the predicted slowdown is below
0.1% (printed next to the undamped value), the three patterns still agree, and one Hooke
constant still gives pattern-dependent speeds. Backward Euler runs step by step through the
engine's implicit integrator, so --solver, --tol and --newton-iterations apply; per step it is
tens of times slower here than the fused explicit kernel. Forward Euler's runs are stopped, and
reported, at the step where the energy passes ten times its start.
"""


def _chain_lengths(kind: str, h: float) -> np.ndarray:
    if kind == "uniform":
        n = int(round(1.0 / h))
        return np.full(n, 1.0 / n)
    if kind == "alternating":
        L = np.tile([h, 2 * h], int(round(1.0 / (3 * h))))
        return L / L.sum()
    # graded: L(p) = h (1 + p), from h at p = 0 to 2h at p = 1
    p = [0.0]
    while p[-1] < 1.0:
        p.append(p[-1] + h * (1.0 + p[-1]))
    p = np.asarray(p) / p[-1]
    return np.diff(p)


def _chain_model(Ls: np.ndarray, k: np.ndarray, rho: float):
    p = np.concatenate([[0.0], np.cumsum(Ls)])
    n = p.size
    X = np.zeros((n, 3))
    X[:, 0] = p
    m = np.zeros(n)
    m[:-1] += 0.5 * rho * Ls
    m[1:] += 0.5 * rho * Ls
    return Model.from_springs(X, chain_edges(n), k=k, mass=m), p


UNDAMPED = ("symplectic-euler", "velocity-verlet")


def _pulse_speed(ctx, name, model, p, c_scale, sigma, k, rho, p0=0.25):
    """Release a Gaussian bump at p0 from rest; fit the speed of the right-moving half's peak
    once it has separated from the left half. ``c_scale`` only sets the run time.

    A scene run: ``--integrator`` chooses the method (symplectic Euler by default; the explicit
    ones run in the fused kernel, backward Euler through :func:`lessons._scene.simulate`). Returns
    (measured speed, predicted speed): the prediction is None for the undamped symplectic methods,
    else the same fit on the scheme's own solution. Moving along its axis the chain is exactly a
    linear 1D rod with E_j = k_j and the same lumped masses, so that solution is
    :class:`engine.rod.ModalReference` (each normal mode advanced with the scheme's 2x2 step matrix).
    """
    method = ctx.integrator_name("symplectic-euler")
    A = 1e-4
    u0 = A * np.exp(-0.5 * ((p - p0) / sigma) ** 2)
    x0 = model.X.copy()
    x0[:, 0] += u0
    st = model.make_state(x0)
    bound = 10 * diagnostics.total_energy(model, st)  # forward Euler is stopped (and reported) there
    dt = 0.5 * stable_dt_estimate(model)
    n_steps = int(0.45 / c_scale / dt)
    every = max(n_steps // 100, 1)

    region = [(p0, 1.0, 1)]  # the right-moving half
    (track,), observe = track_peaks(p, region)
    calls = [0]

    def log(rec, s):  # every 5th observation: 20 frames per run keep the recording small
        calls[0] += 1
        if (calls[0] - 1) % 5:
            return
        x = s.x.to_numpy()[:, 0]
        rec.rod(x, p, rod_node_strain(x, p), gain=0.1 / A)

    on_state = lambda step, s: observe(step, step * dt, s.x.to_numpy()[:, 0] - p)
    if method in FUSED_METHODS:
        simulate_fused(ctx, name, model, st, dt, n_steps, method, every, energy_bound=bound, observe=on_state,
                       log=log)
    else:  # backward Euler (with --solver/--tol/--newton-iterations) via the engine's integrator
        scene_simulate(ctx, name, model, st, dt, n_steps, "symplectic-euler", every=every, energy_bound=bound,
                       observe=on_state, log=log)

    def fit(track):  # the peak's speed once the halves have separated
        return fit_slope(*np.array([(t, x) for t, x, _ in track if t * c_scale > 6 * sigma]).T)

    if method in UNDAMPED:
        return fit(track), None
    steps = observation_steps(n_steps, every)  # the observation steps of both runners
    (ref_track,), _ = modal_tracks(Rod(p, k, rho), u0, None, dt, method, steps, region)
    return fit(track), fit(ref_track)


def stage_sound(ctx):
    cfg = ctx.cfg
    rho = cfg.rho
    c = math.sqrt(cfg.E / rho)
    h = 1.0 / cfg.wave_segments
    sigma = 30 * h  # ten periods of the alternating pattern
    method = ctx.integrator_name("symplectic-euler")
    exps = []
    speeds, predicted_speeds = [], []
    for kind in ("uniform", "alternating", "graded"):
        Ls = _chain_lengths(kind, h)
        k = np.full(Ls.size, rho * c * c)  # k_j = rho c^2, i.e. kappa_j = rho c^2 / L_j
        model, p = _chain_model(Ls, k, rho)
        v, v_pred = _pulse_speed(ctx, f"matched_{kind}", model, p, c, sigma, k, rho)
        speeds.append(v)
        predicted_speeds.append(v_pred)
        exps.append(expect(ctx, method, f"k_j = rho c^2 ({kind} lengths, {Ls.size} segments): pulse speed = c",
                           c, v, v_pred, 1e-2, unit="m/s"))
    spread = lambda v: (max(v) - min(v)) / c
    exps.append(expect(ctx, method, "k_j = rho c^2: spread of the three speeds (max - min) / c", 0.0,
                       spread(speeds), None if v_pred is None else spread(predicted_speeds), 1e-2, "abs"))
    kappa = rho * c * c / h  # one Hooke constant, chosen to give c on the uniform chain of spacing h
    const = []
    for kind in ("uniform", "alternating"):
        Ls = _chain_lengths(kind, h)
        model, p = _chain_model(Ls, kappa * Ls, rho)  # notes' k = kappa L
        predicted = math.sqrt(kappa * Ls.mean() / rho)  # sqrt(k_eff L_mean / m_mean), k_eff = kappa L_mean
        v, v_pred = _pulse_speed(ctx, f"constant_kappa_{kind}", model, p, predicted, sigma, kappa * Ls, rho)
        const.append(v)
        exps.append(expect(ctx, method, f"one Hooke constant kappa ({kind} lengths): speed = sqrt(kappa L_mean / "
                           "rho)", predicted, v, v_pred, 1e-2, unit="m/s"))
    exps.append(Experiment("one Hooke constant: the two patterns' speeds differ by more than 1% (rel. diff.)",
                           0.01, abs(const[1] - const[0]) / const[0], 0, ">="))
    return exps


# ------------------------------------------------------------------------- stage 5

S5_TEXT = """
A rod of length L hangs from its top under its own weight. Measuring p downwards from the pin,
the rod below p weighs rho g (L - p), and that weight is carried by the tension E u'(p), so the
downward displacement is u(p) = (rho g / E)(L p - p^2/2). Built from the notes' springs with
k = E and lumped masses, the discrete rod reproduces this at the nodes exactly, on any grid: the
tension in a segment carries the mass of everything below the segment's midpoint, and the
midpoint rule integrates the linear strain exactly.

We ask the engine for the static equilibrium, the state where every free node's force (springs
plus gravity) vanishes: its static solver minimises the total potential energy (springs plus
gravity) by Newton's method, here until the net force on every node is below 1e-10 of a node's
weight. On a uniform and on a graded grid the result matches the formula to within what that
residual allows, and the pin's reaction carries the rod's whole weight.

Nothing moves in time here, so --integrator does not apply to this stage.
"""


def _hanging_rod(cfg, kind):
    n = cfg.hang_nodes
    s = np.linspace(0.0, 1.0, n)
    p = s if kind == "uniform" else s + 0.2 * np.sin(np.pi * s)
    X = np.zeros((n, 3))
    X[:, 2] = -p
    Ls = np.diff(p)
    m = np.zeros(n)
    m[:-1] += 0.5 * cfg.rho * Ls
    m[1:] += 0.5 * cfg.rho * Ls
    model = Model.from_springs(X, chain_edges(n), k=cfg.E, mass=m, pinned=[0], gravity=(0.0, 0.0, -G))
    return model, p


def stage_hanging(ctx):
    cfg = ctx.cfg
    exps = []
    rec = ctx.rec
    tol = 1e-10
    for kind in ("uniform", "graded"):
        model, p = _hanging_rod(cfg, kind)
        t0 = time.perf_counter()
        res = solve_static(model, tol=tol, raise_on_failure=False)
        ctx.progress(f"{kind}: Newton {res.iterations} iterations, residual {res.residual:.3g} "
                     f"({time.perf_counter() - t0:.2f} s)")
        x = np.asarray(res.x)
        u = -(x[:, 2] - model.X[:, 2])
        u_exact = cfg.rho * G / cfg.E * (p - 0.5 * p * p)
        err = float(np.max(np.abs(u - u_exact)) / np.max(np.abs(u_exact)))
        weight = cfg.rho * G * 1.0
        exps += [
            Experiment(f"{kind} grid: static solver converged (net-force residual <= tol)", tol, res.residual, 0,
                       "<="),
            # a residual r leaves each tension wrong by at most (n - 1) r max(m g), hence u by at most
            # (n - 1) r max(m) g L / E = 2 (n - 1) max(m) / (rho L) r u_max
            Experiment(f"{kind} grid: nodal displacement = (rho g/E)(L p - p^2/2) (max rel. error)",
                       0.0, err, 2 * (cfg.hang_nodes - 1) * model.mass.max() / cfg.rho * tol, "abs"),
            # R - weight = sum of the free nodes' residual forces: at most (n - 1) r max(m g)
            Experiment(f"{kind} grid: pin reaction carries the whole weight rho g L", weight,
                       float(res.reactions[0, 2]), (cfg.hang_nodes - 1) * tol, "rel", "N"),
        ]
        if rec.enabled:
            rec.run(f"hanging_{kind}")
            rec.set_time(0, 0.0)
            draw_springs(rec, model, model.X, cfg.rho * G / cfg.E)
            rec.set_time(1, 0.0)
            draw_springs(rec, model, x, cfg.rho * G / cfg.E)
    return exps


LESSON = Lesson(
    id="springs",
    title="Springs: forces from energy, the variational derivative, energy conservation",
    summary="The notes' spring energy and its gradient, energy and momentum conservation under "
            "symplectic time stepping, discretising the energy instead of the PDE, choosing spring "
            "stiffness from the speed of sound, and a rod hanging under its own weight.",
    config=SpringsConfig,
    stages=[
        Stage("one spring: force = -dW/dx", S1_TEXT, stage_one_spring),
        Stage("energy conservation", S2_TEXT, stage_conservation),
        Stage("discretise the energy, not the PDE", S3_TEXT, stage_variational),
        Stage("stiffness from the speed of sound", S4_TEXT, stage_sound),
        Stage("a hanging rod", S5_TEXT, stage_hanging),
    ],
    order=2,
)
