"""A compiled function's native address, and an intrinsic that calls the function at such an
address from a kernel: a law's step, chosen at run time, called from one cached kernel
(``kinadapt_nn.compiled``)."""

from __future__ import annotations

import numba as nb


def jit_address(fn, sig) -> int:
    """The native address of ``fn`` compiled for ``sig`` in this process (compiled, or loaded
    from numba's cache, first): what :func:`address_caller`'s intrinsic calls."""
    from numba.experimental.function_type import _get_jit_address

    fn.compile(sig)
    return _get_jit_address(fn, sig)


def address_caller(sig):
    """An intrinsic ``call(addr)`` for kernels: the function of signature ``sig`` at native address
    ``addr`` (int64, :func:`jit_address`) as a first-class function, called with numba's own calling
    convention (exceptions propagate). The address is data, not code: the kernels that call it
    compile and cache once for every function of that signature."""
    import numba.experimental.function_type  # noqa: F401  (registers the function-pointer data model)
    from llvmlite import ir
    from numba.core import cgutils, types
    from numba.extending import intrinsic

    fn_type = types.FunctionType(sig)
    if getattr(nb.core.datamodel.default_manager.lookup(fn_type), "_fields", ()) != ("c_addr", "py_addr", "jit_addr"):
        raise ImportError("kinadapt_nn's law dispatch needs numba's first-class function model (c_addr, py_addr, "
                          "jit_addr; numba >= 0.59)")

    @intrinsic
    def call(typingctx, addr):
        if not isinstance(addr, types.Integer):
            return None

        def codegen(context, builder, signature, args):
            vp = context.get_value_type(types.voidptr)
            fp = cgutils.create_struct_proxy(fn_type)(context, builder)
            fp.c_addr = ir.Constant(vp, None)
            fp.py_addr = ir.Constant(vp, None)
            fp.jit_addr = builder.inttoptr(args[0], vp)
            return fp._getvalue()

        return fn_type(addr), codegen

    return call



__all__ = ["address_caller", "jit_address"]
