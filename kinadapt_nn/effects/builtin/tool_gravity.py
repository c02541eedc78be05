"""An undeclared mass on the tool (or a wrong declared mass/COM): its weight and inertial load.

Parameters: the added mass ``dm`` [kg] and its first moment ``dm c`` [kg m] (c: the added mass's
COM in s). Change of the tool-on-sensor wrench (Newton-Euler, the added mass's own rotational
inertia neglected): ``[dm (g_s - a_s) - alpha x dmc - omega x (omega x dmc); dmc x (g_s - a_s)]``.
"""

from __future__ import annotations

import numpy as np

from kinadapt_nn.effects.contract import effect

RELEVANT_MASS_KG = 0.03  #: 30 g
RELEVANT_FIRST_MOMENT_KG_M = 0.0015  #: 30 g at 50 mm


def first_moment_columns(s) -> np.ndarray:
    """(n, 6, 3): the wrench change per unit first moment ``m c`` (s axes) at fixed mass."""
    ga = s.g_s - s.a_s
    C = np.zeros((s.n, 6, 3))
    for j in range(3):
        e = np.zeros(3)
        e[j] = 1.0
        C[:, :3, j] = -np.cross(s.alpha_s, e) - np.cross(s.omega_s, np.cross(s.omega_s, e))
        C[:, 3:, j] = np.cross(e, ga)
    return C


def _report(p, sd, setup) -> dict:
    """Added mass [kg] and its COM [m] (first-order sd); the total mass and COM of the tool."""

    def q(v, s_, unit):
        return {"value": float(v), "sd": float(s_), "unit": unit}

    dm, sdm = float(p[0]), float(sd[0])
    out = {"mass": q(dm, sdm, "kg")}
    for a, mc, smc in zip("xyz", p[1:], sd[1:]):
        if abs(dm) < RELEVANT_MASS_KG:  # no relevant added mass: a shift of the declared COM
            out[f"com_{a}"] = {"value": None, "sd": None, "unit": "m",
                               "note": "no relevant added mass: see first_moment_* and total_com_*"}
            continue
        c = mc / dm
        sc = abs(c) * np.hypot(smc / max(abs(mc), 1e-12), sdm / max(abs(dm), 1e-12))
        out[f"com_{a}"] = q(c, sc, "m")
    m0, mc0, _ = setup.tool.inertials()  # the declared tool
    tot = m0 + dm
    out["total_mass"] = q(tot, sdm, "kg")
    for a, mc, smc in zip("xyz", p[1:], sd[1:]):
        out[f"first_moment_{a}"] = q(mc, smc, "kg m")
    for a, mc_t, smc in zip("xyz", mc0 + p[1:], sd[1:]):
        if tot > 0:
            c_t = mc_t / tot
            out[f"total_com_{a}"] = q(c_t, abs(c_t) * np.hypot(smc / max(abs(mc_t), 1e-12), sdm / tot), "m")
        else:
            out[f"total_com_{a}"] = {"value": None, "sd": None, "unit": "m", "note": "the total mass is not positive"}
    return out


def _plausible(p, setup) -> str | None:
    tot = setup.tool.mass_kg + p[0]
    if tot <= 0:
        return f"the tool would weigh {tot:.3g} kg (declared {setup.tool.mass_kg:g} kg + {p[0]:.3g} kg)"
    if abs(p[0]) >= RELEVANT_MASS_KG and np.linalg.norm(p[1:] / p[0]) > 1.0:
        return f"the added mass would sit {np.linalg.norm(p[1:] / p[0]):.3g} m from the sensor"
    return None


@effect(params={"mass": "kg", "mass*com_x": "kg m", "mass*com_y": "kg m", "mass*com_z": "kg m"},
        relevant=[RELEVANT_MASS_KG] + [RELEVANT_FIRST_MOMENT_KG_M] * 3,
        doc="a mass on the tool that the setup does not declare (or a wrong declared mass/COM)",
        excite="reorient the tool in free space through several poses (tilts of 20-40 deg about two horizontal axes)",
        report=_report, plausible=_plausible, uses_contact=False,
        online=True)  # online: these columns, tared at the controller's tare (effects.online.from_wrench)
def tool_gravity(s):
    C = np.zeros((s.n, 6, 4))
    C[:, :3, 0] = s.g_s - s.a_s
    C[:, :, 1:] = first_moment_columns(s)
    return C
