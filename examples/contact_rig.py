"""A contact-task rig: logs for ``kinadapt diagnose`` the way a real contact-task robot writes them.

Standalone on purpose, like ``examples/foreign_rig.py``: this file imports nothing from
``kinadapt_nn`` (only MuJoCo, NumPy, SciPy and the standard library); the only shared input is the
arm model ``examples/arms/ur5e.urdf``. ::

    python examples/contact_rig.py --out DIR [--case NAME ...] [--seed N] [--mount-known] [--self-test]

What a real contact-task log looks like (issue 38): mostly contact, weakly excited. 10 s at 200 Hz
(2001 samples) of a UR5e, the wrench tared at the first pose, ~3 s of guarded approach in free
space during which the wrist turns only 18 deg about ONE axis, then ~7 s (70 %) of contact to the
end of the log.

Frames: ``w`` world (z up, gravity (0, 0, -9.81) m/s^2), ``f`` the flange = the URDF's last link
``wrist_3_link`` (the frame the diagnosis takes for ``[arm] urdf`` with ``flange_link = ""``), ``s``
the F/T sensor frame: origin ``SENSOR_POS_F_M`` in ``f``, axes ``R_fs = Rz(yaw) Ry(pitch) Rx(roll)``
with (roll, pitch, yaw) = ``SENSOR_RPY_F_DEG`` = (10, -5, 120) deg (an adapter with a wedge, turned
on its bolt circle). The tool (everything distal of the measuring plane) in ``s``: 0.62 kg, centre
of mass (0.012, -0.006, 0.055) m (off-axis), inertia ``TOOL_INERTIA_COM_KG_M2``; its contact point,
the "tip", at (0.03, -0.015, 0.12) m, well off the sensor axis.

Physics (as foreign_rig's): bodies ``ft_sensor`` (housing, arm side) and ``tool`` welded to the
flange in MuJoCo; the scripted q, qdot, qddot go to qpos/qvel/qacc, the contact's force and moment
(about the contact point) are applied to the tool through ``xfrc_applied``, and ``mj_inverse`` +
``mj_rnePostConstraint`` + ``mj_sensorAcc`` give the force/torque sensors on the tool's site
(``cfrc_int``: the sensor-on-tool wrench; the log holds its negation, the tool-on-sensor wrench).

The experiment (``trajectory``; every joint pose from IK of the tip, 6D, at every sample, joined by
a quintic interpolating spline at rest at both ends for exact velocities and accelerations):
  0.0-0.5 s   hold at the start pose (the tare: the sensor is zeroed here, at the first sample);
  0.5-2.5 s   approach: the tip moves ~12 cm down towards a horizontal table while the tool turns
              18 deg about one horizontal world axis (``APPROACH_AXIS_W``) into its contact
              orientation (tool axis s_z straight down); no other rotation in free space;
  2.5-3.0 s   guarded descent at 12 mm/s; the tip touches the table at ``T_TOUCH_S`` = 3.0 s, the
              normal force rises to 8 N in 50 ms (the arm stops in 60 ms) and to 12 N by 3.5 s, then
              varies 10.5-13.5 N;
  ``point``:  3.5-7.0 s the tip sticks while the tool pivots about it (a 10 deg tilt that goes round,
              a 12 deg twist) and pushes sideways within the friction cone (40 % of the normal force,
              its direction turning 1.5 times round); 7.0-9.0 s it slides 25 mm and 20 mm in two
              directions (Coulomb friction mu = 0.35 against the tip's velocity); 9.1-10 s a 30 %
              sideways push. The contact force's direction in ``s`` changes by tens of degrees.
  ``flat``:   the tool ends in a box peg whose 20 x 20 mm face (centre = the tip, normal = s_z) is
              pressed flat on the table and slid (20, 18, 15 mm in three directions) and twisted
              about the normal (+-15-25 deg); the face carries a moment about its centre: the
              pressure centre shifts towards the leading edge (3.5 mm) and wanders (1.5 mm), and
              torsional friction (limit-surface approximation, effective radius 7.65 mm) resists
              the twist: 0.03-0.06 N m in all.

Cases (``CASES``): ``point`` (a point contact at the tip) and ``flat_face`` (the face contact plus a
hidden F/T crosstalk: the sensor reports ``Fx + 0.04 Fz``; the user's effect file for it is
``examples/effects/crosstalk_fx_fz.py``). To first order that crosstalk does to the force what a
mount rotation of 0.04 rad about s_y does, and in contact what a tool tilt about s_y does to the
moment about the tip: with this weak free-space motion it separates from them only through the
moment about s_z and the small changes of Fz in free space. ``flat_face_rich`` is ``flat_face``
after a rich free-space phase that separates them (``RICH_TARGETS``, 7.7 s, so the log is 17.7 s,
3541 samples, 40 % contact, touch-down at 10.7 s): from the start pose (held 0.5 s: the tare) six
min-jerk moves with short holds, the tool tilted 25-35 deg about world x, world y and both, turned
about its own axis by up to 60 deg (rotations along the geodesic, the tip moved by a few cm), back
to the start pose; then the flat_face experiment unchanged (same q and contact wrench, delayed).
``flat_face_alone`` and ``flat_face_alone_rich`` are ``flat_face`` and ``flat_face_rich`` with
nothing hidden but the face contact (no crosstalk): the effect-free face-contact logs.
``flat_face_rotation`` is ``flat_face_alone_rich`` read by a sensor whose measuring axes are rotated
2.05 deg from its body (rotation vector ``AXES_ROTVEC_DEG`` = (1.2, -0.9, 1.4) deg in the body axes:
it reports ``R^T F``, ``R^T M``), the body's true mount declared known: a hidden ``ft_frame_rotation``
beside the unmodelled face. Also after the rich free motion, the mount declared known:
``flat_face_true_tool`` (the true tool declared too: nothing but the face), ``flat_face_drift`` (the
reading drifts, ``DRIFT_PER_S``), ``flat_face_encoder`` (joint 4 reads 1 deg short) and
``flat_face_crosstalk_mount_known`` (``flat_face_rich`` with the mount declared). Pipeline: physics -> crosstalk
``(I + E) w`` -> measuring axes ``diag(R^T, R^T)`` -> tare (minus the noise-free reading at the first pose) -> drift -> noise N(0, 0.05 N /
0.003 N m) -> text with 6 decimals (q to 1 urad).

Per case ``DIR/<case>/``: ``log.csv`` (``t`` [s], ``q1..q6`` [rad], ``fx fy fz tx ty tz`` [N, N m]
the tool-on-sensor wrench in ``s``), ``setup.toml`` (the set-up as a user would declare it: the
URDF, tared, the mount unknown with a zero first guess -- or with ``--mount-known`` the true mount
declared known --, a guessed 0.5 kg tool with its centre of mass on the axis; ``point`` declares no
tip, the flat cases the face centre) and ``truth.json``.
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import sys
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np
from scipy.interpolate import make_interp_spline

REPO_ROOT = Path(__file__).resolve().parents[1]
UR5E_URDF = REPO_ROOT / "examples" / "arms" / "ur5e.urdf"
FLANGE_BODY = "wrist_3_link"

# --- the rig (true) --------------------------------------------------------------------------------
SENSOR_POS_F_M = (0.0, 0.0, 0.02)  # [m] sensor origin in f (declared as it is)
SENSOR_RPY_F_DEG = (10.0, -5.0, 120.0)  # [deg] R_fs = Rz(yaw) Ry(pitch) Rx(roll); declared unknown
SENSOR_HOUSING_KG = 0.25  # [kg] arm side of the measuring plane: never seen by the reading
TOOL_MASS_KG = 0.62
TOOL_COM_S_M = (0.012, -0.006, 0.055)  # [m] in s
TOOL_INERTIA_COM_KG_M2 = (0.0011, 0.0013, 0.0005, 0.0001, 0.0, 0.0)  # ixx iyy izz ixy ixz iyz, s axes
TIP_S_M = (0.03, -0.015, 0.12)  # [m] the contact point (the flat peg's face centre) in s
FACE_SIDE_M = 0.02  # [m] the flat peg's square face
FACE_RADIUS_M = 0.3826 * FACE_SIDE_M  # [m] mean distance of a square's points from its centre
CROSSTALK_FX_FROM_FZ = 0.04  # flat_face: the sensor reports Fx + 0.04 Fz
LINK_MASS_KG = 1.0  # the arm's links (the URDF has no inertials; they do not change the reading)

# --- what the user declares ------------------------------------------------------------------------
DECLARED_MASS_KG = 0.5
DECLARED_COM_S_M = (0.0, 0.0, 0.05)

# --- the experiment --------------------------------------------------------------------------------
RATE_HZ = 200.0
N_SAMPLES = 2001  # t_i = i / RATE_HZ, 10 s
Q_REF = (0.0, -math.pi / 2, math.pi / 2, -math.pi / 2, -math.pi / 2, 0.0)  # [rad] near the contact pose
APPROACH_TURN_DEG = 18.0  # [deg] the only free-space rotation, about APPROACH_AXIS_W
APPROACH_AXIS_W = (math.cos(math.radians(30.0)), math.sin(math.radians(30.0)), 0.0)
START_OFFSET_W_M = (0.03, -0.04, 0.11)  # [m] start tip position from the guard point
T_APPROACH_S = (0.5, 2.5)  # [s] the min-jerk approach
T_GUARD_S, GUARD_RAMP_S, GUARD_SPEED_M_S = 2.5, 0.2, 0.012  # guarded descent: start, speed-up, speed
T_TOUCH_S, STOP_S = 3.0, 0.06  # [s] touch-down; the arm stops within STOP_S
IMPACT_N, IMPACT_S, PRESS_N, T_PRESS_S = 8.0, 0.05, 12.0, 3.5  # normal force: impact, then the press
FORCE_WAVE_N, FORCE_WAVE_S = 1.5, 2.3  # normal force variation after T_PRESS_S
MU = 0.35  # Coulomb friction tip/face <-> table
SLIP_SMOOTH_M_S = 0.002  # [m/s] friction = -mu N v / sqrt(|v|^2 + eps^2)
# point contact: pivot (tilt amplitude, twist amplitude [deg], sideways push fraction, turns of it)
T_PIVOT_S, PIVOT_TILT_DEG, PIVOT_TWIST_DEG, PIVOT_PUSH, PIVOT_PUSH_TURNS = (3.5, 7.0), 10.0, 12.0, 0.4, 1.5
PIVOT_EDGE_S = 1.0  # [s] the pivot's and the push's min-jerk fade in / out
# slides: (t0, t1, distance [m], direction in the table plane [deg], twist about the normal [deg])
POINT_SLIDES = ((7.0, 7.9, 0.025, -40.0, 0.0), (8.1, 9.0, 0.020, 80.0, 0.0))
FLAT_SLIDES = ((3.5, 5.0, 0.020, 20.0, 15.0), (5.3, 6.8, 0.018, 130.0, -25.0), (7.1, 8.4, 0.0, 0.0, 20.0),
               (8.4, 9.4, 0.015, 250.0, -10.0))
T_PUSH_S, PUSH_FRACTION, PUSH_DIR_DEG = (9.1, 9.5), 0.3, 200.0  # point: final sideways push
COP_LEAD_M, COP_WANDER_M = 0.0035, 0.0015  # flat: pressure-centre shift towards the leading edge, wander
TWIST_SMOOTH_RAD_S = 0.02  # [rad/s] torsional friction smoothing
# rich free motion (``flat_face_rich``), before the experiment above: from the start pose, min-jerk
# moves (IK of the tip, 6D) to (tilt rotation vector about world axes [deg], turn about the tool
# axis s_z [deg], tip displacement in w [m], move [s], hold after it [s]); the last returns to the
# start pose. Tilts of 25-35 deg about world x, y and both; turns about s_z of up to 60 deg.
RICH_START_HOLD_S = 0.5  # [s] the tare pose, held first
RICH_TARGETS = (
    ((30.0, 0.0, 0.0), 0.0, (0.0, 0.03, 0.02), 0.9, 0.3),
    ((0.0, 30.0, 0.0), 0.0, (0.04, 0.0, 0.0), 0.9, 0.3),
    ((-25.0, 0.0, 0.0), 60.0, (0.0, -0.04, 0.03), 1.0, 0.3),
    ((0.0, -35.0, 0.0), 20.0, (-0.03, 0.02, 0.04), 1.0, 0.3),
    ((25.0, 20.0, 0.0), -30.0, (0.02, 0.03, 0.0), 1.0, 0.3),
    ((0.0, 0.0, 0.0), 0.0, (0.0, 0.0, 0.0), 0.9, 0.0),
)
T_RICH_S = RICH_START_HOLD_S + sum(mv + hold for *_, mv, hold in RICH_TARGETS)  # [s] the experiment's delay

# --- noise -----------------------------------------------------------------------------------------
SIGMA_FORCE_N = 0.05
SIGMA_TORQUE_NM = 0.003


@dataclass(frozen=True)
class Case:
    """One log of the rig."""

    description: str
    contact: str  # "point": a point contact at the tip; "flat": the box peg's face
    free_motion: str  # "turn": the 18 deg approach turn only; "rich": RICH_TARGETS first
    crosstalk_fx_from_fz: float  # [-] the sensor reports Fx + this Fz
    declares_tip: bool  # the set-up declares the tip (the face centre)
    #: [deg] the sensor's measuring axes rotated from its body by this rotation vector (body axes s): it reports
    #: ``R^T F`` and ``R^T M``; the set-up then declares the body's true mount, known (``ft_frame_rotation``)
    axes_rotvec_deg: tuple[float, float, float] | None = None
    drift_per_s: tuple[float, ...] | None = None  #: [N/s, N m/s] the reading drifts linearly from the first sample
    encoder_offset_deg: tuple[int, float] | None = None  #: (joint 1-6, true - logged [deg]) an encoder's zero offset
    declares_true_tool: bool = False  #: the set-up declares the true tool (mass, COM, inertia), not the guess
    declares_mount: bool = False  #: the set-up declares the true mount, known (also with any hidden sensor effect)


_FACE = ("a 20 x 20 mm box-peg face pressed, slid and twisted on the table (a moment about the face centre: "
         "pressure shift + torsional friction)")
_FLAT = _FACE + " and a hidden crosstalk Fx += 0.04 Fz"
AXES_ROTVEC_DEG = (1.2, -0.9, 1.4)  # [deg] flat_face_rotation: the measuring axes' rotation (2.05 deg)
DRIFT_PER_S = (0.06, -0.04, 0.05, 0.006, -0.005, 0.004)  # [N/s, N m/s] flat_face_drift
ENCODER_OFFSET_DEG = (4, 1.0)  # flat_face_encoder: joint 4 reads 1 deg less than it is
_RICH = "; first the rich free-space phase"
CASES: dict[str, Case] = {
    "point": Case("a point contact at the tip (0.03, -0.015, 0.12) m of the sensor frame, not declared; pivot, "
                  "sideways pushes and slides change the force's direction", "point", "turn", 0.0, False),
    "flat_face": Case(_FLAT, "flat", "turn", CROSSTALK_FX_FROM_FZ, True),
    "flat_face_rich": Case(_FLAT + "; first a rich free-space phase (tilts of 25-35 deg about two axes, turns "
                           "about the tool axis)", "flat", "rich", CROSSTALK_FX_FROM_FZ, True),
    "flat_face_alone": Case(_FACE + "; nothing else hidden", "flat", "turn", 0.0, True),
    "flat_face_alone_rich": Case(_FACE + "; nothing else hidden; first the rich free-space phase of flat_face_rich",
                                 "flat", "rich", 0.0, True),
    "flat_face_rotation": Case(_FACE + "; the sensor's measuring axes rotated 2.05 deg from its body (rotation vector "
                               "(1.2, -0.9, 1.4) deg, the body's mount declared known); first the rich free-space phase",
                               "flat", "rich", 0.0, True, AXES_ROTVEC_DEG),
    "flat_face_true_tool": Case(_FACE + "; nothing else hidden: the true tool (mass, COM, inertia) and mount declared"
                                + _RICH, "flat", "rich", 0.0, True, declares_true_tool=True, declares_mount=True),
    "flat_face_drift": Case(_FACE + "; the reading drifts linearly (0.06, -0.04, 0.05 N/s, 0.006, -0.005, 0.004 "
                            "N m/s), the mount declared" + _RICH, "flat", "rich", 0.0, True, drift_per_s=DRIFT_PER_S,
                            declares_mount=True),
    "flat_face_encoder": Case(_FACE + "; joint 4's encoder reads 1 deg less than the joint's angle, the mount "
                              "declared" + _RICH, "flat", "rich", 0.0, True, encoder_offset_deg=ENCODER_OFFSET_DEG,
                              declares_mount=True),
    "flat_face_crosstalk_mount_known": Case(_FLAT + "; the mount declared" + _RICH, "flat", "rich",
                                            CROSSTALK_FX_FROM_FZ, True, declares_mount=True),
}
Q_COLS = tuple(f"q{j}" for j in range(1, 7))
WRENCH_COLS = ("fx", "fy", "fz", "tx", "ty", "tz")


# ==================================================================================================
# rotations
# ==================================================================================================
def rpy_matrix_deg(rpy_deg) -> np.ndarray:
    """``Rz(yaw) Ry(pitch) Rx(roll)`` for (roll, pitch, yaw) [deg]; (3,) -> (3, 3)."""
    r, p, y = np.deg2rad(np.asarray(rpy_deg, dtype=float))
    rx = np.array([[1, 0, 0], [0, math.cos(r), -math.sin(r)], [0, math.sin(r), math.cos(r)]])
    ry = np.array([[math.cos(p), 0, math.sin(p)], [0, 1, 0], [-math.sin(p), 0, math.cos(p)]])
    rz = np.array([[math.cos(y), -math.sin(y), 0], [math.sin(y), math.cos(y), 0], [0, 0, 1]])
    return rz @ ry @ rx


def rotvec_matrix(v) -> np.ndarray:
    """Rotation matrix of the rotation vector ``v`` [rad] (Rodrigues); (3,) -> (3, 3)."""
    v = np.asarray(v, dtype=float)
    th = float(np.linalg.norm(v))
    if th < 1e-15:
        return np.eye(3)
    k = v / th
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(th) * kx + (1 - math.cos(th)) * kx @ kx


def matrix_rotvec(r: np.ndarray) -> np.ndarray:
    """Rotation vector [rad] of a rotation matrix with angle < pi; (3, 3) -> (3,)."""
    th = math.acos(float(np.clip((np.trace(r) - 1.0) / 2.0, -1.0, 1.0)))
    w = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]]) / 2.0
    return w if th < 1e-9 else w * th / math.sin(th)


def _quat(r: np.ndarray) -> np.ndarray:
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(r, dtype=float).ravel())
    return q


# ==================================================================================================
# the MuJoCo model
# ==================================================================================================
def build_model() -> mujoco.MjModel:
    """The UR5e from its URDF (links given a nominal mass: the URDF has none) with the F/T sensor
    body ``ft_sensor`` welded to the flange at ``s`` and the tool body ``tool`` (frame = ``s``);
    sites ``ft`` (= ``s``) and ``tip``; sensors ``ft_force`` / ``ft_torque`` on ``ft``."""
    spec = mujoco.MjSpec.from_file(str(UR5E_URDF))
    for body in spec.bodies[1:]:
        body.mass, body.ipos, body.inertia, body.explicitinertial = LINK_MASS_KG, [0, 0, 0], [0.01] * 3, True
    flange = spec.body(FLANGE_BODY)
    sensor = flange.add_body(name="ft_sensor", pos=list(SENSOR_POS_F_M), quat=_quat(rpy_matrix_deg(SENSOR_RPY_F_DEG)))
    sensor.mass, sensor.ipos, sensor.inertia = SENSOR_HOUSING_KG, [0.0, 0.0, -0.01], [1.5e-4, 1.5e-4, 2.5e-4]
    sensor.explicitinertial = True
    tool = sensor.add_body(name="tool")
    tool.mass, tool.ipos, tool.fullinertia = TOOL_MASS_KG, list(TOOL_COM_S_M), list(TOOL_INERTIA_COM_KG_M2)
    tool.explicitinertial = True
    tool.add_site(name="ft", size=[0.005, 0.005, 0.005])
    tool.add_site(name="tip", pos=list(TIP_S_M), size=[0.004, 0.004, 0.004])
    for name, typ in (("ft_force", mujoco.mjtSensor.mjSENS_FORCE), ("ft_torque", mujoco.mjtSensor.mjSENS_TORQUE)):
        spec.add_sensor(name=name, type=typ, objtype=mujoco.mjtObj.mjOBJ_SITE, objname="ft")
    return spec.compile()


class _Ids:
    def __init__(self, m: mujoco.MjModel):
        self.ft, self.tip, self.tool = m.site("ft").id, m.site("tip").id, m.body("tool").id
        self.flange = m.body(FLANGE_BODY).id
        self.adr_f = int(m.sensor_adr[m.sensor("ft_force").id])
        self.adr_t = int(m.sensor_adr[m.sensor("ft_torque").id])


def _fk(m: mujoco.MjModel, d: mujoco.MjData, q: np.ndarray) -> None:
    d.qpos[:] = q
    mujoco.mj_kinematics(m, d)
    mujoco.mj_comPos(m, d)


def inverse_dynamics_wrench(m: mujoco.MjModel, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray,
                            f_w: np.ndarray, m_w: np.ndarray) -> np.ndarray:
    """``w_tool_on_sensor_s`` (N, 6) [N, N m] for the motion q, qd, qdd (N, 6) and the contact's
    force ``f_w`` (N, 3) [N] and moment ``m_w`` (N, 3) [N m] about the tip, world axes, acting on
    the tool (applied at the tool's COM: force and moment + (tip - COM) x force)."""
    d = mujoco.MjData(m)
    ids = _Ids(m)
    out = np.empty((len(q), 6))
    for i in range(len(q)):
        d.qpos[:], d.qvel[:], d.qacc[:] = q[i], qd[i], qdd[i]
        mujoco.mj_kinematics(m, d)
        d.xfrc_applied[ids.tool, :3] = f_w[i]
        d.xfrc_applied[ids.tool, 3:] = m_w[i] + np.cross(d.site_xpos[ids.tip] - d.xipos[ids.tool], f_w[i])
        mujoco.mj_inverse(m, d)
        mujoco.mj_rnePostConstraint(m, d)  # cfrc_int from the qacc given
        mujoco.mj_sensorAcc(m, d)
        out[i] = -np.r_[d.sensordata[ids.adr_f:ids.adr_f + 3], d.sensordata[ids.adr_t:ids.adr_t + 3]]
    return out


def _ik(m: mujoco.MjModel, d: mujoco.MjData, q0: np.ndarray, site: int, p_target: np.ndarray,
        r_target: np.ndarray, tol: float = 1e-11, iters: int = 100) -> np.ndarray:
    """Damped least squares on the 6D pose of ``site`` (position [m], orientation [rad]), from q0."""
    q = np.array(q0, dtype=float)
    jp, jr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
    for _ in range(iters):
        _fk(m, d, q)
        e = np.r_[p_target - d.site_xpos[site], matrix_rotvec(r_target @ d.site_xmat[site].reshape(3, 3).T)]
        if np.linalg.norm(e) < tol:
            return q
        mujoco.mj_jacSite(m, d, jp, jr, site)
        j = np.vstack([jp, jr])
        q = q + j.T @ np.linalg.solve(j @ j.T + 1e-10 * np.eye(6), e)
    raise RuntimeError("IK did not converge")


# ==================================================================================================
# the experiment
# ==================================================================================================
def _minjerk(tau):
    """s(tau) = 10 tau^3 - 15 tau^4 + 6 tau^5, tau clipped to [0, 1]."""
    t = np.clip(tau, 0.0, 1.0)
    return 10 * t**3 - 15 * t**4 + 6 * t**5


def _ramp_distance(t: np.ndarray, t0: float, dur: float) -> np.ndarray:
    """Integral of s((u - t0) / dur) du up to t [s]: the distance at unit speed after a min-jerk speed-up."""
    tau = (t - t0) / dur
    c = np.clip(tau, 0.0, 1.0)
    return dur * np.where(tau <= 1.0, 2.5 * c**4 - 3 * c**5 + c**6, 0.5 + tau - 1.0)


def _envelope(t: np.ndarray, t0: float, t1: float, edge_s: float = PIVOT_EDGE_S) -> np.ndarray:
    """0 -> 1 -> 0 over [t0, t1], min-jerk edges of ``edge_s``."""
    return _minjerk((t - t0) / edge_s) * _minjerk((t1 - t) / edge_s)


def _slide_path(t: np.ndarray, slides) -> tuple[np.ndarray, np.ndarray]:
    """In-plane tip displacement (N, 3) [m, world] and twist about the normal (N,) [rad] of ``slides``."""
    disp, twist = np.zeros((len(t), 3)), np.zeros(len(t))
    for t0, t1, dist, dir_deg, twist_deg in slides:
        s = _minjerk((t - t0) / (t1 - t0))
        a = math.radians(dir_deg)
        disp += s[:, None] * dist * np.array([math.cos(a), math.sin(a), 0.0])
        twist += s * math.radians(twist_deg)
    return disp, twist


@dataclass(frozen=True)
class Path6:
    """The scripted tip pose: ``tip_w`` (N, 3) [m] and ``rotvec_w`` (N, 3) [rad] of the tool's
    rotation from its contact orientation ``R_c`` (world axes: R_ws = Rotvec(rotvec_w) R_c)."""

    tip_w: np.ndarray
    rotvec_w: np.ndarray


def _rich_path(t: np.ndarray, tip_start_w: np.ndarray) -> Path6:
    """The rich free motion at ``t`` (N,) [s] in [0, T_RICH_S]: holds and min-jerk moves through
    ``RICH_TARGETS`` from the start pose (tip ``tip_start_w`` (3,) [m]) back to it; the rotation
    between targets along the geodesic. Rotations are kept as ``R_ws R_c^T``; the tool axis s_z is
    -z (world) in the contact orientation ``R_c``, so a turn about it is one about -z before the start turn."""
    r_start = rotvec_matrix(math.radians(APPROACH_TURN_DEG) * np.asarray(APPROACH_AXIS_W))  # R_ws R_c^T
    poses = [(np.zeros(3), r_start)]  # (tip displacement [m], R_ws R_c^T)
    for tilt_deg, turn_deg, dp, _, _ in RICH_TARGETS:
        turn = rotvec_matrix(np.deg2rad([0.0, 0.0, -turn_deg]))  # R_c Rz(turn) R_c^T
        poses.append((np.asarray(dp, dtype=float), rotvec_matrix(np.deg2rad(tilt_deg)) @ r_start @ turn))
    disp, rot = np.zeros((len(t), 3)), np.empty((len(t), 3))
    rot[:] = matrix_rotvec(r_start)
    t0 = RICH_START_HOLD_S
    for (dp_a, r_a), (dp_b, r_b), (*_, t_move, t_hold) in zip(poses[:-1], poses[1:], RICH_TARGETS):
        s = _minjerk((t - t0) / t_move)
        on = t >= t0
        step = matrix_rotvec(r_a.T @ r_b)
        disp[on] = dp_a + s[on, None] * (dp_b - dp_a)
        rot[on] = [matrix_rotvec(r_a @ rotvec_matrix(si * step)) for si in s[on]]
        t0 += t_move + t_hold
    return Path6(tip_start_w + disp, rot)


def tip_path(case: Case, t: np.ndarray, p0_w: np.ndarray) -> Path6:
    """The tip's pose at ``t`` (N,) [s] for ``case``; ``p0_w`` the touch-down point. A rich free
    motion comes first and delays the rest by ``T_RICH_S``."""
    path = _experiment_path(case.contact, t - experiment_delay_s(case), p0_w)
    if case.free_motion == "rich":
        early = t < T_RICH_S
        rich = _rich_path(t[early], path.tip_w[0])
        path.tip_w[early], path.rotvec_w[early] = rich.tip_w, rich.rotvec_w
    return path


def experiment_delay_s(case: Case) -> float:
    """[s] the time the approach-and-contact experiment starts after the first sample."""
    return T_RICH_S if case.free_motion == "rich" else 0.0


def _experiment_path(kind: str, t: np.ndarray, p0_w: np.ndarray) -> Path6:
    """The approach-and-contact experiment's tip pose at ``t`` (N,) [s from its start] for ``kind``
    ("point" or "flat"); ``p0_w`` the touch-down point; before 0 the start pose."""
    axis = np.asarray(APPROACH_AXIS_W)
    s = _minjerk((t - T_APPROACH_S[0]) / (T_APPROACH_S[1] - T_APPROACH_S[0]))
    descent = GUARD_SPEED_M_S * (_ramp_distance(t, T_GUARD_S, GUARD_RAMP_S) - _ramp_distance(t, T_TOUCH_S, STOP_S))
    guard_h = GUARD_SPEED_M_S * (T_TOUCH_S - T_GUARD_S - GUARD_RAMP_S / 2)  # the guarded descent's length
    tip = (p0_w + np.array([0.0, 0.0, guard_h]) + (1.0 - s)[:, None] * np.asarray(START_OFFSET_W_M)
           - descent[:, None] * np.array([0.0, 0.0, 1.0]))
    rot = (1.0 - s)[:, None] * math.radians(APPROACH_TURN_DEG) * axis[None, :]
    slides = POINT_SLIDES if kind == "point" else FLAT_SLIDES
    disp, twist = _slide_path(t, slides)
    tip = tip + disp
    rot = rot + twist[:, None] * np.array([0.0, 0.0, 1.0])
    if kind == "point":  # the tool pivots about the stuck tip: a tilt that goes round, and a twist
        u = (t - T_PIVOT_S[0]) / (T_PIVOT_S[1] - T_PIVOT_S[0])
        env = _envelope(t, *T_PIVOT_S)
        tilt = math.radians(PIVOT_TILT_DEG) * env
        rot = rot + np.c_[tilt * np.cos(2 * np.pi * u), tilt * np.sin(2 * np.pi * u),
                          math.radians(PIVOT_TWIST_DEG) * env * np.sin(2 * np.pi * u)]
    return Path6(tip, rot)


@dataclass(frozen=True)
class Trajectory:
    """The experiment at the log's samples (all arrays read-only).

    t (N,) [s]; q, qd, qdd (N, 6) [rad, rad/s, rad/s^2] the true joint motion; f_w (N, 3) [N] and
    m_w (N, 3) [N m] the table's force on the tool and its moment about the tip (world axes);
    tip_w (N, 3) [m] the tip; r_ws (N, 3, 3) the sensor axes in the world; normal_n (N,) [N].
    """

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    f_w: np.ndarray
    m_w: np.ndarray
    tip_w: np.ndarray
    r_ws: np.ndarray
    normal_n: np.ndarray


def contact_orientation(m: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray]:
    """(R_c (3, 3), p0_w (3,)): the sensor axes in contact (s_z straight down, turned the least from
    the sensor at ``Q_REF``) and the tip there (the touch-down point is this tip moved to the table)."""
    d = mujoco.MjData(m)
    ids = _Ids(m)
    _fk(m, d, np.asarray(Q_REF))
    r_ref = d.site_xmat[ids.ft].reshape(3, 3).copy()
    z = r_ref[:, 2]
    axis = np.cross(z, [0.0, 0.0, -1.0])
    r_c = rotvec_matrix(axis / np.linalg.norm(axis) * math.acos(float(np.clip(-z[2], -1, 1)))) @ r_ref
    return r_c, d.site_xpos[ids.tip].copy()


def _joint_motion(m: mujoco.MjModel, t: np.ndarray, path: Path6, r_c: np.ndarray):
    """IK at every sample, warm-started, then a quintic interpolating spline at rest at both ends:
    (q, qd, qdd), each (N, 6)."""
    d = mujoco.MjData(m)
    ids = _Ids(m)
    q = np.empty((len(t), m.nq))
    q_prev = np.asarray(Q_REF, dtype=float)
    for i in range(len(t)):
        q_prev = q[i] = _ik(m, d, q_prev, ids.tip, path.tip_w[i], rotvec_matrix(path.rotvec_w[i]) @ r_c)
    zero = np.zeros(m.nq)
    spline = make_interp_spline(t, q, k=5, bc_type=([(1, zero), (2, zero)], [(1, zero), (2, zero)]))
    return spline(t), spline(t, 1), spline(t, 2)


def _normal_force(t: np.ndarray) -> np.ndarray:
    """The table's normal force on the tool [N] (N,): impact, press, a slow wave."""
    impact = IMPACT_N * _minjerk((t - T_TOUCH_S) / IMPACT_S)
    press = (PRESS_N - IMPACT_N) * _minjerk((t - T_TOUCH_S - IMPACT_S) / (T_PRESS_S - T_TOUCH_S - IMPACT_S))
    wave = FORCE_WAVE_N * np.sin(2 * np.pi * np.clip(t - T_PRESS_S, 0.0, None) / FORCE_WAVE_S)
    return impact + press + wave


def _kinematics(m: mujoco.MjModel, q: np.ndarray, qd: np.ndarray):
    """(tip_w (N, 3) [m], tip velocity (N, 3) [m/s], r_ws (N, 3, 3), twist rate about world z (N,) [rad/s])."""
    d = mujoco.MjData(m)
    ids = _Ids(m)
    tip, vel, r_ws, wz = np.empty((len(q), 3)), np.empty((len(q), 3)), np.empty((len(q), 3, 3)), np.empty(len(q))
    jp, jr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
    for i in range(len(q)):
        _fk(m, d, q[i])
        tip[i], r_ws[i] = d.site_xpos[ids.tip], d.site_xmat[ids.ft].reshape(3, 3)
        mujoco.mj_jacSite(m, d, jp, jr, ids.tip)
        vel[i], wz[i] = jp @ qd[i], (jr @ qd[i])[2]
    return tip, vel, r_ws, wz


def _contact_wrench(kind: str, t: np.ndarray, fn: np.ndarray, vel: np.ndarray, wz: np.ndarray):
    """The table's force on the tool (N, 3) [N] and moment about the tip (N, 3) [N m], world axes."""
    n = np.array([0.0, 0.0, 1.0])
    vt = vel - np.outer(vel @ n, n)
    if kind == "point":  # Coulomb friction when sliding, a sideways push within the cone when stuck
        fric = -MU * fn[:, None] * vt / np.sqrt(np.sum(vt**2, axis=1) + SLIP_SMOOTH_M_S**2)[:, None]
        u = (t - T_PIVOT_S[0]) / (T_PIVOT_S[1] - T_PIVOT_S[0])
        phi = 2 * np.pi * PIVOT_PUSH_TURNS * u
        push = PIVOT_PUSH * _envelope(t, *T_PIVOT_S) * fn
        a = math.radians(PUSH_DIR_DEG)
        end = PUSH_FRACTION * _minjerk((t - T_PUSH_S[0]) / (T_PUSH_S[1] - T_PUSH_S[0])) * fn
        side = np.c_[push * np.cos(phi) + end * math.cos(a), push * np.sin(phi) + end * math.sin(a), 0 * t]
        return fn[:, None] * n + fric + side, np.zeros((len(t), 3))
    # flat face: limit-surface friction shared by sliding and twisting; the pressure centre shifts
    speed = np.sqrt(np.sum(vt**2, axis=1) + (FACE_RADIUS_M * wz) ** 2 + SLIP_SMOOTH_M_S**2)
    fric = -MU * fn[:, None] * vt / speed[:, None]
    torsion = -MU * fn * FACE_RADIUS_M**2 * wz / np.sqrt(speed**2 + (FACE_RADIUS_M * TWIST_SMOOTH_RAD_S) ** 2)
    lead = COP_LEAD_M * vt / np.sqrt(np.sum(vt**2, axis=1) + SLIP_SMOOTH_M_S**2)[:, None]
    wander = COP_WANDER_M * np.c_[np.sin(2 * np.pi * t / 3.1), np.cos(2 * np.pi * t / 2.3), 0 * t]
    cop = (lead + wander) * (fn > 0)[:, None]
    return fn[:, None] * n + fric, np.cross(cop, fn[:, None] * n) + torsion[:, None] * n


def trajectory(case: Case) -> Trajectory:
    """The experiment of ``case`` (10 s, plus ``T_RICH_S`` for a rich free motion first), see the
    module docstring; the same for every case of the same contact and free motion."""
    return _trajectory(Case("", case.contact, case.free_motion, 0.0, False))


@functools.lru_cache(maxsize=3)
def _trajectory(case: Case) -> Trajectory:
    m = build_model()
    delay = experiment_delay_s(case)
    t = np.arange(N_SAMPLES + round(delay * RATE_HZ)) / RATE_HZ
    r_c, p0 = contact_orientation(m)
    q, qd, qdd = _joint_motion(m, t, tip_path(case, t, p0), r_c)
    tip, vel, r_ws, wz = _kinematics(m, q, qd)
    fn = _normal_force(t - delay)
    f_w, m_w = _contact_wrench(case.contact, t - delay, fn, vel, wz)
    arrays = (t, q, qd, qdd, f_w, m_w, tip, r_ws, fn)
    for a in arrays:
        a.setflags(write=False)
    return Trajectory(*arrays)


# ==================================================================================================
# the log
# ==================================================================================================
def crosstalk_matrix(name: str) -> np.ndarray:
    """(6, 6) what the sensor reports of the true wrench (rows/cols Fx Fy Fz Tx Ty Tz): ``I + E`` (the
    crosstalk), then the measuring axes' rotation R (``diag(R^T, R^T)``)."""
    e = np.eye(6)
    case = CASES[name]
    e[0, 2] += case.crosstalk_fx_from_fz
    if case.axes_rotvec_deg is not None:
        r_t = rotvec_matrix(np.deg2rad(case.axes_rotvec_deg)).T
        e = np.block([[r_t, np.zeros((3, 3))], [np.zeros((3, 3)), r_t]]) @ e
    return e


def case_signals(name: str, seed: int = 0, noise: bool = True) -> dict[str, np.ndarray]:
    """The log of case ``name``: ``t`` (N,) [s], ``q`` (N, 6) [rad], ``wrench`` (N, 6) [N, N m]
    (tool on sensor, s axes, tared, with noise), and the truth: ``wrench_true`` (N, 6) before the
    crosstalk, tare and noise, ``tare`` (6,) the reading subtracted, ``f_w`` (N, 3) the contact force."""
    if name not in CASES:
        raise KeyError(f"unknown case '{name}' (choose from {', '.join(CASES)})")
    tr = trajectory(CASES[name])
    m = build_model()
    w_true = inverse_dynamics_wrench(m, tr.q, tr.qd, tr.qdd, tr.f_w, tr.m_w)
    reported = w_true @ crosstalk_matrix(name).T
    tare = reported[0].copy()  # the arm is at rest at the first sample: the sensor is zeroed there
    wrench = reported - tare
    case = CASES[name]
    q = tr.q
    if case.drift_per_s is not None:
        wrench = wrench + (tr.t - tr.t[0])[:, None] * np.asarray(case.drift_per_s)[None, :]
    if case.encoder_offset_deg is not None:
        j, off = case.encoder_offset_deg
        q = q.copy()
        q[:, j - 1] -= math.radians(off)
    if noise:
        rng = np.random.default_rng(seed)
        wrench = wrench + rng.normal(size=wrench.shape) * np.r_[[SIGMA_FORCE_N] * 3, [SIGMA_TORQUE_NM] * 3]
    return {"t": tr.t, "q": q, "wrench": wrench, "wrench_true": w_true, "tare": tare, "f_w": tr.f_w}


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (int, float)):
        return repr(float(v))
    return "[" + ", ".join(_toml_value(x) for x in v) + "]"


def setup_toml(name: str, mount_known: bool = False) -> str:
    """The set-up a user of this rig declares: the URDF, tared, the mount's rotation unknown (zero
    first guess; ``mount_known``: the true rotation, declared known; always for a case whose measuring axes
    are rotated), a guessed tool; ``point`` declares no tip, the flat cases the face centre."""
    case = CASES[name]
    mount_known = mount_known or case.declares_mount or case.axes_rotvec_deg is not None
    tool = {"mass_kg": DECLARED_MASS_KG, "com_sensor_m": DECLARED_COM_S_M}
    if case.declares_true_tool:
        tool = {"mass_kg": TOOL_MASS_KG, "com_sensor_m": TOOL_COM_S_M, "inertia_com_kg_m2": TOOL_INERTIA_COM_KG_M2}
    if CASES[name].declares_tip:
        tool["tip_sensor_m"] = TIP_S_M
    rpy = SENSOR_RPY_F_DEG if mount_known else (0.0, 0.0, 0.0)
    sections = {
        "log": {"time": "t", "q": Q_COLS, "wrench": WRENCH_COLS, "wrench_acts": "tool_on_sensor", "tared": True},
        "sensor": {"position_flange_m": SENSOR_POS_F_M, "rpy_flange_deg": rpy, "mount_known": mount_known},
        "tool": tool,
        "arm": {"urdf": str(UR5E_URDF)},
    }
    lines = [f"# contact_rig case '{name}': the set-up as its user declares it", ""]
    for sec, kv in sections.items():
        lines += [f"[{sec}]", *(f"{k} = {_toml_value(v)}" for k, v in kv.items()), ""]
    return "\n".join(lines)


def truth(name: str, sig: dict[str, np.ndarray], seed: int, mount_known: bool = False) -> dict:
    """What the log hides (SI units, sensor frame unless named)."""
    case = CASES[name]
    mount_known = mount_known or case.declares_mount or case.axes_rotvec_deg is not None
    in_contact = np.linalg.norm(sig["f_w"], axis=1) > 0.0
    onset = float(sig["t"][np.argmax(in_contact)])
    out = {"case": name, "description": case.description, "seed": int(seed),
           "tool_mass_kg": TOOL_MASS_KG, "tool_com_sensor_m": list(TOOL_COM_S_M),
           "tool_inertia_com_kg_m2": list(TOOL_INERTIA_COM_KG_M2),
           "sensor_rpy_flange_deg": list(SENSOR_RPY_F_DEG), "sensor_position_flange_m": list(SENSOR_POS_F_M),
           "contact_point_sensor_m": list(TIP_S_M), "contact_onset_s": T_TOUCH_S + experiment_delay_s(case),
           "first_contact_sample_s": onset, "contact_fraction": float(in_contact.mean()),
           "tare_wrench": [float(v) for v in sig["tare"]],
           "noise": {"force_N": SIGMA_FORCE_N, "torque_Nm": SIGMA_TORQUE_NM},
           "declared": {"tool_mass_kg": DECLARED_MASS_KG, "tool_com_sensor_m": list(DECLARED_COM_S_M),
                        "mount_known": mount_known, "tip_sensor_m": list(TIP_S_M) if case.declares_tip else None}}
    if case.contact == "flat":
        tr = trajectory(case)
        m_s = np.einsum("nji,nj->ni", tr.r_ws, tr.m_w)[in_contact]
        out["face"] = {"side_m": FACE_SIDE_M, "mu": MU,
                       "moment_about_tip_rms_Nm": float(np.sqrt(np.mean(np.sum(m_s**2, axis=1)))),
                       "moment_about_tip_max_Nm": float(np.linalg.norm(m_s, axis=1).max())}
    if case.crosstalk_fx_from_fz:
        k = case.crosstalk_fx_from_fz
        out["crosstalk"] = {"fx_from_fz": k, "reads": f"Fx + {k} Fz (tool-on-sensor, before the tare)",
                            "effect_file": "examples/effects/crosstalk_fx_fz.py"}
    eff = {}  # the hidden library effects in the report's terms (deg; the log's wrench convention)
    if case.axes_rotvec_deg is not None:
        eff["ft_frame_rotation"] = dict(zip(("rot_x", "rot_y", "rot_z"), case.axes_rotvec_deg))
    if case.drift_per_s is not None:
        eff["ft_bias_drift"] = dict(zip(("rate_fx", "rate_fy", "rate_fz", "rate_tx", "rate_ty", "rate_tz"),
                                        case.drift_per_s))
    if case.encoder_offset_deg is not None:
        eff["encoder_offset"] = {f"offset_joint{case.encoder_offset_deg[0]}": case.encoder_offset_deg[1]}
    if eff:
        out["effects"] = eff
    if case.declares_true_tool:
        out["declared"].update(tool_mass_kg=TOOL_MASS_KG, tool_com_sensor_m=list(TOOL_COM_S_M),
                               tool_inertia_com_kg_m2=list(TOOL_INERTIA_COM_KG_M2))
    return out


def make_case(name: str, out_dir: Path, seed: int = 0, mount_known: bool = False) -> Path:
    """Write case ``name`` into ``out_dir/name/`` (log.csv, setup.toml, truth.json); return the folder.
    ``mount_known``: the set-up declares the true mount, known."""
    sig = case_signals(name, seed)
    case_dir = Path(out_dir) / name
    case_dir.mkdir(parents=True, exist_ok=True)
    data = np.c_[sig["t"], sig["q"], sig["wrench"]]
    np.savetxt(case_dir / "log.csv", data, delimiter=",", fmt=["%.3f"] + ["%.6f"] * 12,
               header=",".join(("t", *Q_COLS, *WRENCH_COLS)), comments="")
    (case_dir / "setup.toml").write_text(setup_toml(name, mount_known))
    (case_dir / "truth.json").write_text(json.dumps(truth(name, sig, seed, mount_known), indent=2) + "\n")
    return case_dir


# ==================================================================================================
# self-test
# ==================================================================================================
def _urdf_flange(q: np.ndarray) -> np.ndarray:
    """(3, 3) flange axes in the world at ``q`` (6,), from the URDF text by plain NumPy (joint origin
    rotation Rz Ry Rx of its rpy, then Rodrigues about its axis)."""
    joints = {j.find("parent").get("link"): j for j in ET.parse(UR5E_URDF).getroot().iter("joint")}
    r, link, k = np.eye(3), "base_link", 0
    while link in joints:
        j = joints[link]
        r = r @ rpy_matrix_deg(np.rad2deg([float(v) for v in j.find("origin").get("rpy").split()]))
        axis = np.array([float(v) for v in j.find("axis").get("xyz").split()])
        r, k, link = r @ rotvec_matrix(axis * q[k]), k + 1, j.find("child").get("link")
    return r


def self_test(seed: int = 0) -> dict[str, float]:
    """Check the rig: the weight's sign and size (tool-on-sensor force = m g at rest, world axes), the
    flange = the URDF's last link, the tare (the log reads 0 at the first pose), the free space's
    single 18 deg turn, and the contact fraction (~70 %). Returns the figures; raises AssertionError."""
    m = build_model()
    d = mujoco.MjData(m)
    ids = _Ids(m)
    tr = trajectory(CASES["point"])
    out = {}
    for i in (0, 600, 1500):  # poses of the log, at rest
        w = inverse_dynamics_wrench(m, tr.q[i:i + 1], tr.qd[i:i + 1] * 0, tr.qdd[i:i + 1] * 0, np.zeros((1, 3)),
                                    np.zeros((1, 3)))[0]
        _fk(m, d, tr.q[i])
        f_world = d.site_xmat[ids.ft].reshape(3, 3) @ w[:3]
        out["weight_err_N"] = max(out.get("weight_err_N", 0.0),
                                  float(np.abs(f_world - [0.0, 0.0, -TOOL_MASS_KG * 9.81]).max()))
        out["urdf_flange_err"] = max(out.get("urdf_flange_err", 0.0),
                                     float(np.abs(d.xmat[ids.flange].reshape(3, 3) - _urdf_flange(tr.q[i])).max()))
    sig = case_signals("point", seed, noise=False)
    out["tare_first_sample"] = float(np.abs(sig["wrench"][0]).max())
    free = tr.t < T_TOUCH_S
    turn = np.array([matrix_rotvec(r @ tr.r_ws[0].T) for r in tr.r_ws[free]])
    axis = turn[-1] / np.linalg.norm(turn[-1])
    out["free_turn_deg"] = float(np.rad2deg(np.linalg.norm(turn[-1])))
    out["free_turn_off_axis_deg"] = float(np.rad2deg(np.abs(turn - np.outer(turn @ axis, axis)).max()))
    out["contact_fraction"] = float((tr.normal_n > 0).mean())
    ok = (out["weight_err_N"] < 1e-9 and out["urdf_flange_err"] < 1e-9 and out["tare_first_sample"] < 1e-12
          and abs(out["free_turn_deg"] - APPROACH_TURN_DEG) < 1e-3 and out["free_turn_off_axis_deg"] < 1e-3
          and 0.68 < out["contact_fraction"] < 0.72)
    if not ok:
        raise AssertionError(f"contact rig self-test failed: {out}")
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description="Write contact-task test logs for `kinadapt diagnose`.")
    p.add_argument("--out", type=Path, required=True, help="output folder (one subfolder per case)")
    p.add_argument("--case", nargs="+", default=list(CASES), choices=list(CASES), help="cases (default: all)")
    p.add_argument("--seed", type=int, default=0, help="noise seed")
    p.add_argument("--mount-known", action="store_true",
                   help="the set-up declares the true mount rotation, known (default: unknown, zero first guess)")
    p.add_argument("--self-test", action="store_true", help="check the rig's physics and timing first")
    a = p.parse_args(argv)
    if a.self_test:
        print("self-test:", {k: f"{v:.3g}" for k, v in self_test(a.seed).items()})
    for name in a.case:
        t0 = time.perf_counter()
        d = make_case(name, a.out, a.seed, a.mount_known)
        print(f"{d}: {', '.join(sorted(x.name for x in d.iterdir()))} ({time.perf_counter() - t0:.2f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
