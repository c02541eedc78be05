"""After the loop: truth-side evaluation of a run (Jacobian error, identification, the
certificate check) and its ``summary.json``. Evaluation only -- nothing here feeds back into a
run.
"""

from __future__ import annotations



import numpy as np

from kinadapt_nn.config import ExperimentCfg
from kinadapt_nn.controller.controller import Controller, rank_margin
from kinadapt_nn.controller.core import RANK_GATE  # the paper's kinematic gate (1e-6)
from kinadapt_nn.features import AdjointFeatures
from kinadapt_nn.sensing import CHANNEL_NAMES, CHANNEL_UNITS
from kinadapt_nn.trace import Trace
from kinadapt_nn.runs.monitor import SeatMonitor, classify_failure


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
    """What was and was not identified, and why, in plain words (the summary's first explanation).

    Said from facts, the same way for every law: the steps with the contact gate open and how far
    theta moved in this insertion, with how many components sit on Omega's bounds (the
    controller's state), and what the law reports of its own state (``ctrl.law``, the law
    module's view: identified directions and uncertainty where the law has a covariance)."""
    law = ctrl.law
    p = ctrl.features.n_params
    where = "kinadapt online --config online/identify_socket.toml (a matched socket with a commanded dither)"
    theta, lo, hi = ctrl.theta, ctrl.consts.pv[0], ctrl.consts.pv[1]
    moved = float(np.linalg.norm(theta - ctrl.theta_start))
    n_bound = int(np.count_nonzero((theta <= lo) | (theta >= hi)))
    unit = " m" if ctrl.features.theta_is_offset else ""
    movement = f"theta moved by {moved:.3g}{unit} from its start; {n_bound} of {p} components at the bounds of Omega"
    out = {"identified": None, "of": p, "contact_steps": ctrl.contact_steps, "theta_moved": moved,
           "at_omega_bounds": n_bound}
    if law.name == "frozen":  # (the oracle runs it: Features.fixed_law)
        return {**out, "text": "theta held fixed (frozen / oracle): nothing to identify"}
    if ctrl.contact_steps == 0:  # the gate never opened: no law adapts in free space
        return {**out, "identified": 0 if law.has_covariance else None,
                "text": ("nothing identified: no contact was sensed, so there was nothing to learn from (theta at its "
                         f"prior); identification needs contact and excitation: {where}")}
    if not law.has_covariance:
        head = movement if moved > 0.0 else f"theta did not move in {ctrl.contact_steps} steps in contact"
        return {**out, "text": (f"{head}; the {law.name} law has no covariance: it follows the data whatever their "
                                "bias (in the bore the estimate tracks the contact bias, not the offset: "
                                f"docs/identification.md); where it works: {where}")}
    k = law.identified_directions()
    ratio = law.uncertainty_ratio()
    r = law.residual_rms()
    if k == 0:
        stay = "theta stayed at its prior" if moved == 0.0 else movement
        txt = (f"nothing identified: {stay} (uncertainty {100 * ratio:.0f}% of the prior) - in contact the measured "
               f"residual (RMS {r:.3g}, W-scaled, the bias b included) was not beaten by what the parameters can "
               f"explain with this motion; identification needs excitation: {where}")
    elif k < p:
        txt = (f"{k} of {p} directions of theta identified ({law.identified_criterion()}); the others stay at the "
               f"prior: this motion does not excite them above the measured residual (RMS {r:.3g}); {movement}")
    else:
        txt = f"all {p} directions of theta identified (uncertainty {100 * ratio:.0f}% of the prior); {movement}"
    return {**out, "identified": k, "uncertainty_ratio": ratio, "text": txt}


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
    pred_on = (trace["phi_norm2"] > 0) & (ctrl.law.name in ("composite", "prediction"))
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
    * ``theta_sd_data_only``: the standard deviation of each parameter (units of theta: m for the
      adjoint) that the contact data *alone* would give, no prior: least squares on the W-scaled
      prediction residual, ``sqrt(diag(sigma^2 H^-1 N/N_eff))``, ``H`` the summed Gram of
      ``W Phi_f``, ``sigma^2`` the residual's mean square, ``N/N_eff = (1 + rho1)/(1 - rho1)`` from
      its lag-1 autocorrelation ``residual_lag1_autocorr``. Metres where the motion does not
      excite a direction (the bore's lateral offset); the law's own posterior, prior included, is
      ``theta_sd_final``. Statistical only: a bias b that co-varies with the motion is not in it
      (compare ``offset_error_final_m``). None for p > 12.
    """
    p = ctrl.features.n_params
    n_contact = ctrl.contact_steps
    out: dict = {"contact_steps": n_contact}
    gate = trace["adapt_gate"] > 0
    if n_contact == 0 or not gate.any():
        out.update(regressor_gram=None, pred_error_rms_contact_w=None, theta_sd_data_only=None)
        return out
    G = ctrl.gram_sum / n_contact
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
    H = ctrl.gram_sum
    try:
        cov = sigma2 * np.linalg.inv(H) * n_ratio
        out["theta_sd_data_only"] = [float(np.sqrt(max(c, 0.0))) for c in np.diag(cov)][:p] if p <= 12 else None
    except np.linalg.LinAlgError:
        out["theta_sd_data_only"] = None
    out["residual_lag1_autocorr"] = rho1
    return out


def contact_quality(t_s: np.ndarray, contact_force_N: np.ndarray) -> dict:
    """How the peg touches (evaluation only, from the simulator's truth): ``t_s`` (T,) [s] and the
    total normal contact force (T,) [N]. From the first contact to the end of the log:
    ``contact_transitions_per_s`` (on/off changes per second -- a peg bouncing off a wall at
    tens of Hz, or a continuous slide near 0), ``longest_contact_span_s`` [s] and
    ``contact_fraction`` (of that span's time in contact). None where there is no contact."""
    on = np.asarray(contact_force_N) > 0.0
    if not on.any():
        return {"contact_transitions_per_s": None, "longest_contact_span_s": None, "contact_fraction": None}
    i0 = int(np.argmax(on))
    on, t = on[i0:], np.asarray(t_s)[i0:]
    dur = float(t[-1] - t[0]) if len(t) > 1 else 0.0
    edges = np.flatnonzero(np.diff(np.r_[0, on.astype(int), 0]))
    starts, ends = edges[::2], edges[1::2]
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    longest = float(max(t[min(e, len(t)) - 1] - t[a] + dt for a, e in zip(starts, ends)))
    transitions = int(np.count_nonzero(np.diff(on.astype(int))))
    return {"contact_transitions_per_s": transitions / dur if dur > 0 else 0.0, "longest_contact_span_s": longest,
            "contact_fraction": float(on.mean())}


def _outcome(cfg: ExperimentCfg, trace: Trace, monitor: SeatMonitor, diverged: bool,
             active: np.ndarray) -> tuple[bool, str]:
    """(success, failure class) of a run; ``active`` (T,) marks the steps with the drive on."""
    t, s, w = trace["t_s"], trace["s"], trace["w_env_w"]
    success = monitor.seat_time is not None and not diverged
    failure = "none" if success else classify_failure(cfg, t[active], s[active], w[active], diverged)
    if trace.meta.get("rank_gate_breach_t_s") is not None:  # a breach is its own failure class
        success, failure = False, "rank_gate"
    if cfg.control.program == "excite":  # an identification experiment: it completes, it does not seat
        success = not diverged and failure != "divergence"
        failure = "none" if success else failure
    return success, failure


def _peaks(trace: Trace) -> dict:
    """The largest measured force |F| [N], lateral force |(s_1, s_2)| [N] and moment |M| [N m]."""
    s, w = trace["s"], trace["w_env_w"]
    fmag = np.linalg.norm(w[:, :3], axis=1)
    mmag = np.linalg.norm(w[:, 3:], axis=1)
    flat = np.hypot(s[:, 1], s[:, 2])
    return {"max_force_N": float(fmag.max()) if len(fmag) else None,
            "max_lateral_force_N": float(flat.max()) if len(flat) else None,
            "max_moment_Nm": float(mmag.max()) if len(mmag) else None}


def _prediction_errors(trace: Trace, active: np.ndarray) -> dict:
    """RMS of the prediction error ds/dt measured - predicted (through the same filter on both
    sides) per channel, over the driven steps and over those where the law adapts (in contact)."""
    eps = trace["s_dot_meas"][active] - trace["s_dot_pred"][active]
    pred_rms = {name: float(np.sqrt(np.mean(eps[:, i] ** 2))) if len(eps) else None for i, name in enumerate(CHANNEL_NAMES)}
    in_contact = trace["adapt_gate"][active] > 0  # where the law adapts (S's contact model applies)
    eps_c = eps[in_contact]
    pred_rms_contact = {name: float(np.sqrt(np.mean(eps_c[:, i] ** 2))) if len(eps_c) else None
                        for i, name in enumerate(CHANNEL_NAMES)}
    return {"pred_error_rms": pred_rms, "pred_error_rms_contact": pred_rms_contact,
            "pred_error_rms_units": {n: u + "/s" for n, u in zip(CHANNEL_NAMES, CHANNEL_UNITS)}}


def _offset_ends(ctrl: Controller, trace: Trace, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The tool offset estimate (3,) [m, flange frame] at the first and the last step: the estimate
    itself (adjoint) or the offset implied by a LS fit of J_hat (others); NaN for an empty trace."""
    if not len(trace):
        return np.full(3, np.nan), np.full(3, np.nan)
    if ctrl.features.theta_is_offset:
        return trace["theta"][0], theta
    return (implied_offset(ctrl, trace["q_rad"][0], trace["theta"][0]),
            implied_offset(ctrl, trace["q_rad"][-1], theta))


def _drift_and_touch(trace: Trace) -> dict:
    """The tip's lateral drift [m] (before the first contact and overall, from the truth) and which
    surfaces the peg touched."""
    tip = trace["truth_tip_pos_w_m"]
    touched = trace["truth_contact_face"] | trace["truth_contact_bore"]
    first_touch = int(np.argmax(touched)) if touched.any() else len(trace)
    drift = np.linalg.norm(tip[:, :2] - tip[0, :2], axis=1) if len(trace) else np.zeros(1)
    return {"lateral_drift_free_space_m": float(drift[: max(first_touch, 1)].max()),
            "lateral_drift_max_m": float(drift.max()),
            "truth_touched_block_face": bool(trace["truth_contact_face"].any()),
            "truth_touched_bore": bool(trace["truth_contact_bore"].any())}


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
    t, s = trace["t_s"], trace["s"]
    active = trace["drive_scale"] > 0
    success, failure = _outcome(cfg, trace, monitor, diverged, active)
    theta = trace["theta"][-1] if len(trace) else ctrl.theta
    true_off = np.asarray(cfg.tool.offset_f_m)
    jerr = trace["truth_jacobian_rel_error"]
    jac_err = float(jerr[-1]) if len(trace) else None
    off0, off_T = _offset_ends(ctrl, trace, theta)
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
        **_peaks(trace),
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
        **_prediction_errors(trace, active),
        "offset_error_lateral_initial_m": float(np.hypot(*(off0[:2] - true_off[:2]))),
        "offset_error_lateral_final_m": float(np.hypot(*(off_T[:2] - true_off[:2]))),
        **ident,
        **contact_quality(t, trace["truth_contact_force_N"]),
        **_drift_and_touch(trace),
        "features": cfg.run.features,
        "program": cfg.control.program,
        "hidden_effects": cfg.effects.enabled(),
        "law": ctrl.law.name,
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
