"""Gaussian RBF features (Sanner & Slotine 1992) with the paper's per-entry blocks.

``J_hat_ij(q) = K_ij(q) + theta_ij^T psi(q)`` for the force/moment rows i = 1..5 and joints
j = 1..7, ``psi_k(q) = exp(-|q - c_k|^2 / (2 w^2))`` (K centres in joint space). ``K(q)`` is the
known part: the adjoint model at the prior offset (the nominal CAD tool), depth row included;
the depth row is never adapted. ``p = 5 * 7 * K``. ``theta`` is stored flat in (i, j, k) order.

Regressor: row ``i`` of ``Phi`` holds ``qdot_j psi_k`` in block i and zeros elsewhere, so rows
are mutually orthogonal with equal norms ``|psi| |qdot|`` -- the per-entry structure for which
the prediction step is exactly eq. ident_qp_solution.
"""

from __future__ import annotations

import numpy as np

from kinadapt_nn.features.adjoint import AdjointFeatures
from kinadapt_nn.features.base import Features, KinState, Regressor

N_ROWS = 5  # adapted rows: F_lat (2) and M (3)


class RBFFeatures(Features):
    """Per-entry Gaussian RBF features on top of the known adjoint prior."""

    name = "rbf"

    def __init__(self, known: AdjointFeatures, prior_offset_f: np.ndarray, centres: np.ndarray, width_rad: float) -> None:
        self.known = known
        self.prior = np.asarray(prior_offset_f, dtype=float)
        self.centres = np.asarray(centres, dtype=float)  # (K, n)
        self.K, self.n = self.centres.shape
        self.inv2w2 = 1.0 / (2.0 * width_rad**2)
        self.width = float(width_rad)
        self.n_params = N_ROWS * self.n * self.K
        self._cache_key: bytes | None = None
        self._cache_val: np.ndarray | None = None

    @property
    def kernel(self) -> str | None:
        """"rbf": psi, the regressor and J_hat run in the controller's kernel (``core.step_rbf``,
        on the in-kernel adjoint's known part); this class's methods are the reference."""
        return "rbf" if self.known.kernel == "adjoint" else None

    def psi(self, q: np.ndarray) -> np.ndarray:
        """RBF activations (cached for the last q; do not modify the result). (n,) -> (K,)."""
        key = q.tobytes()
        if key != self._cache_key:
            d = self.centres - q
            self._cache_key, self._cache_val = key, np.exp(-np.einsum("kj,kj->k", d, d) * self.inv2w2)
        return self._cache_val

    def prior_from_adjoint(self, kin_of, P_adj: np.ndarray, floor: float) -> np.ndarray:
        """The analogous prior of the RBF weights: the adjoint's offset prior ``P_adj`` (3, 3)
        pushed through the RBF fit (``theta = A dl``, A from ``d J_adj / d l`` interpolated at the
        centres), plus ``floor`` x its mean diagonal isotropically (the RBF may also represent
        what the adjoint cannot, e.g. arm errors). ``kin_of(q) -> KinState``. -> (p, p)."""
        Psi = np.stack([self.psi(c).copy() for c in self.centres])  # (K centres, K features)
        self._cache_key = None
        dJ = np.zeros((3, len(self.centres), N_ROWS, self.n))  # d J[1:] / d l_k at each centre
        for a, c in enumerate(self.centres):
            kin = kin_of(c)
            J0 = self.known.jacobian(kin, self.prior)
            for k in range(3):
                dl = np.zeros(3)
                dl[k] = 1e-4
                dJ[k, a] = (self.known.jacobian(kin, self.prior + dl) - J0)[1:] / 1e-4
        A = np.zeros((self.n_params, 3))
        lam = 1e-6 * float(np.trace(Psi.T @ Psi)) / len(Psi)
        sol = np.linalg.solve(Psi.T @ Psi + lam * np.eye(self.K), Psi.T)  # (K, centres): least squares
        for k in range(3):
            W = np.einsum("ka,aij->ijk", sol, dJ[k])  # (5, n, K) weights reproducing dJ_k at the centres
            A[:, k] = W.ravel()
        C = A @ P_adj @ A.T
        return C + floor * float(np.trace(C)) / len(C) * np.eye(len(C))

    def jacobian(self, kin: KinState, theta: np.ndarray) -> np.ndarray:
        J = self.known.jacobian(kin, self.prior)
        J[1:] += theta.reshape(N_ROWS, self.n, self.K) @ self.psi(kin.q_rad)
        return J

    def regressor(self, kin: KinState, qdot: np.ndarray) -> Regressor:
        reg0 = self.known.regressor(kin, qdot)
        known = reg0.known + reg0.Phi @ self.prior
        block = np.outer(qdot, self.psi(kin.q_rad)).ravel()  # (n K,)
        Phi = np.zeros((N_ROWS + 1, self.n_params))
        w = block.size
        for i in range(N_ROWS):
            Phi[1 + i, i * w : (i + 1) * w] = block
        return Regressor(known=known, Phi=Phi)


def auto_width(centres: np.ndarray) -> float:
    """Mean distance from each centre to its nearest neighbour [rad] (0.05 rad if one centre)."""
    if len(centres) < 2:
        return 0.05
    d = np.linalg.norm(centres[:, None, :] - centres[None, :, :], axis=2)
    np.fill_diagonal(d, np.inf)
    return float(np.mean(d.min(axis=1)))
