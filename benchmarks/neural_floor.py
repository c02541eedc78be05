"""Why the neural features stop short of the adjoint in the socket + dither scenario (issue 12).

For each held-out tool of ``kinadapt compare`` (same seed, same draw) this runs the socket +
dither episode with the neural features and the default law, then replays the recorded
encoder and wrench data offline (evaluation only: the truth enters only the error figures) and
prints, as Jacobian errors ``|W (J_hat - J_true)| / |W J_true|`` at the episode's last step:

* ``represent``: the head fitted by least squares to the *true* Jacobian along the recorded
  path -- what the 12-feature basis can represent (its floor);
* ``online``: the online estimate (default law);
* ``batch_ls``: the head fitted by least squares to *all* the measured contact data at once
  (the best any estimator without a prior could do with these data);
* ``batch_ls_lever``: the same with the moment's lever mismatch ``(R l - L n) x f_dot`` modelled
  (3 extra unknowns, a regressor from the measured force rate), which removes most of the
  measured residual;
* ``evid``: the log-evidence of the calibrated-arm prior minus that of the all-arms prior
  (the kalman filter's innovations; > 0 favours a calibrated arm).

``python benchmarks/neural_floor.py [--family nominal|arm_errors] [--tools 4]`` (2 cores: ~4 s a tool).
"""

from __future__ import annotations

import argparse

import numpy as np

from kinadapt_nn.config import arm_mjcf_path, load_config
from kinadapt_nn.controller.laws import kalman
from kinadapt_nn.controller.standalone import StandaloneLaw
from kinadapt_nn.geometry import skew
from kinadapt_nn.known import BORE_AXIS_W
from kinadapt_nn.robot import ArmKinematics
from kinadapt_nn.runs.build import make_features
from kinadapt_nn.runs.compare import CompareCfg, draw_tools
from kinadapt_nn.runs.episode import run_episode
from kinadapt_nn.sensing import LowPass, channel_metric, nominal_sensor_map
from kinadapt_nn.sim.truth import TrueSensorJacobian

SOCKET = ["scene.contact_model=socket", "control.dither_rad_s=[0.05,0.05,0.05]"]


def _jerr(J_hat: np.ndarray, J_true: np.ndarray, W: np.ndarray) -> float:
    return float(np.linalg.norm(W[:, None] * (J_hat - J_true)) / np.linalg.norm(W[:, None] * J_true))


def _kalman_law(cfg, p: int, P0: np.ndarray) -> StandaloneLaw:
    ad = cfg.adaptation
    return StandaloneLaw("kalman", kalman.LAW.params_of(ad, cfg.run.dt_s, P0), channel_metric(cfg.sensing), np.full(p, -np.inf),
                         np.full(p, np.inf), filter_tau_s=cfg.sensing.filter_tau_s,
                         contact_gate=(ad.contact_force_N, ad.contact_moment_Nm))


def one_tool(overrides: list[str]) -> dict[str, float]:
    cfg = load_config(None, ["run.progress=false", "run.figure=false", "run.tensorboard=false", "run.features=neural",
                             *SOCKET, *overrides])
    tr = run_episode(cfg).trace
    feats, _ = make_features(cfg)
    p, dt = feats.n_params, cfg.run.dt_s
    W = channel_metric(cfg.sensing)
    S = nominal_sensor_map(cfg.sensing, BORE_AXIS_W)
    l_nom = np.asarray(cfg.sensing.nominal_offset_f_m, dtype=float)
    L, n = float(np.linalg.norm(l_nom)), BORE_AXIS_W
    arm = ArmKinematics(arm_mjcf_path(cfg.scene))
    truth = TrueSensorJacobian(S, l_nom, np.asarray(cfg.tool.offset_f_m), arm_mjcf_path(cfg.scene),
                               cfg.arm.link_length_error_m, cfg.arm.joint_offset_rad)
    tau = cfg.sensing.filter_tau_s
    flt_known, flt_phi = LowPass(tau, dt, (6,)), LowPass(tau, dt, (6, p + 3))
    laws = {k: _kalman_law(cfg, p, feats.prior_cov(k)) for k in ("all_arms", "calibrated_arm")}
    th = {k: np.zeros(p) for k in laws}
    evid = dict.fromkeys(laws, 0.0)
    A, y_lever, y_plain, f_prev = [], [], [], None
    rep_A, rep_y = [], []
    for k in range(len(tr["t_s"])):
        q, qd, w = tr["q_rad"][k], tr["qdot_rad_s"][k], tr["w_env_w"][k]
        kin = arm(q)
        reg = feats.regressor(kin, qd)
        f = w[:3]
        f_dot = np.zeros(3) if f_prev is None else (f - f_prev) / dt
        f_prev = f.copy()
        om = (kin.J_arm @ qd)[3:]
        lever = skew(f_dot) + skew(f) @ skew(om)  # d/dt of -(R l) x f, per unit of R l (world)
        known_lever = reg.known.copy()
        known_lever[3:] += lever @ (kin.R_wf @ l_nom - L * n)  # S carries the lever L n x f_lat only
        Phi = np.zeros((6, p + 3))
        Phi[:, :p] = reg.Phi
        Phi[3:, p:] = lever @ kin.R_wf
        flt_known(known_lever)
        flt_phi(Phi)
        for name, law in laws.items():  # the two priors' filters, and their innovations' evidence
            kv = law.view  # the kalman law's own state (KalmanView)
            P_pre, th_pre = kv.P.copy(), None if kv.theta_kf is None else kv.theta_kf.copy()
            th[name], _ = law.update(reg.known, reg.Phi, th[name], tr["s_dot_meas"][k], tr["F_value"][k], w)
            if th_pre is not None and not np.array_equal(P_pre, kv.P):
                H = W[:, None] * law.Phi_f
                e = W * (tr["s_dot_meas"][k] - law.known_f - law.Phi_f @ th_pre)
                Sm = H @ P_pre @ H.T + np.diag(kv.R)  # R = diag(r2 + floor) n_eff, as the update used it
                n_eff = kv.R / (kv.blocks["r2"] + law.consts.lc[kalman.R_FLOOR])
                evid[name] += -0.5 * (e @ np.linalg.solve(Sm, e) + np.linalg.slogdet(Sm)[1]) / float(n_eff.mean())
        if tr["adapt_gate"][k] > 0:  # contact: the rows every law adapts on
            A.append(W[:, None] * flt_phi.z)
            y_lever.append(W * (tr["s_dot_meas"][k] - flt_known.z))
            y_plain.append(W * (tr["s_dot_meas"][k] - laws["all_arms"].known_f))
        if k % 50 == 0:  # the representation floor: the truth's rows along the recorded path
            J0 = feats.jacobian(kin, np.zeros(p))
            rep_A.append((W[1:, None, None] * feats.body(q)).reshape(-1, p))
            rep_y.append((W[1:, None] * (truth(q)[1:] - J0[1:])).ravel())
    kin = arm(tr["q_rad"][-1])
    J_t = truth(tr["q_rad"][-1])
    out = {"online": float(tr["truth_jacobian_rel_error"][-1])}
    th_rep = np.linalg.lstsq(np.concatenate(rep_A), np.concatenate(rep_y), rcond=None)[0]
    out["represent"] = _jerr(feats.jacobian(kin, th_rep), J_t, W)
    Am = np.concatenate(A)
    yl, yp = np.concatenate(y_lever), np.concatenate(y_plain)
    th_ls = np.linalg.lstsq(Am[:, :p], yp, rcond=None)[0]
    out["batch_ls"] = _jerr(feats.jacobian(kin, th_ls), J_t, W)
    out["resid_rms"] = float(np.sqrt(np.mean((yp - Am[:, :p] @ th_ls) ** 2)))
    th_lv = np.linalg.lstsq(Am, yl, rcond=None)[0]
    out["batch_ls_lever"] = _jerr(feats.jacobian(kin, th_lv[:p]), J_t, W)
    out["resid_rms_lever"] = float(np.sqrt(np.mean((yl - Am @ th_lv) ** 2)))
    out["calibrated_prior"] = _jerr(feats.jacobian(kin, th["calibrated_arm"]), J_t, W)
    out["evid"] = evid["calibrated_arm"] - evid["all_arms"]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--family", choices=["nominal", "arm_errors"], default="nominal")
    ap.add_argument("--tools", type=int, default=4)
    a = ap.parse_args()
    tools = draw_tools(CompareCfg(n_tools=a.tools, families=[a.family]))[a.family]
    keys = ["represent", "online", "batch_ls", "batch_ls_lever", "calibrated_prior", "resid_rms", "resid_rms_lever", "evid"]
    print(f"family={a.family} (socket + dither, neural features, default law; Jacobian errors in %)")
    print("tool " + " ".join(f"{k:>16s}" for k in keys))
    rows = []
    for i, over in enumerate(tools):
        r = one_tool(over)
        rows.append(r)
        print(f"{i:4d} " + " ".join(f"{100 * r[k]:16.4f}" if k not in ("evid", "resid_rms", "resid_rms_lever")
                                    else f"{r[k]:16.4g}" for k in keys), flush=True)
    med = {k: float(np.median([r[k] for r in rows])) for k in keys}
    print("med  " + " ".join(f"{100 * med[k]:16.4f}" if k not in ("evid", "resid_rms", "resid_rms_lever")
                             else f"{med[k]:16.4g}" for k in keys))


if __name__ == "__main__":
    main()
