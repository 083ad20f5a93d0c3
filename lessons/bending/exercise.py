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
from .._exercise import call_student, TI_FUNC, Sampler, Task, agreement, central_difference, deviation, \
    factor_text, first_bad, ratio, substitute


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


def _hinges(n: int = 40, seed: int = 9):
    """Random hinges: vertex positions (n, 4, 3) for the slots (v0, v1, w0, w1), folded by angles
    over the whole circle (the wings stay clear of the hinge edge)."""
    s = Sampler(seed)
    P = np.zeros((n, 4, 3))
    P[:, 1] = [1.0, 0.0, 0.0]
    phi = s.uniform(n, -3.0, 3.0)
    t0, t1 = s.uniform(n, 0.2, 0.8), s.uniform(n, 0.2, 0.8)
    r0, r1 = s.uniform(n, 0.3, 1.0), s.uniform(n, 0.3, 1.0)
    P[:, 2] = np.column_stack([t0, r0, np.zeros(n)])
    P[:, 3] = np.column_stack([t1, -r1 * np.cos(phi), r1 * np.sin(phi)])
    # a random rigid motion of each hinge
    for k in range(n):
        q, _ = np.linalg.qr(s.rng.standard_normal((3, 3)))
        P[k] = P[k] @ q.T + s.vectors(1)
    return P


def _frames(P):
    return P[:, 1] - P[:, 0], P[:, 2] - P[:, 0], P[:, 3] - P[:, 0]


def check_angle(func) -> list:
    P = _hinges()
    got = call_student("dihedral_angle", _angle_call(func), *_frames(P))
    ref = _angle_call(Hg.dihedral_angle)(*_frames(P))
    dev = deviation(got, ref)
    tol = 1e-12
    reason = ""
    if not dev <= tol:
        i = first_bad(got, ref, tol)
        if not np.all(np.isfinite(got)):
            reason = f"dihedral_angle returns NaN or inf at hinge {i}"
        elif deviation(got, -ref) <= 1e-9:
            reason = ("dihedral_angle has the wrong sign: theta is positive when the hinge folds one way "
                      "(about e, from N0 to N1) and negative the other")
        elif deviation(got, np.abs(ref)) <= 1e-9:
            reason = "dihedral_angle loses the sign: it returns |theta|; use atan2 of the signed sine and the cosine"
        else:
            r = factor_text(ratio(got, ref))
            reason = (f"dihedral_angle is {r} the signed angle" if r else
                      f"dihedral_angle gives {got[i]:.6g} rad at hinge {i} instead of {ref[i]:.6g} rad")
    return [agreement("dihedral_angle = the signed angle (A1) on 40 random hinges (max rel. dev.)",
                      "ex-dihedral-angle", dev, tol, reason, "rad")]


def check_gradient(func) -> list:
    P = _hinges(seed=10)
    got = call_student("dihedral_angle_gradient", _gradient_call(func), *_frames(P))
    angle = _angle_call(Hg.dihedral_angle)
    ref = central_difference(lambda flat: angle(*_frames(flat.reshape(-1, 4, 3))), P.reshape(len(P), 12), 1e-6)
    ref = ref.reshape(len(P), 4, 3)
    dev = deviation(got, ref)
    tol = 1e-6
    reason = ""
    if not dev <= tol:
        i = first_bad(got, ref, tol)
        slot = int(np.argmax(np.abs(got[i] - ref[i]).max(axis=1)))
        r = factor_text(ratio(got, ref))
        if not np.all(np.isfinite(got)):
            reason = f"dihedral_angle_gradient returns NaN or inf at hinge {i}"
        elif r == "minus":
            reason = "dihedral_angle_gradient has the wrong sign: it is -dtheta/dx"
        elif r:
            reason = f"dihedral_angle_gradient is {r} dtheta/dx"
        elif np.abs(got.sum(axis=1)).max() > 1e-9 * np.abs(ref).max():
            reason = ("dihedral_angle_gradient does not sum to zero over the four vertices: a translation does not "
                      "change the angle, so the four gradients must cancel")
        else:
            reason = (f"gradient is not dtheta/dx: FD error {dev:.2g} at hinge {i}, slot "
                      f"{('v0', 'v1', 'w0', 'w1')[slot]}")
    return [agreement("dihedral_angle_gradient = dtheta/dx by finite differences (G1)-(G3), 40 random hinges",
                      "ex-dihedral-gradient", dev, tol, reason, "rad/m")]


def install_angle(func) -> None:
    substitute(Hg.dihedral_angle, func)


def install_gradient(func) -> None:
    substitute(Hg.dihedral_angle_gradient, func)


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
