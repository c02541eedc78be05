"""A work cell (truth side, evaluation only): the controller's Jacobian estimate judged on a fixed
held-out set of configurations that spans every bore of the cell, not only the current pose.

``CellJacobianError(cfg, ctrl)`` builds the set once (``kinadapt_nn.sim.workspace.
heldout_configurations``: nominal-tool poses about each bore, drawn from ``cell.heldout_seed``)
and the TRUE sensor Jacobians there (``TrueSensorJacobian``: the true tool and the true arm,
hidden effects folded in); calling it with a controller gives the per-configuration error

    e_i = |W (J_hat(q_i, theta) - J_true(q_i))|_F / |W J_true(q_i)|_F

with ``J_hat`` the controller's own features at the estimate it acts on (``ctrl.theta``). The
median over the set is ``jacobian_error_cell_median`` (summary, TensorBoard, ``kinadapt
compare``). Nothing here is ever handed to the controller.
"""

from __future__ import annotations

import numpy as np

from kinadapt_nn.config import ExperimentCfg, arm_mjcf_path
from kinadapt_nn.controller.controller import Controller


class CellJacobianError:
    """The cell's held-out configurations and their true Jacobians (evaluation only).

    ``q`` (N, n) [rad], ``bore`` (N,) bore index of each configuration, ``J_true`` (N, m, n)."""

    def __init__(self, cfg: ExperimentCfg, ctrl: Controller) -> None:
        from kinadapt_nn.sim.effects import truth_config
        from kinadapt_nn.sim.truth import TrueSensorJacobian
        from kinadapt_nn.sim.workspace import heldout_configurations

        tcfg = truth_config(cfg)
        self.q, self.bore = heldout_configurations(cfg)
        truth = TrueSensorJacobian(ctrl.S, ctrl.l_nom_f, np.asarray(tcfg.tool.offset_f_m), arm_mjcf_path(cfg.scene),
                                   tcfg.arm.link_length_error_m, tcfg.arm.joint_offset_rad)
        self.J_true = np.stack([truth(q) for q in self.q])
        self.W = np.asarray(ctrl.W, dtype=float)
        self._kin = [ctrl.kin(q) for q in self.q]  # the controller's nominal kinematics (known model)
        self._den = np.linalg.norm(self.W[None, :, None] * self.J_true, axis=(1, 2))

    def errors(self, ctrl: Controller, theta: np.ndarray | None = None) -> np.ndarray:
        """Per-configuration relative error (N,) of ``J_hat(q, theta)`` (default: the estimate the
        controller acts on now)."""
        th = ctrl.theta.copy() if theta is None else np.asarray(theta, dtype=float)
        J_hat = np.stack([ctrl.features.jacobian(k, th) for k in self._kin])
        return np.linalg.norm(self.W[None, :, None] * (J_hat - self.J_true), axis=(1, 2)) / self._den

    def median(self, ctrl: Controller, theta: np.ndarray | None = None) -> float:
        """The median of :meth:`errors` (the cell Jacobian error)."""
        return float(np.median(self.errors(ctrl, theta)))
