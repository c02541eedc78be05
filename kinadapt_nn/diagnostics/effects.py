"""The effect library applied to a recorded run: the library's signals from a replay, and the
validation of an estimate against the effect a simulated run injected (benchmarks, tests).

The columns themselves are model-side (``kinadapt_nn.features.effect_library``); this module
takes an experiment config (a run's own config) and so belongs to the diagnosis, not to the
controller side.
"""

from __future__ import annotations

import numpy as np

from kinadapt_nn.config import ExperimentCfg, arm_mjcf_path
from kinadapt_nn.features.effect_library import Signals, tip_twist_map
from kinadapt_nn.known import BORE_AXIS_W
from kinadapt_nn.robot import ArmKinematics
from kinadapt_nn.sensing import nominal_sensor_map


def build_signals(rep, log, cfg: ExperimentCfg) -> Signals:
    """From a ``residual.Replay`` and its ``RawLog``: kinematics per sample (the controller's own
    bare-arm MuJoCo model), the tared reading, the contact gate."""
    kin = ArmKinematics(arm_mjcf_path(cfg.scene))
    n = len(rep.t_s)
    R = np.empty((n, 3, 3))
    twist = np.empty((n, 6))
    l_nom = np.asarray(cfg.sensing.nominal_offset_f_m, dtype=float)
    for i in range(n):
        k = kin.update(log.q_rad[i])
        R[i] = k.R_wf
        twist[i] = tip_twist_map(k.R_wf, k.J_arm, l_nom) @ log.qdot_rad_s[i]
    r_tared = np.einsum("nji,nj->ni", R, rep.w_env[:, :3]), np.einsum("nji,nj->ni", R, rep.w_env[:, 3:])
    r_tared = np.concatenate(r_tared, axis=1)
    dt = float(np.median(np.diff(rep.t_s))) if n > 1 else cfg.run.dt_s
    t_tare = cfg.start.settle_s - 0.5 * cfg.sensing.tare_window_s
    i_tare = int(np.clip(np.searchsorted(rep.t_s, t_tare), 0, n - 1))
    gate = (rep.active & (rep.s[:, 0] >= 0.0)).astype(float)
    return Signals(rep.t_s, dt, rep.s, rep.w_env, r_tared, R, twist, gate, rep.active, t_tare, R[i_tare].copy(),
                   nominal_sensor_map(cfg.sensing, BORE_AXIS_W), l_nom, log.q_rad, log.qdot_rad_s, kin)


def headline_errors(name: str, p_hat: np.ndarray, p_true: np.ndarray) -> dict[str, float]:
    """Relative errors of the physical quantities the injected effect set (for validation)."""
    def rel(a, b):
        return float(np.linalg.norm(a - b) / max(np.linalg.norm(b), 1e-12))

    if name == "tool_gravity":
        com_hat = p_hat[1:] / p_hat[0] if abs(p_hat[0]) > 1e-9 else np.full(3, np.inf)
        return {"mass": rel(p_hat[:1], p_true[:1]), "com": rel(com_hat, p_true[1:] / p_true[0])}
    if name == "ft_bias_drift":
        return {"rate": rel(p_hat, p_true)}
    return {"params": rel(p_hat, p_true)}
