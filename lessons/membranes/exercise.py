"""The membranes lesson's exercise: a triangle's deformation gradient (F1) and the derivatives of
Baraff and Witkin's energy by its columns (M2).

The student's functions take the engine's place in every membrane kernel (energies, forces,
Hessians and damping read the deformation gradient; the Baraff-Witkin forces read the
derivatives), and are checked on their own first: the deformation gradient against the product
[x1 - x0, x2 - x0] Dm^-1 on random triangles, the derivatives against finite differences of the
energy.
"""
import numpy as np
import taichi as ti

from engine.energies import triangle as Tri
from engine.fields import scalar_array, vec3_array
from .._exercise import TI_FUNC, Sampler, Task, agreement, central_difference, deviation, factor_text, \
    first_bad, matches, ratio, substitute

mat2_array = ti.types.ndarray(dtype=ti.math.mat2, ndim=1)


def _gradient_call(func):
    @ti.kernel
    def run(d1: vec3_array, d2: vec3_array, D: mat2_array, wu: vec3_array, wv: vec3_array):
        for i in range(d1.shape[0]):
            wu[i], wv[i] = func(d1[i], d2[i], D[i])

    def call(d1, d2, D):
        wu, wv = np.zeros_like(d1), np.zeros_like(d1)
        run(np.ascontiguousarray(d1), np.ascontiguousarray(d2), np.ascontiguousarray(D), wu, wv)
        return np.stack([wu, wv], axis=1)   # (n, 2 columns, 3)
    return call


def _stress_call(func):
    @ti.kernel
    def run(wu: vec3_array, wv: vec3_array, A: scalar_array, ks: scalar_array, kh: scalar_array, pu: vec3_array,
            pv: vec3_array):
        for i in range(wu.shape[0]):
            pu[i], pv[i] = func(wu[i], wv[i], A[i], ks[i], kh[i])

    def call(wu, wv, A, ks, kh):
        pu, pv = np.zeros_like(wu), np.zeros_like(wu)
        run(*(np.ascontiguousarray(a) for a in (wu, wv, A, ks, kh)), pu, pv)
        return np.stack([pu, pv], axis=1)
    return call


def _triangles(n: int = 48, seed: int = 11):
    """Random rest triangles (their Dm^-1 in a (u, v) frame) from 1 cm to 10 m across, every other
    one listed clockwise, and deformed edges d1, d2 (m) at the same scales."""
    s = Sampler(seed)
    size = s.log_uniform(n, 1e-2, 10.0)
    P = s.rng.uniform(-1.0, 1.0, (n, 3, 2))
    P[:, 1] += [1.5, 0.0]
    P[:, 2] += [0.0, 1.5]                      # well-shaped: no degenerate rest triangle
    P[1::2] = P[1::2][:, [0, 2, 1]]            # the other orientation
    P *= size[:, None, None]
    Dm = np.stack([P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]], axis=2)   # columns: the rest edges
    D = np.linalg.inv(Dm)
    return s.vectors(n) * size[:, None], s.vectors(n) * size[:, None], D


def check_deformation_gradient(student) -> list:
    d1, d2, D = _triangles()
    got = student.via(_gradient_call)(d1, d2, D)
    F = np.stack([d1, d2], axis=2) @ D                                    # (n, 3, 2)
    ref = np.moveaxis(F, 2, 1)                                            # (n, 2 columns, 3)
    dev = deviation(got, ref)
    tol = 1e-12
    reason = ""
    if not dev <= tol:
        i = first_bad(got, ref, tol)
        swapped_D = np.moveaxis(np.stack([d1, d2], axis=2) @ np.transpose(D, (0, 2, 1)), 2, 1)
        if not np.all(np.isfinite(got)):
            reason = f"deformation_gradient returns NaN or inf at triangle {i}"
        elif deviation(got, ref[:, ::-1]) <= 1e-9:
            reason = "deformation_gradient returns (w_v, w_u): the first column is dx/du, the image of the u axis"
        elif deviation(got, swapped_D) <= 1e-9:
            reason = ("deformation_gradient uses Dm^-1 transposed: w_u = d1 Dinv[0, 0] + d2 Dinv[1, 0] "
                      "(F = [d1, d2] Dm^-1, column by column)")
        elif matches(got, np.stack([d1 * D[:, 0, 0, None], d2 * D[:, 1, 1, None]], axis=1)):
            reason = ("deformation_gradient uses only Dinv's diagonal: w_u = d1 Dinv[0, 0] + d2 Dinv[1, 0] and "
                      "w_v = d1 Dinv[0, 1] + d2 Dinv[1, 1]")
        elif matches(got, np.stack([d1, d2], axis=1)):
            reason = "deformation_gradient returns the edges d1, d2 themselves: F = [d1, d2] Dm^-1 needs Dinv"
        else:
            r = factor_text(ratio(got, ref))
            c = int(np.argmax(np.abs(got[i] - ref[i]).max(axis=1)))
            reason = (f"deformation_gradient is {r} F's columns" if r else
                      f"deformation_gradient gives {('w_u', 'w_v')[c]} = {np.round(got[i, c], 6).tolist()} at "
                      f"triangle {i} instead of {np.round(ref[i, c], 6).tolist()}")
    return [agreement("deformation_gradient = the columns of [x1 - x0, x2 - x0] Dm^-1 (F1), 48 random triangles "
                      "from 1 cm to 10 m, both orientations",
                      "ex-deformation-gradient", dev, tol, reason)]


def _energy(wu, wv, A, ks, kh):
    """Baraff-Witkin's W (M2) from F's columns, in numpy (the finite differences' reference)."""
    lu, lv = np.linalg.norm(wu, axis=-1), np.linalg.norm(wv, axis=-1)
    s = np.einsum("...i,...i->...", wu, wv)
    return A * (0.5 * ks * ((lu - 1.0) ** 2 + (lv - 1.0) ** 2) + 0.5 * kh * s * s)


def _columns_match(got, exact, wrong, scale=None) -> bool:
    """Each of the two columns is the exact derivative or the wrong one, and at least one is wrong: a
    mistake made in one line of the student's code (one column) or in both."""
    cols = [deviation(got[:, c], exact[:, c], scale) <= 1e-9 for c in range(2)]
    bad = [deviation(got[:, c], wrong[:, c], scale) <= 1e-9 for c in range(2)]
    return all(a or b for a, b in zip(cols, bad)) and any(b and not a for a, b in zip(cols, bad))


def _call_of(w):
    """The call each row of a finite-difference batch belongs to (6 perturbations per call)."""
    return np.arange(len(w)) // 6


def check_stress(student) -> list:
    s = Sampler(12)
    n = 48
    wu = s.vectors(n, 0.6) + [1.0, 0.0, 0.0]
    wv = s.vectors(n, 0.6) + [0.0, 1.0, 0.0]
    A, ks, kh = s.log_uniform(n, 1e-4, 10.0), s.log_uniform(n, 1.0, 1e4), s.log_uniform(n, 0.5, 5e3)
    got = student.via(_stress_call)(wu, wv, A, ks, kh)
    ref = central_difference(lambda w: _energy(w[:, :3], w[:, 3:], A[_call_of(w)], ks[_call_of(w)], kh[_call_of(w)]),
                             np.hstack([wu, wv]), 1e-6).reshape(n, 2, 3)
    scale = A * (ks + kh)
    dev = deviation(got, ref, scale)
    tol = 1e-6
    reason = ""
    if not dev <= tol:
        i = first_bad(got, ref, tol, scale)
        lu, lv = np.linalg.norm(wu, axis=1)[:, None], np.linalg.norm(wv, axis=1)[:, None]
        aks, sh = (A * ks)[:, None], (A * kh * np.einsum("ij,ij->i", wu, wv))[:, None]
        stretch = np.stack([aks * (lu - 1.0) * wu / lu, aks * (lv - 1.0) * wv / lv], 1)
        shear = np.stack([sh * wv, sh * wu], 1)
        exact = stretch + shear
        mistakes = [   # (the same mistake in either column, what it means)
            (stretch, "leaves out the shear term: d/dw_u of k_h/2 (w_u . w_v)^2 is k_h (w_u . w_v) w_v"),
            (stretch + shear[:, ::-1], "has the shear term on the wrong column: d(w_u . w_v)/dw_u = w_v, "
                                       "so dW/dw_u gets k_h s w_v"),
            (np.stack([aks * (lu - 1.0) * wu, aks * (lv - 1.0) * wv], 1) + shear,
             "has a stretch term that must point along the unit vector: d|w_u|/dw_u = w_u/|w_u|, "
             "so k_s (|w_u| - 1) w_u/|w_u|"),
            (exact / A[:, None, None], "is the derivative per unit area: multiply by the rest area A"),
            (np.stack([aks * (lu - 1.0) * wu / lu, aks * (lv - 1.0) * wv / lv], 1) + 2.0 * shear,
             "has twice the shear term: d/dw_u of k_h/2 (w_u . w_v)^2 is k_h (w_u . w_v) w_v (the 1/2 cancels the 2)"),
            (-exact, "has the wrong sign: it is -dW/dw (the force's sign, not the energy's derivative)"),
        ]
        r = factor_text(ratio(got, ref))
        named = [text for wrong, text in mistakes if _columns_match(got, exact, wrong, scale)]
        if not np.all(np.isfinite(got)):
            reason = f"baraff_witkin_stress returns NaN or inf at call {i}"
        elif named:
            reason = "baraff_witkin_stress " + named[0]
        elif r:
            reason = f"baraff_witkin_stress is {r} dW/dw"
        else:
            reason = f"baraff_witkin_stress is not dW/dw: FD error {dev:.2g} at call {i}"
    return [agreement("baraff_witkin_stress = (dW/dw_u, dW/dw_v) by finite differences (M2), 48 random triangles, "
                      "A from 1 cm^2 to 10 m^2 (max deviation / A (k_s + k_h))",
                      "ex-bw-stress", dev, tol, reason, "J")]


def install_deformation_gradient(func) -> None:
    substitute(Tri.deformation_gradient, func)


def install_stress(func) -> None:
    substitute(Tri.baraff_witkin_stress, func)


LABELS = {   # the equations this exercise cites, defined in its template (what, not how)
    "F1": "F = [x1 - x0, x2 - x0] Dm^-1 = [w_u, w_v], a triangle's deformation gradient",
    "M2": "W = A [k_s/2 ((|w_u| - 1)^2 + (|w_v| - 1)^2) + k_h/2 (w_u . w_v)^2], Baraff and Witkin's energy",
}

TASKS = [
    Task("deformation_gradient", TI_FUNC, "d1, d2, Dinv", """\
The deformation gradient of one triangle (F1): returns its two columns (w_u, w_v), two
ti.math.vec3 (dimensionless): w_u = dx/du and w_v = dx/dv, the images of the rest frame's axes.

d1 = x1 - x0 and d2 = x2 - x0 are the deformed triangle's edges from corner 0 (ti.math.vec3, m);
Dinv (ti.math.mat2, 1/m) is Dm^-1, where Dm's columns are the same edges at rest in the
triangle's (u, v) frame. F = [d1, d2] Dm^-1, a 3x2 matrix: take its columns.""",
         install_deformation_gradient, check_deformation_gradient, (), "w_u, w_v"),
    Task("baraff_witkin_stress", TI_FUNC, "w_u, w_v, A, k_stretch, k_shear", """\
The derivatives of Baraff and Witkin's energy (M2) of one triangle by F's columns: returns
(dW/dw_u, dW/dw_v), two ti.math.vec3 in J.

W = A [k_stretch/2 ((|w_u| - 1)^2 + (|w_v| - 1)^2) + k_shear/2 (w_u . w_v)^2], with A the rest
area (m^2) and k_stretch, k_shear in N/m. The engine turns them into the corner forces,
f_a = -(g_a0 dW/dw_u + g_a1 dW/dw_v).""", install_stress, check_stress, (1, 2, 4, 5), "dW_dwu, dW_dwv"),
]
