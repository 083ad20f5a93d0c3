"""Launching a Taichi kernel whose argument types never change: :class:`BoundKernel` binds a
kernel's fixed arguments once and launches its compiled instance directly (the explicit steps'
fused kernels, engine.integrators.explicit, launch this way: ~30 us a step instead of ~0.3 ms).
"""
import numpy as np
import taichi as ti

DIRECT_LAUNCH = True  # False: every BoundKernel call goes through Taichi's own kernel call


class BoundKernel:
    """A Taichi kernel called many times as ``bound(*head)`` = ``kernel(*head, *tail, *templates)``:
    ``tail`` (ndarrays, ints, floats) and ``templates`` are fixed when it is made, ``head`` changes
    from call to call (ndarrays of unchanging kinds, e.g. a state's x and v, and Python scalars).

    Taichi 1.7.4's kernel call spends Python time on every call mapping each argument's type to a
    compiled instance and checking it: about 5-20 us per ndarray argument, 0.1-0.3 ms for a kernel
    of 16 ndarrays, more than the arithmetic of a 64 x 64 cloth step. A BoundKernel looks the
    compiled instance up with Taichi's own lookup (which checks every argument against the
    kernel's annotations) whenever the head's ndarrays are other objects than at the last call, and
    otherwise fills the launch context itself, with the calls Taichi's call makes for these argument
    kinds (ndarray without gradient, int, float), and launches that compiled instance: the same
    machine code on the same arguments. With Taichi other than 1.7.4, or with DIRECT_LAUNCH False,
    every call is Taichi's own call. Kernels returning nothing or one i32 only."""

    def __init__(self, kernel, tail=(), templates=()):
        self.kernel = kernel
        self.tail = tuple(tail)
        self.templates = tuple(templates)
        self._prim = getattr(kernel, "_primal", None)
        self._direct = self._prim is not None and tuple(ti.__version__) == (1, 7, 4)
        self._head_arrays = None
        self._launch = None

    def public(self, *head):
        """The same launch through Taichi's own kernel call."""
        return self.kernel(*head, *self.tail, *self.templates)

    def __call__(self, *head):
        if not (DIRECT_LAUNCH and self._direct):
            return self.kernel(*head, *self.tail, *self.templates)
        arrays = self._head_arrays
        if arrays is None or len(head) != len(arrays) or any(
                h is not a for h, a in zip(head, arrays) if a is not None):
            self._bind(head)
        return self._launch(head)

    def _bind(self, head):
        from taichi.lang import impl
        prim = self._prim
        args = (*head, *self.tail)
        compiled = prim.compiled_kernels[prim.ensure_compiled(*args, *self.templates)]
        prog = impl.get_runtime().prog
        config, caps = prog.config(), prog.get_device_caps()
        kinds = []
        for a in args:
            if isinstance(a, ti.Ndarray):
                if a.grad is not None:
                    raise TypeError(f"{prim.func.__name__}: BoundKernel does not pass ndarrays with gradients")
                kinds.append(0)
            elif isinstance(a, (int, np.integer)) and not isinstance(a, (bool, np.bool_)):
                kinds.append(1)
            elif isinstance(a, (float, np.floating)):
                kinds.append(2)
            else:
                raise TypeError(f"{prim.func.__name__}: BoundKernel passes ndarrays, ints and floats, "
                                f"not {type(a).__name__}")
        ret = prim.return_type
        has_ret = ret is not None
        if has_ret and (len(ret) != 1 or ret[0] not in (ti.i32, int)):
            raise TypeError(f"{prim.func.__name__}: BoundKernel launches kernels returning nothing or one i32")
        nh = len(head)
        head_kinds = tuple(enumerate(kinds[:nh]))
        tail_arrays = tuple(((nh + j,), a.arr) for j, a in enumerate(self.tail) if kinds[nh + j] == 0)
        tail_ints = tuple(((nh + j,), int(a)) for j, a in enumerate(self.tail) if kinds[nh + j] == 1)
        tail_floats = tuple(((nh + j,), float(a)) for j, a in enumerate(self.tail) if kinds[nh + j] == 2)

        def launch(head):
            ctx = compiled.make_launch_context()
            for i, kind in head_kinds:
                if kind == 0:
                    ctx.set_arg_ndarray((i,), head[i].arr)
                elif kind == 1:
                    ctx.set_arg_int((i,), int(head[i]))
                else:
                    ctx.set_arg_float((i,), float(head[i]))
            for idx, arr in tail_arrays:
                ctx.set_arg_ndarray(idx, arr)
            for idx, val in tail_ints:
                ctx.set_arg_int(idx, val)
            for idx, val in tail_floats:
                ctx.set_arg_float(idx, val)
            prog.launch_kernel(prog.compile_kernel(config, caps, compiled), ctx)
            if has_ret:
                ti.sync()
                return ctx.get_struct_ret_int((0,))
            return None

        self._launch = launch
        self._head_arrays = tuple(h if isinstance(h, ti.Ndarray) else None for h in head)
