"""The sensor's axes are rotated from their declared mounting (columns first order in the rotation; once
selected, re-estimated exactly: ``exact_rotation``, ``diagnostics.nonlinear``).

``r_meas = R(delta)^T r = r + r x delta``: the measured wrench stands for the true one, whatever
loads the sensor (the tool, an undeclared mass, a contact). A tared log's missing
``w(q_tare) x delta`` is constant and goes into the offset nuisance.
"""

from __future__ import annotations

import numpy as np

from kinadapt_nn.effects.contract import effect
from kinadapt_nn.geometry import skews

MAX_FIRST_ORDER_DEG = 15.0  #: beyond this a first-order rotation model is not a finding


def report_deg(names):
    """A ``report`` that gives radian parameters in degrees."""
    def rep(p, sd, setup) -> dict:
        return {n: {"value": float(np.rad2deg(v)), "sd": float(np.rad2deg(s_)), "unit": "deg"}
                for n, v, s_ in zip(names, p, sd)}
    return rep


def plausible_small_angle(p, setup) -> str | None:
    if np.max(np.abs(p)) > np.deg2rad(MAX_FIRST_ORDER_DEG):
        return f"{np.rad2deg(np.max(np.abs(p))):.3g} deg is beyond a mounting/zero error (the model is first order)"
    return None


def exact_rotation(s, p) -> np.ndarray:
    """(n, 6) the exact change ``r_meas - R(delta) r_meas`` of the measured wrench's forces and moments for the
    rotation vector ``delta = p`` (3,) [rad] (the columns are its first-order part ``r_meas x delta``)."""
    from scipy.spatial.transform import Rotation

    R = Rotation.from_rotvec(np.asarray(p, float)).as_matrix()
    r = s.wrench
    return np.concatenate([r[:, :3] - r[:, :3] @ R.T, r[:, 3:] - r[:, 3:] @ R.T], axis=1)


@effect(params={"rot_x": "rad", "rot_y": "rad", "rot_z": "rad"}, relevant=[np.deg2rad(1.0)] * 3,
        doc="the sensor's axes are rotated from their declared mounting",
        excite="reorient in free space (gravity along several sensor axes) and push in contact in two directions",
        report=report_deg(("rot_x", "rot_y", "rot_z")), plausible=plausible_small_angle, uses_contact=False,
        applies=lambda setup: setup.sensor.mount_known,  # an unknown mount is estimated whole (diagnostics.mount)
        exact=exact_rotation,  # re-estimated exactly once selected (diagnostics.nonlinear)
        online=True)  # online: these columns on the tared reading (effects.online.from_wrench)
def ft_frame_rotation(s):
    w = np.asarray(s.wrench, dtype=float)
    return np.concatenate([skews(w[:, :3]), skews(w[:, 3:])], axis=1)  # column j: r x e_j
