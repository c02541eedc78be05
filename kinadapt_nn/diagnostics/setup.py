"""The setup file: what a user knows about *their* robot, sensor, tool and log (TOML).

``kinadapt diagnose LOG --setup SETUP.toml`` judges the log against the physical nominal model
this file declares (``kinadapt_nn.diagnostics.physical``): the declared tool's rigid-body wrench
(gravity and inertia from the encoders) in free space, and "contacts act through the declared
tip" in contact. Nothing here comes from this package's simulator. Validated like every config
(frozen pydantic models, ``extra="forbid"``: an unknown key, a wrong type or an out-of-range value
is a one-line ``ConfigError``), and written beside the result (``setup.toml``).

Frames. ``f`` the flange frame of the arm model (``arm.flange_site``), ``s`` the F/T sensor frame
(``sensor.position_flange_m``, ``sensor.rpy_flange_deg``: origin in ``f`` and the rotation
``R_fs = Rz(yaw) Ry(pitch) Rx(roll)``, roll/pitch/yaw about the flange's fixed x, y, z axes). The
tool is everything distal of the sensor, described in ``s``. Template (every key shown with its
default; ``examples/setups/`` has complete ones)::

    [log]
    time = "t"                 # column names in the user's file (ROS 2 bag: see the topics); "" = none (static logs only;
                               # a static log without a column "t" may leave time out)
    time_scale_s = 1.0         # seconds per unit of the time column (1e-9 for nanosecond stamps)
    static = false             # true: each row is a pose at rest (F/T calibration); time and qdot optional
    q = ["q1", "q2", "q3", "q4", "q5", "q6", "q7"]   # one name per arm joint (any number)
    qdot = []                  # optional: one name per joint; empty = differentiate q (zero for a static log)
    angle_unit = "rad"         # or "deg" (q and qdot)
    wrench = ["fx", "fy", "fz", "tx", "ty", "tz"]   # sensor frame, about its origin
    force_unit = "N"           # or "kN", "mN", "lbf", "kgf" (a unit the data do not fit is named)
    torque_unit = "N m"        # or "N mm", "N cm", "lbf in", "lbf ft"
    wrench_acts = "tool_on_sensor"                  # or "sensor_on_tool"
    tared = false              # true: zeroed at an unknown pose (offset estimated jointly)
    extra = []                 # extra columns your effects or the hints may use (e.g. ["temp_C"]; bag: "TOPIC:FIELD")
    joint_state_topic = "/joint_states"             # ROS 2 bags: sensor_msgs/JointState
    wrench_topic = "/ft_sensor/wrench"              # ROS 2 bags: geometry_msgs/WrenchStamped
    [sensor]
    position_flange_m = [0.0, 0.0, 0.0]
    rpy_flange_deg = [0.0, 0.0, 0.0]
    mount_known = true         # false: the mount's rotation is estimated (any angle); rpy_flange_deg is a first guess
    range_force_N = 0.0        # the sensor's rated force range (0 = not declared)
    range_torque_Nm = 0.0      # the sensor's rated torque range (0 = not declared)
    [tool]
    mass_kg = 0.0
    com_sensor_m = [0.0, 0.0, 0.0]
    inertia_com_kg_m2 = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0]   # ixx, iyy, izz, ixy, ixz, iyz about the COM, s axes
    tip_sensor_m = [0.0, 0.0, 0.0]
    tip_known = true           # false: tip_sensor_m is a first guess; where the contact wrench pins a point, it is the tip
    tip_within_m = 0.03        # tip_known = false: how far from the guess the tip can be [m]
    [arm]                      # one of mjcf / urdf / dh ("" and no dh = the shipped Panda)
    mjcf = ""                  # a MuJoCo MJCF file
    flange_site = "flange"     # MJCF: the site whose frame is the flange
    urdf = ""                  # a URDF file (meshes are not needed)
    flange_link = ""           # URDF: the link whose frame is the flange ("" = the link the last joint moves)
    flange_xyz_m = [0.0, 0.0, 0.0]     # URDF: flange origin in that link's frame
    flange_rpy_deg = [0.0, 0.0, 0.0]   # URDF: flange axes in that link's frame, Rz(yaw) Ry(pitch) Rx(roll)
    # dh = { convention = "modified", a_m = [...], d_m = [...], alpha_rad = [...], theta_offset_rad = [...],
    #        base_xyz_m = [0, 0, 0], base_rpy_deg = [0, 0, 0], flange_xyz_m = [0, 0, 0], flange_rpy_deg = [0, 0, 0] }
    [world]
    gravity_mps2 = 9.81        # magnitude; gravity points along -z of the arm's base/world frame
    [contact]
    mode = "tip"               # "tip": contacts act through the declared tip; "exclude": contact left out; "none": free-space log
    detect_force_N = 4.0       # a sample is in contact when the force beyond the tool model exceeds this
    margin_s = 0.1             # contact windows are widened by this on each side
    geometry = "none"          # "socket": a declared compliant contact (its effects are judged, see contact_model)
    entry_w_m = [0.0, 0.0, 0.0]          # socket: a point of its entrance plane, world [m]
    axis_w = [0.0, 0.0, -1.0]            # socket: its axis into the fixture, world (unit)
    zone = "none"              # "entrance": contact counted wherever the declared tip is below entry_w_m's plane (a bore)
    zone_m = 0.002             # "entrance": ... or within this above it [m]
    stiffness_lat_N_per_m = 0.0          # socket: lateral spring at the tip [N/m]
    stiffness_rot_Nm_per_rad = 0.0       # socket: angular spring [N m/rad]
    damping_lat_N_s_per_m = 0.0          # socket: lateral damper at the tip [N s/m] (0: none)
    damping_rot_Nm_s_per_rad = 0.0       # socket: angular damper [N m s/rad] (0: none)
    [analysis]
    exclude_s = []             # [[t0, t1], ...] windows left out [s from the first sample]
    effects = []               # only these effects (empty: all that apply)
    exclude_effects = []       # leave these out
    effects_files = []         # your own effect files (Python, see docs/missing_physics.md), like --effects
    relevant_force_N = 0.2     # a systematic force residual this large is "something the model does not contain"
    relevant_moment_Nm = 0.02  # the same for moments
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import Field, field_validator, model_validator

from kinadapt_nn.config import Vec3, Vec6, _Cfg, load_toml_model
from kinadapt_nn.errors import ConfigError

SETUP_EXAMPLE = "examples/setups/panda_flat_contact.toml"


def rpy_matrix(rpy_rad: np.ndarray) -> np.ndarray:
    """``Rz(yaw) Ry(pitch) Rx(roll)`` for ``rpy = (roll, pitch, yaw)`` [rad]. (3,) -> (3, 3)."""
    r, p, y = (float(a) for a in rpy_rad)
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def inertia_matrix(v) -> np.ndarray:
    """(ixx, iyy, izz, ixy, ixz, iyz) -> (3, 3) symmetric matrix."""
    ixx, iyy, izz, ixy, ixz, iyz = (float(x) for x in v)
    return np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])


def _finite(v, name: str):
    arr = np.atleast_1d(np.asarray(v, dtype=float))
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite")
    return v


#: SI value of one unit of the log's force / torque columns
FORCE_UNITS = {"N": 1.0, "kN": 1000.0, "mN": 1e-3, "lbf": 4.4482216152605, "kgf": 9.80665}
TORQUE_UNITS = {"N m": 1.0, "N mm": 1e-3, "N cm": 1e-2, "lbf in": 0.1129848290276167, "lbf ft": 1.3558179483314004}
MAX_JOINTS = 12


class LogCfg(_Cfg):
    """Where each quantity is in the user's file, and its conventions."""

    time: str = "t"  # column name of the time stamps ("" = none: static logs only; static, default, no such column: none)
    time_scale_s: float = Field(1.0, gt=0.0)  # [s per unit] of the time column
    static: bool = False  # each row is a pose at rest (no derivatives taken; time optional)
    q: tuple[str, ...] = ("q1", "q2", "q3", "q4", "q5", "q6", "q7")  # joint positions, one per arm joint
    qdot: tuple[str, ...] = ()  # joint velocities (one per joint) or empty: differentiate q
    angle_unit: Literal["rad", "deg"] = "rad"  # unit of q and qdot (per s)
    wrench: tuple[str, str, str, str, str, str] = ("fx", "fy", "fz", "tx", "ty", "tz")  # sensor frame
    force_unit: Literal["N", "kN", "mN", "lbf", "kgf"] = "N"  # unit of the three force columns
    torque_unit: Literal["N m", "N mm", "N cm", "lbf in", "lbf ft"] = "N m"  # unit of the three torque columns
    wrench_acts: Literal["tool_on_sensor", "sensor_on_tool"] = "tool_on_sensor"  # which body's wrench on which
    tared: bool = False  # true: zeroed at an unknown pose before/while logging
    extra: tuple[str, ...] = ()  # extra columns (temperature, a voltage ...) for effects and hints; bag: "TOPIC:FIELD"
    joint_state_topic: str = "/joint_states"  # ROS 2 bag: sensor_msgs/msg/JointState topic
    wrench_topic: str = "/ft_sensor/wrench"  # ROS 2 bag: geometry_msgs/msg/WrenchStamped topic

    @field_validator("q")
    @classmethod
    def _q_len(cls, v):
        if not 1 <= len(v) <= MAX_JOINTS:
            raise ValueError(f"give one joint-position column name per arm joint (1 to {MAX_JOINTS}; got {len(v)})")
        return v

    @field_validator("time_scale_s")
    @classmethod
    def _ts_finite(cls, v):
        return _finite(v, "time_scale_s")

    @model_validator(mode="after")
    def _distinct(self):
        if len(self.qdot) not in (0, len(self.q)):
            raise ValueError(f"give {len(self.q)} joint-velocity column names (one per q) or none (got {len(self.qdot)})")
        if not self.time and not self.static:
            raise ValueError("time = \"\" (no time column) needs static = true (a log of poses at rest); "
                             "a moving log needs its time column")
        # a ROS 2 bag names joints, not columns: there qdot may repeat q (velocities of the same joints)
        names = [*((self.time,) if self.time else ()), *self.q,
                 *(self.qdot if tuple(self.qdot) != tuple(self.q) else ()), *self.wrench, *self.extra]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"column '{dup[0]}' is named twice; every quantity needs its own column")
        return self

    @property
    def sign(self) -> float:
        """+1 when the log holds the wrench the tool exerts on the sensor, -1 for the reverse."""
        return 1.0 if self.wrench_acts == "tool_on_sensor" else -1.0

    def wrench_scale(self) -> np.ndarray:
        """(6,) SI value of one unit of each wrench column (log units -> N, N m)."""
        return np.array([FORCE_UNITS[self.force_unit]] * 3 + [TORQUE_UNITS[self.torque_unit]] * 3)


class SensorCfg(_Cfg):
    """The F/T sensor frame s in the flange frame f."""

    position_flange_m: Vec3 = (0.0, 0.0, 0.0)  # [m] origin of s in f
    rpy_flange_deg: Vec3 = (0.0, 0.0, 0.0)  # [deg] R_fs = Rz(yaw) Ry(pitch) Rx(roll) (fixed flange axes)
    mount_known: bool = True  # false: the rotation is estimated at any angle (rpy_flange_deg: the first guess)
    range_force_N: float = Field(0.0, ge=0.0)  # [N] rated force range (0 = not declared)
    range_torque_Nm: float = Field(0.0, ge=0.0)  # [N m] rated torque range (0 = not declared)

    @field_validator("position_flange_m", "rpy_flange_deg", "range_force_N", "range_torque_Nm")
    @classmethod
    def _fin(cls, v):
        return _finite(v, "the value")

    def R_fs(self) -> np.ndarray:
        """(3, 3) rotation of the sensor axes in the flange frame."""
        return rpy_matrix(np.deg2rad(np.asarray(self.rpy_flange_deg, dtype=float)))


class ToolDeclCfg(_Cfg):
    """The nominal tool: everything distal of the sensor, in the sensor frame s."""

    mass_kg: float = Field(0.0, ge=0.0)  # [kg]
    com_sensor_m: Vec3 = (0.0, 0.0, 0.0)  # [m] centre of mass in s
    inertia_com_kg_m2: Vec6 = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)  # [kg m^2] ixx, iyy, izz, ixy, ixz, iyz about the COM, s axes
    tip_sensor_m: Vec3 = (0.0, 0.0, 0.0)  # [m] the tip (where contacts act) in s
    #: false: ``tip_sensor_m`` is a first guess (a tool whose geometry is not known, e.g. the one the
    #: package's controller adapts): where the contact wrench pins a point, that point is the tip for
    #: the whole diagnosis and its offset from the guess is reported as a finding about the tool
    tip_known: bool = True
    #: [m] ``tip_known = false``: the tip lies within this of ``tip_sensor_m``; a contact point further
    #: away is not taken for it (e.g. a drifting sensor's free space read as contact)
    tip_within_m: float = Field(0.03, gt=0.0)

    @field_validator("mass_kg", "com_sensor_m", "inertia_com_kg_m2", "tip_sensor_m")
    @classmethod
    def _fin(cls, v):
        return _finite(v, "the value")

    @field_validator("inertia_com_kg_m2")
    @classmethod
    def _psd(cls, v):
        ev = np.linalg.eigvalsh(inertia_matrix(v))
        if ev.min() < -1e-12 * max(1.0, abs(ev).max()):
            raise ValueError("the inertia is not positive semi-definite (check the order ixx, iyy, izz, ixy, ixz, iyz)")
        return v

    def inertia(self) -> np.ndarray:
        """(3, 3) inertia about the COM in s axes [kg m^2]."""
        return inertia_matrix(self.inertia_com_kg_m2)

    def inertials(self) -> tuple[float, np.ndarray, np.ndarray]:
        """(m [kg], m c (3,) [kg m], I_O (3, 3) [kg m^2] about the sensor origin, s axes): the ten
        inertial parameters of the declared tool (parallel axes: ``I_O = I_c + m (|c|^2 1 - c c^T)``)."""
        m = float(self.mass_kg)
        c = np.asarray(self.com_sensor_m, dtype=float)
        return m, m * c, self.inertia() + m * (float(c @ c) * np.eye(3) - np.outer(c, c))


class DHCfg(_Cfg):
    """An arm from Denavit-Hartenberg parameters, one entry per joint (all revolute).

    ``classic``: ``T_{i-1,i} = Rz(theta_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``; ``modified`` (Craig):
    ``T_{i-1,i} = Rx(alpha_{i-1}) Tx(a_{i-1}) Rz(theta_i) Tz(d_i)`` with row i holding ``a_{i-1}``,
    ``alpha_{i-1}``, ``d_i``. ``theta_i = q_i + theta_offset_i``. The base frame sits at
    ``base_xyz_m``/``base_rpy_deg`` in the world (z up); the flange is ``flange_xyz_m``/``flange_rpy_deg``
    in the last joint's frame."""

    convention: Literal["modified", "classic"]
    a_m: tuple[float, ...]
    d_m: tuple[float, ...]
    alpha_rad: tuple[float, ...]
    theta_offset_rad: tuple[float, ...] = ()  # empty: all zero
    base_xyz_m: Vec3 = (0.0, 0.0, 0.0)
    base_rpy_deg: Vec3 = (0.0, 0.0, 0.0)
    flange_xyz_m: Vec3 = (0.0, 0.0, 0.0)
    flange_rpy_deg: Vec3 = (0.0, 0.0, 0.0)

    @model_validator(mode="after")
    def _lengths(self):
        n = len(self.a_m)
        if not 1 <= n <= MAX_JOINTS:
            raise ValueError(f"dh: give one a_m entry per joint (1 to {MAX_JOINTS}; got {n})")
        for key in ("d_m", "alpha_rad", "theta_offset_rad"):
            v = getattr(self, key)
            if key == "theta_offset_rad" and not v:
                continue
            if len(v) != n:
                raise ValueError(f"dh: {key} has {len(v)} entries, a_m has {n}; give one per joint")
        for key in ("a_m", "d_m", "alpha_rad", "theta_offset_rad", "base_xyz_m", "base_rpy_deg", "flange_xyz_m",
                    "flange_rpy_deg"):
            _finite(getattr(self, key) or (0.0,), f"dh: {key}")
        return self

    @property
    def n_joints(self) -> int:
        return len(self.a_m)

    def offsets(self) -> tuple[float, ...]:
        return tuple(self.theta_offset_rad) or (0.0,) * self.n_joints


class ArmDeclCfg(_Cfg):
    """The arm: one of an MJCF file, a URDF file or DH parameters (none: the shipped Panda)."""

    mjcf: str = ""  # arm model file; "" = the shipped Panda (models/panda.xml) unless urdf or dh is given
    flange_site: str = "flange"  # the MJCF site whose frame is the flange f
    urdf: str = ""  # a URDF file (MuJoCo reads it; meshes are not needed)
    flange_link: str = ""  # URDF: the link whose frame is the flange ("" = the last link of the joint chain)
    flange_xyz_m: Vec3 = (0.0, 0.0, 0.0)  # [m] URDF: flange origin in that link's frame
    flange_rpy_deg: Vec3 = (0.0, 0.0, 0.0)  # [deg] URDF: flange axes in that link's frame
    dh: DHCfg | None = None  # DH parameters (``DHCfg``)

    @field_validator("flange_xyz_m", "flange_rpy_deg")
    @classmethod
    def _fin(cls, v):
        return _finite(v, "the value")

    @model_validator(mode="after")
    def _one(self):
        given = [k for k in ("mjcf", "urdf") if getattr(self, k)] + (["dh"] if self.dh is not None else [])
        if len(given) > 1:
            raise ValueError(f"give one arm model, not {' and '.join(given)} (mjcf, urdf or dh)")
        return self

    @property
    def kind(self) -> str:
        """"mjcf", "urdf" or "dh"."""
        return "urdf" if self.urdf else "dh" if self.dh is not None else "mjcf"

    def path(self) -> Path:
        from kinadapt_nn.robot import PANDA_MJCF

        if self.urdf:
            return Path(self.urdf)
        return Path(self.mjcf) if self.mjcf else PANDA_MJCF


class WorldCfg(_Cfg):
    gravity_mps2: float = Field(9.81, gt=0.0, le=30.0)  # [m/s^2] magnitude, along -z of the world (arm base)

    @field_validator("gravity_mps2")
    @classmethod
    def _fin(cls, v):
        return _finite(v, "gravity_mps2")

    def g_w(self) -> np.ndarray:
        """(3,) gravity in the world frame [m/s^2]."""
        return np.array([0.0, 0.0, -float(self.gravity_mps2)])


class ContactDeclCfg(_Cfg):
    #: "tip": contacts act through the declared tip (a probe, an edge, a small tip on any surface);
    #: "exclude": contact is detected and left out (e.g. a flat face pressed flat: the centre of
    #: pressure wanders over the face); "none": the log has no contact (nothing is detected)
    mode: Literal["tip", "exclude", "none"] = "tip"
    detect_force_N: float = Field(4.0, gt=0.0)  # [N] force beyond the tool model that marks contact
    margin_s: float = Field(0.1, ge=0.0)  # [s] contact windows widened by this on each side
    #: "socket": a declared compliant contact (``contact_model``): a lateral spring at the tip and an
    #: angular spring, anchored where the declared tip crosses the entrance plane; its nominal wrench
    #: joins the model and the contact-model effects are judged. "none": no contact geometry declared
    geometry: Literal["none", "socket"] = "none"
    entry_w_m: Vec3 = (0.0, 0.0, 0.0)  # [m] socket: a point of the entrance plane, world
    axis_w: Vec3 = (0.0, 0.0, -1.0)  # socket: the axis into the fixture, world (normalised)
    stiffness_lat_N_per_m: float = Field(0.0, ge=0.0)  # [N/m] socket: lateral spring at the tip
    stiffness_rot_Nm_per_rad: float = Field(0.0, ge=0.0)  # [N m/rad] socket: angular spring
    damping_lat_N_s_per_m: float = Field(0.0, ge=0.0)  # [N s/m] socket: lateral damper at the tip (0: none)
    damping_rot_Nm_s_per_rad: float = Field(0.0, ge=0.0)  # [N m s/rad] socket: angular damper (0: none)
    #: the declared geometry's own account of contact, beside the data's (``detect_force_N``): the
    #: report uses contact where EITHER says so and names the windows they dispute. "entrance": a
    #: rigid fixture (a bore) can touch while the declared tip is below its entrance plane
    #: (``entry_w_m``, ``axis_w``) or within ``zone_m`` above it -- light contacts under the detection
    #: threshold are then never taken for free space; "none": the data's alone (a declared socket's
    #: engagement counts in either case)
    zone: Literal["none", "entrance"] = "none"
    zone_m: float = Field(0.002, ge=0.0)  # [m] "entrance": the declared tip's distance above the plane that counts

    @field_validator("detect_force_N", "margin_s", "entry_w_m", "axis_w", "stiffness_lat_N_per_m",
                     "stiffness_rot_Nm_per_rad", "damping_lat_N_s_per_m", "damping_rot_Nm_s_per_rad", "zone_m")
    @classmethod
    def _fin(cls, v):
        return _finite(v, "the value")

    @model_validator(mode="after")
    def _socket(self):
        if self.zone == "entrance" and np.linalg.norm(self.axis_w) < 1e-9:
            raise ValueError('zone = "entrance" needs axis_w (the fixture\'s axis into it, world; not zero)')
        if self.geometry == "socket":
            if self.mode != "tip":
                raise ValueError('geometry = "socket" needs mode = "tip" (the socket acts through the declared tip)')
            if np.linalg.norm(self.axis_w) < 1e-9:
                raise ValueError("axis_w must not be zero (the socket's axis into the fixture, world)")
            if self.stiffness_lat_N_per_m <= 0.0 and self.stiffness_rot_Nm_per_rad <= 0.0:
                raise ValueError('geometry = "socket" needs stiffness_lat_N_per_m or stiffness_rot_Nm_per_rad > 0')
        return self

    @property
    def declared_geometry(self) -> bool:
        """A contact geometry is declared: the contact-model effects are judged."""
        return self.geometry != "none"


class AnalysisCfg(_Cfg):
    exclude_s: tuple[tuple[float, float], ...] = ()  # [s] windows [t0, t1] (from the first sample) left out
    effects: tuple[str, ...] = ()  # only these effects (empty: every one that applies)
    exclude_effects: tuple[str, ...] = ()  # leave these effects out
    effects_files: tuple[str, ...] = ()  # the user's effect files (Python), as --effects
    relevant_force_N: float = Field(0.2, gt=0.0)  # [N] a systematic force residual worth reporting
    relevant_moment_Nm: float = Field(0.02, gt=0.0)  # [N m] the same for moments

    def left_out(self, t_from_first_s: np.ndarray) -> np.ndarray:
        """(n,) bool: the samples at ``t_from_first_s`` (n,) [s, from the first sample] that ``exclude_s`` leaves
        out (each window closed)."""
        t = np.asarray(t_from_first_s, dtype=float)
        out = np.zeros(t.shape, bool)
        for a, b in self.exclude_s:
            out |= (t >= a) & (t <= b)
        return out

    @field_validator("exclude_s")
    @classmethod
    def _windows(cls, v):
        for a, b in v:
            if not (math.isfinite(a) and math.isfinite(b)) or b <= a:
                raise ValueError(f"window [{a}, {b}] must be finite with t0 < t1")
        return v

    @field_validator("effects", "exclude_effects")
    @classmethod
    def _names(cls, v):  # checked against the built-ins and the user's effects when the diagnosis starts
        for n in v:
            if not n.isidentifier():
                raise ValueError(f"'{n}' is not an effect name (a Python identifier, e.g. tool_gravity)")
        return v

    @field_validator("relevant_force_N", "relevant_moment_Nm")
    @classmethod
    def _fin(cls, v):
        return _finite(v, "the value")


class SetupCfg(_Cfg):
    """A user's set-up (module docstring)."""

    log: LogCfg = LogCfg()
    sensor: SensorCfg = SensorCfg()
    tool: ToolDeclCfg = ToolDeclCfg()
    arm: ArmDeclCfg = ArmDeclCfg()
    world: WorldCfg = WorldCfg()
    contact: ContactDeclCfg = ContactDeclCfg()
    analysis: AnalysisCfg = AnalysisCfg()


def load_setup(path: Path | None, overrides: list[str] | tuple[str, ...] = ()) -> SetupCfg:
    """Load and validate a setup file (``None``: defaults); one-line ``ConfigError`` otherwise."""
    cfg = load_toml_model(SetupCfg, path, overrides, SETUP_EXAMPLE)
    return cfg


def template_text() -> str:
    """The commented template of the module docstring (every key with its default)."""
    doc = __doc__ or ""
    body = doc.split("default; ``examples/setups/`` has complete ones)::", 1)[1]
    lines = [ln[4:] if ln.startswith("    ") else ln for ln in body.strip("\n").splitlines()]
    head = ("# kinadapt diagnose setup file: what you know about your robot, sensor, tool and log.\n"
            "# Frames: f = the arm model's flange site, s = your F/T sensor; the tool is described in s.\n"
            "# Use: kinadapt diagnose YOUR_LOG --setup THIS_FILE --out DIR\n")
    return head + "\n".join(lines).rstrip() + "\n"


def setup_to_toml(cfg: SetupCfg) -> str:
    from kinadapt_nn.config import config_to_toml

    return config_to_toml(cfg)


__all__ = ["SetupCfg", "LogCfg", "SensorCfg", "ToolDeclCfg", "ArmDeclCfg", "DHCfg", "WorldCfg", "ContactDeclCfg", "AnalysisCfg",
           "load_setup", "setup_to_toml", "rpy_matrix", "inertia_matrix", "ConfigError"]
