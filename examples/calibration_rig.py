"""A calibration rig: F/T-calibration logs for ``kinadapt diagnose`` on arms other than the Panda.

Standalone on purpose: this file imports nothing from ``kinadapt_nn`` and no MuJoCo (only NumPy,
SciPy and the standard library). Its kinematics are its own (DH tables below, forward kinematics
by products of elementary transforms), its physics are the statics and the Newton-Euler equations
of a rigid tool written out here, and it fits the classic F/T calibration itself, so that the
diagnosis can be compared with an independent estimate. ::

    python examples/calibration_rig.py --out DIR [--arm ur5e|iiwa14|all] [--case NAME ...] [--seed N] [--self-test]

Per case it writes ``DIR/<arm>/<case>/``: ``log.csv``, ``setup.toml`` (what a user of this rig would
declare: the NOMINAL set-up, with the case's wrong guesses) and ``truth.json`` (the hidden effects in
the diagnosis's reporting units, the true mount/tool/offset and, for static logs, the independent
calibration beside the truth).

Arms (the base at the world origin, z up, gravity (0, 0, -g); the flange f = the last DH frame)
------------------------------------------------------------------------------------------------
* ``ur5e``, classic DH ``T_{i-1,i} = Rz(q_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``: d = (0.1625, 0, 0, 0.1333,
  0.0997, 0.0996) m, a = (0, -0.425, -0.3922, 0, 0, 0) m, alpha = (pi/2, 0, 0, pi/2, -pi/2, 0).
* ``iiwa14`` (KUKA LBR iiwa 14 R820), modified (Craig) DH ``T_{i-1,i} = Rx(alpha_{i-1}) Tx(a_{i-1})
  Rz(q_i) Tz(d_i)``, row i holding (a_{i-1}, alpha_{i-1}, d_i): a = 0, alpha = (0, -pi/2, pi/2, pi/2,
  -pi/2, -pi/2, pi/2), d = (0.36, 0, 0.42, 0, 0.4, 0, 0.126) m (straight up: the flange at 1.306 m).

Sensor frame s: origin ``sensor_pos_f_m`` in f, axes ``R_fs = Rz(yaw) Ry(pitch) Rx(roll)`` of
(roll, pitch, yaw) [deg]. The tool (mass, COM, inertia about the COM) is described in s. Every log
holds the wrench the TOOL exerts on the SENSOR (``wrench_acts = "tool_on_sensor"``), in s, about
the s origin, plus a constant sensor offset (a real sensor always has one; every setup declares
``tared = true`` so that the offset is a nuisance estimated with the rest).

(A) Static logs (``static_cases``; both arms; ur5e 60 poses x 3 samples, columns ``q_base .. q_wrist3``
[rad]; iiwa14 100 poses x 2 samples, ``A1 .. A7`` [deg]): random joint configurations (rejection-
sampled so that the links stay above the table, the flange away from the base column, and gravity
points within 35 deg of each of the six sensor half-axes), each row one sample at rest: ``F = m
R_ws^T g_w``, ``M = c x F`` (the tool's weight), then a hidden sensor-axes rotation (``w -> R^T w``),
+ offset, + noise (N(0, 0.05 N / 0.003 N m), encoders N(0, 1e-5 rad)); torques in N m or N mm. No
time column (``time = ""``, ``static = true``). Cases: ``mount_unknown`` (a large rotation about z,
``mount_known = false`` with the identity as the guess, N mm, the tool mass guessed 15 % off),
``mount_unknown_general`` (a general large rotation, likewise), ``mount_wrong_known`` (the
mount_unknown log, the identity declared as known), ``mount_declared`` (nothing hidden but the
offset; the ur5e's declares g = 9.80665), ``tool_gravity``, ``ft_frame_rotation`` (2-2.5 deg),
``encoder_offset`` (a joint gravity sees; on the ur5e joint 3, parallel to joints 2 and 4, so that the
offset is seen but not attributable: "cannot_decide" with that tie is right), ``encoder_offset_wrist``
(a wrist joint with no parallel neighbour), ``encoder_offset_joint1`` (invisible),
``torque_unit_wrong`` (N mm logged, N m declared), ``torque_unit_wrong_nm`` (N m logged, N mm declared),
``force_unit_wrong`` (forces logged in lbf, N declared). truth.json holds, beside the truth, the rig's own
calibration of the log (``calibrate``: linear least squares, nearest rotation, Levenberg-Marquardt).

(B) Moving logs (``MOVING_CASES``; ur5e only): 12.55 s at 500 Hz (6276 samples; ``timestamp`` [s],
``actual_q_*`` [rad], ``actual_qd_*`` [rad/s], ``fx .. mz`` [N, N m]). Hold 0.5 s, seven minimum-jerk
moves (0.85-1.0 s, holds of 0.3-0.45 s after each) through poses that tilt the tool 29-35 deg about
two horizontal axes and turn it about its own axis, then a 2.5 s four-joint windowed sinusoidal
swing and a final hold 0.4 s. The wrench is the tool's Newton-Euler wrench about the sensor origin
(``F = m (g - a_c)``, ``M = c x F - I alpha - omega x I omega``, all in s) from the sensor's pose,
velocity and acceleration: central differences (5-point, step ``STENCIL_H_S`` = 1 ms) of OUR forward
kinematics evaluated on the analytic q(t) of the segment that owns the sample (never across a
join). The self-test bounds this against the analytic Jacobian (velocities) and the analytic
acceleration recursion: both agree to < 1e-8 (truncation O(h^4), round-off O(eps/h^2) ~ 1e-10).
Pipeline: payload (a point mass) -> sensor-axes rotation -> + offset -> + drift (from the first
sample) -> noise (wrench N(0, 0.05 N / 0.003 N m), q N(0, 1e-5 rad), qdot N(0, 1e-3 rad/s)).
Contact mode "none". Cases: ``moving_none``, ``moving_tool_gravity``, ``moving_ft_frame_rotation``
(3 deg, general axis), ``moving_ft_bias_drift``, ``moving_encoder_offset`` (joint 2; ties as above),
``moving_encoder_offset_joint1`` (invisible), ``moving_pair`` (payload + joint-3 offset).

Arm files: every setup declares the arm by an inline ``[arm] dh`` table, except ``encoder_offset``
and ``moving_tool_gravity`` of the ur5e, which name ``examples/arms/ur5e.urdf`` (absolute path). When
that file exists its chain is compared with the DH table (``urdf_match``: a base turn about z and a
constant flange offset allowed, the offset then declared as ``flange_xyz_m``/``flange_rpy_deg``).

Conventions of the truth (as ``examples/foreign_rig.py``): ``ft_frame_rotation`` rot_x/y/z [deg] is
the rotation vector (in s) of the true sensor axes from the declared ones (logged w = R^T w);
``encoder_offset`` offset_jointJ [deg] = true angle - logged angle; ``ft_bias_drift`` rates in the
log's convention [N/s, N m/s]; ``tool_gravity`` mass [kg] and COM [m] in s of the undeclared mass (a
wrong declared tool mass counts as one: true - declared, negative when over-guessed, at the tool's
COM). ``expected_verdicts``: "present" for each hidden effect, "absent" or "cannot_decide" for an
invisible one, "present" or "cannot_decide" for an offset of a joint with parallel neighbours
(``indistinguishable_from`` names them). ``sensor_mount.declared_consistent``: null for an unknown
mount (nothing claimed), false for a known mount farther than 15 deg from the truth.
"""

from __future__ import annotations

import argparse
import io
import json
import math
import sys
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, NamedTuple

import numpy as np
from scipy.optimize import least_squares

REPO_ROOT = Path(__file__).resolve().parents[1]
UR5E_URDF = (REPO_ROOT / "examples" / "arms" / "ur5e.urdf").resolve()

G_STD = 9.81  # [m/s^2] gravity of every case but one
G_CODATA = 9.80665  # [m/s^2] standard gravity: one case declares it
STENCIL_H_S = 1e-3  # [s] step of the central differences of the sensor pose
RATE_HZ = 500.0  # moving logs
SIGMA_FORCE_N, SIGMA_TORQUE_NM = 0.05, 0.003
SIGMA_Q_RAD, SIGMA_QDOT_RAD_S = 1e-5, 1e-3
COVERAGE_DEG = 35.0  # static logs: gravity within this of each of the six sensor half-axes


# ==================================================================================================
# the arms and the rigs
# ==================================================================================================
@dataclass(frozen=True)
class Arm:
    """A revolute arm from a DH table (one entry per joint)."""

    name: str
    convention: str  # "classic" or "modified" (module docstring)
    a_m: tuple[float, ...]
    d_m: tuple[float, ...]
    alpha_rad: tuple[float, ...]
    sample_lo_rad: tuple[float, ...]  # static poses are drawn uniformly in [lo, hi] per joint
    sample_hi_rad: tuple[float, ...]
    qdot_limit_rad_s: tuple[float, ...]
    min_radius_m: float  # static poses: the flange at least this far from the base's z axis

    @property
    def n(self) -> int:
        return len(self.a_m)


_PI = math.pi
UR5E = Arm("ur5e", "classic", (0.0, -0.425, -0.3922, 0.0, 0.0, 0.0), (0.1625, 0.0, 0.0, 0.1333, 0.0997, 0.0996),
           (_PI / 2, 0.0, 0.0, _PI / 2, -_PI / 2, 0.0),
           (-_PI, -2.9, -2.7, -_PI, -_PI, -_PI), (_PI, -0.25, 2.7, _PI, _PI, _PI), (_PI,) * 6, 0.25)
_IIWA_LIM = tuple(math.radians(x) for x in (170, 120, 170, 120, 170, 120, 175))
IIWA14 = Arm("iiwa14", "modified", (0.0,) * 7, (0.36, 0.0, 0.42, 0.0, 0.4, 0.0, 0.126),
             (0.0, -_PI / 2, _PI / 2, _PI / 2, -_PI / 2, -_PI / 2, _PI / 2),
             tuple(-0.9 * x for x in _IIWA_LIM), tuple(0.9 * x for x in _IIWA_LIM),
             tuple(math.radians(x) for x in (85, 85, 100, 75, 130, 135, 135)), 0.2)
ARMS = {"ur5e": UR5E, "iiwa14": IIWA14}


@dataclass(frozen=True)
class Rig:
    """The sensor, the tool and the log layout of one arm's experiments (true = declared, except
    for a case's hidden effects and guesses)."""

    sensor_pos_f_m: tuple[float, float, float]
    sensor_rpy_f_deg: tuple[float, float, float]  # the known mount
    tool_mass_kg: float
    tool_com_s_m: tuple[float, float, float]
    tool_inertia_com_kg_m2: tuple[float, ...]  # ixx iyy izz ixy ixz iyz about the COM, s axes
    tool_tip_s_m: tuple[float, float, float]
    offset: tuple[float, ...]  # [N, N m] the sensor's constant offset (tool_on_sensor)
    q_cols: tuple[str, ...]
    angle_unit: str  # "rad" or "deg" in the log
    wrench_cols: tuple[str, ...]
    n_poses: int = 0  # static logs: poses and samples per pose
    samples_per_pose: int = 0


STATIC_RIGS = {
    "ur5e": Rig((0.0, 0.0, 0.02), (0.0, 0.0, 90.0), 0.95, (0.002, -0.004, 0.062),
                (0.0021, 0.0019, 0.0008, 0.0, 0.0, 0.0001), (0.0, 0.0, 0.16), (1.2, -0.8, 2.5, 0.05, 0.03, -0.04),
                ("q_base", "q_shoulder", "q_elbow", "q_wrist1", "q_wrist2", "q_wrist3"), "rad",
                ("Fx", "Fy", "Fz", "Tx", "Ty", "Tz"), n_poses=60, samples_per_pose=3),
    "iiwa14": Rig((0.0, 0.0, 0.03), (0.0, 0.0, 60.0), 1.6, (0.010, 0.005, 0.085),
                  (0.0045, 0.0050, 0.0020, 0.0, 0.0002, 0.0), (0.0, 0.0, 0.20), (-0.6, 1.5, -3.1, -0.02, 0.06, 0.015),
                  tuple(f"A{j}" for j in range(1, 8)), "deg",
                  ("force_x", "force_y", "force_z", "torque_x", "torque_y", "torque_z"), n_poses=100,
                  samples_per_pose=2),
}
MOVING_RIG = Rig((0.0, 0.0, 0.02), (0.0, 0.0, 30.0), 1.3, (0.005, -0.003, 0.07),
                 (0.0062, 0.0058, 0.0016, 0.0002, -0.0001, 0.0), (0.0, 0.0, 0.17), (0.4, -0.3, 0.9, 0.02, -0.01, 0.015),
                 tuple(f"actual_q_{j}" for j in range(6)), "rad", ("fx", "fy", "fz", "mx", "my", "mz"))
MOVING_TIME_COL = "timestamp"
MOVING_QDOT_COLS = tuple(f"actual_qd_{j}" for j in range(6))


# ==================================================================================================
# the cases
# ==================================================================================================
@dataclass(frozen=True)
class Case:
    """What differs between the truth and the declaration (module docstring for the conventions)."""

    description: str
    payload: tuple[float, tuple[float, float, float]] | None = None  # (kg, COM in s [m]) undeclared point mass
    rotvec_deg: tuple[float, float, float] | None = None  # small sensor-axes rotation (axis in s)
    drift: tuple[float, ...] | None = None  # [N/s, N m/s] from the first sample (tool_on_sensor)
    encoder_offset_deg: dict[int, float] = field(default_factory=dict)  # joint (1-based) -> true - logged
    mount_rpy_deg: tuple[float, float, float] | None = None  # true mount (None: the rig's)
    declared_rpy_deg: tuple[float, float, float] | None = None  # declared mount (None: the true one)
    mount_known: bool = True
    mass_guess: float = 1.0  # declared tool mass / true tool mass
    torque_unit: str = "N m"  # in the log
    declared_torque_unit: str | None = None  # None: as logged
    force_unit: str = "N"  # in the log
    declared_force_unit: str | None = None  # None: as logged
    gravity_mps2: float = G_STD
    arm_file: str = "dh"  # "dh" (inline table) or "urdf" (examples/arms/ur5e.urdf; ur5e only)
    detectable: bool = True
    #: joints whose offset the log cannot tell from this one's (the ur5e's parallel joints 2, 3, 4: a
    #: static log sees only the flange's orientation, a moving one barely more): "cannot_decide" with
    #: a tie is then as right as "present"
    ties: tuple[int, ...] = ()


def _rotvec_deg(angle_deg: float, axis) -> tuple[float, float, float]:
    a = np.asarray(axis, dtype=float)
    return tuple(float(x) for x in angle_deg * a / np.linalg.norm(a))


def static_cases(arm: str) -> dict[str, Case]:
    """The static cases of ``arm`` (the same kinds for both arms, with different numbers)."""
    ur = arm == "ur5e"
    big = (0.0, 0.0, 137.0) if ur else (0.0, 0.0, -115.0)
    general = (12.0, -7.0, 220.0) if ur else (-10.0, 15.0, 160.0)
    guess = 0.85 if ur else 1.15
    enc_j, enc = (3, 1.2) if ur else (4, 1.4)
    wrist_j = 5 if ur else 6
    payload = (0.25, (0.03, -0.02, 0.05)) if ur else (0.30, (-0.02, 0.025, 0.07))
    rot = _rotvec_deg(2.5, (1.0, -2.0, 0.5)) if ur else _rotvec_deg(2.0, (-1.0, 1.0, 2.0))
    g_declared = "declared 9.80665 m/s^2 (consistent with the log)" if ur else "g = 9.81 m/s^2"
    return {
        "mount_unknown": Case(f"sensor mounted at rpy {big} deg, unknown (mount_known = false, identity guess); "
                              f"torques in N mm; tool mass guessed {guess:.2f} x true", mount_rpy_deg=big,
                              declared_rpy_deg=(0.0, 0.0, 0.0), mount_known=False, mass_guess=guess,
                              torque_unit="N mm"),
        "mount_unknown_general": Case(f"sensor mounted at a general rpy {general} deg, unknown (identity guess); "
                                      f"torques in N mm; tool mass guessed {2 - guess:.2f} x true",
                                      mount_rpy_deg=general, declared_rpy_deg=(0.0, 0.0, 0.0), mount_known=False,
                                      mass_guess=2 - guess, torque_unit="N mm"),
        "mount_wrong_known": Case(f"the mount_unknown log, but the setup declares the identity mount as KNOWN "
                                  f"(true rpy {big} deg): declared_consistent must be false", mount_rpy_deg=big,
                                  declared_rpy_deg=(0.0, 0.0, 0.0), mount_known=True, mass_guess=guess,
                                  torque_unit="N mm"),
        "mount_declared": Case(f"mount {general} deg declared right; nothing hidden but the sensor offset "
                               f"(tared = true); {g_declared}", mount_rpy_deg=general,
                               gravity_mps2=G_CODATA if ur else G_STD),
        "tool_gravity": Case(f"an undeclared {payload[0]} kg payload at {payload[1]} m in s", payload=payload),
        "ft_frame_rotation": Case(f"sensor axes rotated {np.linalg.norm(rot):.1f} deg about "
                                  f"{tuple(round(x, 3) for x in rot)} (rotvec, s) from the known mount",
                                  rotvec_deg=rot),
        "encoder_offset": Case(f"joint {enc_j} reads {enc} deg less than its true angle"
                               + (" (arm from the URDF; joints 2, 3, 4 are parallel: seen, not attributable)"
                                  if ur else ""), encoder_offset_deg={enc_j: enc},
                               arm_file="urdf" if ur else "dh", ties=(2, 4) if ur else ()),
        "encoder_offset_wrist": Case(f"joint {wrist_j} reads 1.0 deg less than its true angle (a wrist joint "
                                     "with no parallel neighbour: attributable)", encoder_offset_deg={wrist_j: 1.0}),
        "encoder_offset_joint1": Case("joint 1 reads 1.5 deg less than its true angle (invisible: gravity is "
                                      "invariant under the vertical first axis)", encoder_offset_deg={1: 1.5},
                                      detectable=False),
        "torque_unit_wrong": Case("torques logged in N mm but declared N m (the likely unit: N mm)",
                                  torque_unit="N mm", declared_torque_unit="N m"),
        "torque_unit_wrong_nm": Case("torques logged in N m but declared N mm (the likely unit: N m)",
                                     declared_torque_unit="N mm"),
        "force_unit_wrong": Case("forces logged in lbf but declared N (the likely unit: lbf)", force_unit="lbf",
                                 declared_force_unit="N"),
    }


_MOVING_ROT = _rotvec_deg(3.0, (1.0, -0.6, 0.8))
MOVING_CASES: dict[str, Case] = {
    "moving_none": Case("no hidden effect (only the declared-tared sensor offset)"),
    "moving_tool_gravity": Case("an undeclared 0.25 kg payload at (0.03, 0.02, 0.05) m in s (arm from the URDF)",
                                payload=(0.25, (0.03, 0.02, 0.05)), arm_file="urdf"),
    "moving_ft_frame_rotation": Case("sensor axes rotated 3 deg about (1, -0.6, 0.8) (s) from the declared mount",
                                     rotvec_deg=_MOVING_ROT),
    "moving_ft_bias_drift": Case("the wrench drifts linearly from the first sample: +(0.12, -0.08, 0.15) N/s, "
                                 "+(0.008, 0.005, -0.006) N m/s", drift=(0.12, -0.08, 0.15, 0.008, 0.005, -0.006)),
    "moving_encoder_offset": Case("joint 2 reads 1.0 deg less than its true angle (parallel to joints 3 and 4: "
                                  "told apart only by the tool's inertia)", encoder_offset_deg={2: 1.0}, ties=(3, 4)),
    "moving_encoder_offset_joint1": Case("joint 1 reads 2.0 deg less than its true angle (invisible)",
                                         encoder_offset_deg={1: 2.0}, detectable=False),
    "moving_pair": Case("an undeclared 0.20 kg payload at (0, 0.03, 0.05) m AND joint 3 reading 0.8 deg less",
                        payload=(0.20, (0.0, 0.03, 0.05)), encoder_offset_deg={3: 0.8}, ties=(2, 4)),
}


def cases(arm: str) -> dict[str, Case]:
    """Case name -> Case of ``arm`` (static for both arms, moving for the ur5e)."""
    return {**static_cases(arm), **(MOVING_CASES if arm == "ur5e" else {})}


# ==================================================================================================
# rotations
# ==================================================================================================
def rpy_matrix_deg(rpy_deg) -> np.ndarray:
    """``Rz(yaw) Ry(pitch) Rx(roll)`` of (roll, pitch, yaw) [deg]: (3,) -> (3, 3)."""
    r, p, y = np.deg2rad(np.asarray(rpy_deg, dtype=float))
    return _rot("z", y) @ _rot("y", p) @ _rot("x", r)


def _rot(axis: str, angle) -> np.ndarray:
    """Elementary rotation(s): angle () or (B,) [rad] -> (3, 3) or (B, 3, 3)."""
    a = np.asarray(angle, dtype=float)
    c, s, one, zero = np.cos(a), np.sin(a), np.ones_like(a), np.zeros_like(a)
    rows = {"x": ((one, zero, zero), (zero, c, -s), (zero, s, c)),
            "y": ((c, zero, s), (zero, one, zero), (-s, zero, c)),
            "z": ((c, -s, zero), (s, c, zero), (zero, zero, one))}[axis]
    return np.moveaxis(np.array(rows), (0, 1), (-2, -1))


def matrix_rpy_deg(r: np.ndarray) -> np.ndarray:
    """(3, 3) -> (roll, pitch, yaw) [deg] with ``r = Rz(yaw) Ry(pitch) Rx(roll)``, pitch in [-90, 90]."""
    return np.rad2deg([math.atan2(r[2, 1], r[2, 2]), math.asin(float(np.clip(-r[2, 0], -1, 1))),
                       math.atan2(r[1, 0], r[0, 0])])


def skew(v: np.ndarray) -> np.ndarray:
    """(..., 3) -> (..., 3, 3) with skew(v) x = v x x."""
    v = np.asarray(v, dtype=float)
    z = np.zeros(v.shape[:-1])
    return np.stack([np.stack([z, -v[..., 2], v[..., 1]], -1), np.stack([v[..., 2], z, -v[..., 0]], -1),
                     np.stack([-v[..., 1], v[..., 0], z], -1)], -2)


def vee(m: np.ndarray) -> np.ndarray:
    """Skew part of (..., 3, 3) -> (..., 3) (inverse of ``skew`` on skew matrices)."""
    return 0.5 * np.stack([m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]], -1)


def rotvec_matrix(v) -> np.ndarray:
    """Rodrigues: rotation vector (3,) [rad] -> (3, 3)."""
    v = np.asarray(v, dtype=float)
    th = float(np.linalg.norm(v))
    if th < 1e-15:
        return np.eye(3)
    k = skew(v / th)
    return np.eye(3) + math.sin(th) * k + (1.0 - math.cos(th)) * k @ k


def rotation_angle_deg(r: np.ndarray) -> float:
    """Angle [deg] of the rotation matrix ``r`` (atan2 of sin and cos: accurate near 0 too)."""
    return math.degrees(math.atan2(float(np.linalg.norm(vee(r))), (float(np.trace(r)) - 1.0) / 2.0))


def homogeneous(r: np.ndarray, p) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3], t[:3, 3] = r, p
    return t


# ==================================================================================================
# kinematics from the DH table
# ==================================================================================================
def _link(arm: Arm, i: int, theta: np.ndarray) -> np.ndarray:
    """T_{i-1,i} for joint i (0-based) at angles theta (B,) -> (B, 4, 4) (module docstring)."""
    B = len(theta)
    rz = np.zeros((B, 4, 4))
    rz[:, :3, :3], rz[:, 3, 3] = _rot("z", theta), 1.0
    tz = homogeneous(np.eye(3), (0.0, 0.0, arm.d_m[i]))
    tx = homogeneous(np.eye(3), (arm.a_m[i], 0.0, 0.0))
    rx = homogeneous(_rot("x", arm.alpha_rad[i]), (0.0, 0.0, 0.0))
    if arm.convention == "classic":
        return rz @ tz @ tx @ rx
    return rx @ tx @ rz @ tz


def frames(arm: Arm, q: np.ndarray) -> np.ndarray:
    """World poses of the DH frames 0..n: q (B, n) [rad] -> (B, n + 1, 4, 4); frame n = the flange."""
    q = np.atleast_2d(q)
    B, n = q.shape
    T = np.empty((B, n + 1, 4, 4))
    T[:, 0] = np.eye(4)
    for i in range(n):
        T[:, i + 1] = T[:, i] @ _link(arm, i, q[:, i])
    return T


def joint_axes(arm: Arm, T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Axis directions z (B, n, 3) and axis points o (B, n, 3) of the joints, world frame: classic DH
    turns joint i about z_{i-1} through o_{i-1}, modified DH about z_i through o_i."""
    sel = slice(0, arm.n) if arm.convention == "classic" else slice(1, arm.n + 1)
    return T[:, sel, :3, 2], T[:, sel, :3, 3]


def sensor_pose(arm: Arm, q: np.ndarray, T_fs: np.ndarray) -> np.ndarray:
    """T_ws: q (B, n) -> (B, 4, 4)."""
    return frames(arm, q)[:, -1] @ T_fs


def jacobian(arm: Arm, q: np.ndarray, p_w: np.ndarray) -> np.ndarray:
    """Geometric Jacobian of the point p_w (B, 3) on the last link: (B, 6, n), rows (v, omega)."""
    z, o = joint_axes(arm, frames(arm, q))
    return np.concatenate([np.cross(z, p_w[:, None, :] - o), z], axis=-1).transpose(0, 2, 1)


def point_acceleration(arm: Arm, q, qd, qdd, p_w) -> tuple[np.ndarray, np.ndarray]:
    """Analytic (acceleration of p_w, angular acceleration) (B, 3) each, by differentiating
    ``v = sum_k z_k x (p - o_k) qd_k``, ``omega = sum_k z_k qd_k`` in time: every joint axis is
    fixed in the link before it, which turns at ``omega_<k = sum_{j<k} z_j qd_j`` (self-test only)."""
    z, o = joint_axes(arm, frames(arm, q))  # (B, n, 3)
    w_k = z * qd[..., None]  # (B, n, 3) contribution of joint k to omega
    w_before = np.cumsum(w_k, axis=1) - w_k  # omega of the link carrying joint k
    zdot = np.cross(w_before, z)
    # velocity of each axis point: sum over the joints before it
    v_o = np.stack([np.cross(w_k[:, :k], o[:, k:k + 1] - o[:, :k]).sum(axis=1) for k in range(arm.n)], axis=1)
    r = p_w[:, None, :] - o
    v_p = np.cross(w_k, r).sum(axis=1)
    acc = (np.cross(zdot, r) * qd[..., None] + np.cross(z, v_p[:, None, :] - v_o) * qd[..., None]
           + np.cross(z, r) * qdd[..., None]).sum(axis=1)
    alpha = (zdot * qd[..., None] + z * qdd[..., None]).sum(axis=1)
    return acc, alpha


def _urdf_chain(path: Path) -> tuple[list[tuple[np.ndarray, np.ndarray | None]], str]:
    """(origin transform (4, 4), axis (3,)) of each revolute joint from the URDF's root outwards
    (a single chain), fixed joints folded into the next origin, a trailing fixed transform last
    with axis None; and the name of the chain's last link."""
    root = ET.parse(path).getroot()
    joints = {j.find("parent").get("link"): j for j in root.findall("joint")}
    children = {j.find("child").get("link") for j in root.findall("joint")}
    link = next(lk.get("name") for lk in root.findall("link") if lk.get("name") not in children)
    chain, pending = [], np.eye(4)
    while link in joints:
        j = joints[link]
        org = j.find("origin")
        xyz = [float(x) for x in (org.get("xyz", "0 0 0") if org is not None else "0 0 0").split()]
        rpy = [math.degrees(float(x)) for x in (org.get("rpy", "0 0 0") if org is not None else "0 0 0").split()]
        pending = pending @ homogeneous(rpy_matrix_deg(rpy), xyz)
        if j.get("type") in ("revolute", "continuous"):
            ax = j.find("axis")
            axis = ax.get("xyz") if ax is not None else "1 0 0"  # URDF's default axis
            chain.append((pending, np.array([float(x) for x in axis.split()])))
            pending = np.eye(4)
        link = j.find("child").get("link")
    chain.append((pending, None))
    return chain, link


def urdf_flange(path: Path, q: np.ndarray) -> np.ndarray:
    """World pose (B, 4, 4) of the URDF's last link (rotations about each joint's axis: Rodrigues)."""
    chain, _ = _urdf_chain(path)
    out = np.empty((len(q), 4, 4))
    for b, qb in enumerate(np.atleast_2d(q)):
        T, k = np.eye(4), 0
        for org, ax in chain:
            T = T @ org
            if ax is not None:
                T = T @ homogeneous(rotvec_matrix(ax / np.linalg.norm(ax) * qb[k]), (0.0, 0.0, 0.0))
                k += 1
        out[b] = T
    return out


class UrdfMatch(NamedTuple):
    """How a URDF's last link relates to the DH flange: ``T_urdf = Rz(base_yaw) T_dh F`` (+ a base shift)."""

    error: float  # worst mismatch over the test poses [m or rotation-matrix entries]; ~0: the same arm
    base_yaw_deg: float  # a turn of the base about the vertical (invisible to gravity)
    F: np.ndarray  # (4, 4) the constant last-link-to-DH-flange offset: T_urdf_last = T_dh_flange F
    last_link: str  # the URDF's last link


def urdf_match(path: Path, arm: Arm, n_poses: int = 20, seed: int = 7) -> UrdfMatch:
    """Compare a URDF with ``arm``'s DH table on random poses, allowing a base turn about z (0, +-90 or
    180 deg, whichever fits), a base shift and a constant flange offset ``F``."""
    q = np.random.default_rng(seed).uniform(-_PI, _PI, (n_poses, arm.n))
    Tu, Td = urdf_flange(path, q), frames(arm, q)[:, -1]
    best = None
    for yaw in (0.0, 90.0, 180.0, -90.0):
        Rb = rpy_matrix_deg((0.0, 0.0, yaw))
        R_F = np.einsum("nji,jk,nkl->nil", Td[:, :3, :3], Rb.T, Tu[:, :3, :3])  # R_d^T R_b^T R_u per pose
        # p_u = R_b (p_d + R_d p_F) + t_b: linear in (p_F, t_b)
        A = np.concatenate([Rb @ Td[:, :3, :3], np.broadcast_to(np.eye(3), (n_poses, 3, 3))], axis=2).reshape(-1, 6)
        y = (Tu[:, :3, 3] - Td[:, :3, 3] @ Rb.T).reshape(-1)
        x = np.linalg.lstsq(A, y, rcond=None)[0]
        err = max(float(np.abs(R_F - R_F[0]).max()), float(np.abs(A @ x - y).max()))
        if best is None or err < best.error:
            best = UrdfMatch(err, yaw, homogeneous(R_F[0], x[:3]), _urdf_chain(path)[1])
    return best


# ==================================================================================================
# trajectories (moving logs) and the sensor's motion
# ==================================================================================================
class Segment(NamedTuple):
    """A piece of q(t), analytic on the whole real line (so a stencil never crosses a join)."""

    t0_s: float
    t1_s: float
    fn: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]]  # t (N,) -> q, qd, qdd (N, n)


@dataclass(frozen=True)
class Trajectory:
    segments: tuple[Segment, ...]

    def owner(self, t: np.ndarray) -> np.ndarray:
        """(N,) index of the segment owning each time (the last one past its end)."""
        starts = np.array([s.t0_s for s in self.segments])
        return np.clip(np.searchsorted(starts, t, side="right") - 1, 0, len(starts) - 1)

    def eval(self, t: np.ndarray, owner: np.ndarray | None = None):
        """q, qd, qdd (N, n) at t (N,) [s], each time on its owner's analytic piece."""
        t = np.asarray(t, dtype=float)
        own = self.owner(t) if owner is None else owner
        outs = None
        for k in np.unique(own):
            sel = own == k
            parts = self.segments[k].fn(t[sel])
            if outs is None:
                outs = [np.empty((len(t), p.shape[1])) for p in parts]
            for o, p in zip(outs, parts):
                o[sel] = p
        return tuple(outs)


def _seg_hold(t0: float, t1: float, q) -> Segment:
    q = np.asarray(q, dtype=float)
    return Segment(t0, t1, lambda t: (np.tile(q, (len(t), 1)), np.zeros((len(t), len(q))), np.zeros((len(t), len(q)))))


def _seg_minjerk(t0: float, t1: float, qa, qb) -> Segment:
    """q = qa + (qb - qa) s(tau), s = 10 tau^3 - 15 tau^4 + 6 tau^5: rest to rest, C2 joins."""
    qa, dq, T = np.asarray(qa, dtype=float), np.asarray(qb, dtype=float) - np.asarray(qa, dtype=float), t1 - t0

    def fn(t):
        u = ((t - t0) / T)[:, None]
        s = 10 * u**3 - 15 * u**4 + 6 * u**5
        ds = (30 * u**2 - 60 * u**3 + 30 * u**4) / T
        dds = (60 * u - 180 * u**2 + 120 * u**3) / T**2
        return qa + dq * s, dq * ds, dq * dds

    return Segment(t0, t1, fn)


def _seg_swing(t0: float, t1: float, base, swing) -> Segment:
    """q_j = base_j + A_j sin(2 pi n_j tau) sin^2(pi tau): zero offset, velocity, acceleration at both ends."""
    base, T = np.asarray(base, dtype=float), t1 - t0

    def fn(t):
        u = (t - t0) / T
        w, dw, ddw = np.sin(_PI * u) ** 2, _PI * np.sin(2 * _PI * u), 2 * _PI**2 * np.cos(2 * _PI * u)
        q, qd, qdd = np.tile(base, (len(t), 1)), np.zeros((len(t), len(base))), np.zeros((len(t), len(base)))
        for j, amp, cycles in swing:
            k = 2 * _PI * cycles
            s, ds, dds = np.sin(k * u), k * np.cos(k * u), -(k**2) * np.sin(k * u)
            q[:, j] += amp * w * s
            qd[:, j] += amp * (dw * s + w * ds) / T
            qdd[:, j] += amp * (ddw * s + 2 * dw * ds + w * dds) / T**2
        return q, qd, qdd

    return Segment(t0, t1, fn)


#: ur5e moving log: the tool points down at home; targets as offsets from home [rad] of joints 1-6,
#: with the move's duration and the hold after it [s] (joints 4 and 5 tilt the tool about two
#: horizontal axes, joint 6 turns it about its own axis)
MOVING_Q_HOME = (0.0, -1.8, 1.6, -1.3708, -_PI / 2, 0.0)
_MOVES = (
    ((0.0, 0.0, 0.0, 0.50, 0.0, 0.0), 0.9, 0.4),
    ((0.0, 0.0, 0.0, 0.0, 0.55, 0.6), 0.95, 0.35),
    ((0.0, 0.1, -0.15, -0.45, 0.35, 1.1), 1.0, 0.45),
    ((0.15, 0.12, -0.2, 0.35, -0.5, -0.2), 1.0, 0.3),
    ((0.0, 0.0, 0.0, 0.0, -0.6, 0.3), 0.9, 0.4),
    ((-0.2, -0.1, 0.1, 0.55, 0.3, -0.9), 1.0, 0.35),
    ((0.0, 0.0, 0.0, 0.0, 0.0, 0.2), 0.85, 0.3),
)
_SWING = ((0, 0.25, 2.0), (3, 0.2, 3.0), (4, -0.3, 2.5), (5, 0.3, 2.0))  # (joint index, amplitude [rad], cycles)
_T_FIRST_HOLD, _SWING_S, _T_LAST_HOLD = 0.5, 2.5, 0.4


def moving_trajectory() -> tuple[Trajectory, np.ndarray, list[tuple[float, float]]]:
    """The ur5e moving experiment: (trajectory, sample times t (N,) [s], hold windows [(t0, t1)])."""
    home = np.asarray(MOVING_Q_HOME)
    segs, holds, t, q = [_seg_hold(0.0, _T_FIRST_HOLD, home)], [(0.0, _T_FIRST_HOLD)], _T_FIRST_HOLD, home
    for dq, move_s, hold_s in _MOVES:
        qb = home + np.asarray(dq)
        segs += [_seg_minjerk(t, t + move_s, q, qb), _seg_hold(t + move_s, t + move_s + hold_s, qb)]
        holds.append((t + move_s, t + move_s + hold_s))
        t, q = t + move_s + hold_s, qb
    segs.append(_seg_swing(t, t + _SWING_S, q, _SWING))
    t += _SWING_S
    segs.append(_seg_hold(t, t + _T_LAST_HOLD, q))
    holds.append((t, t + _T_LAST_HOLD))
    n = int(round((t + _T_LAST_HOLD) * RATE_HZ)) + 1
    return Trajectory(tuple(segs)), np.arange(n) / RATE_HZ, holds


class SensorMotion(NamedTuple):
    """The sensor frame's motion, world axes."""

    R_ws: np.ndarray  # (N, 3, 3)
    p_ws_m: np.ndarray  # (N, 3) [m]
    v_w: np.ndarray  # (N, 3) [m/s] sensor origin
    omega_w: np.ndarray  # (N, 3) [rad/s]
    a_w: np.ndarray  # (N, 3) [m/s^2] sensor origin
    alpha_w: np.ndarray  # (N, 3) [rad/s^2]


def _d1(x: np.ndarray, h: float) -> np.ndarray:
    """5-point central first derivative of samples x (5, ...) at t + k h, k = -2..2 (error h^4 x^(5) / 30)."""
    return (8.0 * (x[3] - x[1]) - (x[4] - x[0])) / (12.0 * h)


def _d2(x: np.ndarray, h: float) -> np.ndarray:
    """5-point central second derivative (error h^4 x^(6) / 90); written in differences so that a
    constant pose gives exactly zero."""
    return (16.0 * ((x[3] - x[2]) + (x[1] - x[2])) - ((x[4] - x[2]) + (x[0] - x[2]))) / (12.0 * h * h)


def stencil_poses(arm: Arm, traj: Trajectory, t: np.ndarray, T_fs: np.ndarray, h_s: float = STENCIL_H_S):
    """T_ws at t + k h, k = -2..2, on each sample's own segment: (5, N, 4, 4)."""
    own = traj.owner(t)
    return np.stack([sensor_pose(arm, traj.eval(t + k * h_s, own)[0], T_fs) for k in (-2, -1, 0, 1, 2)])


def sensor_motion(arm: Arm, traj: Trajectory, t: np.ndarray, T_fs: np.ndarray, h_s: float = STENCIL_H_S
                  ) -> SensorMotion:
    """The sensor's motion by 5-point central differences of its pose (module docstring):
    ``[omega] = Rdot R^T``, ``[alpha] = skew part of Rddot R^T`` (``Rdot Rdot^T`` is symmetric)."""
    T = stencil_poses(arm, traj, t, T_fs, h_s)
    R, p = T[:, :, :3, :3], T[:, :, :3, 3]
    Rt = R[2].transpose(0, 2, 1)
    return SensorMotion(R[2], p[2], _d1(p, h_s), vee(_d1(R, h_s) @ Rt), _d2(p, h_s), vee(_d2(R, h_s) @ Rt))


# ==================================================================================================
# the wrench of a rigid tool
# ==================================================================================================
def inertia_matrix(v) -> np.ndarray:
    ixx, iyy, izz, ixy, ixz, iyz = (float(x) for x in v)
    return np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])


def tool_wrench(mass_kg: float, com_s_m, inertia_com_s, g_w: np.ndarray, motion: SensorMotion) -> np.ndarray:
    """The wrench (N, 6) [N, N m] a rigid tool exerts on the sensor, s axes, about the s origin.

    Newton: ``F = m (g_s - a_c)``, ``a_c = a_s + alpha_s x c + omega_s x (omega_s x c)``; Euler about
    the COM and the moment transported to the origin: ``M = c x F - (I alpha_s + omega_s x I omega_s)``
    (every vector in s; a static pose: a = omega = alpha = 0, the tool's weight)."""
    Rt = motion.R_ws.transpose(0, 2, 1)
    g_s, a_s = Rt @ g_w, np.einsum("nij,nj->ni", Rt, motion.a_w)
    w_s, al_s = np.einsum("nij,nj->ni", Rt, motion.omega_w), np.einsum("nij,nj->ni", Rt, motion.alpha_w)
    c = np.broadcast_to(np.asarray(com_s_m, dtype=float), a_s.shape)
    a_c = a_s + np.cross(al_s, c) + np.cross(w_s, np.cross(w_s, c))
    F = mass_kg * (g_s - a_c)
    I = inertia_matrix(inertia_com_s)
    M = np.cross(c, F) - (al_s @ I.T + np.cross(w_s, w_s @ I.T))
    return np.hstack([F, M])


def at_rest(R_ws: np.ndarray) -> SensorMotion:
    z = np.zeros((len(R_ws), 3))
    return SensorMotion(R_ws, z, z, z, z, z)


def combined_tool(mass, com, payload) -> tuple[float, np.ndarray]:
    """Mass and COM of the tool plus an optional point-mass payload."""
    if payload is None:
        return float(mass), np.asarray(com, dtype=float)
    mp, cp = payload
    m = mass + mp
    return float(m), (mass * np.asarray(com) + mp * np.asarray(cp)) / m


# ==================================================================================================
# the independent F/T calibration (static logs)
# ==================================================================================================
class Calibration(NamedTuple):
    """The classic F/T calibration of a static log (tool_on_sensor, SI)."""

    R_fs: np.ndarray  # (3, 3) sensor axes in the flange
    mass_kg: float
    com_s_m: np.ndarray  # (3,) in the (fitted) sensor frame
    offset: np.ndarray  # (6,) [N, N m]
    residual_rms: np.ndarray  # (6,) [N, N m] per channel


def _calib_model(x: np.ndarray, R0: np.ndarray, g_f: np.ndarray) -> np.ndarray:
    """x = (dtheta (3) [rad] right-perturbation of R0, m, c (3), b (6)) -> wrench (N, 6)."""
    R = R0 @ rotvec_matrix(x[:3])
    F = x[3] * g_f @ R  # rows: m R^T g_f
    return np.hstack([F + x[7:10], np.cross(x[4:7], F) + x[10:13]])


def calibrate(R_wf: np.ndarray, wrench: np.ndarray, g_mps2: float) -> Calibration:
    """Fit ``F = m R_fs^T R_wf^T g + b_F``, ``M = c x (F - b_F) + b_M`` to a static log.

    1. linear least squares ``F = K g_f + b_F`` (K = m R_fs^T, 12 unknowns); 2. the nearest rotation
    to K by SVD and ``m = tr(R_fs K) / 3``; 3. ``(c, b_M)`` linear in the moments; 4. Gauss-Newton
    (``scipy.optimize.least_squares``) on all 13 unknowns, force and moment residuals weighted by the
    RMS of the linear stages. R_wf (N, 3, 3), wrench (N, 6) [N, N m]."""
    N = len(wrench)
    g_f = np.einsum("nji,j->ni", R_wf, np.array([0.0, 0.0, -g_mps2]))  # (N, 3) gravity in f
    A = np.hstack([g_f, np.ones((N, 1))])  # (N, 4)
    X = np.linalg.lstsq(A, wrench[:, :3], rcond=None)[0]  # (4, 3): F^T = g_f^T K^T + b^T
    K = X[:3].T
    U, S, Vt = np.linalg.svd(K)
    Q = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt  # nearest rotation to K / m = R_fs^T
    R0, m0 = Q.T, float(np.trace(Q.T @ K)) / 3.0
    F0 = m0 * g_f @ R0
    Am = np.concatenate([-skew(F0), np.broadcast_to(np.eye(3), (N, 3, 3))], axis=2).reshape(3 * N, 6)
    y = np.linalg.lstsq(Am, wrench[:, 3:].reshape(-1), rcond=None)[0]  # (c, b_M)
    x0 = np.r_[0.0, 0.0, 0.0, m0, y[:3], X[3], y[3:]]
    r0 = wrench - _calib_model(x0, R0, g_f)
    scale = np.r_[[max(np.sqrt(np.mean(r0[:, :3] ** 2)), 1e-9)] * 3, [max(np.sqrt(np.mean(r0[:, 3:] ** 2)), 1e-12)] * 3]
    sol = least_squares(lambda x: ((wrench - _calib_model(x, R0, g_f)) / scale).ravel(), x0, method="lm",
                        xtol=1e-15, ftol=1e-15, gtol=1e-15)
    x = sol.x
    res = wrench - _calib_model(x, R0, g_f)
    return Calibration(R0 @ rotvec_matrix(x[:3]), float(x[3]), x[4:7].copy(), x[7:13].copy(),
                       np.sqrt(np.mean(res**2, axis=0)))


# ==================================================================================================
# a case's signals
# ==================================================================================================
TORQUE_PER_NM = {"N m": 1.0, "N mm": 1000.0}  # log units per N m
FORCE_PER_N = {"N": 1.0, "lbf": 1.0 / 4.4482216152605}  # log units per N (1 lbf = 4.448... N)


def _mount(case: Case, rig: Rig) -> tuple[np.ndarray, np.ndarray]:
    """(true mount R_fs, declared R_fs); the true mount excludes the small hidden rotation."""
    true = rpy_matrix_deg(case.mount_rpy_deg if case.mount_rpy_deg is not None else rig.sensor_rpy_f_deg)
    decl = rpy_matrix_deg(case.declared_rpy_deg) if case.declared_rpy_deg is not None else true
    return true, decl


def _hidden_rotation(case: Case) -> np.ndarray:
    return rotvec_matrix(np.deg2rad(case.rotvec_deg)) if case.rotvec_deg is not None else np.eye(3)


def _rotate_rows(w: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Row-wise R^T w for each 3-block of (N, 6)."""
    return np.hstack([w[:, :3] @ R, w[:, 3:] @ R])


def sample_poses(arm: Arm, n_poses: int, R_fs: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(n_poses, n) random joint configurations: links above z = 0.05 m, the flange at least
    ``arm.min_radius_m`` off the base axis and 0.15 m up; redrawn until gravity comes within
    ``COVERAGE_DEG`` of each of the six sensor half-axes."""
    lo, hi = np.asarray(arm.sample_lo_rad), np.asarray(arm.sample_hi_rad)
    for _ in range(50):
        out = []
        while len(out) < n_poses:
            q = rng.uniform(lo, hi, size=(4 * n_poses, arm.n))
            T = frames(arm, q)
            p = T[:, 2:, :3, 3]
            ok = (p[:, :, 2].min(axis=1) > 0.05) & (T[:, -1, 2, 3] > 0.15)
            ok &= np.linalg.norm(T[:, -1, :2, 3], axis=1) > arm.min_radius_m
            out += list(q[ok])
        q = np.array(out[:n_poses])
        if gravity_coverage_deg(frames(arm, q)[:, -1, :3, :3] @ R_fs) <= COVERAGE_DEG:
            return q
    raise RuntimeError("could not draw poses that turn gravity through every sensor direction")


def gravity_coverage_deg(R_ws: np.ndarray) -> float:
    """Largest, over the six sensor half-axes, of the smallest angle [deg] between it and gravity."""
    g_s = R_ws[:, 2, :] * -1.0  # (N, 3) unit gravity direction in s (rows of R_ws^T (0, 0, -1))
    cos_best = np.concatenate([g_s, -g_s], axis=1).max(axis=0)
    return float(np.degrees(np.arccos(np.clip(cos_best.min(), -1.0, 1.0))))


def _arm_id(arm: Arm) -> int:
    return list(ARMS).index(arm.name)


def static_signals(arm: Arm, name: str, seed: int = 0, noise: bool = True) -> dict[str, np.ndarray]:
    """A static case's samples: ``q_true``, ``q`` (logged, rad) (N, n), ``wrench`` (N, 6) the logged
    tool-on-sensor wrench in SI (before the torque-unit conversion), ``w_true`` (N, 6) the tool's
    weight in the declared-mount axes (no rotation, offset or noise). Poses depend on the seed and the
    true mount only; the noise draws are the same for every case of a seed."""
    case, rig = static_cases(arm.name)[name], STATIC_RIGS[arm.name]
    R_true, _ = _mount(case, rig)
    R_hid = _hidden_rotation(case)
    q_pose = sample_poses(arm, rig.n_poses, R_true, np.random.default_rng((seed, _arm_id(arm), 1)))
    q_true = np.repeat(q_pose, rig.samples_per_pose, axis=0)
    R_ws = frames(arm, q_true)[:, -1, :3, :3] @ R_true
    mass, com = combined_tool(rig.tool_mass_kg, rig.tool_com_s_m, case.payload)
    w_true = tool_wrench(mass, com, rig.tool_inertia_com_kg_m2, np.array([0.0, 0.0, -case.gravity_mps2]),
                         at_rest(R_ws))
    w = _rotate_rows(w_true, R_hid) + np.asarray(rig.offset)
    q = q_true.copy()
    for j, off in case.encoder_offset_deg.items():
        q[:, j - 1] -= math.radians(off)
    if noise:
        rng = np.random.default_rng((seed, _arm_id(arm), 2))
        q += rng.normal(0.0, SIGMA_Q_RAD, q.shape)
        w = w + rng.normal(0.0, 1.0, w.shape) * np.array([SIGMA_FORCE_N] * 3 + [SIGMA_TORQUE_NM] * 3)
    return {"q_true": q_true, "q": q, "wrench": w, "w_true": w_true}


def moving_signals(name: str, seed: int = 0, noise: bool = True) -> dict[str, np.ndarray]:
    """A moving (ur5e) case's samples: ``t`` (N,) [s], ``q`` (N, 6) logged [rad], ``qdot`` (N, 6)
    [rad/s], ``wrench`` (N, 6) logged tool-on-sensor [N, N m], ``w_true`` (N, 6) the noiseless
    Newton-Euler wrench (tool + payload) in the declared axes."""
    case, rig = MOVING_CASES[name], MOVING_RIG
    traj, t, _ = moving_trajectory()
    T_fs = homogeneous(rpy_matrix_deg(rig.sensor_rpy_f_deg), rig.sensor_pos_f_m)
    mo = sensor_motion(UR5E, traj, t, T_fs)
    g_w = np.array([0.0, 0.0, -case.gravity_mps2])
    w_true = tool_wrench(rig.tool_mass_kg, rig.tool_com_s_m, rig.tool_inertia_com_kg_m2, g_w, mo)
    if case.payload is not None:
        w_true = w_true + tool_wrench(case.payload[0], case.payload[1], (0.0,) * 6, g_w, mo)
    w = _rotate_rows(w_true, _hidden_rotation(case)) + np.asarray(rig.offset)
    if case.drift is not None:
        w = w + (t - t[0])[:, None] * np.asarray(case.drift)
    q, qd, _ = traj.eval(t)
    for j, off in case.encoder_offset_deg.items():
        q[:, j - 1] -= math.radians(off)
    if noise:
        rng = np.random.default_rng((seed, 0, 3))
        q += rng.normal(0.0, SIGMA_Q_RAD, q.shape)
        qd = qd + rng.normal(0.0, SIGMA_QDOT_RAD_S, qd.shape)
        w = w + rng.normal(0.0, 1.0, w.shape) * np.array([SIGMA_FORCE_N] * 3 + [SIGMA_TORQUE_NM] * 3)
    return {"t": t, "q": q, "qdot": qd, "wrench": w, "w_true": w_true}


# ==================================================================================================
# files: log.csv, setup.toml, truth.json
# ==================================================================================================
def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (int, float, np.floating)):
        return repr(float(v))
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {_toml_value(x)}" for k, x in v.items()) + " }"
    return "[" + ", ".join(_toml_value(x) for x in v) + "]"


def _toml(sections: dict[str, dict], comment: str) -> str:
    lines = [f"# {ln}" for ln in comment.splitlines()] + [""]
    for sec, kv in sections.items():
        lines.append(f"[{sec}]")
        lines += [f"{k} = {_toml_value(v)}" for k, v in kv.items()]
        lines.append("")
    return "\n".join(lines)


def _arm_section(arm: Arm, case: Case) -> dict:
    if case.arm_file == "urdf":
        sec: dict = {"urdf": str(UR5E_URDF)}
        if UR5E_URDF.is_file():  # declare the flange so that it is the DH flange: last link * F^-1
            m = urdf_match(UR5E_URDF, arm)
            Finv = np.linalg.inv(m.F)
            if np.abs(Finv - np.eye(4)).max() > 1e-9:
                sec.update({"flange_link": m.last_link, "flange_xyz_m": [round(float(x), 9) for x in Finv[:3, 3]],
                            "flange_rpy_deg": [round(float(x), 9) for x in matrix_rpy_deg(Finv[:3, :3])]})
        return sec
    return {"dh": {"convention": arm.convention, "a_m": arm.a_m, "d_m": arm.d_m, "alpha_rad": arm.alpha_rad}}


def setup_toml(arm: Arm, name: str) -> str:
    """The setup a user of this rig would write for case ``name`` (its declared, nominal set-up)."""
    case = cases(arm.name)[name]
    moving = name in MOVING_CASES
    rig = MOVING_RIG if moving else STATIC_RIGS[arm.name]
    _, R_decl = _mount(case, rig)
    if moving:
        log = {"time": MOVING_TIME_COL, "time_scale_s": 1.0, "q": rig.q_cols, "qdot": MOVING_QDOT_COLS}
    else:
        log = {"time": "", "static": True, "q": rig.q_cols}
    log.update({"angle_unit": rig.angle_unit, "wrench": rig.wrench_cols,
                "force_unit": case.declared_force_unit or case.force_unit,
                "torque_unit": case.declared_torque_unit or case.torque_unit, "wrench_acts": "tool_on_sensor",
                "tared": True})
    decl_rpy = case.declared_rpy_deg if case.declared_rpy_deg is not None else (
        case.mount_rpy_deg if case.mount_rpy_deg is not None else rig.sensor_rpy_f_deg)
    sections = {
        "log": log,
        "sensor": {"position_flange_m": rig.sensor_pos_f_m, "rpy_flange_deg": decl_rpy,
                   "mount_known": case.mount_known},
        "tool": {"mass_kg": round(rig.tool_mass_kg * case.mass_guess, 4), "com_sensor_m": rig.tool_com_s_m,
                 "inertia_com_kg_m2": rig.tool_inertia_com_kg_m2, "tip_sensor_m": rig.tool_tip_s_m},
        "arm": _arm_section(arm, case),
        "world": {"gravity_mps2": case.gravity_mps2},
        "contact": {"mode": "none"},
    }
    what = "a moving free-space log" if moving else "a static F/T-calibration log (one pose at rest per row)"
    return _toml(sections, f"Calibration rig (examples/calibration_rig.py), {arm.name}, case {name}: {what}.\n"
                           "The declared (nominal) set-up; the sensor has an offset, hence tared = true.")


def _write_csv(path: Path, cols: list[str], blocks: list[np.ndarray], fmts: list[str]) -> None:
    buf = io.StringIO()
    np.savetxt(buf, np.hstack(blocks), fmt=fmts, delimiter=",", header=",".join(cols), comments="")
    path.write_text(buf.getvalue())


def _write_static_log(path: Path, arm: Arm, case: Case, sig: dict) -> None:
    rig = STATIC_RIGS[arm.name]
    deg = rig.angle_unit == "deg"
    q = np.rad2deg(sig["q"]) if deg else sig["q"]
    w = sig["wrench"] * np.array([FORCE_PER_N[case.force_unit]] * 3 + [TORQUE_PER_NM[case.torque_unit]] * 3)
    tfmt = "%.3f" if case.torque_unit == "N mm" else "%.6f"
    _write_csv(path, [*rig.q_cols, *rig.wrench_cols], [q, w], ["%.7f" if deg else "%.9f"] * arm.n + ["%.5f"] * 3
               + [tfmt] * 3)


def _write_moving_log(path: Path, sig: dict) -> None:
    rig = MOVING_RIG
    _write_csv(path, [MOVING_TIME_COL, *rig.q_cols, *MOVING_QDOT_COLS, *rig.wrench_cols],
               [sig["t"][:, None], sig["q"], sig["qdot"], sig["wrench"]], ["%.4f"] + ["%.9f"] * 6 + ["%.6f"] * 6
               + ["%.5f"] * 3 + ["%.6f"] * 3)


def _effects_truth(case: Case, rig: Rig) -> dict[str, dict[str, float]]:
    """The hidden effects in the diagnosis's reporting units (module docstring)."""
    eff: dict[str, dict[str, float]] = {}
    payload = case.payload
    if case.mass_guess != 1.0:  # a wrong declared mass is an undeclared (possibly negative) mass at the tool's COM
        payload = (rig.tool_mass_kg * (1.0 - case.mass_guess), rig.tool_com_s_m)
    if payload is not None:
        eff["tool_gravity"] = {"mass": round(payload[0], 9), **dict(zip(("com_x", "com_y", "com_z"), payload[1]))}
    if case.rotvec_deg is not None:
        eff["ft_frame_rotation"] = dict(zip(("rot_x", "rot_y", "rot_z"), case.rotvec_deg))
    if case.drift is not None:
        eff["ft_bias_drift"] = dict(zip(("rate_fx", "rate_fy", "rate_fz", "rate_tx", "rate_ty", "rate_tz"), case.drift))
    if case.encoder_offset_deg:
        eff["encoder_offset"] = {f"offset_joint{j}": v for j, v in sorted(case.encoder_offset_deg.items())}
    return eff


def _calibration_truth(arm: Arm, case: Case) -> dict:
    """What a perfect calibration of the static log would find (the true mount incl. the hidden
    rotation, the total mass, the COM in the true sensor axes, the offset)."""
    rig = STATIC_RIGS[arm.name]
    R_true, _ = _mount(case, rig)
    R_hid = _hidden_rotation(case)
    mass, com = combined_tool(rig.tool_mass_kg, rig.tool_com_s_m, case.payload)
    return {"rpy_flange_deg": matrix_rpy_deg(R_true @ R_hid).tolist(), "tool_mass_kg": mass,
            "tool_com_sensor_m": (R_hid.T @ com).tolist(), "offset": list(rig.offset)}


def _calibration_block(arm: Arm, case: Case, sig: dict) -> dict:
    cal = calibrate(frames(arm, sig["q"])[:, -1, :3, :3], sig["wrench"], case.gravity_mps2)
    truth = _calibration_truth(arm, case)
    est = {"rpy_flange_deg": matrix_rpy_deg(cal.R_fs).tolist(), "tool_mass_kg": cal.mass_kg,
           "tool_com_sensor_m": cal.com_s_m.tolist(), "offset": cal.offset.tolist(),
           "residual_rms": cal.residual_rms.tolist()}
    err = {"rotation_deg": rotation_angle_deg(rpy_matrix_deg(truth["rpy_flange_deg"]).T @ cal.R_fs),
           "mass_pct": 100.0 * (cal.mass_kg - truth["tool_mass_kg"]) / truth["tool_mass_kg"],
           "com_mm": 1000.0 * float(np.linalg.norm(cal.com_s_m - truth["tool_com_sensor_m"])),
           "offset_force_N": float(np.linalg.norm(cal.offset[:3] - truth["offset"][:3])),
           "offset_moment_Nm": float(np.linalg.norm(cal.offset[3:] - truth["offset"][3:]))}
    return {"method": "linear LS F = K g_f + b, nearest rotation by SVD, (c, b_M) linear, then "
                      "Levenberg-Marquardt on (rotation, m, c, b_F, b_M); SI units, tool_on_sensor, "
                      "from the logged (noisy, possibly offset) encoders",
            "estimate": est, "truth": truth, "error": err}


def _mount_truth(case: Case, rig: Rig) -> dict:
    R_true, R_decl = _mount(case, rig)
    R_eff = R_true @ _hidden_rotation(case)
    angle = rotation_angle_deg(R_decl.T @ R_eff)
    return {"declared_rpy_flange_deg": matrix_rpy_deg(R_decl).tolist(), "mount_known": case.mount_known,
            "true_rpy_flange_deg": matrix_rpy_deg(R_eff).tolist(), "rotation_from_declared_deg": angle,
            # unknown mount: no claim to check; a known one is consistent unless it is far off
            "declared_consistent": None if not case.mount_known else bool(angle < 15.0)}


def payload_inertia_truth(mass: float, com) -> dict[str, float]:
    """The point-mass payload's inertia about the sensor origin, ``m (|c|^2 1 - c c^T)`` [kg m^2], as the six
    entries ``dI_xx, dI_yy, dI_zz, dI_xy, dI_xz, dI_yz`` (the ten-parameter payload's inertia part)."""
    c = np.asarray(com, dtype=float)
    I = mass * (float(c @ c) * np.eye(3) - np.outer(c, c))
    return {"dI_xx": float(I[0, 0]), "dI_yy": float(I[1, 1]), "dI_zz": float(I[2, 2]), "dI_xy": float(I[0, 1]),
            "dI_xz": float(I[0, 2]), "dI_yz": float(I[1, 2])}


def truth_dict(arm: Arm, name: str, seed: int, sig: dict) -> dict:
    case = cases(arm.name)[name]
    moving = name in MOVING_CASES
    rig = MOVING_RIG if moving else STATIC_RIGS[arm.name]
    eff = _effects_truth(case, rig)
    expected = {k: ["present"] if case.detectable else ["absent", "cannot_decide"] for k in eff}
    if moving and case.payload is not None:  # a moving payload's second moment: seen where the motion turns it
        eff["tool_inertia"] = payload_inertia_truth(*case.payload)
        expected["tool_inertia"] = ["present", "cannot_decide"]
    if case.ties and case.detectable:
        expected["encoder_offset"] = ["present", "cannot_decide"]
    if case.mount_known and _mount_truth(case, rig)["declared_consistent"] is False:
        # a declared mount the data contradict beyond first order: no effect may be judged present
        expected = {k: ["cannot_decide"] for k in eff}
    mass, com = combined_tool(rig.tool_mass_kg, rig.tool_com_s_m, case.payload)
    truth = {
        "case": name, "arm": arm.name, "kind": "moving" if moving else "static", "description": case.description,
        "effects": eff, "expected_verdicts": expected, "detectable": case.detectable,
        "seed": int(seed), "gravity_mps2": case.gravity_mps2, "tared": True,
        "units": {"force_unit_logged": case.force_unit,
                  "force_unit_declared": case.declared_force_unit or case.force_unit,
                  "likely_force_unit": case.force_unit, "torque_unit_logged": case.torque_unit,
                  "torque_unit_declared": case.declared_torque_unit or case.torque_unit,
                  "likely_torque_unit": case.torque_unit},
        "sensor_mount": _mount_truth(case, rig),
        "tool": {"declared_mass_kg": round(rig.tool_mass_kg * case.mass_guess, 4), "true_mass_kg": mass,
                 "true_com_sensor_m": com.tolist()},
        "offset_tool_on_sensor": list(rig.offset),  # [N, N m], constant
        "arm_model": "urdf" if case.arm_file == "urdf" else f"dh ({arm.convention})",
    }
    if case.ties:
        truth["indistinguishable_from"] = {"encoder_offset": [f"encoder_offset:offset_joint{j}" for j in case.ties]}
    if moving:
        _, t, holds = moving_trajectory()
        truth["experiment"] = {"rate_hz": RATE_HZ, "n_samples": len(t), "duration_s": float(t[-1]),
                               "hold_windows_s": [list(h) for h in holds], "contact": "none",
                               "max_tilt_deg": float(max(tilt_deg(h) for h in range(len(_MOVES))))}
    else:
        r = STATIC_RIGS[arm.name]
        R_true, _ = _mount(case, rig)
        truth["experiment"] = {"n_poses": r.n_poses, "samples_per_pose": r.samples_per_pose,
                               "gravity_coverage_deg": gravity_coverage_deg(
                                   frames(arm, sig["q_true"])[:, -1, :3, :3] @ R_true)}
        truth["calibration"] = _calibration_block(arm, case, sig)
    return truth


def tilt_deg(k: int) -> float:
    """Tilt [deg] of the sensor z axis at hold k (after move k) from its direction at home."""
    home = np.asarray(MOVING_Q_HOME)
    R = frames(UR5E, np.stack([home, home + np.asarray(_MOVES[k][0])]))[:, -1, :3, :3]
    return math.degrees(math.acos(float(np.clip(R[0][:, 2] @ R[1][:, 2], -1, 1))))


def make_case(arm_name: str, name: str, out_dir: Path, seed: int = 0) -> Path:
    """Write case ``name`` of ``arm_name`` into ``out_dir/arm_name/name/`` (log.csv, setup.toml,
    truth.json) and return that folder."""
    arm = ARMS[arm_name]
    table = cases(arm_name)
    if name not in table:
        raise KeyError(f"arm {arm_name} has no case '{name}' (choose from {', '.join(table)})")
    d = Path(out_dir) / arm_name / name
    d.mkdir(parents=True, exist_ok=True)
    if name in MOVING_CASES:
        sig = moving_signals(name, seed)
        _write_moving_log(d / "log.csv", sig)
    else:
        sig = static_signals(arm, name, seed)
        _write_static_log(d / "log.csv", arm, table[name], sig)
    (d / "setup.toml").write_text(setup_toml(arm, name))
    (d / "truth.json").write_text(json.dumps(truth_dict(arm, name, seed, sig), indent=2) + "\n")
    return d


# ==================================================================================================
# self-test: the physics against independent computations
# ==================================================================================================
def _point_cloud(mass: float, com, inertia) -> tuple[np.ndarray, np.ndarray]:
    """Six equal point masses (6,), positions (6, 3) in s with the tool's mass, COM and inertia about
    the COM: pairs at +-d_i e_i along the principal axes, 2 (m/6) d_i^2 = (I_j + I_k - I_i) / 2."""
    ev, V = np.linalg.eigh(inertia_matrix(inertia))
    second = 0.5 * (ev.sum() - 2 * ev)  # second moments along the principal axes
    d = np.sqrt(second / (2 * mass / 6))
    pts = np.concatenate([V * d, -V * d], axis=1).T + np.asarray(com)  # (6, 3)
    return np.full(6, mass / 6), pts


def _check_fk(rng: np.random.Generator) -> dict[str, float]:
    q = {a.name: rng.uniform(-_PI, _PI, (200, a.n)) for a in ARMS.values()}
    err = 0.0
    for a in ARMS.values():
        R = frames(a, q[a.name])[:, :, :3, :3]
        err = max(err, float(np.abs(R.transpose(0, 1, 3, 2) @ R - np.eye(3)).max()),
                  float(np.abs(np.linalg.det(R) - 1).max()))
    # closed forms at q = 0: ur5e flange at (a2 + a3, -(d4 + d6), d1 - d5), iiwa straight up
    p_ur = frames(UR5E, np.zeros((1, 6)))[0, -1, :3, 3]
    p_iiwa = frames(IIWA14, np.zeros((1, 7)))[0, -1, :3, 3]
    zero = max(float(np.abs(p_ur - [-0.425 - 0.3922, -(0.1333 + 0.0996), 0.1625 - 0.0997]).max()),
               float(np.abs(p_iiwa - [0.0, 0.0, 1.306]).max()))
    out = {"fk_orthonormal": err, "fk_zero_pose_m": zero}
    if UR5E_URDF.is_file():  # the shipped URDF against the DH table
        out["urdf_vs_dh_flange"] = urdf_match(UR5E_URDF, UR5E).error
    return out


def _check_motion() -> dict[str, float]:
    """Numerical sensor velocities/accelerations against the analytic Jacobian and recursion, for
    the ur5e experiment and a sinusoidal iiwa motion."""
    traj, t, _ = moving_trajectory()
    iiwa_traj = Trajectory((Segment(0.0, 10.0, _sine(np.linspace(-0.5, 0.6, 7), np.linspace(0.4, 0.8, 7))),))
    T_fs = homogeneous(rpy_matrix_deg((12.0, -7.0, 220.0)), (0.01, -0.02, 0.03))
    ev, ea = 0.0, 0.0
    for arm, tr, ts in ((UR5E, traj, t[::25]), (IIWA14, iiwa_traj, np.linspace(0.0, 6.0, 120))):
        mo = sensor_motion(arm, tr, ts, T_fs)
        q, qd, qdd = tr.eval(ts)
        J = jacobian(arm, q, mo.p_ws_m)
        v = np.einsum("nij,nj->ni", J, qd)
        ev = max(ev, float(np.abs(v - np.hstack([mo.v_w, mo.omega_w])).max()))
        acc, alpha = point_acceleration(arm, q, qd, qdd, mo.p_ws_m)
        ea = max(ea, float(np.abs(np.hstack([acc, alpha]) - np.hstack([mo.a_w, mo.alpha_w])).max()))
    return {"velocity_vs_jacobian": ev, "acceleration_vs_recursion": ea}


def _sine(amp: np.ndarray, freq_hz: np.ndarray) -> Callable:
    q0 = np.linspace(0.3, -0.3, len(amp))

    def fn(t):
        w = 2 * _PI * freq_hz
        s = np.sin(np.outer(t, w) + 0.3)
        return q0 + amp * s, amp * w * np.cos(np.outer(t, w) + 0.3), -amp * w**2 * s

    return fn


def _check_wrench() -> dict[str, float]:
    rig = MOVING_RIG
    traj, t, holds = moving_trajectory()
    T_fs = homogeneous(rpy_matrix_deg(rig.sensor_rpy_f_deg), rig.sensor_pos_f_m)
    g_w = np.array([0.0, 0.0, -G_STD])
    m, c, I = rig.tool_mass_kg, np.asarray(rig.tool_com_s_m), rig.tool_inertia_com_kg_m2
    ts = t[::10]
    mo = sensor_motion(UR5E, traj, ts, T_fs)
    w = tool_wrench(m, c, I, g_w, mo)
    # (1) statics: |F| = m g, M = c x F, R_ws F = m g_w
    ws = tool_wrench(m, c, I, g_w, at_rest(mo.R_ws))
    stat = max(float(np.abs(np.linalg.norm(ws[:, :3], axis=1) - m * G_STD).max()),
               float(np.abs(ws[:, 3:] - np.cross(c, ws[:, :3])).max()),
               float(np.abs(np.einsum("nij,nj->ni", mo.R_ws, ws[:, :3]) - m * g_w).max()))
    # (2) Newton-Euler at the holds = the static wrench
    inside = np.zeros(len(ts), bool)
    for a, b in holds:
        inside |= (ts > a + 0.01) & (ts < b - 0.01)
    hold = float(np.abs(w[inside] - ws[inside]).max())
    # (3) Newton-Euler vs six point masses moved by the numerical pose (no omega/alpha formulas)
    mk, pk = _point_cloud(m, c, I)
    T = stencil_poses(UR5E, traj, ts, T_fs)
    P = T[:, :, None, :3, :3] @ pk[None, None, :, :, None]
    P = P[..., 0] + T[:, :, None, :3, 3]  # (5, N, 6, 3) world positions of the points
    acc = _d2(P, STENCIL_H_S)  # (N, 6, 3)
    f_k = mk[None, :, None] * (g_w - acc)  # force of each point on the sensor, world
    r_k = P[2] - mo.p_ws_m[:, None, :]
    Rt = mo.R_ws.transpose(0, 2, 1)
    w_pts = np.hstack([np.einsum("nij,nj->ni", Rt, f_k.sum(1)), np.einsum("nij,nj->ni", Rt, np.cross(r_k, f_k).sum(1))])
    return {"static_weight": stat, "newton_euler_at_hold": hold, "newton_euler_vs_point_masses":
            float(np.abs(w - w_pts).max()), "max_inertial_force_N": float(np.abs(w[:, :3] - ws[:, :3]).max())}


def _check_calibration() -> dict[str, float]:
    """The calibration recovers a noiseless general mount exactly."""
    out = 0.0
    for arm in ARMS.values():
        case = static_cases(arm.name)["mount_unknown_general"]
        sig = static_signals(arm, "mount_unknown_general", seed=5, noise=False)
        cal = calibrate(frames(arm, sig["q"])[:, -1, :3, :3], sig["wrench"], case.gravity_mps2)
        tr = _calibration_truth(arm, case)
        out = max(out, rotation_angle_deg(rpy_matrix_deg(tr["rpy_flange_deg"]).T @ cal.R_fs),
                  abs(cal.mass_kg - tr["tool_mass_kg"]), float(np.abs(cal.com_s_m - tr["tool_com_sensor_m"]).max()),
                  float(np.abs(cal.offset - tr["offset"]).max()))
    return {"calibration_noiseless": out}


def _check_limits() -> dict[str, float]:
    traj, t, _ = moving_trajectory()
    _, qd, qdd = traj.eval(t)
    tilts = [tilt_deg(k) for k in range(len(_MOVES) - 1)]
    return {"qdot_over_limit": float((np.abs(qd) / np.asarray(UR5E.qdot_limit_rad_s)).max()),
            "tilt_min_deg": min(tilts), "tilt_max_deg": max(tilts), "qdd_max_rad_s2": float(np.abs(qdd).max())}


SELF_TEST_TOL = {"fk_orthonormal": 1e-12, "fk_zero_pose_m": 1e-12, "urdf_vs_dh_flange": 1e-9,
                 "velocity_vs_jacobian": 1e-7, "acceleration_vs_recursion": 1e-6, "static_weight": 1e-12,
                 "newton_euler_at_hold": 1e-12, "newton_euler_vs_point_masses": 1e-6, "calibration_noiseless": 1e-7}


def self_test(seed: int = 0) -> dict[str, float]:
    """The physics against independent computations (module docstring); returns the max errors
    (and a few magnitudes); raises AssertionError beyond ``SELF_TEST_TOL`` or outside the limits."""
    rng = np.random.default_rng(seed)
    err = {**_check_fk(rng), **_check_motion(), **_check_wrench(), **_check_calibration(), **_check_limits()}
    bad = {k: v for k, v in err.items() if k in SELF_TEST_TOL and not v <= SELF_TEST_TOL[k]}
    if err["qdot_over_limit"] >= 1.0 or not 20.0 <= err["tilt_min_deg"] <= err["tilt_max_deg"] <= 40.0:
        bad["trajectory"] = err["qdot_over_limit"]
    if bad:
        raise AssertionError(f"calibration-rig self-test failed: {bad}")
    return err


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description="Write F/T-calibration test logs (ur5e, iiwa14) for `kinadapt diagnose`.")
    p.add_argument("--out", type=Path, help="output folder (DIR/<arm>/<case>/)")
    p.add_argument("--arm", default="all", choices=[*ARMS, "all"], help="which arm (default: all)")
    p.add_argument("--case", nargs="+", default=None, help="cases (default: all of each arm's)")
    p.add_argument("--seed", type=int, default=0, help="noise and pose seed")
    p.add_argument("--self-test", action="store_true", help="check the physics against independent computations")
    a = p.parse_args(argv)
    if a.out is None and not a.self_test:
        p.error("give --out DIR (or --self-test)")
    arms = list(ARMS) if a.arm == "all" else [a.arm]
    known = set().union(*map(cases, arms))
    unknown = [n for n in (a.case or []) if n not in known]
    if unknown:
        p.error(f"no case {', '.join(unknown)} for {a.arm} (choose from {', '.join(sorted(known))})")
    if a.self_test:
        t0 = time.perf_counter()
        err = self_test()
        print(f"self-test passed ({time.perf_counter() - t0:.1f} s); max errors (tolerance) and magnitudes:")
        for k, v in err.items():
            print(f"  {k:30s} {v:.2e}" + (f"  (< {SELF_TEST_TOL[k]:.0e})" if k in SELF_TEST_TOL else ""))
    if a.out is None:
        return 0
    for arm in arms:
        for name in [n for n in (a.case or cases(arm)) if n in cases(arm)]:
            t0 = time.perf_counter()
            d = make_case(arm, name, a.out, a.seed)
            print(f"{d}: {', '.join(sorted(x.name for x in d.iterdir()))} ({time.perf_counter() - t0:.2f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
