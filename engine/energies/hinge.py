"""One hinge: its dihedral angle, the angle's derivatives and the bending energy terms of the angle.

The single-hinge math of the bending energy (engine/energies/bending.py), written once as public
ti.funcs on values: the energy's kernels, the fused cloth step (engine.integrators.cloth_kernels) and
the benchmark's force variants (bench/variants.py) all call these. Lengths in m, angles in rad,
stiffness k in J (= N m), energies in J.

Frame
-----
Hinge convention (engine.mesh): row [v0, v1, w0, w1]; edge e = x_v1 - x_v0, triangle
t0 = (v0, v1, w0), t1 = (v1, v0, w1), both in the mesh's orientation. A hinge's geometry is its
frame of three difference vectors (:func:`hinge_frame`)

    e = x_v1 - x_v0,    a0 = x_w0 - x_v0,    a1 = x_w1 - x_v0.

Angle and gradient
------------------
With N0 = e x a0, N1 = (x_v0 - x_v1) x (x_w1 - x_v1) = a1 x e:

    theta = atan2( e_hat . (N0 x N1), N0 . N1 )   in (-pi, pi]                            (A1)

(atan2 of unnormalised sine and cosine parts: no acos, accurate near 0 and near +-pi).
SIGN: theta = 0 for a flat hinge, theta > 0 where the surface is convex on the side its
normals point to (e.g. every edge of a convex closed surface with outward normals, or a
cylinder with outward normals), theta < 0 where it is concave.  Moving a wing along its own
normal decreases theta.

Gradient (h0 = |N0|/|e|, h1 = |N1|/|e|, n = N/|N|, t_i = (x_wi - x_v0).e / |e|^2 the
position of the wing's foot along the edge):

    dtheta/dx_w0 = -n0/h0 = -|e| N0/|N0|^2,    dtheta/dx_w1 = -n1/h1 = -|e| N1/|N1|^2     (G1)
    dtheta/dx_v1 = -t0 dtheta/dx_w0 - t1 dtheta/dx_w1                                      (G2)
    dtheta/dx_v0 = -(1 - t0) dtheta/dx_w0 - (1 - t1) dtheta/dx_w1                          (G3)

The four sum to zero; Bridson's u_1..u_4 (x1 = w0, x2 = w1, x3 = v0, x4 = v1) are exactly
-grad theta.

Hessian of theta: theta is a function of the frame (e, a0, a1).  In those variables
G_a0 = -|e| N0/|N0|^2, G_a1 = -|e| N1/|N1|^2, G_e = -t0 G_a0 - t1 G_a1, and with
d(N/|N|^2) = (I - 2 n n^T)/|N|^2 dN, dN0 = [e]x da0 - [a0]x de, dN1 = -[e]x da1 + [a1]x de,
the nine 3x3 blocks follow by the product rule (:func:`dihedral_angle_hessian_parts`); the 12x12
Hessian is P^T H9 P with P the map x -> (e, a0, a1) (:func:`dihedral_angle_hessian_block`).

Energy terms
------------
With d = theta - theta_bar wrapped into [-pi, pi) (:func:`wrap_angle`), the energy of a hinge of
stiffness k in one of two shapes (``mode``):

    MODE_QUADRATIC:   W = 1/2 k d^2,             W' = k d,            W'' = k             (W1)
    MODE_HALF_ANGLE:  W = 4 k (1 - cos(d/2)) = 8 k sin^2(d/4),
                      W' = 2 k sin(d/2),         W'' = k cos(d/2)                         (W2)

(primes: d/dtheta).  Forces -dW/dx = -W' grad theta (:func:`hinge_forces`); Hessian exact
H = W'' g g^T + W' Hess(theta), Gauss-Newton (psd) H = max(W'', 0) g g^T, g = grad theta
(:func:`hinge_hessian_block`).  At theta = theta_bar (W' = 0) the two coincide.

The kernels at the end evaluate the angle, its gradient, its Hessian and Bridson's u vectors
(literally, as a reference for the gradient) over an (h, 4) hinge array.
"""
import taichi as ti

from engine.fields import int_array2 as hinge_array
from engine.fields import mat3_array2, scalar_array, vec3_array, vec3_array2

MODE_QUADRATIC = 0   # (W1)
MODE_HALF_ANGLE = 1  # (W2)

# Coefficients of P: (e, a0, a1) = P (x_v0, x_v1, x_w0, x_w1); row p, column slot.
_P = ((-1, 1, 0, 0),   # e  = x_v1 - x_v0
      (-1, 0, 1, 0),   # a0 = x_w0 - x_v0
      (-1, 0, 0, 1))   # a1 = x_w1 - x_v0
_H9_NONZERO = ((1, 1, 1), (1, 1, 0), (1, 0, 1))  # d G_a0 / d a1 = d G_a1 / d a0 = 0

# atan(t) = t - t z P(z), z = t^2, for |t| < 1/8: P(z) = (t - atan t)/(t z) interpolated at 6 Chebyshev
# nodes in z in 80-bit arithmetic, rounded to f64. Against an 80-bit atan the result is within
# 0.57 ulp in f64 (the C library's atan2: 0.52) and 0.51 ulp in f32.
_ATAN_P = (0.3333333333333331, -0.19999999999808935, 0.14285714134412197, -0.11111068939432774,
           0.09085639204325464, -0.07388585930069287)


@ti.func
def _skew(a):
    """[a]x, the matrix with [a]x b = a x b."""
    return ti.Matrix([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


@ti.func
def fast_atan2(y, x):
    """atan2(y, x) (rad, in (-pi, pi]), inline for |y| < x / 8 (|angle| < 7.1 deg: most hinges of a
    cloth or a shell), where the polynomial is quicker than the C library's atan2 call; that call
    otherwise. Within an ulp of the library's atan2 everywhere."""
    r = 0.0
    if ti.abs(y) < 0.125 * x:
        t = y / x
        z = t * t
        c = ti.static(_ATAN_P)
        p = c[4] + z * c[5]
        for j in ti.static(range(3, -1, -1)):
            p = c[j] + z * p
        r = t - t * (z * p)
    else:
        r = ti.atan2(y, x)
    return r


@ti.func
def hinge_frame(x: ti.template(), v0, v1, w0, w1):
    """The frame (e, a0, a1) (m) of the hinge on vertices [v0, v1, w0, w1] of positions x:
    e = x_v1 - x_v0, a0 = x_w0 - x_v0, a1 = x_w1 - x_v0."""
    xv0 = x[v0]
    return x[v1] - xv0, x[w0] - xv0, x[w1] - xv0


@ti.func
def row_frame(x: ti.template(), hinges: ti.template(), h):
    """:func:`hinge_frame` of row h of an (h, 4) hinge array."""
    return hinge_frame(x, hinges[h, 0], hinges[h, 1], hinges[h, 2], hinges[h, 3])


@ti.func
def dihedral_angle(e, a0, a1):
    """(A1) the signed dihedral angle theta (rad, in (-pi, pi]) of the frame (e, a0, a1) (m)."""
    # theta = atan2(e_hat . (N0 x N1), N0 . N1), N0 = e x a0, N1 = a1 x e, evaluated as
    # atan2(-|e| (N0 . a1), N0 . N1): N0 x N1 = (e x a0) x (a1 x e) = -((e x a0) . a1) e, so
    # e_hat . (N0 x N1) = -|e| (N0 . a1) (one dot product instead of a cross product, a dot and a
    # division; the rest of a force or Hessian kernel shares N0 and |e| with the gradient)
    N0 = e.cross(a0)
    N1 = a1.cross(e)
    return fast_atan2(-e.norm() * N0.dot(a1), N0.dot(N1))


@ti.func
def dihedral_angle_gradient(e, a0, a1):
    """(G1)-(G3): dtheta/dx (rad/m, four vec3) for the slots (v0, v1, w0, w1) of the frame (e, a0, a1)."""
    s = e.norm()
    N0 = e.cross(a0)
    N1 = a1.cross(e)
    g_w0 = (-s / N0.norm_sqr()) * N0           # -n0/h0
    g_w1 = (-s / N1.norm_sqr()) * N1           # -n1/h1
    t0 = a0.dot(e) / (s * s)
    t1 = a1.dot(e) / (s * s)
    g_v1 = -t0 * g_w0 - t1 * g_w1
    g_v0 = -(g_v1 + g_w0 + g_w1)               # = -(1-t0) g_w0 - (1-t1) g_w1
    return g_v0, g_v1, g_w0, g_w1


@ti.func
def dihedral_angle_hessian_parts(e, a0, a1):
    """Second derivatives of theta(e, a0, a1) (rad/m^2, seven mat3): the blocks d G_p / d q (row =
    component of the gradient G_p, column = component of q) for p, q in (e, a0, a1), returned as
    (H_ee, H_ea0, H_ea1, H_a0e, H_a0a0, H_a1e, H_a1a1); G_a0 / a1 and G_a1 / a0 vanish."""
    I3 = ti.Matrix.identity(float, 3)
    s = e.norm()
    s2 = s * s
    e_hat = e / s
    N0 = e.cross(a0)
    N1 = a1.cross(e)
    q0 = N0.norm_sqr()
    q1 = N1.norm_sqr()
    f0 = N0 / q0                               # N/|N|^2
    f1 = N1 / q1
    D0 = (I3 - 2.0 * f0.outer_product(N0)) / q0   # d(N/|N|^2)/dN = (I - 2 n n^T)/|N|^2
    D1 = (I3 - 2.0 * f1.outer_product(N1)) / q1
    G_a0 = -s * f0
    G_a1 = -s * f1
    t0 = a0.dot(e) / s2
    t1 = a1.dot(e) / s2
    # G_a0 = -|e| f(N0), dN0/da0 = [e]x, dN0/de = -[a0]x
    H_a0a0 = -s * (D0 @ _skew(e))
    H_a0e = -f0.outer_product(e_hat) + s * (D0 @ _skew(a0))
    # G_a1 = -|e| f(N1), dN1/da1 = -[e]x, dN1/de = [a1]x
    H_a1a1 = s * (D1 @ _skew(e))
    H_a1e = -f1.outer_product(e_hat) - s * (D1 @ _skew(a1))
    # G_e = -t0 G_a0 - t1 G_a1; dt/da = e/|e|^2, dt/de = a/|e|^2 - 2 (a.e) e/|e|^4
    dt0_de = a0 / s2 - (2.0 * a0.dot(e) / (s2 * s2)) * e
    dt1_de = a1 / s2 - (2.0 * a1.dot(e) / (s2 * s2)) * e
    H_ee = -G_a0.outer_product(dt0_de) - t0 * H_a0e - G_a1.outer_product(dt1_de) - t1 * H_a1e
    H_ea0 = -G_a0.outer_product(e / s2) - t0 * H_a0a0
    H_ea1 = -G_a1.outer_product(e / s2) - t1 * H_a1a1
    return H_ee, H_ea0, H_ea1, H_a0e, H_a0a0, H_a1e, H_a1a1


@ti.func
def dihedral_angle_hessian_block(i: ti.template(), j: ti.template(), H_ee, H_ea0, H_ea1, H_a0e, H_a0a0, H_a1e,
                                 H_a1a1):
    """Block (i, j) (slots in [v0, v1, w0, w1] order, rad/m^2) of the 12x12 Hessian of theta from the
    parts of :func:`dihedral_angle_hessian_parts`: sum_pq P[p][i] P[q][j] H9[p][q]."""
    H9 = [[H_ee, H_ea0, H_ea1], [H_a0e, H_a0a0, H_a0a0], [H_a1e, H_a1a1, H_a1a1]]  # dummies where zero
    out = ti.Matrix.zero(float, 3, 3)
    for p in ti.static(range(3)):
        for q in ti.static(range(3)):
            if ti.static(_P[p][i] * _P[q][j] * _H9_NONZERO[p][q] != 0):
                out += ti.static(float(_P[p][i] * _P[q][j])) * H9[p][q]
    return out


@ti.func
def wrap_angle(d):
    """d (rad) into [-pi, pi), so that W stays continuous when theta crosses +-pi."""
    r = d
    if r >= ti.math.pi:
        r -= 2.0 * ti.math.pi
    elif r < -ti.math.pi:
        r += 2.0 * ti.math.pi
    return r


@ti.func
def hinge_energy_terms(theta, k, theta_bar, mode):
    """W (J), dW/dtheta (J/rad), d2W/dtheta2 (J/rad^2) of a hinge at angle theta (rad) with stiffness
    k (J) and rest angle theta_bar (rad): (W1) for mode MODE_QUADRATIC, (W2) for MODE_HALF_ANGLE."""
    d = wrap_angle(theta - theta_bar)
    W = 0.0
    W1 = 0.0
    W2 = 0.0
    if mode == MODE_HALF_ANGLE:
        s4 = ti.sin(0.25 * d)
        W = 8.0 * k * s4 * s4              # 4 k (1 - cos(d/2)), cancellation-free
        W1 = 2.0 * k * ti.sin(0.5 * d)
        W2 = k * ti.cos(0.5 * d)
    else:
        W = 0.5 * k * d * d
        W1 = k * d
        W2 = k
    return W, W1, W2


@ti.func
def hinge_energy(e, a0, a1, k, theta_bar, mode):
    """W (J) of the hinge with frame (e, a0, a1): (W1)/(W2) at the angle (A1)."""
    W, W1, W2 = hinge_energy_terms(dihedral_angle(e, a0, a1), k, theta_bar, mode)
    return W


@ti.func
def hinge_forces(e, a0, a1, k, theta_bar, mode):
    """-dW/dx (N, four vec3) on the slots (v0, v1, w0, w1) of the hinge with frame (e, a0, a1):
    -W'(theta) dtheta/dx_slot, (A1), (W1)/(W2), (G1)-(G3) (= W' u, Bridson's u)."""
    W, W1, W2 = hinge_energy_terms(dihedral_angle(e, a0, a1), k, theta_bar, mode)
    g = dihedral_angle_gradient(e, a0, a1)
    return -W1 * g[0], -W1 * g[1], -W1 * g[2], -W1 * g[3]


@ti.func
def hinge_hessian_parts(psd: ti.template(), e, a0, a1):
    """The second derivatives of theta the exact Hessian needs (:func:`dihedral_angle_hessian_parts`);
    zeros, never read, for the Gauss-Newton one (psd)."""
    z = ti.Matrix.zero(float, 3, 3)
    if ti.static(psd):
        return z, z, z, z, z, z, z
    else:
        return dihedral_angle_hessian_parts(e, a0, a1)


@ti.func
def hinge_hessian_block(i: ti.template(), j: ti.template(), psd: ti.template(), W1, W2, g, parts):
    """Block (i, j) (N/m, mat3) of the hinge's W Hessian: max(W'', 0) g_i g_j^T (psd) or
    W'' g_i g_j^T + W' Hess(theta)_ij (exact; ``parts`` from :func:`hinge_hessian_parts`, unused if
    psd); W1, W2 = W', W'' of :func:`hinge_energy_terms`, g = :func:`dihedral_angle_gradient`."""
    out = ti.Matrix.zero(float, 3, 3)
    if ti.static(psd):
        out = ti.max(W2, 0.0) * g[i].outer_product(g[j])
    else:
        out = W2 * g[i].outer_product(g[j]) + W1 * dihedral_angle_hessian_block(i, j, *parts)
    return out


# --------------------------------------------------------------------------------------------
# Kernels: the angle and its derivatives over an (h, 4) hinge array (no energy)
# --------------------------------------------------------------------------------------------

@ti.kernel
def hinge_angles_kernel(x: vec3_array, hinges: hinge_array, theta: scalar_array):
    # (A1)
    for h in range(hinges.shape[0]):
        e, a0, a1 = row_frame(x, hinges, h)
        theta[h] = dihedral_angle(e, a0, a1)


@ti.kernel
def theta_gradient_kernel(x: vec3_array, hinges: hinge_array, grad: vec3_array2):
    # (G1)-(G3): grad[h, slot] = dtheta_h / dx_slot
    for h in range(hinges.shape[0]):
        e, a0, a1 = row_frame(x, hinges, h)
        g = dihedral_angle_gradient(e, a0, a1)
        for a in ti.static(range(4)):
            grad[h, a] = g[a]


@ti.kernel
def bridson_u_kernel(x: vec3_array, hinges: hinge_array, u: vec3_array2):
    # Bridson et al. 2003, section 4, literally: x1, x2 the wings, x3, x4 the edge,
    # E = x4 - x3, N1 = (x1 - x3) x (x1 - x4), N2 = (x2 - x4) x (x2 - x3),
    # u1 = |E| N1/|N1|^2, u2 = |E| N2/|N2|^2,
    # u3 = (x1-x4).E/|E| N1/|N1|^2 + (x2-x4).E/|E| N2/|N2|^2,
    # u4 = -(x1-x3).E/|E| N1/|N1|^2 - (x2-x3).E/|E| N2/|N2|^2.
    # Mapping x1 = w0, x2 = w1, x3 = v0, x4 = v1; written in slot order (v0, v1, w0, w1) =
    # (u3, u4, u1, u2).  They equal -dtheta/dx.
    for h in range(hinges.shape[0]):
        x3 = x[hinges[h, 0]]
        x4 = x[hinges[h, 1]]
        x1 = x[hinges[h, 2]]
        x2 = x[hinges[h, 3]]
        E = x4 - x3
        En = E.norm()
        N1 = (x1 - x3).cross(x1 - x4)
        N2 = (x2 - x4).cross(x2 - x3)
        m1 = N1 / N1.norm_sqr()
        m2 = N2 / N2.norm_sqr()
        u[h, 2] = En * m1
        u[h, 3] = En * m2
        u[h, 0] = ((x1 - x4).dot(E) / En) * m1 + ((x2 - x4).dot(E) / En) * m2
        u[h, 1] = -((x1 - x3).dot(E) / En) * m1 - ((x2 - x3).dot(E) / En) * m2


@ti.kernel
def theta_hessian_kernel(x: vec3_array, hinges: hinge_array, blocks: mat3_array2):
    # Hess(theta) per hinge, blocks[h, 4a + b] = d2 theta / dx_a dx_b
    for h in range(hinges.shape[0]):
        e, a0, a1 = row_frame(x, hinges, h)
        H_ee, H_ea0, H_ea1, H_a0e, H_a0a0, H_a1e, H_a1a1 = dihedral_angle_hessian_parts(e, a0, a1)
        for i in ti.static(range(4)):
            for j in ti.static(range(4)):
                blocks[h, 4 * i + j] = dihedral_angle_hessian_block(i, j, H_ee, H_ea0, H_ea1, H_a0e, H_a0a0, H_a1e,
                                                                    H_a1a1)
