"""Backward Euler on a chain, by the block Thomas algorithm (the rod's tridiagonal solve).

On a chain (vertex i joined only to i - 1 and i + 1, as the rod of the notes' first slides), one
backward-Euler step linearised at x_n (Baraff & Witkin's step, exact for the rod's linear spring
forces along its axis) is the block-tridiagonal system

    (M + dt^2 H(x_n)) v+ = M v_n + dt (f(x_n) + M g),     x+ = x_n + dt v+                   (T1)

with H the PSD spring Hessian (engine/energies/springs.py (S4)): row i has the diagonal block
m_i I + dt^2 sum_{e ~ i} K_e and the off-diagonal blocks -dt^2 K_e towards i - 1 and i + 1; a pinned
vertex's row is v = 0. The Thomas algorithm eliminates forward (C'_i = D_i^-1 C_i, d'_i = D_i^-1
(d_i - A_i d'_{i-1}), D_i = B_i - A_i C'_{i-1}) and substitutes backward (v_i = d'_i - C'_i v_{i+1}):
O(n) work, serial, inside the many-steps kernel so a whole run is one launch. Along the axis of a
straight chain (the rod, engine.energies.axial) the blocks are the scalars k_j = E_j / h_j and
:func:`axial_backward_euler` is the same elimination on them.
"""
import taichi as ti

from engine.energies.axial import axial_force
from engine.energies.springs import spring_block


@ti.func
def chain_backward_euler(x: ti.template(), v: ti.template(), f: ti.template(), offsets: ti.template(),
                         inc_other: ti.template(), inc_inv_L: ti.template(), inc_c_over_L: ti.template(),
                         mass: ti.template(), inv_mass: ti.template(), g, dt, Cp: ti.template(), Dp: ti.template()):
    """One step (T1) of a chain; ``f`` holds the spring forces at x_n; Cp (mat3), Dp (vec3) are work."""
    n = x.shape[0]
    dt2 = dt * dt
    I3 = ti.Matrix.identity(float, 3)
    for i in range(n):  # forward elimination, in vertex order
        A = ti.math.mat3(0.0)
        B = I3
        C = ti.math.mat3(0.0)
        d = ti.math.vec3(0.0)
        if inv_mass[i] > 0.0:
            B = mass[i] * I3
            d = mass[i] * v[i] + dt * (f[i] + mass[i] * g)
            for k in range(offsets[i], offsets[i + 1]):
                j = inc_other[k]
                K = dt2 * spring_block(x[i] - x[j], inc_inv_L[k], inc_c_over_L[k], 1)
                B += K
                if j == i - 1:
                    A = -K
                elif j == i + 1:
                    C = -K
        if i == 0:
            Binv = B.inverse()
            Cp[i] = Binv @ C
            Dp[i] = Binv @ d
        else:
            Dinv = (B - A @ Cp[i - 1]).inverse()
            Cp[i] = Dinv @ C
            Dp[i] = Dinv @ (d - A @ Dp[i - 1])
    for k in range(n):  # back substitution
        i = n - 1 - k
        vi = Dp[i]
        if i < n - 1:
            vi -= Cp[i] @ v[i + 1]
        v[i] = vi
    for i in range(n):
        if inv_mass[i] > 0.0:
            x[i] += dt * v[i]
        else:
            v[i] = ti.math.vec3(0.0)


@ti.func
def axial_backward_euler(x: ti.template(), v: ti.template(), h: ti.template(), E: ti.template(), m: ti.template(),
                         inv_m: ti.template(), dt, Cp: ti.template(), Dp: ti.template()):
    """One step (T1) along the rod's axis: row i is a_i v_{i-1} + b_i v_i + c_i v_{i+1} = d_i with
    k_j = E_j / h_j (the rod is linear, so the step is exact backward Euler); Cp, Dp scalar work."""
    n = x.shape[0]
    dt2 = dt * dt
    for i in range(n):
        a = 0.0
        b = 1.0
        c = 0.0
        d = 0.0
        if inv_m[i] > 0.0:
            b = m[i]
            d = m[i] * v[i] + dt * axial_force(x, h, E, i, n)
            if i > 0:
                k = E[i - 1] / h[i - 1]
                a = -dt2 * k
                b += dt2 * k
            if i < n - 1:
                k = E[i] / h[i]
                c = -dt2 * k
                b += dt2 * k
        if i == 0:
            Cp[i] = c / b
            Dp[i] = d / b
        else:
            denom = b - a * Cp[i - 1]
            Cp[i] = c / denom
            Dp[i] = (d - a * Dp[i - 1]) / denom
    for k in range(n):
        i = n - 1 - k
        vi = Dp[i]
        if i < n - 1:
            vi -= Cp[i] * v[i + 1]
        v[i] = vi
    for i in range(n):
        x[i] += dt * v[i]
