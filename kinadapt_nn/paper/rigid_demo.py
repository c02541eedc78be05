"""The rigid regulation loop of the paper's Section 2 on the Panda, for Remark cls_self_extinguish.

Task: the tool-tip position ``x`` (3,) of a tool with offset ``l`` (flange frame), measured
(this is Section 2's setting, an exteroceptive task-space measurement, not the F/T loop).
``x_dot = J(q) qdot`` with ``J = [I, -[R_wf l]x] J_arm``; command ``qdot = J_hat^T K e``,
``e = x_d - x`` (eq. control_law); the law is the registered one (``mode``: composite, tracking, ...)
run stand-alone (``kinadapt_nn.controller.standalone.StandaloneLaw``, the controller's own numba
step) with ``Gamma gamma_d = gamma`` and ``F = K e``.

Features:
* ``per_entry`` -- Gaussian RBFs, ``J_hat_ij = theta_ij^T psi(q)`` (eq. cls_per_entry): the
  tracking-only law contracts ``J_hat`` along ``K e`` (eq. cls_rank_one_contraction) and the
  command decays at ``gamma |psi|^2 |K e|^2`` (eq. cls_command_decay) while ``e`` stays;
* ``adjoint`` -- ``theta`` = the offset (3 parameters): the contraction is not available.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import mujoco
import numpy as np

from kinadapt_nn.config import AdaptationCfg
from kinadapt_nn.controller.laws import law_spec
from kinadapt_nn.controller.standalone import StandaloneLaw
from kinadapt_nn.features.base import Features, KinState, Regressor
from kinadapt_nn.geometry import skew
from kinadapt_nn.robot import FLANGE_SITE, PANDA_MJCF


class _PerEntryTip(Features):
    name = "per_entry_rbf"

    def __init__(self, centres: np.ndarray, width: float) -> None:
        self.centres, self.inv2w2 = centres, 1.0 / (2 * width**2)
        self.K = len(centres)
        self.n_params = 3 * 7 * self.K

    def psi(self, q):
        d = self.centres - q
        return np.exp(-np.einsum("kj,kj->k", d, d) * self.inv2w2)

    def jacobian(self, kin, theta):
        return theta.reshape(3, 7, self.K) @ self.psi(kin.q_rad)

    def regressor(self, kin, qdot):
        block = np.outer(qdot, self.psi(kin.q_rad)).ravel()
        Phi = np.zeros((3, self.n_params))
        for i in range(3):
            Phi[i, i * block.size : (i + 1) * block.size] = block
        return Regressor(np.zeros(3), Phi)


class _AdjointTip(Features):
    name = "adjoint"
    n_params = 3

    def jacobian(self, kin, theta):
        return kin.J_arm[:3] - skew(kin.R_wf @ theta) @ kin.J_arm[3:]

    def regressor(self, kin, qdot):
        xi = kin.J_arm @ qdot
        return Regressor(xi[:3], skew(xi[3:]) @ kin.R_wf)  # v + w x (R theta)


class RigidDemoResult(NamedTuple):
    t_s: np.ndarray  #: (N,) time
    command_norm: np.ndarray  #: (N,) |J_hat^T K e| [rad/s]
    error_norm: np.ndarray  #: (N,) |e| [m]
    predicted_rate: np.ndarray  #: (N,) gamma |psi|^2 |K e|^2 (per-entry) [1/s]
    jacobian_error: np.ndarray  #: (N,) |J_hat - J| / |J|
    V_aug: np.ndarray  #: (N,) 1/2 e^T K e + |theta - l|^2 / (2 gamma) (adjoint only; NaN otherwise)


@dataclass(frozen=True)
class RigidDemoSetup:
    """The rigid loop's fixed numbers."""

    k_gain: float = 10.0  #: task-space gain K [1/s]
    dt_s: float = 1e-3  #: step [s]
    target_m: tuple[float, float, float] = (0.03, 0.02, -0.04)  #: target - start of the tip, world [m]
    n_centres: int = 5  #: per-entry features: RBF centres
    theta_error_m: tuple[float, float, float] = (0.0, 0.0, 0.0)  #: adjoint: initial offset error [m]


def run_rigid_demo(
    features: str = "per_entry",
    mode: str = "tracking",
    gamma: float = 50.0,  # negative: the myopic sign of eq. adapt_law
    duration_s: float = 2.0,
    setup: RigidDemoSetup = RigidDemoSetup(),
) -> RigidDemoResult:
    """Simulate the rigid loop; ``J_hat`` starts exact at q0 (so only the law moves it)."""
    k_gain, dt_s, target_m = setup.k_gain, setup.dt_s, setup.target_m
    n_centres, theta_error_m = setup.n_centres, setup.theta_error_m
    model = mujoco.MjModel.from_xml_path(str(PANDA_MJCF))
    data = mujoco.MjData(model)
    site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, FLANGE_SITE)
    l_true = np.array([0.003, -0.002, 0.1])
    jac = np.zeros((6, 7))
    q = np.array([0.0, -0.3, 0.0, -2.2, 0.0, 1.9, 0.785])

    def kin_at(q):
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        mujoco.mj_jacSite(model, data, jac[:3], jac[3:], site)
        R = data.site_xmat[site].reshape(3, 3).copy()
        return KinState(q.copy(), data.site_xpos[site].copy(), R, jac.copy()), data.site_xpos[site] + R @ l_true

    kin, x = kin_at(q)
    x_d = x + np.asarray(target_m)
    J_true = lambda k: k.J_arm[:3] - skew(k.R_wf @ l_true) @ k.J_arm[3:]  # noqa: E731
    if features == "per_entry":
        rng = np.random.default_rng(0)
        centres = q + 0.15 * rng.normal(size=(n_centres, 7))
        centres[0] = q
        feats = _PerEntryTip(centres, 0.3)
        psi0 = feats.psi(q)
        theta = np.einsum("ij,k->ijk", J_true(kin), psi0 / (psi0 @ psi0)).ravel()  # J_hat(q0) = J(q0)
        lo, hi = np.full(feats.n_params, -np.inf), np.full(feats.n_params, np.inf)
    else:
        feats = _AdjointTip()
        theta = l_true + np.asarray(theta_error_m)
        lo, hi = l_true - 0.05, l_true + 0.05
    params = law_spec(mode).params_of(AdaptationCfg(), dt_s, np.eye(feats.n_params), gamma=gamma, gamma_d=1.0,
                                      eta=0.5, eps_norm=1e-6)
    # Omega: unbounded for the RBF weights, +-5 cm about the truth for the offset; no gate (rigid task)
    law = StandaloneLaw(mode, params, np.ones(3), lo, hi, filter_tau_s=1e-12)
    n = int(round(duration_s / dt_s))
    out = {k: np.zeros(n) for k in ("t", "c", "e", "r", "j", "v")}
    on = np.ones(6)
    for k in range(n):
        e = x_d - x
        F = k_gain * e
        J_hat = feats.jacobian(kin, theta)
        qdot = J_hat.T @ F  # eq. control_law
        Jt = J_true(kin)
        x_dot = Jt @ qdot
        psi2 = float(feats.psi(q) @ feats.psi(q)) if features == "per_entry" else np.nan
        out["t"][k], out["c"][k], out["e"][k] = k * dt_s, np.linalg.norm(qdot), np.linalg.norm(e)
        out["r"][k] = gamma * psi2 * (F @ F)
        out["j"][k] = np.linalg.norm(J_hat - Jt) / np.linalg.norm(Jt)
        out["v"][k] = (0.5 * k_gain * (e @ e) + 0.5 * np.sum((theta - l_true) ** 2) / abs(gamma)
                       if features == "adjoint" else np.nan)
        reg = feats.regressor(kin, qdot)
        theta, _ = law.update(reg.known, reg.Phi, theta, x_dot, F, on)
        q = q + dt_s * qdot
        kin, x = kin_at(q)
    return RigidDemoResult(out["t"], out["c"], out["e"], out["r"], out["j"], out["v"])
