"""The rod-waves lesson's exercise: the rod's force stencil (R1), one node at a time.

The student's stencil takes the place of the engine's in every kernel that steps the rod (the
many-steps kernel, the explicit updates and the backward-Euler Thomas solve), and is checked on
its own first against finite differences of the rod's energy.
"""
import numpy as np
import taichi as ti

from engine.energies import axial
from engine.fields import scalar_array
from .._exercise import TI_FUNC, Sampler, Task, agreement, central_difference, deviation, explain_failure, \
    substitute


def _force_call(func):
    """A kernel computing the student's stencil at every node of a rod (x, h, E) -> f (N)."""
    axial_force = _adapter(func)

    @ti.kernel
    def run(x: scalar_array, h: scalar_array, E: scalar_array, f: scalar_array):
        n = x.shape[0]
        for i in range(n):
            f[i] = axial_force(x, h, E, i, n)

    def call(x, h, E):
        f = np.zeros_like(x)
        run(np.ascontiguousarray(x), np.ascontiguousarray(h), np.ascontiguousarray(E), f)
        return f
    return call


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


def _rods(seed: int = 3, n: int = 24):
    """A rod of n nodes with segment lengths h from 1 mm to 1 m (each its own), stiffnesses E from
    0.1 to 1000 N and strains up to +-30%; and the same rod at rest."""
    s = Sampler(seed)
    h = s.log_uniform(n - 1, 1e-3, 1.0)
    E = s.log_uniform(n - 1, 0.1, 1e3)
    strain = s.uniform(n - 1, -0.3, 0.3)
    x = np.concatenate([[0.0], np.cumsum(h * (1 + strain))]) + s.uniform(1, -5.0, 5.0)
    rest = np.concatenate([[0.0], np.cumsum(h)])
    return x, rest, h, E


def _stencil(x, h, E, strain=lambda length, h: length / h - 1.0, swap_h="", swap_E=""):
    """The force at every node with a given strain formula, and each side's h or E taken from the
    other side (``swap_*``: "both", "right" or "left"; numpy: the mistakes the check names)."""
    n = len(x)
    hl, hr = np.ones(n), np.ones(n)
    El, Er = np.zeros(n), np.zeros(n)
    hl[1:], El[1:] = h, E
    hr[:-1], Er[:-1] = h, E
    xl = np.concatenate([[x[0]], x[:-1]])
    xr = np.concatenate([x[1:], [x[-1]]])
    hl, hr = (hr if swap_h in ("both", "left") else hl), (hl if swap_h in ("both", "right") else hr)
    El, Er = (Er if swap_E in ("both", "left") else El), (El if swap_E in ("both", "right") else Er)
    return Er * strain(xr - x, hr) - El * strain(x - xl, hl)


def _mean_h(h):
    """Each node's mean rest length of its segments (a free end's missing one counts as h = 1)."""
    hl = np.concatenate([[1.0], h])
    hr = np.concatenate([h, [1.0]])
    return 0.5 * (hl + hr)


def check_rod_force(student) -> list:
    x, rest, h, E = _rods()
    call = student.via(_force_call)
    got, at_rest = call(x, h, E), call(rest, h, E)
    ref = _stencil(x, h, E)
    scale = np.full(len(x), np.max(E))
    dev = deviation(got, ref, scale)
    tol = 1e-9
    reason = ""
    if not dev <= tol:
        k = int(np.argmax(np.abs(at_rest)))   # where the rod at rest is pulled hardest
        at_rest_text = (f"rod_force is not zero for the rod at rest (node {k}: {at_rest[k]:.3g} N)" +
                        (": at a free end the missing segment comes with E = 0 and h = 1 and must give no force"
                         if k in (0, len(x) - 1) else
                         ": a segment's strain is (its length)/h - 1 and its force E times that"))
        mistakes = [
            (_stencil(x, h, E, swap_h="both"), "divides each segment's length by the other segment's rest "
                                               "length: the right segment's strain is (x_right - x)/h_right - 1"),
            (_stencil(x, h, E, swap_h="right"), "divides the right segment's length by h_left: its strain is "
                                                "(x_right - x)/h_right - 1"),
            (_stencil(x, h, E, swap_h="left"), "divides the left segment's length by h_right: its strain is "
                                               "(x - x_left)/h_left - 1"),
            (_stencil(x, h, E, swap_E="both"), "takes each segment's stiffness from the other side: the right "
                                               "segment pulls with E_right, the left with E_left"),
            (_stencil(x, h, E, swap_E="right"), "gives the right segment the left one's stiffness: it pulls with "
                                                "E_right"),
            (_stencil(x, h, E, swap_E="left"), "gives the left segment the right one's stiffness: it pulls with "
                                               "E_left"),
            (_stencil(x, h, E, strain=lambda length, h: length - h), "uses the stretch (length - h) as the strain: "
                                                                      "it is length/h - 1, dimensionless"),
            (_stencil(x, h, E, strain=lambda length, h: (length - h) / h ** 2), "divides the stretch by h^2: the "
                                                                                 "strain is (length - h)/h"),
            (_stencil(x, h, E, strain=lambda length, h: length / h), "leaves out the -1: a segment at its rest "
                                                                      "length pulls with no force"),
            (_stencil(x, h, E) / _mean_h(h), "divides by the node's mean segment length: that is a force per "
                                             "length; the node's force is the difference of the two tensions"),
        ]
        reason = explain_failure(
            "rod_force", got, ref, tol, scale, of="-dW/dx of (R1)",
            where=lambda i: f"node {i}" + (" (a free end: E = 0, h = 1 there)" if i in (0, len(x) - 1) else ""),
            sign="it is +dW/dx; a stretched segment pulls its nodes together",
            mistakes=mistakes,
            after_mistakes=[(lambda: np.abs(at_rest).max() > 1e-9 * scale.max(), at_rest_text)],
            otherwise=lambda i: (f"rod_force is not -dW/dx: {got[i]:.6g} N instead of {ref[i]:.6g} N at node {i} of "
                                 f"{len(x)} (ends included)"))
    return [agreement(f"rod_force = -dW/dx of (R1), a random {len(x)}-node rod, h from 1 mm to 1 m (max deviation / "
                      f"max E)", "ex-rod-force", dev, tol, reason)]


def _energy_check(student) -> list:
    """The stencil is minus the gradient of the rod's energy (R1): finite differences of the
    engine's energy at a second rod, so that the formula above is not the only reference."""
    x, _, h, E = _rods(seed=4, n=12)

    def energy(xs):
        return np.array([axial.axial_energy_kernel(np.ascontiguousarray(row), h, E) for row in xs])
    ref = -central_difference(energy, x[None, :], 1e-7)[0]
    got = student.via(_force_call)(x, h, E)
    dev = deviation(got, ref)
    reason = "" if dev <= 1e-6 else f"rod_force is not minus the gradient of the rod's energy (deviation {dev:.2g})"
    return [agreement("rod_force = -dW/dx by finite differences of the energy, a random 12-node rod",
                      "ex-rod-force-gradient", dev, 1e-6, reason)]


def check_rod_forces(student) -> list:
    return check_rod_force(student) + _energy_check(student)


def install_rod_force(func) -> None:
    substitute(axial.axial_force, _adapter(func))


LABELS = {   # the equations this exercise cites, defined in its template (what, not how)
    "R1": "the force on node i along the rod: minus the derivative by x_i of the rod's energy, the sum over its "
          "segments of 1/2 E (l/h - 1)^2 h (l a segment's length, h its rest length)",
}

TASKS = [
    Task("rod_force", TI_FUNC, "x_left, x, x_right, h_left, h_right, E_left, E_right", """\
The force on one node of the rod along its axis (R1), in N (a float).

x_left, x, x_right: the positions along the axis of the node's left neighbour, the node and its
right neighbour (m); h_left, h_right: the rest lengths of the segments to the left and to the
right (m); E_left, E_right: those segments' stiffnesses (N, Young's modulus times the section).
Each segment's strain is its length over its rest length, minus 1; a segment pulls on its two
nodes with its stiffness times its strain. At the rod's free ends the missing segment comes
with E = 0 (and h = 1), so the same stencil serves every node.""", install_rod_force, check_rod_forces,
         (), "float"),
]
