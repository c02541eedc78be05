"""The Jacobian-basis network: a body whose output is the feature matrix ``Y(q)``.

``J_hat(q) = K(q) + Y(q) theta`` (paper appendix "Extension to Neural Network Jacobians"):
``K(q)`` is the known nominal model, the body below produces ``Y(q)`` for the five adapted
rows (F_lat, M) in W-scaled units, and ``theta`` (the output layer, linear) is per tool. Only
``theta`` adapts online; the body is frozen.

Structures (``structure``):
* ``basis``     -- p matrix-valued features: ``Y(q)`` is (5, n, p), ``R_hat = sum_k theta_k Y_k(q)``;
* ``per_entry`` -- the paper's per-entry blocks: the body gives ``psi(q)`` (K,), and
  ``R_hat_ij = theta_ij^T psi(q)``, p = 5 n K.
"""

from __future__ import annotations

import torch
from torch import nn

from kinadapt_nn.learning.weights import N_JOINTS, N_ROWS


class JacobianBasisNet(nn.Module):
    """q (B, n) -> Y (B, 5, n, p) for ``basis`` or psi (B, K) for ``per_entry``."""

    def __init__(self, structure: str, n_features: int, hidden: int, q_mean, q_std) -> None:
        super().__init__()
        if structure not in ("basis", "per_entry"):
            raise ValueError(f"structure {structure!r} not in ('basis', 'per_entry')")
        self.structure = structure
        self.n_features = n_features
        out = N_ROWS * N_JOINTS * n_features if structure == "basis" else n_features
        self.l1 = nn.Linear(N_JOINTS, hidden)
        self.l2 = nn.Linear(hidden, hidden)
        self.l3 = nn.Linear(hidden, out)
        self.register_buffer("q_mean", torch.as_tensor(q_mean, dtype=torch.float64).reshape(N_JOINTS))
        self.register_buffer("q_std", torch.as_tensor(q_std, dtype=torch.float64).reshape(N_JOINTS))

    @property
    def n_params(self) -> int:
        """Number of online parameters p (size of theta)."""
        return self.n_features if self.structure == "basis" else N_ROWS * N_JOINTS * self.n_features

    def forward(self, q: torch.Tensor) -> torch.Tensor:
        x = (q - self.q_mean) / self.q_std
        h = torch.tanh(self.l2(torch.tanh(self.l1(x))))
        y = self.l3(h)
        if self.structure == "basis":
            return y.reshape(*q.shape[:-1], N_ROWS, N_JOINTS, self.n_features)
        return y

    def residual(self, q: torch.Tensor, theta: torch.Tensor) -> torch.Tensor:
        """``R_hat(q; theta)`` (B, 5, n) for one theta (p,) or per-row thetas (B, p)."""
        y = self(q)
        if self.structure == "basis":
            return torch.einsum("...ijk,...k->...ij", y, theta)
        th = theta.reshape(*theta.shape[:-1], N_ROWS, N_JOINTS, self.n_features)
        return torch.einsum("...ijk,...k->...ij", th, y)


def least_squares_heads(net: JacobianBasisNet, q: torch.Tensor, r: torch.Tensor, ridge: float) -> torch.Tensor:
    """Closed-form per-instance head: argmin_theta sum_q |R_hat(q; theta) - r(q)|^2 + ridge |theta|^2.

    q (I, N, n), r (I, N, 5, n) -> theta (I, p). Differentiable (training backpropagates
    through the solve)."""
    I, N = q.shape[:2]
    y = net(q)
    if net.structure == "basis":
        Y = y.reshape(I, N * N_ROWS * N_JOINTS, net.n_features)  # (I, N*35, p)
        A = Y.transpose(1, 2) @ Y + ridge * torch.eye(net.n_features, dtype=Y.dtype, device=Y.device)
        b = Y.transpose(1, 2) @ r.reshape(I, -1, 1)
        return torch.linalg.solve(A, b).squeeze(-1)
    psi = y  # (I, N, K)
    A = psi.transpose(1, 2) @ psi + ridge * torch.eye(net.n_features, dtype=psi.dtype, device=psi.device)
    b = psi.transpose(1, 2) @ r.reshape(I, N, -1)  # (I, K, 35)
    th = torch.linalg.solve(A, b)  # (I, K, 35)
    return th.transpose(1, 2).reshape(I, -1)  # (I, 35*K) in (i, j, k) order
