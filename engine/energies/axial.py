"""The rod's spring energy along its axis, in scalar arrays (one coordinate per node).

The notes' 1D rod is a chain of springs c_j = E_j h_j whose nodes move along the chain's axis only;
there the 3D spring energy (S1) and force (S2) reduce exactly to

    W = sum_j 1/2 E_j ((x_{j+1} - x_j)/h_j - 1)^2 h_j,    f_i = E_i s_i - E_{i-1} s_{i-1}       (R1)

(s_j the segment strain) for every state without an inverted segment. Stepping the rod in one
coordinate instead of three costs a third of the memory traffic and no square roots, which is
what makes a run of many steps per launch cheap (engine.integrators.batched_steps.axial_steps).
"""
import taichi as ti

from engine.fields import scalar_array


@ti.func
def strain(x: ti.template(), h: ti.template(), j: int) -> float:
    return (x[j + 1] - x[j]) / h[j] - 1.0


@ti.func
def axial_force(x: ti.template(), h: ti.template(), E: ti.template(), i: int, n: int) -> float:
    # f_i = E_i s_i - E_{i-1} s_{i-1}  (minus the gradient of W)   (R1)
    f = 0.0
    if i < n - 1:
        f += E[i] * strain(x, h, i)
    if i > 0:
        f -= E[i - 1] * strain(x, h, i - 1)
    return f


@ti.func
def axial_potential(x: ti.template(), h: ti.template(), E: ti.template(), n: int) -> float:
    # W of (R1), a serial sum
    W = 0.0
    for j in range(n - 1):
        s = strain(x, h, j)
        W += 0.5 * E[j] * s * s * h[j]
    return W


@ti.kernel
def axial_energy_kernel(x: scalar_array, h: scalar_array, E: scalar_array) -> float:
    """W(x) of (R1) (serial sum: deterministic)."""
    W = 0.0
    ti.loop_config(serialize=True)
    for _ in range(1):
        W = axial_potential(x, h, E, x.shape[0])
    return W


@ti.kernel
def axial_forces_kernel(x: scalar_array, h: scalar_array, E: scalar_array, f: scalar_array):
    """f = -dW/dx at every node."""
    n = x.shape[0]
    for i in range(n):
        f[i] = axial_force(x, h, E, i, n)
