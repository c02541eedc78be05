"""A kinadapt effect file (Python code that runs, like a test file): F/T calibration crosstalk.

The sensor reports (I + E) w; a user suspecting these four entries of E writes them as the
parameters (first order: the columns use the measured wrench for the true one). Matches the
``crosstalk`` case of examples/foreign_rig_outside.py.
"""
import numpy as np

from kinadapt_nn.diagnostics import effect

# (row of the reading it leaks into, column of the wrench it leaks from): Fx Fy Fz Tx Ty Tz = 0..5
_ENTRIES = ((1, 0), (2, 2), (3, 1), (5, 0))


@effect(params={"fy_from_fx": "-", "fz_gain": "-", "tx_from_fy": "m", "tz_from_fx": "m"},
        relevant=[0.01, 0.01, 0.002, 0.002],
        doc="F/T calibration-matrix error: Fy from Fx, Fz gain, Tx from Fy, Tz from Fx",
        excite="large forces along x, y and z of the sensor (tilt the tool, press in contact)")
def crosstalk(s):
    """(n, 6, 4): the change of s.wrench per unit of each parameter."""
    cols = np.zeros((len(s.t), 6, len(_ENTRIES)))
    for k, (row, col) in enumerate(_ENTRIES):
        cols[:, row, k] = s.wrench[:, col]
    return cols
