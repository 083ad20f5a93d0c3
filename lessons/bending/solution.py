"""The bending exercise, solved: the reference the grader's tests run."""
import taichi as ti


@ti.func
def dihedral_angle(e, a0, a1):
    N0 = e.cross(a0)
    N1 = a1.cross(e)
    sine = (e / e.norm()).dot(N0.cross(N1))
    return ti.atan2(sine, N0.dot(N1))


@ti.func
def dihedral_angle_gradient(e, a0, a1):
    s = e.norm()
    N0 = e.cross(a0)
    N1 = a1.cross(e)
    g_w0 = -s * N0 / N0.norm_sqr()
    g_w1 = -s * N1 / N1.norm_sqr()
    t0 = a0.dot(e) / (s * s)
    t1 = a1.dot(e) / (s * s)
    g_v1 = -t0 * g_w0 - t1 * g_w1
    g_v0 = -(1.0 - t0) * g_w0 - (1.0 - t1) * g_w1
    return g_v0, g_v1, g_w0, g_w1
