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
    core.py (here)       the run's compile phase (``compiling``, ``compile_calls``) and the
                         stale-cache check over those files (``drop_stale_kernels``)

The controller side only: these modules import no simulator, no episode, no experiment config.
"""

from __future__ import annotations

from kinadapt_nn import compiled
from kinadapt_nn.controller import layout
from kinadapt_nn.controller.arm_chain import arm_chain, fk_batch
from kinadapt_nn.controller.features_kernels import neural_consts, rbf_consts
from kinadapt_nn.controller.layout import *  # noqa: F403  (the generated kernel constants)
from kinadapt_nn.controller.step_kernels import (FUSED, _law, act_kernel, intake_kernel, law_kernel, sense_kernel,
                                                 step_adjoint, step_neural, step_rbf)
from kinadapt_nn.controller.twocore import compile_two_cores, kernel_opt_level

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
    cache is compiled by two processes (``twocore.compile_two_cores``: the kernels' callees shared,
    then the law's step there while the kernels compile here; else the law's step alone aside,
    ``LawSpec.compile_aside``); the law is loaded here after. -> wall seconds."""
    with compiling(progress) as phase, kernel_opt_level():  # LLVM at level 1: the same code, compiled sooner
        if not compile_two_cores(calls, law):  # a cold cache: the kernels' callees on two cores
            aside = law.compile_aside() if law is not None else None
            try:
                for _name, fn, args in calls:
                    compiled.compile_for(fn, args)
            finally:
                if aside is not None:
                    aside.wait()
        if law is not None:
            law.address()  # (from the cache the second process wrote; compiled here if it failed)
    return phase.wall_s


def entry_point(fn, args):
    """The machine code's entry of the compiled ``fn`` for the numba types of ``args`` (the
    dispatcher's type resolution skipped): only for arguments whose types never change (a
    controller's own buffers, ``t`` a float); the dispatcher itself when ``fn`` is not compiled for
    them (``compiled.entry_point``)."""
    return compiled.entry_point(fn, args)


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


#: re-exported here: the kernels and their layout are one import for the layers above
__all__ = ["FUSED", "_law", "act_kernel", "arm_chain", "fk_batch", "intake_kernel", "law_kernel", "neural_consts",
           "rbf_consts", "sense_kernel", "step_adjoint", "step_neural", "step_rbf", *layout.__all__]
