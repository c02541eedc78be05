"""The simulator adapter: the only object that touches MuJoCo's state of the world.

It owns the true scene, places the arm at the start pose (solved from the *true* tool: the
scenario is set up by the experimenter, not by the controller), steps the physics, and
hands out exactly what a real Panda would give a user program: joint encoders ``q, qdot``
and the raw wrist F/T reading. Ground truth (true tip depth, contacts) is read here for
evaluation only and never reaches the controller. What a real sensor's imperfections add to
those readings (noise, bias, dropouts, latency: the ``[faults]`` table) is :class:`SensorFaults`.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from types import SimpleNamespace
from typing import NamedTuple

import mujoco
import numba as nb
import numpy as np

from kinadapt_nn.config import ExperimentCfg, FaultsCfg, true_bore_entry
from kinadapt_nn.errors import KinadaptError
from kinadapt_nn.geometry import rotvec_from_matrix, tilt_rotation
from kinadapt_nn.known import BORE_AXIS_W
from kinadapt_nn.robot import JOINT_LIMITS_RAD, Q_HOME_RAD, SERVO_KP, SERVO_KV
from kinadapt_nn.sim.effects import SensorEffects, TimedEffects, timed, truth_config
from kinadapt_nn.sim.ft_sensor import SOURCE_FIELDS as FT_FIELDS
from kinadapt_nn.sim.ft_sensor import RealisedSensor, sensor_chain
from kinadapt_nn.sim.scene import FORCE_SENSOR, TORQUE_SENSOR, TRUTH_CONTACT_SLOTS, SceneIds, build_model
from kinadapt_nn.sim.socket import N_STATE, socket_params, socket_step

#: Flange "down" orientation: z_f along the bore axis, x_f along x_w (peg square aligned with
#: the bore walls).
R_W_F_DOWN = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])


@nb.njit(cache=True)
def contact_sums(sens, adr, found, e0, e1, e2, half_width):
    """(face, bore, total normal force [N]) of the ``found`` peg <-> block contacts in the contact
    sensor's slots of ``sens`` (its data from ``adr``; per contact 7 values: found, force in the
    contact frame (3, the normal first), position (3), world [m]). A contact is on the block's top
    face when it lies within 1.5 mm of the bore entrance's height ``e2`` and outside the square of
    ``half_width`` [m] about the entrance (``e0``, ``e1``); otherwise on the bore."""
    face = False
    bore = False
    fsum = 0.0
    for i in range(found):
        k = adr + 7 * i
        fsum += abs(sens[k + 1])
        on_top = abs(sens[k + 6] - e2) < 1.5e-3 and max(abs(sens[k + 4] - e0), abs(sens[k + 5] - e1)) > half_width
        face |= on_top
        bore |= not on_top
    return face, bore, fsum


class SensorSample(NamedTuple):
    """What a real robot hands a user program each control period."""

    q_rad: np.ndarray  #: (n,) joint encoder positions [rad]
    qdot_rad_s: np.ndarray  #: (n,) joint velocities [rad/s]
    wrench_raw_f: np.ndarray  #: (6,) F/T reading [N, N m]: flange on tool, about O, in f


class SensorFaults:
    """Sensor faults and disturbances between the simulator and the controller (truth side).

    Applied to each ``SensorSample`` in this order: encoder quantisation, F/T bias (from
    ``bias_onset_s`` after the tare), Gaussian F/T noise, saturation, dropouts (the whole
    sample becomes NaN), latency (the controller receives the sample of ``latency_steps`` earlier).
    Seeded from ``run.seed`` so a run is reproducible.
    """

    def __init__(self, cfg: FaultsCfg, seed: int, bias_onset_s: float) -> None:
        self.cfg = cfg
        self.rng = np.random.default_rng(np.random.SeedSequence([seed, 0xFA017]))
        self.onset = bias_onset_s + cfg.bias_onset_s  # after the tare window ends
        self.bias = np.concatenate([np.asarray(cfg.ft_bias_N, dtype=float), np.zeros(3)])
        self.noise = np.array([cfg.ft_noise_N] * 3 + [cfg.ft_noise_Nm] * 3)
        self.queue: deque = deque()
        self.dropped = 0

    @staticmethod
    def active(cfg: FaultsCfg) -> bool:
        return bool(
            cfg.ft_noise_N or cfg.ft_noise_Nm or any(cfg.ft_bias_N) or cfg.ft_dropout_prob or cfg.ft_saturation_N
            or cfg.encoder_resolution_rad or cfg.latency_steps
        )

    def __call__(self, t: float, s: SensorSample) -> SensorSample:
        c = self.cfg
        q, qd, w = s.q_rad.copy(), s.qdot_rad_s.copy(), s.wrench_raw_f.copy()
        if c.encoder_resolution_rad:
            q = np.round(q / c.encoder_resolution_rad) * c.encoder_resolution_rad
        if t >= self.onset:
            w += self.bias
        if c.ft_noise_N or c.ft_noise_Nm:
            w += self.noise * self.rng.standard_normal(6)
        if c.ft_saturation_N:
            w[:3] = np.clip(w[:3], -c.ft_saturation_N, c.ft_saturation_N)
        if c.ft_dropout_prob and self.rng.random() < c.ft_dropout_prob:
            w[:] = np.nan
            self.dropped += 1
        out = SensorSample(q, qd, w)
        if c.latency_steps:
            self.queue.append(out)
            if len(self.queue) <= c.latency_steps:
                return self.queue[0]
            return self.queue.popleft()
        return out


class TruthSample(NamedTuple):
    """Ground truth for evaluation only (never given to the controller)."""

    tip_pos_w_m: np.ndarray  #: (3,) true tip position, world
    tip_depth_m: float  #: true tip depth below the bore entrance along the bore axis
    contact_face: bool  #: the peg touches the block's top face outside the bore
    contact_bore: bool  #: the peg touches a bore wall, the entrance edge or the floor
    contact_force_N: float  #: total normal contact force peg <-> block


def solve_start_ik(
    model: mujoco.MjModel, ids: SceneIds, tip_target_w: np.ndarray, R_target_w_f: np.ndarray, q0: np.ndarray
) -> np.ndarray:
    """Damped least-squares IK on the *true* tip site (scenario set-up only). -> (n,) q."""
    data = mujoco.MjData(model)
    q = q0.copy()
    jacp = np.zeros((3, model.nv))
    jacr = np.zeros((3, model.nv))
    for _ in range(300):
        data.qpos[ids.qpos_adr] = q
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        err_p = tip_target_w - data.site_xpos[ids.tip_site]
        R = data.site_xmat[ids.ft_site].reshape(3, 3)
        err_r = rotvec_from_matrix(R_target_w_f @ R.T)
        err = np.concatenate([err_p, err_r])
        if np.linalg.norm(err) < 1e-10:
            break
        mujoco.mj_jacSite(model, data, jacp, jacr, ids.tip_site)
        J = np.vstack([jacp[:, ids.dof_adr], jacr[:, ids.dof_adr]])
        dq = J.T @ np.linalg.solve(J @ J.T + 1e-8 * np.eye(6), err)
        dq += 0.1 * (np.eye(7) - np.linalg.pinv(J) @ J) @ (Q_HOME_RAD - q)
        q = np.clip(q + dq, JOINT_LIMITS_RAD[:, 0], JOINT_LIMITS_RAD[:, 1])
    if np.linalg.norm(err) > 1e-6:
        raise KinadaptError(
            f"start pose unreachable (IK residual {np.linalg.norm(err):.2e}); move scene.bore_entry_w_m "
            "closer to the robot or reduce start.tilt_deg"
        )
    return q


@nb.njit(cache=True)
def _servo_setpoint(u, q_ref, qdot_ref, kv_over_kp):
    """u = q_ref + kv/kp qdot_ref, element by element (u, q_ref, qdot_ref: (n,)); one call where
    numpy's two (a multiply into u, then an add) cost ~4 us a step. The same two roundings."""
    for i in range(u.shape[0]):
        u[i] = qdot_ref[i] * kv_over_kp + q_ref[i]


class PegInHoleSim:
    """MuJoCo Panda + peg + bore. Truth side: the controller never holds a reference to it."""

    def __init__(self, cfg: ExperimentCfg) -> None:
        cfg = truth_config(cfg)  # hidden effects with a truth-side knob folded in (sim.effects)
        self.cfg = cfg
        self.model, self.ids = build_model(cfg.tool, cfg.scene, arm=cfg.arm, effects=cfg.effects)
        #: hidden sensor effects on the raw F/T reading (truth side; ``active`` False when none)
        self.sensor_effects = SensorEffects(cfg)
        #: hidden effects that change the world during the run (payload picked up, snag, slip), or None
        self.timed = TimedEffects(cfg, self.model) if timed(cfg) else None
        self.model.opt.timestep = cfg.run.dt_s
        self.data = mujoco.MjData(self.model)
        self.entry_w = np.asarray(true_bore_entry(cfg.scene), dtype=float)  # the TRUE bore
        self._block_set = frozenset(int(g) for g in self.ids.block_geoms)
        self._kv_over_kp = SERVO_KV / SERVO_KP
        #: the socket contact model is on (``scene.contact_model = "socket"``, ``sim.socket``)
        self.has_socket = cfg.scene.contact_model == "socket"
        self._tool_body = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, "tool")
        self._sock_st = np.zeros(N_STATE)  # the socket's state (sim.socket): engaged, anchor, |f|
        self._f6 = np.zeros(6)  # mj_contactForce output
        # views into MjData fetched once (each attribute access builds a new array object; the
        # buffers live as long as self.data): encoders, F/T reading, servo set-point, true tip
        d, a = self.data, self.ids
        #: the F/T reading for the motion each step realises (``sim.ft_sensor``), MuJoCo's own at rest,
        #: and the encoders of the reading's instant (``ft.qpos0``, ``ft.qvel0``)
        self.ft_chain = sensor_chain(self.model, FORCE_SENSOR, TORQUE_SENSOR)
        self.ft = RealisedSensor(SimpleNamespace(**{f: getattr(d, f)[None] for f in FT_FIELDS}), self.ft_chain,
                                 cfg.run.dt_s)
        self._q_v = self.ft.qpos0[0, _as_slice(a.qpos_adr)]  # a copy (refreshed in sense) if not contiguous
        self._qdot_v = self.ft.qvel0[0, _as_slice(a.dof_adr)]
        self._views = isinstance(_as_slice(a.qpos_adr), slice) and isinstance(_as_slice(a.dof_adr), slice)
        self._wrench_v = self.ft.wrench[0]
        self._row0 = np.zeros(1, dtype=np.int64)
        self._ctrl_v = d.ctrl
        self._tip_v = d.site_xpos[a.tip_site]
        self._sens_v = d.sensordata
        self._n_t = tuple(BORE_AXIS_W.tolist())
        self._entry_t = tuple(self.entry_w.tolist())
        self._peg = int(a.peg_geom)
        self._face_lat = cfg.scene.bore_half_width_m + 0.5e-3  # truth(): contact outside the bore mouth
        self._sock_prm = socket_params(cfg, self.entry_w, BORE_AXIS_W)
        self._socket_step = self.bind_socket(d)
        self.q_start = self._start_configuration()
        self.reset()

    # -- set-up -----------------------------------------------------------------------
    def _start_configuration(self) -> np.ndarray:
        st = self.cfg.start
        rng = np.random.default_rng(self.cfg.run.seed)  # the run's only random draws
        lat = np.asarray(st.lateral_w_m) + rng.uniform(-1.0, 1.0, 2) * st.lateral_jitter_m
        tilt = np.asarray(st.tilt_deg) + rng.uniform(-1.0, 1.0, 2) * st.tilt_jitter_deg
        self.start_lateral_w_m, self.start_tilt_deg = lat, tilt
        R_target = tilt_rotation(tilt) @ R_W_F_DOWN
        # the start is planned from the KNOWN bore pose (a bore-pose error shows up as misalignment)
        known = np.asarray(self.cfg.scene.bore_entry_w_m, dtype=float)
        tip_target = known + np.array([lat[0], lat[1], st.tip_height_m])
        return solve_start_ik(self.model, self.ids, tip_target, R_target, Q_HOME_RAD)

    def reset(self) -> SensorSample:
        """Put the arm at the start configuration at rest, servo holding it."""
        mujoco.mj_resetData(self.model, self.data)
        self._sock_st[:] = 0.0
        self.data.qpos[self.ids.qpos_adr] = self.q_start
        self.data.ctrl[:] = self.q_start
        mujoco.mj_forward(self.model, self.data)
        self.ft.reset()
        return self.sense()

    # -- the interface a real robot offers ---------------------------------------------
    def sense(self) -> SensorSample:
        """Encoders and the raw F/T reading (copies) of one instant: the last step's start state, its
        reading with the acceleration the step realised (``sim.ft_sensor``); they reach the caller
        one physics step after that instant (at rest before the first step: the current state)."""
        d, a = self.data, self.ids
        wrench = self._wrench_v.copy()
        if self.sensor_effects.active:
            self.sensor_effects(float(d.time), wrench)
        if self._views:
            return SensorSample(self._q_v.copy(), self._qdot_v.copy(), wrench)
        return SensorSample(self.ft.qpos0[0, a.qpos_adr], self.ft.qvel0[0, a.dof_adr], wrench)  # copies

    def sense_into(self, q: np.ndarray, qdot: np.ndarray, wrench: np.ndarray) -> None:
        """``sense()`` written into the caller's arrays (no new arrays)."""
        if not self._views:
            o = self.sense()
            q[:], qdot[:], wrench[:] = o.q_rad, o.qdot_rad_s, o.wrench_raw_f
            return
        q[:] = self._q_v
        qdot[:] = self._qdot_v
        wrench[:] = self._wrench_v
        if self.sensor_effects.active:
            self.sensor_effects(float(self.data.time), wrench)

    def apply(self, q_ref: np.ndarray, qdot_ref: np.ndarray) -> None:
        """Joint servo set-point with velocity feed-forward (q_ref + kv/kp qdot_ref)."""
        _servo_setpoint(self._ctrl_v, q_ref, qdot_ref, self._kv_over_kp)

    def step(self) -> None:
        """One physics step (``mj_step1``, the socket contact's wrench for the state the step starts
        from when it is on, ``mj_step2``: together bit-identical to ``mj_step``)."""
        if self.timed is not None:
            self.timed(float(self.data.time), self.model, self.data.xfrc_applied)
        mujoco.mj_step1(self.model, self.data)
        if self._socket_step is not None:
            self._socket_step(float(self.data.time))
        self.ft.before_step()
        mujoco.mj_step2(self.model, self.data)
        self.ft.after_step(self._row0)

    def bind_socket(self, src) -> Callable[[float], None] | None:
        """The socket contact's wrench for one physics step, ``f(t)``, on this scene's socket state,
        reading and writing the arrays of ``src``: this scene's MjData, or one episode's rows of a
        batch's bound fields (``sim.scenes.SceneBatch``) -- any object with ``site_xpos``, ``xmat``,
        ``xipos``, ``cvel``, ``subtree_com`` and ``xfrc_applied`` indexed by object id. None when
        the contact model is not the socket.

        Low-bias contact (``scene.contact_model = "socket"``): a lateral spring-damper at the
        true tip and an angular spring-damper. ``socket_engage = "drive"``: anchored where they
        are when the drive starts (end of the settle/tare window); ``"depth"``: anchored when the
        true tip crosses the entrance plane, released when it is back 1 mm above it, with an
        axial spring ``socket_k_axial`` pushing the tip out below the plane (a compliant
        fixture). It is the nominal map S's own contact model, so the bias b is what remains:
        the lever (true offset vs nominal), the F-dependent terms, and any stiffness mismatch
        set in the config. Effect ``contact_friction_couple`` adds ``-radius |f| w/(|w|+eps)``.
        The arithmetic is ``sim.socket.socket_step``."""
        if not self.has_socket:
            return None
        a, tb = self.ids, self._tool_body
        vb = int(self.model.site_bodyid[a.tip_site])  # the tip's body: its velocity
        views = (src.site_xpos[a.tip_site], src.xmat[tb], src.xipos[tb], src.cvel[vb],
                 src.subtree_com[int(self.model.body_rootid[vb])], src.xfrc_applied[tb])
        st, prm = self._sock_st, self._sock_prm
        return lambda t: socket_step(t, st, prm, *views)

    @property
    def time_s(self) -> float:
        return float(self.data.time)

    # -- ground truth (evaluation only) ------------------------------------------------
    def truth(self) -> TruthSample:
        """This step's ground truth (evaluation only): the true tip, its depth and the contacts."""
        tip = self._tip_v.copy()
        face, bore, fsum = self.contacts_of(self._sens_v, self._own_data)
        return TruthSample(tip, float(self.tip_depths(tip[None])[0]), face, bore, fsum)

    def tip_depths(self, tip_w_m: np.ndarray) -> np.ndarray:
        """True tip depth below the bore entrance along the bore axis for tips (N, 3), world [m]
        -> (N,): n . (tip - entry), summed left to right as one step's scalars would be."""
        (n0, n1, n2), (e0, e1, e2) = self._n_t, self._entry_t
        return n0 * (tip_w_m[:, 0] - e0) + n1 * (tip_w_m[:, 1] - e1) + n2 * (tip_w_m[:, 2] - e2)

    def _own_data(self) -> mujoco.MjData:
        return self.data

    def contacts_of(self, sensordata: np.ndarray, get_data) -> tuple[bool, bool, float]:
        """(face, bore, normal force [N]) of this step's peg <-> block contacts, from this episode's
        ``sensordata`` (its own, or its row of a batch's, ``sim.scenes.SceneBatch``): MuJoCo's contact
        sensor on those contacts (``scene.TRUTH_CONTACT_SENSOR``: the normal force and position of
        each, in MuJoCo's contact order). More contacts than the sensor's slots: the contact array of
        ``get_data()`` (the episode's MjData), ``mj_contactForce`` for the normal. The socket model's
        own state when it is on."""
        face = bore = False
        fsum = 0.0
        adr = self.ids.contact_adr
        found = int(sensordata[adr]) if adr >= 0 else 0
        if found:
            hw = self._face_lat
            (e0, e1, e2) = self._entry_t
            if found <= TRUTH_CONTACT_SLOTS:  # the sensor's slots
                face, bore, fsum = contact_sums(sensordata, adr, found, e0, e1, e2, hw)
            else:  # the contact array, laid out as the sensor's slots, through the same kernel
                rows = self._contact_scan(get_data())
                slots = np.zeros((len(rows), 7))
                if rows:
                    slots[:, [1, 4, 5, 6]] = rows
                face, bore, fsum = contact_sums(slots.reshape(-1), 0, len(rows), e0, e1, e2, hw)
        if self.has_socket:
            bore = bool(self._sock_st[0])
            fsum = float(self._sock_st[13])
        return face, bore, fsum

    def _contact_scan(self, d: mujoco.MjData) -> list[tuple[float, float, float, float]]:
        """(normal force [N], position (3), world) of each peg <-> block contact in ``d``'s contact
        array, in its order (what the contact sensor reports, without its slot limit)."""
        con = d.contact
        geoms, pos = con.geom.tolist(), con.pos.tolist()
        peg, block, f6, m = self._peg, self._block_set, self._f6, self.model
        rows = []
        for i in range(d.ncon):
            g1, g2 = geoms[i]
            if (g1 == peg and g2 in block) or (g2 == peg and g1 in block):
                mujoco.mj_contactForce(m, d, i, f6)
                rows.append((float(f6[0]), *pos[i]))
        return rows


def _as_slice(adr: np.ndarray) -> slice | np.ndarray:
    """A slice for contiguous addresses (indexing with it gives a view), else the index array."""
    adr = np.asarray(adr)
    if len(adr) and np.array_equal(adr, np.arange(adr[0], adr[0] + len(adr))):
        return slice(int(adr[0]), int(adr[0]) + len(adr))
    return adr
