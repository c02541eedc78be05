"""Parameterisations ``J_hat = Y(q) theta`` of the sensor Jacobian (one module each)."""

from kinadapt_nn.features.adjoint import AdjointFeatures
from kinadapt_nn.features.base import Features, KinState

__all__ = ["AdjointFeatures", "Features", "KinState"]
