"""The tool's rotational inertia is not the declared one (an added or moved payload's second moment).

The textbook payload identification (Atkeson, An & Hollerbach 1986) estimates ten inertial
parameters from the wrench and the arm's motion: the mass, the first moment ``m c`` and the six
independent entries of the inertia tensor about the sensor origin ``I_O``. ``tool_gravity`` carries
the first four; this effect carries the other six, the change ``dI_O`` (s axes, about the sensor
origin) of the declared ``I_O = I_c + m (|c|^2 1 - c c^T)``. A payload ``dm`` at ``c`` adds at least
``dm (|c|^2 1 - c c^T)``. Change of the tool-on-sensor wrench (Newton-Euler about the sensor
origin, ``physical.tool_wrench``): no force; moment ``-dI_O alpha - omega x (dI_O omega)``.

Only rotation shows it: angular accelerations about several axes (a moment ``dI alpha``) or fast
turns (the gyroscopic ``omega x dI omega``); a static or slowly reoriented log leaves it
undetermined and it is never ``present`` there.
"""

from __future__ import annotations

import numpy as np

from kinadapt_nn.effects.contract import effect

#: [kg m^2] smallest change worth reporting: 0.2 kg, 50 mm from the axis (0.2 * 0.05^2)
RELEVANT_INERTIA_KG_M2 = 5e-4
#: parameter -> the (row, col) entries of the symmetric tensor it sets
ENTRIES = {"dI_xx": ((0, 0),), "dI_yy": ((1, 1),), "dI_zz": ((2, 2),),
           "dI_xy": ((0, 1), (1, 0)), "dI_xz": ((0, 2), (2, 0)), "dI_yz": ((1, 2), (2, 1))}


def inertia_basis() -> np.ndarray:
    """(6, 3, 3): the symmetric unit tensors of ``ENTRIES`` (the parameters' order)."""
    E = np.zeros((len(ENTRIES), 3, 3))
    for k, cells in enumerate(ENTRIES.values()):
        for i, j in cells:
            E[k, i, j] = 1.0
    return E


def inertia_columns(omega_s: np.ndarray, alpha_s: np.ndarray) -> np.ndarray:
    """(n, 6, 6): the wrench change [N; N m] per unit [kg m^2] of each entry of ``dI_O`` (``ENTRIES``
    order), for angular velocity ``omega_s`` (n, 3) [rad/s] and acceleration ``alpha_s`` (n, 3)
    [rad/s^2] in the sensor frame."""
    n = len(omega_s)
    C = np.zeros((n, 6, len(ENTRIES)))
    for k, E in enumerate(inertia_basis()):
        C[:, 3:, k] = -alpha_s @ E.T - np.cross(omega_s, omega_s @ E.T)
    return C


def _plausible(p, setup) -> str | None:
    """The total tensor about the sensor origin must stay positive semi-definite (within 10 % of the
    relevant size)."""
    _, _, I_O = setup.tool.inertials()  # the declared tool
    total = I_O + np.tensordot(np.asarray(p, float), inertia_basis(), axes=1)
    lo = float(np.linalg.eigvalsh(total)[0])
    if lo < -0.1 * RELEVANT_INERTIA_KG_M2:
        return f"the tool's inertia about the sensor would have a negative principal moment ({lo:.3g} kg m^2)"
    return None


@effect(params={n: "kg m^2" for n in ENTRIES}, relevant=[RELEVANT_INERTIA_KG_M2] * len(ENTRIES),
        doc="the tool's rotational inertia is not the declared one (e.g. a payload's second moment)",
        excite="turn the wrist quickly back and forth about each of its three axes in free space "
               "(angular accelerations of several rad/s^2)",
        plausible=_plausible, uses_contact=False)
def tool_inertia(s):
    return inertia_columns(s.omega_s, s.alpha_s)
