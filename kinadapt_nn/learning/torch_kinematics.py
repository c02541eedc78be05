"""Differentiable Panda kinematics in torch (pytorch-kinematics), flange frame ``f``.

The chain is read from the shipped MJCF and ends at the ``flange`` site (origin O, axes
parallel to link 7, 0.107 m along the link-7 z axis), expressed in the world frame ``w``.
Batch-first; the chain carries its dtype and device, nothing is set globally.

How the chain is built (two traps of pytorch-kinematics 0.10.0 with mujoco 4):

* ``pk.build_chain_from_mjcf`` raises ``KeyError: np.int32(3)``: its ``JOINT_TYPE_MAP`` is
  keyed by ``mujoco.mjtJoint`` members and looked up with ``joint.type[0]`` (a numpy
  int32); in mujoco 4 the two hash alike but the enum's ``__eq__`` no longer accepts numpy
  ints, so the dict lookup misses. We do not patch pytorch-kinematics: ``_frame_tree``
  walks the compiled ``MjModel`` the way ``pytorch_kinematics.mjcf._build_chain_recurse``
  does (bodies, their single hinge/slide joint, then sites as fixed child frames), with the
  joint type looked up as ``int(joint.type[0])`` in a map keyed by ``int`` enum values.
* pk's parser stores every offset as float32 (``Transform3d``'s default dtype), which costs
  ~2e-8 m of flange position even after ``chain.to(dtype=torch.float64)``. Our frame tree
  is built directly in the requested dtype from MuJoCo's float64 ``body_pos/quat``,
  ``jnt_pos/axis`` and ``site_pos/quat``, so a float64 chain matches MuJoCo to ~1e-15.

The flange needs no hand-applied offset: sites become fixed frames, so the ``SerialChain``
simply ends at the ``flange`` frame, and ``SerialChain.jacobian`` (geometric, in the chain's
root frame, for the end-frame origin, rows [v; omega]) is then the flange Jacobian. The root
is MuJoCo's ``world`` body, so root frame = ``w`` and the Jacobian equals
``mj_jacSite(model, data, jacp, jacr, flange)`` stacked ``[jacp; jacr]``.

``build_chain_from_model`` takes any compiled bare-arm ``MjModel`` -- the shipped arm or a
perturbed one from ``kinadapt_nn.sim.truth.perturbed_arm_model`` -- so pretraining reads
every arm from the one definition the simulator uses. ``nominal_panda_chain`` caches the
shipped arm's chain (it never changes within a process); ``flange_kinematics_pk`` returns pose
and Jacobian from one forward-kinematics pass.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import NamedTuple

import mujoco
import pytorch_kinematics as pk
import torch
from pytorch_kinematics.frame import Frame, Joint, Link
from pytorch_kinematics.transforms import Transform3d

from kinadapt_nn.errors import ModelFileError
from kinadapt_nn.robot import FLANGE_SITE, JOINT_NAMES, N_JOINTS, PANDA_MJCF

__all__ = [
    "FlangeKinematics",
    "build_chain_from_model",
    "build_panda_chain",
    "flange_jacobian_pk",
    "flange_kinematics_pk",
    "flange_pose_pk",
    "nominal_panda_chain",
]

#: MuJoCo joint type (as a plain ``int``) -> pytorch-kinematics joint type.
_JOINT_TYPES: dict[int, str] = {
    int(mujoco.mjtJoint.mjJNT_HINGE): "revolute",
    int(mujoco.mjtJoint.mjJNT_SLIDE): "prismatic",
}


def _offset(pos, quat, dtype: torch.dtype, device: str | torch.device) -> Transform3d:
    """Rigid offset from MuJoCo ``pos`` (3,) and ``quat`` (4,, wxyz) in the given dtype."""
    return Transform3d(
        pos=torch.as_tensor(pos, dtype=dtype, device=device),
        rot=torch.as_tensor(quat, dtype=dtype, device=device),
        dtype=dtype,
        device=device,
    )


def _frame_tree(model: mujoco.MjModel, body_id: int, dtype: torch.dtype, device: str | torch.device) -> Frame:
    """pk ``Frame`` of body ``body_id`` with all descendant bodies and sites (no visuals)."""
    body = model.body(body_id)
    if body.jntnum[0] == 0:
        joint = Joint(body.name + "_fixed_joint", dtype=dtype, device=device)
    elif body.jntnum[0] == 1:
        jnt = model.joint(int(body.jntadr[0]))
        jtype = int(jnt.type[0])
        if jtype not in _JOINT_TYPES:
            raise ValueError(f"joint {jnt.name!r}: MuJoCo joint type {jtype} is not hinge or slide")
        joint = Joint(
            jnt.name,
            offset=Transform3d(pos=torch.as_tensor(jnt.pos, dtype=dtype, device=device), dtype=dtype, device=device),
            joint_type=_JOINT_TYPES[jtype],
            axis=torch.as_tensor(jnt.axis, dtype=dtype, device=device),
            dtype=dtype,
            device=device,
            limits=(float(jnt.range[0]), float(jnt.range[1])),
        )
    else:
        raise ValueError(f"body {body.name!r} has {body.jntnum[0]} joints; composite joints are not supported")
    frame = Frame(body.name, link=Link(body.name, offset=_offset(body.pos, body.quat, dtype, device)), joint=joint)
    frame.children = [
        _frame_tree(model, child, dtype, device)
        for child in range(model.nbody)
        if child != body_id and model.body_parentid[child] == body_id
    ]
    for site_id in range(model.nsite):
        if model.site_bodyid[site_id] == body_id:
            site = model.site(site_id)
            link = Link(site.name, offset=_offset(site.pos, site.quat, dtype, device))
            frame.children.append(Frame(site.name, link=link, joint=Joint(dtype=dtype, device=device)))
    return frame


def build_chain_from_model(
    model: mujoco.MjModel,
    dtype: torch.dtype = torch.float64,
    device: str | torch.device = "cpu",
    source: str = "MjModel",
) -> pk.SerialChain:
    """Serial chain world -> ... -> link7 -> ``flange`` site of a compiled bare-arm model.

    Args:
        model: a compiled Panda arm (no tool, no block), e.g. from
            ``kinadapt_nn.sim.truth.perturbed_arm_model``; read, never modified.
        dtype: dtype of every offset and axis of the chain (float64 recommended).
        device: torch device of the chain.
        source: what the model was read from, for error messages.

    Returns:
        A ``pytorch_kinematics.SerialChain`` with root frame ``w`` (MuJoCo's world body),
        end frame ``f`` (the flange site) and joints ``JOINT_NAMES`` in that order.

    Raises:
        ModelFileError: the model has no ``flange`` site or other joints than ``JOINT_NAMES``.
    """
    if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, FLANGE_SITE) < 0:
        raise ModelFileError(f"{source}: no site named {FLANGE_SITE!r}")
    root = _frame_tree(model, 0, dtype, device)
    chain = pk.SerialChain(pk.Chain(root, dtype=dtype, device=device), FLANGE_SITE, dtype=dtype, device=device)
    names = tuple(chain.get_joint_parameter_names())
    if names != JOINT_NAMES:
        raise ModelFileError(f"{source}: joints to {FLANGE_SITE!r} are {names}, expected {JOINT_NAMES}")
    return chain


def build_panda_chain(
    mjcf_path: Path | None = None,
    dtype: torch.dtype = torch.float64,
    device: str | torch.device = "cpu",
) -> pk.SerialChain:
    """``build_chain_from_model`` of the MJCF at ``mjcf_path`` (``None``: ``PANDA_MJCF``).

    Raises:
        ModelFileError: the MJCF file does not exist, or its chain is not the Panda's.
    """
    path = Path(PANDA_MJCF if mjcf_path is None else mjcf_path)
    if not path.is_file():
        raise ModelFileError(f"MJCF file not found: {path}")
    return build_chain_from_model(mujoco.MjModel.from_xml_path(str(path)), dtype, device, source=str(path))


@lru_cache(maxsize=4)
def nominal_panda_chain(dtype: torch.dtype = torch.float64, device: str = "cpu") -> pk.SerialChain:
    """The shipped arm's chain (``build_panda_chain()``), built once per (dtype, device).

    Shared: callers must not modify it (pk's kinematics calls do not)."""
    return build_panda_chain(None, dtype, device)


class FlangeKinematics(NamedTuple):
    """Flange pose and Jacobian of a batch of configurations (one FK pass)."""

    pos_w: torch.Tensor
    """(B, 3) flange origin O in ``w`` [m]."""
    R_w_f: torch.Tensor
    """(B, 3, 3) rotation taking ``f`` coordinates to ``w`` coordinates."""
    J: torch.Tensor
    """(B, 6, n) world Jacobian of O, rows [v_O; omega] (``mj_jacSite``'s ``[jacp; jacr]``)."""


def _as_batch(chain: pk.SerialChain, q: torch.Tensor) -> tuple[torch.Tensor, bool]:
    """``q`` as a (B, n) tensor in the chain's dtype/device, and whether it was unbatched."""
    q = torch.as_tensor(q, dtype=chain.dtype, device=chain.device)
    if q.shape[-1:] != (N_JOINTS,) or q.ndim not in (1, 2):
        raise ValueError(f"q must have shape (B, {N_JOINTS}) or ({N_JOINTS},), got {tuple(q.shape)}")
    return (q.unsqueeze(0), True) if q.ndim == 1 else (q, False)


def flange_pose_pk(chain: pk.SerialChain, q: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Flange pose in the world frame (differentiable in ``q``).

    Args:
        chain: from ``build_panda_chain``.
        q: joint angles [rad], (B, n) or (n,); cast to the chain's dtype/device.

    Returns:
        ``pos_w`` (B, 3): flange origin O in ``w`` [m];
        ``R_w_f`` (B, 3, 3): rotation taking ``f`` coordinates to ``w`` coordinates.
        The batch dimension is dropped when ``q`` is (n,).
    """
    qb, single = _as_batch(chain, q)
    T_w_f = chain.forward_kinematics(qb).get_matrix()  # (B, 4, 4)
    pos_w, R_w_f = T_w_f[:, :3, 3], T_w_f[:, :3, :3]
    return (pos_w[0], R_w_f[0]) if single else (pos_w, R_w_f)


def flange_jacobian_pk(chain: pk.SerialChain, q: torch.Tensor) -> torch.Tensor:
    """World-frame geometric Jacobian of the flange origin O.

    Args:
        chain: from ``build_panda_chain``.
        q: joint angles [rad], (B, n) or (n,); cast to the chain's dtype/device.

    Returns:
        ``J`` (B, 6, n) with rows [v_O (3); omega (3)], both in ``w``, such that
        ``[v_O; omega] = J @ dq`` (MuJoCo's ``mj_jacSite`` for ``flange``, ``[jacp; jacr]``).
        (6, n) when ``q`` is (n,).
    """
    qb, single = _as_batch(chain, q)
    J = chain.jacobian(qb)  # root frame (= w), end-frame (= flange) origin
    return J[0] if single else J


def flange_kinematics_pk(chain: pk.SerialChain, q: torch.Tensor) -> FlangeKinematics:
    """Flange pose and world Jacobian from one forward-kinematics pass (batch only).

    Args:
        chain: from ``build_chain_from_model`` / ``build_panda_chain``.
        q: joint angles [rad], (B, n); cast to the chain's dtype/device.

    Returns:
        ``FlangeKinematics`` with ``pos_w`` (B, 3), ``R_w_f`` (B, 3, 3), ``J`` (B, 6, n), equal to
        ``flange_pose_pk`` and ``flange_jacobian_pk`` (which each run their own FK pass).
    """
    qb, single = _as_batch(chain, q)
    if single:
        raise ValueError(f"q must have shape (B, {N_JOINTS}), got {tuple(qb.shape[1:])}")
    J, T_w_f = chain.jacobian(qb, ret_eef_pose=True)  # (B, 6, n), (B, 4, 4)
    return FlangeKinematics(T_w_f[:, :3, 3], T_w_f[:, :3, :3], J)
