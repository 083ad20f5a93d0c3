"""Bytes each timed kernel must move: the model behind the report's "fraction of the bandwidth
floor".

Model (compulsory traffic of the kernel's own data layout): every array the kernel touches is
counted once per pass over it, at its full size: read-only or write-only arrays once, arrays it
reads and writes (``f +=``) twice.  Arrays read through an index (x[j] of a neighbour) are counted
once, as if the caches kept every reused entry (the ideal case for a mesh numbered in rows).
Scalars are ``fb`` bytes (8 in f64, 4 in f32), indices 4 bytes.  The floor time is
bytes / (streaming-copy bandwidth); the fraction reported is floor time / measured time
(1 = at the floor).  Launch overheads, arithmetic and atomics are what keep kernels below it.

Sizes: n vertices, m springs (edges), h hinges.
"""

IB = 4  # index bytes (i32)


def _vec(fb):
    return 3 * fb


def kernel_bytes(kind: str, n: int, m: int = 0, h: int = 0, fb: int = 8) -> int:
    """Bytes for one call of the kernel ``kind`` (see the table in :data:`KERNELS`)."""
    v = _vec(fb)
    if kind == "zero":                 # f = 0
        return n * v
    if kind == "update":               # symplectic Euler: read x, v, f, 1/m; write x, v
        return n * (3 * v + fb + 2 * v)
    if kind == "spring_gather":        # x, CSR (offsets, other, 1/L, c/L per incidence), f +=
        return n * v + (n + 1) * IB + 2 * m * (IB + 2 * fb) + 2 * n * v
    if kind in ("spring_atomic", "spring_serial"):   # edges, L, c, x, f +=
        return m * (2 * IB + 2 * fb) + n * v + 2 * n * v
    if kind == "hinge_pass1":          # hinges, k, theta_bar, x; write (h, 4) vectors
        return h * (4 * IB + 2 * fb) + n * v + 4 * h * v
    if kind == "hinge_gather":         # (h, 4) vectors, offsets, entries, f +=
        return 4 * h * v + (n + 1) * IB + 4 * h * IB + 2 * n * v
    if kind == "bending_gather":       # the engine's two passes
        return kernel_bytes("hinge_pass1", n, m, h, fb) + kernel_bytes("hinge_gather", n, m, h, fb)
    if kind in ("bending_atomic", "bending_serial"):  # hinges, k, theta_bar, x, f +=
        return h * (4 * IB + 2 * fb) + n * v + 2 * n * v
    if kind == "explicit_step":        # engine symplectic Euler step: the kernels it launches
        total = kernel_bytes("zero", n, fb=fb) + kernel_bytes("spring_gather", n, m, fb=fb)
        if h:
            total += kernel_bytes("bending_gather", n, m, h, fb)
        return total + kernel_bytes("update", n, fb=fb)
    if kind == "cg_iteration":         # one fused PCG iteration (engine/solvers/, springs + hinges)
        return (n * 3 * v                                       # p = z + beta p
                + h * (12 * fb + 4 * IB + fb) + n * v           # s_h = w_h . p
                + n * (v + 2 * fb + 2 * IB + v)                 # q = a M p + K p + hinge terms
                + m * (2 * 2 * IB + 9 * fb) + h * (4 * IB + fb + 12 * fb)
                + n * (fb + 2 * v + v + 2 * v + v + 9 * fb + v))  # y, r, z, P^-1 update
    if kind == "implicit_setup":       # one backward-Euler step outside its CG loop (approximate):
        forces = kernel_bytes("explicit_step", n, m, h, fb) - kernel_bytes("update", n, fb=fb)
        spring_blocks = m * (2 * IB + 2 * fb + 9 * fb) + n * v
        hinge_blocks = h * (4 * IB + 2 * fb + 16 * 9 * fb) + n * v if h else 0
        hinge_factors = h * (8 * 9 * fb + 12 * fb) if h else 0
        precond = 3 * n * 9 * fb + (4 * h * 9 * fb * 2 + h * (4 * IB + 2 * fb) if h else 0) \
            + n * v + 2 * m * (IB + 2 * fb) + n * 9 * fb
        vectors = 12 * n * v                                    # x_n copy, residual, restart, finish
        return forces + spring_blocks + hinge_blocks + hinge_factors + precond + vectors
    if kind == "rod_explicit_step":    # engine.integrators.batched_steps.many_steps on the rod chain, symplectic Euler incl. the energies
        return 15 * n * fb
    if kind == "rod_implicit_step":    # Thomas algorithm step incl. the energies
        return 20 * n * fb
    if kind == "copy":                 # the probe itself: n scalars read and written
        return 2 * n * fb
    raise ValueError(f"no traffic model for kernel {kind!r}")


def implicit_step_bytes(n: int, m: int, h: int, iterations: int, fb: int = 8) -> int:
    """Backward-Euler step with the PCG solver: setup + iterations x one CG iteration."""
    return kernel_bytes("implicit_setup", n, m, h, fb) + int(iterations) * kernel_bytes("cg_iteration", n, m, h, fb)


def working_set_bytes(n: int, m: int = 0, h: int = 0, fb: int = 8) -> int:
    """Distinct bytes of the scene's arrays (positions, velocities, forces, masses, CSR, per-hinge
    data): decides whether the cache-resident or the DRAM copy bandwidth is the floor."""
    v = _vec(fb)
    return n * (3 * v + 2 * fb + 2 * IB) + m * (2 * IB + 2 * fb) + 2 * m * (2 * IB + 2 * fb) \
        + h * (8 * IB + 2 * fb + 4 * v)


KERNELS = {
    "zero": "f = 0 (one write pass)",
    "spring_gather": "engine spring forces: per-vertex gather over the CSR incidence",
    "spring_atomic": "springs, one parallel loop over edges, float atomics",
    "spring_serial": "springs, serialized loop over edges",
    "hinge_pass1": "engine bending pass 1: per-hinge force vectors",
    "hinge_gather": "engine bending pass 2: per-vertex gather",
    "bending_gather": "engine bending forces (pass 1 + gather)",
    "bending_atomic": "bending, one parallel loop over hinges, float atomics",
    "bending_serial": "bending, serialized loop over hinges",
    "update": "symplectic Euler update of x and v",
}
