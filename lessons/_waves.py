"""The standing-wave run that the sheet and box lessons measure speeds with (area-springs,
membranes): a wave u = A cos(k (X - origin).n) p started from rest, run for RUN_PERIODS of a period
with velocity Verlet (or the integrator of ``--integrator``; under backward Euler the step is
chosen from the phase), its amplitude read over a region by engine.waves.ModeProbe, and how such a
run is drawn (the displacement component the wave carries, on a fixed scale)."""
from __future__ import annotations

import contextlib
import dataclasses
import math

import numpy as np

from engine import mesh as M
from engine.model import Model
from engine.stability import stable_dt_estimate
from engine.theory.schemes import backward_euler_damping_rate as be_damping_rate
from engine.waves import ModeProbe, phase_frequency
from lessons.views import RunView

from ._measure import damped_frequency
from ._scene import simulate

RUN_PERIODS = 0.3   # each standing-wave run lasts this fraction of a period (phase 0 -> 1.9 rad)
BE_PHASE_STEP = 0.05  # w dt of the backward-Euler runs: phase lag 1 - arctan(w dt)/(w dt) = 8.3e-4
DRAWN_AMPLITUDE = 1 / 24  # a drawn wave's displacement amplitude, in wavelengths (the true one: strain/(2 pi))


def unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def square_domain_cells(half: float, spacing: float) -> int:
    return 2 * int(math.ceil(half / spacing))


def wave_grid(n: int, pattern: str, r: float) -> tuple:
    """The square sheet a standing wave runs on: a right-triangle grid of ``pattern`` with n x n
    vertices 1 m apart, and the disc of radius ``r`` about its centre the amplitude is read in:
    (2D mesh, its 3D embedding, the centre, the vertices in the disc)."""
    m2 = M.right_triangle_grid(n, n, n - 1.0, n - 1.0, pattern)
    ctr = np.full(2, 0.5 * (n - 1))
    return m2, M.embed_3d(m2), ctr, np.linalg.norm(m2.vertices - ctr, axis=1) <= r


def wave_steps(ctx, model: Model, k: float, c_guess: float) -> tuple[bool, float, int]:
    """(implicit, dt, n_steps) of a standing-wave run (see :func:`standing_wave`)."""
    implicit = ctx.integrator_name("velocity-verlet") == "backward-euler"
    dt = BE_PHASE_STEP / (k * c_guess) if implicit else ctx.cfg.cfl * stable_dt_estimate(model)
    n_steps = max(8, int(math.ceil(RUN_PERIODS * 2 * math.pi / (k * c_guess) / dt)))
    return implicit, dt, n_steps


def wave_time(ctx, model: Model, k: float, c_guess: float) -> float:
    """The simulated time a standing-wave run covers (a span for the views of a stage's runs)."""
    _, dt, n_steps = wave_steps(ctx, model, k, c_guess)
    return n_steps * dt


def standing_wave(ctx, name: str, model: Model, mass: np.ndarray, direction, polarization, k: float,
                  origin, region: np.ndarray, c_guess: float, draw=None, fits: list | None = None,
                  view: RunView | None = None) -> float:
    """Start u = A cos(k (X - origin).n) p from rest, run RUN_PERIODS of a period (sized with
    ``c_guess``; the measurement does not use it) with velocity Verlet (or the integrator of
    ``--integrator``), and return the measured phase speed w/k from the amplitude over ``region``
    (engine.waves).

    When recording, ``draw(rec, x, gain, axis, quantity, scale)`` (a drawer of this module) draws
    the state with displacements magnified by ``gain`` (the amplitude drawn as DRAWN_AMPLITUDE of a
    wavelength), coloured by the displacement component the wave carries (see
    :func:`displacement_component`) on the fixed scale A, in the view ``view`` (without an energy
    plot; the component's direction is added to its label when it is neither an axis nor the
    direction of travel). A run without ``draw`` only measures.

    Under backward Euler (stable at any step) the step is BE_PHASE_STEP/(k c_guess), whatever the
    CFL limit, so that the scheme's phase lag 1 - arctan(w dt)/(w dt) is the same 8e-4 in every
    run, and the amplitude, which the scheme damps, is fitted as a(0) exp(-gamma t) cos(w t); the
    fit (dt, w, gamma) is appended to ``fits``."""
    cfg = ctx.cfg
    X = model.X
    probe = ModeProbe(X, mass, direction, polarization, k, origin, region)
    A = cfg.strain / k  # peak strain k A
    state = model.make_state(X + probe.displacement(A))
    implicit, dt, n_steps = wave_steps(ctx, model, k, c_guess)
    times, amps = [], []

    def observe(step, st):
        times.append(step * dt)
        amps.append(probe.amplitude(st.x.to_numpy()))

    log = None
    if draw is not None and ctx.rec.enabled:
        axis, quantity = displacement_component(direction, polarization)
        gain = DRAWN_AMPLITUDE * (2 * math.pi / k) / A
        view = dataclasses.replace(view or RunView(), energy=None)
        if quantity.startswith("u_t"):
            view.label = f"{view.label or name}, t = ({', '.join(f'{a:.2f}' for a in axis[:len(polarization)])})"
        log = lambda rec, st: draw(rec, st.x.to_numpy().astype(np.float64), gain, axis, quantity, A)
    W0 = model.potential_energy(state.x)
    with _pcg_for_3d_boxes(ctx, name, model, implicit):
        simulate(ctx, name, model, state, dt, n_steps, integrator="velocity-verlet", every=1,
                 energy_bound=10 * W0, observe=observe, log=log, energy_every=4, view=view if log else None)
    if not implicit:
        return phase_frequency(np.asarray(times), np.asarray(amps)) / k
    w, gamma = damped_frequency(np.asarray(times), np.asarray(amps))
    if fits is not None:
        fits.append(dict(name=name, dt=dt, w=w, gamma=gamma))
    ctx.progress(f"{name}: backward Euler, dt = {dt:.4g} s (w dt = {w * dt:.4f}), fitted damping "
                 f"{gamma:.4g} 1/s, the scheme's {be_damping_rate(w, dt):.4g} 1/s")
    return w / k


@contextlib.contextmanager
def _pcg_for_3d_boxes(ctx, name: str, model: Model, implicit: bool):
    """Under backward Euler with --solver cholesky, a run on a 3D box uses pcg instead: a direct
    LL^T of a 3D lattice fills in far more than a sheet's (Eigen's simplicial factorisation, one
    per step, takes ~1 s for the smallest box here, 3249 vertices, and ~40 s at 10^4; the boxes
    go up to 107217 vertices). Sheets keep cholesky."""
    stepping = ctx.stepping
    if implicit and stepping.solver == "cholesky" and np.ptp(model.X[:, 2]) > 0:
        ctx.progress(f"{name}: --solver cholesky is impractical for this 3D box ({model.n} vertices; a direct "
                     f"LL^T of a 3D lattice fills in: ~1 s per step at 3249 vertices, ~40 s at 10^4): this run "
                     f"uses pcg")
        ctx.stepping = dataclasses.replace(stepping, solver="pcg")
    try:
        yield
    finally:
        ctx.stepping = stepping


# ------------------------------------------------------------------ drawing

def displacement_component(direction, polarization) -> tuple[np.ndarray, str]:
    """(unit 3-vector a, name) of the displacement component that shows a wave travelling along
    ``direction`` n with ``polarization`` p: the axis p lies along if it is within 2 degrees of one;
    else, for a (quasi-)P wave (p within 45 degrees of n), the component along n; else (a
    (quasi-)S wave) the component of p across n. Named "u_x", "u_y", "u_z" when a is an axis, else
    "u_n" (along n) or "u_t" (across n, along the polarization's transverse part)."""
    def unit3(v):
        w = np.zeros(3)
        w[:len(v)] = np.asarray(v, dtype=np.float64)
        return w / np.linalg.norm(w)
    p, n = unit3(polarization), unit3(direction)
    i = int(np.argmax(np.abs(p)))
    if abs(p[i]) > math.cos(math.radians(2.0)):
        a, name = np.eye(3)[i], None
    elif abs(p @ n) >= math.cos(math.radians(45.0)):
        a, name = n, "u_n"
    else:
        a, name = unit3(p - (p @ n) * n), "u_t"
    j = int(np.argmax(np.abs(a)))
    if abs(a[j]) > 1 - 1e-12:
        a, name = np.eye(3)[j], f"u_{'xyz'[j]}"
    return a, f"{name} (m)"


def sheet_drawer(mesh3: M.Mesh):
    """draw(rec, x, gain, axis, quantity, scale): the sheet's triangles at X + gain (x - X), each
    vertex coloured by its displacement along ``axis`` on the run's fixed ``scale``."""
    X, T = mesh3.vertices, mesh3.triangles

    def draw(rec, x, gain, axis, quantity, scale):
        u = x - X
        rec.mesh(X + gain * u, T, vertex_colors=rec.colors(u @ axis, "signed", quantity, scale))
    return draw


def solid_drawer(mesh: M.Mesh):
    """draw(rec, x, gain, axis, quantity, scale): a tet box by its surface triangles, drawn and
    coloured as :func:`sheet_drawer` draws a sheet."""
    faces = M.boundary_faces(mesh)
    verts, inv = np.unique(faces, return_inverse=True)
    faces_local = inv.reshape(-1, 3)
    Xs = mesh.vertices[verts]

    def draw(rec, x, gain, axis, quantity, scale):
        u = x[verts] - Xs
        rec.mesh(Xs + gain * u, faces_local, vertex_colors=rec.colors(u @ axis, "signed", quantity, scale))
    return draw
