"""A kinadapt effect file (Python code that runs, like a test file): F/T crosstalk of Fz into Fx.

The sensor reports ``Fx + k Fz``; a user suspecting this one entry of the calibration matrix writes
it as the parameter (first order: the column uses the measured Fz for the true one). Matches the
``flat_face`` case of examples/contact_rig.py (k = 0.04).
"""
import numpy as np

from kinadapt_nn.diagnostics import effect


@effect(params={"fx_from_fz": "-"}, relevant=[0.01],
        doc="F/T calibration-matrix error: Fx from Fz",
        excite="a large force along the sensor's z axis (press in contact, turn the tool against gravity)")
def crosstalk_fx_fz(s):
    """(n, 6, 1): the change of s.wrench per unit of the parameter."""
    cols = np.zeros((len(s.t), 6, 1))
    cols[:, 0, 0] = s.wrench[:, 2]
    return cols
