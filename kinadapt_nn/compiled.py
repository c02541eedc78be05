"""Compile management for the numba kernels, in one module: the only place that touches numba's internals.

The kernels themselves are plain ``@numba.njit(cache=True)`` functions in their modules (public
numba); everything about compiling them goes through here:

* ``compile_for(fn, args)`` / ``compile_sig(fn, sig)`` compile (or load from numba's on-disk
  cache) a dispatcher for the types of ``args`` / for a signature; ``compile_or_skip`` the same,
  a typing error ignored (a speculative entry of a compile plan);
* ``entry_point(fn, args)``: the machine code's entry for those types (the dispatcher's type
  resolution skipped: arguments whose types never change);
* ``in_cache(fn, sig)``, ``cached_any(fn)``, ``cache_dir(fn)``: what numba's on-disk cache holds;
* ``opt_level(level)``: LLVM's optimisation level meanwhile (this process and helpers it starts);
* ``jit_address(fn, sig)`` and ``address_caller(sig)``: a compiled function's native address, and
  an intrinsic that calls the function at such an address (a law's step, chosen at run time,
  called from one cached kernel);
* ``invalidate_stale(dispatchers, sources)``: numba's cache is invalidated per source file, not
  per callee; a kernel cached with a callee from another file would keep the old callee. Every
  compile phase checks a fingerprint of the kernels' source files and drops the cached code of
  those kernels' modules when any file changed, so nobody deletes cache files by hand.

Every function that reads numba's private cache state degrades to "not cached" (or does nothing)
when numba moves it, so a numba upgrade costs a compile, never a wrong result.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numba as nb

#: the file beside the kernels' cache that holds their sources' fingerprint
STAMP_FILE = "kinadapt_kernel_sources.sha256"


# --------------------------------------------------------------------------------------------- compiling


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


# --------------------------------------------------------------------------------------------- the cache


def in_cache(fn, sig) -> bool:
    """True when numba's on-disk cache holds ``fn`` compiled for ``sig`` by this source and this
    machine's code generator (the key numba's loader looks up); False when it cannot be told."""
    try:
        cache = fn._cache
        return cache._index_key(sig, fn.targetctx.codegen()) in cache._cache_file._load_index()
    except Exception:  # numba's cache internals moved: not known to be cached
        return False


def cached_any(fn) -> bool | None:
    """True when numba's on-disk cache holds ``fn`` compiled for some signature by this source
    (the index is empty when missing or written for another version of the file); None when that
    cannot be told."""
    try:
        return bool(fn._cache._cache_file._load_index())
    except Exception:  # numba's cache internals moved
        return None


def cache_dir(fn) -> Path | None:
    """The folder of ``fn``'s cached code (``NUMBA_CACHE_DIR`` when set, else ``__pycache__``
    beside its source, else numba's user-wide one); None when it cannot be told."""
    try:
        return Path(fn._cache._cache_path)
    except Exception:  # numba's cache internals moved
        return None


def sources_fingerprint(paths: Iterable[Path]) -> str:
    """sha256 over the contents of ``paths`` (sorted by name)."""
    h = hashlib.sha256()
    for p in sorted(Path(x) for x in paths):
        h.update(p.name.encode() + b"\0" + p.read_bytes() + b"\0")
    return h.hexdigest()


def invalidate_stale(dispatchers: Iterable, sources: Iterable[Path], stamp_fn) -> bool:
    """Drop the cached code of the modules of ``dispatchers`` when the fingerprint of ``sources``
    (every file their kernels' code comes from) differs from the one recorded beside ``stamp_fn``'s
    cache; then record the new one. -> True when stale code was dropped. numba's own check covers
    a kernel's own file only (module docstring). Does nothing when the cache cannot be located."""
    stamp_dir = cache_dir(stamp_fn)
    if stamp_dir is None:
        return False
    stamp = stamp_dir / STAMP_FILE
    now = sources_fingerprint(sources)
    try:
        if stamp.read_text().strip() == now:
            return False
    except OSError:
        pass
    dropped = False
    for folder, stems in _cache_files(dispatchers).items():
        for f in folder.glob("*.nb[ic]"):
            if f.name.split(".", 1)[0] in stems:
                with contextlib.suppress(OSError):  # another process dropped it first
                    f.unlink()
                    dropped = True
    with contextlib.suppress(OSError):  # a read-only cache location: checked again next time
        stamp_dir.mkdir(parents=True, exist_ok=True)
        stamp.write_text(now + "\n")
    return dropped


def _cache_files(dispatchers: Iterable) -> dict[Path, set[str]]:
    """cache folder -> the source-file stems whose cached code lives there (numba names a cache
    file ``<stem>.<qualname>-<line>.pyXY.nb[ic]``)."""
    out: dict[Path, set[str]] = {}
    for fn in dispatchers:
        folder = cache_dir(fn)
        if folder is not None:
            out.setdefault(folder, set()).add(Path(fn.py_func.__code__.co_filename).stem)
    return out


# --------------------------------------------------------------------------------------------- addresses


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


__all__ = ["STAMP_FILE", "address_caller", "cache_dir", "cached_any", "compile_for", "compile_or_skip",
           "compile_sig", "entry_point", "in_cache", "invalidate_stale", "is_kernel", "jit_address", "opt_level",
           "signature_of", "sources_fingerprint"]
