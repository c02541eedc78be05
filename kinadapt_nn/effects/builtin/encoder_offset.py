"""A joint encoder's zero offset (one joint at a time): the true angle is the reading + offset.

Columns: ``d w_nominal / d q_j``, the whole nominal model's change (gravity direction and the
tool's inertial load) per unit change of joint j's reading, analytic from the sensor's Jacobians
(``LogSignals.nominal_wrench_dq``: one kinematics pass, not two per joint; the tests check it
against central differences of ``LogSignals.nominal_wrench``). Whether a joint's offset can be
seen at all comes from the data (its column), not from the arm's make.
One parameter per arm joint (``offset_joint1..offset_jointN``, N = the set-up's ``[log] q``):
``params_for``, the public form of set-up-dependent parameters.

A joint whose axis is the sensor's z axis (the wrist's last joint when the sensor sits on the flange
axis; :func:`sensor_z_joint`) turns the sensor frame about z_s: its offset changes the reading as a
sensor rotation about z_s does (``ft_frame_rotation``'s ``rot_z``), apart from the tool's asymmetry
about that axis. Where ``ft_frame_rotation`` is judged (a known mount) the two are one finding: that
joint has no column here (it is never selected; the turn is reported once, as ``rot_z``) -- fitted
as two, they split one turn between them at will (the excitation table: rot_z and a joint-7 offset
0.988 correlated, each estimate off by its share).
"""

from __future__ import annotations

import numpy as np

from kinadapt_nn.effects.builtin.ft_frame_rotation import plausible_small_angle, report_deg
from kinadapt_nn.effects.contract import effect
from kinadapt_nn.robot import N_JOINTS

RELEVANT_RAD = np.deg2rad(0.5)  #: the smallest offset worth reporting


def _names(dof: int) -> tuple[str, ...]:
    return tuple(f"offset_joint{j}" for j in range(1, dof + 1))


def params_per_joint(setup) -> tuple[dict[str, str], list[float]]:
    """One offset per joint of the set-up's arm (its ``[log] q`` columns)."""
    return _per_joint(len(setup.log.q))


def _per_joint(dof: int) -> tuple[dict[str, str], list[float]]:
    names = _names(dof)
    return {n: "rad" for n in names}, [RELEVANT_RAD] * len(names)


def report(p, sd, setup) -> dict:
    """The offsets in degrees, any number of joints."""
    return report_deg(_names(len(p)))(p, sd, setup)


@effect(*_per_joint(N_JOINTS), params_for=params_per_joint,  # until for_setup: this package's arm's joints
        doc="a joint encoder zero offset (one of the joints)",
        excite="move every joint in free space so that gravity turns in the sensor frame (an offset of a joint "
               "whose axis stays vertical is invisible to gravity: it needs a world-fixed load direction, e.g. a "
               "horizontal push against a fixture)",
        one_of=True, report=report, plausible=plausible_small_angle, uses_contact=False)
def encoder_offset(s):
    C = s.nominal_wrench_dq()
    j = sensor_z_joint(s) if s.setup.sensor.mount_known else None
    if j is not None:
        C[:, :, j] = 0.0  # the sensor's turn about z_s: ft_frame_rotation's rot_z (module docstring)
    return C


#: [rad] a joint's axis within this of the sensor's z axis at every row is that axis
AXIS_TOL_RAD = 1e-5


def sensor_z_joint(s) -> int | None:
    """The joint (0-based) whose axis is the sensor's z axis (+-) at every row of the log ``s``, or
    None: its angular Jacobian column in the sensor frame, ``R_ws^T J_w[:, :, j]``, on the first,
    middle and last rows."""
    rows = np.unique([0, s.n // 2, s.n - 1])
    _, J_w = s.arm.sensor_jacobian(np.asarray(s.q, dtype=float)[rows])
    R_ws = np.asarray(s.R_ws, dtype=float)[rows]
    axis_s = np.einsum("nji,njk->nik", R_ws, J_w)  # (r, 3, dof)
    for j in range(axis_s.shape[2] - 1, -1, -1):
        a = axis_s[:, :, j]
        if np.all(np.abs(a[:, 2]) > 0.5) and np.all(np.abs(a[:, :2]) < AXIS_TOL_RAD):  # a hinge (unit axis) along z_s
            return j
    return None
