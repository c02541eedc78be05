"""A foreign rig: test logs for ``kinadapt diagnose`` from a set-up this package never saw.

Standalone on purpose: this file imports nothing from ``kinadapt_nn`` (only MuJoCo, NumPy, SciPy,
PyArrow and the standard library) so that its logs are independent of the package's own simulator
and of the diagnosis code. The only shared input is the arm model ``models/panda.xml``. ::

    python examples/foreign_rig.py --out DIR [--case NAME ...] [--seed N] [--self-test]

writes, per case, ``DIR/<case>/``: ``log.csv.gz``, ``log.parquet`` (the same samples, other column
names and conventions), ``setup_csv.toml``, ``setup_parquet.toml`` (the NOMINAL rig, as a user
would declare it) and ``truth.json`` (the hidden effects, in the diagnosis's reporting units).

The rig
-------
Frames: ``w`` world (z up, gravity (0, 0, -9.81) m/s^2), ``f`` the arm's ``flange`` site frame
(on ``link7``), ``s`` the F/T sensor frame: origin ``SENSOR_POS_F_M`` = (0, 0, 0.012) m in ``f``,
axes ``R_fs = Rz(yaw) Ry(pitch) Rx(roll)`` with (roll, pitch, yaw) = ``SENSOR_RPY_F_DEG`` =
(0, 0, -45) deg (an adapter plate). Everything distal of the sensor (the tool) is described in
``s``: mass 1.10 kg, COM (0.004, -0.002, 0.055) m, inertia about the COM (ixx, iyy, izz, ixy, ixz,
iyz) = (0.0042, 0.0040, 0.0011, 0, 0, 0) kg m^2, tip (0.010, 0, 0.180) m.

In MuJoCo the sensor is a body ``ft_sensor`` welded to ``link7`` at ``s`` (0.3 kg of housing, on the
arm side of the measuring plane) and the tool a body ``tool`` welded to it with its frame equal to
``s``; a site ``ft`` at the tool's origin carries a ``force`` and a ``torque`` sensor. The reading
comes from MuJoCo's physics (``build_model``, ``inverse_dynamics_wrench``): the scripted
q(t), qdot(t), qddot(t) are written to qpos/qvel/qacc, the contact force at the true tip is applied
to the tool through ``xfrc_applied`` (force at the tool body's COM plus the moment of the tip force
about that COM), then ``mj_inverse`` followed by ``mj_rnePostConstraint`` and ``mj_sensorAcc``.
MuJoCo's force/torque sensors report ``cfrc_int`` of the site's body: the wrench its parent (the
sensor) exerts on it (the tool subtree), in the site axes, about the site. The tool-on-sensor
wrench is its negation (``self_test`` checks the sign against the weight and a known tip force).

The experiment (``trajectory``, 15 s at 500 Hz, 7501 samples, every joint inside the Panda's
position, velocity and acceleration limits)
  1. 0-7.3 s free-space reorientation: hold at q_home 0.5 s, then 6 minimum-jerk moves (IK to
     ``_PHASE1_TARGETS``: the tool tilted 25-35 deg about world x, world y and both, turned about
     its own axis by up to 60 deg) with holds of 0.3-0.5 s;
  2. 7.3-9.8 s null-space-like swing: joints 1, 3, 5, 7 oscillate (0.25-0.3 rad);
  3. 9.8-15 s press-and-slide: the tip goes 4 cm down (the table is at the tip height reached,
     world z), the normal force ramps to 15 N, the tip slides 5 cm along +x, 4 cm along +y and back
     to where it touched down, the force ramps to 0 and the tool lifts 4 cm. Friction: Coulomb,
     mu = 0.3, against the tip's horizontal velocity, smoothed below 2 mm/s. Joint motion from IK
     at 20 ms knots (tool orientation fixed), interpolated by a quintic spline (exact derivatives).

Noise (``seed``): wrench N(0, 0.04 N / 0.002 N m), q N(0, 1e-5 rad), qdot N(0, 1e-3 rad/s); the
same draws for every case with the same seed, added after the hidden effects (tare last).

Logs
----
``log.csv.gz``: ``stamp_ns`` (int ns, epoch ``STAMP0_NS``), ``pos_j1..7`` [rad], ``vel_j1..7``
[rad/s], ``F_x F_y F_z T_x T_y T_z`` [N, N m] the wrench the SENSOR exerts on the TOOL (s axes,
about the s origin). ``log.parquet``: ``time_s`` [s from the first sample], ``a1..a7`` [deg], no
velocities, ``wrench_0..5`` the wrench the TOOL exerts on the SENSOR (= - csv wrench).
"""

from __future__ import annotations

import argparse
import functools
import gzip
import io
import json
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from scipy.interpolate import make_interp_spline

REPO_ROOT = Path(__file__).resolve().parents[1]
PANDA_XML = REPO_ROOT / "models" / "panda.xml"
FLANGE_SITE = "flange"

# --- the rig (true = declared, except for the hidden effects of a case) ---------------------------
SENSOR_POS_F_M = (0.0, 0.0, 0.012)  # [m] sensor origin in the flange frame f
SENSOR_RPY_F_DEG = (0.0, 0.0, -45.0)  # [deg] R_fs = Rz(yaw) Ry(pitch) Rx(roll)
SENSOR_HOUSING_KG = 0.3  # [kg] proximal of the measuring plane: never seen by the reading
TOOL_MASS_KG = 1.10
TOOL_COM_S_M = (0.004, -0.002, 0.055)  # [m] in s
TOOL_INERTIA_COM_KG_M2 = (0.0042, 0.0040, 0.0011, 0.0, 0.0, 0.0)  # ixx iyy izz ixy ixz iyz, s axes
TOOL_TIP_S_M = (0.010, 0.0, 0.180)  # [m] in s

# --- the experiment --------------------------------------------------------------------------------
RATE_HZ = 500.0
DURATION_S = 15.0
N_SAMPLES = 7501  # t_i = i / RATE_HZ, i = 0..7500
Q_HOME = (0.0, -math.pi / 4, 0.0, -3 * math.pi / 4, 0.0, math.pi / 2, math.pi / 4)  # [rad]
STAMP0_NS = 1_712_345_678_901_234_000  # [ns] epoch of the csv stamps
TARE_T_S = 0.2  # [s] tare instant (arm still at its start pose)
MU = 0.3  # Coulomb friction coefficient tip <-> table
NORMAL_FORCE_N = 15.0  # [N] plateau of the table's push on the tip
SLIP_SMOOTH_M_S = 0.002  # [m/s] friction = -mu N v / sqrt(|v|^2 + eps^2)

# Panda limits (Franka datasheet): velocity [rad/s] and acceleration [rad/s^2] per joint
QDOT_LIMIT = (2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61)
QDDOT_LIMIT = (15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0)

# Phase 1 IK targets for the sensor frame: (tilt rotation vector about world axes [deg], turn about
# the tool's own z [deg], sensor-origin displacement from its home position [m] in w), and the
# duration of the move to it and of the hold after it [s].
_PHASE1_TARGETS = (
    ((30.0, 0.0, 0.0), 0.0, (0.0, 0.03, 0.02), 0.7, 0.4),
    ((0.0, 30.0, 0.0), 0.0, (0.04, 0.0, 0.0), 0.7, 0.3),
    ((-25.0, 0.0, 0.0), 60.0, (0.0, -0.05, 0.03), 0.8, 0.5),
    ((0.0, -35.0, 0.0), 20.0, (-0.03, 0.02, 0.05), 0.75, 0.35),
    ((25.0, 20.0, 0.0), -30.0, (0.02, 0.04, -0.02), 0.8, 0.45),
    ((0.0, 0.0, 0.0), 30.0, (0.0, 0.0, 0.0), 0.75, 0.3),  # ends at the phase-2/3 base pose
)
_T_START_HOLD = 0.5
_SWING_S = 2.5
_SWING = ((0, 0.3, 2), (2, -0.3, 2), (4, 0.25, 2), (6, 0.25, 3))  # (joint index, amplitude [rad], cycles)
_KNOT_DT = 0.02  # [s] IK knots of phase 3
_DROP_M = 0.04  # [m] lowering / lifting of the tip
# phase 3, relative to its start: (duration [s], tip displacement in w [m] or None, normal force
# target [N] at the end of the segment or None = unchanged)
_PHASE3 = (
    (0.7, (0.0, 0.0, -_DROP_M), None),  # lower onto the table
    (0.5, None, NORMAL_FORCE_N),  # press
    (1.0, (0.05, 0.0, 0.0), None),  # slide +x
    (0.2, None, None),  # pause
    (0.7, (0.0, 0.04, 0.0), None),  # slide +y
    (0.9, (-0.05, -0.04, 0.0), None),  # slide back
    (0.4, None, 0.0),  # release
    (0.6, (0.0, 0.0, _DROP_M), None),  # lift off
    (0.2, None, None),  # hold
)

# --- noise -----------------------------------------------------------------------------------------
SIGMA_FORCE_N = 0.04
SIGMA_TORQUE_NM = 0.002
SIGMA_Q_RAD = 1e-5
SIGMA_QDOT_RAD_S = 1e-3


# ==================================================================================================
# cases
# ==================================================================================================
@dataclass(frozen=True)
class _Hidden:
    """What differs between the truth and the log (all in the csv's conventions)."""

    payload: tuple[float, tuple[float, float, float]] | None = None  # (kg, COM in s [m]) added to the tool
    rotvec_deg: tuple[float, float, float] | None = None  # sensor axes rotated by this (axis in s) [deg]
    drift_csv: tuple[float, ...] | None = None  # [N/s, N m/s] added to the csv (sensor_on_tool) wrench
    encoder_offset_deg: dict[int, float] = field(default_factory=dict)  # joint (1-7) -> true - logged [deg]
    tared: bool = False
    detectable: bool = True


def _rotvec_deg(angle_deg: float, axis: tuple[float, float, float]) -> tuple[float, float, float]:
    a = np.asarray(axis, dtype=float)
    return tuple(float(x) for x in angle_deg * a / np.linalg.norm(a))


_ROT_MAIN = _rotvec_deg(3.0, (1.0, 0.5, 1.0))  # = (2, 1, 2) deg
_ROT_PAIR = _rotvec_deg(2.5, (0.0, 1.0, 1.0))
_HIDDEN: dict[str, _Hidden] = {
    "none": _Hidden(),
    "tool_gravity": _Hidden(payload=(0.25, (0.03, -0.02, 0.06))),
    "ft_frame_rotation": _Hidden(rotvec_deg=_ROT_MAIN),
    "ft_bias_drift": _Hidden(drift_csv=(0.15, -0.10, 0.20, 0.010, 0.006, -0.008)),
    "encoder_offset": _Hidden(encoder_offset_deg={4: 1.0}),
    "encoder_offset_joint1": _Hidden(encoder_offset_deg={1: 2.0}, detectable=False),
    "pair": _Hidden(payload=(0.20, (0.0, 0.03, 0.05)), rotvec_deg=_ROT_PAIR),
    "tared_rotation": _Hidden(rotvec_deg=_ROT_MAIN, tared=True),
}

CASES: dict[str, str] = {
    "none": "no hidden effect: the log matches the declared rig",
    "tool_gravity": "an undeclared 0.25 kg payload at (0.03, -0.02, 0.06) m in the sensor frame",
    "ft_frame_rotation": "the sensor axes are rotated 3 deg about (1, 0.5, 1) (sensor frame) from the declared mount",
    "ft_bias_drift": "the wrench reading drifts linearly from t = 0 (csv convention: +(0.15, -0.10, 0.20) N/s, "
                     "+(0.010, 0.006, -0.008) N m/s)",
    "encoder_offset": "joint 4 reads 1.0 deg less than its true angle",
    "encoder_offset_joint1": "joint 1 reads 2.0 deg less than its true angle (invisible: gravity is "
                             "invariant under a joint-1 rotation)",
    "pair": "an undeclared 0.20 kg payload at (0, 0.03, 0.05) m AND sensor axes rotated 2.5 deg about (0, 1, 1)",
    "tared_rotation": "sensor axes rotated 3 deg about (1, 0.5, 1), log tared at t = 0.2 s",
}


def _effects_truth(h: _Hidden, sign: float = 1.0) -> dict[str, dict[str, float]]:
    """Truth in the diagnosis's reporting units; ``sign`` = -1 gives the drift in the parquet convention."""
    eff: dict[str, dict[str, float]] = {}
    if h.payload is not None:
        mass, com = h.payload
        eff["tool_gravity"] = {"mass": mass, "com_x": com[0], "com_y": com[1], "com_z": com[2]}
    if h.rotvec_deg is not None:
        eff["ft_frame_rotation"] = dict(zip(("rot_x", "rot_y", "rot_z"), h.rotvec_deg))
    if h.drift_csv is not None:
        names = ("rate_fx", "rate_fy", "rate_fz", "rate_tx", "rate_ty", "rate_tz")
        eff["ft_bias_drift"] = {n: sign * r for n, r in zip(names, h.drift_csv)}
    if h.encoder_offset_deg:
        eff["encoder_offset"] = {f"offset_joint{j}": v for j, v in sorted(h.encoder_offset_deg.items())}
    return eff


# ==================================================================================================
# geometry helpers
# ==================================================================================================
def rpy_matrix_deg(rpy_deg) -> np.ndarray:
    """``Rz(yaw) Ry(pitch) Rx(roll)`` for (roll, pitch, yaw) [deg]; (3,) -> (3, 3)."""
    r, p, y = np.deg2rad(np.asarray(rpy_deg, dtype=float))
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx


def rotvec_matrix(v) -> np.ndarray:
    """Rotation matrix of the rotation vector ``v`` [rad] (right-hand rule, Rodrigues); (3,) -> (3, 3)."""
    v = np.asarray(v, dtype=float)
    th = float(np.linalg.norm(v))
    if th < 1e-15:
        return np.eye(3)
    k = v / th
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(th) * kx + (1 - math.cos(th)) * kx @ kx


def matrix_rotvec(r: np.ndarray) -> np.ndarray:
    """Rotation vector [rad] of a rotation matrix with angle < pi; (3, 3) -> (3,)."""
    c = np.clip((np.trace(r) - 1.0) / 2.0, -1.0, 1.0)
    th = math.acos(c)
    w = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]]) / 2.0
    return w if th < 1e-9 else w * th / math.sin(th)


def _quat_of_matrix(r: np.ndarray) -> np.ndarray:
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(r, dtype=float).ravel())
    return q


# ==================================================================================================
# the MuJoCo model
# ==================================================================================================
def build_model(payload: tuple[float, tuple[float, float, float]] | None = None) -> mujoco.MjModel:
    """The shipped Panda with the F/T sensor and the true tool (and an optional extra payload).

    Bodies ``ft_sensor`` (welded to the flange's body at the sensor frame s) and ``tool`` (welded to
    ``ft_sensor``, body frame = s, inertial = the tool's); sites ``ft`` (= s, on ``tool``) and
    ``tip`` (true tip, on ``tool``); sensors ``ft_force`` / ``ft_torque`` on ``ft``. ``payload``
    = (mass [kg], COM in s [m]) adds a near-point-mass body ``payload`` welded to ``tool``.
    """
    spec = mujoco.MjSpec.from_file(str(PANDA_XML))
    flange = spec.site(FLANGE_SITE)
    parent = flange.parent
    r_bf = np.zeros(9)
    mujoco.mju_quat2Mat(r_bf, np.asarray(flange.quat, dtype=float))
    r_bf = r_bf.reshape(3, 3)
    r_bs = r_bf @ rpy_matrix_deg(SENSOR_RPY_F_DEG)
    p_bs = np.asarray(flange.pos, dtype=float) + r_bf @ np.asarray(SENSOR_POS_F_M)
    sensor = parent.add_body(name="ft_sensor", pos=p_bs, quat=_quat_of_matrix(r_bs))
    sensor.mass = SENSOR_HOUSING_KG
    sensor.ipos = [0.0, 0.0, -0.006]
    sensor.inertia = [1.5e-4, 1.5e-4, 2.5e-4]
    sensor.explicitinertial = True
    tool = sensor.add_body(name="tool")
    tool.mass = TOOL_MASS_KG
    tool.ipos = list(TOOL_COM_S_M)
    tool.fullinertia = list(TOOL_INERTIA_COM_KG_M2)
    tool.explicitinertial = True
    tool.add_site(name="ft", size=[0.005, 0.005, 0.005])
    tool.add_site(name="tip", pos=list(TOOL_TIP_S_M), size=[0.004, 0.004, 0.004])
    tool.add_geom(type=mujoco.mjtGeom.mjGEOM_CAPSULE, fromto=[0, 0, 0.01, *TOOL_TIP_S_M], size=[0.012, 0, 0],
                  contype=0, conaffinity=0, density=0.0, group=1)
    if payload is not None:
        mass, com = payload
        extra = tool.add_body(name="payload", pos=list(com))
        extra.mass = float(mass)
        extra.ipos = [0.0, 0.0, 0.0]  # (MjSpec's unset ipos is not the body origin)
        extra.inertia = [1e-8, 1e-8, 1e-8]
        extra.explicitinertial = True
    spec.add_sensor(name="ft_force", type=mujoco.mjtSensor.mjSENS_FORCE, objtype=mujoco.mjtObj.mjOBJ_SITE,
                    objname="ft")
    spec.add_sensor(name="ft_torque", type=mujoco.mjtSensor.mjSENS_TORQUE, objtype=mujoco.mjtObj.mjOBJ_SITE,
                    objname="ft")
    return spec.compile()


class _Ids:
    def __init__(self, m: mujoco.MjModel):
        self.ft = m.site("ft").id
        self.tip = m.site("tip").id
        self.tool = m.body("tool").id
        self.adr_f = int(m.sensor_adr[m.sensor("ft_force").id])
        self.adr_t = int(m.sensor_adr[m.sensor("ft_torque").id])


def _read_tool_on_sensor(m: mujoco.MjModel, d: mujoco.MjData, ids: _Ids) -> np.ndarray:
    """After ``d`` holds qpos/qvel/qacc/xfrc_applied: the wrench the tool exerts on the sensor,
    s axes, about the s origin, (6,) [N, N m] (MuJoCo's sensors give the sensor-on-tool wrench)."""
    mujoco.mj_inverse(m, d)
    mujoco.mj_rnePostConstraint(m, d)  # cacc / cfrc_int from the qacc given (explicit, version-proof)
    mujoco.mj_sensorAcc(m, d)
    return -np.concatenate([d.sensordata[ids.adr_f:ids.adr_f + 3], d.sensordata[ids.adr_t:ids.adr_t + 3]])


def inverse_dynamics_wrench(m: mujoco.MjModel, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray,
                            f_tip_w: np.ndarray | None = None) -> np.ndarray:
    """``w_tool_on_sensor_s`` (N, 6) [N, N m] for the motion q, qd, qdd (N, 7) [rad, rad/s, rad/s^2]
    and the external force ``f_tip_w`` (N, 3) [N, world axes] acting on the tool at the true tip
    (None: no contact). MuJoCo physics: qpos/qvel/qacc set, ``xfrc_applied`` = (F, (tip - COM) x F)
    at the tool body's COM, ``mj_inverse`` + ``mj_rnePostConstraint`` + ``mj_sensorAcc``."""
    d = mujoco.MjData(m)
    ids = _Ids(m)
    q, qd, qdd = (np.asarray(a, dtype=float) for a in (q, qd, qdd))
    out = np.empty((len(q), 6))
    for i in range(len(q)):
        d.qpos[:] = q[i]
        d.qvel[:] = qd[i]
        d.qacc[:] = qdd[i]
        f = None if f_tip_w is None else f_tip_w[i]
        if f is not None and np.any(f != 0.0):
            mujoco.mj_kinematics(m, d)  # tip and COM at this q
            r = d.site_xpos[ids.tip] - d.xipos[ids.tool]
            d.xfrc_applied[ids.tool, :3] = f
            d.xfrc_applied[ids.tool, 3:] = np.cross(r, f)
        else:
            d.xfrc_applied[ids.tool] = 0.0
        out[i] = _read_tool_on_sensor(m, d, ids)
    return out


def _fk(m: mujoco.MjModel, d: mujoco.MjData, q: np.ndarray) -> None:
    d.qpos[:] = q
    mujoco.mj_kinematics(m, d)
    mujoco.mj_comPos(m, d)


def _ik(m: mujoco.MjModel, d: mujoco.MjData, q0: np.ndarray, site: int, p_target: np.ndarray,
        r_target: np.ndarray, tol: float = 1e-11, iters: int = 200) -> np.ndarray:
    """Damped least squares on the 6D pose of ``site`` (position [m], orientation [rad]), from q0."""
    q = np.array(q0, dtype=float)
    jp, jr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
    for _ in range(iters):
        _fk(m, d, q)
        e = np.concatenate([p_target - d.site_xpos[site],
                            matrix_rotvec(r_target @ d.site_xmat[site].reshape(3, 3).T)])
        if np.linalg.norm(e) < tol:
            return q
        mujoco.mj_jacSite(m, d, jp, jr, site)
        j = np.vstack([jp, jr])
        q = q + j.T @ np.linalg.solve(j @ j.T + 1e-8 * np.eye(6), e)
    raise RuntimeError("IK did not converge")


# ==================================================================================================
# the trajectory
# ==================================================================================================
def _minjerk(tau: np.ndarray):
    """s, ds/dtau, d2s/dtau2 of 10 t^3 - 15 t^4 + 6 t^5 (tau clipped to [0, 1])."""
    t = np.clip(tau, 0.0, 1.0)
    return (10 * t**3 - 15 * t**4 + 6 * t**5, 30 * t**2 - 60 * t**3 + 30 * t**4, 60 * t - 180 * t**2 + 120 * t**3)


@dataclass
class Trajectory:
    """The scripted experiment at the log's samples.

    t (N,) [s]; q, qd, qdd (N, 7) [rad, rad/s, rad/s^2] true joint motion; f_tip_w (N, 3) [N] force
    of the table on the tool at the true tip (world axes); tip_w (N, 3) [m] true tip position;
    table_z_m [m]; contact_s (t0, t1) [s] where the normal force is > 0; ``eval(t)`` gives q, qd, qdd
    at any times in [0, 15] s (exact derivatives of the analytic / spline segments).
    """

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    f_tip_w: np.ndarray
    tip_w: np.ndarray
    table_z_m: float
    contact_s: tuple[float, float]
    segments: list

    def eval(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(q, qd, qdd), each (len(t), 7), at times ``t`` [s] (any in [0, DURATION_S])."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        q, qd, qdd = np.zeros((len(t), 7)), np.zeros((len(t), 7)), np.zeros((len(t), 7))
        for k, (t0, t1, fn) in enumerate(self.segments):
            last = k == len(self.segments) - 1
            mask = (t >= t0) & ((t <= t1) if last else (t < t1))
            if np.any(mask):
                q[mask], qd[mask], qdd[mask] = fn(t[mask])
        return q, qd, qdd


def _seg_minjerk(t0: float, t1: float, qa, qb):
    qa, qb = np.asarray(qa, dtype=float), np.asarray(qb, dtype=float)
    dq, T = qb - qa, t1 - t0

    def fn(t):
        s, ds, dds = _minjerk((t - t0) / T)
        return qa + s[:, None] * dq, (ds / T)[:, None] * dq, (dds / T**2)[:, None] * dq

    return (t0, t1, fn)


def _seg_swing(t0: float, t1: float, base):
    """q = base + sum_j A_j sin^2(pi tau) sin(2 pi n_j tau): zero offset, velocity and acceleration
    at both ends (C2 joins with the holds around it)."""
    base = np.asarray(base, dtype=float)
    T = t1 - t0

    def fn(t):
        tau = (t - t0) / T
        e, de, dde = np.sin(np.pi * tau) ** 2, np.pi * np.sin(2 * np.pi * tau), 2 * np.pi**2 * np.cos(2 * np.pi * tau)
        q = np.tile(base, (len(t), 1))
        qd, qdd = np.zeros_like(q), np.zeros_like(q)
        for j, amp, n in _SWING:
            w = 2 * np.pi * n
            s, ds, dds = np.sin(w * tau), w * np.cos(w * tau), -(w**2) * np.sin(w * tau)
            q[:, j] += amp * e * s
            qd[:, j] += amp * (de * s + e * ds) / T
            qdd[:, j] += amp * (dde * s + 2 * de * ds + e * dds) / T**2
        return q, qd, qdd

    return (t0, t1, fn)


def _seg_spline(t0: float, t1: float, spline):
    d1, d2 = spline.derivative(1), spline.derivative(2)
    return (t0, t1, lambda t: (spline(t), d1(t), d2(t)))


def _normal_force(t: np.ndarray, t3: float) -> np.ndarray:
    """Table normal force [N] (>= 0) at times t for phase 3 starting at t3: min-jerk ramps."""
    f = np.zeros_like(t)
    tc, level = t3, 0.0
    for dur, _, target in _PHASE3:
        if target is not None:
            s, _, _ = _minjerk((t - tc) / dur)
            inside = (t >= tc) & (t < tc + dur)
            f[inside] = level + (target - level) * s[inside]
            level = target
        else:
            inside = (t >= tc) & (t < tc + dur)
            f[inside] = level
        tc += dur
    return np.maximum(f, 0.0)


@functools.lru_cache(maxsize=1)
def trajectory() -> Trajectory:
    """Build the scripted 15 s experiment (cached: identical for every case and seed)."""
    m = build_model()
    d = mujoco.MjData(m)
    ids = _Ids(m)
    q_home = np.asarray(Q_HOME)
    _fk(m, d, q_home)
    p0, r0 = d.site_xpos[ids.ft].copy(), d.site_xmat[ids.ft].reshape(3, 3).copy()

    # phase 1: holds and min-jerk moves between IK poses
    segs = [_seg_minjerk(0.0, _T_START_HOLD, q_home, q_home)]
    tc, q_prev = _T_START_HOLD, q_home
    for tilt_deg, turn_deg, dp, t_move, t_hold in _PHASE1_TARGETS:
        r_t = rotvec_matrix(np.deg2rad(tilt_deg)) @ r0 @ rotvec_matrix(np.deg2rad([0.0, 0.0, turn_deg]))
        q_next = _ik(m, d, q_prev, ids.ft, p0 + np.asarray(dp), r_t)
        segs.append(_seg_minjerk(tc, tc + t_move, q_prev, q_next))
        segs.append(_seg_minjerk(tc + t_move, tc + t_move + t_hold, q_next, q_next))
        tc, q_prev = tc + t_move + t_hold, q_next
    q_base = q_prev

    # phase 2: swing of joints 1, 3, 5, 7 about the base pose
    segs.append(_seg_swing(tc, tc + _SWING_S, q_base))
    tc += _SWING_S

    # phase 3: tip path in world (tool orientation fixed), IK at knots, quintic spline
    t3 = tc
    t_end = t3 + sum(s[0] for s in _PHASE3)
    if abs(t_end - DURATION_S) > 1e-9:
        raise RuntimeError("phase durations do not add up to DURATION_S")
    _fk(m, d, q_base)
    tip0, r_tip = d.site_xpos[ids.tip].copy(), d.site_xmat[ids.tip].reshape(3, 3).copy()
    n_knots = int(round((t_end - t3) / _KNOT_DT)) + 1
    tk = np.linspace(t3, t_end, n_knots)
    tip_k = np.tile(tip0, (n_knots, 1))
    ts = t3
    for dur, dp, _ in _PHASE3:
        if dp is not None:
            s, _, _ = _minjerk((tk - ts) / dur)
            tip_k += s[:, None] * np.asarray(dp)[None, :]
        ts += dur
    qk = np.empty((n_knots, 7))
    q_prev = q_base
    for i in range(n_knots):
        q_prev = qk[i] = _ik(m, d, q_prev, ids.tip, tip_k[i], r_tip)
    zero = np.zeros(7)
    spline = make_interp_spline(tk, qk, k=5, bc_type=([(1, zero), (2, zero)], [(1, zero), (2, zero)]))
    segs.append(_seg_spline(t3, t_end, spline))

    traj = Trajectory(t=np.arange(N_SAMPLES) / RATE_HZ, q=None, qd=None, qdd=None, f_tip_w=None, tip_w=None,
                      table_z_m=float("nan"), contact_s=(0.0, 0.0), segments=segs)
    traj.q, traj.qd, traj.qdd = traj.eval(traj.t)

    # contact: the table at the tip height reached after lowering; normal force + Coulomb friction
    t_touch = t3 + _PHASE3[0][0]
    fn = _normal_force(traj.t, t3)
    tip_w = np.empty((N_SAMPLES, 3))
    f_tip = np.zeros((N_SAMPLES, 3))
    jp = np.zeros((3, m.nv))
    for i in range(N_SAMPLES):
        _fk(m, d, traj.q[i])
        tip_w[i] = d.site_xpos[ids.tip]
        if fn[i] > 0.0:
            mujoco.mj_jacSite(m, d, jp, None, ids.tip)
            v = jp @ traj.qd[i]
            vh = np.array([v[0], v[1], 0.0])
            f_tip[i] = np.array([0.0, 0.0, fn[i]]) - MU * fn[i] * vh / math.sqrt(vh @ vh + SLIP_SMOOTH_M_S**2)
    i_touch = int(round(t_touch * RATE_HZ))
    traj.tip_w, traj.f_tip_w = tip_w, f_tip
    traj.table_z_m = float(tip_w[i_touch, 2])
    on = np.nonzero(fn > 0.0)[0]
    traj.contact_s = (float(traj.t[on[0]]), float(traj.t[on[-1]]))
    return traj


@functools.lru_cache(maxsize=8)
def true_wrench(payload: tuple[float, tuple[float, float, float]] | None = None) -> np.ndarray:
    """``w_tool_on_sensor_s`` (N, 6) [N, N m] of the experiment with the true tool (+ ``payload``),
    noiseless, the sensor axes as mounted (cached; read-only)."""
    tr = trajectory()
    w = inverse_dynamics_wrench(build_model(payload), tr.q, tr.qd, tr.qdd, tr.f_tip_w)
    w.setflags(write=False)
    return w


# ==================================================================================================
# a case's signals and files
# ==================================================================================================
def case_signals(name: str, seed: int = 0, noise: bool = True) -> dict[str, np.ndarray]:
    """The logged signals of case ``name`` (csv conventions).

    Returns ``t`` (N,) [s from the first sample], ``q`` (N, 7) [rad] logged encoder angles, ``qdot``
    (N, 7) [rad/s], ``wrench`` (N, 6) [N, N m] the sensor-on-tool wrench in the (possibly rotated)
    sensor axes about the sensor origin, and ``w_tool_on_sensor_s`` (N, 6) the noiseless true
    tool-on-sensor wrench in the declared axes (no hidden effect of the sensor). Pipeline: payload
    (physics) -> sensor-axes rotation R^T w -> csv sign -> drift -> noise (same draws for every case
    of a seed; ``noise=False`` leaves it out) -> tare (subtract the sample at ``TARE_T_S``).
    """
    if name not in _HIDDEN:
        raise KeyError(f"unknown case '{name}' (choose from {', '.join(CASES)})")
    h = _HIDDEN[name]
    tr = trajectory()
    w_true = np.array(true_wrench(h.payload))
    w = w_true.copy()
    if h.rotvec_deg is not None:
        r = rotvec_matrix(np.deg2rad(h.rotvec_deg))
        w = np.hstack([w[:, :3] @ r, w[:, 3:] @ r])  # row-wise R^T w
    w_csv = -w
    if h.drift_csv is not None:
        w_csv = w_csv + tr.t[:, None] * np.asarray(h.drift_csv)[None, :]
    q = tr.q.copy()
    for j, off in h.encoder_offset_deg.items():
        q[:, j - 1] -= math.radians(off)
    qdot = tr.qd.copy()
    if noise:
        rng = np.random.default_rng(seed)
        q += rng.normal(0.0, SIGMA_Q_RAD, q.shape)
        qdot += rng.normal(0.0, SIGMA_QDOT_RAD_S, qdot.shape)
        sig = np.array([SIGMA_FORCE_N] * 3 + [SIGMA_TORQUE_NM] * 3)
        w_csv = w_csv + rng.normal(0.0, 1.0, w_csv.shape) * sig
    if h.tared:
        w_csv = w_csv - w_csv[int(round(TARE_T_S * RATE_HZ))]
    return {"t": tr.t.copy(), "q": q, "qdot": qdot, "wrench": w_csv, "w_tool_on_sensor_s": w_true}


CSV_TIME = "stamp_ns"
CSV_Q = tuple(f"pos_j{j}" for j in range(1, 8))
CSV_QDOT = tuple(f"vel_j{j}" for j in range(1, 8))
CSV_WRENCH = ("F_x", "F_y", "F_z", "T_x", "T_y", "T_z")
PQ_TIME = "time_s"
PQ_Q = tuple(f"a{j}" for j in range(1, 8))
PQ_WRENCH = tuple(f"wrench_{k}" for k in range(6))


def _write_csv_gz(path: Path, sig: dict[str, np.ndarray]) -> None:
    stamps = STAMP0_NS + np.round(sig["t"] * 1e9).astype(np.int64)
    block = np.hstack([sig["q"], sig["qdot"], sig["wrench"]])
    buf = io.StringIO()
    np.savetxt(buf, block, fmt=["%.10f"] * 7 + ["%.8f"] * 7 + ["%.6f"] * 6, delimiter=",")
    header = ",".join((CSV_TIME, *CSV_Q, *CSV_QDOT, *CSV_WRENCH))
    body = "\n".join(f"{s},{line}" for s, line in zip(stamps.tolist(), buf.getvalue().splitlines()))
    with open(path, "wb") as fh, gzip.GzipFile(filename="", mode="wb", fileobj=fh, mtime=0) as gz:
        gz.write((header + "\n" + body + "\n").encode())


def _write_parquet(path: Path, sig: dict[str, np.ndarray]) -> None:
    cols = {PQ_TIME: sig["t"]}
    q_deg = np.rad2deg(sig["q"])
    cols.update({n: q_deg[:, k] for k, n in enumerate(PQ_Q)})
    w = -sig["wrench"]  # tool_on_sensor
    cols.update({n: w[:, k] for k, n in enumerate(PQ_WRENCH)})
    pq.write_table(pa.table({k: pa.array(np.ascontiguousarray(v), pa.float64()) for k, v in cols.items()}), path)


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (int, float)):
        return repr(float(v)) if isinstance(v, float) else str(v)
    return "[" + ", ".join(_toml_value(x) for x in v) + "]"


def setup_toml(variant: str, tared: bool) -> str:
    """The setup file (TOML text) a user of this rig would write: the NOMINAL rig (no hidden
    effect) and the column layout of ``variant`` = "csv" or "parquet"."""
    if variant == "csv":
        log = {"time": CSV_TIME, "time_scale_s": 1e-9, "q": CSV_Q, "qdot": CSV_QDOT, "angle_unit": "rad",
               "wrench": CSV_WRENCH, "wrench_acts": "sensor_on_tool", "tared": tared}
        what = "log.csv.gz: integer ns stamps, rad, wrench of the sensor on the tool"
    elif variant == "parquet":
        log = {"time": PQ_TIME, "time_scale_s": 1.0, "q": PQ_Q, "qdot": (), "angle_unit": "deg",
               "wrench": PQ_WRENCH, "wrench_acts": "tool_on_sensor", "tared": tared}
        what = "log.parquet: s, deg, no velocities, wrench of the tool on the sensor"
    else:
        raise ValueError(f"variant must be 'csv' or 'parquet' (got '{variant}')")
    sections = {
        "log": log,
        "sensor": {"position_flange_m": SENSOR_POS_F_M, "rpy_flange_deg": SENSOR_RPY_F_DEG},
        "tool": {"mass_kg": TOOL_MASS_KG, "com_sensor_m": TOOL_COM_S_M,
                 "inertia_com_kg_m2": TOOL_INERTIA_COM_KG_M2, "tip_sensor_m": TOOL_TIP_S_M},
        "arm": {"mjcf": "", "flange_site": FLANGE_SITE},
        "contact": {"mode": "tip", "detect_force_N": 4.0, "margin_s": 0.1},
        "analysis": {"exclude_s": (), "effects": (), "exclude_effects": ()},
    }
    lines = [f"# Foreign rig (examples/foreign_rig.py): the declared (nominal) set-up of {what}.", ""]
    for sec, kv in sections.items():
        lines.append(f"[{sec}]")
        lines += [f"{k} = {_toml_value(v)}" for k, v in kv.items()]
        lines.append("")
    return "\n".join(lines)


def make_case(name: str, out_dir: Path, seed: int = 0) -> Path:
    """Write case ``name`` into ``out_dir/name/`` (log.csv.gz, log.parquet, setup_csv.toml,
    setup_parquet.toml, truth.json) and return that folder."""
    if name not in _HIDDEN:
        raise KeyError(f"unknown case '{name}' (choose from {', '.join(CASES)})")
    h = _HIDDEN[name]
    case_dir = Path(out_dir) / name
    case_dir.mkdir(parents=True, exist_ok=True)
    sig = case_signals(name, seed)
    _write_csv_gz(case_dir / "log.csv.gz", sig)
    _write_parquet(case_dir / "log.parquet", sig)
    (case_dir / "setup_csv.toml").write_text(setup_toml("csv", h.tared))
    (case_dir / "setup_parquet.toml").write_text(setup_toml("parquet", h.tared))
    tr = trajectory()
    truth = {"case": name, "description": CASES[name], "effects": _effects_truth(h), "detectable": h.detectable,
             "tared": h.tared}
    if h.drift_csv is not None:
        truth["truth_parquet"] = _effects_truth(h, sign=-1.0)  # the effects in log.parquet's convention
    truth["seed"] = int(seed)
    truth["rig"] = {"table_z_m": tr.table_z_m, "contact_s": list(tr.contact_s), "mu": MU,
                    "normal_force_N": NORMAL_FORCE_N, "tare_t_s": TARE_T_S if h.tared else None}
    (case_dir / "truth.json").write_text(json.dumps(truth, indent=2) + "\n")
    return case_dir


# ==================================================================================================
# self-test of the MuJoCo wrench (sign and frame)
# ==================================================================================================
def self_test(tol: float = 1e-9) -> dict[str, float]:
    """Check the MuJoCo reading against statics, at q_home and three tilted poses at rest.

    (1) ``w_tool_on_sensor_s`` = (m R_ws^T g, c x m R_ws^T g) with R_ws from MuJoCo's ``site_xmat``
    of the sensor site; (2) a tip force F (world) changes it by (R_ws^T F, tip x R_ws^T F);
    (3) the sensor agrees with ``cfrc_int`` of the tool body. Returns the largest errors [N or N m];
    raises AssertionError beyond ``tol``.
    """
    m = build_model()
    d = mujoco.MjData(m)
    ids = _Ids(m)
    g = np.asarray(m.opt.gravity, dtype=float)
    c, tip = np.asarray(TOOL_COM_S_M), np.asarray(TOOL_TIP_S_M)
    f_w = np.array([2.5, -1.5, 12.0])
    err = {"static": 0.0, "tip_force": 0.0, "cfrc_int": 0.0}
    poses = [np.asarray(Q_HOME), np.asarray(Q_HOME) + [0.3, 0.4, -0.2, 0.3, 0.6, -0.5, 1.0],
             np.array([-1.0, 0.2, 0.5, -1.8, -1.2, 2.2, -0.7]), np.array([0.5, -1.2, -0.8, -2.6, 1.5, 0.8, 2.0])]
    for q in poses:
        d.qpos[:], d.qvel[:], d.qacc[:] = q, 0.0, 0.0
        d.xfrc_applied[:] = 0.0
        w0 = _read_tool_on_sensor(m, d, ids)
        r_ws = d.site_xmat[ids.ft].reshape(3, 3).copy()
        fg = TOOL_MASS_KG * r_ws.T @ g
        err["static"] = max(err["static"], float(np.abs(w0 - np.r_[fg, np.cross(c, fg)]).max()))
        # cfrc_int: [torque about subtree_com of the root; force], world axes, parent-on-body
        root = m.body_rootid[ids.tool]
        ci = d.cfrc_int[ids.tool]
        tau_site = ci[:3] - np.cross(d.site_xpos[ids.ft] - d.subtree_com[root], ci[3:])
        err["cfrc_int"] = max(err["cfrc_int"], float(np.abs(-np.r_[r_ws.T @ ci[3:], r_ws.T @ tau_site] - w0).max()))
        # a known tip force
        mujoco.mj_kinematics(m, d)
        d.xfrc_applied[ids.tool, :3] = f_w
        d.xfrc_applied[ids.tool, 3:] = np.cross(d.site_xpos[ids.tip] - d.xipos[ids.tool], f_w)
        w1 = _read_tool_on_sensor(m, d, ids)
        fs = r_ws.T @ f_w
        err["tip_force"] = max(err["tip_force"], float(np.abs((w1 - w0) - np.r_[fs, np.cross(tip, fs)]).max()))
    bad = {k: v for k, v in err.items() if not v <= tol}
    if bad:
        raise AssertionError(f"MuJoCo wrench self-test failed: {bad}")
    return err


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description="Write foreign-rig test logs for `kinadapt diagnose`.")
    p.add_argument("--out", type=Path, required=True, help="output folder (one subfolder per case)")
    p.add_argument("--case", nargs="+", default=list(CASES), choices=list(CASES), help="cases (default: all)")
    p.add_argument("--seed", type=int, default=0, help="noise seed")
    p.add_argument("--self-test", action="store_true", help="check the MuJoCo wrench against statics first")
    a = p.parse_args(argv)
    if a.self_test:
        print("self-test max errors:", {k: f"{v:.1e}" for k, v in self_test().items()})
    for name in a.case:
        t0 = time.perf_counter()
        d = make_case(name, a.out, a.seed)
        print(f"{d}: {', '.join(sorted(x.name for x in d.iterdir()))} ({time.perf_counter() - t0:.2f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
