"""Small arm kinematic errors, applied to an MJCF spec (hidden truth; the controller never sees it).

Two mechanisms the 3-parameter adjoint ``S Ad(theta) J_arm`` cannot represent (it assumes
``J_arm`` exact):

* link length errors: each body offset ``pos`` of link1..link7 and of the flange site is
  lengthened by ``delta`` [m] along its own direction (bodies with a zero offset are skipped);
* joint zero offsets: the encoder reads ``q`` while the link sits at ``q + delta`` [rad]. Built
  into the model by turning the child body frame by ``Rz(delta)`` (the hinge axis is the body z
  axis, so the frame chain becomes ``... T_body Rz(q + delta)``).

The same function builds the perturbed arms of the pretraining data set, so training and the
simulator share one definition.
"""

from __future__ import annotations

import mujoco
import numpy as np

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
