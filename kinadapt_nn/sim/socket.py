"""The low-bias socket contact (``scene.contact_model = "socket"``) as one numba kernel.

Truth side only (the simulator applies it; the controller never sees it). One call per physics
step, for one simulation, on the state the step starts from (after ``mj_step1``, before ``mj_step2``;
a batch: after its ``forward(stage=VEL)``, before its step), so the fixture pushes on the pose the
step's reading belongs to: the single episode (``PegInHoleSim.step``) passes views of its ``MjData``,
a batch (``sim.scenes.SceneBatch``) the rows of its bound ``(B, ...)`` arrays, so both run the same
arithmetic. (Before, it read the kinematics the previous step had computed: a spring acting on the
pose one step late, 1 ms, which biased the friction couple's estimate by -0.6 %.)

The wrench, at the tool body (``xfrc_applied``: force at its centre of mass, world)::

    f     = [-k_lat (tip - p0)_xy - c_lat v_xy ; 0]  (- n (k_ax depth + c_ax n.v) below the entrance)
    tau   = -k_rot rotvec(R R0^T) - c_rot w          (- r |f| w / (|w| + eps): contact_friction_couple)
    xfrc  = [f ; tau + (tip - com) x f]

``p0, R0``: where the tip and the tool frame were when the socket engaged (``engage = "drive"``:
at the end of the settle window; ``"depth"``: when the true tip crossed the entrance plane,
released when it is back 1 mm above it). ``[w; v]``: the tip's spatial velocity, world-aligned
(``mj_objectVelocity`` of the tip site with ``flg_local = 0``, here from ``cvel`` and the
subtree centre of mass as MuJoCo computes it).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

#: state row: [engaged (0/1), p0 (3), R0 (9, row-major), |f| of the last step]
N_STATE = 14
#: parameter row indices
(P_ENGAGE_DRIVE, P_SETTLE, P_K_LAT, P_C_LAT, P_K_AX, P_C_AX, P_K_ROT, P_C_ROT, P_COUPLE, P_RADIUS, P_EPS) = range(11)
P_N = 11  # bore axis n (3)
P_ENTRY = 14  # true bore entrance (3)
N_PARAMS = 17
#: [kg] order of the arm's effective mass at the tip, for the damping only
M_EFF_KG = 3.0


def socket_damping(scene) -> tuple[float, float, float]:
    """The socket's dampers from ``scene`` (``SceneCfg``: its stiffnesses and ``socket_damping_ratio``
    z): ``(c_lat [N s/m], c_ax [N s/m], c_rot [N m s/rad])`` = 2 z sqrt(k m) with the arm's effective
    mass ``M_EFF_KG`` at the tip (lateral, axial) and 0.01 kg m^2 (rotation)."""
    z = scene.socket_damping_ratio
    return (2.0 * z * math.sqrt(scene.socket_k_lat_N_per_m * M_EFF_KG),
            2.0 * z * math.sqrt(max(scene.socket_k_axial_N_per_m, 0.0) * M_EFF_KG),
            2.0 * z * math.sqrt(max(scene.socket_k_rot_Nm_per_rad, 0.0) * 0.01))


def socket_params(cfg, entry_w: np.ndarray, bore_axis_w: np.ndarray) -> np.ndarray:
    """The kernel's parameters from the truth-side experiment config (``cfg.scene``'s socket
    stiffnesses and damping ratio, ``cfg.start.settle_s``, effect ``contact_friction_couple``)
    and the true bore entrance / axis (world). -> (N_PARAMS,)."""
    sc = cfg.scene
    fc = cfg.effects.contact_friction_couple
    c_lat, c_ax, c_rot = socket_damping(sc)
    prm = np.zeros(N_PARAMS)
    prm[P_ENGAGE_DRIVE] = 1.0 if sc.socket_engage == "drive" else 0.0
    prm[P_SETTLE] = cfg.start.settle_s
    prm[P_K_LAT] = sc.socket_k_lat_N_per_m
    prm[P_C_LAT] = c_lat
    prm[P_K_AX] = sc.socket_k_axial_N_per_m
    prm[P_C_AX] = c_ax
    prm[P_K_ROT] = sc.socket_k_rot_Nm_per_rad
    prm[P_C_ROT] = c_rot
    prm[P_COUPLE] = 1.0 if fc.enabled else 0.0
    prm[P_RADIUS], prm[P_EPS] = (fc.radius_m, fc.omega_eps_rad_s) if fc.enabled else (0.0, 1.0)
    prm[P_N:P_N + 3] = bore_axis_w
    prm[P_ENTRY:P_ENTRY + 3] = entry_w
    return prm


@nb.njit(cache=True)
def socket_step(t, st, prm, tip, R, com, cvel, subtree_com, xfrc):  # noqa: PLR0913 (a numba kernel: flat arrays by necessity)
    """One step of the socket for one simulation, in place: ``st`` (N_STATE,) its state, ``prm``
    (N_PARAMS,), the current ``tip`` (3,) (the tip site, world), ``R`` (9,) the tool body's
    orientation (row-major), ``com`` (3,) its centre of mass, ``cvel`` (6,) its com-based
    velocity [w; v] and ``subtree_com`` (3,) its tree root's subtree centre of mass; writes the
    tool body's ``xfrc`` (6,). ``t``: the simulation time [s]."""
    n0, n1, n2 = prm[P_N], prm[P_N + 1], prm[P_N + 2]
    depth = n0 * (tip[0] - prm[P_ENTRY]) + n1 * (tip[1] - prm[P_ENTRY + 1]) + n2 * (tip[2] - prm[P_ENTRY + 2])
    if prm[P_ENGAGE_DRIVE] > 0.0:
        if t < prm[P_SETTLE]:
            return
    elif (st[0] == 0.0 and depth < 0.0) or (st[0] != 0.0 and depth < -1e-3):
        st[0] = 0.0
        for i in range(6):
            xfrc[i] = 0.0
        st[13] = 0.0
        return
    if st[0] == 0.0:  # engage: anchor where the tip and the tool frame are now
        st[0] = 1.0
        for i in range(3):
            st[1 + i] = tip[i]
        for i in range(9):
            st[4 + i] = R[i]
    # the tip's velocity, world-aligned: w = cvel_rot, v = cvel_lin - (tip - subtree_com) x w
    w0, w1, w2 = cvel[0], cvel[1], cvel[2]
    d0, d1, d2 = tip[0] - subtree_com[0], tip[1] - subtree_com[1], tip[2] - subtree_com[2]
    v0 = cvel[3] - (d1 * w2 - d2 * w1)
    v1 = cvel[4] - (d2 * w0 - d0 * w2)
    v2 = cvel[5] - (d0 * w1 - d1 * w0)
    f0 = -prm[P_K_LAT] * (tip[0] - st[1]) - prm[P_C_LAT] * v0
    f1 = -prm[P_K_LAT] * (tip[1] - st[2]) - prm[P_C_LAT] * v1
    f2 = 0.0
    if prm[P_K_AX] > 0.0 and depth > 0.0:  # pushes the tip back out (-n)
        a = prm[P_K_AX] * depth + prm[P_C_AX] * (n0 * v0 + n1 * v1 + n2 * v2)
        f0 -= n0 * a
        f1 -= n1 * a
        f2 -= n2 * a
    # rotvec(R R0^T): angle from the trace, axis from the skew part
    M = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            M[i, j] = R[3 * i] * st[4 + 3 * j] + R[3 * i + 1] * st[5 + 3 * j] + R[3 * i + 2] * st[6 + 3 * j]
    cos_a = min(max((M[0, 0] + M[1, 1] + M[2, 2] - 1.0) / 2.0, -1.0), 1.0)
    angle = math.acos(cos_a)
    r0, r1, r2 = M[2, 1] - M[1, 2], M[0, 2] - M[2, 0], M[1, 0] - M[0, 1]
    s = 0.5 if angle < 1e-9 else angle / (2.0 * math.sin(angle))
    k_rot, c_rot = prm[P_K_ROT], prm[P_C_ROT]
    t0 = -k_rot * (s * r0) - c_rot * w0
    t1 = -k_rot * (s * r1) - c_rot * w1
    t2 = -k_rot * (s * r2) - c_rot * w2
    fn = math.sqrt(f0 * f0 + f1 * f1 + f2 * f2)
    if prm[P_COUPLE] > 0.0:  # effect contact_friction_couple
        g = prm[P_RADIUS] * fn / (math.sqrt(w0 * w0 + w1 * w1 + w2 * w2) + prm[P_EPS])
        t0 -= g * w0
        t1 -= g * w1
        t2 -= g * w2
    e0, e1, e2 = tip[0] - com[0], tip[1] - com[1], tip[2] - com[2]
    xfrc[0], xfrc[1], xfrc[2] = f0, f1, f2
    xfrc[3] = t0 + (e1 * f2 - e2 * f1)
    xfrc[4] = t1 + (e2 * f0 - e0 * f2)
    xfrc[5] = t2 + (e0 * f1 - e1 * f0)
    st[13] = fn
