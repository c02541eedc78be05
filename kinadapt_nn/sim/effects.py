"""Hidden physical effects on the truth side (``[effects]`` config; off by default).

Each effect changes the simulated world or the simulated sensor and nothing else: the
controller and the diagnosis model never read ``cfg.effects`` (the model side of each effect,
its regressor columns, is ``kinadapt_nn.features.effect_library``). Where an effect maps onto an
existing truth-side knob it is folded in here (``truth_config``); the others are built by the
scene (payload, grasp hinges, torsional friction) or applied by the adapter (socket contact,
sensor drift and rotation).

=========================  ===================================================================
effect                     what the simulator does
=========================  ===================================================================
tool_gravity               a payload body (mass, COM in f) rigidly on the tool
ft_bias_drift              reading += rate_f * t (sensor frame), from t = 0 (the tare sees part)
ft_frame_rotation          reading = R(rotvec)^T r: force and moment expressed in a rotated frame
tool_tilt                  the tool is rotated in the grasp about O: tip = R_tilt offset
contact_stiffness          bore: solref time constant / sqrt(factor); socket: springs x factor
contact_friction_couple    bore: condim 4 torsional friction (radius); socket: -radius |f| w/(|w|+eps)
grasp_compliance           the tool hangs on two hinges about f x, y at O (stiffness, damped)
encoder_offset             the joint sits at reading + offset (arm.joint_offset_rad)
=========================  ===================================================================
"""

from __future__ import annotations

import numpy as np

from kinadapt_nn.config import ExperimentCfg
from kinadapt_nn.geometry import tilt_rotation


def truth_config(cfg: ExperimentCfg) -> ExperimentCfg:
    """``cfg`` with the effects that have a truth-side knob folded in (tool tilt, contact
    stiffness, encoder offset). Effects off -> ``cfg`` unchanged."""
    e = cfg.effects
    upd: dict = {}
    if e.tool_tilt.enabled:
        R = tilt_rotation(e.tool_tilt.tilt_deg)
        off = R @ np.asarray(cfg.tool.offset_f_m, dtype=float)
        tilt = tuple(float(a + b) for a, b in zip(cfg.tool.tilt_deg, e.tool_tilt.tilt_deg))
        upd["tool"] = cfg.tool.model_copy(update={"offset_f_m": tuple(float(x) for x in off), "tilt_deg": tilt})
    sc = cfg.scene
    if e.contact_stiffness.enabled:
        k = e.contact_stiffness.factor
        upd["scene"] = sc.model_copy(update={
            "contact_timeconst_s": sc.contact_timeconst_s / np.sqrt(k),
            "socket_k_lat_N_per_m": sc.socket_k_lat_N_per_m * k,
            "socket_k_rot_Nm_per_rad": sc.socket_k_rot_Nm_per_rad * k,
            "socket_k_axial_N_per_m": sc.socket_k_axial_N_per_m * k,
        })
    if e.encoder_offset.enabled:
        off = list(cfg.arm.joint_offset_rad)
        off[e.encoder_offset.joint - 1] += float(np.deg2rad(e.encoder_offset.offset_deg))
        upd["arm"] = cfg.arm.model_copy(update={"joint_offset_rad": tuple(off)})
    return cfg.model_copy(update=upd) if upd else cfg


def sensor_rotation_f(cfg: ExperimentCfg) -> np.ndarray | None:
    """``R_f,sensor`` (3, 3) of a rotated sensor mount, or None."""
    e = cfg.effects.ft_frame_rotation
    if not e.enabled:
        return None
    import mujoco

    rv = np.deg2rad(np.asarray(e.rotvec_deg, dtype=float))
    ang = float(np.linalg.norm(rv))
    if ang == 0.0:
        return None
    q = np.zeros(4)
    mujoco.mju_axisAngle2Quat(q, rv / ang, ang)
    R = np.zeros(9)
    mujoco.mju_quat2Mat(R, q)
    return R.reshape(3, 3)


class SensorEffects:
    """Applied to the raw F/T reading in ``PegInHoleSim.sense`` (before faults): a rotated mount,
    then a linear drift. ``__call__(t, wrench_f) -> wrench`` (6,) in place."""

    def __init__(self, cfg: ExperimentCfg) -> None:
        self.R_f_s = sensor_rotation_f(cfg)
        d = cfg.effects.ft_bias_drift
        self.rate = np.asarray(d.rate_f, dtype=float) if d.enabled and any(d.rate_f) else None

    @property
    def active(self) -> bool:
        return self.R_f_s is not None or self.rate is not None

    def __call__(self, t: float, w: np.ndarray) -> np.ndarray:
        if self.R_f_s is not None:  # components in the sensor's own (rotated) frame
            w[:3] = self.R_f_s.T @ w[:3]
            w[3:] = self.R_f_s.T @ w[3:]
        if self.rate is not None:
            w += self.rate * t
        return w
