"""A kinadapt effect file (Python code that runs, like a test file): a hose pulling the tool.

Matches the ``world_pull`` case of examples/foreign_rig_outside.py (a constant world-frame pull at a
fixed clamp point on the tool).
"""
import numpy as np

from kinadapt_nn.diagnostics import effect

CLAMP_S_M = np.array([0.0, 0.035, 0.10])  # [m] the clamp point in the sensor frame s
_SKEW = np.array([[0.0, -CLAMP_S_M[2], CLAMP_S_M[1]], [CLAMP_S_M[2], 0.0, -CLAMP_S_M[0]],
                  [-CLAMP_S_M[1], CLAMP_S_M[0], 0.0]])  # _SKEW @ f = CLAMP_S_M x f


@effect(params={"fx_w": "N", "fy_w": "N", "fz_w": "N"}, relevant=[0.2, 0.2, 0.2],
        doc="a hose pulling with a constant world-frame force, clamped 35 mm off the tool axis",
        excite="reorient the tool in free space (a world-fixed pull turns in the sensor frame, unlike an offset)")
def cable_pull(s):
    """(n, 6, 3): the change of s.wrench per unit of each parameter."""
    f = np.swapaxes(s.R_ws, 1, 2)  # f[:, :, j] = R_ws^T e_j: world axis j in the sensor frame
    return np.concatenate([f, _SKEW @ f], axis=1)  # force; moment of the force at the clamp
