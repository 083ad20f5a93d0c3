"""Peers of the engine: what a user could install with pip and write instead.

The implicit step's linear solvers are in :mod:`bench.peers.sparse`.  The explicit cloth step:

* :mod:`bench.peers.numba_cloth` - :class:`~bench.peers.numba_cloth.NumbaCloth`, ``numba.njit(parallel=True)``
  kernels with ``prange`` (``ELASTIC_THREADS`` threads, default 2);
* :mod:`bench.peers.warp_cloth` - :class:`~bench.peers.warp_cloth.WarpCloth`, ``warp`` kernels on
  ``device="cpu"`` (one thread: Warp's CPU backend runs a launch serially).

Both compute the cloth of :func:`engine.scenes.cloth` exactly as the engine does (area springs,
W_e = 1/2 c_e (l/L - 1)^2, and the notes' dihedral bending W_e = 1/2 k_e (theta - theta_bar)^2 with
the engine's angle and gradient formulas), as one symplectic-Euler step made of the same three
passes as the engine's one-launch step: per hinge, the four force vectors; per vertex, a gather over
a CSR incidence (springs, then hinges) and the kick; per vertex, the drift.  No atomics: the results
are deterministic.  bench/test_peers_explicit.py checks them against the engine.

The packages are optional (``pip install -e '.[dev,peers]'``); nothing here imports them until a
peer is built.  :func:`missing` says which one is absent.
"""
import importlib.util

PACKAGES = {"numba": "numba", "warp": "warp"}


def missing(name: str) -> str | None:
    """None when the package behind peer ``name`` ("numba" or "warp") can be imported, else a
    one-line reason naming it and how to install it."""
    module = PACKAGES[name]
    try:
        spec = importlib.util.find_spec(module)
    except (ImportError, ValueError):
        spec = None
    if spec is None:
        pip = "warp-lang" if name == "warp" else "numba"
        return f"{module} is not installed (pip install {pip}, or pip install -e '.[dev,peers]')"
    return None


def require(name: str):
    """Import and return the package behind peer ``name``; ImportError with :func:`missing`'s line."""
    why = missing(name)
    if why is not None:
        raise ImportError(why)
    return importlib.import_module(PACKAGES[name])


def threads_from_env(upper: int, default: int = 2) -> int:
    """The thread count from ``ELASTIC_THREADS`` (default ``default``, capped at ``upper``); ValueError
    (one line, naming the variable and the valid range) for anything but an integer in 1..upper."""
    import os
    raw = os.environ.get("ELASTIC_THREADS", "").strip()
    if not raw:
        return max(1, min(int(default), int(upper)))
    try:
        n = int(raw)
    except ValueError:
        n = 0
    if not 1 <= n <= upper:
        raise ValueError(f"ELASTIC_THREADS must be an integer in 1..{upper} (got {raw!r})")
    return n


def csr(n: int, vertex_of_entry, payload):
    """A CSR incidence: (offsets (n+1,) int32, payload sorted by vertex); the sort is stable, so each
    vertex keeps its entries in input order."""
    import numpy as np
    order = np.argsort(vertex_of_entry, kind="stable")
    offsets = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(vertex_of_entry, minlength=n), out=offsets[1:])
    return offsets.astype(np.int32), payload[order]


def cloth_arrays(model, springs, bending, dtype) -> dict:
    """The numpy arrays both peers step with, built once from the engine's scene (its rest data only):
    per-vertex ``mass``, ``inv_mass`` (0 on pinned vertices) and gravity ``g``; the springs' CSR
    incidence ``offsets``, ``inc_other``, ``inc_inv_L`` (1/L_e) and ``inc_c_over_L`` (c_e/L_e) - every
    edge at both of its ends; the hinges ``hinges`` (h, 4) [v0, v1, w0, w1], ``k``, ``theta_bar`` and
    their CSR incidence ``h_offsets``, ``h_entries`` (entry = 4 hinge + slot); ``with_hinges``.
    Integers are int32 (as the engine's), floats ``dtype``."""
    import numpy as np
    dtype = np.dtype(dtype)
    if dtype not in (np.float64, np.float32):
        raise ValueError(f"dtype must be float64 or float32 (got {dtype})")
    if bending is not None and bending.variant != "notes":
        raise ValueError(f"bending variant must be 'notes' (got {bending.variant!r}): the peers implement the "
                         f"notes' energy only")
    n = int(model.n)
    pinned = np.asarray(model.pinned, dtype=bool)
    mass = np.asarray(model.mass, dtype=np.float64)
    out = dict(n=n, dtype=dtype, mass=mass.astype(dtype),
               inv_mass=np.where(pinned, 0.0, 1.0 / np.where(mass > 0, mass, 1.0)).astype(dtype),
               g=np.asarray(model.gravity, dtype=np.float64).astype(dtype))
    E = np.asarray(springs.edges_np, dtype=np.int64)
    L = np.asarray(springs.L_np, dtype=np.float64)
    c = np.asarray(springs.c_np, dtype=np.float64)
    m = len(E)
    ends = np.concatenate([E[:, 0], E[:, 1]])
    pair = np.stack([np.concatenate([E[:, 1], E[:, 0]]), np.concatenate([np.arange(m), np.arange(m)])], axis=1)
    out["offsets"], pair = csr(n, ends, pair)
    out["inc_other"] = np.ascontiguousarray(pair[:, 0], dtype=np.int32)
    out["inc_inv_L"] = (1.0 / L)[pair[:, 1]].astype(dtype)
    out["inc_c_over_L"] = (c / L)[pair[:, 1]].astype(dtype)
    with_hinges = bending is not None and bending.n_hinges > 0
    out["with_hinges"] = with_hinges
    if with_hinges:
        H = np.ascontiguousarray(bending.hinges_np, dtype=np.int32)
        out["hinges"] = H
        out["k"] = np.asarray(bending.k, dtype=np.float64).astype(dtype)
        out["theta_bar"] = np.asarray(bending.theta_bar, dtype=np.float64).astype(dtype)
        flat = H.reshape(-1).astype(np.int64)
        out["h_offsets"], entries = csr(n, flat, np.arange(len(flat), dtype=np.int64))
        out["h_entries"] = entries.astype(np.int32)
    else:  # placeholders of the right types, never read
        out["hinges"] = np.zeros((0, 4), dtype=np.int32)
        out["k"] = np.zeros(0, dtype=dtype)
        out["theta_bar"] = np.zeros(0, dtype=dtype)
        out["h_offsets"] = np.zeros(n + 1, dtype=np.int32)
        out["h_entries"] = np.zeros(0, dtype=np.int32)
    out["n_hinges"] = len(out["hinges"])
    return out


def check_step_args(n: int, x, v, dt, n_steps):
    """Validate a peer's step(x, v, dt, n_steps); returns (dt, n_steps).  ValueError (one line,
    naming the argument) otherwise."""
    import math
    for name, a in (("x", x), ("v", v)):
        if tuple(getattr(a, "shape", ())) != (n, 3):
            raise ValueError(f"{name} must have shape ({n}, 3) (got {getattr(a, 'shape', None)})")
    dt = float(dt)
    if not (math.isfinite(dt) and dt > 0.0):
        raise ValueError(f"dt must be finite and > 0 (got {dt!r})")
    n_steps = int(n_steps)
    if n_steps < 0:
        raise ValueError(f"n_steps must be >= 0 (got {n_steps})")
    return dt, n_steps


def explicit_peer(name: str, c, bending: bool, dtype):
    """The explicit peer ``name`` ("numba" or "warp") for the cloth scene ``c`` (with or without its
    bending) in ``dtype``."""
    if name == "numba":
        from bench.peers.numba_cloth import NumbaCloth
        return NumbaCloth(c.model, c.springs, c.bending if bending else None, dtype=dtype)
    if name == "warp":
        from bench.peers.warp_cloth import WarpCloth
        return WarpCloth(c.model, c.springs, c.bending if bending else None, dtype=dtype)
    raise ValueError(f"unknown explicit peer {name!r}; valid: {', '.join(PACKAGES)}")
