"""The rod-waves exercise, solved: the reference the grader's tests run."""
import taichi as ti


@ti.func
def rod_force(x_left, x, x_right, h_left, h_right, E_left, E_right):
    strain_right = (x_right - x) / h_right - 1.0
    strain_left = (x - x_left) / h_left - 1.0
    return E_right * strain_right - E_left * strain_left
