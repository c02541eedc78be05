"""A features type in one file: the adjoint with theta in millimetres (docs/architecture.md,
"Adding a features type").

``J_hat(q; theta) = J_adjoint(q; theta / 1000)``, ``Phi = Phi_adjoint / 1000`` (p = 3, theta in
mm). It is not the adjoint's class, so no kernel knows it: the controller takes its rows from
Python. Registering it is the second file's one line: ``FEATURES[SPEC.name] = SPEC`` (or ``SPEC``
in the ``registry(...)`` of ``kinadapt_nn/features/__init__.py``); then ``run.features=adjoint_mm``
runs it.
"""

from __future__ import annotations

import numpy as np

from kinadapt_nn.features.adjoint import nominal_adjoint
from kinadapt_nn.features.base import Features, KinState, Regressor
from kinadapt_nn.features.registry import Built, FeaturesContext, FeaturesSpec

MM = 1e3  #: theta's unit: millimetres per metre


class MillimetreAdjoint(Features):
    """The adjoint with theta in millimetres (p = 3)."""

    name = "adjoint_mm"
    n_params = 3

    def __init__(self, adjoint) -> None:
        self.adjoint = adjoint
        self.P0 = MM**2 * adjoint.P0  # the same prior, in mm^2

    def jacobian(self, kin: KinState, theta: np.ndarray) -> np.ndarray:
        """J_hat (m, n) at theta (3,) [mm]."""
        return self.adjoint.jacobian(kin, theta / MM)

    def twist_jacobian(self, kin: KinState, theta: np.ndarray) -> np.ndarray:
        """J_hat on the wrist twist (m, 6) at theta (3,) [mm]."""
        return self.adjoint.twist_jacobian(kin, theta / MM)

    def regressor(self, kin: KinState, qdot: np.ndarray) -> Regressor:
        """known (m,), Phi (m, 3) per mm."""
        reg = self.adjoint.regressor(kin, qdot)
        return Regressor(reg.known, reg.Phi / MM)

    def omega(self) -> tuple[np.ndarray, np.ndarray]:
        """Omega's centre and half-widths (3,) [mm]."""
        centre, half = self.adjoint.omega()
        return MM * centre, MM * half


def build(ctx: FeaturesContext) -> Built:
    """The type from what the robot knows; theta0 = the offset estimate in mm."""
    return Built(MillimetreAdjoint(nominal_adjoint(ctx.known)), MM * np.asarray(ctx.offset_estimate_f_m))


SPEC = FeaturesSpec(name="adjoint_mm", doc="the adjoint, theta in mm (an example type)", build=build,
                    theta0_per_episode=True)
