"""The end of an episode: its trace and summary from the loop's raw logs (``runs.loop``).

The truth firewall holds here as in the loop: the trace's controller-side channels come from the
controller's ``out`` rows and the samples it was given; the ``truth_*`` channels from the
simulator's per-step truth (``sim.scenes.SceneBatch.truth_into``), for evaluation only. Success
and failure are judged from sensor-side signals (``SeatMonitor``, ``classify_failure``); the
truth only checks them afterwards.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from kinadapt_nn.config import ExperimentCfg, arm_mjcf_path
from kinadapt_nn.controller.controller import Controller
from kinadapt_nn.controller.core import RANK_GATE  # the paper's kinematic gate (1e-6)
from kinadapt_nn.runs.evaluate import certificate_check, evaluate_offline, summarize
from kinadapt_nn.runs.monitor import SeatMonitor
from kinadapt_nn.sensing import CHANNEL_NAMES
from kinadapt_nn.sim.adapter import PegInHoleSim
from kinadapt_nn.sim.truth import TrueSensorJacobian
from kinadapt_nn.trace import Trace, TraceRecorder


class EpisodeResult(NamedTuple):
    trace: Trace  #: every logged channel
    summary: dict  #: the run-outputs contract (``summary.json``)


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


class EpisodeEnd(NamedTuple):
    """How an episode's loop ended (what its logs do not hold)."""

    n_logged: int  #: logged rows written
    steps: int  #: control steps taken (a sample refused as diverged is one)
    t_end_s: float  #: the episode's final simulated time [s]
    wall_s: float  #: the episode's wall time [s] (its share of a batch's)
    diverged: bool  #: stopped by a sensor error, a MuJoCo warning or the rank gate
    divergence_reason: str | None  #: what stopped it, in words (None: not diverged)
    lam_min_all: float  #: min of lambda_min(W J_hat J_hat^T W) over the steps with the drive on (inf: none)
    rank_breach_t: float | None  #: when the rank gate was first breached [s], else None


class MonitorBrief(NamedTuple):
    """What a run's live monitor found, in brief (``kinadapt_nn.monitor``; the aggregates of compare,
    sweep and work cells)."""

    events: int  #: events named (0 with the monitor on and nothing found)
    shapes: list[str]  #: each event's shape, in the order named

    @property
    def text(self) -> str:
        """``"2: world_force, ft_bias_drift"``, ``"0"``."""
        return f"{self.events}" + (f": {', '.join(self.shapes)}" if self.shapes else "")


def monitor_brief(summary: dict) -> MonitorBrief | None:
    """The monitor's events of a run (``summary["monitor"]``); a work cell's or a run of several
    insertions' summed over its insertions (``summary["insertions"]`` rows' ``monitor_shapes``).
    None: the run had no monitor."""
    rows = summary.get("insertions") or []
    if rows and all("monitor_shapes" in r for r in rows):
        shapes = [sh for r in rows for sh in r["monitor_shapes"]]
        return MonitorBrief(len(shapes), shapes)
    mon = summary.get("monitor")
    if not mon:
        return None
    return MonitorBrief(len(mon["events"]), [e["shape"] for e in mon["events"]])


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
                   end: EpisodeEnd, keep_regressor: bool = False) -> EpisodeResult:
    """An episode's trace and summary from its loop's logs and the controller's final state.
    ``sim``: the episode's simulator object, for its truth-side config and geometry only (its
    MjData is not read: ``end.t_end_s`` is the episode's final simulated time). ``keep_regressor``:
    also keep the law's filtered regressor rows as ``trace.arrays["law_Phi_fT"]`` (N, p, m)."""
    n_logged = end.n_logged
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
    trace = _trace_from_logs(ctrl, meta, n_logged, logs, theta_true, monitor)
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
    trace.meta["min_lambda_JJt_all_steps"] = float(end.lam_min_all) if math.isfinite(end.lam_min_all) else None
    trace.meta["rank_gate_breach_t_s"] = end.rank_breach_t
    certificate = certificate_check(tcfg, trace, ctrl)
    summary = summarize(tcfg, trace, ctrl, monitor, end.diverged, end.steps, end.t_end_s, end.wall_s)
    summary["certificate"] = certificate
    summary["sensor_dropouts"] = int(ctrl.dropouts)
    summary["divergence_reason"] = end.divergence_reason
    return EpisodeResult(trace, summary)


def _trace_from_logs(ctrl: Controller, meta: dict, n_rec: int, logs: EpisodeLogs, theta_true: np.ndarray | None,
                     monitor: SeatMonitor) -> Trace:
    """The trace channels from the loop's raw logs (controller ``out`` rows, I/O rows, truth), built
    vectorised after the loop; the same numbers the per-step recorder wrote. ``theta_true``: the
    true offset (p,) [m] where theta is one (the ``truth_bias_w`` channel), else None."""
    t_log, out_log, io_log, phi_log, tip_log, truth_log = logs.t, logs.out, logs.io, logs.phi, logs.tip, logs.truth
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
