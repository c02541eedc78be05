"""A first run's compile on two cores: the step kernels' callees shared between two processes.

numba compiles a kernel's callees while it types the kernel, one after another, so a cold cache
meant one core compiling for ~15 s (the adjoint step kernel; the law's step, ~5 s, already went to
a second process, ``LawSpec.compile_aside``). Each callee is its own cached function: once it is
in numba's on-disk cache, compiling the kernel loads it instead (the adjoint kernel alone then
takes ~3 s) and the machine code, hence every number, is the same (checked: a whole episode's
trace equal to the last bit).

:func:`compile_two_cores` therefore lists the kernels' direct callees with their argument types
(:func:`callee_plan`) and starts one helper process (``python -m kinadapt_nn.controller.twocore``).
The helper compiles the law's step first (measured: 12.7-12.9 s in all against 13.3 s with the
law last); both then take callees from the same list, largest first, each claiming one before
compiling it (a file created exclusively in a shared temporary folder), so none is compiled
twice. Once the helper has finished its callees, this process compiles the kernels themselves,
their callees now loaded from the cache.

A callee whose argument types cannot be told from the kernel's call (a local value not in
:data:`LOCAL_TYPES`) is left out: the kernel compiles it in line, as before. If the helper cannot
start or fails, this process compiles whatever it left, so the result never depends on it.
"""

from __future__ import annotations

import contextlib
import inspect
import os
import pickle
import shutil
import subprocess
import sys
import tempfile

import numba as nb
from numba import types as T

from kinadapt_nn import compiled

_F1, _F2, _F3 = (T.Array(T.float64, d, "C") for d in (1, 2, 3))
#: numba types of the values the step kernels make themselves and pass to callees, by the
#: callee's parameter name (the kernels' own arguments are typed from the call)
LOCAL_TYPES = {"b": T.int64, "n": T.int64, "rho": T.float64, "t_rel": T.float64, "known": _F1, "Phi_T": _F2,
               "theta": _F1, "F": _F1, "drive": _F1, "Lc": _F2, "Jh": _F2, "Kq": _F2, "Y": _F3, "psi": _F1,
               "q": _F1}


#: LLVM's optimisation level for the kernels (numba's default is 3). Measured on the 2-core VM, a
#: fresh cache each time: the default episode's compile 13.7-14.7 s at 3, 11.3-12.0 s at 1; the
#: episodes' traces and summaries bit for bit the same (eight configurations: no fast-math, so no
#: level may reorder floating point) and the episodes as fast (bench_episode: adjoint 5.40 vs
#: 5.33, RBF 10.61 vs 10.21). Level 0 compiles no faster (13.6 s) and runs 6x slower.
KERNEL_OPT = 1


def kernel_opt_level() -> contextlib.AbstractContextManager:
    """Compile the kernels at :data:`KERNEL_OPT` meanwhile (``compiled.opt_level``: this process and
    the helpers started meanwhile; a ``NUMBA_OPT`` the user has set is left to rule)."""
    return compiled.opt_level(KERNEL_OPT)


def _code_size(fn, module: dict, seen: set) -> int:
    """Bytecode bytes of ``fn`` and of the callees it reaches in ``module`` (each counted once):
    the order of the compile list, largest first."""
    size = len(fn.py_func.__code__.co_code)
    for name in fn.py_func.__code__.co_names:
        callee = module.get(name)
        if compiled.is_kernel(callee) and name not in seen:
            seen.add(name)
            size += _code_size(callee, callee.py_func.__globals__, seen)
    return size


def callee_plan(calls) -> list[tuple[object, tuple]]:
    """The direct callees of the kernels of ``calls`` ((name, dispatcher, args) each) as
    (dispatcher, argument types), the largest first; a callee is listed when every parameter is
    one of its kernel's (typed from the call's arguments) or in :data:`LOCAL_TYPES`."""
    plan: dict[str, tuple[object, tuple, int]] = {}
    for _name, fn, args in calls:
        module = fn.py_func.__globals__
        by_name = {p: nb.typeof(a) for p, a in zip(inspect.signature(fn.py_func).parameters, args)}
        for name in fn.py_func.__code__.co_names:
            callee = module.get(name)
            if not compiled.is_kernel(callee) or callee is fn or name in plan:
                continue
            params = inspect.signature(callee.py_func).parameters
            if not all(p in by_name or p in LOCAL_TYPES for p in params):
                continue
            sig = tuple(by_name[p] if p in by_name else LOCAL_TYPES[p] for p in params)
            plan[name] = (callee, sig, _code_size(callee, callee.py_func.__globals__, set()))
    return [(fn, sig) for fn, sig, _ in sorted(plan.values(), key=lambda e: -e[2])]


def _claim(folder: str, i: int) -> bool:
    """True for the one process that creates ``folder/i`` (the right to compile plan entry i)."""
    try:
        os.close(os.open(os.path.join(folder, str(i)), os.O_CREAT | os.O_EXCL | os.O_WRONLY))
        return True
    except FileExistsError:
        return False


def compile_two_cores(calls, law=None) -> bool:
    """Compile the kernels of ``calls`` and ``law``'s step (a ``LawSpec``) with a helper process
    sharing the callees (module docstring). -> False, having done nothing, where there is nothing to
    share (every callee cached, or one core): the caller compiles as before."""
    if (os.cpu_count() or 1) < 2:
        return False
    try:
        plan = [(fn, sig) for fn, sig in callee_plan(calls) if not compiled.in_cache(fn, sig)]
    except Exception:  # numba's cache internals moved: compile as before
        return False
    if not plan:
        return False
    law_target = law.aside_target() if law is not None else None
    claims = tempfile.mkdtemp(prefix="kinadapt-compile-")
    payload = pickle.dumps(([(fn.py_func.__module__, fn.py_func.__qualname__, sig) for fn, sig in plan], law_target))
    try:
        proc = subprocess.Popen([sys.executable, "-m", "kinadapt_nn.controller.twocore", claims],
                                stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
        proc.stdin.write(payload)
        proc.stdin.close()
    except OSError:
        proc = None
    try:
        for i, (fn, sig) in enumerate(plan):
            if _claim(claims, i):
                compiled.compile_or_skip(fn, sig)
        if proc is not None:
            proc.stdout.readline()  # its callees are in the cache (or it has ended: the kernels compile them)
        for _name, fn, args in calls:
            compiled.compile_for(fn, args)
        if proc is not None:
            proc.wait()
    finally:
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait()
        shutil.rmtree(claims, ignore_errors=True)
    return True


def _helper(claims: str) -> None:
    """The helper process: the law's step, then the unclaimed callees of the plan on stdin, and a
    line on stdout when done with them."""
    import importlib

    entries, law_target = pickle.loads(sys.stdin.buffer.read())

    def resolve(module: str, qualname: str):
        obj = importlib.import_module(module)
        for part in qualname.split("."):
            obj = getattr(obj, part)
        return obj

    if law_target is not None:
        from kinadapt_nn.controller.laws.base import STEP_SIG

        compiled.compile_sig(resolve(*law_target), STEP_SIG)
    for i, (module, qualname, sig) in enumerate(entries):
        if _claim(claims, i):
            compiled.compile_or_skip(resolve(module, qualname), sig)
    sys.stdout.write("callees\n")
    sys.stdout.flush()


if __name__ == "__main__":
    _helper(sys.argv[1])
