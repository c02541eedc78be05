"""The controller's per-step maths, written once over B episodes (numba kernels).

One control period of episode b (eq. names as in docs/method.md and ``kinadapt_nn.controller.laws``):

    intake       non-finite samples are held (at most ``max_dropout_s``), never let in
    w_env        = [R (r_f - r0_f); R (r_m - r0_m)]                    tared wrench, world, at O
    s            = [n . (p_O + R l_nom) - n . p_entry ;  G w_env]      (kinadapt_nn.sensing)
    filters      y, known_f, Phi_f += alpha (input - state);  s_dot_meas = (s - y) / (tau + dt)
    F            = -grad V(s)                                          eq. ft_force
    drive        = J_hat_xi^T F = (S Ad(R theta))^T F (adjoint, fused) eq. cp_admittance's drive
    xi+          = (M xi + dt (rho drive - w_env)) / (M + dt D)        eq. cp_admittance
    qdot_ref     = J^+ xi + (I - J^+ J) k_ns (q_0 - q)
    theta+       = the law's step (kinadapt_nn.controller.laws: kalman | composite | ...) in contact

Shapes: B episodes, n joints, m = 6 sensor channels, p parameters. All state lives in one
``ControllerState`` (float rows ``x`` (B, NX) and counters ``k`` (B, NK)); its named views
(``xi``, ``q_ref``, ``filt``, ``theta``, ``law_x``, ...) are what the wrappers read. Constants are
bundled into few arrays (``CoreConsts``) so a kernel call costs one dispatch.

Laws: the law-independent part of a law step is here (``_law``: the contact gate, eq. ft_pred,
the Gram log, the tracking rows); the law's own step (``controller/laws/<name>.py``) is called
through its native address (``CoreConsts.law_fn``, ``laws.base.law_step_fn``), so these kernels
compile -- and are cached -- once for every law, registered ones included. A law's state is its
own block of the state rows (``Layout``'s ``law`` block and counters, declared by the law).

Features: the adjoint's regressor and drive are computed in the kernel (``FEAT_ADJOINT``), and so
are the neural basis (``FEAT_NEURAL``: the frozen MLP body evaluated here, ``neural_consts``) and
the per-entry Gaussian RBF (``FEAT_RBF``: ``rbf_consts``);
other features supply ``[known; Phi^T]`` and either ``J_hat_xi`` (``FEAT_TWIST``) or ``J_hat``
(``FEAT_JHAT``) from Python between :func:`sense_kernel` and :func:`act_kernel`.

Where it is written, one concern per module, all re-exported here (``core.step_adjoint``,
``core.DT``, ...), the one import of the layers above:

    layout.py            the constants and state, declared once (names and sizes); the kernels'
                         index constants are generated from the declaration
    step_kernels.py      the step sequence above and the kernels that run it
    features_kernels.py  the in-kernel features: the adjoint's rows and drive, neural, RBF
    arm_chain.py         forward kinematics of the bare arm (MuJoCo's formulas)
    core.py (here)       the run's compile phase, whole: ``compiling`` (the bar, the measured
                         time), ``compile_calls`` (a cold cache compiled on two cores: the
                         kernels' callees shared with a helper process, which compiles the law's
                         step first) and the stale-cache check over those files
                         (``drop_stale_kernels``)

The controller side only: these modules import no simulator, no episode, no experiment config.
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
from kinadapt_nn.compiled import entry_point  # noqa: F401  (re-exported: the compiled step's entry)
from kinadapt_nn.controller import layout
from kinadapt_nn.controller.arm_chain import arm_chain, fk_batch
from kinadapt_nn.controller.features_kernels import neural_consts, rbf_consts
from kinadapt_nn.controller.laws.base import STEP_SIG
from kinadapt_nn.controller.layout import *  # noqa: F403  (the generated kernel constants)
from kinadapt_nn.controller.step_kernels import (FUSED, _law, act_kernel, intake_kernel, law_kernel, sense_kernel,
                                                 step_adjoint, step_neural, step_rbf)

#: [s] the one-time compile of the adjoint's step kernel and the kalman law (two processes), measured
#: on the 2-core CI VM (bench_first_run.py); the estimate shown until this machine has measured its
#: own (``compile_record``)
COMPILE_ESTIMATE_S = 17.0


def _compile_record_path():
    """Where the last measured compile time is kept: numba's cache folder for this module
    (``NUMBA_CACHE_DIR`` when set, else ``__pycache__`` beside this file, else numba's user-wide one)."""
    folder = compiled.cache_dir(step_adjoint)
    return None if folder is None else folder / "kinadapt_compile_s.json"


def compile_record() -> float:
    """[s] this machine's last measured compile of the kernels, else :data:`COMPILE_ESTIMATE_S`."""
    import json

    path = _compile_record_path()
    try:
        return float(json.loads(path.read_text())["seconds"])
    except Exception:
        return COMPILE_ESTIMATE_S


_COMPILING = [False]  # a compile phase is open (nested phases add nothing)


class compiling:
    """Context manager: the one-time compile phase of a run (the law's step, built with the
    controller, and the step kernels). With ``progress`` and a cold cache it is one bar in seconds
    against the expected compile time (this machine's last measured one, else
    :data:`COMPILE_ESTIMATE_S`) and, at the end, one line with the measured time, which is recorded
    for the next estimate. A warm cache shows nothing."""

    def __init__(self, progress: bool = False) -> None:
        self.progress = progress
        self.wall_s = 0.0
        self._cold = False

    @property
    def cold(self) -> bool:
        """True when this phase compiled (the outermost phase, a cold cache): its ``wall_s`` is then
        the one-time compile, not the loading of cached code."""
        return self._cold

    def __enter__(self) -> "compiling":
        import threading
        import time

        self._outer = not _COMPILING[0]
        if self._outer:  # numba checks a kernel's own file only: drop code cached with an edited callee
            drop_stale_kernels()
        self._cold = self._outer and not kernels_cached()
        _COMPILING[0] = True
        self._t0 = time.perf_counter()
        self._stop = threading.Event()
        self._bar = None
        if self.progress and self._cold:
            self._tick_honestly(compile_record())
        return self

    def _tick_honestly(self, expected_s: float) -> None:
        """One status line, refreshed twice a second: the time spent and the last measured
        compile -- no percentage (numba does not say how far it is, and a loaded machine
        compiles slower than the last time)."""
        import threading
        import time

        from tqdm import tqdm

        bar = self._bar = tqdm(total=None, leave=False, bar_format="{desc}",
                               desc="compiling the controller (first run only, cached after)")
        t0, stop = self._t0, self._stop

        def tick() -> None:
            while not stop.wait(0.5):
                dt = time.perf_counter() - t0
                more = "" if dt <= expected_s else ", still compiling"
                bar.set_description_str(f"compiling the controller (first run only, cached after): {dt:4.0f} s "
                                        f"so far (the last compile here took {expected_s:.0f} s{more})")

        threading.Thread(target=tick, daemon=True).start()

    def __exit__(self, *exc) -> None:
        import json
        import sys
        import time

        self.wall_s = time.perf_counter() - self._t0
        if not self._outer:
            return
        _COMPILING[0] = False
        self._stop.set()
        if self._bar is not None:
            self._bar.close()
        if self._cold and exc[0] is None:
            try:
                _compile_record_path().write_text(json.dumps({"seconds": round(self.wall_s, 2)}))
            except Exception:  # a read-only cache location: the next estimate stays the default
                pass
            if self.progress:
                print(f"compiled the controller's kernels in {self.wall_s:.0f} s (cached: later runs start at once)",
                      file=sys.stderr, flush=True)


def compile_calls(calls, progress: bool = False, law=None) -> float:
    """Compile (or load from numba's cache) each ``(name, dispatcher, args)`` for the types of
    ``args``, inside a :class:`compiling` phase; ``law`` (a ``LawSpec``): its step too. A cold
    cache is compiled by two processes (:func:`compile_two_cores`: the law's step in the helper
    while the kernels compile here, the kernels' callees shared); the law is loaded here after.
    -> wall seconds."""
    with compiling(progress) as phase, kernel_opt_level():  # LLVM at level 1: the same code, compiled sooner
        compile_two_cores(calls, law)
        if law is not None:
            law.address()  # (from the cache the helper wrote; compiled here if it failed)
    return phase.wall_s


def calls_cached(calls, law=None) -> bool:
    """True when every ``(name, dispatcher, args)`` of ``calls`` (for the types of ``args``) and
    ``law``'s step (a ``LawSpec``) are in numba's on-disk cache, so a process can load them
    instead of compiling; False when not, or when that cannot be told."""
    from kinadapt_nn.controller.laws.base import STEP_SIG

    if law is not None and not law._address and not compiled.in_cache(law.step, STEP_SIG):
        return False
    return all(compiled.in_cache(fn, compiled.signature_of(args)) for _name, fn, args in calls)


#: more kernels a compile phase must find cached to be warm (``cache_probe``: the episode loop's)
_CACHE_PROBES: list = []


def cache_probe(dispatchers) -> None:
    """Register numba dispatchers (a layer above this one: the episode loop's, the scenes') that
    :func:`kernels_cached` checks too, so that a compile phase that compiles them is cold and shown."""
    _CACHE_PROBES.extend(dispatchers)


def kernels_cached() -> bool:
    """True when the step kernel's compiled code (and every :func:`cache_probe` kernel's) is in
    numba's on-disk cache (the first run on a machine compiles it, once); True also when that
    cannot be told (no message then)."""
    told = [compiled.cached_any(f) for f in (step_adjoint, *_CACHE_PROBES)]
    return None in told or all(told)  # None: numba's cache internals moved, say nothing


def _controller_kernels() -> list:
    """Every numba kernel of the controller's loaded modules (``core``, ``dense``, the laws')."""
    import sys

    mods = [m for name, m in list(sys.modules.items()) if name.startswith("kinadapt_nn.controller") and m is not None]
    return [f for m in mods for f in vars(m).values()
            if compiled.is_kernel(f) and f.py_func.__module__ == m.__name__]


def kernel_sources() -> set:
    """The files the controller's cached kernels come from: every loaded module of the controller
    that defines a kernel (``core``'s parts, ``dense``, the laws'), and the layout whose generated
    constants numba froze into them (``controller/layout.py``)."""
    from pathlib import Path

    sources = {Path(f.py_func.__code__.co_filename) for f in _controller_kernels()}
    return sources | {Path(layout.__file__)}


def drop_stale_kernels() -> bool:
    """Drop the controller kernels' cached code when any of :func:`kernel_sources` changed since it
    was cached (``compiled.invalidate_stale``: numba itself checks a kernel's own file only, and a
    cached kernel holds its callees from other files). -> True when some was dropped."""
    return compiled.invalidate_stale(_controller_kernels(), kernel_sources(), step_adjoint)


# ------------------------------------------------------------------------------------------------
# A cold cache compiled on two cores: the step kernels' callees, and the law's step, shared
# between two processes.
#
# numba compiles a kernel's callees while it types the kernel, one after another, so a cold cache
# meant one core compiling for ~15 s (the adjoint step kernel) plus the law's step (~5 s). Each
# callee is its own cached function: once it is in numba's on-disk cache, compiling the kernel
# loads it instead (the adjoint kernel alone then takes ~3 s) and the machine code, hence every
# number, is the same (checked: a whole episode's trace equal to the last bit).
#
# :func:`compile_two_cores` therefore lists the kernels' direct callees with their argument types
# (:func:`callee_plan`) and starts one helper process (``python -m kinadapt_nn.controller.core``).
# The helper compiles the law's step first (measured: 12.7-12.9 s in all against 13.3 s with the
# law last); both then take callees from the same list, largest first, each claiming one before
# compiling it (a file created exclusively in a shared temporary folder), so none is compiled
# twice. Once the helper has finished its callees, this process compiles the kernels themselves,
# their callees now loaded from the cache. With every callee cached but not the law's step, the
# helper compiles that step alone while the kernels compile here.
#
# A callee whose argument types cannot be told from the kernel's call (a local value not in
# :data:`LOCAL_TYPES`) is left out: the kernel compiles it in line, as before. If the helper cannot
# start or fails, this process compiles whatever it left, so the result never depends on it.

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
    one of its kernel's (typed from the call's arguments), in the kernel's own ``local_types`` (a
    step kernel's: what its features kind passes between its parts) or in :data:`LOCAL_TYPES`, and
    not inlined (``inline="always"``: numba types its body inside the kernel, so nothing of it is
    compiled apart)."""
    plan: dict[str, tuple[object, tuple, int]] = {}
    for _name, fn, args in calls:
        module = fn.py_func.__globals__
        by_name = {**LOCAL_TYPES, **getattr(fn, "local_types", {}),
                   **{p: nb.typeof(a) for p, a in zip(inspect.signature(fn.py_func).parameters, args)}}
        for name in fn.py_func.__code__.co_names:
            callee = module.get(name)
            if not compiled.is_kernel(callee) or callee is fn or name in plan or compiled.inlined(callee):
                continue
            params = inspect.signature(callee.py_func).parameters
            if not all(p in by_name for p in params):
                continue
            sig = tuple(by_name[p] for p in params)
            plan[name] = (callee, sig, _code_size(callee, callee.py_func.__globals__, set()))
    return [(fn, sig) for fn, sig, _ in sorted(plan.values(), key=lambda e: -e[2])]


def _claim(folder: str, i: int) -> bool:
    """True for the one process that creates ``folder/i`` (the right to compile plan entry i)."""
    try:
        os.close(os.open(os.path.join(folder, str(i)), os.O_CREAT | os.O_EXCL | os.O_WRONLY))
        return True
    except FileExistsError:
        return False


def _law_target(law) -> tuple[str, str] | None:
    """(module, qualified name) of ``law``'s step (a ``LawSpec``) when the helper process can
    compile it into numba's on-disk cache for this one to load; None when there is nothing to gain
    (no law, compiled in this process already, cached) or it cannot (a law defined in ``__main__``
    or in a function: it is then compiled here)."""
    fn = getattr(getattr(law, "step", None), "py_func", None)
    if fn is None or "<" in fn.__qualname__ or fn.__module__ == "__main__":
        return None
    if STEP_SIG.args in [tuple(s) for s in law.step.signatures]:  # compiled in this process
        return None
    if compiled.cached_any(law.step) is not False:  # cached, or cannot be told: compile here
        return None
    return fn.__module__, fn.__qualname__


def compile_two_cores(calls, law=None) -> None:
    """Compile the kernels of ``calls`` and ``law``'s step (a ``LawSpec``) with a helper process
    (the section's comment above): the law's step there, the callees shared. Where there is nothing
    to share (one core, or every callee and the law cached) everything is compiled (loaded) here."""
    plan, target = [], None
    if (os.cpu_count() or 1) >= 2:
        target = _law_target(law)  # (the helper compiles it first)
        try:
            plan = [(fn, sig) for fn, sig in callee_plan(calls) if not compiled.in_cache(fn, sig)]
        except Exception:  # numba's cache internals moved: the kernels compile their callees in line
            plan = []
    claims = tempfile.mkdtemp(prefix="kinadapt-compile-") if plan or target is not None else None
    proc = None
    if claims is not None:
        payload = pickle.dumps(([(fn.py_func.__module__, fn.py_func.__qualname__, sig) for fn, sig in plan], target))
        try:
            proc = subprocess.Popen([sys.executable, "-m", "kinadapt_nn.controller.core", claims],
                                    stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
            proc.stdin.write(payload)
            proc.stdin.close()
        except OSError:
            proc = None
    try:
        for i, (fn, sig) in enumerate(plan):
            if _claim(claims, i):
                compiled.compile_or_skip(fn, sig)
        if proc is not None and plan:
            proc.stdout.readline()  # its callees are in the cache (or it has ended: the kernels compile them)
        for _name, fn, args in calls:
            compiled.compile_for(fn, args)
        if proc is not None:
            proc.wait()
    finally:
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait()
        if claims is not None:
            shutil.rmtree(claims, ignore_errors=True)


def _helper(claims: str) -> None:
    """The helper process: the law's step, then the unclaimed callees of the plan on stdin, and a
    line on stdout when done with them."""
    import importlib

    entries, target = pickle.loads(sys.stdin.buffer.read())

    def resolve(module: str, qualname: str):
        obj = importlib.import_module(module)
        for part in qualname.split("."):
            obj = getattr(obj, part)
        return obj

    if target is not None:
        compiled.compile_sig(resolve(*target), STEP_SIG)
    for i, (module, qualname, sig) in enumerate(entries):
        if _claim(claims, i):
            compiled.compile_or_skip(resolve(module, qualname), sig)
    sys.stdout.write("callees\n")
    sys.stdout.flush()


#: re-exported here: the kernels and their layout are one import for the layers above
__all__ = ["FUSED", "_law", "act_kernel", "arm_chain", "fk_batch", "intake_kernel", "law_kernel", "neural_consts",
           "rbf_consts", "sense_kernel", "step_adjoint", "step_neural", "step_rbf", *layout.__all__]


if __name__ == "__main__":  # the helper process of :func:`compile_two_cores`
    _helper(sys.argv[1])
