"""Backward Euler on the rod, by the Thomas algorithm (the rod's tridiagonal solve).

The rod (engine.energies.axial) is linear along its axis, so one backward-Euler step is exactly one
solve of the tridiagonal system

    (M + dt^2 K) v+ = M v_n + dt f(x_n),     x+ = x_n + dt v+                                 (T1)

with K the stiffness k_j = E_j / h_j of each segment on its two nodes (a pinned node's row is
v = 0). The Thomas algorithm eliminates forward (c'_i = c_i / d_i, d'_i = (d_i - a_i d'_{i-1}) /
d_i with d_i = b_i - a_i c'_{i-1}) and substitutes backward (v_i = d'_i - c'_i v_{i+1}): O(n) work,
serial, inside the many-steps kernel so a whole run is one launch.
"""
import taichi as ti

from engine.energies.axial import axial_force


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
