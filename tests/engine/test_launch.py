"""engine.launch.FastKernel: a call that repeats an earlier call's array objects is launched
directly; it must be the same launch as Taichi's own call (the same bits), see what the arrays hold
now (numpy arrays by address, not a copy taken when first seen), and never reuse a compiled
instance or an address for a call that differs: a new array (also one at a freed array's address),
another template value, a resized or reshaped numpy array, a scalar of another type. A wrong
argument still gets Taichi's own error."""
import gc

import numpy as np
import pytest
import taichi as ti

from engine import launch
from engine.fields import vec3_ndarray
from engine.launch import FastKernel, kernel
from engine.scenes import cloth

f64_flat = ti.types.ndarray(dtype=ti.f64, ndim=1)


@kernel
def _axpy_sum(x: f64_flat, y: f64_flat, a: ti.f64, n: ti.i32) -> ti.f64:
    """y[:n] += a x[:n]; returns the sum of y (a float return)."""
    for i in range(n):
        y[i] = y[i] + a * x[i]
    s = 0.0
    ti.loop_config(serialize=True)
    for i in range(y.shape[0]):
        s += y[i]
    return s


@kernel
def _scaled(x: f64_flat, out: f64_flat, how: ti.template()) -> ti.i32:
    """out = how * x (a template value picks the compiled instance); returns how (an int return)."""
    for i in range(x.shape[0]):
        out[i] = how * x[i]
    return how


@kernel
def _vec_copy(src: ti.types.ndarray(dtype=ti.math.vec3, ndim=1), dst: ti.types.ndarray(dtype=ti.math.vec3, ndim=1)):
    for i in range(src.shape[0]):
        dst[i] = src[i]


def _direct(fast: FastKernel, args) -> bool:
    """Whether this call of ``fast`` would be launched directly (it repeats a remembered call)."""
    return fast.remembered(args) is not None


def test_the_second_call_is_direct_and_sees_the_arrays_now():
    x, y = np.arange(5.0), np.zeros(5)
    assert not _direct(_axpy_sum, (x, y, 2.0, 5))
    assert _axpy_sum(x, y, 2.0, 5) == 20.0
    assert _direct(_axpy_sum, (x, y, 0.5, 3)), "the same arrays with other scalars of the same types"
    x[:] = 1.0   # written in place: the direct launch reads the array's memory, not a copy
    assert _axpy_sum(x, y, 0.5, 3) == 21.5
    assert np.array_equal(y, [0.5, 2.5, 4.5, 6.0, 8.0])


def test_a_scalar_of_another_type_goes_through_taichi():
    x, y = np.ones(4), np.zeros(4)
    _axpy_sum(x, y, 1.0, 4)
    assert _axpy_sum(x, y, 1, 4) == 8.0          # an int where a float is declared: Taichi converts it
    with pytest.raises(Exception, match=r"(?i)argument|type"):
        _axpy_sum(x, y, 1.0, 4.0)                # a float where an int is declared: Taichi refuses it
    assert _axpy_sum(x, y, 1.0, 4) == 12.0


def test_a_wrong_array_still_gets_taichis_error():
    x, y = np.ones(4), np.zeros(4)
    _axpy_sum(x, y, 1.0, 4)
    with pytest.raises(Exception, match=r"(?i)f32|float32|dtype|type"):
        _axpy_sum(np.ones(4, dtype=np.float32), y, 1.0, 4)
    with pytest.raises(ValueError, match="(?i)contiguous"):
        _axpy_sum(np.ones(8)[::2], y, 1.0, 4)


def test_template_values_are_not_mixed_up():
    x, out = np.arange(3.0), np.zeros(3)
    for how in (2, 3, 2, 3, True):
        assert _scaled(x, out, how) == int(how)
        assert np.array_equal(out, int(how) * x)


def test_a_new_array_at_a_freed_arrays_address_is_a_new_call(monkeypatch):
    """Weak references: a remembered array may be freed (a ti.ndarray's memory with it), and Python
    may place a new array at its object address, so that the new call's key (array identities) is the
    freed call's. Made certain here by giving every call the first call's key: the new arrays must
    still be launched with their own memory and length."""
    fast = FastKernel(_vec_copy.kernel)
    first = None
    for n in (3, 5, 4, 6, 2):
        src, dst = vec3_ndarray(n, np.full((n, 3), float(n))), vec3_ndarray(n)
        if first is None:
            first = fast._key((src, dst))
            monkeypatch.setattr(fast, "_key", lambda args: first)
        else:
            assert fast.remembered((src, dst)) is None   # the key matches, the dead references do not
        fast(src, dst)
        assert np.array_equal(dst.to_numpy(), np.full((n, 3), float(n)))
        del src, dst
        gc.collect()


def test_a_numpy_array_reshaped_in_place_is_a_new_call():
    """numpy cannot resize an array a weak reference points to (so a remembered buffer cannot move),
    but its shape can be set in place: a call after that is Taichi's, with Taichi's checks."""
    x, y = np.ones(6), np.zeros(6)
    _axpy_sum(x, y, 1.0, 6)
    x.shape = (6,)          # the same shape: still direct
    assert _direct(_axpy_sum, (x, y, 1.0, 6))
    with pytest.raises(ValueError, match="(?i)resize"):
        y.resize(3, refcheck=False)
    y.shape = (2, 3)
    assert not _direct(_axpy_sum, (x, y, 1.0, 6))   # the same objects, but y's shape is not the remembered one
    with pytest.raises(Exception, match=r"(?i)dim|shape"):
        _axpy_sum(x, y, 1.0, 6)


def test_element_shaped_arrays_numpy_and_taichi():
    """vec3 arguments: a (n, 3) numpy array passes its n as the array shape; ti.ndarrays likewise."""
    src = np.arange(12.0).reshape(4, 3)
    dst = vec3_ndarray(4)
    for _ in range(3):
        _vec_copy(src, dst)
        assert np.array_equal(dst.to_numpy(), src)
        src += 1.0
    back = np.zeros((4, 3))
    for _ in range(2):
        _vec_copy(dst, back)
    assert np.array_equal(back, dst.to_numpy())


def test_at_most_slots_calls_are_remembered():
    arrays = [(np.ones(2), np.zeros(2)) for _ in range(FastKernel.SLOTS + 2)]
    for x, y in arrays:
        _axpy_sum(x, y, 1.0, 2)
    assert len(_axpy_sum._slots) == FastKernel.SLOTS
    assert _direct(_axpy_sum, (*arrays[-1], 1.0, 2)) and not _direct(_axpy_sum, (*arrays[0], 1.0, 2))


def test_backward_euler_steps_are_the_same_bits_either_way(monkeypatch):
    """The implicit step's kernels (forces, assembly, PARDISO's right-hand side and solution, the
    update) launched directly or through Taichi's own call: the same states."""
    from engine.integrators import Stepper
    from engine.integrators.implicit import BackwardEuler
    from engine.solvers import pardiso_available

    def steps():
        model = cloth(12, B=1e-3).model
        st = model.make_state(None, 0.02 * np.random.default_rng(5).standard_normal((model.n, 3)))
        Stepper(model, BackwardEuler("pardiso" if pardiso_available() else "cholesky", tol=1e-8)).step(st, 1 / 60, 4)
        return st.numpy()
    a = steps()
    monkeypatch.setattr(launch, "DIRECT_LAUNCH", False)
    b = steps()
    assert np.array_equal(a.x, b.x) and np.array_equal(a.v, b.v)


@kernel
def _shift(x: ti.types.ndarray(dtype=ti.math.vec3, ndim=1), d: ti.math.vec3):
    for i in range(x.shape[0]):
        x[i] = x[i] + d


def test_an_argument_kind_not_launched_directly_always_goes_through_taichi():
    """A vector argument: remembered as a call for Taichi's own launch, and every call is still right."""
    x = np.zeros((3, 3))
    for k in range(1, 4):
        _shift(x, ti.math.vec3(1.0, 2.0, 3.0))
        assert np.array_equal(x, k * np.tile([1.0, 2.0, 3.0], (3, 1)))
    assert _shift._slots and _shift._slots[0][3] is None
