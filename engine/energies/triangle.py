"""One triangle of a membrane: its deformation gradient, the energies' terms and Hessian blocks, and
Baraff and Witkin's condition gradients.

The single-triangle math of the membrane energies (engine/energies/membrane.py), written once as
ti.funcs on values: the energy's kernels (engine/energies/membrane_kernels.py) call these, and the
membranes exercise puts its own :func:`deformation_gradient` and :func:`baraff_witkin_stress` in
their place.

Both energies read a triangle's deformation in its rest frame (u, v), an orthonormal frame of the
rest triangle's plane whose u axis is the projection of a chosen material direction (default: the x
axis; the warp of a cloth; engine.energies.membrane.rest_frames). With the rest coordinates of the
corners in that frame, Dm = [p1 - p0, p2 - p0] (2x2), the deformation gradient of the (linear)
triangle is

    F = [x1 - x0, x2 - x0] Dm^-1 = sum_a x_a g_a^T,   g1, g2 = the rows of Dm^-1,  g0 = -(g1 + g2)  (F1)

(3x2; its columns w_u = dx/du and w_v = dx/dv are the images of the rest frame's axes), constant
over the triangle. A is the rest area.

Constant-strain triangle, St. Venant-Kirchhoff, with E = (F^T F - I)/2 (Green strain, 2x2):

    W = A [ mu E:E + lambda/2 tr(E)^2 ],   S = lambda tr(E) I + 2 mu E,   dW/dx_a = A F S g_a   (M1)
    H_ab = A [ (g_a . S g_b) I + lambda (F g_a)(F g_b)^T + mu (g_a . g_b) F F^T + mu (F g_b)(F g_a)^T ]

with the plane-stress Lame parameters of a sheet of 2D Young's modulus Y (N/m) and Poisson's
ratio nu:  mu = Y / (2 (1 + nu)),  lambda = Y nu / (1 - nu^2). Its small-strain limit is the
isotropic linear membrane, so a static stretch measures Y and nu as set, on any mesh. The PSD
variant keeps the positive part of S in the first term (the rest, lambda tr(M)^2 + 2 mu |sym M|^2
for M = F^T dF, is never negative).

Baraff and Witkin (1998), section 4.2: conditions on each triangle,

    stretch  C_u = sqrt(A) (|w_u| - 1),  C_v = sqrt(A) (|w_v| - 1);   shear  C_s = sqrt(A) w_u . w_v
    W = k_s/2 (C_u^2 + C_v^2) + k_h/2 C_s^2                                                     (M2)

(their C carries the area a itself, which makes W grow with a^2 and the stiffness depend on the
resolution; sqrt(A) makes W an integral over the rest area, k_s and k_h in N/m). For small strains
(M2) is an orthotropic membrane with Young's moduli k_s along u and v, Poisson's ratio 0 (the
stretch conditions do not couple u and v) and shear modulus k_h: isotropic only when
k_h = k_s / 2. With n_u = w_u/|w_u|:

    dW/dx_a = A [ k_s ((|w_u| - 1) g_a0 n_u + (|w_v| - 1) g_a1 n_v) + k_h s (g_a0 w_v + g_a1 w_u) ],  s = w_u . w_v
    H_ab = A [ k_s (g_a0 g_b0 K_u + g_a1 g_b1 K_v) + k_h ( q_a q_b^T + s (g_a0 g_b1 + g_a1 g_b0) I ) ]
           K_u = n_u n_u^T + (1 - 1/|w_u|) (I - n_u n_u^T),   q_a = g_a0 w_v + g_a1 w_u

The PSD variant clips K's transverse coefficient at 0 (a compressed direction, as for springs)
and drops the shear's s-term (Baraff and Witkin's own approximation: dC/dx^T dC/dx only).

:func:`condition_gradients` gives the conditions' gradients dC/dx_a, which their damping (M3,
engine/energies/membrane.py) is made of.
"""
import taichi as ti

# the models' codes (MembraneEnergy.model_code, a compile-time argument of the kernels)
STVK, BARAFF_WITKIN = 0, 1
MODELS = {"stvk": STVK, "baraff-witkin": BARAFF_WITKIN}
vec2 = ti.math.vec2
mat2 = ti.math.mat2


# --------------------------------------------------------------------------------------------
# One triangle
# --------------------------------------------------------------------------------------------

@ti.func
def deformation_gradient(d1, d2, D):
    """(w_u, w_v), the columns of F = [d1, d2] Dm^-1 (F1), for the deformed edges d1 = x1 - x0,
    d2 = x2 - x0 and D = Dm^-1 (the membranes exercise's first function)."""
    return d1 * D[0, 0] + d2 * D[1, 0], d1 * D[0, 1] + d2 * D[1, 1]


@ti.func
def triangle_frame(x: ti.template(), tris: ti.template(), Dinv: ti.template(), t):
    """(w_u, w_v, g0, g1, g2) of triangle t (F1): F's columns and the corners' gradient rows."""
    x0 = x[tris[t, 0]]
    D = Dinv[t]
    wu, wv = deformation_gradient(x[tris[t, 1]] - x0, x[tris[t, 2]] - x0, D)
    g1 = vec2(D[0, 0], D[0, 1])
    g2 = vec2(D[1, 0], D[1, 1])
    return wu, wv, -(g1 + g2), g1, g2


@ti.func
def baraff_witkin_stress(wu, wv, A, ks, kh):
    """(dW/dw_u, dW/dw_v) of Baraff and Witkin's energy (M2) of one triangle (the membranes
    exercise's second function)."""
    lu, lv, s = wu.norm(), wv.norm(), wu.dot(wv)
    return A * (ks * (lu - 1.0) / lu * wu + kh * s * wv), A * (ks * (lv - 1.0) / lv * wv + kh * s * wu)


@ti.func
def positive_part(S):
    """The positive part of a symmetric 2x2 matrix (its negative eigenvalues set to 0)."""
    a, b, d = S[0, 0], S[0, 1], S[1, 1]
    mean = 0.5 * (a + d)
    r = ti.sqrt(0.25 * (a - d) * (a - d) + b * b)
    hi, lo = mean + r, mean - r
    out = S
    if lo < 0.0:
        out = mat2(0.0)
        if hi > 0.0:
            v = vec2(1.0, 0.0)
            if b != 0.0:
                v = vec2(b, hi - a)
            elif d > a:
                v = vec2(0.0, 1.0)
            v = v / v.norm()
            out = hi * v.outer_product(v)
    return out


@ti.func
def membrane_terms(model: ti.template(), wu, wv, A, p0, p1):
    """(W, S, P_u, P_v) of one triangle: its energy, St. Venant-Kirchhoff's second Piola-Kirchhoff
    stress S (2x2; zero for Baraff-Witkin), and P_u = dW/dw_u, P_v = dW/dw_v, the derivatives by
    F's columns, so that dW/dx_a = g_a0 P_u + g_a1 P_v ((M1): P = A F S; (M2))."""
    W = 0.0
    S = mat2(0.0)
    Pu, Pv = ti.math.vec3(0.0), ti.math.vec3(0.0)
    if ti.static(model == STVK):
        mu, lam = p0, p1
        E00 = 0.5 * (wu.dot(wu) - 1.0)
        E11 = 0.5 * (wv.dot(wv) - 1.0)
        E01 = 0.5 * wu.dot(wv)
        tr = E00 + E11
        W = A * (mu * (E00 * E00 + E11 * E11 + 2.0 * E01 * E01) + 0.5 * lam * tr * tr)
        S = mat2([[lam * tr + 2.0 * mu * E00, 2.0 * mu * E01], [2.0 * mu * E01, lam * tr + 2.0 * mu * E11]])
        Pu = A * (S[0, 0] * wu + S[1, 0] * wv)
        Pv = A * (S[0, 1] * wu + S[1, 1] * wv)
    else:
        ks, kh = p0, p1
        lu, lv, s = wu.norm(), wv.norm(), wu.dot(wv)
        W = A * (0.5 * ks * ((lu - 1.0) ** 2 + (lv - 1.0) ** 2) + 0.5 * kh * s * s)
        Pu, Pv = baraff_witkin_stress(wu, wv, A, ks, kh)
    return W, S, Pu, Pv


@ti.func
def stretch_stiffness(psd: ti.template(), wu, wv):
    """(K_u, K_v, s) of Baraff and Witkin's stretch conditions (M2): K = n n^T + (1 - 1/|w|) (I - n n^T)
    for w_u and w_v, the transverse coefficient clipped at 0 in the PSD variant, and s = w_u . w_v."""
    I3 = ti.math.eye(3)
    lu, lv, s = wu.norm(), wv.norm(), wu.dot(wv)
    nu_, nv_ = wu / lu, wv / lv
    cu, cv = 1.0 - 1.0 / lu, 1.0 - 1.0 / lv
    if ti.static(psd):
        cu, cv = ti.max(cu, 0.0), ti.max(cv, 0.0)
    Pu, Pv = nu_.outer_product(nu_), nv_.outer_product(nv_)
    return Pu + cu * (I3 - Pu), Pv + cv * (I3 - Pv), s


@ti.func
def block_ab(model: ti.template(), psd: ti.template(), wu, wv, ga, gb, S, A, p0, p1):
    """H_ab = d2W/dx_a dx_b (3x3) of one triangle, (M1) or (M2), exact or PSD."""
    I3 = ti.math.eye(3)
    H = ti.math.mat3(0.0)
    if ti.static(model == STVK):
        mu, lam = p0, p1
        Sp = S
        if ti.static(psd):
            Sp = positive_part(S)
        Fa = ga[0] * wu + ga[1] * wv
        Fb = gb[0] * wu + gb[1] * wv
        FFt = wu.outer_product(wu) + wv.outer_product(wv)
        H = A * (ga.dot(Sp @ gb) * I3 + lam * Fa.outer_product(Fb) + mu * ga.dot(gb) * FFt
                 + mu * Fb.outer_product(Fa))
    else:
        ks, kh = p0, p1
        Ku, Kv, s = stretch_stiffness(psd, wu, wv)
        qa = ga[0] * wv + ga[1] * wu
        qb = gb[0] * wv + gb[1] * wu
        H = ks * (ga[0] * gb[0] * Ku + ga[1] * gb[1] * Kv) + kh * qa.outer_product(qb)
        if ti.static(not psd):
            H += kh * s * (ga[0] * gb[1] + ga[1] * gb[0]) * I3
        H = A * H
    return H


@ti.func
def deformation_blocks(model: ti.template(), psd: ti.template(), wu, wv, S, A, p0, p1):
    """(A_uu, A_uv, A_vv): the triangle's Hessian by F's columns, d2W/dw_i dw_j (3x3 each; A_vu = A_uv^T),
    of which every block (M1)/(M2) is a combination, H_ab = sum_ij g_ai g_bj A_ij:

        St. Venant-Kirchhoff  A_ij = A [ S_ij I + lambda w_i w_j^T + mu delta_ij F F^T + mu w_j w_i^T ]
        Baraff-Witkin         A_uu = A [ k_s K_u + k_h w_v w_v^T ],  A_vv = A [ k_s K_v + k_h w_u w_u^T ],
                              A_uv = A k_h [ w_v w_u^T + s I ]  (s I: exact only)

    with the same PSD variants as :func:`block_ab` (S's positive part; K's clipped coefficient, no s I).
    27 numbers per triangle instead of the 81 of its nine blocks: the product H p of one triangle is
    F's differential dw_j = sum_b g_bj p_b, then r_i = sum_j A_ij dw_j, then (H p)_a = sum_i g_ai r_i."""
    I3 = ti.math.eye(3)
    Auu, Auv, Avv = ti.math.mat3(0.0), ti.math.mat3(0.0), ti.math.mat3(0.0)
    if ti.static(model == STVK):
        mu, lam = p0, p1
        Sp = S
        if ti.static(psd):
            Sp = positive_part(S)
        FFt = wu.outer_product(wu) + wv.outer_product(wv)
        Auu = A * (Sp[0, 0] * I3 + (lam + mu) * wu.outer_product(wu) + mu * FFt)
        Avv = A * (Sp[1, 1] * I3 + (lam + mu) * wv.outer_product(wv) + mu * FFt)
        Auv = A * (Sp[0, 1] * I3 + lam * wu.outer_product(wv) + mu * wv.outer_product(wu))
    else:
        ks, kh = p0, p1
        Ku, Kv, s = stretch_stiffness(psd, wu, wv)
        Auu = A * (ks * Ku + kh * wv.outer_product(wv))
        Avv = A * (ks * Kv + kh * wu.outer_product(wu))
        Auv = A * kh * wv.outer_product(wu)
        if ti.static(not psd):
            Auv += A * kh * s * I3
    return Auu, Auv, Avv


@ti.func
def condition_gradients(wu, wv, g, A):
    """dC/dx_a of Baraff-Witkin's three conditions for the corners a = 0, 1, 2: (stretch u,
    stretch v, shear) lists of vec3, (M2)."""
    r = ti.sqrt(A)
    nu_, nv_ = wu / wu.norm(), wv / wv.norm()
    gu = [r * g[a][0] * nu_ for a in ti.static(range(3))]
    gv = [r * g[a][1] * nv_ for a in ti.static(range(3))]
    gs = [r * (g[a][0] * wv + g[a][1] * wu) for a in ti.static(range(3))]
    return gu, gv, gs
