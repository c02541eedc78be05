"""A declared contact geometry's nominal wrench (``[contact] geometry = "socket"`` of the setup).

A socket is a compliant fixture the declared tip enters: a lateral spring at the tip and an
angular spring, anchored where the tip and the tool were when the tip crossed the entrance plane
(released when it is back ``RELEASE_M`` above it)::

    f   = -k_lat P (tip - tip_0) - c_lat P v_tip      (P: the projector across the axis)
    tau = -k_rot rotvec(R R_0^T) - c_rot w            (both on the tool, world)

``c_lat``, ``c_rot``: a declared damper (zero unless the set-up declares one); ``v_tip``, ``w`` the
tip's velocity and the tool's angular velocity (world), differentiated from the pose along the log's
time (``t_s``; a log without time has no damping term).

The environment's wrench on the tool adds to the wrench the tool exerts on the sensor (quasi-
static balance), so ``nominal_wrench`` is that wrench in the sensor frame about its origin: it
joins the declared tool's wrench in the nominal model (``signals.LogSignals.w_nom``). An axial
spring acts through the tip along the axis; it is not modelled (the contact rows are moments
about the tip, where it has none). With no geometry declared the contact force is not modelled
and only "contacts act through the tip" is (``userlog``).

Everything here is computed from the encoders and the set-up: ``R_ws`` (n, 3, 3) the sensor axes
in the world, ``p_ws`` (n, 3) [m] its origin. The contact-model effects
(``builtin/contact_stiffness.py`` and the others) are built on the same terms.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.spatial.transform import Rotation

#: [m] the socket releases when the tip is this far back above the entrance plane (engages at 0)
RELEASE_M = 1e-3


class SocketTerms(NamedTuple):
    """The socket's kinematics per sample (n samples), world frame."""

    gate: np.ndarray  #: (n,) bool: engaged
    tip_w: np.ndarray  #: (n, 3) [m] the declared tip
    disp_lat_w: np.ndarray  #: (n, 3) [m] tip displacement since the anchor, across the axis (0 when free)
    rotvec_w: np.ndarray  #: (n, 3) [rad] rotation of the tool since the anchor (0 when free)
    axis_w: np.ndarray  #: (3,) the unit axis


def _engaged(depth: np.ndarray) -> np.ndarray:
    """(n,) bool: engaged from the first sample at depth >= 0 until depth < -RELEASE_M."""
    out = np.zeros(len(depth), bool)
    near = np.r_[0, (depth >= -RELEASE_M).astype(int), 0]
    edges = np.flatnonzero(np.diff(near))
    for a, b in zip(edges[::2], edges[1::2]):
        inside = np.flatnonzero(depth[a:b] >= 0.0)
        if len(inside):
            out[a + inside[0]:b] = True
    return out


def _anchors(gate: np.ndarray) -> np.ndarray:
    """(n,) the index of each engaged sample's anchor (the first sample of its run); -1 when free."""
    idx = np.arange(len(gate))
    start = gate & ~np.r_[False, gate[:-1]]
    anchor = np.maximum.accumulate(np.where(start, idx, -1))
    return np.where(gate, anchor, -1)


def socket_axis(contact) -> np.ndarray:
    """(3,) the declared socket's unit axis (world): depth along it is ``(tip - entry) . axis``."""
    n_ax = np.asarray(contact.axis_w, dtype=float)
    return n_ax / np.linalg.norm(n_ax)


def socket_terms(contact, R_ws: np.ndarray, p_ws: np.ndarray, tip_s) -> SocketTerms:
    """The socket of ``contact`` (``setup.ContactDeclCfg``) along a log. ``tip_s`` (3,) [m] the
    declared tip in the sensor frame. -> ``SocketTerms``."""
    n_ax = socket_axis(contact)
    tip_w = p_ws + R_ws @ np.asarray(tip_s, dtype=float)
    gate = _engaged((tip_w - np.asarray(contact.entry_w_m, dtype=float)) @ n_ax)
    anc = _anchors(gate)
    on = anc >= 0
    disp = np.zeros_like(tip_w)
    rot = np.zeros_like(tip_w)
    if on.any():
        d = tip_w[on] - tip_w[anc[on]]
        disp[on] = d - np.outer(d @ n_ax, n_ax)
        rel = R_ws[on] @ np.transpose(R_ws[anc[on]], (0, 2, 1))
        rot[on] = Rotation.from_matrix(rel).as_rotvec()
    return SocketTerms(gate, tip_w, disp, rot, n_ax)


def declared_contact(setup, R_ws: np.ndarray, p_ws: np.ndarray) -> np.ndarray | None:
    """(n,) bool: where the declared geometry says the tool can touch -- a declared socket's
    engagement and/or ``[contact] zone = "entrance"`` (the declared tip below the entrance plane or
    within ``zone_m`` above it); None when the set-up declares neither. ``R_ws`` (n, 3, 3),
    ``p_ws`` (n, 3) [m]: the sensor's pose, world."""
    c = setup.contact
    tip = np.asarray(setup.tool.tip_sensor_m, dtype=float)
    out = socket_terms(c, R_ws, p_ws, tip).gate if c.geometry == "socket" else None
    if c.zone == "entrance":
        n_ax = socket_axis(c)
        depth = (p_ws + R_ws @ tip - np.asarray(c.entry_w_m, dtype=float)) @ n_ax
        near = depth >= -c.zone_m
        out = near if out is None else out | near
    return out


def on_tool_to_sensor(R_ws: np.ndarray, tip_s, f_w: np.ndarray, tau_w: np.ndarray) -> np.ndarray:
    """An environment wrench on the tool (force ``f_w`` (n, 3) [N] at the tip, couple ``tau_w``
    (n, 3) [N m], world) as the change of the wrench the tool exerts on the sensor: (n, 6), sensor
    frame, about its origin."""
    f_s = np.einsum("nji,nj->ni", R_ws, f_w)
    tau_s = np.einsum("nji,nj->ni", R_ws, tau_w)
    return np.concatenate([f_s, tau_s + np.cross(np.asarray(tip_s, dtype=float), f_s)], axis=1)


def pose_rates(R_ws: np.ndarray, tip_w: np.ndarray, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The tool's angular velocity ``w_w`` (n, 3) [rad/s] and the tip's velocity ``v_w`` (n, 3) [m/s],
    world, by central differences of the pose along ``t_s`` (n,) [s]: ``w = vee(dR/dt R^T)``."""
    t = np.asarray(t_s, dtype=float)
    if len(t) < 3:
        return np.zeros_like(tip_w), np.zeros_like(tip_w)
    R = np.asarray(R_ws, dtype=float)
    W = np.gradient(R, t, axis=0) @ np.transpose(R, (0, 2, 1))  # (n, 3, 3), skew up to rounding
    w = 0.5 * np.stack([W[:, 2, 1] - W[:, 1, 2], W[:, 0, 2] - W[:, 2, 0], W[:, 1, 0] - W[:, 0, 1]], axis=1)
    return w, np.gradient(np.asarray(tip_w, dtype=float), t, axis=0)


def log_times(s) -> np.ndarray | None:
    """(n,) [s] the samples' times of a log's signals ``s`` for the pose's derivatives (a declared
    damper); None for a static log (its poses are not a motion)."""
    return None if s.setup.log.static else s.t


def nominal_wrench(setup, R_ws: np.ndarray, p_ws: np.ndarray, t_s: np.ndarray | None = None) -> np.ndarray:
    """The declared contact geometry's wrench on the sensor (n, 6) [N, N m] (module docstring);
    zeros when none is declared. ``t_s`` (n,) [s]: the samples' times, for a declared damper."""
    c = setup.contact
    if c.geometry == "none":
        return np.zeros((len(R_ws), 6))
    tip = setup.tool.tip_sensor_m
    st = socket_terms(c, R_ws, p_ws, tip)
    f_w = -c.stiffness_lat_N_per_m * st.disp_lat_w
    tau_w = -c.stiffness_rot_Nm_per_rad * st.rotvec_w
    if t_s is not None and (c.damping_lat_N_s_per_m > 0.0 or c.damping_rot_Nm_s_per_rad > 0.0):
        w_w, v_w = pose_rates(R_ws, st.tip_w, t_s)
        v_lat = v_w - np.outer(v_w @ st.axis_w, st.axis_w)
        f_w = f_w - c.damping_lat_N_s_per_m * v_lat * st.gate[:, None]
        tau_w = tau_w - c.damping_rot_Nm_s_per_rad * w_w * st.gate[:, None]
    return on_tool_to_sensor(R_ws, tip, f_w, tau_w)


def tip_derivative(setup, R_ws: np.ndarray, p_ws: np.ndarray, dtip_s, t_s: np.ndarray | None = None) -> np.ndarray:
    """d ``nominal_wrench`` / d tip along ``dtip_s`` (3,) [m per unit parameter], sensor frame:
    (n, 6). The tip moves the lateral spring's displacement (``P (R - R_0) dtip``: the anchor moves
    with it) and the spring force's lever (``dtip x f``); with the samples' times ``t_s`` (n,) [s] the
    anchors' samples move too (``anchor_shift``: the moved tip crosses the entrance at another time).
    The engagement's own flips are not differentiable. Zeros when no contact geometry is declared."""
    c = setup.contact
    if c.geometry == "none":
        return np.zeros((len(R_ws), 6))
    tip = np.asarray(setup.tool.tip_sensor_m, dtype=float)
    dtip = np.asarray(dtip_s, dtype=float)
    st = socket_terms(c, R_ws, p_ws, tip)
    anc = np.where(st.gate, np.maximum(_anchors(st.gate), 0), 0)
    d_w = (R_ws - R_ws[anc]) @ dtip  # (n, 3): the tip's extra displacement since the anchor
    d_w = np.where(st.gate[:, None], d_w - np.outer(d_w @ st.axis_w, st.axis_w), 0.0)
    f_s = np.einsum("nji,nj->ni", R_ws, -c.stiffness_lat_N_per_m * st.disp_lat_w)
    df_s = np.einsum("nji,nj->ni", R_ws, -c.stiffness_lat_N_per_m * d_w)
    out = np.concatenate([df_s, np.cross(tip, df_s) + np.cross(dtip, f_s)], axis=1)
    if t_s is not None:
        out += anchor_shift(setup, R_ws, p_ws, t_s, (R_ws @ dtip)[:, :, None])[:, :, 0]
    return out

def nominal_wrench_dq(setup, R_ws: np.ndarray, p_ws: np.ndarray, J_v: np.ndarray, J_w: np.ndarray,  # noqa: PLR0913
                      eps: float = 1e-6, t_s: np.ndarray | None = None) -> np.ndarray:
    """(n, 6, dof) ``d nominal_wrench / d q_j``: joint j turns the sensor by ``J_w[:, :, j]`` and
    moves its origin by ``J_v[:, :, j]`` (world, per unit ``q_j``); central differences of the
    socket's wrench along that motion, the engagement and the anchors' samples held, plus the
    anchors' own move (``anchor_shift``: the tip crosses the entrance plane at another time; needs
    the samples' times ``t_s`` (n,) [s], none for a static log)."""
    n, _, dof = J_v.shape
    C = np.zeros((n, 6, dof))
    if setup.contact.geometry == "none":
        return C
    for j in range(dof):
        w = []
        for sgn in (1.0, -1.0):
            Rj = Rotation.from_rotvec(sgn * eps * J_w[:, :, j]).as_matrix() @ R_ws
            w.append(nominal_wrench(setup, Rj, p_ws + sgn * eps * J_v[:, :, j]))
        C[:, :, j] = (w[0] - w[1]) / (2.0 * eps)
    if t_s is not None:
        tip = np.asarray(setup.tool.tip_sensor_m, dtype=float)
        lever = R_ws @ tip  # (n, 3)
        C += anchor_shift(setup, R_ws, p_ws, t_s, J_v + np.cross(J_w, lever[:, :, None], axis=1))
    return C


#: [m/s] an entry slower than this along the axis has no defined crossing time: no anchor move
MIN_ENTRY_SPEED_M_S = 1e-4


def anchor_shift(setup, R_ws: np.ndarray, p_ws: np.ndarray, t_s: np.ndarray, dtip_w: np.ndarray) -> np.ndarray:
    """(n, 6, k) the socket's wrench change through its anchors when the declared tip moves by
    ``dtip_w`` (n, 3, k) [m per unit parameter, world] at every sample. The anchor is the tip's pose
    where it crosses the entrance plane (``socket_terms``); a tip moved by ``dtip`` along the axis
    crosses ``dt_a = -(n . dtip(a)) / (n . v_tip(a))`` later, so the anchored pose moves by
    ``v_tip(a) dt_a`` and ``w(a) dt_a``: the lateral spring's force changes by ``+k_lat P v_tip(a) dt_a``
    and the angular spring's moment by ``+k_rot w(a) dt_a`` (small rotations since the anchor), on
    every engaged sample of that run. The gate's own flips are not differentiable (the release:
    ``diagnostics.release``)."""
    c = setup.contact
    n, _, k = dtip_w.shape
    out = np.zeros((n, 6, k))
    if c.geometry != "socket" or len(t_s) < 3:
        return out
    tip = np.asarray(setup.tool.tip_sensor_m, dtype=float)
    st = socket_terms(c, R_ws, p_ws, tip)
    if not st.gate.any():
        return out
    anc = _anchors(st.gate)
    w_w, v_w = pose_rates(R_ws, st.tip_w, t_s)
    speed = v_w @ st.axis_w  # (n,) along the axis
    on = st.gate
    a = anc[on]
    ok = np.abs(speed[a]) > MIN_ENTRY_SPEED_M_S
    dt_a = np.where(ok[:, None], -np.einsum("i,mik->mk", st.axis_w, dtip_w[a]) / np.where(ok, speed[a], 1.0)[:, None], 0.0)
    v_lat = v_w[a] - np.outer(v_w[a] @ st.axis_w, st.axis_w)  # (m, 3)
    f_w = c.stiffness_lat_N_per_m * v_lat[:, :, None] * dt_a[:, None, :]  # (m, 3, k)
    tau_w = c.stiffness_rot_Nm_per_rad * w_w[a][:, :, None] * dt_a[:, None, :]
    for j in range(k):
        out[on, :, j] = on_tool_to_sensor(R_ws[on], tip, f_w[:, :, j], tau_w[:, :, j])
    return out

__all__ = ["SocketTerms", "socket_axis", "socket_terms", "on_tool_to_sensor", "nominal_wrench", "pose_rates", "log_times", "nominal_wrench_dq", "anchor_shift", "tip_derivative",
           "RELEASE_M"]
