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

from kinadapt_nn.config import FeaturesCfg
from kinadapt_nn.features.adjoint import AdjointFeatures, nominal_adjoint
from kinadapt_nn.features.base import Features, KinState, Regressor
from kinadapt_nn.features.registry import Built, FeaturesContext, FeaturesSpec, Workspace
from kinadapt_nn.robot import ArmKinematics

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

    def per_entry_row_norm2(self, kin: KinState, qdot: np.ndarray) -> float:
        """``|psi(q)|^2 |qdot|^2``: every adapted row of ``Phi`` holds ``qdot_j psi_k`` in its own block."""
        psi = self.psi(kin.q_rad)
        return (psi @ psi) * (qdot @ qdot)

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


def centres(fc: FeaturesCfg, workspace: Workspace) -> np.ndarray:
    """The K = ``rbf_n_centres`` centres: on the nominal insertion path (evenly in depth) or sampled
    about it (``rbf_centres``, ``rbf_seed``); in a work cell shared out over its bores in turn
    (bore b gets ``K // nb`` plus one of the remainder, at least one). -> (K', 7), K' = max(K, nb)."""
    k, rng = fc.rbf_n_centres, np.random.default_rng(fc.rbf_seed)
    if workspace.n_bores == 1 and fc.rbf_centres == "path":
        return workspace.paths(k)[0]
    paths = workspace.paths(12)
    nb = len(paths)
    if nb == 1:
        return workspace.sample(paths[0], k, 0.03, rng)
    out = []
    for b, path in enumerate(paths):
        kb = max(1, k // nb + (1 if b < k % nb else 0))
        if fc.rbf_centres == "path":
            idx = np.round(np.linspace(0, len(path) - 1, kb + 2)[1:-1]).astype(int)
            out.append(path[idx])
        else:
            out.append(workspace.sample(path, kb, 0.03, rng))
    return np.concatenate(out)


def build(ctx: FeaturesContext) -> Built:
    """RBFs on the nominal adjoint (the prior offset = the nominal one), theta0 = 0 (the nominal
    tool); theta's prior: the adjoint's pushed through the RBF fit (:meth:`RBFFeatures.prior_from_adjoint`)."""
    known = ctx.known
    adjoint = nominal_adjoint(known)
    c = centres(known.features, ctx.workspace)
    feats = RBFFeatures(adjoint, np.asarray(known.sensing.nominal_offset_f_m, dtype=float), c,
                        known.features.rbf_width_rad or auto_width(c))
    feats.P0 = feats.prior_from_adjoint(ArmKinematics(known.arm_mjcf), adjoint.P0, known.adaptation.rbf_prior_floor)
    return Built(feats, np.zeros(feats.n_params))


SPEC = FeaturesSpec(name="rbf", doc="Gaussian RBFs in joint space, the paper's per-entry blocks (p = 5 x 7 x K)",
                    build=build, cost=5.0)
