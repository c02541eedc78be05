"""The prediction-only law: the fractional normalised step of the per-sample identification QP
(eq. ident_qp_solution) alone.

With ``H = W Phi_f`` (m, p) and ``e = W (s_dot_meas - known_f - Phi_f theta)`` (eq. ft_pred):

    d_pred      = eta H^T e / (||H||_2^2 + eps_norm)
    theta_{k+1} = Proj_Omega(theta_k + d_pred)

``||.||_2`` is the spectral norm: for per-entry features (rows of Phi mutually orthogonal with
equal norms) ``||Phi||_2^2 = ||psi||^2 ||qdot||^2`` and ``d_pred`` with ``eta = 1`` *is* the
closed form of eq. ident_qp_solution with ``eps_norm = 1/(kappa gamma)``; the size of the step
does not grow with ``Gamma`` (a naive ``dt kappa Gamma`` step at Gamma = 8000 would exceed the
normalised-LMS stability limit ``eta < 2``).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from kinadapt_nn.controller.laws.base import LawParams, LawSpec, config_key, lambda_max_sym3, project_omega

ETA, EPS_NORM = 0, 1  #: consts indices


class Params(LawParams):
    """The normalised step's parameters (flat config keys)."""

    eta: float = config_key("eta")  # [-] adaptation.eta: fraction of the exact per-sample QP step
    eps_norm: float = config_key("eps_norm")  # [-] adaptation.eps_norm: regulariser, W-scaled units of ||W Phi||^2


def constants(params: Params, m: int, p: int) -> np.ndarray:
    """[eta, eps_norm] (2,)."""
    return np.array([params.eta, params.eps_norm])


@nb.njit(cache=True)
def spectral_norm2(H_T, G):
    """||H||_2^2, the largest eigenvalue of H^T H = G (p <= m; closed form for p = 3) or of H H^T
    (p > m). H_T (p, m), G (p, p)."""
    p, m = H_T.shape
    if p <= m:
        return lambda_max_sym3(G) if p == 3 else np.linalg.eigvalsh(G)[-1]
    return np.linalg.eigvalsh(H_T.T @ H_T)[-1]


@nb.njit(cache=True)
def prediction_term(H_T, G, e, eta, eps_norm, th, d_pred):
    """d_pred = eta H^T e / (||H||_2^2 + eps_norm) (eq. ident_qp_solution, fractional,
    normalised); th += d_pred. Returns ||H||_2^2."""
    p, m = H_T.shape
    n2 = spectral_norm2(H_T, G)
    g = eta / (n2 + eps_norm)
    for j in range(p):
        v = 0.0
        for i in range(m):
            v += H_T[j, i] * e[i]
        d_pred[j] = v * g
        th[j] += d_pred[j]
    return n2


@nb.njit(cache=True)
def step(theta, H_T, G, e, PhiF, lo, hi, consts, x, k, unc, d_track, d_pred):
    """theta = Proj_Omega(theta + d_pred) (laws.base: the step contract). Returns ||W Phi_f||_2^2."""
    th = theta.copy()
    n2 = prediction_term(H_T, G, e, consts[ETA], consts[EPS_NORM], th, d_pred)
    project_omega(th, lo, hi, theta)
    return n2


LAW = LawSpec(name="prediction", doc="the normalised identification step alone (eq. ident_qp_solution)",
              step=step, params=Params, constants=constants)
