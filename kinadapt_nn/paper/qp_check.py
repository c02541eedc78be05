"""Appendix QP, checked numerically with a real QP solver (``quadprog``, Goldfarb-Idnani).

* eq. ident_qp: ``min_D 1/2 D^T Gamma^-1 D + kappa/2 |eps - Phi D|^2`` solved by quadprog equals
  ``(Gamma^-1 + kappa Phi^T Phi)^-1 kappa Phi^T eps`` for every features type, and for per-entry
  features with ``Gamma = gamma I`` the scalar closed form eq. ident_qp_solution,
  ``Phi^T eps / (|psi|^2 |qdot|^2 + 1/(kappa gamma))``;
* eq. QPaug: ``min 1/2 qdot^T qdot + 1/2 thetadot^T Gamma^-1 thetadot  s.t.  xdot_d = J_hat qdot``
  has ``thetadot = 0`` at its optimum (eq. kkt_theta) and ``qdot = J_hat^+ xdot_d``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class QPCheck(NamedTuple):
    features: str  #: features type
    p: int  #: parameter count
    ident_qp_max_abs_error: float  #: quadprog vs matrix closed form
    scalar_closed_form_max_abs_error: float | None  #: vs eq. ident_qp_solution (per-entry only)
    qpaug_thetadot_max_abs: float  #: |thetadot| at the QPaug optimum (eq. kkt_theta: 0)
    qpaug_qdot_max_abs_error: float  #: qdot vs J_hat^+ xdot_d


def _solve(G: np.ndarray, a: np.ndarray, C: np.ndarray | None = None, b: np.ndarray | None = None, meq: int = 0):
    import quadprog

    if C is None:
        return quadprog.solve_qp(G, a)[0]
    return quadprog.solve_qp(G, a, C, b, meq)[0]


def check_features(name: str, feats, kin, qdot: np.ndarray, theta: np.ndarray, W: np.ndarray, rng) -> QPCheck:
    """Run the three checks for one features object at one state."""
    Phi = W[:, None] * feats.regressor(kin, qdot).Phi  # (m, p), W-scaled as the law uses it
    m, p = Phi.shape
    eps = rng.normal(size=m)
    kappa, gamma = 3.0, 0.7
    # a general (non-isotropic) Gamma for the matrix identity, gamma I for the scalar one
    Gam = np.diag(gamma * (0.5 + rng.random(p)))
    Gi = np.linalg.inv(Gam)
    G = Gi + kappa * Phi.T @ Phi
    qp = _solve(G, kappa * Phi.T @ eps)
    closed = np.linalg.solve(G, kappa * Phi.T @ eps)
    err_matrix = float(np.max(np.abs(qp - closed)))
    err_scalar = None
    row2 = feats.per_entry_row_norm2(kin, qdot)
    if row2 is not None:  # per-entry features, unscaled rows: eq. ident_qp_solution literally
        Praw = feats.regressor(kin, qdot).Phi
        qp_iso = _solve(np.eye(p) / gamma + kappa * Praw.T @ Praw, kappa * Praw.T @ eps)
        scalar = Praw.T @ eps / (row2 + 1.0 / (kappa * gamma))
        err_scalar = float(np.max(np.abs(qp_iso - scalar)))
    # QPaug: variables z = [qdot (n); thetadot (p)]; equality J_hat qdot = xdot_d
    J = feats.jacobian(kin, theta)
    n = J.shape[1]
    xd = rng.normal(size=m)
    Gz = np.zeros((n + p, n + p))
    Gz[:n, :n] = np.eye(n)
    Gz[n:, n:] = Gi
    C = np.zeros((n + p, m))
    C[:n, :] = J.T  # quadprog: C^T z >= b, first meq rows as equalities
    z = _solve(Gz, np.zeros(n + p), C, xd, meq=m)
    qd_expected = np.linalg.pinv(J) @ xd
    return QPCheck(
        features=name,
        p=p,
        ident_qp_max_abs_error=err_matrix,
        scalar_closed_form_max_abs_error=err_scalar,
        qpaug_thetadot_max_abs=float(np.max(np.abs(z[n:]))),
        qpaug_qdot_max_abs_error=float(np.max(np.abs(z[:n] - qd_expected))),
    )


def run_qp_checks(seed: int = 0) -> list[QPCheck]:
    """Every compared features type (``features.compared_types``) at a random state near the
    insertion start."""
    from kinadapt_nn.config import load_config
    from kinadapt_nn.features import compared_types
    from kinadapt_nn.runs.build import make_controller, make_features

    rng = np.random.default_rng(seed)
    from kinadapt_nn.sim.workspace import insertion_path

    cfg = load_config(None, [])
    ctrl = make_controller(cfg)
    q = insertion_path(cfg, n=5)[2] + 0.01 * rng.normal(size=7)  # mid-insertion, where the RBFs live
    kin = ctrl.kin(q)
    qdot = 0.2 * rng.normal(size=7)
    out = []
    for name in compared_types():
        feats, theta0 = make_features(load_config(None, [f"run.features={name}"]))
        out.append(check_features(name, feats, kin, qdot, theta0, ctrl.W, rng))
    return out
