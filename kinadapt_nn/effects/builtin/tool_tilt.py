"""The tool sits rotated in the grasp about the sensor's x and y axes (first order).

The COM moves by ``delta x c`` (gravity and inertia, through ``tool_gravity``'s first-moment
columns), the tip by ``delta x p``: the contact force's moment about the sensor changes by
``(delta x p) x F_c``, and a declared socket's spring sees the moved tip (its displacement and
lever: ``contact_model.tip_derivative``). Judged only where contacts act through the tip (``[contact] mode = "tip"``):
without it a tilt is only a COM shift, which ``tool_gravity`` already holds.
"""

from __future__ import annotations

import numpy as np

from kinadapt_nn.effects import contact_model
from kinadapt_nn.effects.builtin.ft_frame_rotation import plausible_small_angle, report_deg
from kinadapt_nn.effects.builtin.tool_gravity import first_moment_columns
from kinadapt_nn.effects.contract import effect
from kinadapt_nn.effects.online import Signals, Terms, contact_rate, rot


def online_columns(sig: Signals) -> Terms:
    """The controller's columns (level domain, ``effects.online``): the true tip sits at ``R (l_nom +
    delta x l_nom)``, so in contact it moves with ``omega x (R delta x l_nom)`` (the contact's rate) and
    the contact force acts on a lever longer by ``R (delta x l_nom)`` (a closed-form moment)."""
    n = len(sig.t_s)
    lev = np.zeros((n, 6, 2))
    integ = np.zeros((n, 6, 2))  # rates
    f_tool = -sig.w_env_w[:, :3]
    for j in range(2):
        e = np.zeros(3)
        e[j] = 1.0
        dl_w = rot(sig.R_wf, np.broadcast_to(np.cross(e, sig.l_nom_f), (n, 3)))
        tw = np.zeros((n, 6))
        tw[:, :3] = np.cross(sig.twist_tip_w[:, 3:], dl_w)  # the true tip's extra velocity
        integ[:, :, j] = contact_rate(sig, tw)
        lev[:, 3:, j] = sig.gate[:, None] * np.cross(dl_w, f_tool)  # moment of the contact force about O
    return Terms(lev, integ)


def depth(s, idx: np.ndarray) -> np.ndarray:
    """(e, 2) [m/rad] the tip's depth along a declared socket's axis per unit tilt at the samples ``idx``:
    the tip moves by ``R_ws (delta x p)`` (``contract.Effect.depth``)."""
    tip = np.asarray(s.setup.tool.tip_sensor_m, dtype=float)
    dtip_s = np.stack([np.cross(e, tip) for e in np.eye(3)[:2]], axis=1)  # (3, 2)
    return np.einsum("i,mij,jk->mk", contact_model.socket_axis(s.setup.contact), np.asarray(s.R_ws, dtype=float)[idx],
                     dtip_s)


@effect(params={"tilt_x": "rad", "tilt_y": "rad"}, relevant=[np.deg2rad(1.0)] * 2,
        doc="the tool sits rotated in the grasp (its COM and tip move)",
        excite="push the tip in contact in two lateral directions (the tip lever shows in the moment)",
        report=report_deg(("tilt_x", "tilt_y")), plausible=plausible_small_angle,
        applies=lambda setup: setup.contact.mode == "tip", online=online_columns, depth=depth)
def tool_tilt(s):
    m = float(s.setup.tool.mass_kg)
    mc = m * np.asarray(s.setup.tool.com_sensor_m, dtype=float)
    tip = np.asarray(s.setup.tool.tip_sensor_m, dtype=float)
    grav = first_moment_columns(s)  # (n, 6, 3) per unit first moment
    C = np.zeros((s.n, 6, 2))
    for j in range(2):
        e = np.zeros(3)
        e[j] = 1.0
        C[:, :, j] = grav @ np.cross(e, mc)
        C[:, 3:, j] += np.cross(np.cross(e, tip), s.contact_force_s)
        C[:, :, j] += contact_model.tip_derivative(s.setup, s.R_ws, s.p_ws, np.cross(e, tip), contact_model.log_times(s))
    return C
