"""A kinadapt effect file (Python code that runs, like a test file): a flat face pressed on a surface.

A flat-faced tool (a box peg) whose face is centred at the declared tip and pressed flat is not a
point contact: the pressure spreads over the face, so the surface's wrench has a moment about the
face centre. It follows the contact force the diagnosis already has (``s.contact_force_s``, the
force beyond the tool model in contact, sensor frame; ``n`` the face's outward normal, ``f_n`` the
normal force):

* tilting: friction pulls the face along the surface and the pressure centre moves towards the
  leading edge in proportion to the friction force, ``M = h f_c x n`` (the normal part of ``f_c``
  drops out); ``h`` [m] = the shift per unit of friction/normal force (positive);
* a pressure centre off the face centre, ``M = p x f_n n`` for ``p`` = (``centre_x``, ``centre_y``)
  [m] along the sensor's x and y axes (the face's plane for a normal along s_z);
* torsional (drilling) friction against the turn ``w = omega . n`` about the normal, sharing the
  friction with the slip of the face centre ``v_t`` (a limit surface: a face that slides and turns
  at once resists each less), ``M = -r_t |f_n| rho w / sqrt(|v_t|^2 + (rho w)^2 + eps^2) n``, with
  ``rho`` the face's effective radius (the mean distance of its points from the centre: about
  0.38 x the side of a square) and ``eps`` the slip speed below which the face is taken as
  sticking; ``r_t`` [m] = friction coefficient x ``rho``.

Edit ``FACE_NORMAL_S`` (the face's outward normal in the sensor frame, here the tool axis s_z),
``FACE_SIDE_M`` and ``SLIP_EPS_M_S`` to your tool. The moment is about the declared tip (the face
centre), so the effect acts only in contact. Matches the ``flat_face*`` cases of
examples/contact_rig.py (h = 3.5 mm / 0.35 = 10 mm, r_t = 0.35 x 7.65 mm = 2.7 mm).
"""
import numpy as np

from kinadapt_nn.diagnostics import effect

FACE_NORMAL_S = np.array([0.0, 0.0, 1.0])  # the face's outward normal in the sensor frame (the tool axis)
FACE_SIDE_M = 0.020  # [m] side of the square face
FACE_RADIUS_M = 0.3826 * FACE_SIDE_M  # [m] mean distance of a square's points from its centre
SLIP_EPS_M_S = 0.003  # [m/s] slip speed below which the face is taken as sticking


def _slip_velocity_s(s) -> np.ndarray:
    """(n, 3) [m/s] the face centre's velocity along the face, sensor frame."""
    tip_s = np.asarray(s.setup.tool.tip_sensor_m, dtype=float)
    tip_w = s.p_ws + np.einsum("nij,j->ni", s.R_ws, tip_s)
    v_s = np.einsum("nji,nj->ni", s.R_ws, np.gradient(tip_w, s.t, axis=0))
    return v_s - np.outer(v_s @ FACE_NORMAL_S, FACE_NORMAL_S)


@effect(params={"tilt_lever": "m", "centre_x": "m", "centre_y": "m", "torsion_radius": "m"},
        relevant=[0.002, 0.001, 0.001, 0.001],
        doc="flat face pressed on a surface: pressure centre moved by friction and off centre, torsional friction",
        excite="press the face and slide it in several directions, and twist it about its normal")
def face_contact(s):
    """(n, 6, 4): the change of s.wrench per unit of each parameter (moments about the face centre)."""
    c = np.asarray(s.contact, dtype=float)
    f = s.contact_force_s  # (n, 3) [N], zero in free space
    f_n = f @ FACE_NORMAL_S  # (n,) [N]
    w = s.omega_s @ FACE_NORMAL_S  # (n,) [rad/s]
    slip = np.sqrt(np.sum(_slip_velocity_s(s) ** 2, axis=1) + (FACE_RADIUS_M * w) ** 2 + SLIP_EPS_M_S**2)
    cols = np.zeros((len(s.t), 6, 4))
    cols[:, 3:, 0] = c[:, None] * np.cross(f, FACE_NORMAL_S)
    for k, axis in ((1, (1.0, 0.0, 0.0)), (2, (0.0, 1.0, 0.0))):
        cols[:, 3:, k] = c[:, None] * np.cross(np.asarray(axis), np.outer(f_n, FACE_NORMAL_S))
    cols[:, 3:, 3] = -(c * np.abs(f_n) * FACE_RADIUS_M * w / slip)[:, None] * FACE_NORMAL_S
    return cols
