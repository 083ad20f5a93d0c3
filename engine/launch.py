"""Launching a Taichi kernel without Taichi's per-call Python work, where the arguments repeat.

Taichi 1.7.4's kernel call spends Python time on every call mapping each argument's type to a
compiled instance and checking it: about 5-20 us per array argument, 0.1-0.3 ms for a kernel of
16 ndarrays, more than the arithmetic of a 64 x 64 cloth step. Two ways around it, both launching
the same compiled instance on the same arguments with the calls Taichi's own call makes for these
argument kinds (the same machine code, the same bits: tested):

- :class:`BoundKernel` (the explicit steps' fused kernels): ``bound(*head)`` = ``kernel(*head,
  *tail, *templates)``, the tail and templates fixed when it is made;
- :class:`FastKernel` / :func:`kernel` (the kernels of an implicit step, each called once or
  twice a step with the same arrays): ``fast(*args)`` is ``kernel(*args)``; a call whose array
  arguments are the same objects as an earlier successful call's (its last few, kept by weak
  reference), with scalars of the same Python types and the same template values, reuses that
  call's compiled instance; any other call is Taichi's own, which checks every argument.

Argument kinds launched directly: ti.ndarray without gradient, numpy C-contiguous arrays (as
Taichi passes them on the CPU: by address, no copy), ints and floats; a kernel with any other
argument (a matrix, a struct, a sparse-matrix builder), keyword arguments, an autodiff tape or a
print goes through Taichi's call every time. Returns: nothing or one int or float. With Taichi
other than 1.7.4, or with DIRECT_LAUNCH False, every call is Taichi's own call.
"""
import weakref

import numpy as np
import taichi as ti
from taichi.lang import impl
from taichi.lang.enums import Layout
from taichi.lang.util import cook_dtype
from taichi.types import ndarray_type, primitive_types
from taichi.types.utils import is_signed

DIRECT_LAUNCH = True  # False: every BoundKernel / FastKernel call goes through Taichi's own kernel call
TAICHI_174 = tuple(ti.__version__) == (1, 7, 4)

_NDARRAY, _EXT, _INT, _UINT, _FLOAT = range(5)


def _primal(kernel):
    prim = getattr(kernel, "_primal", None)
    return prim if (prim is not None and TAICHI_174) else None


def _annotations(prim) -> list:
    return [a.annotation for a in prim.arguments]


def _kind(needed, value):
    """How Taichi 1.7.4's launch sets an argument of annotation ``needed`` (``_NDARRAY`` ...), or None
    for a kind this module does not launch (and ``False`` for a template: not a launch argument)."""
    if isinstance(needed, ti.template):
        return False
    if id(needed) in primitive_types.real_type_ids:
        return _FLOAT if isinstance(value, (float, int, np.floating, np.integer)) else None
    if id(needed) in primitive_types.integer_type_ids:
        if not isinstance(value, (int, np.integer)) or isinstance(value, (bool, np.bool_)):
            return None
        return _INT if is_signed(cook_dtype(needed)) else _UINT
    if isinstance(needed, ndarray_type.NdarrayType):
        if isinstance(value, ti.Ndarray):
            return _NDARRAY if value.grad is None else None
        if isinstance(value, np.ndarray) and value.flags.c_contiguous:
            return _EXT
    return None


def _ext_shape(needed, a: np.ndarray) -> tuple:
    """The array shape Taichi passes for numpy array ``a`` (its element dimensions stripped)."""
    if needed.dtype is None or id(needed.dtype) in primitive_types.type_ids:
        return tuple(a.shape)
    d = needed.dtype.ndim
    return tuple(a.shape[d:]) if needed.layout == Layout.SOA else tuple(a.shape[:-d])


def _returns(prim):
    """(has_ret, getter name) for a kernel returning nothing or one int / float; None otherwise."""
    ret = prim.return_type
    if ret is None:
        return False, None
    if len(ret) == 1:
        r = ret[0] if ret[0] not in (int, float) else (ti.i32 if ret[0] is int else ti.f64)
        if r in primitive_types.integer_types:
            return True, "get_struct_ret_int" if is_signed(cook_dtype(r)) else "get_struct_ret_uint"
        if r in primitive_types.real_types:
            return True, "get_struct_ret_float"
    return None


def _launcher(prim, args: tuple, varying):
    """launch(call) -> the kernel's return, for calls of ``prim`` like ``prim(*args)`` (templates
    included, where the signature has them): the arguments at the positions ``varying`` are read
    from ``call`` (a tuple at least that long) at each launch, the others are set from ``args`` as
    bound now. None when an argument's kind is not launched directly. ``args`` must have passed
    Taichi's own checks (a successful call, or ``ensure_compiled``)."""
    annotations = _annotations(prim)
    if len(annotations) != len(args):
        return None
    returns = _returns(prim)
    if returns is None:
        return None
    has_ret, getter = returns
    sync = has_ret or getattr(prim, "has_print", False)
    compiled = prim.compiled_kernels[prim.ensure_compiled(*args)]
    prog = impl.get_runtime().prog
    config, caps = prog.config(), prog.get_device_caps()
    ctx_type = type(compiled.make_launch_context())
    setters = []   # (the context's setter, slot index, kind, shape for _EXT, position in call or None, bound values)
    slot = 0
    for pos, (needed, a) in enumerate(zip(annotations, args)):
        k = _kind(needed, a)
        if k is False:
            continue
        if k is None:
            return None
        shape = _ext_shape(needed, a) if k == _EXT else None
        bound = None if pos in varying else _values(k, a, shape)
        setters.append((getattr(ctx_type, _SETTERS[k]), (slot,), k, shape, pos if bound is None else None, bound))
        slot += 1
    setters = tuple(setters)

    def launch(call):
        ctx = compiled.make_launch_context()
        for setter, idx, k, shape, pos, bound in setters:
            setter(ctx, idx, *(bound if pos is None else _values(k, call[pos], shape)))
        prog.launch_kernel(prog.compile_kernel(config, caps, compiled), ctx)
        if sync:
            ti.sync()
        return getattr(ctx, getter)((0,)) if has_ret else None
    return launch


# the launch context's setter per argument kind, and the values it takes after the slot index
_SETTERS = {_NDARRAY: "set_arg_ndarray", _EXT: "set_arg_external_array_with_shape", _INT: "set_arg_int",
            _UINT: "set_arg_uint", _FLOAT: "set_arg_float"}


def _values(k, a, shape) -> tuple:
    if k == _NDARRAY:
        return (a.arr,)
    if k == _EXT:
        return (int(a.ctypes.data), a.nbytes, shape, 0)
    return (float(a),) if k == _FLOAT else (int(a),)


class BoundKernel:
    """A Taichi kernel called many times as ``bound(*head)`` = ``kernel(*head, *tail, *templates)``:
    ``tail`` (ndarrays, numpy arrays, ints, floats) and ``templates`` are fixed when it is made,
    ``head`` changes from call to call (arrays of unchanging kinds, e.g. a state's x and v, and
    Python scalars). The compiled instance is looked up with Taichi's own lookup (which checks every
    argument against the kernel's annotations) whenever the head's arrays are other objects than at
    the last call; otherwise the launch context is filled directly (module docstring)."""

    def __init__(self, kernel, tail=(), templates=()):
        self.kernel = kernel
        self.tail = tuple(tail)
        self.templates = tuple(templates)
        self._prim = _primal(kernel)
        self._head_arrays = None
        self._launch = None

    def public(self, *head):
        """The same launch through Taichi's own kernel call."""
        return self.kernel(*head, *self.tail, *self.templates)

    def __call__(self, *head):
        if not (DIRECT_LAUNCH and self._prim is not None):
            return self.kernel(*head, *self.tail, *self.templates)
        arrays = self._head_arrays
        if arrays is None or len(head) != len(arrays) or any(
                h is not a for h, a in zip(head, arrays) if a is not None):
            self._bind(head)
        return self._launch(head)

    def _bind(self, head):
        prim = self._prim
        launch = _launcher(prim, (*head, *self.tail, *self.templates), range(len(head)))
        if launch is None:
            raise TypeError(f"{prim.func.__name__}: BoundKernel passes ndarrays without gradients, numpy arrays, "
                            f"ints and floats, and returns nothing or one int or float")
        self._launch = launch
        self._head_arrays = tuple(h if isinstance(h, (ti.Ndarray, np.ndarray)) else None for h in head)


class FastKernel:
    """``fast(*args)`` = ``kernel(*args)``, launched directly when the call repeats an earlier one's
    array objects (module docstring). Up to SLOTS argument combinations are remembered per kernel,
    their arrays by weak reference: a remembered array may be freed, and a call with another object
    at the same address is a new combination. A numpy array is also checked for the same address,
    shape and dtype as when it was remembered. A combination with an argument kind not launched
    directly is remembered as one that goes to Taichi's call without being examined again."""

    SLOTS = 4

    def __init__(self, kernel):
        self.kernel = kernel
        self._prim = _primal(kernel)
        self._slots = []   # [(key, refs, numpy checks, launch)], most recent first
        self.__doc__ = getattr(kernel, "__doc__", None)
        self.__name__ = getattr(getattr(self._prim, "func", None), "__name__", "kernel")
        self.__wrapped__ = kernel
        self._templates = frozenset(p for p, a in enumerate(_annotations(self._prim)) if isinstance(a, ti.template)) \
            if self._prim is not None else frozenset()

    def _key(self, args):
        """The call's arrays by identity, its scalars by type, its templates by value (by identity
        where a value cannot be hashed: checked again by reference on a hit)."""
        key = []
        for p, a in enumerate(args):
            if isinstance(a, (ti.Ndarray, np.ndarray)):
                key.append(id(a))
            elif p in self._templates:
                try:
                    hash(a)
                    key.append((0, type(a), a))
                except TypeError:
                    key.append((1, id(a)))
            else:
                key.append(type(a))
        return tuple(key)

    def __call__(self, *args, **kwargs):
        prim = self._prim
        if kwargs or not DIRECT_LAUNCH or prim is None or prim.runtime.target_tape or prim.runtime.fwd_mode_manager:
            return self.kernel(*args, **kwargs)
        key = self._key(args)
        i = self.remembered(args, key)
        if i is not None:
            if i:
                self._slots.insert(0, self._slots.pop(i))
            launch = self._slots[0][3]
            return launch(args) if launch is not None else self.kernel(*args)
        out = self.kernel(*args)   # Taichi's call: its checks, compilation, and the result
        self._remember(key, args)
        return out

    def remembered(self, args, key=None):
        """The index of the remembered call that ``args`` repeat (launched directly), or None."""
        key = self._key(args) if key is None else key
        for i, (k, refs, checks, _) in enumerate(self._slots):
            if k == key and all(r() is args[p] for p, r in refs) and all(
                    args[p].ctypes.data == ptr and args[p].shape == shape and args[p].dtype == dt
                    for p, ptr, shape, dt in checks):
                return i
        return None

    def _remember(self, key, args):
        varying = [p for p, a in enumerate(args) if p not in self._templates and not isinstance(a, (ti.Ndarray, np.ndarray))]
        launch = _launcher(self._prim, args, set(varying))   # None: always Taichi's call (remembered too)
        refs, checks = [], []
        for p, a in enumerate(args):
            if isinstance(a, (ti.Ndarray, np.ndarray)):
                refs.append((p, weakref.ref(a)))
                if isinstance(a, np.ndarray):
                    checks.append((p, int(a.ctypes.data), a.shape, a.dtype))
            elif p in self._templates and key[p][0] == 1:   # an unhashable template, kept by reference
                refs.append((p, weakref.ref(a) if _weakrefable(a) else (lambda a=a: a)))
        self._slots.insert(0, (key, tuple(refs), tuple(checks), launch))
        del self._slots[self.SLOTS:]


def _weakrefable(a) -> bool:
    try:
        weakref.ref(a)
        return True
    except TypeError:
        return False


def kernel(fn):
    """``@kernel`` = ``@ti.kernel``, called through a :class:`FastKernel`."""
    return FastKernel(ti.kernel(fn))
