"""A foreign rig: test logs for ``kinadapt diagnose`` from a set-up this package never saw.

Standalone on purpose: this file imports nothing from ``kinadapt_nn`` (only MuJoCo, NumPy, SciPy,
PyArrow and the standard library) so that its logs are independent of the package's own simulator
and of the diagnosis code. The only shared input is the arm model ``models/panda.xml``. ::

    python examples/foreign_rig.py --out DIR [--rig A|B] [--case NAME ...] [--seed N] [--self-test]

Two rigs, different in every respect we could think of (mount, tool, trajectory, contact, log
format, rate, noise, conventions), so that the diagnosis is not tuned to one file. Rig A (the
default) writes, per case, ``DIR/<case>/``: ``log.csv.gz``, ``log.parquet`` (the same samples, other
column names and conventions), ``setup_csv.toml``, ``setup_parquet.toml`` (the NOMINAL rig, as a
user would declare it) and ``truth.json`` (the hidden effects, in the diagnosis's reporting units).
Rig B (``--rig B``, described at the end of this docstring) writes ``log.csv`` (plain text),
``setup.toml`` and ``truth.json``.

Rig A
-----
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

Rig B
-----
A sensor mounted flipped behind a light offset probe. Sensor frame ``s``: origin (0, 0, 0.035) m in
``f``, (roll, pitch, yaw) = (180, 0, 90) deg, so its z axis points back into the flange and the tool
lies at negative sensor z. Sensor housing 0.2 kg on the arm side (positive s z). Tool: 0.48 kg, COM
(0.012, 0, -0.07) m in ``s``, inertia about the COM (0.0011, 0.0012, 0.0003, 0.0001, 0, 0) kg m^2,
tip (0, 0.02, -0.21) m (off the sensor axis). Same MuJoCo construction and reading as rig A.

The experiment (``trajectory(rig="B")``, 12 s at 1 kHz, 12001 samples, limits as for rig A)
  1. 0-7.4 s: hold at ``B_Q_HOME`` 0.25 s, then 8 fast minimum-jerk moves (0.6-0.9 s, IK to
     ``_B_PHASE1_TARGETS``: the tool tilted 18-40 deg about varied world axes, turned about its
     own axis by up to 45 deg between targets, one move a pure turn; the last to a 12 deg tilted
     base pose) with holds of 0-0.2 s;
  2. 7.4-9.0 s: joint-space wiggle of joints 2 (up only), 4 and 6 (parallel axes at this pose);
  3. 9.0-12 s: press-and-slide on a table TILTED 10 deg about world x (normal
     (0, -sin 10, cos 10)): the tip approaches 6 cm along the normal, the normal force ramps to
     25 N, the tip runs a 2 cm radius circle in the table plane (1.2 s), the force ramps to 0, the
     tip lifts 6 cm along the normal and holds. Coulomb friction mu = 0.4 against the tip's in-plane
     velocity (smoothed below 2 mm/s); tool orientation fixed; IK at 20 ms knots, quintic spline.
     The tip stays above the table plane outside contact.

Log ``log.csv`` (plain): ``t`` [s], first sample at 3.7 s, ``q1..q7`` [rad], NO velocities,
``fx fy fz tx ty tz`` the wrench the TOOL exerts on the SENSOR. Every rig-B case is tared: the
sensor was zeroed at power-up at ``B_TARE_Q`` (at rest, a pose not in the log), and its zero is off
by a constant: logged = reading - reading(B_TARE_Q) + ``B_TARE_OFFSET`` (0.8, -0.5, 1.2) N,
(0.03, 0.02, -0.01) N m; the tare reading includes a case's payload and sensor-axes rotation but
no drift or noise. Pipeline: payload (physics) -> sensor-axes rotation -> tare -> drift (from the
first sample) -> noise (wrench N(0, 0.08 N / 0.004 N m), q N(0, 2e-5 rad)) -> quantisation of the
wrench to 1/64 N and 1/1000 N m.
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

# --- rig B (a second, different set-up; see the module docstring) -------------------------------
B_SENSOR_POS_F_M = (0.0, 0.0, 0.035)
B_SENSOR_RPY_F_DEG = (180.0, 0.0, 90.0)  # flipped: s z points back into the flange
B_SENSOR_HOUSING_KG = 0.2
B_TOOL_MASS_KG = 0.48
B_TOOL_COM_S_M = (0.012, 0.0, -0.07)  # negative z: the tool is at -z of the flipped sensor
B_TOOL_INERTIA_COM_KG_M2 = (0.0011, 0.0012, 0.0003, 0.0001, 0.0, 0.0)
B_TOOL_TIP_S_M = (0.0, 0.02, -0.21)  # an offset probe
B_RATE_HZ = 1000.0
B_DURATION_S = 12.0
B_N_SAMPLES = 12001
B_T0_S = 3.7  # [s] the log's time of its first sample
B_Q_HOME = (0.3, -0.2, -0.3, -2.2, 0.2, 2.0, -0.5)  # [rad] tool roughly down (14 deg off vertical)
B_TARE_Q = (-0.6, 0.35, 0.7, -1.75, -0.9, 1.35, 1.6)  # [rad] power-up pose of the tare, not in the log
B_TARE_OFFSET = (0.8, -0.5, 1.2, 0.03, 0.02, -0.01)  # [N, N m] the tared zero's constant error
B_MU = 0.4
B_NORMAL_FORCE_N = 25.0
B_TABLE_TILT_DEG = 10.0  # about world x: normal (0, -sin, cos)
B_CIRCLE_RADIUS_M = 0.02
B_FORCE_LSB_N = 1.0 / 64.0
B_TORQUE_LSB_NM = 1.0 / 1000.0
B_SIGMA_FORCE_N = 0.08
B_SIGMA_TORQUE_NM = 0.004
B_SIGMA_Q_RAD = 2e-5

# Phase 1 of rig B: (tilt rotation vector about world axes [deg], turn about the sensor's z [deg],
# sensor-origin displacement [m] in w, move duration [s], hold after it [s]); the first starts at
# _B_T_START_HOLD, the last ends at the phase-2/3 base pose (which is not the home pose)
_B_PHASE1_TARGETS = (
    ((18.0, 0.0, 0.0), 0.0, (0.0, 0.02, 0.0), 0.6, 0.15),
    ((20.0, 22.0, 0.0), 20.0, (0.03, 0.0, 0.02), 0.7, 0.1),
    ((0.0, 35.0, 0.0), 20.0, (0.02, -0.02, 0.0), 0.75, 0.2),
    ((0.0, 35.0, 0.0), -25.0, (0.02, -0.02, 0.0), 0.7, 0.1),  # a pure turn about the tool axis
    ((-25.0, 15.0, 10.0), -25.0, (-0.02, 0.02, 0.03), 0.9, 0.15),
    ((-30.0, -20.0, 0.0), 10.0, (-0.03, 0.0, -0.02), 0.9, 0.1),
    ((0.0, -40.0, 0.0), 30.0, (0.0, -0.02, 0.0), 0.8, 0.2),
    ((0.0, -12.0, 0.0), 0.0, (0.0, 0.0, 0.0), 0.8, 0.0),
)
_B_T_START_HOLD = 0.25
_B_WIGGLE_S = 1.6
# joints 2, 4, 6: (index, amplitude [rad], cycles); joint 2 half a cycle, up only (the table is below)
_B_WIGGLE = ((1, -0.15, 0.5), (3, 0.2, 1.5), (5, 0.25, 2.0))
# phase 3 of rig B: durations [s] of approach, press, circle, release, lift, hold
_B_PHASE3_S = (0.45, 0.3, 1.2, 0.3, 0.45, 0.3)
_B_APPROACH_M = 0.06  # [m] along the table normal


@dataclass(frozen=True)
class Rig:
    """The physical set-up of a rig (true = declared, except for a case's hidden effects)."""

    name: str
    sensor_pos_f_m: tuple[float, float, float]
    sensor_rpy_f_deg: tuple[float, float, float]
    housing_kg: float
    housing_com_s_m: tuple[float, float, float]  # arm side of the measuring plane
    tool_mass_kg: float
    tool_com_s_m: tuple[float, float, float]
    tool_inertia_com_kg_m2: tuple[float, ...]
    tool_tip_s_m: tuple[float, float, float]
    q_home: tuple[float, ...]


RIGS: dict[str, Rig] = {
    "A": Rig("A", SENSOR_POS_F_M, SENSOR_RPY_F_DEG, SENSOR_HOUSING_KG, (0.0, 0.0, -0.006), TOOL_MASS_KG,
             TOOL_COM_S_M, TOOL_INERTIA_COM_KG_M2, TOOL_TIP_S_M, Q_HOME),
    "B": Rig("B", B_SENSOR_POS_F_M, B_SENSOR_RPY_F_DEG, B_SENSOR_HOUSING_KG, (0.0, 0.0, 0.01), B_TOOL_MASS_KG,
             B_TOOL_COM_S_M, B_TOOL_INERTIA_COM_KG_M2, B_TOOL_TIP_S_M, B_Q_HOME),
}


def _rig(rig: str | Rig) -> Rig:
    if isinstance(rig, Rig):
        return rig
    if rig not in RIGS:
        raise KeyError(f"unknown rig '{rig}' (choose from {', '.join(RIGS)})")
    return RIGS[rig]


# ==================================================================================================
# cases
# ==================================================================================================
@dataclass(frozen=True)
class _Hidden:
    """What differs between the truth and the log (all in the csv's conventions)."""

    payload: tuple[float, tuple[float, float, float]] | None = None  # (kg, COM in s [m]) added to the tool
    rotvec_deg: tuple[float, float, float] | None = None  # sensor axes rotated by this (axis in s) [deg]
    drift_csv: tuple[float, ...] | None = None  # [N/s, N m/s] added to the csv's wrench (its own convention:
    # rig A sensor_on_tool, from t = 0; rig B tool_on_sensor, from the first sample)
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

_ROT_B = _rotvec_deg(1.5, (0.3, -1.0, 0.2))
_DRIFT_B = (-0.08, 0.05, 0.12, 0.004, -0.003, 0.002)  # tool_on_sensor (log.csv's convention)
_HIDDEN_B: dict[str, _Hidden] = {
    "none": _Hidden(tared=True),
    "tool_gravity": _Hidden(payload=(0.12, (-0.02, 0.01, -0.04)), tared=True),
    "ft_frame_rotation": _Hidden(rotvec_deg=_ROT_B, tared=True),
    "ft_bias_drift": _Hidden(drift_csv=_DRIFT_B, tared=True),
    "encoder_offset": _Hidden(encoder_offset_deg={6: 0.8}, tared=True),
    "encoder_offset_joint1": _Hidden(encoder_offset_deg={1: 1.5}, tared=True, detectable=False),
    "pair": _Hidden(drift_csv=_DRIFT_B, encoder_offset_deg={2: 0.7}, tared=True),
    "rotation_z_only": _Hidden(rotvec_deg=(0.0, 0.0, 2.0), tared=True),
}

CASES_B: dict[str, str] = {
    "none": "no hidden effect: the log matches the declared rig (tared at an unknown pose, as every rig-B log)",
    "tool_gravity": "an undeclared 0.12 kg payload at (-0.02, 0.01, -0.04) m in the sensor frame",
    "ft_frame_rotation": "the sensor axes are rotated 1.5 deg about (0.3, -1, 0.2) (sensor frame) from the declared "
                         "mount",
    "ft_bias_drift": "the wrench reading drifts linearly from the first sample (log convention tool_on_sensor: "
                     "+(-0.08, 0.05, 0.12) N/s, +(0.004, -0.003, 0.002) N m/s)",
    "encoder_offset": "joint 6 reads 0.8 deg less than its true angle",
    "encoder_offset_joint1": "joint 1 reads 1.5 deg less than its true angle (invisible: gravity is "
                             "invariant under a joint-1 rotation)",
    "pair": "the ft_bias_drift case's drift AND joint 2 reading 0.7 deg less than its true angle",
    "rotation_z_only": "the sensor axes are rotated 2 deg about the sensor's own z axis (the tool axis)",
}

_CASE_TABLES = {"A": (_HIDDEN, CASES), "B": (_HIDDEN_B, CASES_B)}


def cases(rig: str = "A") -> dict[str, str]:
    """Case name -> description for ``rig``."""
    return _CASE_TABLES[_rig(rig).name][1]


def _hidden(name: str, rig: str) -> _Hidden:
    table, desc = _CASE_TABLES[_rig(rig).name]
    if name not in table:
        raise KeyError(f"unknown case '{name}' for rig {_rig(rig).name} (choose from {', '.join(desc)})")
    return table[name]


#: [kg m^2] the inertia change a diagnosis counts as relevant (kinadapt's ``tool_inertia``: 0.2 kg at
#: 50 mm); a payload whose inertia about the sensor reaches it has ``tool_inertia`` in its truth
PAYLOAD_INERTIA_RELEVANT_KG_M2 = 5e-4


def _effects_truth(h: _Hidden, sign: float = 1.0) -> dict[str, dict[str, float]]:
    """Truth in the diagnosis's reporting units; ``sign`` = -1 gives the drift in the parquet convention."""
    eff: dict[str, dict[str, float]] = {}
    if h.payload is not None:
        mass, com = h.payload
        eff["tool_gravity"] = {"mass": mass, "com_x": com[0], "com_y": com[1], "com_z": com[2]}
        c = np.asarray(com, dtype=float)  # the payload (a point mass) also adds m (|c|^2 1 - c c^T) about the sensor
        dI = mass * (c @ c * np.eye(3) - np.outer(c, c))
        if np.abs(dI).max() >= PAYLOAD_INERTIA_RELEVANT_KG_M2:  # real physics a diagnosis should report
            eff["tool_inertia"] = dict(zip(("dI_xx", "dI_yy", "dI_zz", "dI_xy", "dI_xz", "dI_yz"),
                                           (dI[0, 0], dI[1, 1], dI[2, 2], dI[0, 1], dI[0, 2], dI[1, 2])))
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
def build_model(payload: tuple[float, tuple[float, float, float]] | None = None, rig: str | Rig = "A"
                ) -> mujoco.MjModel:
    """The shipped Panda with ``rig``'s F/T sensor and true tool (and an optional extra payload).

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
    rg = _rig(rig)
    r_bs = r_bf @ rpy_matrix_deg(rg.sensor_rpy_f_deg)
    p_bs = np.asarray(flange.pos, dtype=float) + r_bf @ np.asarray(rg.sensor_pos_f_m)
    sensor = parent.add_body(name="ft_sensor", pos=p_bs, quat=_quat_of_matrix(r_bs))
    sensor.mass = rg.housing_kg
    sensor.ipos = list(rg.housing_com_s_m)
    sensor.inertia = [1.5e-4, 1.5e-4, 2.5e-4]
    sensor.explicitinertial = True
    tool = sensor.add_body(name="tool")
    tool.mass = rg.tool_mass_kg
    tool.ipos = list(rg.tool_com_s_m)
    tool.fullinertia = list(rg.tool_inertia_com_kg_m2)
    tool.explicitinertial = True
    tool.add_site(name="ft", size=[0.005, 0.005, 0.005])
    tool.add_site(name="tip", pos=list(rg.tool_tip_s_m), size=[0.004, 0.004, 0.004])
    z0 = math.copysign(0.01, rg.tool_tip_s_m[2])  # the probe starts 1 cm from the sensor, towards the tip
    tool.add_geom(type=mujoco.mjtGeom.mjGEOM_CAPSULE, fromto=[0, 0, z0, *rg.tool_tip_s_m], size=[0.012, 0, 0],
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
    at any times in [0, duration] s (exact derivatives of the analytic / spline segments). The table
    is the plane through ``table_point_w`` with the normal ``table_normal_w`` (rig A: horizontal at
    ``table_z_m``; rig B: tilted, ``table_z_m`` is the height of the touch-down point). Times are
    from the first sample (rig B's log adds ``B_T0_S``).
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
    table_point_w: np.ndarray | None = None
    table_normal_w: np.ndarray | None = None

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


def _seg_swing(t0: float, t1: float, base, swing=_SWING):
    """q = base + sum_j A_j sin^2(pi tau) sin(2 pi n_j tau): zero offset, velocity and acceleration
    at both ends (C2 joins with the holds around it)."""
    base = np.asarray(base, dtype=float)
    T = t1 - t0

    def fn(t):
        tau = (t - t0) / T
        e, de, dde = np.sin(np.pi * tau) ** 2, np.pi * np.sin(2 * np.pi * tau), 2 * np.pi**2 * np.cos(2 * np.pi * tau)
        q = np.tile(base, (len(t), 1))
        qd, qdd = np.zeros_like(q), np.zeros_like(q)
        for j, amp, n in swing:
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


def trajectory(rig: str | Rig = "A") -> Trajectory:
    """The scripted experiment of ``rig`` (cached: identical for every case and seed; read-only use)."""
    return _trajectory(_rig(rig).name)


@functools.lru_cache(maxsize=2)
def _trajectory(rig: str) -> Trajectory:
    return _trajectory_a() if rig == "A" else _trajectory_b()


def _phase1(m, d, ids, q_home: np.ndarray, t_start_hold: float, targets) -> tuple[list, float, np.ndarray]:
    """Phase 1 of either rig: a hold at ``q_home``, then for each target (tilt rotvec [deg], turn about
    the tool axis [deg], sensor displacement [m], move [s], hold [s]) a minimum-jerk move to the IK
    pose and a hold (none when 0). -> (segments, end time [s], the last pose (7,))."""
    _fk(m, d, q_home)
    p0, r0 = d.site_xpos[ids.ft].copy(), d.site_xmat[ids.ft].reshape(3, 3).copy()
    segs = [_seg_minjerk(0.0, t_start_hold, q_home, q_home)]
    tc, q_prev = t_start_hold, q_home
    for tilt_deg, turn_deg, dp, t_move, t_hold in targets:
        r_t = rotvec_matrix(np.deg2rad(tilt_deg)) @ r0 @ rotvec_matrix(np.deg2rad([0.0, 0.0, turn_deg]))
        q_next = _ik(m, d, q_prev, ids.ft, p0 + np.asarray(dp), r_t)
        segs.append(_seg_minjerk(tc, tc + t_move, q_prev, q_next))
        if t_hold > 0.0:
            segs.append(_seg_minjerk(tc + t_move, tc + t_move + t_hold, q_next, q_next))
        tc, q_prev = tc + t_move + t_hold, q_next
    return segs, tc, q_prev


def _tip_path_segment(m, d, ids, q_base: np.ndarray, tk: np.ndarray, tip_k: np.ndarray, r_tip: np.ndarray):
    """Phase 3 of either rig: IK of the tip path ``tip_k`` (K, 3) at knot times ``tk`` (K,) with the
    tool orientation ``r_tip`` held, joined by a quintic spline at rest at both ends."""
    qk = np.empty((len(tk), 7))
    q_prev = q_base
    for i in range(len(tk)):
        q_prev = qk[i] = _ik(m, d, q_prev, ids.tip, tip_k[i], r_tip)
    zero = np.zeros(7)
    spline = make_interp_spline(tk, qk, k=5, bc_type=([(1, zero), (2, zero)], [(1, zero), (2, zero)]))
    return _seg_spline(tk[0], tk[-1], spline)


def _tip_contact(m, d, ids, q: np.ndarray, qd: np.ndarray, fn: np.ndarray, n: np.ndarray, mu: float
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The true tip (N, 3) [m, w] and the prescribed contact force on it (N, 3) [N, w]: the normal
    force ``fn`` along the table normal ``n`` plus Coulomb friction against the in-plane tip velocity."""
    tip_w = np.empty((len(q), 3))
    f_tip = np.zeros((len(q), 3))
    jp = np.zeros((3, m.nv))
    for i in range(len(q)):
        _fk(m, d, q[i])
        tip_w[i] = d.site_xpos[ids.tip]
        if fn[i] > 0.0:
            mujoco.mj_jacSite(m, d, jp, None, ids.tip)
            vel = jp @ qd[i]
            vt = vel - (vel @ n) * n
            f_tip[i] = fn[i] * n - mu * fn[i] * vt / math.sqrt(vt @ vt + SLIP_SMOOTH_M_S**2)
    return tip_w, f_tip


def _trajectory_a() -> Trajectory:
    """Build rig A's scripted 15 s experiment."""
    m = build_model()
    d = mujoco.MjData(m)
    ids = _Ids(m)
    # phase 1: holds and min-jerk moves between IK poses
    segs, tc, q_base = _phase1(m, d, ids, np.asarray(Q_HOME), _T_START_HOLD, _PHASE1_TARGETS)

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
    segs.append(_tip_path_segment(m, d, ids, q_base, tk, tip_k, r_tip))

    traj = Trajectory(t=np.arange(N_SAMPLES) / RATE_HZ, q=None, qd=None, qdd=None, f_tip_w=None, tip_w=None,
                      table_z_m=float("nan"), contact_s=(0.0, 0.0), segments=segs)
    traj.q, traj.qd, traj.qdd = traj.eval(traj.t)

    # contact: the table at the tip height reached after lowering; normal force + Coulomb friction
    t_touch = t3 + _PHASE3[0][0]
    fn = _normal_force(traj.t, t3)
    tip_w, f_tip = _tip_contact(m, d, ids, traj.q, traj.qd, fn, np.array([0.0, 0.0, 1.0]), MU)
    i_touch = int(round(t_touch * RATE_HZ))
    traj.tip_w, traj.f_tip_w = tip_w, f_tip
    traj.table_z_m = float(tip_w[i_touch, 2])
    on = np.nonzero(fn > 0.0)[0]
    traj.contact_s = (float(traj.t[on[0]]), float(traj.t[on[-1]]))
    traj.table_point_w, traj.table_normal_w = tip_w[i_touch].copy(), np.array([0.0, 0.0, 1.0])
    return traj


def _b_table_axes() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rig B's table: normal n and in-plane axes u, v (orthonormal, u x v = n), world."""
    a = math.radians(B_TABLE_TILT_DEG)
    n = np.array([0.0, -math.sin(a), math.cos(a)])
    u = np.array([1.0, 0.0, 0.0])
    return n, u, np.cross(n, u)


def _b_phase3(t: np.ndarray, t3: float, tip_base: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rig B phase 3 from ``t3``: tip position (len(t), 3) [m, w] and table normal force (len(t),) [N]."""
    t = np.asarray(t, dtype=float)
    n, u, v = _b_table_axes()
    ta, tp, tc, tr, tl, _ = _B_PHASE3_S
    s_app, _, _ = _minjerk((t - t3) / ta)
    s_lift, _, _ = _minjerk((t - (t3 + ta + tp + tc + tr)) / tl)
    s_circ, _, _ = _minjerk((t - (t3 + ta + tp)) / tc)
    phi = 2.0 * math.pi * s_circ
    tip = (tip_base[None, :] - _B_APPROACH_M * (s_app - s_lift)[:, None] * n[None, :]
           + B_CIRCLE_RADIUS_M * ((np.cos(phi) - 1.0)[:, None] * u[None, :] + np.sin(phi)[:, None] * v[None, :]))
    s_on, _, _ = _minjerk((t - (t3 + ta)) / tp)
    s_off, _, _ = _minjerk((t - (t3 + ta + tp + tc)) / tr)
    fn = B_NORMAL_FORCE_N * (s_on - s_off)
    return tip, np.where((t > t3 + ta) & (t < t3 + ta + tp + tc + tr), np.maximum(fn, 0.0), 0.0)


def _trajectory_b() -> Trajectory:
    """Build rig B's scripted 12 s experiment (see the module docstring)."""
    m = build_model(rig="B")
    d = mujoco.MjData(m)
    ids = _Ids(m)
    # phase 1: fast min-jerk moves between IK poses, short holds
    segs, tc, q_base = _phase1(m, d, ids, np.asarray(B_Q_HOME), _B_T_START_HOLD, _B_PHASE1_TARGETS)

    # phase 2: wiggle of joints 2, 4, 6
    segs.append(_seg_swing(tc, tc + _B_WIGGLE_S, q_base, _B_WIGGLE))
    tc += _B_WIGGLE_S

    # phase 3: approach along the tilted table's normal, press, circle, release, lift
    t3 = tc
    t_end = t3 + sum(_B_PHASE3_S)
    if abs(t_end - B_DURATION_S) > 1e-9:
        raise RuntimeError("rig B phase durations do not add up to B_DURATION_S")
    _fk(m, d, q_base)
    tip0, r_tip = d.site_xpos[ids.tip].copy(), d.site_xmat[ids.tip].reshape(3, 3).copy()
    n_knots = int(round((t_end - t3) / _KNOT_DT)) + 1
    tk = np.linspace(t3, t_end, n_knots)
    tip_k, _ = _b_phase3(tk, t3, tip0)
    segs.append(_tip_path_segment(m, d, ids, q_base, tk, tip_k, r_tip))

    t = np.arange(B_N_SAMPLES) / B_RATE_HZ
    traj = Trajectory(t=t, q=None, qd=None, qdd=None, f_tip_w=None, tip_w=None, table_z_m=float("nan"),
                      contact_s=(0.0, 0.0), segments=segs)
    traj.q, traj.qd, traj.qdd = traj.eval(t)

    # contact: normal force along the table normal + Coulomb friction against the in-plane velocity
    n, _, _ = _b_table_axes()
    _, fn = _b_phase3(t, t3, tip0)
    tip_w, f_tip = _tip_contact(m, d, ids, traj.q, traj.qd, fn, n, B_MU)
    traj.tip_w, traj.f_tip_w = tip_w, f_tip
    touch = tip0 - _B_APPROACH_M * n
    traj.table_point_w, traj.table_normal_w = touch, n
    traj.table_z_m = float(touch[2])
    on = np.nonzero(fn > 0.0)[0]
    traj.contact_s = (float(t[on[0]]), float(t[on[-1]]))
    return traj


@functools.lru_cache(maxsize=8)
def true_wrench(payload: tuple[float, tuple[float, float, float]] | None = None, rig: str | Rig = "A"
                ) -> np.ndarray:
    """``w_tool_on_sensor_s`` (N, 6) [N, N m] of ``rig``'s experiment with the true tool
    (+ ``payload``), noiseless, the sensor axes as mounted (cached; read-only)."""
    return _true_wrench(payload, _rig(rig).name)


@functools.lru_cache(maxsize=8)
def _true_wrench(payload, rig: str) -> np.ndarray:
    tr = trajectory(rig)
    w = inverse_dynamics_wrench(build_model(payload, rig), tr.q, tr.qd, tr.qdd, tr.f_tip_w)
    w.setflags(write=False)
    return w


@functools.lru_cache(maxsize=8)
def tare_wrench_b(payload: tuple[float, tuple[float, float, float]] | None = None) -> np.ndarray:
    """Rig B: the noiseless ``w_tool_on_sensor_s`` (6,) at rest at the power-up pose ``B_TARE_Q``
    (declared axes; the tare subtracts it, rotated like the reading; cached, read-only)."""
    z = np.zeros((1, 7))
    w = inverse_dynamics_wrench(build_model(payload, "B"), np.asarray([B_TARE_Q]), z, z)[0]
    w.setflags(write=False)
    return w


# ==================================================================================================
# a case's signals and files
# ==================================================================================================
def case_signals(name: str, seed: int = 0, noise: bool = True, rig: str | Rig = "A") -> dict[str, np.ndarray]:
    """The logged signals of case ``name`` of rig A (csv conventions); rig B: ``_case_signals_b``.

    Returns ``t`` (N,) [s from the first sample], ``q`` (N, 7) [rad] logged encoder angles, ``qdot``
    (N, 7) [rad/s], ``wrench`` (N, 6) [N, N m] the sensor-on-tool wrench in the (possibly rotated)
    sensor axes about the sensor origin, and ``w_tool_on_sensor_s`` (N, 6) the noiseless true
    tool-on-sensor wrench in the declared axes (no hidden effect of the sensor). Pipeline: payload
    (physics) -> sensor-axes rotation R^T w -> csv sign -> drift -> noise (same draws for every case
    of a seed; ``noise=False`` leaves it out) -> tare (subtract the sample at ``TARE_T_S``).
    """
    if _rig(rig).name == "B":
        return _case_signals_b(name, seed, noise)
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


def _case_signals_b(name: str, seed: int = 0, noise: bool = True) -> dict[str, np.ndarray]:
    """The logged signals of rig-B case ``name`` (log.csv's conventions).

    Returns ``t`` (N,) [s] the log's time (first sample at ``B_T0_S``), ``q`` (N, 7) [rad] logged
    encoder angles, ``wrench`` (N, 6) [N, N m] the logged tool-on-sensor wrench (tared, quantised),
    ``w_tool_on_sensor_s`` (N, 6) the noiseless true tool-on-sensor wrench in the declared axes and
    ``tare`` (6,) the constant the tare added to the reading (= - rotated tare-pose reading +
    ``B_TARE_OFFSET``). Pipeline: payload (physics) -> sensor-axes rotation R^T w -> + tare ->
    drift rate * (t - t_first) -> noise (same draws for every case of a seed; ``noise=False``
    leaves it out) -> quantisation (always).
    """
    h = _hidden(name, "B")
    tr = trajectory("B")
    w_true = np.array(true_wrench(h.payload, "B"))
    w_tare = np.array(tare_wrench_b(h.payload))
    w = w_true.copy()
    if h.rotvec_deg is not None:
        r = rotvec_matrix(np.deg2rad(h.rotvec_deg))
        w = np.hstack([w[:, :3] @ r, w[:, 3:] @ r])  # row-wise R^T w
        w_tare = np.r_[r.T @ w_tare[:3], r.T @ w_tare[3:]]
    tare = np.asarray(B_TARE_OFFSET) - w_tare
    w = w + tare[None, :]
    if h.drift_csv is not None:
        w = w + tr.t[:, None] * np.asarray(h.drift_csv)[None, :]
    q = tr.q.copy()
    for j, off in h.encoder_offset_deg.items():
        q[:, j - 1] -= math.radians(off)
    if noise:
        rng = np.random.default_rng(seed)
        q += rng.normal(0.0, B_SIGMA_Q_RAD, q.shape)
        sig = np.array([B_SIGMA_FORCE_N] * 3 + [B_SIGMA_TORQUE_NM] * 3)
        w = w + rng.normal(0.0, 1.0, w.shape) * sig
    per_unit = np.array([1.0 / B_FORCE_LSB_N] * 3 + [1.0 / B_TORQUE_LSB_NM] * 3)  # 64 per N, 1000 per N m
    w = np.round(w * per_unit) / per_unit  # k / 1000 as the double nearest to it (= what the csv text parses to)
    return {"t": B_T0_S + tr.t, "q": q, "wrench": w, "w_tool_on_sensor_s": w_true, "tare": tare}


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


B_CSV_TIME = "t"
B_CSV_Q = tuple(f"q{j}" for j in range(1, 8))
B_CSV_WRENCH = ("fx", "fy", "fz", "tx", "ty", "tz")


def _write_csv_b(path: Path, sig: dict[str, np.ndarray]) -> None:
    """Rig B's plain ``log.csv``: t [s] (3 decimals), q [rad], tool-on-sensor wrench (quantised)."""
    block = np.hstack([sig["t"][:, None], sig["q"], sig["wrench"]])
    buf = io.StringIO()
    np.savetxt(buf, block, fmt=["%.3f"] + ["%.9f"] * 7 + ["%.6f"] * 3 + ["%.3f"] * 3, delimiter=",",
               header=",".join((B_CSV_TIME, *B_CSV_Q, *B_CSV_WRENCH)), comments="")
    path.write_text(buf.getvalue())


def _setup_toml_b(tared: bool) -> str:
    """Rig B's setup file (TOML text): the NOMINAL rig B and log.csv's layout."""
    rg = RIGS["B"]
    sections = {
        "log": {"time": B_CSV_TIME, "time_scale_s": 1.0, "q": B_CSV_Q, "qdot": (), "angle_unit": "rad",
                "wrench": B_CSV_WRENCH, "wrench_acts": "tool_on_sensor", "tared": tared},
        "sensor": {"position_flange_m": rg.sensor_pos_f_m, "rpy_flange_deg": rg.sensor_rpy_f_deg},
        "tool": {"mass_kg": rg.tool_mass_kg, "com_sensor_m": rg.tool_com_s_m,
                 "inertia_com_kg_m2": rg.tool_inertia_com_kg_m2, "tip_sensor_m": rg.tool_tip_s_m},
        "arm": {"mjcf": "", "flange_site": FLANGE_SITE},
        "contact": {"mode": "tip", "detect_force_N": 5.0, "margin_s": 0.1},
        "analysis": {"exclude_s": (), "effects": (), "exclude_effects": ()},
    }
    lines = ["# Foreign rig B (examples/foreign_rig.py --rig B): the declared (nominal) set-up of log.csv:",
             "# s, rad, no velocities, wrench of the tool on the (flipped) sensor, zeroed at power-up.", ""]
    for sec, kv in sections.items():
        lines.append(f"[{sec}]")
        lines += [f"{k} = {_toml_value(v)}" for k, v in kv.items()]
        lines.append("")
    return "\n".join(lines)


def setup_toml(variant: str, tared: bool, rig: str | Rig = "A") -> str:
    """The setup file (TOML text) a user of this rig would write: the NOMINAL rig (no hidden
    effect) and the column layout of ``variant`` = "csv" or "parquet" (rig B: "csv" only)."""
    if _rig(rig).name == "B":
        if variant != "csv":
            raise ValueError(f"rig B has one variant, 'csv' (got '{variant}')")
        return _setup_toml_b(tared)
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


def make_case(name: str, out_dir: Path, seed: int = 0, rig: str | Rig = "A") -> Path:
    """Write case ``name`` of ``rig`` into ``out_dir/name/`` and return that folder. Rig A:
    log.csv.gz, log.parquet, setup_csv.toml, setup_parquet.toml, truth.json; rig B: log.csv,
    setup.toml, truth.json."""
    if _rig(rig).name == "B":
        return _make_case_b(name, out_dir, seed)
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


def _make_case_b(name: str, out_dir: Path, seed: int = 0) -> Path:
    h = _hidden(name, "B")
    case_dir = Path(out_dir) / name
    case_dir.mkdir(parents=True, exist_ok=True)
    sig = _case_signals_b(name, seed)
    _write_csv_b(case_dir / "log.csv", sig)
    (case_dir / "setup.toml").write_text(setup_toml("csv", h.tared, "B"))
    tr = trajectory("B")
    truth = {"case": name, "description": CASES_B[name], "effects": _effects_truth(h), "detectable": h.detectable,
             "tared": h.tared, "seed": int(seed), "rig": "B"}
    truth["experiment"] = {
        "log_t0_s": B_T0_S,
        "table_point_w_m": [float(x) for x in tr.table_point_w],
        "table_normal_w": [float(x) for x in tr.table_normal_w],
        "table_z_m": tr.table_z_m,
        "contact_t_s": [round(B_T0_S + c, 9) for c in tr.contact_s],  # in the log's time
        "mu": B_MU,
        "normal_force_N": B_NORMAL_FORCE_N,
        "circle_radius_m": B_CIRCLE_RADIUS_M,
        "tare_q_rad": list(B_TARE_Q),
        "tare_added_log": [float(x) for x in sig["tare"]],  # constant in the logged wrench
    }
    (case_dir / "truth.json").write_text(json.dumps(truth, indent=2) + "\n")
    return case_dir


# ==================================================================================================
# self-test of the MuJoCo wrench (sign and frame)
# ==================================================================================================
def self_test(tol: float = 1e-9, rig: str | Rig = "A") -> dict[str, float]:
    """Check ``rig``'s MuJoCo reading against statics, at q_home and three tilted poses at rest.

    (1) ``w_tool_on_sensor_s`` = (m R_ws^T g, c x m R_ws^T g) with R_ws from MuJoCo's ``site_xmat``
    of the sensor site; (2) a tip force F (world) changes it by (R_ws^T F, tip x R_ws^T F);
    (3) the sensor agrees with ``cfrc_int`` of the tool body; (4) the sensor site sits at the
    declared mount in the flange frame. Returns the largest errors [N, N m or m]; raises
    AssertionError beyond ``tol``.
    """
    rg = _rig(rig)
    m = build_model(rig=rg)
    d = mujoco.MjData(m)
    ids = _Ids(m)
    g = np.asarray(m.opt.gravity, dtype=float)
    c, tip = np.asarray(rg.tool_com_s_m), np.asarray(rg.tool_tip_s_m)
    f_w = np.array([2.5, -1.5, 12.0])
    err = {"static": 0.0, "tip_force": 0.0, "cfrc_int": 0.0, "mount": 0.0}
    fl = m.site(FLANGE_SITE).id
    poses = [np.asarray(rg.q_home), np.asarray(rg.q_home) + [0.3, 0.4, -0.2, 0.3, 0.6, -0.5, 1.0],
             np.array([-1.0, 0.2, 0.5, -1.8, -1.2, 2.2, -0.7]), np.array([0.5, -1.2, -0.8, -2.6, 1.5, 0.8, 2.0])]
    for q in poses:
        d.qpos[:], d.qvel[:], d.qacc[:] = q, 0.0, 0.0
        d.xfrc_applied[:] = 0.0
        w0 = _read_tool_on_sensor(m, d, ids)
        r_ws = d.site_xmat[ids.ft].reshape(3, 3).copy()
        r_wf = d.site_xmat[fl].reshape(3, 3)
        err["mount"] = max(err["mount"], float(np.abs(r_wf.T @ r_ws - rpy_matrix_deg(rg.sensor_rpy_f_deg)).max()),
                           float(np.abs(r_wf.T @ (d.site_xpos[ids.ft] - d.site_xpos[fl]) - rg.sensor_pos_f_m).max()))
        fg = rg.tool_mass_kg * r_ws.T @ g
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
    p.add_argument("--rig", default="A", choices=list(RIGS), help="which rig (default: A)")
    p.add_argument("--case", nargs="+", default=None, choices=sorted(set(CASES) | set(CASES_B)),
                   help="cases (default: all of the rig's)")
    p.add_argument("--seed", type=int, default=0, help="noise seed")
    p.add_argument("--self-test", action="store_true", help="check the MuJoCo wrench against statics first")
    a = p.parse_args(argv)
    names = list(cases(a.rig)) if a.case is None else a.case
    unknown = [n for n in names if n not in cases(a.rig)]
    if unknown:
        p.error(f"rig {a.rig} has no case {', '.join(unknown)} (choose from {', '.join(cases(a.rig))})")
    if a.self_test:
        print("self-test max errors:", {k: f"{v:.1e}" for k, v in self_test(rig=a.rig).items()})
    for name in names:
        t0 = time.perf_counter()
        d = make_case(name, a.out, a.seed, a.rig)
        print(f"{d}: {', '.join(sorted(x.name for x in d.iterdir()))} ({time.perf_counter() - t0:.2f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
