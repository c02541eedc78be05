"""One insertion: a batch of one in the episode loop (``runs.loop``), ending in its trace and summary.

The loop is the truth firewall in action: each period the scene hands the controller
``(t, q, qdot, wrench)`` -- nothing else -- and applies the returned joint command. Ground
truth is read from the scene beside it, into ``truth_*`` channels, for evaluation only
(``sim.scenes.SceneBatch.truth_into``). Success and failure are judged from sensor-side signals
(``SeatMonitor``, ``classify_failure``); the truth only checks them afterwards.
"""

from __future__ import annotations

from kinadapt_nn.config import ExperimentCfg
from kinadapt_nn.controller import core
from kinadapt_nn.controller.controller import Controller
from kinadapt_nn.runs.batch import compile_loop, run_episodes
from kinadapt_nn.runs.build import make_controller
from kinadapt_nn.runs.monitor import FAILURES
from kinadapt_nn.runs.outcome import EpisodeResult

__all__ = ["FAILURES", "EpisodeResult", "precompile", "run_episode"]


def precompile(cfgs: list[ExperimentCfg], progress: bool = False) -> float:
    """Compile (or load from numba's cache) the kernels of every distinct features type and law
    among ``cfgs``, in this process and as one compile phase (``core.compiling``: its own bar on a
    cold cache), before a pool of worker processes runs the episodes: the workers then load the
    kernels from the cache instead of each compiling them behind a frozen episode bar. Nothing
    when every kernel is cached already (``core.calls_cached``). -> wall seconds."""
    kinds = {}
    for c in cfgs:
        kinds.setdefault((c.run.features, c.adaptation.mode), c)
    ctrls = [make_controller(c) for c in kinds.values()]
    if all(core.calls_cached(k.kernel_calls(), k.law_spec) for k in ctrls) and core.kernels_cached():
        return 0.0  # all cached: each worker loads them (loading here too would only delay the workers)
    with core.compiling(progress) as phase:
        for k in ctrls:
            k.compile_kernels()
        compile_loop(cfgs[0])  # the episode loop's and the scenes' kernels too (a two-step episode)
    return phase.wall_s


def run_episode(cfg: ExperimentCfg, progress: bool = False, ctrl: Controller | None = None,
                keep_regressor: bool = False) -> EpisodeResult:
    """Simulate one insertion with config ``cfg``: ``run_episodes([cfg], [ctrl], keep_regressor,
    progress=progress)[0]``, a batch of one. Deterministic for a given config. ``ctrl``: a
    controller to use as it is (``run_insertions`` carries one over), else a new one.
    ``keep_regressor``: also return the law's filtered regressor rows ``Phi_f^T`` of every logged
    step as ``trace.arrays["law_Phi_fT"]`` (N, p, m). ``progress``: a bar of the steps."""
    return run_episodes([cfg], [ctrl], keep_regressor=keep_regressor, progress=progress)[0]
