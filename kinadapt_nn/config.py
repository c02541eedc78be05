"""Typed, validated experiment configuration (TOML in, TOML out).

Every field carries its unit in the comment. Configs are frozen pydantic models with
``extra="forbid"``: an unknown key, a wrong type, a non-finite number (NaN or inf, anywhere,
tuples included) or an out-of-range value raises ``ConfigError`` with one line naming the key
and what would be right. The fully resolved config is written beside every run
(``config.toml``) so a run explains itself.
"""

from __future__ import annotations

import math
import re
import tomllib
from pathlib import Path
from typing import Any, Literal, TypeVar, get_args

import tomli_w
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from kinadapt_nn.errors import ConfigError, did_you_mean

Vec2 = tuple[float, float]
Vec3 = tuple[float, float, float]
Vec6 = tuple[float, float, float, float, float, float]


def _arrays_as_tuples(value: Any) -> Any:
    """TOML arrays (lists, nested too) as tuples: strict mode takes a tuple field only as a tuple."""
    if isinstance(value, list):
        return tuple(_arrays_as_tuples(v) for v in value)
    return value


class _Cfg(BaseModel):
    # strict=True: a TOML value of the wrong type is an error, never coerced ("no" or 0 is not a bool,
    # "0.4" is not a number); an integer is still taken where a float is expected (mass_kg = 1).
    # allow_inf_nan=False: every float, nested tuples included, must be finite
    model_config = ConfigDict(extra="forbid", frozen=True, strict=True, validate_default=True, allow_inf_nan=False)

    @model_validator(mode="before")
    @classmethod
    def _tuples(cls, data: Any) -> Any:
        if isinstance(data, dict):
            return {k: _arrays_as_tuples(v) for k, v in data.items()}
        return data


def _within(v: tuple[float, ...], lo: tuple[float, ...] | float, hi: tuple[float, ...] | float, unit: str) -> tuple:
    """Field-validator helper: every entry of ``v`` in its closed range [lo, hi] (per entry or shared)."""
    los = lo if isinstance(lo, tuple) else (lo,) * len(v)
    his = hi if isinstance(hi, tuple) else (hi,) * len(v)
    u = f" {unit}" if unit else ""
    for i, (x, a, b) in enumerate(zip(v, los, his)):
        if not a <= x <= b:
            raise ValueError(f"entry {i} is {x:g}{u}; each must lie in [{a:g}, {b:g}]{u}")
    return v


#: tool offsets O -> tip in f [m]: lateral within +-5 cm, the tip 1 mm to 0.5 m in front of the flange
_OFFSET_LO, _OFFSET_HI = (-0.05, -0.05, 1e-3), (0.05, 0.05, 0.5)


class ToolCfg(_Cfg):
    """The true tool (hidden from the controller): a rigid square peg held at the flange."""

    offset_f_m: Vec3 = (0.003, -0.002, 0.100)  # [m] O -> tip in the flange frame f (true)
    tilt_deg: Vec2 = (0.0, 0.0)  # [deg] rotation of the peg in the grasp about f x, then f y
    mass_kg: float = Field(0.10, gt=0.0)  # [kg] peg mass (loads the wrist sensor)
    side_m: float = Field(0.020, gt=0.0, lt=0.022)  # [m] square peg side (bore is 22 mm)
    length_m: float = Field(0.100, gt=0.0)  # [m] peg length along its own axis, ending at the tip

    @field_validator("offset_f_m")
    @classmethod
    def _offset(cls, v: Vec3) -> Vec3:
        return _within(v, _OFFSET_LO, _OFFSET_HI, "m")

    @field_validator("tilt_deg")
    @classmethod
    def _tilt(cls, v: Vec2) -> Vec2:
        return _within(v, -45.0, 45.0, "deg")


class SceneCfg(_Cfg):
    """The bore block: a square bore whose walls are +-bore_half_width about its axis."""

    arm_mjcf: str = ""  # arm MJCF path ("" = the shipped models/panda.xml); known to both sides

    bore_entry_w_m: Vec3 = (0.45, 0.0, 0.30)  # [m] centre of the bore entrance, world frame (KNOWN)
    bore_pose_error_m: Vec3 = (0.0, 0.0, 0.0)  # [m] true bore = known pose + this (hidden)
    bore_half_width_m: float = Field(0.011, gt=0.0)  # [m] wall position about the bore centre
    bore_depth_m: float = Field(0.050, gt=0.0)  # [m] bore depth (floor below the entrance)
    block_half_size_m: float = Field(0.06, gt=0.0)  # [m] half side of the block (x and y)
    chamfer_m: float = Field(0.0, ge=0.0, le=0.005)  # [m] 45-deg entrance chamfer (0 = none)
    friction: float = Field(0.3, ge=0.0, le=2.0)  # [-] Coulomb friction peg <-> block
    contact_timeconst_s: float = Field(0.02, gt=0.0)  # [s] MuJoCo solref time constant
    contact_dampratio: float = Field(1.0, gt=0.0)  # [-] MuJoCo solref damping ratio
    # [s] MuJoCo solreffriction time constant of the bore's friction rows (elliptic cone); 0 = the normal's solref,
    # pyramidal cone (`kinadapt reproduce`), whose sliding peg rattles at ~90 Hz (docs/paper_results.md, "The bore rattle")
    contact_friction_timeconst_s: float = Field(2.0, ge=0.0)
    contact_model: Literal["bore", "socket"] = "bore"  # bore block | low-bias tip "socket" spring
    socket_k_lat_N_per_m: float = Field(2.0e4, gt=0.0)  # [N/m] socket: lateral spring at the tip
    socket_k_rot_Nm_per_rad: float = Field(20.0, ge=0.0)  # [N m/rad] socket: angular spring
    socket_damping_ratio: float = Field(0.05, ge=0.0)  # [-] socket: damping (x critical, 3 kg)
    socket_engage: Literal["drive", "depth"] = "drive"  # socket anchors at drive start | when the tip enters
    socket_k_axial_N_per_m: float = Field(0.0, ge=0.0)  # [N/m] socket "depth": axial spring below the entrance

    @field_validator("bore_entry_w_m")
    @classmethod
    def _entry(cls, v: Vec3) -> Vec3:
        return _within(v, -2.0, 2.0, "m")  # (reachability is checked when the start pose is solved)

    @field_validator("bore_pose_error_m")
    @classmethod
    def _pose_error(cls, v: Vec3) -> Vec3:
        return _within(v, -0.05, 0.05, "m")


class ArmCfg(_Cfg):
    """The TRUE arm's small kinematic errors (hidden; see kinadapt_nn.sim.truth)."""

    link_length_error_m: tuple[float, ...] = (0.0,) * 8  # [m] link1..link7 offsets + flange
    joint_offset_rad: tuple[float, ...] = (0.0,) * 7  # [rad] encoder zero offsets, joint1..7

    @model_validator(mode="after")
    def _lengths(self) -> ArmCfg:
        if len(self.link_length_error_m) != 8 or len(self.joint_offset_rad) != 7:
            raise ValueError("arm.link_length_error_m needs 8 values and arm.joint_offset_rad 7")
        if max(abs(x) for x in self.link_length_error_m) > 0.02 or max(abs(x) for x in self.joint_offset_rad) > 0.1:
            raise ValueError("arm errors must be small: |link error| <= 0.02 m, |joint offset| <= 0.1 rad")
        return self


class StartCfg(_Cfg):
    """Where the episode starts (set by the simulator from the true tool; truth side)."""

    tip_height_m: float = Field(0.005, gt=0.0, le=0.2)  # [m] true tip above the bore entrance
    lateral_w_m: Vec2 = (0.0008, 0.0)  # [m] true tip lateral misalignment (world x, y)
    tilt_deg: Vec2 = (0.0, 2.0)  # [deg] flange tilt from vertical about world x, then y
    settle_s: float = Field(0.3, ge=0.05)  # [s] hold still at start (servo settles, tare)
    lateral_jitter_m: float = Field(0.0, ge=0.0, le=0.005)  # [m] seeded uniform +- jitter of lateral_w_m
    tilt_jitter_deg: float = Field(0.0, ge=0.0, le=5.0)  # [deg] seeded uniform +- jitter of tilt_deg

    @field_validator("lateral_w_m")
    @classmethod
    def _lateral(cls, v: Vec2) -> Vec2:
        return _within(v, -0.05, 0.05, "m")

    @field_validator("tilt_deg")
    @classmethod
    def _tilt(cls, v: Vec2) -> Vec2:
        return _within(v, -45.0, 45.0, "deg")


class SensingCfg(_Cfg):
    """Known sensing model: the constant nominal map S, the channel metric W, the filter."""

    nominal_offset_f_m: Vec3 = (0.0, 0.0, 0.100)  # [m] nominal tool (CAD) O -> tip, known
    stiffness_lat_N_per_m: float = Field(2.0e4, gt=0.0)  # [N/m] nominal lateral contact k_t
    stiffness_rot_Nm_per_rad: float = Field(20.0, ge=0.0)  # [N m/rad] nominal contact couple k_r
    filter_tau_s: float = Field(0.01, gt=0.0)  # [s] first-order filter of s_dot (both sides)
    # channel metric W = diag(1/scale): [d m, F_lat N, F_lat N, M N m, M N m, M N m]
    channel_scale: Vec6 = (0.01, 10.0, 10.0, 1.0, 1.0, 1.0)
    tare_window_s: float = Field(0.1, gt=0.0)  # [s] free-space window averaged for the tare
    max_dropout_s: float = Field(0.02, ge=0.0)  # [s] NaN/inf samples bridged by holding the last valid one

    @field_validator("nominal_offset_f_m")
    @classmethod
    def _offset(cls, v: Vec3) -> Vec3:
        return _within(v, _OFFSET_LO, _OFFSET_HI, "m")

    @model_validator(mode="after")
    def _positive_scales(self) -> SensingCfg:
        if min(self.channel_scale) <= 0.0:
            raise ValueError("sensing.channel_scale entries must all be > 0 (units m, N, N m)")
        return self


class ControlCfg(_Cfg):
    """Value function V(s) and the second-order twist admittance (paper Results constants)."""

    depth_target_m: float = Field(0.045, gt=0.0)  # [m] d* (minimum of V)
    k_depth_N_per_m: float = Field(1.0e4, gt=0.0)  # [N/m] V = 1/2 k_d (d - d*)^2 + ...
    depth_force_max_N: float = Field(80.0, gt=0.0)  # [N] V is linear (Huber) beyond this force
    compliance_lat_m_per_N: float = Field(2.0e-5, ge=0.0)  # [m/N] V += 1/2 c_F |F_lat|^2
    compliance_mom_rad_per_Nm: float = Field(2.0e-3, ge=0.0)  # [rad/(N m)] V += 1/2 c_M |M|^2
    tau_trans_s: float = Field(2.0e-3, gt=0.0)  # [s] virtual time constant, translation
    tau_ang_s: float = Field(1.0e-2, gt=0.0)  # [s] virtual time constant, rotation
    beta_trans: float = Field(0.072, ge=0.0)  # [-] extra damping beta, translation
    beta_ang: float = Field(0.0, ge=0.0)  # [-] extra damping beta, rotation
    gain_trans: float = Field(2.0e-4, gt=0.0)  # [m/(N s)] wrench-to-velocity gain, translation
    gain_ang: float = Field(2.0e-4, gt=0.0)  # [rad/(N m s)] wrench-to-velocity gain, rotation
    v_max_m_per_s: float = Field(0.05, gt=0.0)  # [m/s] translational speed limit of the twist
    w_max_rad_per_s: float = Field(0.5, gt=0.0)  # [rad/s] angular speed limit of the twist
    ramp_s: float = Field(0.3, ge=0.0)  # [s] the drive is ramped in over this time after tare
    nullspace_gain: float = Field(2.0, ge=0.0)  # [1/s] posture pull in the null space of J_arm
    loop: Literal["admittance", "rigid"] = "admittance"  # rigid: eq. ft_control, no contact feedback
    dither_rad_s: Vec3 = (0.0, 0.0, 0.0)  # [rad/s] commanded angular excitation about world x, y, z
    dither_hz: float = Field(1.0, gt=0.0)  # [Hz] dither frequency (x: sin, y: cos, z: sin at 1.7 f)
    program: Literal["insert", "excite"] = "insert"  # insert: descend V's gradient | excite: [excite] script

    @field_validator("dither_rad_s")
    @classmethod
    def _dither(cls, v: Vec3) -> Vec3:
        return _within(v, -1.0, 1.0, "rad/s")


class FeaturesCfg(_Cfg):
    """Learned feature settings (``run.features = rbf | neural``)."""

    rbf_centres: Literal["path", "sampled"] = "path"  # centres on the insertion path or sampled about it
    rbf_n_centres: int = Field(6, ge=1, le=64)  # K; p = 5 * 7 * K
    rbf_width_rad: float = Field(0.0, ge=0.0)  # [rad] Gaussian width (0 = mean nearest-centre distance)
    rbf_seed: int = Field(0, ge=0, le=2**32 - 1)  # seed of the sampled centres
    neural_checkpoint: str = ""  # pretrained body ("" = the shipped models/neural_default.safetensors; a bare file name = a shipped model, e.g. "neural_cell.safetensors")
    neural_prior: Literal["all_arms", "calibrated_arm"] = "all_arms"  # kalman: theta's prior = the heads of every training arm | only the nominal arm's (declare a calibrated arm)


class AdaptationCfg(_Cfg):
    """The adaptation law (kinadapt_nn.controller.laws; eq. ft_composite) and the initial estimate."""

    mode: str = "kalman"  # the law: a name in kinadapt_nn.controller.laws.LAWS (composite = the paper's: reproduce)
    gamma: float = Field(100.0, gt=0.0)  # [m^2] Gamma = gamma I: V_aug = gamma_d V + |theta~|^2/(2 Gamma)
    gamma_d: float = Field(1.0e-7, gt=0.0)  # [1/J] weight of V(s) in V_aug (paper Results; undefined there)
    eta: float = Field(0.5, gt=0.0, lt=2.0)  # [-] fraction of the exact per-sample QP step
    eps_norm: float = Field(1.0e-4, gt=0.0)  # [-] regulariser, W-scaled units of ||W Phi||^2
    initial_error_m: float = Field(0.005, ge=0.0, le=0.05)  # [m] |theta0 - true offset|
    initial_error_dir_f: Vec3 = (0.0, 0.0, 0.0)  # [-] direction in f; 0 = away from the flange axis
    omega_lateral_m: float = Field(0.015, gt=0.0)  # [m] Omega: |theta_xy - nominal_xy| bound
    omega_axial_m: float = Field(0.030, gt=0.0)  # [m] Omega: |theta_z - nominal_z| bound
    contact_force_N: float = Field(1.0, ge=0.0)  # [N] free-space rule: adapt only in contact
    contact_moment_Nm: float = Field(0.05, ge=0.0)  # [N m] ... or when |M| exceeds this
    # kalman law (kinadapt_nn.controller.laws.kalman): prior, residual level, decorrelation
    prior_sd_lateral_m: float = Field(0.005, gt=0.0)  # [m] adjoint prior sd of the lateral offset components
    prior_sd_axial_m: float = Field(0.010, gt=0.0)  # [m] adjoint prior sd of the axial offset component
    rbf_prior_floor: float = Field(0.001, ge=0.0)  # [-] RBF prior: isotropic part, fraction of the adjoint push-forward
    corr_s: float = Field(0.2, gt=0.0)  # [s] residual correlation time: samples within it count as one
    resid_tau_s: float = Field(1.0, gt=0.0)  # [s] time constant of the measured residual level
    resid_floor_w: float = Field(1.0e-4, gt=0.0)  # [W-scaled^2] floor of the residual level
    act_sd_ratio: float = Field(0.4, gt=0.0, le=1.0)  # [-] act on a direction of theta once its sd < this x the prior sd (1: all)
    persist_tau_s: float = Field(0.5, gt=0.0)  # [s] window of the residual's mean: a persistent residual counts once per 2 tau
    # a law's own parameters, by law name: [adaptation.params.<law>] name = value, declared (unit, default, bounds) in
    # the law's module (its Params) and checked when the run builds the law; the keys above are the built-in laws'
    params: dict[str, dict[str, float | int | bool | str]] = {}

    @field_validator("initial_error_dir_f")
    @classmethod
    def _direction(cls, v: Vec3) -> Vec3:
        return _within(v, -1.0, 1.0, "")  # a direction (normalised where used)


class FaultsCfg(_Cfg):
    """Sensor faults and disturbances (truth side, kinadapt_nn.sim.adapter.SensorFaults); all off by default."""

    ft_noise_N: float = Field(0.0, ge=0.0)  # [N] std of white force noise per axis
    ft_noise_Nm: float = Field(0.0, ge=0.0)  # [N m] std of white torque noise per axis
    ft_bias_N: Vec3 = (0.0, 0.0, 0.0)  # [N] force bias in f, appearing at bias_onset_s (after the tare)
    bias_onset_s: float = Field(0.0, ge=0.0)  # [s] bias appears this long after the tare (end of settle)
    ft_dropout_prob: float = Field(0.0, ge=0.0, le=0.5)  # [-] probability a sample is NaN (dropout)
    ft_saturation_N: float = Field(0.0, ge=0.0)  # [N] clip force components (0 = off)
    encoder_resolution_rad: float = Field(0.0, ge=0.0)  # [rad] encoder quantisation step (0 = off)
    latency_steps: int = Field(0, ge=0, le=10)  # [steps] delivery delay of every sample

    @field_validator("ft_bias_N")
    @classmethod
    def _bias(cls, v: Vec3) -> Vec3:
        return _within(v, -1000.0, 1000.0, "N")


class ToolGravityCfg(_Cfg):
    """Effect ``tool_gravity``: an extra payload on the tool (e.g. a heavier tool than the tared one)."""

    enabled: bool = False
    mass_kg: float = Field(0.5, gt=0.0, le=5.0)  # [kg] payload mass
    com_f_m: Vec3 = (0.0, 0.0, 0.05)  # [m] payload centre of mass from O, flange frame
    onset_s: float = Field(0.0, ge=0.0, le=600.0)  # [s] the payload is picked up at this time (0: there from the start)
    ramp_s: float = Field(0.0, ge=0.0, le=10.0)  # [s] its mass grows linearly over this long from the onset (0: a step)

    @field_validator("com_f_m")
    @classmethod
    def _com(cls, v: Vec3) -> Vec3:
        return _within(v, -0.5, 0.5, "m")


class FtBiasDriftCfg(_Cfg):
    """Effect ``ft_bias_drift``: the F/T offset drifts linearly in time (after the tare it shows)."""

    enabled: bool = False
    rate_f: Vec6 = (0.2, 0.0, 0.0, 0.0, 0.0, 0.0)  # [N/s, N m/s] drift of the reading, sensor frame
    onset_s: float = Field(0.0, ge=0.0, le=600.0)  # [s] the drift starts at this time (reading += rate (t - onset))

    @field_validator("rate_f")
    @classmethod
    def _rate(cls, v: Vec6) -> Vec6:
        return _within(v, -100.0, 100.0, "N/s or N m/s")


class FtFrameRotationCfg(_Cfg):
    """Effect ``ft_frame_rotation``: the sensor is mounted slightly rotated about O."""

    enabled: bool = False
    rotvec_deg: Vec3 = (1.41, 0.0, 1.41)  # [deg] rotation vector of the sensor frame in f (2 deg total)
    onset_s: float = Field(0.0, ge=0.0, le=600.0)  # [s] the mount turns at this time (0: rotated from the start)
    ramp_s: float = Field(0.0, ge=0.0, le=10.0)  # [s] the angle grows linearly over this long from the onset (0: a step)

    @field_validator("rotvec_deg")
    @classmethod
    def _rotvec(cls, v: Vec3) -> Vec3:
        return _within(v, -30.0, 30.0, "deg")


class ToolTiltCfg(_Cfg):
    """Effect ``tool_tilt``: the tool sits rotated in the grasp (its tip moves with it)."""

    enabled: bool = False
    tilt_deg: Vec2 = (2.0, 0.0)  # [deg] rotation of the tool about f x, then f y

    @field_validator("tilt_deg")
    @classmethod
    def _tilt(cls, v: Vec2) -> Vec2:
        return _within(v, -45.0, 45.0, "deg")


class ContactStiffnessCfg(_Cfg):
    """Effect ``contact_stiffness``: the contact is stiffer/softer than the model's S."""

    enabled: bool = False
    factor: float = Field(0.5, gt=0.05, le=5.0)  # [-] true stiffness / nominal stiffness


class ContactFrictionCoupleCfg(_Cfg):
    """Effect ``contact_friction_couple``: a torsional friction couple opposing rotation in contact."""

    enabled: bool = False
    radius_m: float = Field(0.005, gt=0.0, le=0.05)  # [m] couple = radius x |contact force|
    omega_eps_rad_s: float = Field(0.005, gt=0.0)  # [rad/s] smoothing of sign(omega) (known to the model)


class GraspComplianceCfg(_Cfg):
    """Effect ``grasp_compliance``: the tool yields in the grasp under moment (hinges about f x, y at O)."""

    enabled: bool = False
    stiffness_Nm_per_rad: float = Field(200.0, gt=1.0)  # [N m/rad] grasp rotational stiffness


class EncoderOffsetCfg(_Cfg):
    """Effect ``encoder_offset``: one joint's encoder zero is off."""

    enabled: bool = False
    joint: int = Field(4, ge=1, le=7)  # [-] which joint (1..7)
    offset_deg: float = Field(0.5, ge=-5.0, le=5.0)  # [deg] true angle = reading + offset


class WorldForceCfg(_Cfg):
    """Effect ``world_force``: a snag -- a cable or hose pulls on the tool with a constant world-frame force at a
    point of the tool, from a time on."""

    enabled: bool = False
    force_w_N: Vec3 = (0.0, -1.5, 0.0)  # [N] the pull, world frame
    point_f_m: Vec3 = (0.0, 0.02, 0.06)  # [m] where it acts on the tool, flange frame (from O)
    onset_s: float = Field(0.0, ge=0.0, le=600.0)  # [s] the snag catches at this time
    ramp_s: float = Field(0.0, ge=0.0, le=10.0)  # [s] the pull grows linearly over this long from the onset (0: a step)

    @field_validator("force_w_N")
    @classmethod
    def _force(cls, v: Vec3) -> Vec3:
        return _within(v, -100.0, 100.0, "N")

    @field_validator("point_f_m")
    @classmethod
    def _point(cls, v: Vec3) -> Vec3:
        return _within(v, -0.5, 0.5, "m")


class GraspSlipCfg(_Cfg):
    """Effect ``grasp_slip``: the tool slips in the grasp at a time, turning about O (the sensor stays put)."""

    enabled: bool = False
    slip_deg: Vec2 = (8.0, 0.0)  # [deg] the turn of the tool in the grasp about f x, then f y
    onset_s: float = Field(0.0, ge=0.0, le=600.0)  # [s] the grasp slips at this time
    ramp_s: float = Field(0.02, ge=0.0, le=10.0)  # [s] the slip takes this long (0: a jump)

    @field_validator("slip_deg")
    @classmethod
    def _slip(cls, v: Vec2) -> Vec2:
        return _within(v, -20.0, 20.0, "deg")


class EffectsCfg(_Cfg):
    """Hidden physical effects (truth side; ``kinadapt_nn.effects.builtin`` has the model side).

    Enable one with ``--set effects.NAME.enabled=true``; the controller and the model do not know it."""

    tool_gravity: ToolGravityCfg = ToolGravityCfg()
    ft_bias_drift: FtBiasDriftCfg = FtBiasDriftCfg()
    ft_frame_rotation: FtFrameRotationCfg = FtFrameRotationCfg()
    tool_tilt: ToolTiltCfg = ToolTiltCfg()
    contact_stiffness: ContactStiffnessCfg = ContactStiffnessCfg()
    contact_friction_couple: ContactFrictionCoupleCfg = ContactFrictionCoupleCfg()
    grasp_compliance: GraspComplianceCfg = GraspComplianceCfg()
    encoder_offset: EncoderOffsetCfg = EncoderOffsetCfg()
    world_force: WorldForceCfg = WorldForceCfg()
    grasp_slip: GraspSlipCfg = GraspSlipCfg()

    def enabled(self) -> list[str]:
        return [k for k in type(self).model_fields if getattr(self, k).enabled]


class MonitorCfg(_Cfg):
    """The live monitor (``kinadapt online --monitor``, ``kinadapt_nn.monitor``): a sequential test of the
    measured wrench against the nominal model's prediction (declared tool, its gravity and inertia), on
    what the controller receives only. docs/monitor.md."""

    enabled: bool = False  # run the monitor beside the controller (--monitor sets it)
    false_alarms_per_h: float = Field(0.1, gt=0.0, le=3600.0)  # [1/h] false-alarm rate of the test on white noise at the floor (sets the CUSUM threshold)
    cusum_k: float = Field(1.5, gt=0.0, le=20.0)  # [-] CUSUM reference value, in noise sd: half the smallest shift it is tuned to
    floor_N: float = Field(0.01, gt=0.0)  # [N] smallest noise sd of a force channel (model error below it is noise)
    floor_Nm: float = Field(0.001, gt=0.0)  # [N m] smallest noise sd of a moment channel
    calib_s: float = Field(0.2, gt=0.0, le=10.0)  # [s] at the start, at rest: the sensor's offset and noise are measured this long
    window_s: float = Field(0.5, gt=0.01, le=10.0)  # [s] after an alarm: samples this long are fitted to name the shape
    contact_zone_m: float = Field(0.004, ge=0.0, le=0.1)  # [m] the nominal tip within this of the entrance plane (or below it): contact, not judged
    rotation_test: bool = True  # also a GLR test of the sensor frame's rotation on the force channels, threshold from false_alarms_per_h (docs/monitor.md)
    pause_law: bool = False  # the law listens: while an alarm is being named or an event is open (to the run's end) the adaptive law does not step -- theta held, the controller acts on its last estimate (docs/monitor.md)

    @model_validator(mode="after")
    def _pause_needs_monitor(self) -> MonitorCfg:
        if self.pause_law and not self.enabled:
            raise ValueError("monitor.pause_law = true pauses the law on the live monitor's events: turn the monitor "
                             "on too (monitor.enabled = true, or --monitor)")
        return self


class ModelCfg(_Cfg):
    """The controller's model beyond the features: library effects adapted online."""

    effects: tuple[str, ...] = ()  # columns adapted by the prediction law, e.g. ["contact_stiffness"]: built-ins with an online side (kinadapt_nn.features.effect_library.LIBRARY, checked there) or "PATH.py:NAME" of an effects file


class ExciteCfg(_Cfg):
    """The scripted excitation program (``control.program = "excite"``): segments of a commanded
    nominal-tip twist, tracked through the same admittance (so contact stays compliant)."""

    # each row: [duration s, v_x, v_y, v_z m/s, w_x, w_y, w_z rad/s], world axes, about the nominal tip
    segments: tuple[tuple[float, float, float, float, float, float, float], ...] = ()
    blend_s: float = Field(0.2, ge=0.0, le=2.0)  # [s] linear blend from one segment's twist to the next (bounded accelerations)

    @model_validator(mode="after")
    def _durations(self) -> ExciteCfg:
        if any(seg[0] <= 0.0 or seg[0] > 600.0 for seg in self.segments):
            raise ValueError("excite.segments: every row starts with a duration in (0, 600] s")
        return self


class SuccessCfg(_Cfg):
    """Success and failure classification, judged from sensor-side signals only."""

    depth_m: float = Field(0.045, gt=0.0)  # [m] seat depth (paper: 45 mm)
    depth_tol_m: float = Field(0.0005, ge=0.0)  # [m] V's minimum is approached asymptotically
    max_lateral_force_N: float = Field(50.0, gt=0.0)  # [N] |F_lat| limit
    max_moment_Nm: float = Field(2.0, gt=0.0)  # [N m] |M| limit
    hold_s: float = Field(0.05, ge=0.0)  # [s] all three conditions held this long
    jam_window_s: float = Field(1.0, gt=0.0)  # [s] no depth progress for this long under load
    jam_progress_m: float = Field(0.0005, gt=0.0)  # [m] progress that counts as "moving"
    jam_force_N: float = Field(30.0, gt=0.0)  # [N] |F| above which a stall is a jam
    face_depth_m: float = Field(0.003, gt=0.0)  # [m] loaded at d below this -> block face
    diverge_force_N: float = Field(500.0, gt=0.0)  # [N] |F| beyond this = divergence


class RunCfg(_Cfg):
    """What to run."""

    seed: int = Field(0, ge=0, le=2**32 - 1)  # [-] seeds every random draw of the run
    duration_s: float = Field(8.0, gt=0.0, le=600.0)  # [s] simulated time limit (timeout)
    dt_s: float = Field(0.001, gt=0.0, le=0.01)  # [s] control and physics timestep
    features: str = "adjoint"  # Y(q): a registered features type, kinadapt_nn.features.FEATURES (oracle = the true offset, held)
    stop_after_seat_s: float = Field(0.5, ge=0.0)  # [s] keep simulating this long after seating
    log_every: int = Field(1, ge=1)  # [steps] trace decimation
    insertions: int = Field(1, ge=1, le=1000)  # [-] consecutive insertions of the same tool; theta (and P) carried over
    tensorboard: bool = True  # write TensorBoard event files
    figure: bool = True  # write the rollout figure (PNG)
    progress: bool = True  # show a progress bar


class CellCfg(_Cfg):
    """A work cell: several bores (KNOWN entrance poses, as an integrator writes them down) visited
    in a sequence by ``run.insertions`` with theta (and the law's covariance) carried over, and
    the held-out configurations on which the cell Jacobian error is evaluated (truth side)."""

    bores_w_m: tuple[Vec3, ...] = ()  # [m] bore entrances, world (KNOWN); () = the one bore scene.bore_entry_w_m
    order: tuple[int, ...] = ()  # [-] bore indices visited in turn (cycled); () = 0, 1, 2, ... cycled
    heldout_per_bore: int = Field(8, ge=1, le=200)  # [-] held-out configurations per bore (cell Jacobian error)
    heldout_seed: int = Field(20261123, ge=0)  # [-] draws the held-out configurations (fixed: the same set every insertion)
    heldout_tilt_deg: float = Field(3.0, ge=0.0, le=10.0)  # [deg] held-out flange tilt, uniform +- about vertical
    heldout_lateral_m: float = Field(0.003, ge=0.0, le=0.02)  # [m] held-out tip offset from the bore axis, uniform +-
    between: Literal["carry", "refit"] = "carry"  # between insertions: carry theta/P | refit theta on every logged insertion (measured data only)
    refit_channels: tuple[int, ...] = (1, 2)  # [-] channels of s the refit fits (0 d, 1-2 F_lat, 3-5 M); default: the lateral forces (docs/cell.md)
    refit_prior_weight: float = Field(1.0, gt=0.0, le=1e6)  # [-] the refit's prior information = this x P0^-1
    refit_timing_sd_s: float = Field(0.0, ge=0.0, le=0.1)  # [s] > 0: the refit also estimates the F/T-vs-encoder timing offset (prior sd); 0 = off
    refit_neural_prior_choice: float = Field(30.0, ge=0.0)  # [-] > 0, neural features: the refit acts on the calibrated-arm prior's estimate unless the measured data favour the features' own prior by more than this x insertions in log marginal likelihood; 0 = off (default 30: measured better over five draws, docs/cell.md)
    refit_max_directions_neural: int = Field(0, ge=0, le=1000)  # [-] neural features: the refit acts on at most this many of the best-identified directions (0 = no cap: every direction past act_sd_ratio)
    refit_step_sd: float = Field(0.5, ge=0.0, le=1e6)  # [-] > 0: between insertions the acted estimate moves towards the new refit by at most this many posterior sd (|d|_{P^-1}); 0 = off: act on each refit as it is (default 0.5: no rise between insertions in five draws, docs/cell.md)

    @field_validator("bores_w_m")
    @classmethod
    def _bores(cls, v: tuple) -> tuple:
        for i, b in enumerate(v):
            try:
                _within(b, -2.0, 2.0, "m")
            except ValueError as exc:
                raise ValueError(f"bore {i}: {exc}") from None
        return v

    @model_validator(mode="after")
    def _order(self) -> CellCfg:
        nb = max(1, len(self.bores_w_m))
        bad = [i for i in self.order if not 0 <= i < nb]
        if bad:
            raise ValueError(f"cell.order names bore {bad[0]}, but the cell has {nb} bore(s) (indices 0..{nb - 1})")
        if not self.refit_channels or any(not 0 <= c <= 5 for c in self.refit_channels):
            raise ValueError("cell.refit_channels must name channels of s in 0..5 (0 d, 1-2 F_lat, 3-5 M)")
        if self.refit_neural_prior_choice > 0 and self.refit_timing_sd_s > 0 and \
                "refit_neural_prior_choice" in self.model_fields_set:  # the default gives way to the timing offset
            raise ValueError("cell.refit_neural_prior_choice and cell.refit_timing_sd_s cannot be combined: set one "
                             "of them to 0")
        return self

    def bores(self, scene: SceneCfg) -> list[tuple[float, float, float]]:
        """The cell's known bore entrances (at least the scene's one bore). -> [(3,)] world [m]."""
        return [tuple(b) for b in self.bores_w_m] or [tuple(scene.bore_entry_w_m)]

    def bore_of(self, i: int) -> int:
        """The bore index of insertion ``i`` (0-based)."""
        order = self.order or tuple(range(max(1, len(self.bores_w_m))))
        return order[i % len(order)]


class ExperimentCfg(_Cfg):
    """One online experiment (``kinadapt online``)."""

    run: RunCfg = RunCfg()
    tool: ToolCfg = ToolCfg()
    arm: ArmCfg = ArmCfg()
    scene: SceneCfg = SceneCfg()
    start: StartCfg = StartCfg()
    sensing: SensingCfg = SensingCfg()
    control: ControlCfg = ControlCfg()
    features: FeaturesCfg = FeaturesCfg()
    adaptation: AdaptationCfg = AdaptationCfg()
    faults: FaultsCfg = FaultsCfg()
    effects: EffectsCfg = EffectsCfg()
    model: ModelCfg = ModelCfg()
    excite: ExciteCfg = ExciteCfg()
    success: SuccessCfg = SuccessCfg()
    cell: CellCfg = CellCfg()
    monitor: MonitorCfg = MonitorCfg()


def true_bore_entry(scene: SceneCfg) -> tuple[float, float, float]:
    """The TRUE bore entrance (truth side): the known pose plus the hidden pose error."""
    return tuple(a + b for a, b in zip(scene.bore_entry_w_m, scene.bore_pose_error_m))


def arm_mjcf_path(scene: SceneCfg) -> Path:
    """The arm model file named by ``scene.arm_mjcf`` (default: the shipped Panda)."""
    from kinadapt_nn.robot import PANDA_MJCF

    return Path(scene.arm_mjcf) if scene.arm_mjcf else PANDA_MJCF


def _dotted_keys(model: type[BaseModel], prefix: str = "") -> list[str]:
    """Every key of ``model`` as ``--set`` takes it, sections and their keys (``run``, ``run.seed``)."""
    keys = []
    for name, field in model.model_fields.items():
        sub = [a for a in (field.annotation, *get_args(field.annotation))
               if isinstance(a, type) and issubclass(a, BaseModel)]
        keys += [f"{prefix}{name}", *(_dotted_keys(sub[0], f"{prefix}{name}.") if sub else [])]
    return keys


#: pydantic's strict type errors -> the TOML type a key expects
_EXPECTED_TYPE = {"bool_type": "a boolean (true or false)", "float_type": "a number (e.g. 0.4)",
                  "int_type": "an integer (e.g. 3)", "string_type": 'a string (in quotes, e.g. "rad")',
                  "tuple_type": "an array ([...])", "model_type": "a table ([section] or { ... })",
                  "dict_type": "a table ([section] or { ... })"}
#: Python types of parsed TOML values -> their TOML names
_TOML_TYPE = {str: "a string", bool: "a boolean", int: "an integer", float: "a float", list: "an array",
              tuple: "an array", dict: "a table"}


def _format_validation_error(err: ValidationError, model: type[BaseModel]) -> str:
    first = err.errors()[0]
    loc = "".join(f"[{x}]" if isinstance(x, int) else f".{x}" for x in first["loc"]).lstrip(".") or "<root>"
    kind = first["type"]
    if kind == "extra_forbidden":
        hint = did_you_mean(loc, [k for k in _dotted_keys(model) if k.count(".") == loc.count(".")])
        if hint:
            return f"unknown config key '{loc}'; {hint} (see online/rollout.toml)"
        return f"unknown config key '{loc}' (check the spelling; see online/rollout.toml)"
    msg = " ".join(str(first["msg"]).split()).removeprefix("Value error, ")
    if kind == "finite_number":
        msg = "must be a finite number (not nan or inf)"
    if kind in _EXPECTED_TYPE:  # a wrong TOML type: say what was given and what is expected
        given = _TOML_TYPE.get(type(first.get("input")), type(first.get("input")).__name__)
        msg = f"expects {_EXPECTED_TYPE[kind]}, not {given}"
    if kind == "literal_error" and isinstance(first.get("input"), str):  # a misspelt name (effect, law, ...)
        hint = did_you_mean(first["input"], re.findall(r"'([^']*)'", str(first.get("ctx", {}).get("expected", ""))))
        msg += f"; {hint}" if hint else ""
    got = repr(first.get("input"))
    got = got.lower() if isinstance(first.get("input"), bool) else got  # as TOML writes it
    return f"config key '{loc}': {msg} (got {got if len(got) <= 80 else got[:77] + '...'})"


def _non_finite_key(value: Any, key: str = "") -> str | None:
    """The dotted key (``a.b[2]``) of the first NaN/inf float anywhere in ``value``, else None."""
    if isinstance(value, float):
        return None if math.isfinite(value) else key
    if isinstance(value, dict):
        items = ((f"{key}.{k}" if key else str(k), v) for k, v in value.items())
    elif isinstance(value, (list, tuple)):
        items = ((f"{key}[{i}]", v) for i, v in enumerate(value))
    else:
        return None
    for sub, v in items:
        if (bad := _non_finite_key(v, sub)) is not None:
            return bad
    return None


def _parse_value(text: str) -> Any:
    """Parse the right-hand side of ``--set key=value`` as a TOML value (fallback: string)."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def _set_dotted(tree: dict[str, Any], dotted: str, value: Any) -> None:
    parts = dotted.split(".")
    node = tree
    for p in parts[:-1]:
        nxt = node.setdefault(p, {})
        if not isinstance(nxt, dict):
            raise ConfigError(f"--set {dotted}: '{p}' is a value, not a section")
        node = nxt
    node[parts[-1]] = value


#: Short aliases accepted by ``--set`` (``features=oracle`` means ``run.features=oracle``).
SET_ALIASES: dict[str, str] = {"features": "run.features", "seed": "run.seed", "mode": "adaptation.mode"}


M = TypeVar("M", bound=BaseModel)


def load_toml_model(
    model: type[M],
    path: Path | None,
    overrides: list[str] | tuple[str, ...] = (),
    example_file: str = "online/rollout.toml",
    aliases: dict[str, str] | None = None,
) -> M:
    """Load any config model from TOML (``None``: defaults), apply ``key=value`` overrides and
    validate. Raises ``ConfigError`` (one line) for a missing/unparsable file, a malformed
    override, an unknown key, a wrong type or an out-of-range value."""
    tree: dict[str, Any] = {}
    if path is not None:
        path = Path(path)
        if not path.is_file():
            raise ConfigError(f"config file '{path}' not found (pass an existing .toml file)")
        try:
            tree = tomllib.loads(path.read_text())
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
            raise ConfigError(f"config file '{path}' is not valid TOML: {exc}") from None
    for item in overrides:
        if "=" not in item:
            raise ConfigError(f"--set '{item}': expected key=value (see {example_file})")
        key, _, text = item.partition("=")
        key = (aliases or {}).get(key.strip(), key.strip())
        _set_dotted(tree, key, _parse_value(text.strip()))
    try:
        cfg = model.model_validate(tree)
    except ValidationError as err:
        raise ConfigError(_format_validation_error(err, model).replace("online/rollout.toml", example_file)) from None
    bad = _non_finite_key(cfg.model_dump())  # models not derived from _Cfg (sweep, compare, pretrain) too
    if bad is not None:
        raise ConfigError(f"config key '{bad}': must be a finite number (not nan or inf)")
    return cfg


def load_config(path: Path | None, overrides: list[str] | tuple[str, ...] = ()) -> ExperimentCfg:
    """Load an experiment config (``kinadapt online``); see ``load_toml_model``."""
    return load_toml_model(ExperimentCfg, path, overrides, "online/rollout.toml", SET_ALIASES)


def config_to_toml(cfg: BaseModel) -> str:
    """The fully resolved config as TOML text (tuples become arrays; an unset optional section,
    ``None``, is left out: TOML has no null)."""
    return tomli_w.dumps(cfg.model_dump(mode="json", exclude_none=True))
