"""Analytic adjoint features: ``J_hat = S Ad(R_wf theta) J_arm`` (eq. ft_factor).

``theta`` (p = 3) is the estimated offset O -> tip in the flange frame ``f`` [m]. The depth
row is built on the *known* nominal offset (the depth channel is defined on it, see
``kinadapt_nn.sensing``) and so is a known constant part that is never adapted.

With the flange twist ``xi = J_arm qdot = [v; omega]`` (world):
``Ad(l_w) xi = [v + omega x l_w; omega]`` and ``l_w = R_wf theta``, hence

    J_hat qdot = S xi + S_v [omega]x R_wf theta      (rows F_lat, M)
    Phi        = S_v [omega]x R_wf                   (m, 3); depth row 0

which is affine in ``theta`` as the paper requires.
"""

from __future__ import annotations

import numpy as np

from kinadapt_nn.features.base import Features, KinState, Regressor
from kinadapt_nn.geometry import skew


class AdjointFeatures(Features):
    """Analytic adjoint of the wrist-to-tip offset (p = 3)."""

    n_params = 3
    name = "adjoint"

    def __init__(self, S: np.ndarray, nominal_offset_f_m: np.ndarray) -> None:
        self.S = np.asarray(S, dtype=float)  # (m, 6)
        self.S_v = self.S[:, :3].copy()
        self.S_v[0] = 0.0  # the depth row does not see theta
        self.l_nom_f = np.asarray(nominal_offset_f_m, dtype=float)

    def twist_jacobian(self, kin: KinState, theta: np.ndarray) -> np.ndarray:
        """``S Ad(R_wf theta)`` with the depth row on the nominal offset. -> (m, 6)."""
        R = kin.R_wf
        # S Ad(l) = [S_v, S_w - S_v [l]x]  (geometry.adjoint_offset)
        J_xi = self.S.copy()
        J_xi[:, 3:] -= self.S_v @ skew(R @ theta)
        J_xi[0, 3:] -= self.S[0, :3] @ skew(R @ self.l_nom_f)
        return J_xi

    def jacobian(self, kin: KinState, theta: np.ndarray) -> np.ndarray:
        return self.twist_jacobian(kin, theta) @ kin.J_arm

    def regressor(self, kin: KinState, qdot: np.ndarray) -> Regressor:
        xi = kin.J_arm @ qdot
        v, w = xi[:3], xi[3:]
        known = self.S @ xi
        known[0] += self.S[0, :3] @ np.cross(w, kin.R_wf @ self.l_nom_f)
        Phi = self.S_v @ skew(w) @ kin.R_wf
        return Regressor(known=known, Phi=Phi)
