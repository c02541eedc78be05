"""Small SE(3) helpers: skew matrices, rotations and the twist adjoint of a tool offset.

Twists are stacked ``[v; omega]`` (linear first) and wrenches ``[f; m]``, both expressed in
the world frame ``w`` and referred to the point named in the variable.
"""

from __future__ import annotations

import numpy as np


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrix: ``skew(a) @ b == np.cross(a, b)``. (3,) -> (3, 3)."""
    x, y, z = np.asarray(v, dtype=float).ravel().tolist()  # Python floats: one array build (~1 us)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def skews(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices of a batch: ``skews(a)[i] @ b == np.cross(a[i], b)``, and column j of
    ``skews(a)[i]`` is ``np.cross(a[i], e_j)`` to the bit. (N, 3) -> (N, 3, 3)."""
    v = np.asarray(v, dtype=float)
    out = np.zeros((len(v), 3, 3))
    out[:, 0, 1], out[:, 0, 2] = -v[:, 2], v[:, 1]
    out[:, 1, 0], out[:, 1, 2] = v[:, 2], -v[:, 0]
    out[:, 2, 0], out[:, 2, 1] = -v[:, 1], v[:, 0]
    return out


def rot_x(angle_rad: float) -> np.ndarray:
    """Rotation about x by ``angle_rad``. -> (3, 3)."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(angle_rad: float) -> np.ndarray:
    """Rotation about y by ``angle_rad``. -> (3, 3)."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def tilt_rotation(tilt_deg: tuple[float, float] | np.ndarray) -> np.ndarray:
    """``Rx(tilt[0]) @ Ry(tilt[1])`` with angles in degrees. -> (3, 3)."""
    return rot_x(np.deg2rad(tilt_deg[0])) @ rot_y(np.deg2rad(tilt_deg[1]))


def adjoint_offset(offset_w_m: np.ndarray) -> np.ndarray:
    """Adjoint of a pure offset: flange twist -> tip twist, both in world coordinates.

    ``[v_tip; w] = Ad(l) [v_O; w]`` with ``v_tip = v_O + w x l`` (paper eq. ft_factor's
    middle factor). Affine in ``l``. (3,) -> (6, 6).
    """
    ad = np.eye(6)
    ad[:3, 3:] = -skew(offset_w_m)
    return ad


def rotvec_from_matrix(R: np.ndarray) -> np.ndarray:
    """Rotation vector (axis * angle) of a rotation matrix, angle in [0, pi). (3,3) -> (3,)."""
    cos_a = np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    angle = np.arccos(cos_a)
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if angle < 1e-9:
        return 0.5 * w
    return angle / (2.0 * np.sin(angle)) * w


def quat_from_matrix(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of a rotation matrix. (3,3) -> (4,)."""
    import mujoco

    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(R, dtype=np.float64).ravel())
    return q
