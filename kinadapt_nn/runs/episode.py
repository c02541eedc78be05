"""One insertion: simulator adapter -> controller -> trace, success and failure class.

The loop is the truth firewall in action: each period the adapter hands the controller
``(t, q, qdot, wrench)`` -- nothing else -- and applies the returned joint command. Ground
truth is read from the adapter beside it, into ``truth_*`` channels, for evaluation only.
Success and failure are judged from sensor-side signals (``SeatMonitor``,
``classify_failure``); the truth only checks them afterwards.
"""

from __future__ import annotations

import math

import time
from typing import NamedTuple

import numpy as np

from kinadapt_nn.config import ExperimentCfg, arm_mjcf_path
from kinadapt_nn.controller.controller import Controller
from kinadapt_nn.controller import core
from kinadapt_nn.controller.core import RANK_GATE  # the paper's kinematic gate (1e-6)
from kinadapt_nn.errors import SensorError
from kinadapt_nn.sensing import CHANNEL_NAMES
from kinadapt_nn.sim.adapter import PegInHoleSim
from kinadapt_nn.sim.faults import SensorFaults
from kinadapt_nn.trace import Trace, TraceRecorder
from kinadapt_nn.sim.truth import TrueSensorJacobian
from kinadapt_nn.runs.build import make_controller, one_blas_thread
from kinadapt_nn.runs.evaluate import certificate_check, evaluate_offline, summarize
from kinadapt_nn.runs.monitor import SeatMonitor, seat_step

FAILURES = ("none", "timeout", "jam", "block_face", "divergence")


class EpisodeResult(NamedTuple):
    trace: Trace  #: every logged channel
    summary: dict  #: the run-outputs contract (``summary.json``)


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
    if all(core.calls_cached(k.kernel_calls(), k.law_spec) for k in ctrls):
        return 0.0  # all cached: each worker loads them (loading here too would only delay the workers)
    with core.compiling(progress) as phase:
        for k in ctrls:
            k.compile_kernels()
    return phase.wall_s


def run_episode(cfg: ExperimentCfg, progress: bool = False, ctrl: Controller | None = None,
                keep_regressor: bool = False) -> EpisodeResult:
    """Simulate one insertion with config ``cfg``. Deterministic for a given config. ``ctrl``: a
    controller to use as it is (``run_insertions`` carries one over), else a new one.
    ``keep_regressor``: also return the law's filtered regressor rows ``Phi_f^T`` of every logged
    step as ``trace.arrays["law_Phi_fT"]`` (N, p, m) (controller side: what a between-insertion
    refit of theta needs). BLAS runs at one thread meanwhile (:func:`one_blas_thread`)."""
    wall0 = time.perf_counter()  # the episode's wall time includes loading scipy's BLAS (one_blas_thread)
    with one_blas_thread():
        return _run_episode(cfg, progress, ctrl, keep_regressor, wall0)


def _run_episode(cfg: ExperimentCfg, progress: bool, ctrl: Controller | None, keep_regressor: bool,
                 wall0: float) -> EpisodeResult:
    sim = PegInHoleSim(cfg)
    compile_s = 0.0  # [s] the one-time compile of this process's kernels, kept out of the episode's wall time
    if ctrl is None:
        with core.compiling(progress) as phase:
            ctrl = make_controller(cfg)
            ctrl.compile_kernels()
        compile_s = phase.wall_s if phase.cold else 0.0
    dt = cfg.run.dt_s
    n_steps = int(round(cfg.run.duration_s / dt))
    every = cfg.run.log_every
    n_rec = n_steps // every + 1
    monitor = SeatMonitor(cfg)
    faults = SensorFaults(cfg.faults, cfg.run.seed, cfg.start.settle_s) if SensorFaults.active(cfg.faults) else None
    diverged = False
    divergence_reason = None
    warn0 = int(sim.data.warning.number.sum())
    stop_at: float | None = None
    ctrl.compile_kernels(progress)  # (compiled already, or a ctrl built elsewhere: not the episode's first step)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=n_steps, unit="step", desc="episode", leave=False, mininterval=0.25)
    # -- the hot loop only copies into preallocated logs; trace channels are built after it
    lay = ctrl.layout
    n, m, p = lay.n, lay.m, lay.p
    out, q_ref, qdot_ref = ctrl.out[0], ctrl.state.q_ref[0], ctrl._o["qdot_ref"]
    i_rho, i_lam, i_s = lay.out_blocks["rho"][0], lay.out_blocks["lam_min"][0], lay.out_blocks["s"][0]
    fused = ctrl._fused
    x_row = ctrl.state.x[0]
    f0 = lay.x_blocks["filt"][0] + 2 * m  # Phi_f^T rows of the state (truth_bias_w, evaluation only)
    t_log = np.zeros(n_rec)
    out_log = np.zeros((n_rec, lay.nout))
    io_log = np.zeros((n_rec, 3 * n + 6))  # q, qdot, wrench (raw, as given), q_ref
    phi_log = np.zeros((n_rec, p * m)) if (ctrl.features.theta_is_offset or keep_regressor) else None
    tip_log = np.zeros((n_rec, 3))
    truth_log = np.zeros((n_rec, 4))  # depth (from the tip after the loop), face, bore, normal force
    lam_log = np.full(n_rec, math.inf)
    k = 0
    n_logged = 0
    lam_min_all = math.inf  # the rank gate, every step with the drive on
    lam_since = math.inf  # its minimum since the last logged sample
    rank_breach_t: float | None = None
    inp = ctrl.input_row  # the sample is written straight into the controller's input row
    s_out, phi_row = out[i_s:i_s + 6], x_row[f0:f0 + p * m]  # views, fetched once
    seat_lim, seat_clock = monitor.lim, monitor.clock
    q_in, qd_in, w_in = inp[:n], inp[n:2 * n], inp[2 * n:]

    def read_sample() -> None:
        if faults is None:
            sim.sense_into(q_in, qd_in, w_in)
        else:
            o = faults(sim.time_s, sim.sense())
            q_in[:], qd_in[:], w_in[:] = o.q_rad, o.qdot_rad_s, o.wrench_raw_f

    read_sample()
    t = sim.time_s
    for k in range(n_steps):
        logged = k % every == 0
        if logged:
            io_log[k // every, :2 * n + 6] = inp  # the sample as given (before any dropout hold)
        try:
            ctrl.advance_input(t)
        except SensorError as exc:
            diverged = True
            divergence_reason = sensor_reason(str(exc))
            break
        sim.apply(q_ref, qdot_ref)
        if out[i_rho] > 0:  # seat monitor and the rank gate every step (paper Results, "A separate kinematic gate")
            seat_step(t, s_out, seat_lim, seat_clock)  # (monitor.update, without the method call)
            lam = float(out[i_lam]) if fused else ctrl.rank_margin_now()
            if lam < lam_since:
                lam_since = lam
            if lam < lam_min_all:
                lam_min_all = lam
                if lam < RANK_GATE and rank_breach_t is None:
                    rank_breach_t = t
        if logged:
            j = k // every
            n_logged = j + 1
            lam_log[j] = lam_since
            lam_since = math.inf
            t_log[j] = t
            out_log[j] = out
            io_log[j, 2 * n + 6:] = q_ref
            if phi_log is not None:
                phi_log[j] = phi_row
            sim.truth_into(tip_log[j], truth_log[j, 1:])
        sim.step()
        read_sample()
        t = sim.time_s
        if bar is not None and k % 250 == 0:
            bar.update(250 if k else 1)
        if stop_at is None and seat_clock[1] == seat_clock[1]:  # seated (the clock's seat time is not NaN)
            stop_at = monitor.seat_time + cfg.run.stop_after_seat_s
        if stop_at is not None and t >= stop_at:
            break
        # (a non-finite simulator state reaches the controller as a sensor sample: SensorError)
        if rank_breach_t is not None:
            diverged = True
            divergence_reason = rank_breach_reason(lam_min_all, rank_breach_t)
            break
        if k % 100 == 0:  # divergence watch at 10 Hz: MuJoCo warnings
            nwarn = int(sim.data.warning.number.sum())
            if nwarn > warn0:
                diverged = True
                divergence_reason = warning_reason(t)
                break
    if bar is not None:
        bar.close()
    logs = EpisodeLogs(t_log, out_log, io_log, phi_log, tip_log, truth_log, lam_log)
    res = episode_result(cfg, sim, ctrl, monitor, logs, n_logged, steps=k + 1, t_end_s=sim.time_s,
                         wall_s=time.perf_counter() - wall0 - compile_s, diverged=diverged,
                         divergence_reason=divergence_reason, lam_min_all=lam_min_all, rank_breach_t=rank_breach_t,
                         keep_regressor=keep_regressor)
    res.summary["compile_time_s"] = compile_s
    return res


class EpisodeLogs(NamedTuple):
    """An episode loop's raw logs, one row per logged step (``n_rec`` rows allocated, the first
    ``n_logged`` written): what :func:`episode_result` builds the trace from."""

    t: np.ndarray  #: (n_rec,) time [s]
    out: np.ndarray  #: (n_rec, nout) the controller's out row (``core.Layout.out_blocks``)
    io: np.ndarray  #: (n_rec, 3n+6) [q; qdot; raw wrench] as given, then q_ref
    phi: np.ndarray | None  #: (n_rec, p*m) the law's filtered regressor Phi_f^T, or None
    tip: np.ndarray  #: (n_rec, 3) true tip, world [m] (truth side)
    truth: np.ndarray  #: (n_rec, 4) [depth (filled here), face, bore, normal force [N]] (truth side)
    lam: np.ndarray  #: (n_rec,) lambda_min(W J_hat J_hat^T W) minimum since the last logged step (inf: drive off)


def sensor_reason(message: str) -> str:
    """The divergence reason of an episode stopped by a dropout longer than ``max_dropout_s``
    (``message``: the controller's, ``controller.sensor_error_message``)."""
    return f"non-finite sensor sample: {message}"


def rank_breach_reason(lam_min_all: float, t_s: float) -> str:
    """The divergence reason of an episode stopped by the rank gate."""
    return f"rank gate breached (lambda_min {lam_min_all:.3g} < {RANK_GATE:g}) at t={t_s:.3f} s"


def warning_reason(t_s: float) -> str:
    """The divergence reason of an episode stopped by a MuJoCo warning (the 10 Hz watch)."""
    return f"MuJoCo warning(s) at t={t_s:.3f} s"


def episode_result(cfg: ExperimentCfg, sim: PegInHoleSim, ctrl: Controller, monitor: SeatMonitor, logs: EpisodeLogs,
                   n_logged: int, *, steps: int, t_end_s: float, wall_s: float, diverged: bool,
                   divergence_reason: str | None, lam_min_all: float, rank_breach_t: float | None,
                   keep_regressor: bool) -> EpisodeResult:
    """An episode's trace and summary from its loop's logs and the controller's final state (the
    single episode's loop and the batched one, ``runs.batch``, both end here). ``sim``: the
    episode's simulator object, for its truth-side config and geometry only (its MjData is not
    read: ``t_end_s`` is the episode's final simulated time); ``steps``: control steps taken."""
    tcfg = sim.cfg  # the truth-side config (hidden effects folded in): evaluation only
    theta_true = np.asarray(tcfg.tool.offset_f_m, dtype=float) if ctrl.features.theta_is_offset else None
    logs.truth[:n_logged, 0] = sim.tip_depths(logs.tip[:n_logged])
    meta = {
        "dt_s": cfg.run.dt_s * cfg.run.log_every,
        "features": cfg.run.features,
        "seed": cfg.run.seed,
        "truth_offset_f_m": list(tcfg.tool.offset_f_m),
        "channel_names": list(CHANNEL_NAMES),
        "bore_entry_w_m": list(cfg.scene.bore_entry_w_m),
        "start_lateral_w_m": [float(x) for x in sim.start_lateral_w_m],
        "start_tilt_deg": [float(x) for x in sim.start_tilt_deg],
    }
    trace = _trace_from_logs(ctrl, cfg, meta, n_logged, logs.t, logs.out, logs.io,
                             logs.phi if theta_true is not None else None, logs.tip, logs.truth, theta_true, monitor)
    if keep_regressor:
        p, m = ctrl.layout.p, ctrl.layout.m
        trace.arrays["law_Phi_fT"] = logs.phi[:len(trace)].reshape(len(trace), p, m)
    truth_jac = TrueSensorJacobian(
        ctrl.S, ctrl.l_nom_f, np.asarray(tcfg.tool.offset_f_m), arm_mjcf_path(cfg.scene),
        tcfg.arm.link_length_error_m, tcfg.arm.joint_offset_rad,
    )
    evaluate_offline(trace, ctrl, truth_jac=truth_jac)
    lam_arr = logs.lam[: len(trace)]  # per-step minima where the drive was on
    if len(lam_arr) == len(trace):
        trace.arrays["lambda_min"] = np.where(np.isfinite(lam_arr), lam_arr, trace["lambda_min"])
    trace.meta["min_lambda_JJt_all_steps"] = float(lam_min_all) if math.isfinite(lam_min_all) else None
    trace.meta["rank_gate_breach_t_s"] = rank_breach_t
    certificate = certificate_check(tcfg, trace, ctrl)
    summary = summarize(tcfg, trace, ctrl, monitor, diverged, steps, t_end_s, wall_s)
    summary["certificate"] = certificate
    summary["sensor_dropouts"] = int(ctrl.dropouts)
    summary["divergence_reason"] = divergence_reason
    return EpisodeResult(trace, summary)


def _trace_from_logs(ctrl: Controller, cfg: ExperimentCfg, meta: dict, n_rec: int, t_log, out_log, io_log, phi_log,
                     tip_log, truth_log, theta_true, monitor: SeatMonitor) -> Trace:
    """The trace channels from the loop's raw logs (controller ``out`` rows, I/O rows, truth), built
    vectorised after the loop; the same numbers the per-step recorder wrote."""
    lay = ctrl.layout
    n, m, p = lay.n, lay.m, lay.p
    rec = TraceRecorder(n_rec, p)
    a = rec.arrays
    o = out_log[:n_rec]

    def blk(name: str) -> np.ndarray:
        off, size = lay.out_blocks[name]
        return o[:, off:off + size]

    io = io_log[:n_rec]
    rho = blk("rho")[:, 0]
    s = blk("s")
    gate = blk("gate")[:, 0]
    a["t_s"][:] = t_log[:n_rec]
    a["q_rad"][:], a["qdot_rad_s"][:] = io[:, :n], io[:, n:2 * n]
    a["wrench_raw_f"][:], a["q_ref_rad"][:] = io[:, 2 * n:2 * n + 6], io[:, 2 * n + 6:]
    for ch, name in (("w_env_w", "w_env"), ("s", "s"), ("s_dot_meas", "s_dot_meas"), ("s_dot_pred", "s_dot_pred"),
                     ("F_value", "F"), ("xi", "xi_cmd"), ("theta", "theta_used"), ("eps_w", "eps_w")):
        a[ch][:] = blk(name)
    a["drive_scale"][:] = rho
    a["adapt_gate"][:] = gate
    a["phi_norm2"][:] = blk("phi_norm2")[:, 0]
    a["theta_dot_track"][:] = blk("d_track") / ctrl.dt
    a["theta_dot_pred"][:] = blk("d_pred") / ctrl.dt
    a["theta_uncertainty"][:] = blk("uncertainty")[:, 0]  # the law's sqrt(tr P / tr P0); NaN without covariance
    on = rho > 0
    a["depth_ok"][:] = on & (s[:, 0] >= monitor.d_seat)
    a["force_ok"][:] = on & (np.hypot(s[:, 1], s[:, 2]) < monitor.f_max)
    a["moment_ok"][:] = on & (np.sqrt(s[:, 3] ** 2 + s[:, 4] ** 2 + s[:, 5] ** 2) < monitor.m_max)
    if theta_true is not None:  # evaluation side: the law's filtered regressor against the true offset
        Phi_f = phi_log[:n_rec].reshape(n_rec, p, m).transpose(0, 2, 1)  # (N, m, p)
        bias = a["eps_w"] - ctrl.W * np.matmul(Phi_f, (theta_true - a["theta"])[:, :, None])[:, :, 0]
        a["truth_bias_w"][:] = np.where(gate[:, None] > 0.0, bias, np.nan)
    else:
        a["truth_bias_w"][:] = np.nan
    a["truth_tip_depth_m"][:] = truth_log[:n_rec, 0]
    a["truth_tip_pos_w_m"][:] = tip_log[:n_rec]
    a["truth_contact_face"][:] = truth_log[:n_rec, 1] > 0
    a["truth_contact_bore"][:] = truth_log[:n_rec, 2] > 0
    a["truth_contact_force_N"][:] = truth_log[:n_rec, 3]
    rec.n = n_rec
    return rec.finish(meta)
