"""A kinadapt effect file (Python code that runs, like a test file): a temperature-driven F/T offset.

Needs the logged sensor temperature declared in the setup (``[log] extra = ["temp_C"]``). Matches the
``temperature`` case of examples/foreign_rig_outside.py: the offset is zero at power-up (the first
sample) and follows the temperature's change since then.
"""
import numpy as np

from kinadapt_nn.diagnostics import effect


@effect(params={"k_fx": "N/K", "k_fy": "N/K", "k_fz": "N/K", "k_tx": "N m/K", "k_ty": "N m/K", "k_tz": "N m/K"},
        relevant=[0.02, 0.02, 0.02, 0.001, 0.001, 0.001],
        doc="the F/T offset follows the sensor temperature (column temp_C)",
        excite="a log long enough for the sensor temperature to change by a few K")
def temperature_bias(s):
    """(n, 6, 6): the change of s.wrench per unit of each parameter."""
    temp = np.asarray(s.extra["temp_C"], dtype=float)
    return (temp - temp[0])[:, None, None] * np.eye(6)[None, :, :]  # zero at the first sample (power-up)
