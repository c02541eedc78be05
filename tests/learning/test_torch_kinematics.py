"""pytorch-kinematics flange FK / Jacobian against MuJoCo and against finite differences."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch

from kinadapt_nn.errors import ModelFileError
from kinadapt_nn.robot import FLANGE_SITE, JOINT_LIMITS_RAD, N_JOINTS, PANDA_MJCF, Q_HOME_RAD
from kinadapt_nn.learning.torch_kinematics import build_panda_chain, flange_jacobian_pk, flange_pose_pk

N_CONFIGS = 20


@pytest.fixture(scope="module")
def chain():
    return build_panda_chain()


@pytest.fixture(scope="module")
def q_samples() -> np.ndarray:
    """(N_CONFIGS, n) seeded configurations inside the joint limits, plus the home pose."""
    rng = np.random.default_rng(1234)
    q = rng.uniform(JOINT_LIMITS_RAD[:, 0], JOINT_LIMITS_RAD[:, 1], size=(N_CONFIGS - 1, N_JOINTS))
    return np.vstack([Q_HOME_RAD, q])


@pytest.fixture(scope="module")
def mujoco_ref(q_samples: np.ndarray) -> dict[str, np.ndarray]:
    """MuJoCo flange position (B,3), rotation (B,3,3) and [jacp; jacr] (B,6,n) at q_samples."""
    model = mujoco.MjModel.from_xml_path(str(PANDA_MJCF))
    data = mujoco.MjData(model)
    site_id = model.site(FLANGE_SITE).id
    pos, rot, jac = [], [], []
    for q in q_samples:
        data.qpos[:] = q
        mujoco.mj_forward(model, data)
        jacp, jacr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
        mujoco.mj_jacSite(model, data, jacp, jacr, site_id)
        pos.append(data.site(FLANGE_SITE).xpos.copy())
        rot.append(data.site(FLANGE_SITE).xmat.reshape(3, 3).copy())
        jac.append(np.vstack([jacp, jacr]))
    return {"pos": np.array(pos), "rot": np.array(rot), "jac": np.array(jac)}


def _rotvec(R: np.ndarray) -> np.ndarray:
    """Rotation vector (3,) of a rotation matrix (3, 3) with angle < pi."""
    angle = np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))
    vee = 0.5 * np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    return vee if angle < 1e-12 else vee * angle / np.sin(angle)


def test_chain_is_float64_and_ends_at_flange(chain) -> None:
    assert chain.dtype == torch.float64
    assert chain._serial_frames[-1].name == FLANGE_SITE
    assert chain._static_offsets.dtype == torch.float64


def test_fk_matches_mujoco(chain, q_samples, mujoco_ref) -> None:
    pos, rot = flange_pose_pk(chain, torch.from_numpy(q_samples))
    assert pos.shape == (N_CONFIGS, 3) and rot.shape == (N_CONFIGS, 3, 3)
    assert pos.dtype == torch.float64
    np.testing.assert_allclose(pos.numpy(), mujoco_ref["pos"], rtol=0, atol=1e-6)
    np.testing.assert_allclose(rot.numpy(), mujoco_ref["rot"], rtol=0, atol=1e-6)


def test_jacobian_matches_mujoco(chain, q_samples, mujoco_ref) -> None:
    J = flange_jacobian_pk(chain, torch.from_numpy(q_samples))
    assert J.shape == (N_CONFIGS, 6, N_JOINTS)
    np.testing.assert_allclose(J.numpy(), mujoco_ref["jac"], rtol=0, atol=1e-6)


def test_jacobian_matches_finite_differences(chain, q_samples) -> None:
    h = 1e-5
    J = flange_jacobian_pk(chain, torch.from_numpy(q_samples)).numpy()
    # All perturbed configurations in one batch: (N_CONFIGS, n, 2, n), +h then -h.
    eye = np.eye(N_JOINTS)
    q_pert = q_samples[:, None, None, :] + h * np.stack([eye, -eye], axis=1)[None]
    pos, rot = flange_pose_pk(chain, torch.from_numpy(q_pert.reshape(-1, N_JOINTS)))
    pos = pos.numpy().reshape(N_CONFIGS, N_JOINTS, 2, 3)
    rot = rot.numpy().reshape(N_CONFIGS, N_JOINTS, 2, 3, 3)
    J_fd = np.empty_like(J)
    for b in range(N_CONFIGS):
        for j in range(N_JOINTS):
            J_fd[b, :3, j] = (pos[b, j, 0] - pos[b, j, 1]) / (2 * h)
            J_fd[b, 3:, j] = _rotvec(rot[b, j, 0] @ rot[b, j, 1].T) / (2 * h)
    np.testing.assert_allclose(J, J_fd, rtol=0, atol=1e-5)


def test_batch_equals_loop(chain, q_samples) -> None:
    q = torch.from_numpy(q_samples)
    pos, rot = flange_pose_pk(chain, q)
    J = flange_jacobian_pk(chain, q)
    for b in range(N_CONFIGS):
        pos_b, rot_b = flange_pose_pk(chain, q[b])  # unbatched (n,) input
        J_b = flange_jacobian_pk(chain, q[b])
        assert pos_b.shape == (3,) and rot_b.shape == (3, 3) and J_b.shape == (6, N_JOINTS)
        torch.testing.assert_close(pos_b, pos[b], rtol=0, atol=1e-12)
        torch.testing.assert_close(rot_b, rot[b], rtol=0, atol=1e-12)
        torch.testing.assert_close(J_b, J[b], rtol=0, atol=1e-12)


def test_float32_chain(q_samples, mujoco_ref) -> None:
    chain32 = build_panda_chain(dtype=torch.float32)
    pos, _ = flange_pose_pk(chain32, torch.from_numpy(q_samples))
    J = flange_jacobian_pk(chain32, torch.from_numpy(q_samples))
    assert pos.dtype == torch.float32 and J.dtype == torch.float32
    np.testing.assert_allclose(pos.numpy(), mujoco_ref["pos"], rtol=0, atol=1e-5)
    np.testing.assert_allclose(J.numpy(), mujoco_ref["jac"], rtol=0, atol=1e-5)


def test_bad_inputs(chain, tmp_path: Path) -> None:
    with pytest.raises(ValueError):
        flange_pose_pk(chain, torch.zeros(4, N_JOINTS - 1, dtype=torch.float64))
    with pytest.raises(ModelFileError):
        build_panda_chain(tmp_path / "missing.xml")


def test_chain_of_a_perturbed_model_matches_mujoco(q_samples) -> None:
    """``build_chain_from_model`` reads a compiled, perturbed arm as MuJoCo evaluates it."""
    from kinadapt_nn.learning.torch_kinematics import build_chain_from_model, flange_kinematics_pk
    from kinadapt_nn.sim.truth import ArmJacobians, perturbed_arm_model

    rng = np.random.default_rng(7)
    model = perturbed_arm_model(PANDA_MJCF, rng.normal(0, 0.002, 8), rng.normal(0, 0.01, 7))
    kin = flange_kinematics_pk(build_chain_from_model(model), torch.from_numpy(q_samples))
    arm = ArmJacobians(model)
    for b, q in enumerate(q_samples):
        pos, R, J = arm(q)
        np.testing.assert_allclose(kin.pos_w[b].numpy(), pos, rtol=0, atol=1e-12)
        np.testing.assert_allclose(kin.R_w_f[b].numpy(), R, rtol=0, atol=1e-12)
        np.testing.assert_allclose(kin.J[b].numpy(), J, rtol=0, atol=1e-12)
    with pytest.raises(ValueError):
        flange_kinematics_pk(build_chain_from_model(model), torch.from_numpy(q_samples[0]))
