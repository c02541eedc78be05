"""A constant F/T offset in an untared log (a tared log's offset is a nuisance, always fitted)."""

from __future__ import annotations

import numpy as np

from kinadapt_nn.effects.contract import effect


def _report(p, sd, setup) -> dict:  # in the log's own wrench convention
    names, units = ("fx", "fy", "fz", "tx", "ty", "tz"), ("N",) * 3 + ("N m",) * 3
    return {n: {"value": float(setup.log.sign * v), "sd": float(s_), "unit": u} for n, v, s_, u in zip(names, p, sd, units)}


def _plausible(p, setup) -> str | None:
    """An offset no sensor of the declared range shows (only when the range is declared)."""
    rf, rt = setup.sensor.range_force_N, setup.sensor.range_torque_Nm
    if rf > 0 and np.max(np.abs(p[:3])) > rf:
        return f"a force offset of {np.max(np.abs(p[:3])):.3g} N exceeds the sensor's range ({rf:g} N)"
    if rt > 0 and np.max(np.abs(p[3:])) > rt:
        return f"a torque offset of {np.max(np.abs(p[3:])):.3g} N m exceeds the sensor's range ({rt:g} N m)"
    return None


@effect(params={"fx": "N", "fy": "N", "fz": "N", "tx": "N m", "ty": "N m", "tz": "N m"},
        relevant=[0.2, 0.2, 0.2, 0.02, 0.02, 0.02], doc="a constant F/T offset in an untared log",
        excite="reorient in free space (a constant offset does not turn with gravity)",
        report=_report, plausible=_plausible, applies=lambda setup: not setup.log.tared, uses_contact=False)
def ft_offset(s):
    return np.broadcast_to(np.eye(6)[None], (s.n, 6, 6)).copy()
