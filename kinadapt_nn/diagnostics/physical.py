"""The physical nominal model of a user's set-up, and the effect library in the sensor frame.

Everything here comes from the setup file (``kinadapt_nn.diagnostics.setup``) and what the robot
logged (encoders, the F/T reading, time). Nothing needs a tare window, a contact stiffness or
this package's simulator (docs/diagnose.md).

Convention inside this module: ``r`` (N, 6) is the wrench the tool exerts ON the sensor, in the
sensor frame s, about the sensor origin [N; N m] (``setup.log.sign`` converts the log). Frames:
``w`` world (z up, gravity ``-9.81 z``), ``f`` the arm model's flange site, ``s`` the sensor.

Nominal model (free space). The declared tool (mass m, COM c, inertia I_c, all in s) is a rigid
body on the sensor. With ``g_s`` gravity, ``a_s`` the acceleration of the sensor origin, ``omega``
and ``alpha`` the angular velocity and acceleration (all in s, from the encoders)::

    F = m (g_s - a_s) - alpha x (m c) - omega x (omega x (m c))
    M = (m c) x (g_s - a_s) - I_O alpha - omega x (I_O omega),   I_O = I_c + m (|c|^2 1 - c c^T)

(Newton-Euler about the sensor origin; linear in the ten inertial parameters.)

Contact. Any contact acts through the declared tip ``p`` (in s): the contact wrench at the sensor
is ``[F_c; p x F_c]``, whatever the surface. The force is unknown, so in contact only the moment
about the tip is a model prediction: ``L r = M - p x F`` equals ``L w_nominal``. Contact samples are
those whose force departs from the tool model by more than ``contact.detect_force_N`` (widened by
``contact.margin_s``); the ``L`` rows hold anywhere, so calling a free sample "contact" only loses
information, never biases.

Effects (columns linear in physical parameters; ``EffectSpec`` below; units in the user's
convention at report time):

===================  ===================================  =============================================
effect               parameters                           change of r
===================  ===================================  =============================================
tool_gravity         added mass dm [kg], dm*c_x,y,z       [dm (g_s - a_s) - alpha x dmc - omega x (omega
                     [kg m] (c: the added mass's COM, s)  x dmc); dmc x (g_s - a_s)] (added inertia
                                                          neglected)
ft_bias_drift        rate_fx..tz [N/s, N m/s]             rate * (t - t_0)
ft_frame_rotation    rotation vector delta of the         r_meas = R(delta)^T r = r + r x delta (first
                     sensor axes [rad]                    order), r the true wrench in declared axes
encoder_offset       one joint's zero offset [rad]        d w_nominal / d q_j (true q = reading +
                     (joints 1-7, "one of")               offset; the whole model differentiated)
tool_tilt            tool rotated in the grasp about      COM moves by delta x c (gravity), the tip by
                     s x, s y [rad]                       delta x p (contact moment (delta x p) x F_c)
ft_offset            constant offset [N, N m]             + offset (untared logs only; a tared log's
                                                          offset is a nuisance fitted always)
===================  ===================================  =============================================

A joint-1 offset cannot be seen from gravity and the tool's own inertia at all: rotating the
whole arm about the vertical leaves every sensor-frame quantity unchanged. A joint-7 offset and
a sensor rotation about the flange axis are the same change when the COM and the tip are on that
axis. The ranking reports such cases as ``cannot_decide``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, NamedTuple

import numpy as np

from kinadapt_nn.diagnostics.setup import PHYSICAL_EFFECTS, SetupCfg
from kinadapt_nn.errors import KinadaptError, ModelFileError

G_W = np.array([0.0, 0.0, -9.81])  #: [m/s^2] gravity in the world frame
#: library effects that are judged only on this package's own bore/socket runs (``kinadapt diagnose RUN``)
CONTACT_MODEL_EFFECTS = ("contact_stiffness", "contact_friction_couple", "grasp_compliance")
N_JOINTS = 7
#: [s] Savitzky-Golay window of the velocity derivative (accelerations)
ACC_WINDOW_S = 0.1


class KinSeries(NamedTuple):
    """Sensor-frame kinematics of every sample (N samples), from the encoders."""

    R_ws: np.ndarray  #: (N, 3, 3) sensor axes in the world
    g_s: np.ndarray  #: (N, 3) gravity in s [m/s^2]
    a_s: np.ndarray  #: (N, 3) acceleration of the sensor origin in s [m/s^2]
    omega_s: np.ndarray  #: (N, 3) angular velocity in s [rad/s]
    alpha_s: np.ndarray  #: (N, 3) angular acceleration in s [rad/s^2]


class ArmModel:
    """The arm's MJCF for forward kinematics and site Jacobians (looked up once)."""

    def __init__(self, setup: SetupCfg) -> None:
        import mujoco

        path = setup.arm.path()
        if not path.is_file():
            raise ModelFileError(f"arm model '{path}' not found (fix [arm] mjcf in the setup file; \"\" = the shipped Panda)")
        try:
            self.model = mujoco.MjModel.from_xml_path(str(path))
        except Exception as exc:  # mujoco raises ValueError with a multi-line message
            raise ModelFileError(f"arm model '{path}' could not be loaded: {str(exc).splitlines()[0]}") from None
        self.site = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_SITE, setup.arm.flange_site)
        if self.site < 0:
            names = [self.model.site(i).name for i in range(self.model.nsite)]
            raise KinadaptError(f"arm model '{path}' has no site '{setup.arm.flange_site}' (fix [arm] flange_site; "
                                f"sites: {', '.join(names) or 'none'})")
        if self.model.nq < N_JOINTS:
            raise KinadaptError(f"arm model '{path}' has {self.model.nq} joint coordinates; the log has 7 joints")
        self.data = mujoco.MjData(self.model)
        self.R_fs = setup.sensor.R_fs()
        self.p_fs = np.asarray(setup.sensor.position_flange_m, dtype=float)
        self._mj = mujoco

    def series(self, q: np.ndarray, qdot: np.ndarray, t_s: np.ndarray) -> KinSeries:
        """Sensor kinematics for (N, 7) joint positions/velocities at times (N,) -> ``KinSeries``.

        Velocities from the site Jacobian, accelerations by a Savitzky-Golay derivative of the
        world-frame sensor twist (window ``ACC_WINDOW_S``)."""
        mj, m, d = self._mj, self.model, self.data
        n = len(q)
        R_ws = np.empty((n, 3, 3))
        v_w = np.empty((n, 3))
        w_w = np.empty((n, 3))
        jacp = np.zeros((3, m.nv))
        jacr = np.zeros((3, m.nv))
        qpos = d.qpos
        xmat = d.site_xmat[self.site]
        nv7 = min(m.nv, N_JOINTS)
        for i in range(n):
            qpos[:N_JOINTS] = q[i]
            mj.mj_kinematics(m, d)
            mj.mj_comPos(m, d)
            mj.mj_jacSite(m, d, jacp, jacr, self.site)
            R_wf = xmat.reshape(3, 3)
            R_ws[i] = R_wf @ self.R_fs
            w = jacr[:, :nv7] @ qdot[i, :nv7]
            w_w[i] = w
            v_w[i] = jacp[:, :nv7] @ qdot[i, :nv7] + np.cross(w, R_wf @ self.p_fs)
        dv = derivative(v_w, t_s)
        dw = derivative(w_w, t_s)
        rot = lambda x: np.einsum("nji,nj->ni", R_ws, x)  # noqa: E731  (world -> s)
        return KinSeries(R_ws, rot(np.broadcast_to(G_W, (n, 3))), rot(dv), rot(w_w), rot(dw))


def derivative(x: np.ndarray, t_s: np.ndarray, window_s: float = ACC_WINDOW_S) -> np.ndarray:
    """Smoothed time derivative of (N, k) samples: Savitzky-Golay (cubic) over ``window_s`` on
    the median step (the readers refuse gaps), ``np.gradient`` for very short logs."""
    from scipy.signal import savgol_filter

    n = len(x)
    dt = float(np.median(np.diff(t_s))) if n > 1 else 1.0
    k = int(round(window_s / dt)) | 1
    if n < max(k, 7):
        return np.gradient(x, t_s, axis=0) if n > 1 else np.zeros_like(x)
    return savgol_filter(x, max(k, 5), 3, deriv=1, delta=dt, axis=0, mode="interp")


def tool_wrench(kin: KinSeries, mass: float, mc_s: np.ndarray, I_O: np.ndarray) -> np.ndarray:
    """Rigid-body wrench a tool exerts on the sensor (s, about its origin), Newton-Euler
    (module docstring). mass [kg], first moment ``m c`` (3,) [kg m], inertia about the sensor
    origin (3, 3) [kg m^2] -> (N, 6)."""
    ga = kin.g_s - kin.a_s
    F = mass * ga - np.cross(kin.alpha_s, mc_s) - np.cross(kin.omega_s, np.cross(kin.omega_s, mc_s))
    Iw = kin.omega_s @ I_O.T
    M = np.cross(mc_s, ga) - kin.alpha_s @ I_O.T - np.cross(kin.omega_s, Iw)
    return np.concatenate([F, M], axis=1)


def nominal_inertials(setup: SetupCfg) -> tuple[float, np.ndarray, np.ndarray]:
    """(m [kg], m c (3,) [kg m], I_O (3, 3) [kg m^2] about the sensor origin) of the declared tool."""
    from kinadapt_nn.diagnostics.setup import inertia_matrix

    m = float(setup.tool.mass_kg)
    c = np.asarray(setup.tool.com_sensor_m, dtype=float)
    I_O = inertia_matrix(setup.tool.inertia_com_kg_m2) + m * (float(c @ c) * np.eye(3) - np.outer(c, c))
    return m, m * c, I_O


def tip_moment_map(tip_s: np.ndarray) -> np.ndarray:
    """``L = [-[p]x, 1]`` (3, 6): a sensor wrench -> its moment about the tip ``p`` (s)."""
    p = np.asarray(tip_s, dtype=float)
    px = np.array([[0.0, -p[2], p[1]], [p[2], 0.0, -p[0]], [-p[1], p[0], 0.0]])
    return np.concatenate([-px, np.eye(3)], axis=1)


class Prepared(NamedTuple):
    """A log through the nominal model (N samples): what the effect columns need."""

    t_s: np.ndarray  #: (N,) [s]
    q_rad: np.ndarray  #: (N, 7)
    qdot_rad_s: np.ndarray  #: (N, 7)
    r: np.ndarray  #: (N, 6) measured wrench, tool on sensor, s [N, N m]
    w_nom: np.ndarray  #: (N, 6) the declared tool's wrench (nominal model)
    kin: KinSeries
    contact: np.ndarray  #: (N,) bool: contact rows (tip-moment only)
    f_contact_s: np.ndarray  #: (N, 3) contact force as the sensor reads it (r - w_nom - offset, force rows), 0 in free space
    L: np.ndarray  #: (3, 6) tip-moment map
    setup: SetupCfg
    arm: ArmModel


# ------------------------------------------------------------------------------------- effects
def _cols_tool_gravity(p: Prepared) -> np.ndarray:
    kin = p.kin
    n = len(p.t_s)
    ga = kin.g_s - kin.a_s
    C = np.zeros((n, 6, 4))
    C[:, :3, 0] = ga
    for j in range(3):
        e = np.zeros(3)
        e[j] = 1.0
        C[:, :3, 1 + j] = -np.cross(kin.alpha_s, e) - np.cross(kin.omega_s, np.cross(kin.omega_s, e))
        C[:, 3:, 1 + j] = np.cross(e, ga)
    return C


def _cols_ft_bias_drift(p: Prepared) -> np.ndarray:
    n = len(p.t_s)
    C = np.zeros((n, 6, 6))
    for j in range(6):
        C[:, j, j] = p.t_s - p.t_s[0]
    return C


def _cols_ft_frame_rotation(p: Prepared) -> np.ndarray:
    """``r x e_j``: the measured wrench stands for the true one (first order in delta; it holds
    whatever loads the sensor: the tool, an undeclared mass, a contact). A tared log's missing
    ``w(q_tare) x delta`` is constant and goes into the offset nuisance."""
    w = p.r
    n = len(p.t_s)
    C = np.zeros((n, 6, 3))
    for j in range(3):
        e = np.zeros(3)
        e[j] = 1.0
        C[:, :3, j] = np.cross(w[:, :3], e)  # R(delta)^T F = F + F x delta
        C[:, 3:, j] = np.cross(w[:, 3:], e)
    return C


def _cols_encoder_offset(p: Prepared, eps: float = 1e-5) -> np.ndarray:
    """d w_nominal / d q_j: the whole nominal model (gravity direction and the tool's inertial
    load) recomputed with joint j's reading moved by ``eps`` (central difference)."""
    m, mc, I_O = nominal_inertials(p.setup)
    n = len(p.t_s)
    C = np.zeros((n, 6, N_JOINTS))
    for j in range(N_JOINTS):
        dq = np.zeros(N_JOINTS)
        dq[j] = eps
        hi = tool_wrench(p.arm.series(p.q_rad + dq, p.qdot_rad_s, p.t_s), m, mc, I_O)
        lo = tool_wrench(p.arm.series(p.q_rad - dq, p.qdot_rad_s, p.t_s), m, mc, I_O)
        C[:, :, j] = (hi - lo) / (2 * eps)
    return C


def _cols_tool_tilt(p: Prepared) -> np.ndarray:
    m, mc, _ = nominal_inertials(p.setup)
    grav = _cols_tool_gravity(p)[:, :, 1:]  # per unit first moment (N, 6, 3)
    tip = np.asarray(p.setup.tool.tip_sensor_m, dtype=float)
    n = len(p.t_s)
    C = np.zeros((n, 6, 2))
    for j in range(2):
        e = np.zeros(3)
        e[j] = 1.0
        C[:, :, j] = grav @ np.cross(e, mc)  # the COM moves by delta x c
        C[:, 3:, j] += np.cross(np.cross(e, tip), p.f_contact_s)  # the contact acts at p + delta x p
    return C


def _cols_ft_offset(p: Prepared) -> np.ndarray:
    C = np.zeros((len(p.t_s), 6, 6))
    for j in range(6):
        C[:, j, j] = 1.0
    return C


@dataclass(frozen=True)
class EffectSpec:
    """One effect of the physical library: columns (internal convention), parameter names and
    units, the smallest magnitude worth reporting per parameter (the ranking's scale: below it an
    effect is not called present, and "absent" needs the data to be able to see it), and the
    motion that excites it."""

    name: str
    params: tuple[str, ...]
    units: tuple[str, ...]
    columns: Callable[[Prepared], np.ndarray]  #: Prepared -> (N, 6, k)
    relevant: tuple[float, ...]  #: (k,) smallest relevant magnitude per parameter (internal units)
    excite_hint: str
    doc: str
    one_of: bool = False  #: one column at a time (e.g. one joint's offset)


def _relevant_gravity() -> tuple[float, ...]:
    return (0.03, 0.0015, 0.0015, 0.0015)  # 30 g; 30 g at 50 mm


SPECS: dict[str, EffectSpec] = {s.name: s for s in (
    EffectSpec("tool_gravity", ("mass", "mass*com_x", "mass*com_y", "mass*com_z"), ("kg", "kg m", "kg m", "kg m"),
               _cols_tool_gravity, _relevant_gravity(),
               "reorient the tool in free space through several poses (tilts of 20-40 deg about two horizontal axes)",
               "a mass on the tool that the setup does not declare (or a wrong declared mass/COM)"),
    EffectSpec("ft_bias_drift", ("rate_fx", "rate_fy", "rate_fz", "rate_tx", "rate_ty", "rate_tz"),
               ("N/s", "N/s", "N/s", "N m/s", "N m/s", "N m/s"), _cols_ft_bias_drift,
               (0.03, 0.03, 0.03, 0.003, 0.003, 0.003),
               "a longer log, returning to the same free-space poses at its start and end",
               "the F/T offset drifts linearly in time"),
    EffectSpec("ft_frame_rotation", ("rot_x", "rot_y", "rot_z"), ("rad", "rad", "rad"), _cols_ft_frame_rotation,
               (np.deg2rad(1.0),) * 3,
               "reorient in free space (gravity along several sensor axes) and push in contact in two directions",
               "the sensor's axes are rotated from their declared mounting"),
    EffectSpec("encoder_offset", tuple(f"offset_joint{j}" for j in range(1, 8)), ("rad",) * 7, _cols_encoder_offset,
               (np.deg2rad(0.5),) * 7,
               "move every joint in free space so that gravity turns in the sensor frame (a joint-1 offset is "
               "invisible to gravity: it needs a world-fixed load direction, e.g. a horizontal push against a fixture)",
               "a joint encoder zero offset (one of joints 1-7)", one_of=True),
    EffectSpec("tool_tilt", ("tilt_x", "tilt_y"), ("rad", "rad"), _cols_tool_tilt, (np.deg2rad(1.0),) * 2,
               "push the tip in contact in two lateral directions (the tip lever shows in the moment)",
               "the tool sits rotated in the grasp (its COM and tip move)"),
    EffectSpec("ft_offset", ("fx", "fy", "fz", "tx", "ty", "tz"), ("N", "N", "N", "N m", "N m", "N m"), _cols_ft_offset,
               (0.2, 0.2, 0.2, 0.02, 0.02, 0.02),
               "reorient in free space (a constant offset does not turn with gravity)",
               "a constant F/T offset in an untared log"),
)}


def applicable_effects(setup: SetupCfg) -> list[str]:
    """The effects judged for this set-up, after the analysis filters."""
    names = [n for n in PHYSICAL_EFFECTS if not (n == "ft_offset" and setup.log.tared)]
    if setup.contact.mode != "tip":  # without tip contact a tilt is only a COM shift (tool_gravity's columns)
        names = [n for n in names if n != "tool_tilt"]
    if setup.analysis.effects:
        names = [n for n in names if n in setup.analysis.effects]
    return [n for n in names if n not in setup.analysis.exclude_effects]


def to_user(name: str, p: np.ndarray, sd: np.ndarray, setup: SetupCfg) -> dict:
    """An estimate in the user's convention and units: ``{param: {value, sd, unit}}``.

    tool_gravity: added ``mass`` [kg] and the COM of the added mass ``com_x/y/z`` [m] (sensor
    frame; first-order sd); rotations and offsets in degrees; drift and offset rates in the log's
    own wrench convention (``wrench_acts``)."""
    def q(v, s, unit):
        return {"value": float(v), "sd": float(s), "unit": unit}

    sign = setup.log.sign
    if name == "tool_gravity":
        dm, sdm = float(p[0]), float(sd[0])
        out = {"mass": q(dm, sdm, "kg")}
        for a, mc, smc in zip("xyz", p[1:], sd[1:]):
            if abs(dm) < 0.03:  # no relevant added mass: the change is a shift of the declared COM
                out[f"com_{a}"] = {"value": None, "sd": None, "unit": "m",
                                   "note": "no relevant added mass: see first_moment_* and total_com_*"}
                continue
            c = mc / dm
            sc = abs(c) * np.hypot(smc / max(abs(mc), 1e-12), sdm / max(abs(dm), 1e-12))
            out[f"com_{a}"] = q(c, sc, "m")
        m0, mc0, _ = nominal_inertials(setup)
        tot = m0 + dm
        out["total_mass"] = q(tot, sdm, "kg")
        for a, mc, smc in zip("xyz", p[1:], sd[1:]):  # the change of the tool's first moment m c
            out[f"first_moment_{a}"] = q(mc, smc, "kg m")
        for a, mc_t in zip("xyz", mc0 + p[1:]):
            out[f"total_com_{a}"] = q(mc_t / tot if abs(tot) > 1e-9 else np.nan, np.nan, "m")
        return out
    spec = SPECS[name]
    if name in ("ft_frame_rotation", "encoder_offset", "tool_tilt"):
        return {pn: q(np.rad2deg(v), np.rad2deg(s), "deg") for pn, v, s in zip(spec.params, p, sd)}
    if name in ("ft_bias_drift", "ft_offset"):
        return {pn: q(sign * v, s, u) for pn, v, s, u in zip(spec.params, p, sd, spec.units)}
    return {pn: q(v, s, u) for pn, v, s, u in zip(spec.params, p, sd, spec.units)}


def implausible(name: str, p: np.ndarray, setup: SetupCfg) -> str | None:
    """Why an estimate is physically impossible (None when it is possible)."""
    if not np.all(np.isfinite(p)):
        return "the estimate is not finite"
    if name == "tool_gravity":
        tot = setup.tool.mass_kg + p[0]
        if tot <= 0:
            return f"the tool would weigh {tot:.3g} kg (declared {setup.tool.mass_kg:g} kg + {p[0]:.3g} kg)"
        # a real added mass sits within 1 m of the sensor; below the relevant mass (30 g) the
        # estimate is a shift of the declared COM (first moment), reported as total_com_*
        if abs(p[0]) >= 0.03 and np.linalg.norm(p[1:] / p[0]) > 1.0:
            return f"the added mass would sit {np.linalg.norm(p[1:] / p[0]):.3g} m from the sensor"
    if name in ("ft_frame_rotation", "encoder_offset", "tool_tilt") and np.max(np.abs(p)) > np.deg2rad(15.0):
        return f"{np.rad2deg(np.max(np.abs(p))):.3g} deg is beyond a mounting/zero error (the model is first order)"
    if name == "ft_bias_drift" and np.max(np.abs(p)) > 10.0:
        return f"a drift of {np.max(np.abs(p)):.3g} per second is not a sensor drift"
    return None
