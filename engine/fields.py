"""Taichi array types and the small per-vertex kernels that every engine module shares.

Kernel argument annotations are plain objects (creating them needs no ``ti.init``); the
ndarray constructors and kernels need :func:`engine.runtime.init` first. Every engine kernel
takes ``ti.ndarray`` arguments, so it compiles once for all sizes.

Conventions: a vec3 array has one entry per model vertex; ``inv_mass`` is 0 on pinned
vertices (they never move and carry no unknowns), so "free" reductions skip them.
"""
import numpy as np
import taichi as ti

from engine import constants, runtime
from engine.launch import kernel as fast_kernel

# -- kernel argument annotations -----------------------------------------------------------
vec3_array = ti.types.ndarray(dtype=ti.math.vec3, ndim=1)
vec3_array2 = ti.types.ndarray(dtype=ti.math.vec3, ndim=2)
mat3_array = ti.types.ndarray(dtype=ti.math.mat3, ndim=1)
mat3_array2 = ti.types.ndarray(dtype=ti.math.mat3, ndim=2)
mat2_array = ti.types.ndarray(dtype=ti.math.mat2, ndim=1)
scalar_array = ti.types.ndarray(ndim=1)
int_array = ti.types.ndarray(dtype=ti.i32, ndim=1)
int_array2 = ti.types.ndarray(dtype=ti.i32, ndim=2)
edge_array = ti.types.ndarray(dtype=ti.math.ivec2, ndim=1)


# -- set-up arrays (numpy) -------------------------------------------------------------------

def per_item(name: str, value, count: int) -> np.ndarray:
    """A float64 array of ``count`` values from a scalar or a (count,) array (a copy); ModelError
    (one line, naming ``name``) for any other shape."""
    from engine.errors import ModelError
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim == 0:
        return np.full(count, float(arr))
    if arr.shape != (count,):
        raise ModelError(f"{name} must be a scalar or have shape ({count},), got {arr.shape}")
    return arr.copy()


# -- ndarray constructors --------------------------------------------------------------------

def float_dtype() -> type:
    """The numpy float type matching Taichi's ``default_fp`` (f64 normally, f32 for benchmarks)."""
    info = runtime.current()
    if info is None:
        raise RuntimeError("Taichi is not initialised: call engine.runtime.init() before building a Model")
    return np.float64 if info.fp == 64 else np.float32


def vec3_ndarray(n: int, values: np.ndarray | None = None):
    """A ``ti.ndarray`` of ``n`` vec3 (default_fp), zero-filled or copied from ``values`` (n, 3)."""
    a = ti.ndarray(dtype=ti.math.vec3, shape=max(int(n), 1))
    if values is None:
        a.from_numpy(np.zeros((max(int(n), 1), 3), dtype=float_dtype()))
    else:
        a.from_numpy(np.ascontiguousarray(values, dtype=float_dtype()).reshape(-1, 3))
    return a


def scalar_ndarray(values: np.ndarray):
    """A ``ti.ndarray`` of default_fp scalars copied from ``values``."""
    values = np.ascontiguousarray(values, dtype=float_dtype()).reshape(-1)
    a = ti.ndarray(dtype=float, shape=max(values.size, 1))
    if values.size:
        a.from_numpy(values)
    return a


def int_ndarray(values: np.ndarray):
    """A ``ti.ndarray`` of i32 copied from ``values`` (any shape; an empty array becomes one zero)."""
    values = np.ascontiguousarray(values, dtype=np.int32)
    shape = values.shape if values.size else (1,) + values.shape[1:]
    a = ti.ndarray(dtype=ti.i32, shape=shape if len(shape) > 1 else shape[0])
    if values.size:
        a.from_numpy(values)
    return a


def vec3_argument(a, n: int, scratch: dict, slot: str, error: type, owner: str):
    """``a`` as a vec3 ndarray of ``n`` entries, for an energy's methods that take numpy arrays too: a
    numpy array (n vec3, any shape) is copied into ``scratch[slot]`` (allocated on first use, reused
    after) and that buffer returned; anything else (an ndarray) is returned as it is. A numpy array
    of another length raises ``error``: "<slot> has <len> vertices, <owner> has <n>"."""
    if isinstance(a, np.ndarray):
        a = np.asarray(a, dtype=np.float64).reshape(-1, 3)
        if len(a) != n:
            raise error(f"{slot} has {len(a)} vertices, {owner} has {n}")
        buf = scratch.get(slot)
        if buf is None:
            buf = scratch[slot] = vec3_ndarray(n)
        buf.from_numpy(a.astype(float_dtype()))
        return buf
    return a


class WorkArrays:
    """Named vec3 work arrays of ``n`` entries, allocated on first use and owned by whoever holds
    this object (a :class:`engine.integrators.stepper.Stepper`, a linear solver's set-up, one static
    solve): nothing is kept per model behind the caller's back."""

    def __init__(self, n: int):
        self.n = int(n)
        self._arrays: dict = {}

    def vec3(self, name: str):
        a = self._arrays.get(name)
        if a is None:
            a = self._arrays[name] = vec3_ndarray(self.n)
        return a


# -- small per-vertex kernels ------------------------------------------------------------------

def serial_pass(n: int) -> bool:
    """Whether a light per-vertex pass over ``n`` vertices runs serialized (the launching thread
    alone) rather than on the thread pool: below engine.constants.VERTEX_PASS_SERIAL_BELOW, where
    the pool's hand-over costs more than the pass. A kernel takes it as a template argument
    (``ti.loop_config(serialize=serial)``); a per-vertex pass gives the same bits either way."""
    return int(n) < constants.VERTEX_PASS_SERIAL_BELOW


@ti.kernel
def zero_vec3(a: vec3_array):
    for i in range(a.shape[0]):
        a[i] = ti.math.vec3(0.0)


@fast_kernel
def _copy_vec3(src: vec3_array, dst: vec3_array, serial: ti.template()):
    ti.loop_config(serialize=serial)
    for i in range(src.shape[0]):
        dst[i] = src[i]


def copy_vec3(src, dst) -> None:
    """dst = src (one vertex per iteration; serialized below VERTEX_PASS_SERIAL_BELOW vertices)."""
    _copy_vec3(src, dst, serial_pass(src.shape[0]))


@ti.kernel
def scale_vec3(u: vec3_array, scale: float):
    for i in range(u.shape[0]):
        u[i] *= scale


@fast_kernel
def axpy_into(x: vec3_array, dx: vec3_array, s: float, out: vec3_array):
    # out = x + s dx
    for i in range(x.shape[0]):
        out[i] = x[i] + s * dx[i]


@fast_kernel
def _axpy_inplace(q: vec3_array, t: vec3_array, s: float, serial: ti.template()):
    ti.loop_config(serialize=serial)
    for i in range(q.shape[0]):
        q[i] += s * t[i]


def axpy_inplace(q, t, s: float) -> None:
    """q += s t (serialized below VERTEX_PASS_SERIAL_BELOW vertices)."""
    _axpy_inplace(q, t, float(s), serial_pass(q.shape[0]))


@ti.kernel
def sub_into(a: vec3_array, b: vec3_array, out: vec3_array):
    # out = a - b
    for i in range(a.shape[0]):
        out[i] = a[i] - b[i]


@fast_kernel
def dot_vec3(a: vec3_array, b: vec3_array) -> float:
    # sum_i a_i . b_i over every vertex
    s = 0.0
    for i in range(a.shape[0]):
        s += a[i].dot(b[i])
    return s


@ti.kernel
def free_dot(u: vec3_array, w: vec3_array, inv_mass: scalar_array, serial: ti.template()) -> float:
    # sum over free vertices of u_i . w_i
    s = 0.0
    ti.loop_config(serialize=serial)
    for i in range(u.shape[0]):
        if inv_mass[i] > 0.0:
            s += u[i].dot(w[i])
    return s


@ti.kernel
def mass_dot(a: vec3_array, b: vec3_array, mass: scalar_array, inv_mass: scalar_array) -> float:
    # sum over free vertices of m_i a_i . b_i
    s = 0.0
    for i in range(a.shape[0]):
        if inv_mass[i] > 0.0:
            s += mass[i] * a[i].dot(b[i])
    return s


@ti.kernel
def zero_pinned(a: vec3_array, inv_mass: scalar_array):
    for i in range(a.shape[0]):
        if inv_mass[i] == 0.0:
            a[i] = ti.math.vec3(0.0)
