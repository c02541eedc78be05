"""The shared abstraction of every Jacobian parameterisation.

``Features`` maps a kinematic state (from the encoders) and parameters ``theta`` (p,) to

* ``jacobian(kin, theta) -> J_hat``  (m, n): the estimated sensor Jacobian
  (eq. adaptive_factorization, ``J_hat = Y(q) theta`` plus a known constant part);
* ``regressor(kin, qdot) -> Regressor(known, Phi)`` with ``J_hat(q) qdot = known + Phi theta``
  (the prediction regressor of Section ft_rigid; ``Phi`` is (m, p)).

The composite law is written once on ``Phi``; analytic, RBF and neural features differ
only in how they build it.
"""

from __future__ import annotations

import abc
from typing import NamedTuple

import numpy as np

from kinadapt_nn.robot import KinState  # noqa: F401  (re-exported: the features' input)


class Regressor(NamedTuple):
    """``J_hat qdot = known + Phi @ theta``."""

    known: np.ndarray  #: (m,) part of the prediction that does not depend on theta
    Phi: np.ndarray  #: (m, p) prediction regressor


class Features(abc.ABC):
    """Base class: subclasses provide the Jacobian and the regressor."""

    #: number of adapted parameters p
    n_params: int
    #: short name used in summaries and TensorBoard
    name: str

    @abc.abstractmethod
    def jacobian(self, kin: KinState, theta: np.ndarray) -> np.ndarray:
        """J_hat(q; theta). -> (m, n)."""

    @abc.abstractmethod
    def regressor(self, kin: KinState, qdot: np.ndarray) -> Regressor:
        """Prediction regressor on joint velocity ``qdot`` (n,)."""

    #: True where theta is the physical wrist-to-tip offset in f [m] (the adjoint): the run then
    #: reports theta's error against the true tool; learned features' theta has no such meaning
    theta_is_offset: bool = False
    #: theta's prior covariance (p, p) where the features declare one (the kalman law's P0);
    #: ``None``: the controller takes a third of Omega's half widths as the prior sd
    P0: np.ndarray | None = None
    #: the law these features always run, whatever ``adaptation.mode`` says (the oracle holds
    #: the true offset: "frozen"); ``None``: the configured law
    fixed_law: str | None = None

    @property
    def kernel(self) -> str | None:
        """Which in-kernel implementation of ``kinadapt_nn.controller.core`` computes these
        features ("adjoint", "neural", "rbf"); ``None``: the controller takes their rows from Python."""
        return None

    def twist_jacobian(self, kin: KinState, theta: np.ndarray) -> np.ndarray | None:
        """``J_hat_xi`` (m, 6) with ``J_hat = J_hat_xi J_arm`` where the parameterisation
        factors through the wrist twist (the adjoint does); ``None`` otherwise."""
        return None

    def per_entry_row_norm2(self, kin: KinState, qdot: np.ndarray) -> float | None:
        """``|Phi_i|^2``, the one squared norm of every adapted row of ``Phi``, where the features
        have the paper's per-entry block structure (rows mutually orthogonal with equal norms: the
        prediction step is eq. ident_qp_solution literally); ``None`` otherwise."""
        return None

    def omega(self) -> tuple[np.ndarray, np.ndarray]:
        """The projection set Omega as a box: (centre (p,), half widths (p,)); default unbounded."""
        return np.zeros(self.n_params), np.full(self.n_params, np.inf)

    def predict_rate(self, kin: KinState, qdot: np.ndarray, theta: np.ndarray) -> np.ndarray:
        """Predicted sensor rate ``J_hat qdot``. -> (m,)."""
        reg = self.regressor(kin, qdot)
        return reg.known + reg.Phi @ theta
