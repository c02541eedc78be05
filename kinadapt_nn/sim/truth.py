"""The true sensor Jacobian (evaluation and offline data only; never used by the controller).

``J_true(q)`` maps encoder rates to the rates of the controller's sensor vector
``s = [d, F_lat, M]`` under the nominal contact model S:

* row 0 (depth): ``d`` is computed by the controller from the *nominal* forward kinematics, so
  its row is ``S_0 Ad(R_nom l_nom) J_arm,nom`` whatever the true arm is;
* rows 1..5: the true tip moves with the *true* arm and tool,
  ``S_{1:} Ad(R_true l_true) J_arm,true`` (eq. ft_factor on the true kinematics).

With a nominal arm and ``l_true`` this is exactly the adjoint features at ``theta = l_true``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from kinadapt_nn.geometry import adjoint_offset
from kinadapt_nn.sim.arm_errors import ArmJacobians, perturbed_arm_model


def sensor_jacobian_rows(S: np.ndarray, R_wf: np.ndarray, J_arm: np.ndarray, offset_f: np.ndarray) -> np.ndarray:
    """``S Ad(R_wf offset_f) J_arm``. S (m, 6), R_wf (3, 3), J_arm (6, n), offset (3,) -> (m, n)."""
    return S @ adjoint_offset(R_wf @ offset_f) @ J_arm


def sensor_jacobian_rows_batch(S: np.ndarray, R_wf: np.ndarray, J_arm: np.ndarray, offset_f: np.ndarray) -> np.ndarray:
    """``sensor_jacobian_rows`` over a batch: S (m, 6), R_wf (B, 3, 3), J_arm (B, 6, n),
    offset (3,) -> (B, m, n). ``Ad(l) [v; w] = [v - l x w; w]`` (eq. ft_factor's middle factor)."""
    l_w = R_wf @ np.asarray(offset_f, dtype=float)  # (B, 3)
    Jv, Jw = J_arm[:, :3], J_arm[:, 3:]  # (B, 3, n) each
    Jv_tip = Jv - np.cross(l_w[:, :, None], Jw, axis=1)  # (B, 3, n): v_tip = v_O - l x w
    return S @ np.concatenate([Jv_tip, Jw], axis=1)  # (B, m, n)


class TrueSensorJacobian:
    """``q -> J_true(q)`` (6, n) for a given true tool offset and arm errors."""

    def __init__(
        self,
        S: np.ndarray,
        nominal_offset_f: np.ndarray,
        true_offset_f: np.ndarray,
        mjcf_path: Path,
        link_length_m=None,
        joint_offset_rad=None,
    ) -> None:
        self.S = np.asarray(S, dtype=float)
        self.l_nom = np.asarray(nominal_offset_f, dtype=float)
        self.l_true = np.asarray(true_offset_f, dtype=float)
        link = np.zeros(8) if link_length_m is None else np.asarray(link_length_m, dtype=float)
        off = np.zeros(7) if joint_offset_rad is None else np.asarray(joint_offset_rad, dtype=float)
        self.nominal = ArmJacobians(perturbed_arm_model(mjcf_path, np.zeros(8), np.zeros(7)))
        self.true = self.nominal if not (link.any() or off.any()) else ArmJacobians(
            perturbed_arm_model(mjcf_path, link, off)
        )

    def __call__(self, q: np.ndarray) -> np.ndarray:
        _, R_n, J_n = self.nominal(q)
        J = np.empty((self.S.shape[0], J_n.shape[1]))
        J[0] = sensor_jacobian_rows(self.S[:1], R_n, J_n, self.l_nom)[0]
        if self.true is self.nominal:
            R_t, J_t = R_n, J_n
        else:
            _, R_t, J_t = self.true(q)
        J[1:] = sensor_jacobian_rows(self.S[1:], R_t, J_t, self.l_true)
        return J
