"""A joint encoder's zero offset (one joint at a time): the true angle is the reading + offset.

Columns: ``d w_nominal / d q_j``, the whole nominal model's change (gravity direction and the
tool's inertial load) per unit change of joint j's reading, analytic from the sensor's Jacobians
(``LogSignals.nominal_wrench_dq``: one kinematics pass, not two per joint; the tests check it
against central differences of ``LogSignals.nominal_wrench``). Whether a joint's offset can be
seen at all comes from the data (its column), not from the arm's make.
One parameter per arm joint (``offset_joint1..offset_jointN``, N = the set-up's ``[log] q``):
``params_for``, the public form of set-up-dependent parameters.
"""

from __future__ import annotations

import numpy as np

from kinadapt_nn.diagnostics.builtin.ft_frame_rotation import plausible_small_angle, report_deg
from kinadapt_nn.diagnostics.contract import effect

RELEVANT_RAD = np.deg2rad(0.5)  #: the smallest offset worth reporting


def _names(dof: int) -> tuple[str, ...]:
    return tuple(f"offset_joint{j}" for j in range(1, dof + 1))


def params_per_joint(setup) -> tuple[dict[str, str], list[float]]:
    """One offset per joint of the set-up's arm (its ``[log] q`` columns)."""
    names = _names(len(setup.log.q))
    return {n: "rad" for n in names}, [RELEVANT_RAD] * len(names)


def report(p, sd, setup) -> dict:
    """The offsets in degrees, any number of joints."""
    return report_deg(_names(len(p)))(p, sd, setup)


@effect(params_for=params_per_joint, doc="a joint encoder zero offset (one of the joints)",
        excite="move every joint in free space so that gravity turns in the sensor frame (an offset of a joint "
               "whose axis stays vertical is invisible to gravity: it needs a world-fixed load direction, e.g. a "
               "horizontal push against a fixture)",
        one_of=True, report=report, plausible=plausible_small_angle, uses_contact=False)
def encoder_offset(s):
    return s.nominal_wrench_dq()
