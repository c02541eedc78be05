"""The sensor mount, estimated at any angle: the classic F/T calibration, on every user log.

Unknowns (13, reported): the rotation ``D`` of the true sensor axes from the declared ones (``R_fs,true =
R_fs,declared D``), the tool's mass ``m`` [kg], its first moment ``m c`` [kg m] (c in the true
sensor frame s) and a constant offset ``b`` (6,) [N, N m]. Model of the wrench the tool exerts on
the sensor (``physical`` module docstring), with every kinematic vector of the declared frame
turned into the true one (``x_s = D^T x_declared``)::

    F = m g_a - alpha x (m c) - omega x (omega x (m c)) + b_F,      g_a = D^T (g_s - a_s)
    M = (m c) x g_a - I_O alpha - omega x (I_O omega) + b_M

(the declared inertia ``I_O`` in s; on a moving log the inertia beyond it, ``dI``, six more unknowns,
adds ``- dI alpha - omega x (dI omega)`` to M and is fitted as a nuisance: never reported, its
uncertainty marginalised out of the 13's). A linear start (``F = K g_a + b_F``: ``K = m D^T``; the
nearest rotation by SVD) and the declared mount ``D = 1`` both start a Gauss-Newton refinement on
the noise-weighted samples by variable projection (the model is linear in ``m``, ``m c`` and ``b``
for a fixed rotation: those ten are solved in closed form at every step, the rotation is updated
locally, ``D exp([delta])``), robust to the few contact/outlier samples through Huber weights
(IRLS); the better end wins. Uncertainties: the larger of the information-limited sd
(``s^2 (J^T J)^-1``, never a pseudo-inverse: an unexcited direction gets a large, finite sd) and a
delete-one-block jackknife over the diagnosis's cross-validation blocks.

``declared_consistent``: the declared mount agrees with the data when the fitted rotation is not
significant (< 3 sd), or when the first-order rotation effect (``ft_frame_rotation``) can represent
it (the neglected second-order term ``|w| theta^2 / 2`` stays below the relevant sizes on every
sample and ``theta <= 15 deg``), or when the rotation removes less than ``ROTATION_EXPLAINS`` of
the robust misfit the declared mount leaves (``rotation_explains``: then something other than the
mount distorts the fit -- physics outside the model -- and the mount is not what the data contradict). Everything reported is in the setup's own convention (roll, pitch,
yaw of ``R_fs = Rz(yaw) Ry(pitch) Rx(roll)``) and the offset/residual in the log's units.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from kinadapt_nn.diagnostics import steps

MAX_ROWS = 2000  #: samples used by the fit (evenly spaced subset)
N_THETA = 10  #: [m, m c, b] reported by the fit
N_INERTIA = 6  #: the inertia beyond the declared one, fitted beside them on a moving log (a nuisance)
STEP_TOL_RAD = 1e-8  #: Gauss-Newton stops when the rotation update is this small
MAX_FIRST_ORDER_DEG = 15.0
COM_PLAUSIBLE_M = 0.5  #: [m] a tool's centre of mass farther from the sensor than this is not a tool
MASS_PLAUSIBLE_FACTOR = 5.0  #: a fitted mass this many times the declared one is not the declared tool
UNDETERMINED_DEG = 10.0  #: [deg] a mount angle with a larger sd is reported undetermined
UNDETERMINED_MASS_REL = 0.2  #: a mass sd above this share of the mass: undetermined
UNDETERMINED_COM_M = 0.02  #: [m] a centre-of-mass coordinate with a larger sd: undetermined
SIGNIFICANT_SD = 3.0
ROTATION_EXPLAINS = 0.9  #: a declared mount is contradicted only when the rotation removes this share of its misfit
GN_ITERS = 300  #: Gauss-Newton iterations at most (a weakly turned sensor's curved valley takes ~100; 40 stopped 60 deg short)
MIRROR_COST = 4.5  #: robust cost (half chi^2) a positive-mass mirror fit may exceed the negative one by (3 sd)
WEAK_SCANS = 4  #: scans along the least-determined rotation axis, each followed by Gauss-Newton
HUBER_K = 3.0  #: [noise sd] the robust loss is quadratic up to this weighted residual
#: [m/s^2] free space whose g_a moves less than this (~6 deg of turn) cannot calibrate: the declared mount and
#: tool stand (``_declared_fit``); the sign check's and the segmentation's "turns" (``segmentation.TURN_MPS2``)
TURN_MIN_MPS2 = 1.0


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
    #: fit the inertia beyond the declared one as a nuisance on a moving log (``_moves``); False: the
    #: declared inertia holds (the units check: a free inertia would absorb a wrong torque unit's misfit)
    inertia: bool = True


def _without(d: MountData, drop: np.ndarray) -> MountData:
    """``d`` without the samples ``drop`` (n,) bool (a jackknife replicate)."""
    keep = ~drop
    return d._replace(ga=d.ga[keep], omega=d.omega[keep], alpha=d.alpha[keep], r=d.r[keep], block=d.block[keep])


def _info_cov(J: np.ndarray, e: np.ndarray) -> np.ndarray:
    """The information-limited covariance ``s^2 (J^T J)^-1`` of a weighted least-squares fit with
    Jacobian ``J`` (N, p) and residual ``e`` (N,); a tiny relative ridge, never a pseudo-inverse: an
    unexcited direction gets a large, finite sd."""
    p = J.shape[1]
    H = J.T @ J
    H += np.eye(p) * 1e-12 * max(float(np.trace(H)), 1e-300) / p
    return float(e @ e) / max(len(e) - p, 1) * np.linalg.inv(H)


def _jackknife_groups(d: MountData, max_blocks: int) -> list[np.ndarray]:
    """The cross-validation blocks of ``d`` in at most ``max_blocks`` groups, each left out once by
    the delete-one-block jackknife; none when fewer than 3 groups (or ``max_blocks`` 0)."""
    ub = np.unique(d.block)
    groups = np.array_split(ub, min(max_blocks, len(ub))) if max_blocks > 0 else []
    return groups if len(groups) >= 3 else []


def _jackknife_sd(reps) -> np.ndarray:
    """(k,) the delete-one-group jackknife sd of replicates (B, k) (or (B,))."""
    a = np.asarray(reps, dtype=float).reshape(len(reps), -1)
    return np.sqrt((len(a) - 1) / len(a) * np.sum((a - a.mean(0)) ** 2, axis=0))


def _moves(d: MountData) -> bool:
    """Whether the samples turn the sensor (omega or alpha not all zero): then the tool's inertia
    about the sensor origin beyond the declared one is fitted too (a nuisance of the fit)."""
    return bool(d.inertia and (np.any(d.omega) or np.any(d.alpha)))


def _linear_part(D: np.ndarray, d: MountData) -> tuple[np.ndarray, np.ndarray]:
    """The model is linear in ``theta = [m, m c, b]`` (10,) -- and, when the samples turn the sensor
    (``_moves``), the six entries of the tool's inertia about the sensor origin beyond the declared
    ``I_O`` (theta (16,) = [m, m c, b, dI]; a payload changes the inertia too, and a fit that leaves
    it out biases the mount and the centre of mass: the ten inertial parameters of Atkeson, An &
    Hollerbach 1986) -- for a fixed rotation ``D``: ``w = A theta + c`` with A (n, 6, 10 or 16) and
    c (n, 6) (the declared inertia's own terms). Only ``theta[:10]`` is reported; the inertia stays
    a nuisance (the ``tool_inertia`` effect judges it against the declared tool)."""
    Ad, c = _dense_part(D, d)
    A = np.zeros((len(Ad), 6, N_THETA + Ad.shape[2] - 4))
    A[:, :, :4] = Ad[:, :, :4]
    A[:, :, 4:N_THETA] = np.eye(6)
    A[:, :, N_THETA:] = Ad[:, :, 4:]
    return A, c


def _mass_part(D: np.ndarray, d: MountData) -> tuple[np.ndarray, np.ndarray]:
    """``_linear_part``'s mass and first-moment columns A1 (n, 6, 4) and c (n, 6) (its offset columns
    are the identity)::

        F: m ga - (alpha x + omega x omega x) mc = m ga - ([alpha]x + omega omega^T - |omega|^2 1) mc
        M: mc x ga = -[ga]x mc;   c_M = -I_O alpha - omega x (I_O omega)
    """
    ga, om, al = d.ga @ D, d.omega @ D, d.alpha @ D  # rows: D^T v
    n = len(ga)
    A = np.zeros((n, 6, 4))
    A[:, :3, 0] = ga
    M = A[:, :3, 1:]
    M -= om[:, :, None] * om[:, None, :]
    w2 = np.einsum("ni,ni->n", om, om)
    for i in range(3):
        M[:, i, i] += w2
    M[:, 0, 1] += al[:, 2]
    M[:, 0, 2] -= al[:, 1]
    M[:, 1, 0] -= al[:, 2]
    M[:, 1, 2] += al[:, 0]
    M[:, 2, 0] += al[:, 1]
    M[:, 2, 1] -= al[:, 0]
    G = A[:, 3:, 1:]
    G[:, 0, 1], G[:, 0, 2], G[:, 1, 2] = ga[:, 2], -ga[:, 1], ga[:, 0]
    G[:, 1, 0], G[:, 2, 0], G[:, 2, 1] = -ga[:, 2], ga[:, 1], -ga[:, 0]
    c = np.zeros((n, 6))
    Iw = om @ d.I_O.T
    c[:, 3:] = -al @ d.I_O.T - np.cross(om, Iw)
    return A, c


def _dense_part(D: np.ndarray, d: MountData) -> tuple[np.ndarray, np.ndarray]:
    """``_mass_part``'s columns (n, 6, 4) and, when the samples turn the sensor (``_moves``), the
    inertia nuisance's six after them (n, 6, 10): ``- dI alpha - omega x (dI omega)`` in M. -> (A, c)."""
    A1, c = _mass_part(D, d)
    if not _moves(d):
        return A1, c
    om, al = d.omega @ D, d.alpha @ D
    A = np.zeros((len(A1), 6, 4 + N_INERTIA))
    A[:, :, :4] = A1
    A[:, 3:, 4:] = -_inertia_moment(om, al)
    return A, c


def _inertia_moment(om: np.ndarray, al: np.ndarray) -> np.ndarray:
    """(n, 3) omega, alpha -> (n, 3, 6): ``dI alpha + omega x (dI omega)`` column by column of the
    symmetric basis [xx, yy, zz, xy, xz, yz] (``I v`` = L(v) [I_xx, I_yy, I_zz, I_xy, I_xz, I_yz],
    written out: the calibration fit builds it at every trial rotation)."""
    o0, o1, o2 = om[:, 0], om[:, 1], om[:, 2]
    a0, a1, a2 = al[:, 0], al[:, 1], al[:, 2]
    out = np.empty((len(om), 3, 6))
    out[:, 0, 0], out[:, 1, 0], out[:, 2, 0] = a0, o2 * o0, -o1 * o0  # v = (o0, 0, 0)
    out[:, 0, 1], out[:, 1, 1], out[:, 2, 1] = -o2 * o1, a1, o0 * o1  # v = (0, o1, 0)
    out[:, 0, 2], out[:, 1, 2], out[:, 2, 2] = o1 * o2, -o0 * o2, a2  # v = (0, 0, o2)
    out[:, 0, 3], out[:, 1, 3], out[:, 2, 3] = a1 - o2 * o0, a0 + o2 * o1, o0 * o0 - o1 * o1  # (o1, o0, 0)
    out[:, 0, 4], out[:, 1, 4], out[:, 2, 4] = a2 + o1 * o0, o2 * o2 - o0 * o0, a0 - o1 * o2  # (o2, 0, o0)
    out[:, 0, 5], out[:, 1, 5], out[:, 2, 5] = o1 * o1 - o2 * o2, a2 - o0 * o1, a1 + o0 * o2  # (0, o2, o1)
    return out


def _model(x: np.ndarray, d: MountData) -> np.ndarray:
    """(13,) [rotvec, m, mc, b] -> predicted wrench (n, 6) (the declared inertia; no fitted nuisance)."""
    A1, c = _mass_part(rotvec_matrix(x[:3]), d)
    return np.einsum("nik,k->ni", A1, x[3:7]) + x[7:13] + c


def _project(D: np.ndarray, d: MountData, rw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The best ``theta`` for the rotation ``D`` (weighted least squares, robust row weights
    ``rw`` (n, 6)) and the noise-weighted residual (n*6,). The normal equations by blocks: the
    offset's columns are the identity (``_dense_part``: the mass, first moment and inertia nuisance).
    (A numba kernel of this solve, tried, was 6x faster but loads LLVM into the diagnosis: +107 MiB
    of resident memory, which the hour-long log's 2 GB budget does not have.)"""
    Ad, c = _dense_part(D, d)
    n, k = len(Ad), Ad.shape[2]
    A2 = Ad.reshape(-1, k)  # (n*6, k): BLAS products below, no einsum
    y = d.r - c
    sw2 = d.w**2 * rw  # (n, 6) squared row weights
    Aw = A2 * sw2.reshape(-1, 1)
    H = np.empty((k + 6, k + 6))
    H[:k, :k] = Aw.T @ A2
    H[:k, k:] = Aw.reshape(n, 6, k).sum(0).T
    H[k:, :k] = H[:k, k:].T
    H[k:, k:] = np.diag(sw2.sum(0))
    g = np.concatenate([Aw.T @ y.reshape(-1), (sw2 * y).sum(0)])
    H[np.diag_indices_from(H)] += 1e-12 * max(float(np.trace(H)), 1e-300) / len(H)  # as _normal_solve
    sol = np.linalg.solve(H, g)
    theta = np.concatenate([sol[:4], sol[k:], sol[4:k]])  # [m, m c, b, dI]
    return theta, ((y - (A2 @ sol[:k]).reshape(n, 6) - sol[k:]) * d.w).reshape(-1)


def _normal_solve(A: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Least squares by the normal equations (a few columns, many rows: far cheaper than an SVD),
    with a tiny ridge so that an unexcited column gives a finite answer."""
    H = A.T @ A
    H[np.diag_indices_from(H)] += 1e-12 * max(float(np.trace(H)), 1e-300) / len(H)
    return np.linalg.solve(H, A.T @ y)


def _huber(e: np.ndarray, k: float = HUBER_K) -> np.ndarray:
    """IRLS weights of the Huber loss for the weighted residual (n*6,) -> (n, 6)."""
    a = np.abs(e)
    return np.where(a <= k, 1.0, k / np.maximum(a, 1e-300)).reshape(-1, 6)


def _gauss_newton(d: MountData, D0: np.ndarray, iters: int = GN_ITERS) -> tuple[np.ndarray, np.ndarray, float]:
    """Variable projection: Gauss-Newton over the rotation (local updates ``D exp([delta])``),
    ``theta`` solved in closed form at every step, Huber IRLS weights. -> (D, theta, robust cost)."""
    D = D0
    rw = np.ones_like(d.r)
    h = 1e-6
    for _ in range(iters):
        theta, e = _project(D, d, rw)
        rw = _huber(e)
        e0 = e * np.sqrt(rw.reshape(-1))
        J = np.empty((len(e0), 3))
        for k in range(3):
            dv = np.zeros(3)
            dv[k] = h
            _, ek = _project(D @ rotvec_matrix(dv), d, rw)
            J[:, k] = (ek * np.sqrt(rw.reshape(-1)) - e0) / h
        step = _normal_solve(J, -e0)
        # backtracking: never accept a step that raises the cost
        c0 = float(e0 @ e0)
        for lam in (1.0, 0.5, 0.25, 0.1):
            Dn = D @ rotvec_matrix(lam * step)
            _, en = _project(Dn, d, rw)
            en = en * np.sqrt(rw.reshape(-1))
            if float(en @ en) <= c0:
                D = Dn
                break
        else:
            break
        if np.linalg.norm(lam * step) < STEP_TOL_RAD or float(en @ en) > (1.0 - 1e-9) * c0:
            break
    theta, e = _project(D, d, _huber(_project(D, d, rw)[1]))
    a = np.abs(e)
    cost = float(np.sum(np.where(a <= HUBER_K, 0.5 * a**2, HUBER_K * a - 0.5 * HUBER_K**2)))
    return D, theta, cost


def _cost_at(D: np.ndarray, d: MountData, iters: int = 8) -> float:
    """The robust (Huber) cost of the best ``theta`` at a fixed rotation ``D`` (IRLS)."""
    rw = np.ones_like(d.r)
    for _ in range(iters):
        _, e = _project(D, d, rw)
        rw = _huber(e)
    _, e = _project(D, d, rw)
    a = np.abs(e)
    return float(np.sum(np.where(a <= HUBER_K, 0.5 * a**2, HUBER_K * a - 0.5 * HUBER_K**2)))


def _linear_start(d: MountData) -> np.ndarray | None:
    """The closed-form start: ``F = K g_a + b_F`` with ``K = m D^T`` -> D by the nearest rotation
    (SVD). -> D (3, 3), or None when gravity does not turn through the sensor."""
    n = len(d.ga)
    A = np.concatenate([d.ga, np.ones((n, 1))], axis=1)  # (n, 4)
    if n < 8 or np.linalg.cond(A) > 1e8:
        return None
    coef = np.linalg.lstsq(A, d.r[:, :3], rcond=None)[0]  # F_j = sum_i ga_i K[j, i] + b_j
    K = coef[:3].T
    U, _, Vt = np.linalg.svd(K)
    sign = 1.0 if np.linalg.det(U @ Vt) > 0 else -1.0  # det < 0: a negative mass (flipped convention)
    return (sign * (U @ Vt)).T


def _refine(d: MountData, D: np.ndarray, theta: np.ndarray, best: float) -> tuple[np.ndarray, np.ndarray, float]:
    """A weakly turned sensor: Gauss-Newton creeps along its flat, curved valley; scan along the
    least-determined axis and start again from the best point there, while that lowers the cost
    and keeps the mass's sign."""
    for _ in range(WEAK_SCANS):
        Dw = _scan_weak_axis(d, D)
        if Dw is None:
            break
        Dk, thk, ck = _gauss_newton(d, Dw)
        if not (ck < best and (thk[0] > 0) == (theta[0] > 0)):
            break
        D, theta, best = Dk, thk, ck
    return D, theta, best


def _scan_weak_axis(d: MountData, D: np.ndarray, step_deg: float = 10.0) -> np.ndarray | None:
    """The rotation about the least-determined axis at ``D`` (the smallest eigenvalue of the
    variable-projection J^T J) scanned over a full turn by the robust cost; -> the best rotation
    on that circle when it beats ``D``, else None. A sensor turned about one axis leaves a long,
    curved valley in which local steps creep (observed: 40 iterations ending 60 deg short)."""
    rw = _huber(_project(D, d, np.ones_like(d.r))[1])
    _, e0 = _project(D, d, rw)
    sq = np.sqrt(rw.reshape(-1))
    J = np.empty((len(e0), 3))
    for k in range(3):
        dv = np.zeros(3)
        dv[k] = 1e-6
        J[:, k] = (_project(D @ rotvec_matrix(dv), d, rw)[1] - e0) * sq / 1e-6
    _, V = np.linalg.eigh(J.T @ J)
    axis = V[:, 0]  # the smallest eigenvalue's direction
    angles = np.deg2rad(np.arange(step_deg, 360.0, step_deg))
    costs = [_cost_at(D @ rotvec_matrix(a * axis), d, iters=4) for a in angles]
    i = int(np.argmin(costs))
    return D @ rotvec_matrix(angles[i] * axis) if costs[i] < _cost_at(D, d, iters=4) else None


def _best_start(d: MountData, starts: list[np.ndarray], positive: bool = False):
    """Gauss-Newton from each start; the lowest cost wins (``positive``: among positive masses).
    -> (D, theta, cost)."""
    D, theta, best = np.eye(3), np.zeros(10), np.inf
    what = "sensor mount: the mirror branch (a positive mass), start" if positive else "sensor mount: rotation, start"
    for D0 in steps.counted(starts, what):
        Dk, thk, ck = _gauss_newton(d, D0)
        if ck < best and (thk[0] > 0 or not positive):
            D, theta, best = Dk, thk, ck
    return D, theta, best


def _rpy_deg(x: np.ndarray, R_fs_decl: np.ndarray) -> np.ndarray:
    return np.rad2deg(matrix_rpy(R_fs_decl @ rotvec_matrix(x[:3])))


class MountFit(NamedTuple):
    x: np.ndarray  #: (13,) [rotvec of D (declared s), m, mc, b]
    sd: np.ndarray  #: (13,) finite; the first three: the local rotation about the sensor axes [rad]
    rpy_deg: np.ndarray  #: (3,) in the setup's convention
    rpy_sd_deg: np.ndarray  #: (3,)
    angle_deg: float  #: rotation from the declared mount
    angle_sd_deg: float
    residual: np.ndarray | None  #: (n, 6) [N, N m] measured - fitted on the free samples, SI (None: not kept)
    report: dict  #: diagnosis.json "sensor_mount"
    cov: np.ndarray | None = None  #: (13, 13) of (local rotation, theta): the information correlation at ``sd``


def shifted(x: np.ndarray, dx: np.ndarray) -> np.ndarray:
    """The fit's ``x`` (13,) moved by ``dx`` (13,) in ``MountFit.cov``'s coordinates (the first three a local
    rotation about the fitted sensor axes [rad], the rest added)."""
    from scipy.spatial.transform import Rotation

    D = rotvec_matrix(x[:3]) @ rotvec_matrix(dx[:3])
    return np.concatenate([Rotation.from_matrix(D).as_rotvec(), x[3:] + dx[3:]])


def _solve(d: MountData) -> tuple[np.ndarray, np.ndarray, float]:
    """The mount's rotation D (3, 3), theta and the robust cost: Gauss-Newton from the identity and
    the linear start, refined; a mirror branch of positive mass taken when the data cannot tell
    the two apart."""
    starts = [np.eye(3)]
    lin = _linear_start(d)
    if lin is not None and np.all(np.isfinite(lin)):
        starts.append(lin)
    D, theta, best = _refine(d, *_best_start(d, starts))
    if theta[0] <= 0:  # a weakly turned sensor leaves a mirror branch (D turned by 180 deg, -m): a mass is positive
        Dp, thp, cp = _best_start(d, [D0 @ rotvec_matrix(np.pi * e) for D0 in (*starts, D) for e in np.eye(3)], True)
        if thp[0] > 0:
            Dp, thp, cp = _refine(d, Dp, thp, cp)
        if thp[0] > 0 and _mirror_indistinguishable(d, (D, theta, best), (Dp, thp, cp)):
            D, theta, best = Dp, thp, cp  # as good a fit: the data cannot tell them, physics can
    return D, theta, best


def _info_covariance(d: MountData, D: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """(13, 13) information-limited covariance in (local rotation, theta), theta held at the
    solution; the inertia nuisance (moving logs) is marginalised: the block of the whole inverse."""
    e = _resid_at(D, theta, d)
    npar = 3 + len(theta)
    J = np.empty((len(e), npar))
    for k in range(3):
        dv = np.zeros(3)
        dv[k] = 1e-6
        J[:, k] = (_resid_at(D @ rotvec_matrix(dv), theta, d) - e) / 1e-6
    A, _ = _linear_part(D, d)
    J[:, 3:] = -(A * d.w[None, :, None]).reshape(-1, A.shape[2])
    return _info_cov(J, e)[:3 + N_THETA, :3 + N_THETA]


def _jackknife(d: MountData, D: np.ndarray, R_decl: np.ndarray, rpy: np.ndarray,
               max_blocks: int) -> tuple[np.ndarray, np.ndarray, float]:
    """Delete-one-block jackknife sd (correlated residuals of a moving log make the information sd
    small): -> (13,) of (local rotation [rad], theta), (3,) of rpy [deg], the angle's [deg]."""
    from scipy.spatial.transform import Rotation

    groups = _jackknife_groups(d, max_blocks)
    reps, devs, rpys, angs = [], [], [], []
    for g in steps.counted(groups, "sensor mount: its uncertainty, refit without block"):
        Db, thb, _ = _gauss_newton(_without(d, np.isin(d.block, g)), D, iters=4)
        reps.append(thb[:N_THETA])
        devs.append(Rotation.from_matrix(D.T @ Db).as_rotvec())
        rpys.append(_wrap_deg(np.rad2deg(matrix_rpy(R_decl @ Db)) - rpy))
        angs.append(np.rad2deg(rotation_angle(Db)))
    if not reps:
        return np.zeros(13), np.zeros(3), 0.0
    return (np.concatenate([_jackknife_sd(devs), _jackknife_sd(reps)]), _jackknife_sd(rpys),
            float(_jackknife_sd(angs)[0]))


def _angle_sds(D: np.ndarray, R_decl: np.ndarray, rpy: np.ndarray, cov_loc: np.ndarray) -> tuple[np.ndarray, float]:
    """Information sd of rpy (3,) [deg] and of the rotation angle [deg], through derivatives in the
    local rotation whose (3, 3) covariance is ``cov_loc``."""
    th = rotation_angle(D)
    G = np.zeros((3, 3))
    ga_ = np.zeros(3)
    for k in range(3):
        dv = np.zeros(3)
        dv[k] = 1e-6
        Dk = D @ rotvec_matrix(dv)
        G[:, k] = _wrap_deg(np.rad2deg(matrix_rpy(R_decl @ Dk)) - rpy) / 1e-6
        ga_[k] = (rotation_angle(Dk) - th) / 1e-6
    return (np.sqrt(np.maximum(np.diag(G @ cov_loc @ G.T), 0.0)),
            float(np.rad2deg(np.sqrt(max(ga_ @ cov_loc @ ga_, 0.0)))))


def fit(s, free: np.ndarray, block: np.ndarray, sigma: np.ndarray, max_blocks: int = 20,
        residual: bool = True) -> MountFit:
    """The calibration fit on the free-space samples ``free`` (n,) bool of ``LogSignals`` s.
    ``block`` (n,) the cross-validation block of every sample; ``sigma`` (6,) the per-channel
    noise; ``residual``: keep the residual of every free sample (else ``MountFit.residual`` is
    None: a long log's free samples). -> ``MountFit`` (module docstring)."""
    from scipy.spatial.transform import Rotation

    from kinadapt_nn.diagnostics.physical import nominal_inertials

    setup = s.setup
    idx = np.flatnonzero(free)
    if len(idx) > MAX_ROWS:
        idx = idx[np.linspace(0, len(idx) - 1, MAX_ROWS).round().astype(int)]
    m_decl, mc_decl, I_O = nominal_inertials(setup)
    d = MountData(s.g_s[idx] - s.a_s[idx], s.omega_s[idx], s.alpha_s[idx], s.wrench[idx], 1.0 / sigma, I_O, block[idx])
    turn = _turn_mps2(d)
    if turn < TURN_MIN_MPS2:  # the log cannot calibrate: nothing to search for
        return _declared_fit(d, s, free, residual, (m_decl, mc_decl), turn)
    D, theta, best = _solve(d)
    x = np.concatenate([Rotation.from_matrix(D).as_rotvec(), theta[:N_THETA]])
    cost_declared = _cost_at(np.eye(3), d)
    rot_explains = float(max(0.0, 1.0 - best / max(cost_declared, 1e-300)))
    cov = _info_covariance(d, D, theta)
    sd_info = np.sqrt(np.maximum(np.diag(cov), 0.0))
    R_decl = setup.sensor.R_fs()
    rpy = _rpy_deg(x, R_decl)
    th = rotation_angle(D)
    sd_jk, rpy_sd_jk, ang_sd_jk = _jackknife(d, D, R_decl, rpy, max_blocks)
    sd = np.maximum(sd_info, sd_jk)
    rpy_sd_info, ang_sd_info = _angle_sds(D, R_decl, rpy, cov[:3, :3])
    rpy_sd = np.maximum(rpy_sd_info, rpy_sd_jk)
    ang_sd = max(ang_sd_info, ang_sd_jk)
    # the fitted residual on every free sample (not only the subset)
    summary, res = _free_residual(x, s, free, residual)
    rep = report((x, sd), (rpy, rpy_sd), (float(np.rad2deg(th)), ang_sd), summary, s, rot_explains)
    corr = cov / np.sqrt(np.maximum(np.outer(np.diag(cov), np.diag(cov)), 1e-300))
    return MountFit(x, sd, rpy, rpy_sd, float(np.rad2deg(th)), ang_sd, res if residual else None, rep,
                    corr * np.outer(sd, sd))


def _turn_mps2(d: MountData) -> float:
    """[m/s^2] How far ``g_a`` moves in the sensor frame over the samples: the largest
    ``|g_a - mean g_a|`` (rotation invariant: the same in any candidate mount)."""
    return float(np.linalg.norm(d.ga - d.ga.mean(0), axis=1).max()) if len(d.ga) else 0.0


def _mass_sd_at_declared(d: MountData, max_blocks: int = 20) -> float:
    """[kg] The mass's sd with the mount held at the declared one: the larger of the information sd
    and a delete-one-block jackknife's (as the fit's own). What the log says of the mass when it
    cannot calibrate (``_declared_fit``)."""
    theta, res = fit_at(np.eye(3), d)
    m_jk = [fit_at(np.eye(3), _without(d, np.isin(d.block, g)))[0][0] for g in _jackknife_groups(d, max_blocks)]
    sd_jk = float(_jackknife_sd(m_jk)[0]) if m_jk else 0.0
    A, _ = _linear_part(np.eye(3), d)
    cov = _info_cov((A * d.w[None, :, None]).reshape(-1, A.shape[2]), (res * d.w).reshape(-1))
    return max(float(np.sqrt(max(cov[0, 0], 0.0))), sd_jk)


def _declared_fit(d: MountData, s, free: np.ndarray, residual: bool, mass: tuple[float, np.ndarray],
                  turn: float) -> MountFit:
    """The calibration of a log whose free space does not turn the sensor against gravity (``turn``
    [m/s^2] below ``TURN_MIN_MPS2``): a constant ``g_a`` lets any rotation and mass fit with a
    matching offset (``m D^T g_a + b``), so the declared mount, mass and centre of mass stand and
    only the offset ``b`` (6,) is fitted (robust mean of what the declared tool leaves). ``sd`` of
    the rotation is pi (any rotation fits), of the mass what the log says of it at the declared
    mount (``_mass_sd_at_declared``); ``cov`` is conditional on the declared values (zero for them,
    the offset's own block)."""
    m_decl, mc_decl = mass
    mass_sd = _mass_sd_at_declared(d)
    A1, c = _mass_part(np.eye(3), d)
    y = d.r - c - np.einsum("nik,k->ni", A1, np.concatenate([[m_decl], mc_decl]))
    b = np.median(y, axis=0)
    for _ in range(8):  # Huber IRLS of a constant per channel
        rw = _huber(((y - b) * d.w).reshape(-1))
        b = (rw * y).sum(0) / np.maximum(rw.sum(0), 1e-300)
    ub, inv = np.unique(d.block, return_inverse=True)
    if len(ub) >= 3:  # the spread of the blocks' means: a correlated residual is not n independent samples
        means = np.stack([(y - b)[inv == i].mean(0) for i in range(len(ub))])
        b_sd = means.std(0, ddof=1) / np.sqrt(len(ub))
    else:
        b_sd = (y - b).std(0, ddof=1) / np.sqrt(max(len(y), 1))
    x = np.concatenate([np.zeros(3), [m_decl], mc_decl, b])
    c_decl = mc_decl / m_decl if m_decl > 0 else np.zeros(3)
    sd = np.concatenate([np.full(3, np.pi), [mass_sd], mass_sd * np.abs(c_decl), b_sd])
    cov = np.zeros((3 + N_THETA, 3 + N_THETA))
    cov[7:, 7:] = np.diag(b_sd**2)
    R_decl = s.setup.sensor.R_fs()
    rpy = _rpy_deg(x, R_decl)
    summary, res = _free_residual(x, s, free, residual)
    rep = report((x, sd), (rpy, np.full(3, 180.0)), (0.0, 180.0), summary, s, 0.0)
    rep.update({
        "determined": False, "sd_deg": [None] * 3, "rotation_sd_deg": None, "declared_consistent": True,
        "tool_mass_sd_kg": mass_sd, "tool_com_sd_m": [None] * 3,
        "undetermined": [{"parameter": "the sensor mount's rotation and the tool's mass and centre of mass (the "
                                       "declared ones used)", "sd": None, "unit": None,
                          "why": f"the sensor turns against gravity by {turn:.2g} m/s^2 in free space, "
                                 f"{TURN_MIN_MPS2:g} needed",
                          "to_pin": "free-space poses with gravity along several directions in the sensor frame "
                                    "(turn the wrist by 30 deg or more about two axes)"}],
        "turn_mps2": turn,
        "method": f"not determined by this log: the sensor turns against gravity by only {turn:.2g} m/s^2 in free "
                  "space, so neither the mount's rotation nor the tool's mass can be fitted (any of them fits with a "
                  "matching offset); the declared mount, mass and centre of mass are used and only the offset is "
                  "fitted"})
    return MountFit(x, sd, rpy, np.full(3, 180.0), 0.0, 180.0, res if residual else None, rep, cov)


class ResidualSummary(NamedTuple):
    """The calibrated model's residual on the free samples, summarised (``report``)."""

    rms: np.ndarray  #: (6,) [N, N m] per channel
    peak: np.ndarray  #: (2,) [N, N m] the largest measured |F| and |M|
    samples: int


def _free_residual(x: np.ndarray, s, free: np.ndarray, keep: bool, chunk: int = 50_000
                   ) -> tuple[ResidualSummary, np.ndarray | None]:
    """The residual of the fit ``x`` on every free sample, in chunks: its summary, and the (m, 6)
    residual itself when ``keep``."""
    fidx = np.flatnonzero(free)
    sq, peak, kept = np.zeros(6), np.zeros(2), []
    for a in range(0, len(fidx), chunk):
        i = fidx[a:a + chunk]
        r = s.wrench[i]
        e = r - predict(x, s, i)
        sq += np.einsum("nc,nc->c", e, e)
        peak = np.maximum(peak, [np.linalg.norm(r[:, :3], axis=1).max(), np.linalg.norm(r[:, 3:], axis=1).max()])
        if keep:
            kept.append(e)
    rms = np.sqrt(sq / max(len(fidx), 1)) if len(fidx) else np.full(6, np.nan)
    res = (np.concatenate(kept) if kept else np.zeros((0, 6))) if keep else None
    return ResidualSummary(rms, peak, len(fidx)), res


def _block_costs(D: np.ndarray, theta: np.ndarray, d: MountData) -> np.ndarray:
    """The robust (Huber) cost of the fit ``(D, theta)`` summed per cross-validation block -> (B,)
    in the order of ``np.unique(d.block)``."""
    a = np.abs(_resid_at(D, theta, d)).reshape(-1, 6)
    c = np.sum(np.where(a <= HUBER_K, 0.5 * a**2, HUBER_K * a - 0.5 * HUBER_K**2), axis=1)
    _, inv = np.unique(d.block, return_inverse=True)
    return np.bincount(inv.reshape(-1), weights=c)


def _mirror_indistinguishable(d: MountData, neg: tuple, pos: tuple) -> bool:
    """Whether the positive-mass mirror fit ``pos`` = (D, theta, cost) fits as well as the
    negative-mass one ``neg``: its extra cost within ``MIRROR_COST`` times the fit's reduced chi^2
    (white noise) or within 3 sd of the block-to-block scatter of the per-block cost difference
    (a moving log's residuals are correlated and model errors are structured: the sum of B
    block differences has sd sqrt(B) sd_b). Measured on a real arm's tared contact-task log
    (HIRO trial 12, 7 free-space blocks): the mirror costs 61 more of 16 463 (reduced chi^2 8.3),
    outside the white-noise allowance (37), far inside the block scatter (3 sqrt(B) sd_b = 825)."""
    misfit = max(1.0, 2.0 * neg[2] / max(d.r.size - 13, 1))  # the fit's reduced chi^2: model error scales the test
    if pos[2] <= neg[2] + MIRROR_COST * misfit:
        return True
    diff = _block_costs(pos[0], pos[1], d) - _block_costs(neg[0], neg[1], d)
    if len(diff) < 4:
        return False
    return float(diff.sum()) <= SIGNIFICANT_SD * np.sqrt(len(diff)) * float(np.std(diff, ddof=1))


def _resid_at(D: np.ndarray, theta: np.ndarray, d: MountData) -> np.ndarray:
    A, c = _linear_part(D, d)
    return ((d.r - c - np.einsum("nik,k->ni", A, theta)) * d.w).reshape(-1)


def predict(x: np.ndarray, s, idx: np.ndarray | None = None, chunk: int = 50_000) -> np.ndarray:
    """The calibrated model's wrench (n, 6) [N, N m] on every sample of ``LogSignals`` s, or on the
    samples ``idx`` (m,) only (-> (m, 6)); in chunks of ``chunk`` samples (the linear part is
    (chunk, 6, 10))."""
    from kinadapt_nn.diagnostics.physical import nominal_inertials

    _, _, I_O = nominal_inertials(s.setup)
    idx = np.arange(s.n) if idx is None else np.asarray(idx)
    out = np.empty((len(idx), 6))
    for a in range(0, len(idx), chunk):
        i = idx[a:a + chunk]
        d = MountData(s.g_s[i] - s.a_s[i], s.omega_s[i], s.alpha_s[i], s.wrench[i], np.ones(6), I_O,
                      np.zeros(len(i), int))
        out[a:a + chunk] = _model(x, d)
    return out


def refine_rotation(d: MountData, starts: list[np.ndarray], iters: int = 8) -> np.ndarray:
    """The rotation ``D`` (3, 3) of the fit on ``d``: Gauss-Newton (as the fit, ``iters`` steps)
    from each start and from the closed-form start of the forces; the lowest robust cost with a
    positive mass wins (a weakly turned sensor leaves a mirror branch, ``D`` turned by 180 deg and
    ``-m``, as in ``fit``), the lowest of all where none has one."""
    lin = _linear_start(d)
    starts = [*starts, *([lin] if lin is not None and np.all(np.isfinite(lin)) else [])]
    ends = [_gauss_newton(d, D0, iters) for D0 in starts]
    return min(ends, key=lambda r: (r[1][0] <= 0, r[2]))[0]


def fit_at(D: np.ndarray, d: MountData, iters: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """The best ``theta = [m, m c, b]`` (10,) at a fixed rotation ``D`` (3, 3) (robust IRLS, as the
    fit, the inertia nuisance fitted beside it on a moving log) and the residual (n, 6) [N, N m] of
    ``d``'s samples."""
    A, c = _linear_part(D, d)  # (n, 6, 10 or 16), (n, 6): built once, the weights change
    y = d.r - c
    rw = np.ones_like(d.r)
    for _ in range(iters + 1):
        sw = d.w * np.sqrt(rw)  # (n, 6)
        theta = _normal_solve((A * sw[:, :, None]).reshape(-1, A.shape[2]), (y * sw).reshape(-1))
        res = y - np.einsum("nik,k->ni", A, theta)
        rw = _huber((res * d.w).reshape(-1))
    return theta[:N_THETA], res


def plausibility(fitm: "MountFit", setup) -> list[str]:
    """Why the calibration fit is not a physical tool on a physical sensor (empty: plausible). A
    tool much heavier than declared is implausible only when the log does not determine its mass
    (then contact in the calibration samples is the likely cause); a determined one is a payload
    the declared tool lacks -- the ``tool_gravity`` effect's finding, judged, not blocked
    (``heavier_than_declared`` words it)."""
    out = []
    m = float(fitm.x[3])
    m_decl = float(setup.tool.mass_kg)
    if m <= 0:
        out.append(f"the fitted tool mass is {m:.3g} kg (not positive)")
    elif m_decl > 0 and m > MASS_PLAUSIBLE_FACTOR * m_decl and fitm.sd[3] > UNDETERMINED_MASS_REL * m:
        out.append(f"the fitted tool mass {m:.3g} ± {fitm.sd[3]:.2g} kg is more than {MASS_PLAUSIBLE_FACTOR:g}x the "
                   f"declared {m_decl:g} kg and not determined by the log (contact in the calibration samples?)")
    elif np.linalg.norm(fitm.x[4:7] / m) > COM_PLAUSIBLE_M:
        out.append(f"the fitted centre of mass is {np.linalg.norm(fitm.x[4:7] / m):.3g} m from the sensor")
    rf, rt = setup.sensor.range_force_N, setup.sensor.range_torque_Nm
    if rf > 0 and np.max(np.abs(fitm.x[7:10])) > rf:
        out.append(f"the force offset {np.max(np.abs(fitm.x[7:10])):.3g} N exceeds the sensor's range ({rf:g} N)")
    if rt > 0 and np.max(np.abs(fitm.x[10:13])) > rt:
        out.append(f"the torque offset {np.max(np.abs(fitm.x[10:13])):.3g} N m exceeds the sensor's range ({rt:g} N m)")
    return out


def heavier_than_declared(fitm: "MountFit", setup) -> str | None:
    """A warning when the fitted mass is ``MASS_PLAUSIBLE_FACTOR`` times the declared one or more
    and determined by the log (not a block: ``plausibility``); None otherwise."""
    m, m_decl = float(fitm.x[3]), float(setup.tool.mass_kg)
    if m_decl <= 0 or m <= MASS_PLAUSIBLE_FACTOR * m_decl or fitm.sd[3] > UNDETERMINED_MASS_REL * m:
        return None
    return (f"the tool weighs {m:.3g} ± {fitm.sd[3]:.2g} kg by the calibration, {m / m_decl:.1f}x the declared "
            f"{m_decl:g} kg: a payload the set-up lacks (see tool_gravity) or [tool] mass_kg is wrong")


def report(fit: tuple, rpy: tuple, angle: tuple[float, float], res: ResidualSummary, s, rot_explains: float = 1.0
           ) -> dict:
    """The ``sensor_mount`` block of diagnosis.json (module docstring); offset/residual in the
    log's units and sign convention. ``fit`` = (x, sd) the fitted parameters and their sd, ``rpy``
    = (rpy, sd) the mount's roll/pitch/yaw [deg], ``angle`` = (angle, sd) its rotation from the
    declared mount [deg], ``res`` the residual on the free samples (``_free_residual``)."""
    (x, sd), (rpy, rpy_sd), (angle_deg, angle_sd) = fit, rpy, angle
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
    wf = np.repeat(res.peak, 3)  # (6,) the largest |F| (force channels) and |M| (moment channels)
    rel = np.array([setup.analysis.relevant_force_N] * 3 + [setup.analysis.relevant_moment_Nm] * 3)
    th = np.deg2rad(angle_deg)
    second_order = float(np.max(wf * th**2 / 2.0 / rel)) if res.samples else 0.0
    significant = angle_deg > SIGNIFICANT_SD * max(angle_sd, 1e-9)
    representable = angle_deg <= MAX_FIRST_ORDER_DEG and second_order < 1.0
    # a mount error is what the rotation explains: when it removes only part of what the declared mount
    # leaves, something else (not the mount) distorts the fit and the declared mount is not contradicted
    consistent = bool(not significant or representable or rot_explains < ROTATION_EXPLAINS)
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
        "residual_rms": [float(v) for v in res.rms / scale],
        "residual_units": [setup.log.force_unit] * 3 + [setup.log.torque_unit] * 3,
        "samples": int(res.samples),
        "second_order_to_relevant": second_order,
        "rotation_explains": rot_explains,
        "method": "rotation, mass, first moment and offset fitted jointly (Gauss-Newton from a closed-form start "
                  "and from the declared mount); sd = max(information, block jackknife)",
    }
    out["determined"] = True  # False: ``_declared_fit`` (the log does not determine the calibration)
    out["paste"] = "[sensor] rpy_flange_deg = [" + ", ".join(f"{v:.2f}" for v in rpy) + "]"
    out["undetermined"] = undetermined(x, sd)
    return out


def undetermined(x: np.ndarray, sd: np.ndarray) -> list[dict]:
    """The calibration parameters whose interval is too wide to call them estimated (``x``, ``sd``
    (13,) as ``MountFit``): each with its sd and the motion that would pin it. The rest stand."""
    out = []
    axes = "xyz"
    for k in range(3):
        sd_deg = float(np.rad2deg(sd[k]))
        if sd_deg > UNDETERMINED_DEG:
            others = axes.replace(axes[k], "")
            out.append({"parameter": f"mount rotation about the sensor's {axes[k]} axis", "sd": sd_deg, "unit": "deg",
                        "to_pin": f"poses with gravity along several directions in the sensor's {others[0]}-{others[1]} "
                                  f"plane (turn the wrist by 30 deg or more about an axis other than the sensor's "
                                  f"{axes[k]} axis)"})
    m = float(x[3])
    if sd[3] > UNDETERMINED_MASS_REL * max(abs(m), 1e-9):
        out.append({"parameter": "tool mass", "sd": float(sd[3]), "unit": "kg",
                    "to_pin": "larger changes of the sensor's orientation against gravity in free space"})
    elif abs(m) > 1e-9:
        for i in range(3):
            c_sd = float(np.hypot(sd[4 + i], abs(x[4 + i] / m) * sd[3]) / abs(m))
            if c_sd > UNDETERMINED_COM_M:
                out.append({"parameter": f"tool centre of mass, sensor {axes[i]}", "sd": c_sd, "unit": "m",
                            "to_pin": f"turn the sensor so that gravity moves across its {axes[i]} axis in free space"})
    return out


__all__ = ["MountFit", "fit", "fit_at", "heavier_than_declared", "matrix_rpy", "plausibility", "predict", "refine_rotation", "rotation_angle",
           "rotvec_matrix"]
