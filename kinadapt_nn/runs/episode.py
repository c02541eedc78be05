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
from pathlib import Path
from typing import NamedTuple

import numpy as np

from kinadapt_nn.config import ExperimentCfg, arm_mjcf_path
from kinadapt_nn.controller.controller import Controller, rank_margin
from kinadapt_nn.controller.core import RANK_GATE  # the paper's kinematic gate (1e-6)
from kinadapt_nn.errors import SensorError
from kinadapt_nn.features import AdjointFeatures
from kinadapt_nn.features.base import Features
from kinadapt_nn.known import KnownCfg
from kinadapt_nn.sensing import CHANNEL_NAMES, channel_metric, nominal_sensor_map
from kinadapt_nn.known import BORE_AXIS_W
from kinadapt_nn.sim.adapter import PegInHoleSim
from kinadapt_nn.sim.faults import SensorFaults
from kinadapt_nn.trace import Trace, TraceRecorder
from kinadapt_nn.sim.truth import TrueSensorJacobian

FAILURES = ("none", "timeout", "jam", "block_face", "divergence")


class SeatMonitor:
    """Sensor-side success: depth reached, |F_lat| and |M| inside limits, held ``hold_s``."""

    def __init__(self, cfg: ExperimentCfg) -> None:
        sc = cfg.success
        self.d_seat = sc.depth_m - sc.depth_tol_m
        self.f_max = sc.max_lateral_force_N
        self.m_max = sc.max_moment_Nm
        self.hold = sc.hold_s
        self.since: float | None = None
        self.seat_time: float | None = None

    def update(self, t: float, s: np.ndarray) -> tuple[bool, bool, bool]:
        s0, s1, s2, s3, s4, s5 = s.tolist()
        depth_ok = s0 >= self.d_seat
        force_ok = math.hypot(s1, s2) < self.f_max
        moment_ok = math.sqrt(s3 * s3 + s4 * s4 + s5 * s5) < self.m_max
        if depth_ok and force_ok and moment_ok:
            if self.since is None:
                self.since = t
            if self.seat_time is None and t - self.since >= self.hold - 1e-12:
                self.seat_time = t
        else:
            self.since = None
        return depth_ok, force_ok, moment_ok


def classify_failure(cfg: ExperimentCfg, t: np.ndarray, s: np.ndarray, w_env: np.ndarray, diverged: bool) -> str:
    """Failure class of an unseated run from sensor-side channels only.

    ``divergence``: non-finite samples or a contact force beyond ``diverge_force_N``;
    ``block_face``: the last ``jam_window_s`` spent loaded with the sensor depth above
    ``face_depth_m`` (the peg never entered); ``jam``: loaded inside the bore with no depth
    progress over the last window; otherwise ``timeout``.
    """
    sc = cfg.success
    fmag = np.linalg.norm(w_env[:, :3], axis=1) if len(t) else np.zeros(0)
    if diverged or (len(fmag) and (not np.all(np.isfinite(fmag)) or fmag.max() > sc.diverge_force_N)):
        return "divergence"
    if len(t) == 0:
        return "timeout"
    win = t >= t[-1] - sc.jam_window_s
    loaded = np.median(fmag[win]) > sc.jam_force_N or np.median(np.linalg.norm(s[win, 3:], axis=1)) > sc.max_moment_Nm
    progress = s[win, 0].max() - s[win, 0].min()
    if loaded and progress < sc.jam_progress_m:
        return "block_face" if s[win, 0].mean() < sc.face_depth_m else "jam"
    return "timeout"


def initial_estimate(cfg: ExperimentCfg) -> np.ndarray:
    """theta0 = true offset + ``initial_error_m`` along ``initial_error_dir_f`` (default: away
    from the flange axis, along the true lateral offset). Experiment design: the controller
    receives the number, never the truth it was derived from. -> (3,) in f [m]."""
    ad = cfg.adaptation
    true = np.asarray(cfg.tool.offset_f_m, dtype=float)
    direction = np.asarray(ad.initial_error_dir_f, dtype=float)
    if not np.any(direction):
        direction = np.array([true[0], true[1], 0.0])
        if not np.any(direction):
            direction = np.array([1.0, 0.0, 0.0])
    return true + ad.initial_error_m * direction / np.linalg.norm(direction)


def make_features(cfg: ExperimentCfg) -> tuple[Features, np.ndarray]:
    """``_base_features`` plus, with ``model.effects``, the library effects' columns
    (``kinadapt_nn.features.effects``; their parameters start at 0)."""
    feats, theta0 = _base_features(cfg)
    if cfg.model.effects:
        from kinadapt_nn.features.effects import EffectFeatures

        feats = EffectFeatures(feats, list(cfg.model.effects), KnownCfg.of(cfg), nominal_sensor_map(cfg.sensing, BORE_AXIS_W))
        theta0 = np.r_[theta0, np.zeros(feats.k)]
    return feats, theta0


def _base_features(cfg: ExperimentCfg) -> tuple[Features, np.ndarray]:
    """Features object and the initial parameters for ``run.features``.

    Nothing here uses the truth except the two declared cases: ``oracle`` (the true offset) and
    the adjoint's initial estimate (true offset + the configured error, experiment design)."""
    S = nominal_sensor_map(cfg.sensing, BORE_AXIS_W)
    l_nom = np.asarray(cfg.sensing.nominal_offset_f_m, dtype=float)
    ad = cfg.adaptation
    adjoint = AdjointFeatures(S, l_nom, np.array([ad.omega_lateral_m, ad.omega_lateral_m, ad.omega_axial_m]))
    kind = cfg.run.features
    if kind == "oracle":
        return adjoint, np.asarray(cfg.tool.offset_f_m, dtype=float)
    adjoint.P0 = np.diag([ad.prior_sd_lateral_m**2, ad.prior_sd_lateral_m**2, ad.prior_sd_axial_m**2])
    if kind == "adjoint":
        return adjoint, initial_estimate(cfg)
    if kind == "rbf":
        from kinadapt_nn.features.rbf import RBFFeatures, auto_width
        from kinadapt_nn.sim.workspace import insertion_path, sample_workspace

        fc = cfg.features
        nominal = cfg.model_copy(update={"tool": cfg.tool.model_copy(update={"offset_f_m": tuple(l_nom), "tilt_deg": (0.0, 0.0)}),
                                         "arm": type(cfg.arm)()})
        if fc.rbf_centres == "path":
            centres = insertion_path(nominal, n=fc.rbf_n_centres)
        else:
            path = insertion_path(nominal)
            centres = sample_workspace(path, fc.rbf_n_centres, 0.03, np.random.default_rng(fc.rbf_seed))
        width = fc.rbf_width_rad or auto_width(centres)
        feats = RBFFeatures(adjoint, l_nom, centres, width)
        from kinadapt_nn.controller.controller import ArmKinematics

        feats.P0 = feats.prior_from_adjoint(ArmKinematics(arm_mjcf_path(cfg.scene)), adjoint.P0, ad.rbf_prior_floor)
        return feats, np.zeros(feats.n_params)
    if kind == "neural":
        from kinadapt_nn.features.neural import NeuralFeatures
        from kinadapt_nn.robot import MODELS_DIR

        ckpt = Path(cfg.features.neural_checkpoint) if cfg.features.neural_checkpoint else MODELS_DIR / "neural_default.pt"
        feats = NeuralFeatures(adjoint, l_nom, ckpt, channel_metric(cfg.sensing))
        feats.P0 = feats.prior_cov()  # the pretraining heads' second moment about the nominal head
        return feats, np.zeros(feats.n_params)  # the head of the nominal tool (zero residual)
    raise ValueError(f"unknown features {kind!r}")  # pragma: no cover (validated by the config)


def law_name(cfg: ExperimentCfg) -> str:
    return "frozen" if cfg.run.features == "oracle" else cfg.adaptation.mode


def make_controller(cfg: ExperimentCfg) -> Controller:
    feats, theta0 = make_features(cfg)
    return Controller(KnownCfg.of(cfg), feats, theta0)


class EpisodeResult(NamedTuple):
    trace: Trace  #: every logged channel
    summary: dict  #: the run-outputs contract (``summary.json``)


def run_insertions(cfg: ExperimentCfg, progress: bool = False) -> EpisodeResult:
    """``run.insertions`` consecutive insertions of the same tool on the same arm (a work cell):
    the controller's theta and its law's covariance are carried from one to the next; insertion
    i uses seed ``run.seed + i`` (its start jitter). -> the last insertion's result, with
    ``summary["insertions"]`` one row per insertion. One insertion is ``run_episode``."""
    n = cfg.run.insertions
    if n == 1:
        return run_episode(cfg, progress)
    ctrl = make_controller(cfg)
    rows = []
    res = None
    for i in range(n):
        cfg_i = cfg.model_copy(update={"run": cfg.run.model_copy(update={"seed": (cfg.run.seed + i) % 2**32})})
        if i:
            ctrl.reset(carry_estimate=True)
        res = run_episode(cfg_i, progress, ctrl=ctrl)
        s = res.summary
        rows.append({"insertion": i + 1, "success": s["success"], "failure": s["failure"], "seat_time_s": s["seat_time_s"],
                     "jacobian_rel_error_initial": s["jacobian_rel_error_initial"],
                     "jacobian_rel_error_final": s["jacobian_rel_error_final"],
                     "offset_error_lateral_final_m": s.get("offset_error_lateral_final_m"),
                     "theta_sd_final": s.get("theta_sd_final"), "max_force_N": s["max_force_N"]})
    res.summary["insertions"] = rows
    return res


def run_episode(cfg: ExperimentCfg, progress: bool = False, ctrl: Controller | None = None) -> EpisodeResult:
    """Simulate one insertion with config ``cfg``. Deterministic for a given config. ``ctrl``: a
    controller to use as it is (``run_insertions`` carries one over), else a new one."""
    wall0 = time.perf_counter()
    sim = PegInHoleSim(cfg)
    ctrl = make_controller(cfg) if ctrl is None else ctrl
    tcfg = sim.cfg  # the truth-side config (hidden effects folded in): evaluation only
    dt = cfg.run.dt_s
    n_steps = int(round(cfg.run.duration_s / dt))
    every = cfg.run.log_every
    n_rec = n_steps // every + 1
    monitor = SeatMonitor(cfg)
    faults = SensorFaults(cfg.faults, cfg.run.seed, cfg.start.settle_s) if SensorFaults.active(cfg.faults) else None
    theta_true = np.asarray(tcfg.tool.offset_f_m, dtype=float) if ctrl.features.theta_is_offset else None
    diverged = False
    divergence_reason = None
    warn0 = int(sim.data.warning.number.sum())
    stop_at: float | None = None
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
    phi_log = np.zeros((n_rec, p * m)) if theta_true is not None else None
    tip_log = np.zeros((n_rec, 3))
    truth_log = np.zeros((n_rec, 4))  # depth, face, bore, normal force
    lam_log = np.full(n_rec, math.inf)
    k = 0
    n_logged = 0
    lam_min_all = math.inf  # the rank gate, every step with the drive on
    lam_since = math.inf  # its minimum since the last logged sample
    rank_breach_t: float | None = None
    inp = ctrl.input_row  # the sample is written straight into the controller's input row
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
            divergence_reason = f"non-finite sensor sample: {exc}"
            break
        sim.apply(q_ref, qdot_ref)
        if out[i_rho] > 0:  # seat monitor and the rank gate every step (paper Results, "A separate kinematic gate")
            monitor.update(t, out[i_s:i_s + 6])
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
                phi_log[j] = x_row[f0:f0 + p * m]
            tr = sim.truth()
            tip_log[j] = tr.tip_pos_w_m
            truth_log[j] = (tr.tip_depth_m, tr.contact_face, tr.contact_bore, tr.contact_force_N)
        sim.step()
        read_sample()
        t = sim.time_s
        if bar is not None and k % 250 == 0:
            bar.update(250 if k else 1)
        if monitor.seat_time is not None and stop_at is None:
            stop_at = monitor.seat_time + cfg.run.stop_after_seat_s
        if stop_at is not None and t >= stop_at:
            break
        # (a non-finite simulator state reaches the controller as a sensor sample: SensorError)
        if rank_breach_t is not None:
            diverged = True
            divergence_reason = f"rank gate breached (lambda_min {lam_min_all:.3g} < {RANK_GATE:g}) at t={rank_breach_t:.3f} s"
            break
        if k % 100 == 0:  # divergence watch at 10 Hz: MuJoCo warnings
            nwarn = int(sim.data.warning.number.sum())
            if nwarn > warn0:
                diverged = True
                divergence_reason = f"MuJoCo warning(s) at t={t:.3f} s"
                break
    if bar is not None:
        bar.close()
    steps = k + 1
    wall = time.perf_counter() - wall0
    meta = {
        "dt_s": dt * every,
        "features": cfg.run.features,
        "seed": cfg.run.seed,
        "truth_offset_f_m": list(tcfg.tool.offset_f_m),
        "channel_names": list(CHANNEL_NAMES),
        "bore_entry_w_m": list(cfg.scene.bore_entry_w_m),
        "start_lateral_w_m": [float(x) for x in sim.start_lateral_w_m],
        "start_tilt_deg": [float(x) for x in sim.start_tilt_deg],
    }
    trace = _trace_from_logs(ctrl, cfg, meta, n_logged, t_log, out_log, io_log, phi_log, tip_log, truth_log,
                             theta_true, monitor)
    lam_log = lam_log[:n_logged]
    truth_jac = TrueSensorJacobian(
        ctrl.S, ctrl.l_nom_f, np.asarray(tcfg.tool.offset_f_m), arm_mjcf_path(cfg.scene),
        tcfg.arm.link_length_error_m, tcfg.arm.joint_offset_rad,
    )
    evaluate_offline(trace, ctrl, truth_jac=truth_jac)
    lam_arr = lam_log[: len(trace)]  # per-step minima where the drive was on
    if len(lam_arr) == len(trace):
        trace.arrays["lambda_min"] = np.where(np.isfinite(lam_arr), lam_arr, trace["lambda_min"])
    trace.meta["min_lambda_JJt_all_steps"] = float(lam_min_all) if math.isfinite(lam_min_all) else None
    trace.meta["rank_gate_breach_t_s"] = rank_breach_t
    certificate = certificate_check(tcfg, trace, ctrl)
    summary = summarize(tcfg, trace, ctrl, monitor, diverged, steps, sim.time_s, wall)
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
    a["theta_uncertainty"][:] = np.sqrt(np.maximum(blk("p_trace")[:, 0], 0.0) / ctrl.law._trP0)
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


def implied_offset(ctrl: Controller, q: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """The adjoint offset whose Jacobian best fits ``J_hat(q; theta)`` (W-scaled rows 1..5, LS;
    exact because ``S Ad(R l) J_arm`` is affine in l). -> (3,) [m] in f."""
    kin = ctrl.kin(q)
    adj = AdjointFeatures(ctrl.S, ctrl.l_nom_f)
    J_hat = ctrl.features.jacobian(kin, theta)
    J0 = adj.jacobian(kin, np.zeros(3))
    B = np.stack([(adj.jacobian(kin, e) - J0)[1:] for e in np.eye(3)], axis=-1)  # (5, n, 3)
    Wr = ctrl.W[1:, None, None]
    x, *_ = np.linalg.lstsq((Wr * B).reshape(-1, 3), (Wr[:, :, 0] * (J_hat - J0)[1:]).ravel(), rcond=None)
    return x


def identification_words(ctrl: Controller, cfg: ExperimentCfg) -> dict:
    """What was and was not identified, and why, in plain words (the summary's first explanation)."""
    law = ctrl.law
    p = ctrl.features.n_params
    k = law.identified_directions()
    where = "kinadapt online --config online/identify_socket.toml (a matched socket with a commanded dither)"
    if cfg.run.features == "oracle" or law.mode == "frozen":
        return {"identified": None, "of": p, "text": "theta held fixed (frozen / oracle): nothing to identify"}
    if k is None:
        return {"identified": None, "of": p,
                "text": (f"the paper's {law.mode} law follows the data whatever their bias: in the bore the estimate "
                         "tracks the contact bias, not the offset (docs/identification.md); where it works: " + where)}
    ratio = law.uncertainty_ratio()
    r = np.sqrt(np.mean(law.r2)) if law._r2_primed else float("nan")
    if k == 0 and not law._r2_primed:
        txt = ("nothing identified: no contact was sensed, so there was nothing to learn from (theta at its prior); "
               f"identification needs contact and excitation: {where}")
    elif k == 0:
        txt = (f"nothing identified: theta stayed at its prior (uncertainty {100 * ratio:.0f}% of the prior) - in "
               f"contact the measured residual (RMS {r:.3g}, W-scaled, the bias b included) was not beaten by what the "
               f"parameters can explain with this motion; identification needs excitation: {where}")
    elif k < p:
        txt = (f"{k} of {p} directions of theta identified (posterior sd < {law._act_ratio:g} x prior); the others stay at "
               f"the prior: this motion does not excite them above the measured residual (RMS {r:.3g})")
    else:
        txt = f"all {p} directions of theta identified (uncertainty {100 * ratio:.0f}% of the prior)"
    return {"identified": k, "of": p, "uncertainty_ratio": ratio, "text": txt}


def evaluate_offline(trace: Trace, ctrl: Controller, rank_every: int = 25, truth_jac=None) -> None:
    """Fill ``V`` and ``lambda_min`` from logged controller-side channels (``s``, ``q``,
    ``theta``): the numbers the controller would compute, kept off the 1 kHz hot path.
    ``lambda_min`` (and the truth Jacobian error) are evaluated every ``rank_every`` samples
    (25 ms at 1 kHz) and held in between."""
    s = trace["s"]
    trace.arrays["V"] = ctrl.value_fn.value_batch(s)
    n = len(s)
    lam = np.empty(n)
    jerr = np.full(n, np.nan)
    W = ctrl.W[:, None]
    for i in range(0, n, rank_every):
        J_hat = ctrl.features.jacobian(ctrl.kin(trace["q_rad"][i]), trace["theta"][i])
        lam[i : i + rank_every] = rank_margin(ctrl.W, J_hat)
        if truth_jac is not None:  # evaluation only: W-scaled relative Frobenius error
            J_true = truth_jac(trace["q_rad"][i])
            jerr[i : i + rank_every] = np.linalg.norm(W * (J_hat - J_true)) / np.linalg.norm(W * J_true)
    if n and truth_jac is not None:
        J_true = truth_jac(trace["q_rad"][-1])
        J_hat = ctrl.features.jacobian(ctrl.kin(trace["q_rad"][-1]), trace["theta"][-1])
        jerr[-1] = np.linalg.norm(W * (J_hat - J_true)) / np.linalg.norm(W * J_true)
    trace.arrays["lambda_min"] = lam
    trace.arrays["truth_jacobian_rel_error"] = jerr


FLANGE_AXES = ("x_f", "y_f", "z_f")


def certificate_check(cfg: ExperimentCfg, trace: Trace, ctrl: Controller, window_s: float = 0.05) -> dict | None:
    """Simulation-side check of eqs. cp_lyap / cp_iss (evaluation only: uses the true offset).

    ``V_tot = gamma_d (V(s) + 1/2 xi^T M xi + S_c) + |theta - theta_true|^2 / (2 Gamma)`` with the
    *nominal* contact storage ``S_c = 1/2 (|f|^2 / k_t + |m|^2 / k_r)`` of the wrench at O, and
    the bound rate of eq. cp_iss in our scaling: ``-gamma_d xi^T D xi + kappa/4 |b|^2`` with the
    per-step prediction gain ``kappa = eta / (dt Gamma (||W Phi_f||^2 + eps_norm))`` (only while
    the prediction term runs). Reports the worst excess of ``Delta V_tot`` over the integrated
    bound in ``window_s`` windows after the drive ramp. Returns None for non-adjoint features.
    """
    if not ctrl.features.theta_is_offset or len(trace) < 3:
        return None
    ad, sc = cfg.adaptation, cfg.sensing
    dt = float(trace.meta["dt_s"])
    xi, w, theta = trace["xi"], trace["w_env_w"], trace["theta"]
    true = np.asarray(cfg.tool.offset_f_m, dtype=float)
    kin = 0.5 * np.sum(ctrl.M_virt * xi**2, axis=1)
    S_c = 0.5 * (np.sum(w[:, :3] ** 2, axis=1) / sc.stiffness_lat_N_per_m
                 + np.sum(w[:, 3:] ** 2, axis=1) / max(sc.stiffness_rot_Nm_per_rad, 1e-9))
    param = 0.5 * np.sum((theta - true) ** 2, axis=1) / ad.gamma
    V_tot = ad.gamma_d * (trace["V"] + kin + S_c) + param
    trace.arrays["truth_V_tot"] = V_tot
    D = (1.0 + np.array([cfg.control.beta_trans] * 3 + [cfg.control.beta_ang] * 3)) / np.array(
        [cfg.control.gain_trans] * 3 + [cfg.control.gain_ang] * 3
    )
    diss = ad.gamma_d * np.sum(D * xi**2, axis=1)
    pred_on = (trace["phi_norm2"] > 0) & (law_name(cfg) in ("composite", "prediction"))
    kappa = np.where(pred_on, ad.eta / (dt * ad.gamma * (trace["phi_norm2"] + ad.eps_norm)), 0.0)
    b2 = np.nan_to_num(np.sum(trace["truth_bias_w"] ** 2, axis=1))
    bound_rate = -diss + 0.25 * kappa * b2
    t = trace["t_s"]
    start = cfg.start.settle_s + cfg.control.ramp_s
    n_win = max(1, int(round(window_s / dt)))
    idx = np.flatnonzero(t >= start)
    if len(idx) < n_win + 1:
        return None
    i0s = np.arange(idx[0], len(t) - n_win, n_win)
    dV = V_tot[i0s + n_win] - V_tot[i0s]
    cum = np.concatenate([[0.0], np.cumsum(bound_rate[:-1] * dt)])
    bound = cum[i0s + n_win] - cum[i0s]
    excess = dV - bound
    worst = int(np.argmax(excess))
    return {
        "window_s": window_s,
        "windows": int(len(i0s)),
        "worst_excess": float(excess[worst]),
        "worst_excess_at_s": float(t[i0s[worst]]),
        "worst_excess_over_V_tot": float(excess[worst] / max(V_tot[i0s[worst]], 1e-300)),
        "fraction_windows_violating": float(np.mean(excess > 0.0)),
        "V_tot_start": float(V_tot[idx[0]]),
        "V_tot_final": float(V_tot[-1]),
    }


def identification_report(trace: Trace, ctrl: Controller, true_offset: np.ndarray) -> dict:
    """Observability and uncertainty of the offset over the contact phase (gate = 1).

    * ``regressor_gram``: eigen-decomposition of the mean W-scaled regressor Gram
      ``<(W Phi_f)^T (W Phi_f)>`` [1/s^2 per m^2], eigenvalues in the order of the flange axis each
      eigenvector is closest to (x_f, y_f, z_f), not sorted.
    * ``pred_error_rms_contact_w``: RMS of the W-scaled prediction error in contact (for the
      oracle this *is* the bias b of eq. ft_pred, filtered).
    * ``offset_uncertainty_m``: least-squares standard deviation of each offset component from
      the residual, ``sqrt(diag(sigma^2 H^-1 N/N_eff))``, ``H`` the summed Gram, ``N_eff`` from the
      residual's lag-1 autocorrelation. Statistical only: a bias b that co-varies with the motion
      is not in it (compare ``offset_error_final_m``).
    """
    law = ctrl.law
    p = ctrl.features.n_params
    out: dict = {"contact_steps": int(law.gram_n)}
    gate = trace["adapt_gate"] > 0
    if law.gram_n == 0 or not gate.any():
        out.update(regressor_gram=None, pred_error_rms_contact_w=None, offset_uncertainty_m=None)
        return out
    G = law.gram_sum / law.gram_n
    lam, vec = np.linalg.eigh(G)
    eps = trace["eps_w"][gate]
    out["pred_error_rms_contact_w"] = float(np.sqrt(np.mean(np.sum(eps**2, axis=1))))
    if p == 3:
        order = []
        for ax in range(3):  # eigenvector closest to each flange axis, without reuse
            cand = [j for j in np.argsort(-np.abs(vec[ax])) if j not in order]
            order.append(int(cand[0]))
        out["regressor_gram"] = {
            "axes": list(FLANGE_AXES),
            "eigenvalues": [float(lam[j]) for j in order],
            "eigenvectors_f": [[float(x) for x in vec[:, j]] for j in order],
            "separation_max_over_min": float(lam.max() / max(lam.min(), 1e-300)),
        }
    else:
        out["regressor_gram"] = {"eigenvalues": [float(x) for x in lam[::-1]], "separation_max_over_min":
                                 float(lam.max() / max(lam.min(), 1e-300))}
    sigma2 = float(np.mean(eps**2))
    e = eps - eps.mean(axis=0)
    den = float(np.sum(e[:-1] ** 2))
    rho1 = float(np.sum(e[1:] * e[:-1]) / den) if den > 0 else 0.0
    rho1 = min(max(rho1, 0.0), 0.999)
    n_ratio = (1.0 + rho1) / (1.0 - rho1)  # N / N_eff
    H = law.gram_sum
    try:
        cov = sigma2 * np.linalg.inv(H) * n_ratio
        out["offset_uncertainty_m"] = [float(np.sqrt(max(c, 0.0))) for c in np.diag(cov)][:p] if p <= 12 else None
    except np.linalg.LinAlgError:
        out["offset_uncertainty_m"] = None
    out["residual_lag1_autocorr"] = rho1
    return out


def summarize(
    cfg: ExperimentCfg,
    trace: Trace,
    ctrl: Controller,
    monitor: SeatMonitor,
    diverged: bool,
    steps: int,
    sim_time: float,
    wall: float,
) -> dict:
    """The ``summary.json`` contract (README, "What the run writes") plus run-specific figures."""
    t, s, w = trace["t_s"], trace["s"], trace["w_env_w"]
    active = trace["drive_scale"] > 0
    success = monitor.seat_time is not None and not diverged
    failure = "none" if success else classify_failure(cfg, t[active], s[active], w[active], diverged)
    if trace.meta.get("rank_gate_breach_t_s") is not None:  # a breach is its own failure class
        success, failure = False, "rank_gate"
    if cfg.control.program == "excite":  # an identification experiment: it completes, it does not seat
        success = not diverged and failure != "divergence"
        failure = "none" if success else failure
    fmag = np.linalg.norm(w[:, :3], axis=1)
    mmag = np.linalg.norm(w[:, 3:], axis=1)
    flat = np.hypot(s[:, 1], s[:, 2])
    # prediction error through the same filter on both sides
    eps = trace["s_dot_meas"][active] - trace["s_dot_pred"][active]
    pred_rms = {name: float(np.sqrt(np.mean(eps[:, i] ** 2))) if len(eps) else None for i, name in enumerate(CHANNEL_NAMES)}
    in_contact = trace["adapt_gate"][active] > 0  # where the law adapts (S's contact model applies)
    eps_c = eps[in_contact]
    pred_rms_contact = {name: float(np.sqrt(np.mean(eps_c[:, i] ** 2))) if len(eps_c) else None
                        for i, name in enumerate(CHANNEL_NAMES)}
    theta = trace["theta"][-1] if len(trace) else ctrl.theta
    true_off = np.asarray(cfg.tool.offset_f_m)
    jerr = trace["truth_jacobian_rel_error"]
    jac_err = float(jerr[-1]) if len(trace) else None
    # offset: the estimate itself (adjoint) or the offset implied by a LS fit of J_hat (others)
    if not len(trace):
        off0 = off_T = np.full(3, np.nan)
    elif ctrl.features.theta_is_offset:
        off0, off_T = trace["theta"][0], theta
    elif len(trace):
        off0 = implied_offset(ctrl, trace["q_rad"][0], trace["theta"][0])
        off_T = implied_offset(ctrl, trace["q_rad"][-1], theta)
    else:
        off0 = off_T = np.full(3, np.nan)
    tip = trace["truth_tip_pos_w_m"]
    touched = trace["truth_contact_face"] | trace["truth_contact_bore"]
    first_touch = int(np.argmax(touched)) if touched.any() else len(trace)
    drift = np.linalg.norm(tip[:, :2] - tip[0, :2], axis=1) if len(trace) else np.zeros(1)
    seated = success and monitor.seat_time is not None
    seat_idx = int(np.searchsorted(t, monitor.seat_time)) if seated else None
    ident = identification_report(trace, ctrl, true_off)
    return {
        "success": bool(success),
        "failure": failure,
        "seat_time_s": monitor.seat_time if seated else None,
        "final_depth_m": float(s[-1, 0]) if len(trace) else None,
        "true_final_depth_m": float(trace["truth_tip_depth_m"][-1]) if len(trace) else None,
        "true_depth_at_seat_m": float(trace["truth_tip_depth_m"][min(seat_idx, len(trace) - 1)]) if seated else None,
        "max_force_N": float(fmag.max()) if len(fmag) else None,
        "max_lateral_force_N": float(flat.max()) if len(flat) else None,
        "max_moment_Nm": float(mmag.max()) if len(mmag) else None,
        "identification": identification_words(ctrl, cfg),
        "theta_sd_final": (None if ctrl.law.information_sd() is None
                           else [float(x) for x in ctrl.law.information_sd()][:12]),
        "min_lambda_JJt": (trace.meta.get("min_lambda_JJt_all_steps") if "min_lambda_JJt_all_steps" in trace.meta
                           else float(trace["lambda_min"][active].min()) if active.any() else None),
        "rank_gate": {"threshold": RANK_GATE, "checked": "every control step with the drive on",
                      "breach_t_s": trace.meta.get("rank_gate_breach_t_s")},
        "offset_estimate_final_f_m": [float(x) for x in off_T],
        "offset_error_final_m": [float(x) for x in (off_T - true_off)],
        "jacobian_rel_error_initial": float(jerr[0]) if len(trace) else None,
        "jacobian_rel_error_final": jac_err,
        "pred_error_rms": pred_rms,
        "pred_error_rms_contact": pred_rms_contact,
        "offset_error_lateral_initial_m": float(np.hypot(*(off0[:2] - true_off[:2]))),
        "offset_error_lateral_final_m": float(np.hypot(*(off_T[:2] - true_off[:2]))),
        **ident,
        "lateral_drift_free_space_m": float(drift[: max(first_touch, 1)].max()),
        "lateral_drift_max_m": float(drift.max()),
        "truth_touched_block_face": bool(trace["truth_contact_face"].any()),
        "truth_touched_bore": bool(trace["truth_contact_bore"].any()),
        "features": cfg.run.features,
        "program": cfg.control.program,
        "hidden_effects": cfg.effects.enabled(),
        "law": law_name(cfg),
        "n_params": int(ctrl.features.n_params),
        "model_effects": list(cfg.model.effects),
        "model_effect_params": [float(x) for x in theta[getattr(ctrl.features, "p0", len(theta)):]],
        "seed": cfg.run.seed,
        "start_lateral_w_m": trace.meta.get("start_lateral_w_m"),
        "start_tilt_deg": trace.meta.get("start_tilt_deg"),
        "steps": int(steps),
        "sim_time_s": float(sim_time),
        "wall_time_s": float(wall),
    }
