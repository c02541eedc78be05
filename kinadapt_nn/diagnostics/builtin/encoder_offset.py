"""A joint encoder's zero offset (one joint at a time): the true angle is the reading + offset.

Columns: ``d w_nominal / d q_j``, the whole nominal model (gravity direction and the tool's
inertial load) recomputed with joint j's reading moved by ``EPS_RAD`` (central difference). Whether
a joint's offset can be seen at all comes from the data (its column), not from the arm's make.
"""

from __future__ import annotations

import numpy as np

from kinadapt_nn.diagnostics.builtin.ft_frame_rotation import plausible_small_angle, report_deg
from kinadapt_nn.diagnostics.contract import effect

EPS_RAD = 1e-5
N_JOINTS = 7
_NAMES = tuple(f"offset_joint{j}" for j in range(1, N_JOINTS + 1))


@effect(params={n: "rad" for n in _NAMES}, relevant=[np.deg2rad(0.5)] * N_JOINTS,
        doc="a joint encoder zero offset (one of the joints)",
        excite="move every joint in free space so that gravity turns in the sensor frame (an offset of a joint "
               "whose axis stays vertical is invisible to gravity: it needs a world-fixed load direction, e.g. a "
               "horizontal push against a fixture)",
        one_of=True, report=report_deg(_NAMES), plausible=plausible_small_angle, uses_contact=False)
def encoder_offset(s):
    C = np.zeros((s.n, 6, N_JOINTS))
    for j in range(min(N_JOINTS, s.q.shape[1])):
        dq = np.zeros(s.q.shape[1])
        dq[j] = EPS_RAD
        C[:, :, j] = (s.nominal_wrench(s.q + dq) - s.nominal_wrench(s.q - dq)) / (2 * EPS_RAD)
    return C
