"""The tracking-only law: eq. ft_composite's first term alone (Remark cls_self_extinguish shows
why it is not enough on per-entry features).

    d_track     = -dt Gamma gamma_d Phi_r^T F        (eq. ft_composite, 1st term; Phi_r on the
                                                      realised velocity, the features' tracking rows)
    theta_{k+1} = Proj_Omega(theta_k + d_track)

``gamma_d`` weighs V(s) in ``V_aug = gamma_d V(s) + 1/2 |theta~|^2 / Gamma`` (the paper's Results
section writes it but never gives it): it makes V [J] and the parameter energy [m^2 / Gamma]
commensurate; a negative Gamma is the myopic sign of eq. adapt_law (paper/rigid_demo.py).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from kinadapt_nn.controller.laws.base import LawParams, LawSpec, config_key, project_omega

C_TRACK = 0  #: consts index: -dt Gamma gamma_d [m^2 s / J]


class Weight(LawParams):
    """gamma_d, the weight of V(s) in V_aug (also the kalman law's tracking term)."""

    gamma_d: float = config_key("gamma_d")  # [1/J] adaptation.gamma_d


class Params(Weight):
    """The tracking term's parameters (flat config keys)."""

    gamma: float = config_key("gamma")  # [m^2] adaptation.gamma: Gamma = gamma I


def constants(params: Params, m: int, p: int) -> np.ndarray:
    """[-dt Gamma gamma_d] (1,)."""
    return np.array([-params.dt_s * params.gamma * params.gamma_d])


@nb.njit(cache=True)
def tracking_term(PhiF, c_track, th, d_track):
    """d_track = c_track Phi_r^T F = -dt Gamma gamma_d Phi_r^T F (eq. ft_composite, 1st term);
    th += d_track. PhiF, th, d_track: (p,)."""
    for j in range(th.shape[0]):
        d_track[j] = PhiF[j] * c_track
        th[j] += d_track[j]


@nb.njit(cache=True)
def step(theta, H_T, G, e, PhiF, lo, hi, consts, x, k, unc, d_track, d_pred):
    """theta = Proj_Omega(theta + d_track) (laws.base: the step contract). Returns 0 (no
    prediction step)."""
    th = theta.copy()
    tracking_term(PhiF, consts[C_TRACK], th, d_track)
    project_omega(th, lo, hi, theta)
    return 0.0


LAW = LawSpec(name="tracking", doc="eq. ft_composite's tracking term alone (-dt Gamma gamma_d Phi^T F)",
              step=step, params=Params, constants=constants)
