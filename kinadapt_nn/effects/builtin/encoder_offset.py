"""A joint encoder's zero offset (one joint at a time): the true angle is the reading + offset.

Columns: ``d w_nominal / d q_j``, the whole nominal model's change (gravity direction and the
tool's inertial load) per unit change of joint j's reading, analytic from the sensor's Jacobians
(``LogSignals.nominal_wrench_dq``: one kinematics pass, not two per joint; the tests check it
against central differences of ``LogSignals.nominal_wrench``). Whether a joint's offset can be
seen at all comes from the data (its column), not from the arm's make.
One parameter per arm joint (``offset_joint1..offset_jointN``, N = the set-up's ``[log] q``):
``params_for``, the public form of set-up-dependent parameters.

A joint whose axis is the sensor's z axis (the wrist's last joint when the sensor sits on the flange
axis; :func:`sensor_z_joint`) turns the sensor frame about z_s: its offset changes the reading as a
sensor rotation about z_s does (``ft_frame_rotation``'s ``rot_z``), apart from the tool's asymmetry
about that axis. Where ``ft_frame_rotation`` is judged (a known mount) the two are one finding: that
joint has no column here (it is never selected; the turn is reported once, as ``rot_z``) -- fitted
as two, they split one turn between them at will (the excitation table: rot_z and a joint-7 offset
0.988 correlated, each estimate off by its share).
"""

from __future__ import annotations

import numpy as np

from kinadapt_nn.effects import contact_model
from kinadapt_nn.effects.builtin.ft_frame_rotation import plausible_small_angle, report_deg
from kinadapt_nn.effects.contract import effect
from kinadapt_nn.effects.online import Signals, Terms, contact_rate, rot, tip_twist_map, to_level
from kinadapt_nn.robot import N_JOINTS

RELEVANT_RAD = np.deg2rad(0.5)  #: the smallest offset worth reporting


def _names(dof: int) -> tuple[str, ...]:
    return tuple(f"offset_joint{j}" for j in range(1, dof + 1))


def params_per_joint(setup) -> tuple[dict[str, str], list[float]]:
    """One offset per joint of the set-up's arm (its ``[log] q`` columns)."""
    return _per_joint(len(setup.log.q))


def _per_joint(dof: int) -> tuple[dict[str, str], list[float]]:
    names = _names(dof)
    return {n: "rad" for n in names}, [RELEVANT_RAD] * len(names)


def report(p, sd, setup) -> dict:
    """The offsets in degrees, any number of joints."""
    return report_deg(_names(len(p)))(p, sd, setup)


def encoder_derivatives(sig: Signals, eps: float = 1e-6, grid_s: float = 0.005) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per joint ``j`` = 0..N_JOINTS-2 (the flange joint left out: ``online_columns``), the derivatives of
    the encoder-dependent signals in that joint's zero (``q -> q + eps e_j``, forward differences):
    ``(dR (N, 3, 3), dtwist (N, 6))`` of ``R_wf`` and of the nominal-tip twist ``Ad(R l_nom) J_arm qdot``.
    The derivatives of the tip-twist map and of ``R_wf`` depend on ``q`` only, so they are evaluated on a
    ``grid_s`` grid and interpolated, then applied to the full-rate ``qdot``. -> N_JOINTS - 1 pairs."""
    n = len(sig.t_s)
    step = max(1, int(round(grid_s / sig.dt_s)))
    grid = np.r_[np.arange(0, n, step), n - 1] if n > 1 else np.zeros(1, int)
    grid = np.unique(grid)

    def tip_map(k) -> np.ndarray:  # (6, 7): [v_tip; omega] = A qdot
        return tip_twist_map(k.R_wf, k.J_arm, sig.l_nom_f)

    base_A = np.empty((len(grid), 6, 7))
    base_R = np.empty((len(grid), 3, 3))
    for gi, i in enumerate(grid):
        k = sig.kin.update(sig.q_rad[i])
        base_A[gi], base_R[gi] = tip_map(k), k.R_wf
    t = sig.t_s
    out = []
    for j in range(N_JOINTS - 1):
        dA = np.empty((len(grid), 6, 7))
        dR = np.empty((len(grid), 3, 3))
        for gi, i in enumerate(grid):
            q = sig.q_rad[i].copy()
            q[j] += eps
            k = sig.kin.update(q)
            dA[gi] = (tip_map(k) - base_A[gi]) / eps
            dR[gi] = (k.R_wf - base_R[gi]) / eps
        dA_f = np.stack([np.interp(t, t[grid], dA[:, a, b]) for a in range(6) for b in range(7)], axis=1).reshape(n, 6, 7)
        dR_f = np.stack([np.interp(t, t[grid], dR[:, a, b]) for a in range(3) for b in range(3)], axis=1).reshape(n, 3, 3)
        out.append((dR_f, np.einsum("nij,nj->ni", dA_f, sig.qdot_rad_s)))
    return out


def online_columns(sig: Signals, eps: float = 1e-6, grid_s: float = 0.005,
                   derivs: list[tuple[np.ndarray, np.ndarray]] | None = None) -> Terms:
    """The controller's columns (level domain, ``effects.online``), one per joint of this package's arm:
    finite differences of the nominal model in each joint's zero (``encoder_derivatives``): the measured
    level ``Z = to_level(R r)`` with the lever ``R l_nom`` and the tip-contact rate of the twist. A joint
    that sits at reading + offset leaves ``-dZ/dq_j`` in the level and ``+d(rate)/dq_j`` in the
    prediction's integral (the residual is measured minus predicted). The flange joint's column is zero:
    its axis is the sensor's z axis, and its offset turns the reading as ``ft_frame_rotation``'s ``rot_z``
    does (the nominal tip is on that axis), as in the diagnosis (``sensor_z_joint``). ``derivs``:
    ``encoder_derivatives`` when already computed."""
    n = len(sig.t_s)
    lev = np.zeros((n, 6, N_JOINTS))
    integ = np.zeros((n, 6, N_JOINTS))
    for j, (dR_f, dtw) in enumerate(derivs if derivs is not None else encoder_derivatives(sig, eps, grid_s)):
        dRr = np.concatenate([rot(dR_f, sig.r_tared_f[:, :3]), rot(dR_f, sig.r_tared_f[:, 3:])], axis=1)
        integ[:, :, j] = contact_rate(sig, dtw)
        dZ = to_level(sig, dRr)  # d/dq_j of Z = to_level(R r) with the lever R l_nom:
        dZ[:, 3:] -= sig.gate[:, None] * np.cross(rot(dR_f, np.broadcast_to(sig.l_nom_f, (n, 3))), -sig.w_env_w[:, :3])
        lev[:, :, j] = -dZ
    return Terms(lev, integ)


def depth(s, idx: np.ndarray) -> np.ndarray:
    """(e, dof) [m/rad] the declared tip's depth along a declared socket's axis per unit offset of each
    joint at the samples ``idx`` (``contract.Effect.depth``): the tip moves by ``J_v + J_w x R_ws p``
    (world, per unit q_j). The joint whose column ``encoder_offset`` leaves zero is zero here too."""
    idx = np.asarray(idx, dtype=int)
    q = np.asarray(s.q, dtype=float)[idx]
    J_v, J_w = s.arm.sensor_jacobian(q)  # (e, 3, dof) world
    lever = np.asarray(s.R_ws, dtype=float)[idx] @ np.asarray(s.setup.tool.tip_sensor_m, dtype=float)  # (e, 3)
    dtip = J_v + np.cross(J_w, lever[:, :, None], axis=1)
    out = np.einsum("i,mij->mj", contact_model.socket_axis(s.setup.contact), dtip)
    j = sensor_z_joint(s) if s.setup.sensor.mount_known else None
    if j is not None:
        out[:, j] = 0.0
    return out


def exact(s, p: np.ndarray) -> np.ndarray:
    """(n, 6) the declared model's wrench had the encoders read ``q + p`` (``p`` (dof,) [rad]), less the
    wrench at ``q``: the tool's gravity and inertia, and a declared socket's with its engagement and
    anchors where the moved tip puts them (``diagnostics.nonlinear``: the columns are first order)."""
    q = np.asarray(s.q, dtype=float)
    return s.nominal_wrench(q + np.asarray(p, dtype=float)[None, :]) - s.nominal_wrench(q)


@effect(*_per_joint(N_JOINTS), params_for=params_per_joint,  # until for_setup: this package's arm's joints
        doc="a joint encoder zero offset (one of the joints)",
        excite="move every joint in free space so that gravity turns in the sensor frame (an offset of a joint "
               "whose axis stays vertical is invisible to gravity: it needs a world-fixed load direction, e.g. a "
               "horizontal push against a fixture)",
        one_of=True, report=report, plausible=plausible_small_angle, uses_contact=False, online=online_columns,
        depth=depth, exact=exact)
def encoder_offset(s):
    C = s.nominal_wrench_dq()
    j = sensor_z_joint(s) if s.setup.sensor.mount_known else None
    if j is not None:
        C[:, :, j] = 0.0  # the sensor's turn about z_s: ft_frame_rotation's rot_z (module docstring)
    return C


#: [rad] a joint's axis within this of the sensor's z axis at every row is that axis
AXIS_TOL_RAD = 1e-5


def sensor_z_joint(s) -> int | None:
    """The joint (0-based) whose axis is the sensor's z axis (+-) at every row of the log ``s``, or
    None: its angular Jacobian column in the sensor frame, ``R_ws^T J_w[:, :, j]``, on the first,
    middle and last rows."""
    rows = np.unique([0, s.n // 2, s.n - 1])
    _, J_w = s.arm.sensor_jacobian(np.asarray(s.q, dtype=float)[rows])
    R_ws = np.asarray(s.R_ws, dtype=float)[rows]
    axis_s = np.einsum("nji,njk->nik", R_ws, J_w)  # (r, 3, dof)
    for j in range(axis_s.shape[2] - 1, -1, -1):
        a = axis_s[:, :, j]
        if np.all(np.abs(a[:, 2]) > 0.5) and np.all(np.abs(a[:, :2]) < AXIS_TOL_RAD):  # a hinge (unit axis) along z_s
            return j
    return None
