"""Naming an event: which shape of the effect library (and the hint shapes) fits the residual best.

After an alarm the monitor fits each candidate shape to the residual from the change's onset (the
CUSUM's last restart) to ``window_s`` past the alarm, free-space samples only, every row divided by
its channel's noise sd. Each shape is linear in its parameters (columns per sample, (n, 6, k)); the
best is the one with the least Bayesian information criterion ``chi^2 + k ln(rows)``, with the model's
own slow error (an unknown constant per channel) integrated out when its size is given (``slow_bic``).
Its estimate's covariance is ``(A^T A)^-1`` scaled by ``chi^2 / (rows - k)`` where the fit leaves more
than noise. ``ties``: the other shapes the window cannot tell from the best (a near-tie).

=====================  =========================================================  ==========================
shape                  columns (s: sensor frame; the tool's wrench on the sensor)  what it reads as
=====================  =========================================================  ==========================
tool_gravity           dm (g_s - a_s); d(mc): -al x dmc - om x (om x dmc),        a payload picked up
                       dmc x (g_s - a_s)  (``diagnostics.physical``'s model)
world_force            F: R^T f_w; M: p x R^T f_w (f_w, p: Gauss-Newton)         a snag: a pull in the world
                       (``diagnostics.completeness``'s world_force, its point)
ft_bias_drift          per channel: rate (t - t_onset); a constant on the channels a drifting sensor
                       whose test fired (the onset's error)
ft_frame_rotation      r x delta for force and moment (r: the reading)            the sensor turned in its mount
tool_tilt              the declared tool's first moment turned about O by          the tool slipped in the grasp
                       (dx, dy): dmc = delta x mc
sensor_constant        a constant per channel                                      a bias step
encoder_offset         one joint's zero offset (the best joint): the declared      a joint encoder's zero is
                       tool's wrench with g_s - a_s, omega, alpha turned by delta   off (the end-of-run look
                       about the joint's axis in s, a = R_ws^T z_j                 only: ``END_SHAPES``)
=====================  =========================================================  ==========================

``encoder_offset`` (``columns``): joint j's encoder reads q while the link sits at q + delta. The links from
j on, the sensor with them, are turned by delta about the joint's axis; in s that axis is ``a = R_ws^T z_j``
(``z_j``: the arm Jacobian's angular column, world; the ring keeps ``a`` per sample, ``kernel.G_AX``). A world
vector x seen from the turned sensor frame is ``x + delta x x a`` to first order, so the declared tool's
wrench (``kernel.predict``) changes by ``dF = m dga - dal x mc - dom x (om x mc) - om x (dom x mc)``, ``dM =
mc x dga - I_O dal - dom x (I_O om) - om x (I_O dom)`` with ``dga = ga x a``, ``dal = al x a``, ``dom = om x
a``. At rest that is the exact derivative of the model in q_j (``tests/monitor/test_encoder_shape.py`` checks
it against central differences of ``kernel.predict`` on the arm's kinematics); moving, the sensor's
acceleration also changes with the joint's angle (its centripetal and tangential parts), which the column
leaves out: of order ``|qdot|^2 L / |g|`` of it (L ~ 1 m, the arm's reach; the test bounds it at 0.5 rad/s).
At rest an offset about ``a``
is the mount turned by ``delta a`` plus the tool's first moment turned about ``a`` (``dmc = delta a x mc``;
Jacobi: ``mc x (g x a) = (mc x g) x a + (a x mc) x g``): the tool's gravity moment tells the two apart.
One joint at a time, as the
offline library's ``encoder_offset`` (``one_of``): each joint's column is fitted alone and the best kept
(``Fit.joint``), one parameter; a joint whose axis is the sensor's z axis at every row is left out (its turn
is ``ft_frame_rotation``'s about z_s, as the diagnosis leaves it out where the mount is known), and so is a
joint with no axis (a slide joint, or rows without axes).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from kinadapt_nn.diagnostics.completeness import world_force_columns
from kinadapt_nn.monitor import kernel as K

#: shapes in the order they are tried (ties: the earlier, fewer parameters first): the live naming's
SHAPES = ("tool_tilt", "ft_frame_rotation", "tool_gravity", "sensor_constant", "world_force", "ft_bias_drift")
#: the end-of-run look's (``Monitor._end_look``): the live ones and a joint encoder's zero offset, which the
#: offline diagnosis's library has (docs/monitor.md: why it is not named live)
END_SHAPES = (*SHAPES, "encoder_offset")
#: [-] z of the printed +- (a two-sided 95 % interval)
Z95 = 1.96
#: [rad] a joint's axis within this of the sensor's z axis at every row is that axis (``encoder_joints``)
AXIS_TOL_RAD = 1e-5


class Tool(NamedTuple):
    """The declared tool's inertial parameters (sensor frame, about its origin O), as ``kernel.predict`` has them."""

    m: float  #: [kg] mass
    mc: np.ndarray  #: (3,) [kg m] first moment
    I_O: np.ndarray  #: (3, 3) [kg m^2] inertia about O


class Fit(NamedTuple):
    shape: str
    p: np.ndarray  #: (k,) estimate
    cov: np.ndarray  #: (k, k)
    chi2: float
    bic: float
    rows: int
    joint: int = -1  #: ``encoder_offset``: the joint (0-based, base to flange) whose offset it is; else -1


def _skew(v: np.ndarray) -> np.ndarray:
    """(n, 3) -> (n, 3, 3): [v]x, so that [v]x u = v x u."""
    n = len(v)
    S = np.zeros((n, 3, 3))
    S[:, 0, 1], S[:, 0, 2] = -v[:, 2], v[:, 1]
    S[:, 1, 0], S[:, 1, 2] = v[:, 2], -v[:, 0]
    S[:, 2, 0], S[:, 2, 1] = -v[:, 1], v[:, 0]
    return S


def _gravity_cols(om, al, ga) -> np.ndarray:
    """(n, 6, 4): dm, dmc -> the added rigid body's wrench (its inertia about its own centre left out)."""
    n = len(ga)
    C = np.zeros((n, 6, 4))
    C[:, :3, 0] = ga
    Sal, Som, Sga = _skew(al), _skew(om), _skew(ga)
    C[:, :3, 1:] = -Sal - Som @ Som
    C[:, 3:, 1:] = -Sga  # dmc x ga = -ga x dmc
    return C


def joint_axes(rows: np.ndarray) -> np.ndarray:
    """(n, nj, 3) the arm's joint axes in s of ring rows (``kernel.G_AX``; nj = 0 on rows without them)."""
    return rows[:, K.G_AX:K.G_AX + 3 * ((rows.shape[1] - K.G_AX) // 3)].reshape(len(rows), -1, 3)


def encoder_joints(rows: np.ndarray) -> list[int]:
    """The joints (0-based) an ``encoder_offset`` may be of on ring rows: an axis there (not a slide joint's
    zero), and not the sensor's z axis at every row (module docstring)."""
    a = joint_axes(rows)
    out = []
    for j in range(a.shape[1]):
        norm = np.linalg.norm(a[:, j], axis=1)
        if not np.any(norm > 0.5):
            continue
        if np.all(np.abs(a[:, j, 2]) > 0.5) and np.all(np.abs(a[:, j, :2]) < AXIS_TOL_RAD):
            continue
        out.append(j)
    return out


def _encoder_cols(tool: Tool, om: np.ndarray, al: np.ndarray, ga: np.ndarray, a: np.ndarray) -> np.ndarray:
    """(n, 6, 1): the declared tool's wrench per unit turn of the world about ``a`` (n, 3) in s (module
    docstring: ``kernel.predict``'s model, its vectors turned)."""
    mc, I = np.asarray(tool.mc, dtype=float), np.asarray(tool.I_O, dtype=float)
    dga, dal, dom = np.cross(ga, a), np.cross(al, a), np.cross(om, a)
    C = np.empty((len(ga), 6, 1))
    C[:, :3, 0] = (tool.m * dga - np.cross(dal, mc) - np.cross(dom, np.cross(om, mc))
                   - np.cross(om, np.cross(dom, mc)))
    C[:, 3:, 0] = (np.cross(mc, dga) - dal @ I.T - np.cross(dom, om @ I.T) - np.cross(om, dom @ I.T))
    return C


def columns(shape: str, rows: np.ndarray, tool: Tool, t_onset: float, joint: int = -1) -> np.ndarray:
    """The shape's columns (n, 6, k) on ring rows (n, NCOL + 3 nj) (``kernel``'s layout); ``joint``: the
    ``encoder_offset``'s joint (0-based)."""
    n = len(rows)
    R = rows[:, K.G_R:K.G_R + 9].reshape(n, 3, 3)
    om, al, ga = rows[:, K.G_OM:K.G_OM + 3], rows[:, K.G_AL:K.G_AL + 3], rows[:, K.G_GA:K.G_GA + 3]
    if shape == "tool_gravity":
        return _gravity_cols(om, al, ga)
    if shape == "tool_tilt":  # dmc = delta x mc = -[mc]x delta, delta = (dx, dy, 0)
        G = _gravity_cols(om, al, ga)[:, :, 1:]  # (n, 6, 3) per dmc
        return (G @ (-_skew(np.broadcast_to(tool.mc, (n, 3)))))[:, :, :2]
    if shape == "encoder_offset":
        if not 0 <= joint < joint_axes(rows).shape[1]:
            raise ValueError(f"encoder_offset needs a joint of the rows' {joint_axes(rows).shape[1]}, not {joint}")
        return _encoder_cols(tool, om, al, ga, joint_axes(rows)[:, joint])
    if shape == "world_force":
        return world_force_columns(R)
    if shape == "ft_bias_drift":
        C = np.zeros((n, 6, 12))
        dt = rows[:, K.G_T] - t_onset
        for i in range(6):
            C[:, i, i] = dt
            C[:, i, 6 + i] = 1.0
        return C
    if shape == "ft_frame_rotation":  # r x delta = [r]x delta
        r = rows[:, K.G_RM:K.G_RM + 6]
        return np.concatenate([_skew(r[:, :3]), _skew(r[:, 3:])], axis=1)
    if shape == "sensor_constant":
        return np.broadcast_to(np.eye(6), (n, 6, 6)).copy()
    raise ValueError(shape)


def prior_sd(shape: str) -> np.ndarray:
    """Each parameter's prior sd (a weak, zero-mean prior: what a shape may plausibly reach; it keeps a
    direction the window does not see at its prior, not at an arbitrary value with no variance)."""
    return {"tool_gravity": np.array([5.0, 1.0, 1.0, 1.0]),  # [kg], [kg m]
            "tool_tilt": np.full(2, np.deg2rad(30.0)),  # [rad]
            "world_force": np.array([100.0, 100.0, 100.0, 0.1, 0.1, 0.1]),  # [N], [m] from the sensor: on the tool
            "ft_bias_drift": np.array([100.0] * 6 + [1000.0] * 6),  # [N/s, N m/s], [N, N m]
            "ft_frame_rotation": np.full(3, np.deg2rad(30.0)),  # [rad]
            "encoder_offset": np.full(1, np.deg2rad(30.0)),  # [rad]
            "sensor_constant": np.full(6, 1000.0)}[shape]  # [N, N m]


def _world_force(rows: np.ndarray, sd: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, int]:
    """A world force ``f_w`` at a point ``p`` (s) of the tool: force rows ``R^T f_w`` (linear: ``f_w``
    first), moment rows ``p x R^T f_w`` (linear in p given f_w), then Gauss-Newton on both. p along the
    force is not seen while the tool keeps its orientation: the least-norm step leaves it where it is.
    -> (p = [f_w; p] (6,), its covariance (6, 6), chi^2, rows)."""
    n = len(rows)
    P0 = np.diag(1.0 / prior_sd("world_force") ** 2)
    R = rows[:, K.G_R:K.G_R + 9].reshape(n, 3, 3)
    Rt = R.transpose(0, 2, 1)
    e = rows[:, K.G_E:K.G_E + 6] / sd[None, :]
    fw, *_ = np.linalg.lstsq((R / sd[None, :3, None]).reshape(-1, 3), e[:, :3].reshape(-1), rcond=None)
    p = np.zeros(3)
    for _ in range(8):
        f_s = R.transpose(0, 2, 1) @ fw  # (n, 3) the force in s
        r = np.concatenate([f_s, np.cross(p, f_s)], axis=1) / sd[None, :]
        Jm = np.zeros((n, 6, 6))
        Jm[:, :3, :3] = Rt
        Jm[:, 3:, :3] = _skew(np.broadcast_to(p, (n, 3))) @ Rt
        Jm[:, 3:, 3:] = -_skew(f_s)
        A = (Jm / sd[None, :, None]).reshape(-1, 6)
        x = np.concatenate([fw, p])
        H = A.T @ A + P0
        step = np.linalg.solve(H, A.T @ (e - r).reshape(-1) - P0 @ x)
        fw, p = fw + step[:3], p + step[3:]
        if np.linalg.norm(step) < 1e-10:
            break
    f_s = R.transpose(0, 2, 1) @ fw
    res = (e - np.concatenate([f_s, np.cross(p, f_s)], axis=1) / sd[None, :]).reshape(-1)
    chi2 = float(res @ res)
    m = len(res)
    cov = np.linalg.inv(A.T @ A + P0) * max(1.0, chi2 / max(m - 6, 1))
    return np.concatenate([fw, p]), cov, chi2, m


#: contiguous blocks of the delete-one-block jackknife (``fit``)
JACK_BLOCKS = 10


def fit(shape: str, rows: np.ndarray, sd: np.ndarray, tool: Tool, t_onset: float,
        fired: np.ndarray | None = None, jackknife: bool = False, model_sd: np.ndarray | None = None) -> Fit:
    """``_fit1``; with ``jackknife`` the covariance also counts what the noise sd does not: errors of
    the model that persist in time (a residual correlated over many samples). The delete-one-block
    jackknife over ``JACK_BLOCKS`` contiguous blocks estimates the spread such errors give within the
    window; ``model_sd`` (6,) [N, N m], the model's own slow error per channel before the change (what
    the nominal model already missed), adds the change a constant error of that size in each channel
    makes to the estimate (``sum_c d_c d_c^T``, d_c the estimate's shift when channel c's residual is
    shifted by ``model_sd[c]``: exact for the linear shapes). The covariance is the white-noise one plus
    both. ``encoder_offset``: the best joint (``_fit1``), kept for the jackknife's and the shifts' refits."""
    f = _fit1(shape, rows, sd, tool, t_onset, fired)
    if f is None:
        raise ValueError("encoder_offset: the rows hold no joint axis it may be of (kernel.new_state(nj), "
                         "encoder_joints)")
    if model_sd is not None:
        add = np.zeros_like(f.cov)
        for c in range(6):
            if model_sd[c] > 0.0:
                shifted = rows.copy()
                shifted[:, K.G_E + c] += model_sd[c]
                d = _fit1(shape, shifted, sd, tool, t_onset, fired, f.joint).p - f.p
                add += np.outer(d, d)
        f = f._replace(cov=f.cov + add)
    if not jackknife or len(rows) < 5 * JACK_BLOCKS:
        return f
    edges = np.linspace(0, len(rows), JACK_BLOCKS + 1).astype(int)
    ps = np.array([_fit1(shape, np.concatenate([rows[:edges[i]], rows[edges[i + 1]:]]), sd, tool, t_onset, fired,
                         f.joint).p
                   for i in range(JACK_BLOCKS)])
    d = ps - ps.mean(axis=0)
    jack = (JACK_BLOCKS - 1) / JACK_BLOCKS * d.T @ d
    return f._replace(cov=f.cov + jack)


def _fit1(shape: str, rows: np.ndarray, sd: np.ndarray, tool: Tool, t_onset: float,
          fired: np.ndarray | None = None, joint: int = -1) -> Fit:
    """Least squares of the residual on the shape's columns, rows divided by the channel sd (6,);
    ``fired`` (6,) bool: the channels whose test fired (a drift's constant is fitted on those only);
    ``encoder_offset``: of ``joint``, or (-1) each of ``encoder_joints`` alone and the least chi^2 kept
    (one parameter: the offline library's one-of; None where no joint has an axis)."""
    if shape == "world_force":
        p, cov, chi2, m = _world_force(rows, sd)
        return Fit(shape, p, cov, chi2, chi2 + 6 * np.log(m), m)
    if shape == "encoder_offset" and joint < 0:
        fits = [_fit1(shape, rows, sd, tool, t_onset, fired, j) for j in encoder_joints(rows)]
        return min(fits, key=lambda f: f.chi2) if fits else None
    C = columns(shape, rows, tool, t_onset, joint)
    if shape == "ft_bias_drift":  # the rate on every channel, the constant (the onset's error) on those that fired
        keep = np.concatenate([np.ones(6, bool), fired if fired is not None else np.ones(6, bool)])
        C = C[:, :, keep]
    C = C / sd[None, :, None]
    y = rows[:, K.G_E:K.G_E + 6] / sd[None, :]
    A = C.reshape(-1, C.shape[2])
    b = y.reshape(-1)
    P0 = np.diag(1.0 / prior_sd(shape)[keep if shape == "ft_bias_drift" else slice(None)] ** 2)
    H = A.T @ A + P0
    p = np.linalg.solve(H, A.T @ b)
    r = b - A @ p
    chi2 = float(r @ r)
    m, k = len(b), A.shape[1]
    cov = np.linalg.inv(H) * max(1.0, chi2 / max(m - k, 1))
    if shape == "ft_bias_drift":  # back to rate (6) + constant (6)
        full = np.zeros(12)
        full[keep] = p
        cf = np.zeros((12, 12))
        cf[np.ix_(keep, keep)] = cov
        p, cov = full, cf
    return Fit(shape, p, cov, chi2, chi2 + k * np.log(m), m, joint)


def relevant_sizes(shape: str, relevant_force_N: float) -> np.ndarray:
    """Each parameter's relevant size in SI, the smallest worth reporting (the offline diagnosis's: its
    effect library's ``relevant``, ``effects.builtin``): ``tool_gravity`` 30 g and 1.5 g m,
    ``tool_tilt`` and ``ft_frame_rotation`` 1 deg a component, ``encoder_offset`` 0.5 deg,
    ``ft_bias_drift`` 0.03 N/s and 0.003 N m/s
    (its constants and ``sensor_constant``: ``ft_offset``'s 0.2 N, 0.02 N m); ``world_force``: the set-up's
    ``[analysis] relevant_force_N`` per component of the force (its point: none, inf). -> (k,)"""
    from kinadapt_nn.effects.builtin import BUILTINS

    if shape == "world_force":
        return np.array([relevant_force_N] * 3 + [np.inf] * 3)
    if shape == "ft_bias_drift":
        return np.concatenate([BUILTINS["ft_bias_drift"].relevant, BUILTINS["ft_offset"].relevant])
    if shape == "encoder_offset":  # one joint's (the library's one-of)
        return np.asarray(BUILTINS["encoder_offset"].relevant[:1], dtype=float)
    return np.asarray(BUILTINS["ft_offset" if shape == "sensor_constant" else shape].relevant, dtype=float)


def relevance(f: Fit, relevant_force_N: float) -> float:
    """The estimate's size in relevant sizes, ``|p / relevant_sizes|`` (for a turn: its angle over 1 deg);
    an event needs at least 1."""
    return float(np.linalg.norm(f.p / relevant_sizes(f.shape, relevant_force_N)))


def significant(f: Fit, p_false: float) -> bool:
    """Whether the estimate differs from no change: ``p^T cov^+ p`` beyond the chi^2 quantile at
    ``1 - p_false`` with the covariance's rank as the degrees of freedom."""
    from scipy.stats import chi2

    w, V = np.linalg.eigh(0.5 * (f.cov + f.cov.T))
    keep = w > 1e-12 * max(float(w.max()), 1e-300)
    proj = V[:, keep].T @ f.p
    return float(np.sum(proj ** 2 / w[keep])) > float(chi2.ppf(1.0 - p_false, int(keep.sum())))


def evaluate(f: Fit, rows: np.ndarray, tool: Tool, t_onset: float) -> np.ndarray:
    """The fitted shape's wrench on ring rows -> (n, 6) (tool on sensor, s)."""
    if f.shape == "world_force":
        n = len(rows)
        R = rows[:, K.G_R:K.G_R + 9].reshape(n, 3, 3)
        f_s = R.transpose(0, 2, 1) @ f.p[:3]
        return np.concatenate([f_s, np.cross(f.p[3:], f_s)], axis=1)
    return columns(f.shape, rows, tool, t_onset, f.joint) @ f.p


def chi2_of(f: Fit, rows: np.ndarray, sd: np.ndarray, tool: Tool, t_onset: float) -> float:
    """chi^2 of ring rows' residual (without the shape's correction) against the fitted shape."""
    r = (rows[:, K.G_E:K.G_E + 6] - evaluate(f, rows, tool, t_onset)) / sd[None, :]
    return float(np.sum(r * r))


def design(shape: str, rows: np.ndarray, sd: np.ndarray, tool: Tool, t_onset: float, f: Fit,
           fired: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The shape's design at its fit, rows divided by the channel sd: (A (6n, k) the columns -- for the
    world force the Jacobian at the estimate --, e (6n,) the residual the fit leaves)."""
    n = len(rows)
    if shape == "world_force":
        R = rows[:, K.G_R:K.G_R + 9].reshape(n, 3, 3)
        Rt = R.transpose(0, 2, 1)
        fw, p = f.p[:3], f.p[3:]
        f_s = Rt @ fw
        J = np.zeros((n, 6, 6))
        J[:, :3, :3] = Rt
        J[:, 3:, :3] = _skew(np.broadcast_to(p, (n, 3))) @ Rt
        J[:, 3:, 3:] = -_skew(f_s)
        A = (J / sd[None, :, None]).reshape(-1, 6)
    else:
        C = columns(shape, rows, tool, t_onset, f.joint)
        if shape == "ft_bias_drift":
            C = C[:, :, np.concatenate([np.ones(6, bool), fired if fired is not None else np.ones(6, bool)])]
        A = (C / sd[None, :, None]).reshape(-1, C.shape[2])
    e = ((rows[:, K.G_E:K.G_E + 6] - evaluate(f, rows, tool, t_onset)) / sd[None, :]).reshape(-1)
    return A, e


def slow_bic(f: Fit, rows: np.ndarray, sd: np.ndarray, tool: Tool, t_onset: float, slow_sd: np.ndarray,
             fired: np.ndarray | None = None) -> float:
    """The fit's BIC where each channel also carries an unknown constant error of the model, ``b_c ~ N(0,
    slow_sd_c^2)`` [N, N m] (the model's slow error before the change: what a constant shape would otherwise
    be named for fitting): ``-2 ln`` of the likelihood with ``b`` integrated out (Laplace, exact for a
    linear shape) and the shape's parameters by BIC's ``k ln m``: the least ``|e - A dp - B b|^2 + b^T
    P_b b`` plus ``ln det(S_b P_b^-1)``, ``S_b`` b's precision with the shape's parameters free (where the
    shape has a constant of its own on a channel, b there is not seen: no cost). -> the BIC."""
    keep = slow_sd > 0.0
    if not keep.any():
        return f.bic
    A, e = design(f.shape, rows, sd, tool, t_onset, f, fired)
    n = len(rows)
    B = np.zeros((n, 6, 6))
    B[:, np.arange(6), np.arange(6)] = 1.0 / sd
    B = B.reshape(-1, 6)[:, keep]
    Pb = np.diag(1.0 / slow_sd[keep] ** 2)
    pr = prior_sd(f.shape)
    if f.shape == "ft_bias_drift":
        pr = pr[np.concatenate([np.ones(6, bool), fired if fired is not None else np.ones(6, bool)])]
    Pp = np.diag(1.0 / pr ** 2)
    Hpp, Hpb, Hbb = A.T @ A + Pp, A.T @ B, B.T @ B + Pb
    H = np.block([[Hpp, Hpb], [Hpb.T, Hbb]])
    x = np.linalg.solve(H, np.concatenate([A.T @ e, B.T @ e]))
    k = A.shape[1]
    r = e - A @ x[:k] - B @ x[k:]
    chi2 = float(r @ r + x[k:] @ Pb @ x[k:])
    S = Hbb - Hpb.T @ np.linalg.solve(Hpp, Hpb)
    occam = float(np.linalg.slogdet(S)[1] - np.linalg.slogdet(Pb)[1])
    return chi2 + k * np.log(f.rows) + occam


def best(rows: np.ndarray, sd: np.ndarray, tool: Tool, t_onset: float,
         fired: np.ndarray | None = None, slow_sd: np.ndarray | None = None,
         shapes: tuple[str, ...] = SHAPES) -> tuple[Fit, list[Fit]]:
    """The best-fitting of ``shapes`` (least BIC) and every fit, best first; with ``slow_sd`` (6,) [N, N m]
    the BIC with the model's slow error integrated out (``slow_bic``). ``encoder_offset`` is left out where
    the rows have no joint it may be of (``encoder_joints``)."""
    fits = [f for f in (fit(s, rows, sd, tool, t_onset, fired) if s != "encoder_offset" or encoder_joints(rows)
                        else None for s in shapes) if f is not None]
    if slow_sd is not None:
        fits = [f._replace(bic=slow_bic(f, rows, sd, tool, t_onset, slow_sd, fired)) for f in fits]
    fits = sorted(fits, key=lambda f: f.bic)
    return fits[0], fits


def end_look(rows: np.ndarray, sd: np.ndarray, tool: Tool, t_onset: float, fired: np.ndarray | None = None,
             slow_sd: np.ndarray | None = None) -> tuple[Fit, list[Fit], list[str]]:
    """The end-of-run look's verdict (``Monitor._end_look``): every shape of ``END_SHAPES`` fitted (``best``);
    the best is the least-BIC live shape (``SHAPES``), and its near-ties (``ties``) are sought among all of
    them, so ``encoder_offset`` is a rival only: it may tie the best, it is not named best (docs/monitor.md,
    "Agreement with the offline diagnosis": as a candidate it out-named a turned mount by BIC on its one
    parameter against three while its chi^2 was worse, the moment error the slow BIC forgives).
    -> (the best, every fit in BIC order, the best's ties)."""
    _, fits = best(rows, sd, tool, t_onset, fired, slow_sd=slow_sd, shapes=END_SHAPES)
    named = next(f for f in fits if f.shape in SHAPES)
    return named, fits, ties(named, fits, rows, sd, tool, t_onset, fired)


#: near-ties (``ties``): a shape ties the best when it explains at least TIE_RATIO of what the best explains
#: (``diagnostics.selection``'s ``tie_ratio``) and neither is worth its parameters once the other is fitted
#: (the monitor's own criterion, BIC)
TIE_RATIO = 0.8


def _target(f: Fit, rows: np.ndarray, sd: np.ndarray, tool: Tool, t_onset: float,
            fired: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The fit's linear form on the window: (A (6n, k) its columns -- the world force's Jacobian at its
    estimate --, b (6n,) the data it is fitted to -- for the world force linearised at its estimate,
    ``e + J p`` --, the prior precision's diagonal (k,))."""
    A, e = design(f.shape, rows, sd, tool, t_onset, f, fired)
    pr = prior_sd(f.shape)
    p = f.p
    if f.shape == "ft_bias_drift":
        keep = np.concatenate([np.ones(6, bool), fired if fired is not None else np.ones(6, bool)])
        pr, p = pr[keep], p[keep]
    return A, e + A @ p, 1.0 / pr ** 2


def _misfit(A: np.ndarray, b: np.ndarray, prec: np.ndarray) -> float:
    """chi^2 of ``b`` after the least squares on ``A`` with the prior precision ``prec`` (the data's part)."""
    p = np.linalg.solve(A.T @ A + np.diag(prec), A.T @ b)
    r = b - A @ p
    return float(r @ r)


def ties(best: Fit, fits: list[Fit], rows: np.ndarray, sd: np.ndarray, tool: Tool, t_onset: float,
         fired: np.ndarray | None = None) -> list[str]:
    """The shapes the window cannot tell from ``best`` (``fits``: every shape's fit on ``rows``, rows divided
    by ``sd``): each explains at least ``TIE_RATIO`` of the chi^2 ``best`` explains, and with both fitted
    together neither lowers the chi^2 by more than its parameters cost in BIC (``k ln(rows)``, the criterion
    that named the best): the data hold no part one explains and the other does not. A shape that contains
    the best (``tool_gravity`` holds every ``tool_tilt``: a first moment turned about O) adds nothing worth
    its parameters when the best is enough, so it ties: the best is then named for having fewer parameters
    only. -> shape names, in ``fits``' order."""
    A1, b, P1 = _target(best, rows, sd, tool, t_onset, fired)
    log_m = np.log(len(b))
    none = float(np.sum((rows[:, K.G_E:K.G_E + 6] / sd[None, :]) ** 2))  # chi^2 of the window with no shape
    out = []
    for f in fits:
        if f.shape == best.shape:
            continue
        A2, b2, P2 = _target(f, rows, sd, tool, t_onset, fired)
        c1, c2 = _misfit(A1, b, P1), _misfit(A2, b2, P2)
        # together: on the world force's linearised data where one is the world force (its fit's residual at
        # its estimate, the other's columns free), else on the data
        both = _misfit(np.hstack([A1, A2]), b2 if f.shape == "world_force" else b, np.concatenate([P1, P2]))
        if none - c2 < TIE_RATIO * (none - c1):
            continue
        if c2 - both > A1.shape[1] * log_m or c1 - both > A2.shape[1] * log_m:
            continue  # one explains a part of what the other leaves, worth its parameters: the data tell them apart
        out.append(f.shape)
    return out


AXES = ("x", "y", "z")
CHANNELS = ("F_x", "F_y", "F_z", "M_x", "M_y", "M_z")


def _along(v: np.ndarray, cov: np.ndarray) -> tuple[float, float, str]:
    """|v| along its direction with the sd of that projection, and the direction in words (the
    dominant axis with its sign, '-y', or the unit vector)."""
    size = float(np.linalg.norm(v))
    u = v / max(size, 1e-300)
    sd = float(np.sqrt(max(u @ cov @ u, 0.0)))
    i = int(np.argmax(np.abs(u)))
    word = f"{'+' if u[i] > 0 else '-'}{AXES[i]}" if abs(u[i]) > 0.95 else "(" + ", ".join(f"{x:+.2f}" for x in u) + ")"
    return size, sd, word


def describe(f: Fit, tool: Tool, frame: str, sign: float = 1.0) -> tuple[str, dict]:
    """The event's words and its estimate (a dict of values, their sds and units) from the best fit;
    ``frame``: what the world frame is called (for a world force's direction); ``sign``: the log's
    convention (``LogCfg.sign``): a drift's or a step's channels are said as the log has them."""
    p, cov = f.p, f.cov
    if f.shape in ("ft_bias_drift", "sensor_constant"):
        p = sign * p
    if f.shape == "tool_gravity":
        m, sd = float(p[0]), float(np.sqrt(cov[0, 0]))
        com = p[1:4] / m if abs(m) > 1e-9 else np.full(3, np.nan)
        text = (f"a payload appeared, {m:.3g} ± {Z95 * sd:.2g} kg" if m > 0 else
                f"the tool got lighter, {-m:.3g} ± {Z95 * sd:.2g} kg")
        return text, {"mass_kg": m, "mass_sd_kg": sd, "com_s_m": com.tolist(), "first_moment_kg_m": p[1:4].tolist()}
    if f.shape == "world_force":
        size, sd, word = _along(p[:3], cov[:3, :3])
        return (f"a {frame}-frame force appeared, {size:.2g} ± {Z95 * sd:.2g} N along {word}",
                {"force_w_N": p[:3].tolist(), "force_cov_w_N2": cov[:3, :3].tolist(), "size_N": size,
                 "size_sd_N": sd, "point_s_m": p[3:].tolist()})
    if f.shape == "ft_bias_drift":
        sd6 = np.sqrt(np.diag(cov)[:6])
        i = int(np.argmax(np.abs(p[:6]) / np.maximum(sd6, 1e-300)))
        unit = "N/s" if i < 3 else "N m/s"
        return (f"the sensor started drifting, {p[i]:+.2g} ± {Z95 * sd6[i]:.2g} {unit} in {CHANNELS[i]}",
                {"rate_s": p[:6].tolist(), "rate_sd_s": sd6.tolist()})
    if f.shape == "ft_frame_rotation":
        deg = np.rad2deg(p)
        cd = np.rad2deg(np.rad2deg(cov))
        size, sd, word = _along(deg, cd)
        return (f"the sensor turned in its mount, {size:.2g} ± {Z95 * sd:.2g} deg about {word}",
                {"rotvec_deg": deg.tolist(), "rotvec_cov_deg2": cd.tolist(), "angle_deg": size, "angle_sd_deg": sd})
    if f.shape == "encoder_offset":
        deg, sd = float(np.rad2deg(p[0])), float(np.rad2deg(np.sqrt(cov[0, 0])))
        return (f"joint {f.joint + 1}'s encoder zero is off, {deg:+.2g} ± {Z95 * sd:.2g} deg",
                {"joint": f.joint + 1, "offset_deg": deg, "offset_sd_deg": sd})
    if f.shape == "tool_tilt":
        deg = np.rad2deg(p)
        cd = np.rad2deg(np.rad2deg(cov))
        size, sd, word = _along(np.array([*deg, 0.0]), np.pad(cd, ((0, 1), (0, 1))))
        return (f"the tool turned in the grasp, {size:.2g} ± {Z95 * sd:.2g} deg about {word}",
                {"tilt_deg": deg.tolist(), "tilt_cov_deg2": cd.tolist(), "angle_deg": size, "angle_sd_deg": sd})
    sd6 = np.sqrt(np.diag(cov))
    i = int(np.argmax(np.abs(p) / np.maximum(sd6, 1e-300)))
    unit = "N" if i < 3 else "N m"
    return (f"a constant wrench appeared, {p[i]:+.2g} ± {Z95 * sd6[i]:.2g} {unit} in {CHANNELS[i]}",
            {"step_s": p.tolist(), "step_sd_s": sd6.tolist()})


def correction(f: Fit, tool: Tool, t_onset: float) -> np.ndarray:
    """The fitted shape as the kernel's model correction (``kernel.NCORR``), added to what is there (a live
    shape's: ``SHAPES``)."""
    if f.shape not in SHAPES:
        raise ValueError(f"{f.shape} is not named live: the kernel has no correction of it")
    c = np.zeros(K.NCORR)
    p = f.p
    if f.shape == "tool_gravity":
        c[K.K_DM], c[K.K_DMC:K.K_DMC + 3] = p[0], p[1:4]
    elif f.shape == "tool_tilt":
        c[K.K_DMC:K.K_DMC + 3] = np.cross(np.array([p[0], p[1], 0.0]), tool.mc)
    elif f.shape == "world_force":
        c[K.K_FW:K.K_FW + 3], c[K.K_P:K.K_P + 9] = p[:3], np.outer(p[3:], p[:3]).ravel()
    elif f.shape == "ft_bias_drift":
        c[K.K_RATE:K.K_RATE + 6], c[K.K_CONST:K.K_CONST + 6] = p[:6], p[6:]
    elif f.shape == "ft_frame_rotation":
        c[K.K_ROT:K.K_ROT + 3] = p
    else:
        c[K.K_CONST:K.K_CONST + 6] = p
    return c
