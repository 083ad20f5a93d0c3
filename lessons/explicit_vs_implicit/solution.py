"""The explicit-vs-implicit exercise, solved: the reference the grader's tests run."""
import taichi as ti


@ti.func
def newton_residual(f, m, x, x_n, v_n, dt):
    return f - m * (x - x_n - dt * v_n) / (dt * dt)


def newton_coefficients(dt):
    return 1.0 / (dt * dt), 1.0


@ti.func
def step_velocity(x_new, x_n, dt):
    return (x_new - x_n) / dt
