"""The paper's composite law (eq. ft_composite), written once on the regressor ``Phi``; what
``kinadapt reproduce`` runs.

Per control step in contact (the gate and eq. ft_pred are the kernel's, ``core._law``), with
``Phi_r`` the regressor on the *realised* (measured) joint velocity and ``H = W Phi_f`` the
W-scaled regressor through the rate filter:

    d_track     = -dt Gamma gamma_d Phi_r^T F              (eq. ft_composite, 1st term: tracking.py)
    d_pred      = eta H^T e / (||H||_2^2 + eps_norm)      (eq. ident_qp_solution: prediction.py)
    theta_{k+1} = Proj_Omega(theta_k + d_track + d_pred)

``Omega`` (paper appendix, eq. QPaug) is the features' box (the adjoint's about the nominal
offset, ``omega_lateral_m`` / ``omega_axial_m``); the projection is the Euclidean one (a clip).
The law has no covariance: it follows the data whatever their bias (docs/identification.md).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from kinadapt_nn.controller.laws import prediction, tracking
from kinadapt_nn.controller.laws.base import LawSpec, project_omega

C_TRACK, ETA, EPS_NORM = 0, 1, 2  #: consts indices


class Params(tracking.Params, prediction.Params):
    """Both terms' parameters: gamma, gamma_d (tracking.py), eta, eps_norm (prediction.py)."""


def constants(params: Params, m: int, p: int) -> np.ndarray:
    """[-dt Gamma gamma_d, eta, eps_norm] (3,)."""
    return np.concatenate([tracking.constants(params, m, p), prediction.constants(params, m, p)])


@nb.njit(cache=True)
def step(theta, H_T, G, e, PhiF, lo, hi, consts, x, k, unc, d_track, d_pred):
    """theta = Proj_Omega(theta + d_track + d_pred) (laws.base: the step contract). Returns
    ||W Phi_f||_2^2."""
    th = theta.copy()
    tracking.tracking_term(PhiF, consts[C_TRACK], th, d_track)
    n2 = prediction.prediction_term(H_T, G, e, consts[ETA], consts[EPS_NORM], th, d_pred)
    project_omega(th, lo, hi, theta)
    return n2


LAW = LawSpec(name="composite", doc="the paper's composite law, eq. ft_composite (kinadapt reproduce)",
              step=step, params=Params, constants=constants)
