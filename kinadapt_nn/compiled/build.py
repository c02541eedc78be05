"""Compiling the numba kernels: for the types of given arguments or a signature, their machine
code's entry, and LLVM's optimisation level meanwhile (``kinadapt_nn.compiled``)."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator, Sequence
from typing import Any

import numba as nb

def signature_of(args: Sequence[Any]) -> tuple:
    """The numba types of ``args`` (a dispatcher's signature for them)."""
    return tuple(nb.typeof(a) for a in args)


def compile_for(fn, args: Sequence[Any]) -> None:
    """Compile ``fn`` (or load it from numba's cache) for the types of ``args``."""
    fn.compile(signature_of(args))


def compile_sig(fn, sig) -> None:
    """Compile ``fn`` (or load it from numba's cache) for the signature ``sig``."""
    fn.compile(sig)


def compile_or_skip(fn, sig) -> None:
    """``compile_sig``; a typing error (a compile plan's entry typed wrongly) only wastes that entry:
    the caller's kernel then compiles the callee for the types it has and reports any real error."""
    try:
        fn.compile(sig)
    except nb.core.errors.TypingError:
        pass


def is_kernel(obj) -> bool:
    """True for a numba CPU dispatcher (an ``@njit`` function)."""
    from numba.core.registry import CPUDispatcher

    return isinstance(obj, CPUDispatcher)


def inlined(fn) -> bool:
    """True for a kernel numba types inside each caller (``@njit(inline="always")``): nothing of it is
    compiled apart, so a compile plan leaves it out."""
    return getattr(fn, "targetoptions", {}).get("inline") == "always"


def entry_point(fn, args: Sequence[Any]):
    """The machine code's entry of the compiled ``fn`` for the numba types of ``args``: what the
    dispatcher calls once it has resolved the types. It checks nothing, so only for arguments whose
    types never change; the dispatcher itself when ``fn`` is not compiled for them."""
    try:
        return fn.overloads[signature_of(args)].entry_point
    except (KeyError, AttributeError):
        return fn


@contextlib.contextmanager
def opt_level(level: int) -> Iterator[None]:
    """Compile at LLVM optimisation ``level`` meanwhile: ``numba.config.OPT`` in this process and
    ``NUMBA_OPT`` for the helper processes started meanwhile; both restored after. numba's code
    generator is made first at the process's own level, so the user's other numba code keeps it. A
    ``NUMBA_OPT`` the user has set is left to rule."""
    if "NUMBA_OPT" in os.environ:
        yield
        return
    from numba.core import config
    from numba.core.registry import cpu_target

    cpu_target.target_context  # noqa: B018  (numba's code generator, made at the process's level)
    old = config.OPT
    config.OPT = config._OptLevel(level)
    os.environ["NUMBA_OPT"] = str(level)
    try:
        yield
    finally:
        config.OPT = old
        os.environ.pop("NUMBA_OPT", None)


__all__ = ["compile_for", "compile_or_skip", "compile_sig", "entry_point", "is_kernel", "opt_level", "signature_of"]
