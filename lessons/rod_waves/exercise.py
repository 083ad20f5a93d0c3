"""The rod-waves lesson's exercise: the rod's force stencil (R1), one node at a time.

The student's stencil takes the place of the engine's in every kernel that steps the rod (the
many-steps kernel, the explicit updates and the backward-Euler Thomas solve), and is checked on
its own first against finite differences of the rod's energy.
"""
import numpy as np
import taichi as ti

from engine.energies import axial
from engine.fields import scalar_array
from .._exercise import TI_FUNC, Sampler, Task, call_student, agreement, central_difference, deviation, \
    factor_text, first_bad, ratio, substitute


def _force_call(axial_force):
    @ti.kernel
    def run(x: scalar_array, h: scalar_array, E: scalar_array, f: scalar_array):
        n = x.shape[0]
        for i in range(n):
            f[i] = axial_force(x, h, E, i, n)
    return run


def _adapter(func):
    """engine.energies.axial.axial_force's signature around the student's stencil: a missing
    neighbour (the rod's free ends) is a segment of zero stiffness."""
    @ti.func
    def axial_force(x: ti.template(), h: ti.template(), E: ti.template(), i: int, n: int) -> float:
        x_left, x_right = x[i], x[i]
        h_left, h_right, E_left, E_right = 1.0, 1.0, 0.0, 0.0
        if i > 0:
            x_left, h_left, E_left = x[i - 1], h[i - 1], E[i - 1]
        if i < n - 1:
            x_right, h_right, E_right = x[i + 1], h[i], E[i]
        return func(x_left, x[i], x_right, h_left, h_right, E_left, E_right)
    return axial_force


def _rods(seed: int = 3):
    """A rod of 16 nodes with random segment lengths h (m), stiffnesses E (N) and strains up to
    +-30%; and the same rod at rest."""
    s = Sampler(seed)
    h = s.uniform(15, 0.05, 0.2)
    E = s.uniform(15, 1.0, 10.0)
    strain = s.uniform(15, -0.3, 0.3)
    x = np.concatenate([[0.0], np.cumsum(h * (1 + strain))])
    rest = np.concatenate([[0.0], np.cumsum(h)])
    return x, rest, h, E


def check_rod_force(func) -> list:
    x, rest, h, E = _rods()
    run = _force_call(_adapter(func))
    got, at_rest = np.zeros_like(x), np.zeros_like(x)
    call_student("rod_force", run, x, h, E, got)
    call_student("rod_force", run, rest, h, E, at_rest)

    def energy(xs):
        return np.array([axial.axial_energy_kernel(np.ascontiguousarray(row), h, E) for row in xs])
    ref = -central_difference(lambda xs: energy(xs), x[None, :], 1e-7)[0]
    dev = deviation(got, ref)
    tol = 1e-6
    reason = ""
    if not dev <= tol:
        i = first_bad(got, ref, tol)
        r = factor_text(ratio(got, ref))
        if not np.all(np.isfinite(got)):
            reason = f"rod_force returns NaN or inf at node {i}"
        elif np.abs(at_rest).max() > 1e-9 * np.abs(ref).max():
            reason = ("rod_force is not zero for the rod at rest: a segment's strain is (its length)/h - 1; "
                      "is the rest length used (the -1)?")
        elif r == "minus":
            reason = "rod_force has the wrong sign: it is +dW/dx; a stretched segment pulls its nodes together"
        elif r:
            reason = f"rod_force is {r} -dW/dx of (R1)"
        else:
            reason = f"force is not -dW/dx: FD error {dev:.2g} at node {i} of 16 (ends included)"
    return [agreement("rod_force = -dW/dx of (R1) by finite differences, a random 16-node rod (max rel. dev.)",
                      "ex-rod-force", dev, tol, reason)]


def install_rod_force(func) -> None:
    substitute(axial.axial_force, _adapter(func))


TASKS = [
    Task("rod_force", TI_FUNC, "x_left, x, x_right, h_left, h_right, E_left, E_right", """\
The force on one node of the rod along its axis (R1), in N (a float).

x_left, x, x_right: the positions along the axis of the node's left neighbour, the node and its
right neighbour (m); h_left, h_right: the rest lengths of the segments to the left and to the
right (m); E_left, E_right: those segments' stiffnesses (N, Young's modulus times the section).
Each segment's strain is its length over its rest length, minus 1; a segment pulls on its two
nodes with its stiffness times its strain. At the rod's free ends the missing segment comes
with E = 0 (and h = 1), so the same stencil serves every node.""", install_rod_force, check_rod_force,
         (), "float"),
]
