"""Compile management for the numba kernels, in one subpackage: the only place that touches numba's internals.

The kernels themselves are plain ``@numba.njit(cache=True)`` functions in their modules (public
numba); everything about compiling them goes through here:

* ``compile_for(fn, args)`` / ``compile_sig(fn, sig)`` compile (or load from numba's on-disk
  cache) a dispatcher for the types of ``args`` / for a signature; ``compile_or_skip`` the same,
  a typing error ignored (a speculative entry of a compile plan);
* ``inlined(fn)``: a kernel numba types inside each caller (``inline="always"``), compiled nowhere apart;
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

It sits in the ground layer (``tests/test_layout.py``): the simulator's kernels (``sim/``), the
controller's and the monitor's all compile through it. Its modules: ``build`` (compiling, entry
points, the optimisation level), ``cache`` (numba's on-disk cache, the stale-callee check) and
``address`` (native addresses and their caller); everything is imported from here.
"""

from __future__ import annotations

from kinadapt_nn.compiled.address import address_caller, jit_address
from kinadapt_nn.compiled.build import (compile_for, compile_or_skip, compile_sig, entry_point, inlined, is_kernel,
                                        opt_level, signature_of)
from kinadapt_nn.compiled.cache import (STAMP_FILE, cache_dir, cached_any, in_cache, invalidate_stale,
                                        sources_fingerprint)

__all__ = ["STAMP_FILE", "address_caller", "cache_dir", "cached_any", "compile_for", "compile_or_skip",
           "compile_sig", "entry_point", "in_cache", "inlined", "invalidate_stale", "is_kernel", "jit_address", "opt_level",
           "signature_of", "sources_fingerprint"]
