"""A constant F/T offset in an untared log (a tared log's offset is a nuisance, always fitted)."""

from __future__ import annotations

import numpy as np

from kinadapt_nn.diagnostics.contract import effect


def _report(p, sd, setup) -> dict:  # in the log's own wrench convention
    names, units = ("fx", "fy", "fz", "tx", "ty", "tz"), ("N",) * 3 + ("N m",) * 3
    return {n: {"value": float(setup.log.sign * v), "sd": float(s_), "unit": u} for n, v, s_, u in zip(names, p, sd, units)}


@effect(params={"fx": "N", "fy": "N", "fz": "N", "tx": "N m", "ty": "N m", "tz": "N m"},
        relevant=[0.2, 0.2, 0.2, 0.02, 0.02, 0.02], doc="a constant F/T offset in an untared log",
        excite="reorient in free space (a constant offset does not turn with gravity)",
        report=_report, applies=lambda setup: not setup.log.tared, uses_contact=False)
def ft_offset(s):
    return np.broadcast_to(np.eye(6)[None], (s.n, 6, 6)).copy()
