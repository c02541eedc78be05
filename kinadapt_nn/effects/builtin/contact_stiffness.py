"""The contact is stiffer or softer than the declared socket: ``factor - 1`` times its nominal wrench.

Judged only where a contact geometry is declared (``[contact] geometry``, ``contact_model``): the
columns are the declared socket's own wrench on the sensor (lateral spring at the tip, angular
spring), so a factor scales both springs. In the contact rows (moments about the tip) the angular
spring carries it; the lateral force, acting at the tip, shows only outside the detected contact.
"""

from __future__ import annotations

from kinadapt_nn.effects import contact_model
from kinadapt_nn.effects.contract import effect
from kinadapt_nn.effects.online import Signals, Terms, contact_rate


def _report(p, sd, setup) -> dict:
    return {"stiffness_factor": {"value": float(1.0 + p[0]), "sd": float(sd[0]), "unit": "-"}}


def _plausible(p, setup) -> str | None:
    if 1.0 + p[0] <= 0.0:
        return f"a stiffness factor of {1.0 + p[0]:.3g} (a contact that pulls)"
    return None


def online_columns(sig: Signals) -> Terms:
    """The controller's columns (level domain, ``effects.online``): the nominal map's contact rate
    ``S [v_tip; omega]`` (gated), scaled by ``factor - 1``."""
    return Terms(None, contact_rate(sig, sig.twist_tip_w)[:, :, None])


def has_geometry(setup) -> bool:
    """A contact geometry is declared ([contact] geometry): the contact-model effects are judged."""
    return setup.contact.declared_geometry and setup.contact.mode == "tip"


@effect(params={"stiffness_factor_minus_1": "-"}, relevant=[0.1],
        doc="the contact stiffness differs from the declared socket's",
        excite="push laterally into the contact and rotate about the tip in contact",
        report=_report, plausible=_plausible, applies=has_geometry, uses_contact=False, online=online_columns)
def contact_stiffness(s):
    return contact_model.nominal_wrench(s.setup, s.R_ws, s.p_ws)[:, :, None]


__all__ = ["contact_stiffness", "has_geometry"]
