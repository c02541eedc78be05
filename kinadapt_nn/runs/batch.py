"""Episodes stepped together in the one episode loop (``runs.loop``), and how each ends.

:func:`run_episodes` gives each episode's whole trace and summary (``kinadapt compare``, work
cells; ``runs.episode.run_episode`` is a batch of one); :func:`run_batch` summaries only
(``kinadapt sweep``), from controllers built from the known config alone. Both step the same
loop: the controller's kernels on (B, ...) state (``controller.core``: the same kernels
``Controller.step`` runs at B = 1), the scenes of ``sim.scenes.SceneBatch`` (one
``mujoco.batch.Batch``; one episode: ``mj_step`` on its own MjData, bit-identical). The truth
firewall holds the same way: the controller's kinematics come from its own model of the bare
arm fed with the encoder readings; the scenes only supply encoders and raw F/T readings.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from kinadapt_nn.config import ExperimentCfg
from kinadapt_nn.controller import core
from kinadapt_nn.runs.build import one_blas_thread
from kinadapt_nn.runs.loop import Loop, SummaryLog, TraceLog, compile_unreached, new_controllers, run, setup
from kinadapt_nn.runs.monitor import SeatMonitor, classify_failure
from kinadapt_nn.runs.outcome import EpisodeEnd, EpisodeLogs, EpisodeResult, episode_result, rank_breach_reason


class BatchResult(NamedTuple):
    summaries: list[dict]  #: per episode: success, seat_time_s, failure, forces, offset error
    steps: int  #: control steps taken (the longest episode)
    sim_steps: int  #: sum over episodes of the physics steps actually simulated
    wall_s: float  #: wall time of the stepping loop
    setup_s: float  #: wall time to build models and start poses
    theta_final: np.ndarray | None = None  #: (B, p) the controllers' final estimates
    ctrl_log: np.ndarray | None = None  #: (steps, B, n) servo set-points, when asked (record_ctrl)


def run_batch(cfgs: list[ExperimentCfg], nthread: int = 2, record_ctrl: bool = False) -> BatchResult:
    """Run len(cfgs) episodes together, summaries only. All cfgs share every KNOWN setting
    (sensing, control, adaptation, success, bore pose) and differ in hidden truth (tool, start,
    seed). ``record_ctrl``: keep the servo set-points (``BatchResult.ctrl_log``). With
    ``monitor.enabled`` each episode's summary has its own monitor's ``monitor`` (its events; no
    residual: there is no trace). BLAS at one thread meanwhile (``runs.build.one_blas_thread``)."""
    compile_loop(cfgs[0])
    with one_blas_thread():
        t0 = time.perf_counter()
        lp = setup(cfgs, None, traces=False, nthread=nthread)
        if record_ctrl:
            lp.ctrl_log = np.zeros((lp.n_steps, len(cfgs), lp.kn.lay.n))
        log = SummaryLog(lp)
        t1 = time.perf_counter()
        steps = run(lp, log)
        wall = time.perf_counter() - t1
        return BatchResult(_summaries(lp, log), steps, int(lp.watch["n_sim"].sum()), wall, t1 - t0,
                           lp.kn.st.theta.copy(), None if lp.ctrl_log is None else lp.ctrl_log[:steps])


def _summaries(lp: Loop, log: SummaryLog) -> list[dict]:
    """Each episode's summary from the watch and the summary log (sensor side: seat check, peaks,
    the failure class) and its final estimate against the true offset (truth side, evaluation)."""
    w, kn, c0 = lp.watch, lp.kn, lp.cfgs[0]
    tl, sl, wl = np.array(log.t), np.array(log.s), np.array(log.w)  # (T,), (T, B, 6), (T, B, 6)
    act = tl >= c0.start.settle_s
    out = []
    for b, cfg in enumerate(lp.cfgs):
        seat, breach, diverged = lp.clock[b, 1], bool(w["breach"][b]), bool(w["diverged"][b])
        success = not np.isnan(seat) and not breach and not diverged
        failure = "none" if success else ("rank_gate" if breach else
                                          classify_failure(cfg, tl[act], sl[act, b], wl[act, b], diverged))
        true_off = np.asarray(lp.world.sims[b].cfg.tool.offset_f_m)  # the truth-side tool (hidden effects folded in)
        err = kn.st.theta[b, :3] - true_off if kn.feats_b[b].theta_is_offset else np.full(3, np.nan)
        out.append({
            "success": bool(success), "failure": failure, "seat_time_s": float(seat) if success else None,
            "max_force_N": float(w["peak_f"][b]), "max_lateral_force_N": float(w["peak_lat"][b]),
            "max_moment_Nm": float(w["peak_m"][b]),
            "offset_error_final_m": err.tolist(), "offset_error_lateral_final_m": float(math.hypot(err[0], err[1])),
            "seed": cfg.run.seed, "law": kn.law.name, "steps": int(w["n_ctrl"][b]),
        })
    for b, mon in lp.monitors:  # the live monitor's events (kinadapt_nn.monitor): no trace, so no residual
        mon.finish()
        out[b]["monitor"] = mon.summary()
    return out


_WARMING = [False]  # a warm-up episode is running (it must not warm up again)


def compile_loop(cfg: ExperimentCfg, progress: bool = False) -> float:
    """On a cold cache (``core.kernels_cached`` false: the controller's kernels or the loop's and
    the scenes', which compile at their first call), compile them all in one compile phase (its
    own status line with ``progress``) by running ``cfg`` for two control steps, traced and as a
    summary; nothing on a warm cache. Without it the loop's kernels compile inside the first
    episode, behind its step bar (measured: 94 s of a cold run on the loaded 2-core VM).
    -> the phase's wall seconds (0 when warm)."""
    if _WARMING[0] or core.kernels_cached():
        return 0.0
    short = cfg.model_copy(update={"run": cfg.run.model_copy(update={"duration_s": 2 * cfg.run.dt_s})})
    _WARMING[0] = True
    try:
        with core.compiling(progress) as phase:
            run_episodes([short])
            run_batch([short], nthread=1)
            compile_unreached()  # what two free-space steps do not call (a contact's kernels)
    finally:
        _WARMING[0] = False
    return phase.wall_s if phase.cold else 0.0


class StepShare:
    """A stand-in for the loop's step bar (``loop.run``'s ``bar``): each ``update(n)`` of n control
    steps out of ``n_steps`` calls ``report(n / n_steps)`` -- the batch's progress as a fraction,
    for a job runner's episode bar (``runs.jobs``) that should move while a batch steps."""

    def __init__(self, n_steps: int, report: Callable[[float], None]) -> None:
        self.n_steps, self.report = max(1, int(n_steps)), report

    def update(self, n: int) -> None:
        self.report(n / self.n_steps)


def run_episodes(cfgs: list[ExperimentCfg], ctrls: list | None = None, keep_regressor: bool = False,
                 nthread: int = 1, progress: bool = False,
                 on_steps: Callable[[float], None] | None = None) -> list[EpisodeResult]:
    """Simulate the insertions ``cfgs`` together; each result (trace and summary) is the episode's
    own, whatever else shares the batch (deterministic for a given config). ``ctrls``: controllers
    to step from their current state (a work cell carries them from one insertion to the next),
    None or None entries for new ones; each ends in the state its episode leaves.
    ``keep_regressor``: also return the law's filtered regressor rows ``Phi_f^T`` of every logged
    step as ``trace.arrays["law_Phi_fT"]`` (N, p, m) (controller side: what a between-insertion
    refit of theta needs). ``progress``: a bar of the steps (and of a cold compile); else
    ``on_steps(fraction)``, if given, as the steps go (every 250; :class:`StepShare`).
    ``wall_time_s``: the episode's share of the batch's wall time (set-up and loop, in proportion
    to its physics steps), without the one-time compile of a cold cache (``compile_time_s``). The cfgs share every KNOWN setting and ``run.duration_s``,
    ``run.log_every``, ``run.stop_after_seat_s`` (else a ``ConfigError`` saying which). BLAS runs
    at one thread meanwhile (``runs.build.one_blas_thread``)."""
    wall0 = time.perf_counter()  # the wall time includes loading scipy's BLAS (one_blas_thread)
    # a cold cache's one-time compile -- the loop's kernels and the new controllers' -- as one phase:
    # one line and one record of the real compile time (left out of the wall time)
    with core.compiling(progress) as phase:
        compile_loop(cfgs[0], progress)
        ctrls = new_controllers(cfgs, list(ctrls or [None] * len(cfgs)))
    with one_blas_thread():
        lp = setup(cfgs, ctrls, traces=True, nthread=nthread, progress=progress)
        lp.kn.compile_s = phase.wall_s if phase.cold else 0.0
        log = TraceLog(lp, cfgs[0].run.log_every, lp.kn.feats_b[0].theta_is_offset or keep_regressor)
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=lp.n_steps, unit="step", desc="episode", leave=False, mininterval=0.25)
        elif on_steps is not None:
            bar = StepShare(lp.n_steps, on_steps)
        run(lp, log, bar)
        if progress:
            bar.close()
        return _episode_results(lp, log, time.perf_counter() - wall0 - lp.kn.compile_s, keep_regressor)


def _episode_results(lp: Loop, log: TraceLog, wall_s: float, keep_regressor: bool) -> list[EpisodeResult]:
    """Each episode's trace and summary (``runs.outcome.episode_result``), its controller given the
    state its row was stepped to."""
    w, st, out = lp.watch, lp.kn.st, lp.kn.out
    sim_steps = max(1, int(w["n_sim"].sum()))
    t_end = lp.world.time_s
    results = []
    for b, (cfg, ctrl) in enumerate(zip(lp.cfgs, lp.kn.ctrls)):
        ctrl.set_state(st.x[b], st.k[b], out[b])
        monitor = SeatMonitor(cfg)
        monitor.clock[:] = lp.clock[b]
        breach_t = None if np.isnan(w["breach_t"][b]) else float(w["breach_t"][b])
        diverged, reason = bool(w["diverged"][b]), lp.reason[b]
        if w["breach"][b]:
            diverged, reason = True, rank_breach_reason(float(w["lam_min"][b]), w["breach_t"][b])
        logs = EpisodeLogs(log.t[:, b], log.out[:, b], log.io[:, b], None if log.phi is None else log.phi[:, b],
                           log.tip[:, b], log.truth[:, b], log.lam[:, b])
        n_sim = int(w["n_sim"][b])
        end = EpisodeEnd(n_logged=-(-n_sim // log.every), steps=int(w["n_ctrl"][b]), t_end_s=float(t_end[b]),
                         wall_s=wall_s * n_sim / sim_steps, diverged=diverged, divergence_reason=reason,
                         lam_min_all=float(w["lam_min"][b]), rank_breach_t=breach_t)
        res = episode_result(cfg, lp.world.sims[b], ctrl, monitor, logs, end, keep_regressor)
        res.summary["compile_time_s"] = lp.kn.compile_s
        for bm, mon in lp.monitors:  # the live monitor's events and residual (kinadapt_nn.monitor): the
            if bm == b:  # episode's own monitor, fed its row of the batch (runs.loop.run)
                mon.finish()
                res.summary["monitor"] = mon.summary()
                n_rec = len(res.trace)
                res.trace.arrays["monitor_residual"] = mon.res_log[:n_rec]
                res.trace.arrays["monitor_z"] = mon.z_log[:n_rec]
                res.trace.meta["monitor"] = res.summary["monitor"]
        results.append(res)
    return results
