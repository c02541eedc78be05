"""The hidden truth of the arm: its small kinematic errors and the true sensor Jacobian (the simulator,
evaluation and offline data only; the controller never uses anything here).

**Arm errors** (``apply_arm_errors``, ``perturbed_arm_model``): small errors applied to an MJCF spec.

Two mechanisms the 3-parameter adjoint ``S Ad(theta) J_arm`` cannot represent (it assumes
``J_arm`` exact):

* link length errors: each body offset ``pos`` of link1..link7 and of the flange site is
  lengthened by ``delta`` [m] along its own direction (bodies with a zero offset are skipped);
* joint zero offsets: the encoder reads ``q`` while the link sits at ``q + delta`` [rad]. Built
  into the model by turning the child body frame by ``Rz(delta)`` (the hinge axis is the body z
  axis, so the frame chain becomes ``... T_body Rz(q + delta)``).

The same function builds the perturbed arms of the pretraining data set, so training and the
simulator share one definition.

**The true sensor Jacobian** (``TrueSensorJacobian``).

``J_true(q)`` maps encoder rates to the rates of the controller's sensor vector
``s = [d, F_lat, M]`` under the nominal contact model S:

* row 0 (depth): ``d`` is computed by the controller from the *nominal* forward kinematics, so
  its row is ``S_0 Ad(R_nom l_nom) J_arm,nom`` whatever the true arm is;
* rows 1..5: the true tip moves with the *true* arm and tool,
  ``S_{1:} Ad(R_true l_true) J_arm,true`` (eq. ft_factor on the true kinematics).

With a nominal arm and ``l_true`` this is exactly the adjoint features at ``theta = l_true``.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np

from kinadapt_nn.geometry import adjoint_offset
from kinadapt_nn.robot import FLANGE_SITE

#: bodies whose offsets carry link-length errors (index i -> link{i+1}); the 8th entry is the flange site
N_LINK_ERRORS = 8


def apply_arm_errors(spec: mujoco.MjSpec, link_length_m, joint_offset_rad) -> None:
    """Perturb ``spec`` in place. ``link_length_m`` (8,) [m], ``joint_offset_rad`` (7,) [rad]."""
    link = np.asarray(link_length_m, dtype=float)
    off = np.asarray(joint_offset_rad, dtype=float)
    if not link.any() and not off.any():
        return
    for i in range(7):
        body = spec.body(f"link{i + 1}")
        pos = np.asarray(body.pos, dtype=float)
        n = np.linalg.norm(pos)
        if n > 0 and link[i] != 0.0:
            body.pos = list(pos * (n + link[i]) / n)
        if off[i] != 0.0:
            q = np.asarray(body.quat, dtype=float)
            rz = np.array([np.cos(off[i] / 2), 0.0, 0.0, np.sin(off[i] / 2)])
            out = np.zeros(4)
            mujoco.mju_mulQuat(out, q / np.linalg.norm(q), rz)
            body.quat = list(out)
    site = spec.site(FLANGE_SITE)
    pos = np.asarray(site.pos, dtype=float)
    n = np.linalg.norm(pos)
    if n > 0 and link[7] != 0.0:
        site.pos = list(pos * (n + link[7]) / n)


def random_arm_errors(rng: np.random.Generator, link_sigma_m: float, joint_sigma_rad: float) -> tuple[np.ndarray, np.ndarray]:
    """Draw (link_length_m (8,), joint_offset_rad (7,)) from zero-mean normals."""
    return rng.normal(0.0, link_sigma_m, N_LINK_ERRORS), rng.normal(0.0, joint_sigma_rad, 7)


def perturbed_arm_model(mjcf_path, link_length_m, joint_offset_rad) -> mujoco.MjModel:
    """A bare-arm model (no tool, no block) with the given errors applied. Truth side only."""
    spec = mujoco.MjSpec.from_file(str(mjcf_path))
    apply_arm_errors(spec, link_length_m, joint_offset_rad)
    return spec.compile()


class ArmJacobians:
    """Flange pose and world Jacobian ``[v_O; omega]`` of a (possibly perturbed) bare arm.

    ``__call__(q) -> (p_w_O (3,), R_wf (3, 3), J_arm (6, n))`` (copies)."""

    def __init__(self, model: mujoco.MjModel) -> None:
        self.model = model
        self.data = mujoco.MjData(model)
        self.site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, FLANGE_SITE)
        self._jac = np.zeros((6, model.nv))

    def __call__(self, q: np.ndarray):
        d = self.data
        d.qpos[:] = q
        mujoco.mj_kinematics(self.model, d)
        mujoco.mj_comPos(self.model, d)
        mujoco.mj_jacSite(self.model, d, self._jac[:3], self._jac[3:], self.site)
        return d.site_xpos[self.site].copy(), d.site_xmat[self.site].reshape(3, 3).copy(), self._jac.copy()


def sensor_jacobian_rows(S: np.ndarray, R_wf: np.ndarray, J_arm: np.ndarray, offset_f: np.ndarray) -> np.ndarray:
    """``S Ad(R_wf offset_f) J_arm``. S (m, 6), R_wf (3, 3), J_arm (6, n), offset (3,) -> (m, n)."""
    return S @ adjoint_offset(R_wf @ offset_f) @ J_arm


def sensor_jacobian_rows_batch(S: np.ndarray, R_wf: np.ndarray, J_arm: np.ndarray, offset_f: np.ndarray) -> np.ndarray:
    """``sensor_jacobian_rows`` over a batch: S (m, 6), R_wf (B, 3, 3), J_arm (B, 6, n),
    offset (3,) -> (B, m, n). ``Ad(l) [v; w] = [v - l x w; w]`` (eq. ft_factor's middle factor)."""
    l_w = R_wf @ np.asarray(offset_f, dtype=float)  # (B, 3)
    Jv, Jw = J_arm[:, :3], J_arm[:, 3:]  # (B, 3, n) each
    Jv_tip = Jv - np.cross(l_w[:, :, None], Jw, axis=1)  # (B, 3, n): v_tip = v_O - l x w
    return S @ np.concatenate([Jv_tip, Jw], axis=1)  # (B, m, n)


class TrueSensorJacobian:
    """``q -> J_true(q)`` (6, n) for a given true tool offset and arm errors."""

    def __init__(
        self,
        S: np.ndarray,
        nominal_offset_f: np.ndarray,
        true_offset_f: np.ndarray,
        mjcf_path: Path,
        link_length_m=None,
        joint_offset_rad=None,
    ) -> None:
        self.S = np.asarray(S, dtype=float)
        self.l_nom = np.asarray(nominal_offset_f, dtype=float)
        self.l_true = np.asarray(true_offset_f, dtype=float)
        link = np.zeros(8) if link_length_m is None else np.asarray(link_length_m, dtype=float)
        off = np.zeros(7) if joint_offset_rad is None else np.asarray(joint_offset_rad, dtype=float)
        self.nominal = ArmJacobians(perturbed_arm_model(mjcf_path, np.zeros(8), np.zeros(7)))
        self.true = self.nominal if not (link.any() or off.any()) else ArmJacobians(
            perturbed_arm_model(mjcf_path, link, off)
        )

    def __call__(self, q: np.ndarray) -> np.ndarray:
        _, R_n, J_n = self.nominal(q)
        J = np.empty((self.S.shape[0], J_n.shape[1]))
        J[0] = sensor_jacobian_rows(self.S[:1], R_n, J_n, self.l_nom)[0]
        if self.true is self.nominal:
            R_t, J_t = R_n, J_n
        else:
            _, R_t, J_t = self.true(q)
        J[1:] = sensor_jacobian_rows(self.S[1:], R_t, J_t, self.l_true)
        return J
