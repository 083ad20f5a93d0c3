"""The lumped masses' own energies, written once for every kernel that sums them.

    kinetic energy     T   = sum_i 1/2 m_i |v_i|^2                     (all vertices)
    gravity potential  W_g = -sum_{free i} m_i g . x_i                 (free: inverse mass > 0)

Pinned vertices (inverse mass 0) have v = 0 and take no part in W_g (they never move). The sums
run over the vertices in index order: inside a serial loop (the many-steps kernels) that order is
the order of the additions; at a kernel's outermost level the loop is Taichi's parallel reduction
(engine.diagnostics, engine.model), correct to rounding, not bitwise reproducible across thread
counts.
"""
import taichi as ti


def _is_vector(value) -> bool:
    """Compile time: whether a Taichi value is a vector (a 3D velocity), not a scalar."""
    return value.is_tensor() if hasattr(value, "is_tensor") else isinstance(value, ti.Matrix)


@ti.func
def kinetic_energy(v: ti.template(), mass: ti.template()):
    """T = sum_i 1/2 m_i |v_i|^2 (J) for velocities v (m/s: vec3 per vertex, or a scalar per node for
    the rod along its axis) and lumped masses ``mass`` (kg)."""
    T = 0.0
    for i in range(v.shape[0]):
        vi = v[i]
        if ti.static(_is_vector(vi)):
            T += 0.5 * mass[i] * vi.dot(vi)
        else:
            T += 0.5 * mass[i] * vi * vi
    return T


@ti.func
def add_gravity_potential(W, x: ti.template(), mass: ti.template(), inv_mass: ti.template(), g):
    """W + W_g (J): W_g = -sum_{free i} m_i g . x_i for positions x (m), masses ``mass`` (kg),
    inverse masses ``inv_mass`` (1/kg, 0 = pinned) and gravity g (m/s^2, vec3). The terms are
    subtracted from W one by one in vertex order, so a caller's running sum (W the other energies,
    or 0.0) keeps its order of operations."""
    acc = W
    for i in range(x.shape[0]):
        if inv_mass[i] > 0.0:
            acc -= mass[i] * g.dot(x[i])
    return acc


@ti.func
def finish_force(f_i, m, inv_m, g):
    """A vertex's whole force from its elastic force f_i (N): f_i + m g for a free vertex (the weight,
    -dW_g/dx_i), 0 for a pinned one (inverse mass 0)."""
    out = ti.math.vec3(0.0)
    if inv_m > 0.0:
        out = f_i + m * g
    return out
