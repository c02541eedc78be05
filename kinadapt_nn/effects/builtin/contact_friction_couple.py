"""A torsional friction couple opposing rotation in the declared contact: ``-radius |f| w/(|w| + eps)``.

``|f|``: the whole contact force, the measured force beyond the tool's model where the socket is
engaged (``contact_model``; the declared socket's own spring force included); ``w`` the tool's angular velocity (sensor frame; a couple is the same
about any point, so it shows in the moment about the tip). Judged only with a declared geometry.
"""

from __future__ import annotations

import numpy as np

from kinadapt_nn.effects import contact_model
from kinadapt_nn.effects.builtin.contact_stiffness import has_geometry
from kinadapt_nn.effects.contract import effect
from kinadapt_nn.effects.online import Signals, Terms

OMEGA_EPS_RAD_S = 0.005  #: [rad/s] smoothing of sign(w) (a model constant)


def contact_force_norm(s) -> np.ndarray:
    """(n,) [N] the whole contact force where the declared socket is engaged, else 0: the force
    beyond the tool's model -- what the declared socket's springs predict plus what is left beyond
    them (a couple grows with the contact's whole force, not with the part the springs miss)."""
    st = contact_model.socket_terms(s.setup.contact, s.R_ws, s.p_ws, s.setup.tool.tip_sensor_m)
    w_socket = contact_model.nominal_wrench(s.setup, s.R_ws, s.p_ws, contact_model.log_times(s))
    f = (s.wrench - s.w_nom)[:, :3] + w_socket[:, :3]
    return np.linalg.norm(f, axis=1) * st.gate


def couple_columns(force_norm: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(n, 3): the couple per unit radius, ``-|f| w/(|w| + eps)``, for the contact force's norm
    ``force_norm`` (n,) [N] and the angular velocity ``w`` (n, 3) [rad/s] (any frame: the couple's)."""
    return -force_norm[:, None] * w / (np.linalg.norm(w, axis=1) + OMEGA_EPS_RAD_S)[:, None]


def online_columns(sig: Signals) -> Terms:
    """The controller's columns (level domain, ``effects.online``): the couple with the measured
    contact force (the tared wrench's force where S's contact rows apply) and the tool's angular
    velocity, world; the couple on the tool changes the moment levels directly (a closed form)."""
    cols = np.zeros((len(sig.t_s), 6, 1))
    cols[:, 3:, 0] = couple_columns(sig.gate * np.linalg.norm(sig.w_env_w[:, :3], axis=1), sig.twist_tip_w[:, 3:])
    return Terms(cols, None)


def _report(p, sd, setup) -> dict:
    return {"radius": {"value": float(p[0]), "sd": float(sd[0]), "unit": "m"}}


def _plausible(p, setup) -> str | None:
    if p[0] < 0.0:
        return f"a friction radius of {1000 * p[0]:.3g} mm (friction that drives the rotation)"
    return None


@effect(params={"radius": "m"}, relevant=[1e-3],
        doc="a torsional friction couple opposing rotation in contact",
        excite="rotate back and forth in contact under a steady normal force (a couple that flips with the rotation)",
        report=_report, plausible=_plausible, applies=has_geometry, uses_contact=False, online=online_columns)
def contact_friction_couple(s):
    C = np.zeros((s.n, 6, 1))
    C[:, 3:, 0] = couple_columns(contact_force_norm(s), s.omega_s)
    return C


__all__ = ["contact_friction_couple", "contact_force_norm"]
