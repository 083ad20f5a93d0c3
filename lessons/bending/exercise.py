"""The bending lesson's exercise: the signed dihedral angle of a hinge (A1) and its gradient
(G1)-(G3).

The student's functions take the engine's place in every bending kernel (energies, forces, the
fused cloth step, the rest angles), and are checked on their own first: the angle against the
lesson's formula on random hinges, the gradient against finite differences of the angle.
"""
import numpy as np
import taichi as ti

from engine.energies import hinge as Hg
from engine.fields import scalar_array, vec3_array
from .._exercise import TI_FUNC, Sampler, Task, agreement, central_difference, deviation, factor_text, \
    first_bad, matches, ratio, substitute


def _angle_call(func):
    @ti.kernel
    def run(e: vec3_array, a0: vec3_array, a1: vec3_array, out: scalar_array):
        for i in range(e.shape[0]):
            out[i] = func(e[i], a0[i], a1[i])

    def call(e, a0, a1):
        out = np.zeros(len(e))
        run(np.ascontiguousarray(e), np.ascontiguousarray(a0), np.ascontiguousarray(a1), out)
        return out
    return call


def _gradient_call(func):
    @ti.kernel
    def run(e: vec3_array, a0: vec3_array, a1: vec3_array, g0: vec3_array, g1: vec3_array, g2: vec3_array,
            g3: vec3_array):
        for i in range(e.shape[0]):
            g0[i], g1[i], g2[i], g3[i] = func(e[i], a0[i], a1[i])

    def call(e, a0, a1):
        g = [np.zeros_like(e) for _ in range(4)]
        run(np.ascontiguousarray(e), np.ascontiguousarray(a0), np.ascontiguousarray(a1), *g)
        return np.stack(g, axis=1)   # (n, 4 vertices, 3)
    return call


def _hinges(n: int = 48, seed: int = 9, fold: float = 3.0):
    """Random hinges: vertex positions (n, 4, 3) for the slots (v0, v1, w0, w1). Edges from 1 cm to
    100 m long, wings 0.1 to 3 edge lengths high whose feet lie anywhere from one edge length before
    v0 to one after v1 (outside the edge too), folded by angles in (-fold, fold), the first four
    flat; each hinge moved by its own rotation and translation."""
    s = Sampler(seed)
    E = s.log_uniform(n, 1e-2, 1e2)
    P = np.zeros((n, 4, 3))
    P[:, 1, 0] = 1.0
    phi = s.uniform(n, -fold, fold)
    phi[:4] = 0.0
    t0, t1 = s.uniform(n, -1.0, 2.0), s.uniform(n, -1.0, 2.0)
    r0, r1 = s.log_uniform(n, 0.1, 3.0), s.log_uniform(n, 0.1, 3.0)
    P[:, 2] = np.column_stack([t0, r0, np.zeros(n)])
    P[:, 3] = np.column_stack([t1, -r1 * np.cos(phi), r1 * np.sin(phi)])
    P = np.einsum("nkj,nij->nki", P * E[:, None, None], s.rotations(n)) + s.vectors(n, 10.0)[:, None, :]
    return P


def _frames(P):
    return P[:, 1] - P[:, 0], P[:, 2] - P[:, 0], P[:, 3] - P[:, 0]


def _angle_np(e, a0, a1, unit_e=True):
    """theta (A1) in numpy (``unit_e`` False: the sine not divided by |e|, a mistake named)."""
    N0, N1 = np.cross(e, a0), np.cross(a1, e)
    axis = e / np.linalg.norm(e, axis=1)[:, None] if unit_e else e
    return np.arctan2(np.einsum("ij,ij->i", axis, np.cross(N0, N1)), np.einsum("ij,ij->i", N0, N1))


def _gradient_np(e, a0, a1, foot=lambda t, s: t, edge_factor=True, swap_weights=False, w1_sign=1.0):
    """(G1)-(G3) in numpy, (n, 4, 3); ``foot`` maps the feet's positions t along the edge and
    ``edge_factor`` False drops |e| from the wings' gradient, ``swap_weights`` gives v1 the weight
    1 - t, ``w1_sign`` -1 flips w1's gradient (the mistakes named)."""
    s = np.linalg.norm(e, axis=1)[:, None]
    N0, N1 = np.cross(e, a0), np.cross(a1, e)
    k = s if edge_factor else 1.0
    g_w0 = -k * N0 / np.einsum("ij,ij->i", N0, N0)[:, None]
    g_w1 = -w1_sign * k * N1 / np.einsum("ij,ij->i", N1, N1)[:, None]
    t0 = foot(np.einsum("ij,ij->i", a0, e)[:, None] / s ** 2, s)
    t1 = foot(np.einsum("ij,ij->i", a1, e)[:, None] / s ** 2, s)
    if swap_weights:
        t0, t1 = 1.0 - t0, 1.0 - t1
    g_v1 = -t0 * g_w0 - t1 * g_w1
    g_v0 = -(1.0 - t0) * g_w0 - (1.0 - t1) * g_w1
    return np.stack([g_v0, g_v1, g_w0, g_w1], axis=1)


def check_angle(student) -> list:
    P = _hinges(fold=3.13)
    got = student.via(_angle_call)(*_frames(P))
    ref = _angle_call(Hg.dihedral_angle)(*_frames(P))
    dev = deviation(got, ref, scale=np.pi)
    tol = 1e-12
    reason = ""
    if not dev <= tol:
        i = first_bad(got, ref, tol, scale=np.pi)
        finite = np.isfinite(got)
        flat_only = not np.all(finite) and np.all(finite[4:])
        if flat_only and np.allclose(got[4:], np.abs(ref[4:]), rtol=0, atol=1e-9):
            reason = ("dihedral_angle returns NaN on a flat hinge (acos of a cosine rounded above 1) and loses the "
                      "sign elsewhere: use atan2 of the signed sine and the cosine")
        elif not np.all(finite):
            reason = f"dihedral_angle returns NaN or inf at hinge {i}" + (" (a flat hinge: theta = 0 there)"
                                                                          if flat_only else "")
        elif deviation(got, -ref, scale=np.pi) <= 1e-9:
            reason = ("dihedral_angle has the wrong sign: theta is positive when the hinge folds one way "
                      "(about e, from N0 to N1) and negative the other")
        elif deviation(got, np.abs(ref), scale=np.pi) <= 1e-9:
            reason = "dihedral_angle loses the sign: it returns |theta|; use atan2 of the signed sine and the cosine"
        elif matches(got, np.arcsin(np.clip(np.sin(ref), -1, 1)), scale=np.pi, tol=1e-9):
            reason = ("dihedral_angle uses asin: it cannot tell theta from pi - theta beyond pi/2; use atan2 of the "
                      "sine and the cosine")
        elif matches(got, _angle_np(*_frames(P), unit_e=False), scale=np.pi):
            reason = ("dihedral_angle's sine is not divided by |e|: e . (N0 x N1) grows with the edge's length, so "
                      "the angle changes when the hinge is scaled; use e/|e|")
        elif np.abs(got[:4]).max() > 1e-9:
            reason = f"dihedral_angle is not zero on a flat hinge: {got[int(np.argmax(np.abs(got[:4])))]:.3g} rad"
        else:
            r = factor_text(ratio(got, ref))
            reason = (f"dihedral_angle is {r} the signed angle" if r else
                      f"dihedral_angle gives {got[i]:.6g} rad at hinge {i} instead of {ref[i]:.6g} rad "
                      f"(|e| = {np.linalg.norm(P[i, 1] - P[i, 0]):.3g} m)")
    return [agreement(f"dihedral_angle = the signed angle (A1) on {len(P)} random hinges, |e| from 1 cm to 100 m, "
                      f"feet outside the edge too, folds up to 3.13 rad (max deviation / pi)", "ex-dihedral-angle",
                      dev, tol, reason, "rad")]


def check_gradient(student) -> list:
    P = _hinges(seed=10)
    got = student.via(_gradient_call)(*_frames(P))
    angle = _angle_call(Hg.dihedral_angle)
    size = np.linalg.norm(P[:, 1] - P[:, 0], axis=1)
    ref = central_difference(lambda flat: angle(*_frames(flat.reshape(-1, 4, 3) * np.repeat(size, 12)[:, None, None])),
                             (P / size[:, None, None]).reshape(len(P), 12), 1e-6)   # steps of 1e-6 |e|
    ref = ref.reshape(len(P), 4, 3) / size[:, None, None]
    scale = np.abs(ref).reshape(len(P), -1).max(axis=1)
    dev = deviation(got, ref, scale)
    tol = 1e-6
    reason = ""
    if not dev <= tol:
        i = first_bad(got, ref, tol, scale)
        slot = int(np.argmax(np.abs(got[i] - ref[i]).max(axis=1)))
        r = factor_text(ratio(got, ref))
        frames = _frames(P)
        outside = [k for k in range(len(P)) if not 0 <= np.dot(frames[1][k], frames[0][k]) / size[k] ** 2 <= 1
                   or not 0 <= np.dot(frames[2][k], frames[0][k]) / size[k] ** 2 <= 1]
        named = next((text for wrong, text in [
            (_gradient_np(*frames, edge_factor=False),
             "is missing the factor |e| in the wings' gradient: dtheta/dx_w0 = -|e| N0/|N0|^2 = -n0/h0, with "
             "h0 = |N0|/|e| the wing's height"),
            (_gradient_np(*frames, foot=lambda t, s: np.abs(t)), "takes the feet's positions along the edge "
                                                                 "unsigned: t = a.e/|e|^2 is negative when a wing's "
                                                                 "foot lies before v0"),
            (_gradient_np(*frames, foot=lambda t, s: np.clip(t, 0.0, 1.0)),
             "clips the feet's positions to the edge: t = a.e/|e|^2 may lie outside [0, 1]"),
            (_gradient_np(*frames, foot=lambda t, s: t * s), "measures the feet's positions in metres, a.e/|e|: "
                                                             "the weight is the fraction t = a.e/|e|^2 of the edge"),
            (_gradient_np(*frames, swap_weights=True), "swaps the hinge vertices' weights: with t = a.e/|e|^2 "
                                                       "measured from v0, v1 gets t and v0 gets 1 - t"),
            (_gradient_np(*frames, w1_sign=-1.0), "has the wrong sign on w1's gradient: -|e| N1/|N1|^2 with "
                                                  "N1 = a1 x e, the same form as w0's"),
        ] if matches(got, wrong, scale, tol=1e-6)), "")
        wrong_only_outside = set(np.flatnonzero(np.abs(got - ref).reshape(len(P), -1).max(axis=1) > tol * scale)) \
            <= set(outside)
        if not np.all(np.isfinite(got)):
            reason = f"dihedral_angle_gradient returns NaN or inf at hinge {i}"
        elif r == "minus":
            reason = "dihedral_angle_gradient has the wrong sign: it is -dtheta/dx"
        elif named:
            reason = f"dihedral_angle_gradient {named}"
        elif r:
            reason = f"dihedral_angle_gradient is {r} dtheta/dx"
        elif np.abs(got.sum(axis=1)).max(axis=1).max() > 1e-9 * scale.max():
            reason = ("dihedral_angle_gradient does not sum to zero over the four vertices: a translation does not "
                      "change the angle, so the four gradients must cancel")
        elif wrong_only_outside:
            reason = ("dihedral_angle_gradient is wrong only on hinges whose wing's foot lies outside the edge: "
                      "the hinge vertices' weights come from t = a.e/|e|^2, which may be below 0 or above 1")
        else:
            reason = (f"gradient is not dtheta/dx: deviation {dev:.2g} at hinge {i}, slot "
                      f"{('v0', 'v1', 'w0', 'w1')[slot]} (|e| = {size[i]:.3g} m)")
    return [agreement(f"dihedral_angle_gradient = dtheta/dx by finite differences (G1)-(G3), {len(P)} random "
                      f"hinges, |e| from 1 cm to 100 m, feet outside the edge too (max deviation / largest entry)",
                      "ex-dihedral-gradient", dev, tol, reason, "rad/m")]


def install_angle(func) -> None:
    substitute(Hg.dihedral_angle, func)


def install_gradient(func) -> None:
    substitute(Hg.dihedral_angle_gradient, func)


LABELS = {   # the equations this exercise cites, defined in its template (what, not how)
    "A1": "theta, the signed angle between the wings' normals N0 = e x a0 and N1 = a1 x e, turning about e",
    "G1": "the gradient of (A1) at a wing vertex",
    "G2": "where each wing's foot (the nearest point of the edge's line) lies along the edge",
    "G3": "the gradient of (A1) at the two hinge vertices, from (G1) and (G2)",
}

TASKS = [
    Task("dihedral_angle", TI_FUNC, "e, a0, a1", """\
The signed dihedral angle theta of one hinge (A1), in rad, in (-pi, pi]; zero when flat.

The hinge has two triangles (v0, v1, w0) and (v1, v0, w1) sharing the edge v0-v1. Its frame
(ti.math.vec3, m): e = x_v1 - x_v0 (the hinge edge), a0 = x_w0 - x_v0, a1 = x_w1 - x_v0.
The wings' normals are N0 = e x a0 and N1 = a1 x e; theta is the angle from N0 to N1, positive
when turning about e. Its cosine goes with N0 . N1, its sine with e/|e| . (N0 x N1); atan2 of
the two keeps the sign.""", install_angle, check_angle, (), "float"),
    Task("dihedral_angle_gradient", TI_FUNC, "e, a0, a1", """\
The gradient of theta (G1)-(G3) with respect to the four vertices: returns
(g_v0, g_v1, g_w0, g_w1), four ti.math.vec3 in rad/m.

e, a0, a1 as in dihedral_angle. A wing vertex moves theta only along its wing's normal, by one
over its height above the hinge edge (the wing w1 with the opposite sign of w0); the hinge
vertices get the rest, weighted by where the wings' feet lie along the edge, so that the four
gradients sum to zero.""", install_gradient, check_gradient, (), "g_v0, g_v1, g_w0, g_w1"),
]
