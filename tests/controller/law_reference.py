"""Independent closed forms the laws' numba steps are checked against (tests only)."""

from __future__ import annotations

import numpy as np


def exact_qp_step(Phi_w: np.ndarray, eps_w: np.ndarray, eps_norm: float) -> np.ndarray:
    """The exact minimiser of eq. ident_qp (with Gamma = gamma I, eps_norm = 1/(kappa gamma)):
    ``Phi^T (Phi Phi^T + eps_norm I)^{-1} eps`` (push-through form). Phi_w (m, p), eps_w (m,)."""
    m = Phi_w.shape[0]
    return Phi_w.T @ np.linalg.solve(Phi_w @ Phi_w.T + eps_norm * np.eye(m), eps_w)


def kalman_update(P: np.ndarray, H: np.ndarray, e: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One Kalman measurement update: ``K = P H^T (H P H^T + diag r)^-1``; returns (K e (p,),
    (I - K H) P (p, p)). P (p, p), H (m, p), e (m,), r (m,)."""
    K = P @ H.T @ np.linalg.inv(H @ P @ H.T + np.diag(r))
    return K @ e, (np.eye(len(P)) - K @ H) @ P


def one_law_step(name: str, Phi: np.ndarray, eps: np.ndarray, theta: np.ndarray | None = None,
                 F: np.ndarray | None = None, lo: np.ndarray | None = None, hi: np.ndarray | None = None, **params):
    """One step of the registered law ``name`` in contact on rows given directly: no filter lag
    (``filter_tau_s = 0``), W = 1, known = 0, so the law sees ``H = Phi`` (m, p) and ``e = eps -
    Phi theta`` (m,); ``F`` (m,) the value force of the tracking term (default 0). ``params``:
    the law's ``Params`` fields (default the config's; another law's fields are ignored). ->
    (theta_next (p,), AdaptStep, StandaloneLaw)."""
    from kinadapt_nn.config import AdaptationCfg
    from kinadapt_nn.controller.laws import law_spec
    from kinadapt_nn.controller.standalone import StandaloneLaw

    m, p = Phi.shape
    prior = params.pop("prior_cov", np.eye(p))
    law_params = law_spec(name).params_of(AdaptationCfg(), params.pop("dt_s", 1e-3), prior, **params)
    law = StandaloneLaw(name, law_params, np.ones(m),
                        np.full(p, -np.inf) if lo is None else lo, np.full(p, np.inf) if hi is None else hi,
                        filter_tau_s=0.0)
    theta = np.zeros(p) if theta is None else np.asarray(theta, dtype=float)
    theta_next, a = law.update(np.zeros(m), Phi, theta, eps, np.zeros(m) if F is None else F, np.ones(6))
    return theta_next, a, law
