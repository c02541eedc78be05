"""The F/T offset drifts linearly in time: ``rate * t`` on each channel."""

from __future__ import annotations

import numpy as np

from kinadapt_nn.effects.contract import effect


def _report(p, sd, setup) -> dict:  # in the log's own wrench convention
    units = ("N/s",) * 3 + ("N m/s",) * 3
    names = ("rate_fx", "rate_fy", "rate_fz", "rate_tx", "rate_ty", "rate_tz")
    return {n: {"value": float(setup.log.sign * v), "sd": float(s_), "unit": u} for n, v, s_, u in zip(names, p, sd, units)}


def _plausible(p, setup) -> str | None:
    if np.max(np.abs(p)) > 10.0:
        return f"a drift of {np.max(np.abs(p)):.3g} per second is not a sensor drift"
    return None


def _has_time(setup) -> bool:
    """Time effects are judged only on a time axis that exists (not on a static log's pose index)."""
    return not (setup.log.static and not setup.log.time)


@effect(params={"rate_fx": "N/s", "rate_fy": "N/s", "rate_fz": "N/s", "rate_tx": "N m/s", "rate_ty": "N m/s",
                "rate_tz": "N m/s"},
        relevant=[0.03, 0.03, 0.03, 0.003, 0.003, 0.003], doc="the F/T offset drifts linearly in time",
        excite="a longer log, returning to the same free-space poses at its start and end",
        report=_report, plausible=_plausible, uses_contact=False, applies=_has_time,
        online=True)  # online: these columns, tared at the controller's tare (effects.online.from_wrench)
def ft_bias_drift(s):
    C = np.zeros((s.n, 6, 6))
    for j in range(6):
        C[:, j, j] = s.t
    return C
