"""Hidden physical effects on the truth side (``[effects]`` config; off by default).

Each effect changes the simulated world or the simulated sensor and nothing else: the
controller and the diagnosis model never read ``cfg.effects`` (the model side of each effect,
its regressor columns, is ``kinadapt_nn.effects.builtin``). Where an effect maps onto an
existing truth-side knob it is folded in here (``truth_config``); the others are built by the
scene (payload, grasp hinges, torsional friction) or applied by the adapter (socket contact,
sensor drift and rotation).

=========================  ===================================================================
effect                     what the simulator does
=========================  ===================================================================
tool_gravity               a payload body (mass, COM in f) rigidly on the tool; from onset_s (mass
                           ramped over ramp_s), before it the body weighs nothing
ft_bias_drift              reading += rate_f * (t - onset_s) (sensor frame) for t > onset_s (onset 0:
                           from t = 0, the tare sees part)
ft_frame_rotation          reading = R(rotvec)^T r: force and moment expressed in a rotated frame,
                           from onset_s (the angle ramped over ramp_s)
tool_tilt                  the tool is rotated in the grasp about O: tip = R_tilt offset
contact_stiffness          bore: solref time constant / sqrt(factor); socket: springs x factor, its
                           dampers unchanged (the declared ones)
contact_friction_couple    bore: condim 4 torsional friction (radius); socket: -radius |f| w/(|w|+eps)
grasp_compliance           the tool hangs on two hinges about f x, y at O (stiffness, damped)
encoder_offset             the joint sits at reading + offset (arm.joint_offset_rad)
world_force                a snag: a world-frame force at a point of the tool (a massless body
                           there, ``xfrc_applied``), from onset_s (ramped over ramp_s)
grasp_slip                 the tool (peg, its inertia, tip, payload, snag point) turns about O in
                           the grasp by slip_deg (about f x, then f y) from onset_s over ramp_s; the
                           sensor stays on the flange
=========================  ===================================================================

Onsets (``onset_s``): before it an effect leaves the run as the clean run is (the payload's and the
snag's bodies weigh nothing and carry no force; ``tests/monitor/test_onsets.py``). The timed ones that
change the simulated world are applied before each physics step by :class:`TimedEffects`.
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
        # the springs change; the socket's dampers stay the declared ones (``socket_damping`` is
        # 2 z sqrt(k m): z / sqrt(k) keeps c): the effect is the stiffness, one physical property
        upd["scene"] = sc.model_copy(update={
            "contact_timeconst_s": sc.contact_timeconst_s / np.sqrt(k),
            "socket_k_lat_N_per_m": sc.socket_k_lat_N_per_m * k,
            "socket_k_rot_Nm_per_rad": sc.socket_k_rot_Nm_per_rad * k,
            "socket_k_axial_N_per_m": sc.socket_k_axial_N_per_m * k,
            "socket_damping_ratio": sc.socket_damping_ratio / np.sqrt(k),
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
        self.drift_onset = float(d.onset_s)
        r = cfg.effects.ft_frame_rotation
        self.rot_onset, self.rot_ramp = float(r.onset_s), float(r.ramp_s)
        self._rv = np.deg2rad(np.asarray(r.rotvec_deg, dtype=float))

    @property
    def active(self) -> bool:
        return self.R_f_s is not None or self.rate is not None

    def _rotation(self, t: float) -> np.ndarray | None:
        """The mount's rotation at ``t`` [s] (3, 3), or None before the onset."""
        if t < self.rot_onset:
            return None
        if self.rot_ramp > 0.0 and t < self.rot_onset + self.rot_ramp:
            return rotation_of(self._rv * ((t - self.rot_onset) / self.rot_ramp))
        return self.R_f_s

    def __call__(self, t: float, w: np.ndarray) -> np.ndarray:
        R = self._rotation(t) if self.R_f_s is not None else None
        if R is not None:  # components in the sensor's own (rotated) frame
            w[:3] = R.T @ w[:3]
            w[3:] = R.T @ w[3:]
        if self.rate is not None and t > self.drift_onset:
            w += self.rate * (t - self.drift_onset)
        return w


def rotation_of(rotvec: np.ndarray) -> np.ndarray:
    """The rotation matrix (3, 3) of a rotation vector (3,) [rad] (Rodrigues)."""
    ang = float(np.linalg.norm(rotvec))
    if ang == 0.0:
        return np.eye(3)
    k = rotvec / ang
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(ang) * K + (1.0 - np.cos(ang)) * (K @ K)


def ramp(t: float, onset: float, ramp_s: float) -> float:
    """The share of an effect present at ``t`` [s]: 0 before ``onset``, rising linearly to 1 over
    ``ramp_s`` (a step when 0)."""
    if t < onset:
        return 0.0
    if ramp_s <= 0.0 or t >= onset + ramp_s:
        return 1.0
    return (t - onset) / ramp_s


PAYLOAD_BODY, SNAG_BODY = "payload", "snag"


def timed(cfg: ExperimentCfg) -> bool:
    """Whether ``cfg`` has a truth-side effect that changes the simulated world during the run
    (a payload picked up, a snag, a grasp slip): those :class:`TimedEffects` applies."""
    e = cfg.effects
    return (e.tool_gravity.enabled and e.tool_gravity.onset_s > 0.0) or e.world_force.enabled or e.grasp_slip.enabled


class TimedEffects:
    """The effects that change the simulated world at a time, applied before each physics step
    (``__call__(t, model, data)``): the payload's mass and inertia (from 0), the snag's world
    force on its body, the slip's turn of everything the tool body carries (geoms, inertia, sites,
    child bodies) about O. Truth side: the controller never sees these."""

    def __init__(self, cfg: ExperimentCfg, model) -> None:
        import mujoco

        e = cfg.effects
        name = lambda kind, n: mujoco.mj_name2id(model, kind, n)  # noqa: E731
        self.payload = None
        g = e.tool_gravity
        if g.enabled and g.onset_s > 0.0:
            b = name(mujoco.mjtObj.mjOBJ_BODY, PAYLOAD_BODY)
            self.payload = (b, float(model.body_mass[b]), model.body_inertia[b].copy(), g.onset_s, g.ramp_s)
            model.body_mass[b] = 0.0  # nothing there before the onset
            model.body_inertia[b] = 0.0
        self.snag = None
        w = e.world_force
        if w.enabled:
            self.snag = (name(mujoco.mjtObj.mjOBJ_BODY, SNAG_BODY), np.asarray(w.force_w_N, dtype=float), w.onset_s,
                         w.ramp_s)
        self.slip = None
        sl = e.grasp_slip
        if sl.enabled:
            from kinadapt_nn.sim.scene import TOOL_BODY

            tool = name(mujoco.mjtObj.mjOBJ_BODY, TOOL_BODY)
            geoms = np.flatnonzero(model.geom_bodyid == tool)
            sites = np.flatnonzero(model.site_bodyid == tool)
            from kinadapt_nn.sim.scene import FT_SITE

            sites = sites[sites != name(mujoco.mjtObj.mjOBJ_SITE, FT_SITE)]  # the sensor stays on the flange
            kids = np.flatnonzero(model.body_parentid == tool)
            kids = kids[kids != tool]
            self.slip = dict(tool=tool, geoms=geoms, sites=sites, kids=kids, rv=np.deg2rad([*sl.slip_deg, 0.0]),
                             onset=sl.onset_s, ramp=sl.ramp_s, share=0.0,
                             geom=(model.geom_pos[geoms].copy(), model.geom_quat[geoms].copy()),
                             site=(model.site_pos[sites].copy(), model.site_quat[sites].copy()),
                             kid=(model.body_pos[kids].copy(), model.body_quat[kids].copy()),
                             inert=(model.body_ipos[tool].copy(), model.body_iquat[tool].copy()))
        self._mj = mujoco

    def __call__(self, t: float, model, xfrc: np.ndarray) -> None:
        """The state of the timed effects at ``t`` [s] written into ``model`` (payload, slip) and
        ``xfrc`` (the episode's ``xfrc_applied`` (nbody, 6): the snag)."""
        if self.payload is not None:
            b, m, inertia, onset, ramp_s = self.payload
            a = ramp(t, onset, ramp_s)
            if model.body_mass[b] != m * a:
                model.body_mass[b] = m * a
                model.body_inertia[b] = inertia * a
        if self.snag is not None:
            b, f, onset, ramp_s = self.snag
            xfrc[b, :3] = f * ramp(t, onset, ramp_s)
        if self.slip is not None:
            sl = self.slip
            a = ramp(t, sl["onset"], sl["ramp"])
            if a != sl["share"]:
                sl["share"] = a
                self._turn(model, tilt_rotation(np.rad2deg(sl["rv"][:2]) * a))

    def _turn(self, model, R: np.ndarray) -> None:
        """Everything on the tool body turned by ``R`` about O (its origin) from where it was built."""
        mj, sl = self._mj, self.slip
        q = np.zeros(4)
        mj.mju_mat2Quat(q, R.ravel())
        out = np.zeros(4)
        for (pos_f, quat_f), ids, pos, quat in ((sl["geom"], sl["geoms"], model.geom_pos, model.geom_quat),
                                                (sl["site"], sl["sites"], model.site_pos, model.site_quat),
                                                (sl["kid"], sl["kids"], model.body_pos, model.body_quat)):
            for i, k in enumerate(ids):
                pos[k] = R @ pos_f[i]
                mj.mju_mulQuat(out, q, quat_f[i])
                quat[k] = out
        ip, iq = sl["inert"]
        model.body_ipos[sl["tool"]] = R @ ip
        mj.mju_mulQuat(out, q, iq)
        model.body_iquat[sl["tool"]] = out
