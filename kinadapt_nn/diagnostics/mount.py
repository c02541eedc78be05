"""The sensor mount, estimated at any angle: the classic F/T calibration, on every user log.

Unknowns (13): the rotation ``D`` of the true sensor axes from the declared ones (``R_fs,true =
R_fs,declared D``), the tool's mass ``m`` [kg], its first moment ``m c`` [kg m] (c in the true
sensor frame s) and a constant offset ``b`` (6,) [N, N m]. Model of the wrench the tool exerts on
the sensor (``physical`` module docstring), with every kinematic vector of the declared frame
turned into the true one (``x_s = D^T x_declared``)::

    F = m g_a - alpha x (m c) - omega x (omega x (m c)) + b_F,      g_a = D^T (g_s - a_s)
    M = (m c) x g_a - I_O alpha - omega x (I_O omega) + b_M

(the declared inertia ``I_O`` in s). A linear start (``F = K g_a + b_F``: ``K = m D^T``; the
nearest rotation by SVD; then ``m c`` and ``b_M`` linear in the moments) and the declared mount
``D = 1`` both start a Gauss-Newton refinement of all 13 unknowns on the noise-weighted free-space
samples (``scipy.optimize.least_squares``, robust to the few contact/outlier samples through a
soft-L1 loss); the better end wins. Uncertainties: the larger of the information-limited sd
(``s^2 (J^T J)^-1``, never a pseudo-inverse: an unexcited direction gets a large, finite sd) and a
delete-one-block jackknife over the diagnosis's cross-validation blocks.

``declared_consistent``: the declared mount agrees with the data when the fitted rotation is not
significant (< 3 sd) or when the first-order rotation effect (``ft_frame_rotation``) can represent
it: the neglected second-order term ``|w| theta^2 / 2`` stays below the relevant sizes on every
sample and ``theta <= 15 deg``. Everything reported is in the setup's own convention (roll, pitch,
yaw of ``R_fs = Rz(yaw) Ry(pitch) Rx(roll)``) and the offset/residual in the log's units.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from kinadapt_nn.diagnostics.setup import TORQUE_UNITS, rpy_matrix

MAX_ROWS = 3000  #: samples used by the fit (evenly spaced subset)
MAX_FIRST_ORDER_DEG = 15.0
COM_PLAUSIBLE_M = 0.5  #: [m] a tool's centre of mass farther from the sensor than this is not a tool
SIGNIFICANT_SD = 3.0


def skew(v: np.ndarray) -> np.ndarray:
    x, y, z = (float(a) for a in v)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def rotvec_matrix(v: np.ndarray) -> np.ndarray:
    """Rodrigues: rotation vector (3,) [rad] -> (3, 3)."""
    th = float(np.linalg.norm(v))
    if th < 1e-12:
        return np.eye(3) + skew(v)
    k = skew(np.asarray(v) / th)
    return np.eye(3) + np.sin(th) * k + (1.0 - np.cos(th)) * (k @ k)


def matrix_rpy(R: np.ndarray) -> np.ndarray:
    """(3, 3) -> (roll, pitch, yaw) [rad] of ``R = Rz(yaw) Ry(pitch) Rx(roll)``."""
    pitch = float(np.arcsin(np.clip(-R[2, 0], -1.0, 1.0)))
    roll = float(np.arctan2(R[2, 1], R[2, 2]))
    yaw = float(np.arctan2(R[1, 0], R[0, 0]))
    return np.array([roll, pitch, yaw])


def rotation_angle(R: np.ndarray) -> float:
    """[rad] angle of a rotation matrix."""
    return float(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)))


def _wrap_deg(a: np.ndarray) -> np.ndarray:
    return (np.asarray(a) + 180.0) % 360.0 - 180.0


class MountData(NamedTuple):
    """The free-space samples the fit uses (n samples, declared sensor frame)."""

    ga: np.ndarray  #: (n, 3) [m/s^2] g_s - a_s in the declared s
    omega: np.ndarray  #: (n, 3) [rad/s]
    alpha: np.ndarray  #: (n, 3) [rad/s^2]
    r: np.ndarray  #: (n, 6) [N, N m] the measured wrench (tool on sensor, SI)
    w: np.ndarray  #: (6,) channel weights [1/N, 1/(N m)]
    I_O: np.ndarray  #: (3, 3) [kg m^2] declared inertia about the sensor origin
    block: np.ndarray  #: (n,) cross-validation block of each sample


def _model(x: np.ndarray, d: MountData) -> np.ndarray:
    """(13,) [rotvec, m, mc, b] -> predicted wrench (n, 6)."""
    D = rotvec_matrix(x[:3])
    m, mc, b = x[3], x[4:7], x[7:13]
    ga, om, al = d.ga @ D, d.omega @ D, d.alpha @ D  # rows: D^T v
    F = m * ga - np.cross(al, mc) - np.cross(om, np.cross(om, mc))
    M = np.cross(mc, ga) - al @ d.I_O.T - np.cross(om, om @ d.I_O.T)
    return np.concatenate([F, M], axis=1) + b


def _resid(x: np.ndarray, d: MountData) -> np.ndarray:
    return ((d.r - _model(x, d)) * d.w).reshape(-1)


def _linear_start(d: MountData) -> np.ndarray | None:
    """The closed-form start: F = K g_a + b_F, K = m D^T -> m, D (SVD); then m c, b_M linear."""
    n = len(d.ga)
    A = np.concatenate([d.ga, np.ones((n, 1))], axis=1)  # (n, 4)
    if n < 8 or np.linalg.cond(A) > 1e8:  # gravity does not turn through the sensor: no closed form
        return None
    coef, *_ = np.linalg.lstsq(A, d.r[:, :3], rcond=None)  # (4, 3): F_j = sum_i ga_i K[j, i] + b_j
    K, bF = coef[:3].T, coef[3]
    U, S, Vt = np.linalg.svd(K)
    sign = 1.0 if np.linalg.det(U @ Vt) > 0 else -1.0  # det < 0: a negative mass (flipped convention)
    Rk = sign * (U @ Vt)  # proper rotation ~ D^T
    m = sign * float(np.mean(S))
    D = Rk.T
    ga_t = d.ga @ D
    B = np.zeros((n, 3, 6))  # M = mc x ga_t + bM = -ga_t x mc + bM
    for j in range(3):
        e = np.zeros(3)
        e[j] = 1.0
        B[:, :, j] = np.cross(e, ga_t)
        B[:, j, 3 + j] = 1.0
    cm, *_ = np.linalg.lstsq(B.reshape(-1, 6), d.r[:, 3:].reshape(-1), rcond=None)
    from scipy.spatial.transform import Rotation

    return np.concatenate([Rotation.from_matrix(D).as_rotvec(), [m], cm[:3], bF, cm[3:]])


def _solve(d: MountData, starts: list[np.ndarray], robust: bool = True) -> tuple[np.ndarray, float]:
    from scipy.optimize import least_squares

    best, cost = None, np.inf
    for x0 in starts:
        sol = least_squares(_resid, x0, args=(d,), method="trf", loss="soft_l1" if robust else "linear",
                            f_scale=3.0, x_scale="jac", max_nfev=200)
        c = float(np.sum(_resid(sol.x, d) ** 2))
        if c < cost:
            best, cost = sol.x, c
    return _canonical(best), cost


def _canonical(x: np.ndarray) -> np.ndarray:
    """The rotation vector with angle in [0, pi] (the same rotation, a unique representation)."""
    from scipy.spatial.transform import Rotation

    x = x.copy()
    x[:3] = Rotation.from_rotvec(x[:3]).as_rotvec()
    return x


def _rpy_deg(x: np.ndarray, R_fs_decl: np.ndarray) -> np.ndarray:
    return np.rad2deg(matrix_rpy(R_fs_decl @ rotvec_matrix(x[:3])))


class MountFit(NamedTuple):
    x: np.ndarray  #: (13,) [rotvec (declared s), m, mc, b]
    sd: np.ndarray  #: (13,) finite
    rpy_deg: np.ndarray  #: (3,) in the setup's convention
    rpy_sd_deg: np.ndarray  #: (3,)
    angle_deg: float  #: rotation from the declared mount
    angle_sd_deg: float
    residual: np.ndarray  #: (n, 6) [N, N m] measured - fitted, SI
    report: dict  #: diagnosis.json "sensor_mount"


def fit(s, free: np.ndarray, block: np.ndarray, sigma: np.ndarray, max_blocks: int = 20) -> MountFit:
    """The calibration fit on the free-space samples ``free`` (n,) bool of ``LogSignals`` s.
    ``block`` (n,) the cross-validation block of every sample; ``sigma`` (6,) the per-channel
    noise. -> ``MountFit`` (module docstring)."""
    from kinadapt_nn.diagnostics.physical import nominal_inertials

    setup = s.setup
    idx = np.flatnonzero(free)
    if len(idx) > MAX_ROWS:
        idx = idx[np.linspace(0, len(idx) - 1, MAX_ROWS).round().astype(int)]
    _, mc0, I_O = nominal_inertials(setup)
    d = MountData(s.g_s[idx] - s.a_s[idx], s.omega_s[idx], s.alpha_s[idx], s.wrench[idx], 1.0 / sigma, I_O, block[idx])
    m0 = float(setup.tool.mass_kg)
    starts = [np.concatenate([np.zeros(3), [m0], mc0, np.zeros(6)])]
    lin = _linear_start(d)
    if lin is not None and np.all(np.isfinite(lin)):
        starts.append(lin)
    x, _ = _solve(d, starts)
    # information-limited covariance (ordinary least squares at the solution)
    J = _jac(x, d)
    e = _resid(x, d)
    dof = max(len(e) - len(x), 1)
    s2 = float(e @ e) / dof
    H = J.T @ J
    H += np.eye(len(x)) * 1e-12 * max(np.trace(H), 1e-300) / len(x)
    cov = s2 * np.linalg.inv(H)
    # block jackknife (correlated residuals of a moving log make the information sd too small)
    ub = np.unique(d.block)
    if len(ub) > max_blocks:  # merge blocks evenly
        groups = np.array_split(ub, max_blocks)
        remap = {b: g for g, arr in enumerate(groups) for b in arr}
        bl = np.array([remap[b] for b in d.block])
    else:
        bl = np.searchsorted(ub, d.block)
    nb = int(bl.max()) + 1
    reps = []
    if nb >= 3:
        from scipy.optimize import least_squares

        for b in range(nb):
            keep = bl != b
            db = d._replace(ga=d.ga[keep], omega=d.omega[keep], alpha=d.alpha[keep], r=d.r[keep], block=d.block[keep])
            sol = least_squares(_resid, x, args=(db,), method="trf", loss="soft_l1", f_scale=3.0, x_scale="jac",
                                max_nfev=30)
            reps.append(_canonical(sol.x))
    reps = np.array(reps)
    sd_info = np.sqrt(np.maximum(np.diag(cov), 0.0))
    # rotation and rpy: compare replicates through relative rotations (no wrap-around trouble)
    R_decl = setup.sensor.R_fs()
    rpy = _rpy_deg(x, R_decl)
    Rx = rotvec_matrix(x[:3])
    if len(reps):
        dev = np.array([_relvec(Rx, rotvec_matrix(rp[:3])) for rp in reps])  # (nb, 3) small rotvecs
        jk = lambda a: np.sqrt((nb - 1) / nb * np.sum((a - a.mean(0)) ** 2, axis=0))  # noqa: E731
        sd_jk = jk(reps)
        sd_jk[:3] = jk(dev)
        rpy_reps = np.array([_wrap_deg(_rpy_deg(rp, R_decl) - rpy) for rp in reps])
        rpy_sd_jk = jk(rpy_reps)
        ang_reps = np.rad2deg([rotation_angle(rotvec_matrix(rp[:3])) for rp in reps])
        ang_sd_jk = float(jk(ang_reps[:, None])[0])
    else:
        sd_jk, rpy_sd_jk, ang_sd_jk = np.zeros(13), np.zeros(3), 0.0
    sd = np.maximum(sd_info, sd_jk)
    # information sd of rpy and of the angle: through numerical derivatives in the local rotation
    G = np.zeros((3, 3))
    ga_ = np.zeros(3)
    th = rotation_angle(Rx)
    for k in range(3):
        dv = np.zeros(3)
        dv[k] = 1e-6
        xk = x.copy()
        xk[:3] = _relvec(np.eye(3), Rx @ rotvec_matrix(dv))
        G[:, k] = _wrap_deg(_rpy_deg(xk, R_decl) - rpy) / 1e-6
        ga_[k] = (rotation_angle(Rx @ rotvec_matrix(dv)) - th) / 1e-6
    # covariance of the local rotation: the rotvec block maps to the local frame by the right Jacobian;
    # with |dv| small the information covariance of the local rotation is that of x[:3] mapped by Jr^-1
    Jloc = _local_jac(x[:3])
    cov_loc = Jloc @ cov[:3, :3] @ Jloc.T
    rpy_sd = np.maximum(np.sqrt(np.maximum(np.diag(G @ cov_loc @ G.T), 0.0)), rpy_sd_jk)
    ang_sd = max(float(np.rad2deg(np.sqrt(max(ga_ @ cov_loc @ ga_, 0.0)))), ang_sd_jk)
    # the fitted residual on every free sample (not only the subset)
    dall = d._replace(ga=s.g_s[free] - s.a_s[free], omega=s.omega_s[free], alpha=s.alpha_s[free], r=s.wrench[free],
                      block=block[free])
    res = dall.r - _model(x, dall)
    rep = report(x, sd, rpy, rpy_sd, float(np.rad2deg(th)), ang_sd, res, dall, s)
    return MountFit(x, sd, rpy, rpy_sd, float(np.rad2deg(th)), ang_sd, res, rep)


def predict(x: np.ndarray, s) -> np.ndarray:
    """The calibrated model's wrench (n, 6) [N, N m] on every sample of ``LogSignals`` s."""
    from kinadapt_nn.diagnostics.physical import nominal_inertials

    _, _, I_O = nominal_inertials(s.setup)
    d = MountData(s.g_s - s.a_s, s.omega_s, s.alpha_s, s.wrench, np.ones(6), I_O, np.zeros(s.n, int))
    return _model(x, d)


def plausibility(fitm: "MountFit", setup) -> list[str]:
    """Why the calibration fit is not a physical tool on a physical sensor (empty: plausible)."""
    out = []
    m = float(fitm.x[3])
    if m <= 0:
        out.append(f"the fitted tool mass is {m:.3g} kg (not positive)")
    elif np.linalg.norm(fitm.x[4:7] / m) > COM_PLAUSIBLE_M:
        out.append(f"the fitted centre of mass is {np.linalg.norm(fitm.x[4:7] / m):.3g} m from the sensor")
    rf, rt = setup.sensor.range_force_N, setup.sensor.range_torque_Nm
    if rf > 0 and np.max(np.abs(fitm.x[7:10])) > rf:
        out.append(f"the force offset {np.max(np.abs(fitm.x[7:10])):.3g} N exceeds the sensor's range ({rf:g} N)")
    if rt > 0 and np.max(np.abs(fitm.x[10:13])) > rt:
        out.append(f"the torque offset {np.max(np.abs(fitm.x[10:13])):.3g} N m exceeds the sensor's range ({rt:g} N m)")
    return out


def _relvec(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """Rotation vector of ``Ra^T Rb`` (the local difference)."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(Ra.T @ Rb).as_rotvec()


def _local_jac(v: np.ndarray) -> np.ndarray:
    """d(local rotation)/d(rotvec): numerical, (3, 3)."""
    R0 = rotvec_matrix(v)
    J = np.zeros((3, 3))
    for k in range(3):
        dv = np.zeros(3)
        dv[k] = 1e-7
        J[:, k] = _relvec(R0, rotvec_matrix(v + dv)) / 1e-7
    return J


def _jac(x: np.ndarray, d: MountData) -> np.ndarray:
    """Numerical Jacobian of the weighted residual (central differences), (6n, 13)."""
    J = np.empty((6 * len(d.ga), len(x)))
    for k in range(len(x)):
        h = 1e-6 * max(1.0, abs(x[k]))
        xp, xm = x.copy(), x.copy()
        xp[k] += h
        xm[k] -= h
        J[:, k] = (_resid(xp, d) - _resid(xm, d)) / (2 * h)
    return J


def report(x, sd, rpy, rpy_sd, angle_deg, angle_sd, res, d: MountData, s) -> dict:
    """The ``sensor_mount`` block of diagnosis.json (module docstring); offset/residual in the
    log's units and sign convention."""
    setup = s.setup
    scale = setup.log.wrench_scale()
    sign = setup.log.sign
    m = float(x[3])
    com = (x[4:7] / m).tolist() if abs(m) > 1e-9 else [None, None, None]
    com_sd = [None] * 3
    if abs(m) > 1e-9:
        c = x[4:7] / m
        com_sd = [float(abs(ci) * np.hypot(sd[4 + i] / max(abs(x[4 + i]), 1e-12), sd[3] / abs(m))) for i, ci in
                  enumerate(c)]
    wf = np.concatenate([np.linalg.norm(d.r[:, :3], axis=1)[:, None].repeat(3, 1),
                         np.linalg.norm(d.r[:, 3:], axis=1)[:, None].repeat(3, 1)], axis=1)
    rel = np.array([setup.analysis.relevant_force_N] * 3 + [setup.analysis.relevant_moment_Nm] * 3)
    th = np.deg2rad(angle_deg)
    second_order = float(np.max(wf.max(0) * th**2 / 2.0 / rel)) if len(wf) else 0.0
    significant = angle_deg > SIGNIFICANT_SD * max(angle_sd, 1e-9)
    representable = angle_deg <= MAX_FIRST_ORDER_DEG and second_order < 1.0
    consistent = bool(not significant or representable)
    out = {
        "rpy_flange_deg": [float(v) for v in rpy],
        "sd_deg": [float(v) for v in rpy_sd],
        "rotation_from_declared_deg": float(angle_deg),
        "rotation_sd_deg": float(angle_sd),
        "declared_rpy_flange_deg": [float(v) for v in setup.sensor.rpy_flange_deg],
        "declared_consistent": consistent,
        "mount_known": bool(setup.sensor.mount_known),
        "tool_mass_kg": m,
        "tool_mass_sd_kg": float(sd[3]),
        "tool_com_sensor_m": com,
        "tool_com_sd_m": com_sd,
        "offset": [float(v) for v in sign * x[7:13] / scale],
        "offset_sd": [float(v) for v in sd[7:13] / scale],
        "offset_units": [setup.log.force_unit] * 3 + [setup.log.torque_unit] * 3,
        "offset_convention": setup.log.wrench_acts,
        "residual_rms": [float(v) for v in np.sqrt(np.mean(res**2, axis=0)) / scale],
        "residual_units": [setup.log.force_unit] * 3 + [setup.log.torque_unit] * 3,
        "samples": int(len(res)),
        "second_order_to_relevant": second_order,
        "method": "rotation, mass, first moment and offset fitted jointly (Gauss-Newton from a closed-form start "
                  "and from the declared mount); sd = max(information, block jackknife)",
    }
    out["paste"] = "[sensor] rpy_flange_deg = [" + ", ".join(f"{v:.2f}" for v in rpy) + "]"
    return out


def unit_warning(fitm: MountFit, setup) -> str | None:
    """A plain warning when the torques (or forces) look like another unit than declared: the fit
    needs the centre of mass far outside any tool (torque unit), or the mass is off from the
    declared one by exactly a unit factor (force unit)."""
    m = float(fitm.x[3])
    if m <= 0:
        return None
    c = np.linalg.norm(fitm.x[4:7] / m)
    if c > COM_PLAUSIBLE_M:
        declared = TORQUE_UNITS[setup.log.torque_unit]
        cands = []
        for u, f in TORQUE_UNITS.items():
            scale = f / declared
            if u != setup.log.torque_unit and c * scale <= COM_PLAUSIBLE_M * 0.6:
                cands.append((abs(np.log(scale)), u, c * scale))
        txt = (f"the torques need the tool's centre of mass {c:.3g} m from the sensor, far outside any tool: "
               f"[log] torque_unit = \"{setup.log.torque_unit}\" looks wrong")
        if cands:
            _, u, cc = min(cands)
            txt += f" (as \"{u}\" the centre of mass would be {1000 * cc:.3g} mm away: set [log] torque_unit = \"{u}\")"
        return txt
    return None


__all__ = ["MountFit", "fit", "predict", "plausibility", "unit_warning", "matrix_rpy", "rotvec_matrix", "rotation_angle"]
