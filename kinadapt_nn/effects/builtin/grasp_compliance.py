"""The tool yields in the grasp under moment: it turns by ``compliance * M_perp`` about the sensor's
x and y axes (``M_perp``: the contact moment about the sensor origin across the tool axis z_s).

The declared socket answers the turn: its lateral spring sees the tip move by ``delta x tip``, its
angular spring the rotation ``delta`` (``contact_model``). The loads already on the tool turn with it
(first order in the turn, as large as the springs' answer): the contact force ``F`` acts at the moved
tip and the tool's weight and inertial force ``m (g - a)`` at the moved centre of mass, so the moment
about the sensor origin also changes by ``(delta x tip) x F + (delta x m c) x (g - a)``. Under the
excitation's ~11 N axial preload at the 0.1 m lever the first is 1.1 N m/rad against the socket's
20 N m/rad angular spring: without it the compliance came out ~6 % low (issue 49;
``benchmarks/grasp_compliance_check.py``). The change of the wrench on the sensor is linear in the
compliance. Judged only with a declared geometry.
"""

from __future__ import annotations

import numpy as np

from kinadapt_nn.effects import contact_model
from kinadapt_nn.effects.builtin.contact_stiffness import has_geometry
from kinadapt_nn.effects.contract import effect
from kinadapt_nn.effects.online import Signals, Terms, contact_rate, lever_w


def online_columns(sig: Signals) -> Terms:
    """The controller's columns (level domain, ``effects.online``): the grasp turns by ``compliance *
    M_perp`` (the contact moment across the flange axis z_f, from the sensor vector ``s``), which moves
    the nominal tip by ``M_perp x R l_nom``; the contact answers that displacement and rotation through
    S's contact rows (linear: a closed-form level), and the contact force on the tool now acts at the
    moved tip, its moment about O changed by ``(M_perp x R l_nom) x f_tool`` (a closed-form level, as
    ``tool_tilt``'s lever)."""
    M = sig.s[:, 3:]  # contact moment on the tool about O (world)
    z = sig.R_wf[:, :, 2]
    M_perp = M - np.sum(M * z, axis=1)[:, None] * z  # the hinges yield about f x, f y only
    d_tip = np.cross(M_perp, lever_w(sig))  # tip displacement per unit compliance
    disp = np.concatenate([d_tip, M_perp], axis=1)  # ... and rotation
    level = contact_rate(sig, disp)  # the map is linear: displacement -> level change
    level[:, 3:] += sig.gate[:, None] * np.cross(d_tip, -sig.w_env_w[:, :3])  # the contact force at the moved tip
    return Terms(level[:, :, None], None)


def _report(p, sd, setup) -> dict:
    return {"compliance": {"value": float(p[0]), "sd": float(sd[0]), "unit": "rad/(N m)"},
            "stiffness": {"value": float(1.0 / p[0]) if p[0] > 0 else None, "sd": float(sd[0] / max(p[0], 1e-12) ** 2),
                          "unit": "N m/rad"}}


def _plausible(p, setup) -> str | None:
    if p[0] < 0.0:
        return f"a compliance of {p[0]:.3g} rad/(N m) (a grasp that turns against the moment)"
    return None


@effect(params={"compliance": "rad/(N m)"}, relevant=[1e-3],
        doc="the tool yields in the grasp under moment",
        excite="load the tool with a moment in contact (lateral pushes at the tip)",
        report=_report, plausible=_plausible, applies=has_geometry, uses_contact=False, online=online_columns)
def grasp_compliance(s):
    c = s.setup.contact
    tip = np.asarray(s.setup.tool.tip_sensor_m, dtype=float)
    st = contact_model.socket_terms(c, s.R_ws, s.p_ws, tip)
    # the contact moment about the sensor origin: the measured one beyond the tool model (the
    # socket's nominal wrench is the contact, so it is added back), where the socket is engaged
    w_contact = contact_model.nominal_wrench(s.setup, s.R_ws, s.p_ws, contact_model.log_times(s))
    M_s = (s.wrench - s.w_nom + w_contact)[:, 3:] * st.gate[:, None]
    M_perp = M_s.copy()
    M_perp[:, 2] = 0.0  # the grasp yields about s x and s y only
    turn_w = np.einsum("nij,nj->ni", s.R_ws, M_perp)  # per unit compliance [rad per rad/(N m)]
    d_tip = np.cross(turn_w, np.einsum("nij,j->ni", s.R_ws, tip))
    d_tip -= np.outer(d_tip @ st.axis_w, st.axis_w)
    f_w = -c.stiffness_lat_N_per_m * d_tip * st.gate[:, None]
    tau_w = -c.stiffness_rot_Nm_per_rad * turn_w
    out = contact_model.on_tool_to_sensor(s.R_ws, tip, f_w, tau_w)
    out[:, 3:] += loads_turned(M_perp, tip, (s.wrench - s.w_nom + w_contact)[:, :3] * st.gate[:, None],
                               s.setup.tool.inertials()[1], (s.g_s - s.a_s) * st.gate[:, None])
    return out[:, :, None]


def loads_turned(turn_s: np.ndarray, tip_s: np.ndarray, f_contact_s: np.ndarray, mc_s: np.ndarray,
                 ga_s: np.ndarray) -> np.ndarray:
    """(n, 3) [N m per unit turn] the change of the moment about the sensor origin (s) when the tool
    turns by ``turn_s`` (n, 3) [rad] about it with its loads: the contact force ``f_contact_s`` (n, 3)
    [N] at the tip ``tip_s`` (3,) [m] and the tool's load ``m (g - a)`` at its centre of mass (first
    moment ``mc_s`` (3,) [kg m], ``ga_s`` (n, 3) [m/s^2] gravity minus the sensor's acceleration), both
    on the tool, sensor axes: ``(turn x tip) x F + (turn x m c) x (g - a)``."""
    tip_s, mc_s = np.asarray(tip_s, dtype=float), np.asarray(mc_s, dtype=float)
    return (np.cross(np.cross(turn_s, tip_s), f_contact_s)
            + np.cross(np.cross(turn_s, mc_s), ga_s))


__all__ = ["grasp_compliance", "loads_turned"]
