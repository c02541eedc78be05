"""Forward kinematics of the bare arm in the kernel: a chain of hinges read once from MuJoCo's
compiled ``MjModel`` (:func:`arm_chain`), evaluated with MuJoCo's own formulas (:func:`_fk`:
``mj_kinematics`` + ``mj_comPos`` + ``mj_jacSite``; equal to ~1e-15, ``tests/controller/test_core.py``).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np


def arm_chain(model, site: int) -> np.ndarray:
    """The bare arm's kinematic tree as one array for :func:`_fk`, read once from an ``MjModel``:
    row i (body i, parents first): [parent, pos (3), quat (4), joint qpos address or -1, joint
    pos (3), joint axis (3), qpos0]; last row: [site body, site pos (3), site quat (4), 0...].
    Only hinge joints (one per body at most) are accepted."""
    import mujoco

    nb_ = model.nbody
    chain = np.zeros((nb_ + 1, 16))
    for i in range(nb_):
        chain[i, 0] = model.body_parentid[i]
        chain[i, 1:4] = model.body_pos[i]
        chain[i, 4:8] = model.body_quat[i]
        chain[i, 8] = -1.0
        nj = model.body_jntnum[i]
        if nj > 1 or (nj == 1 and int(model.jnt_type[model.body_jntadr[i]]) != int(mujoco.mjtJoint.mjJNT_HINGE)):
            raise ValueError("the controller's kinematics support one hinge per body (the bare arm)")
        if nj == 1:
            j = model.body_jntadr[i]
            adr = model.jnt_qposadr[j]
            chain[i, 8] = adr
            chain[i, 9:12] = model.jnt_pos[j]
            chain[i, 12:15] = model.jnt_axis[j]
            chain[i, 15] = model.qpos0[adr]
    chain[nb_, 0] = model.site_bodyid[site]
    chain[nb_, 1:4] = model.site_pos[site]
    chain[nb_, 4:8] = model.site_quat[site]
    return chain


@nb.njit(cache=True)
def _quat_mul(a0, a1, a2, a3, b0, b1, b2, b3):
    """The quaternion product a b (w, x, y, z) -> its four components."""
    return (a0 * b0 - a1 * b1 - a2 * b2 - a3 * b3,
            a0 * b1 + a1 * b0 + a2 * b3 - a3 * b2,
            a0 * b2 - a1 * b3 + a2 * b0 + a3 * b1,
            a0 * b3 + a1 * b2 - a2 * b1 + a3 * b0)


@nb.njit(cache=True)
def _quat_mat(q0, q1, q2, q3):
    """The rotation matrix of the unit quaternion (w, x, y, z) -> its nine entries, row by row."""
    return (q0 * q0 + q1 * q1 - q2 * q2 - q3 * q3, 2.0 * (q1 * q2 - q0 * q3), 2.0 * (q1 * q3 + q0 * q2),
            2.0 * (q1 * q2 + q0 * q3), q0 * q0 - q1 * q1 + q2 * q2 - q3 * q3, 2.0 * (q2 * q3 - q0 * q1),
            2.0 * (q1 * q3 - q0 * q2), 2.0 * (q2 * q3 + q0 * q1), q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3)


@nb.njit(cache=True)
def _fk(chain, site, q, p_O, R, J):
    """Flange pose and geometric Jacobian (6, n) at q: body frames down the chain (body pos/quat,
    hinge rotation about its anchor), then column j = [a_j x (p_O - anchor_j); a_j]. The small
    matrices and quaternions are scalars (no arrays of their own)."""
    nbody = chain.shape[0]
    frame = np.zeros((nbody, 7))  # per body: world position (3), world orientation quaternion (4)
    frame[0, 3] = 1.0
    hinge = np.zeros((J.shape[1], 6))  # per joint: world axis (3), world anchor (3)
    for i in range(1, nbody):
        par = int(chain[i, 0])
        fp, fi, ci = frame[par], frame[i], chain[i]
        m00, m01, m02, m10, m11, m12, m20, m21, m22 = _quat_mat(fp[3], fp[4], fp[5], fp[6])
        fi[0] = fp[0] + m00 * ci[1] + m01 * ci[2] + m02 * ci[3]
        fi[1] = fp[1] + m10 * ci[1] + m11 * ci[2] + m12 * ci[3]
        fi[2] = fp[2] + m20 * ci[1] + m21 * ci[2] + m22 * ci[3]
        w, x, y, z = _quat_mul(fp[3], fp[4], fp[5], fp[6], ci[4], ci[5], ci[6], ci[7])
        adr = int(ci[8])
        if adr >= 0:
            m00, m01, m02, m10, m11, m12, m20, m21, m22 = _quat_mat(w, x, y, z)
            h = hinge[adr]
            h[0] = m00 * ci[12] + m01 * ci[13] + m02 * ci[14]
            h[1] = m10 * ci[12] + m11 * ci[13] + m12 * ci[14]
            h[2] = m20 * ci[12] + m21 * ci[13] + m22 * ci[14]
            h[3] = fi[0] + m00 * ci[9] + m01 * ci[10] + m02 * ci[11]
            h[4] = fi[1] + m10 * ci[9] + m11 * ci[10] + m12 * ci[11]
            h[5] = fi[2] + m20 * ci[9] + m21 * ci[10] + m22 * ci[11]
            half = 0.5 * (q[adr] - ci[15])
            sh = math.sin(half)
            w, x, y, z = _quat_mul(w, x, y, z, math.cos(half), ci[12] * sh, ci[13] * sh, ci[14] * sh)
            m00, m01, m02, m10, m11, m12, m20, m21, m22 = _quat_mat(w, x, y, z)
            # off-centre rotation: the anchor stays put
            fi[0] = h[3] - (m00 * ci[9] + m01 * ci[10] + m02 * ci[11])
            fi[1] = h[4] - (m10 * ci[9] + m11 * ci[10] + m12 * ci[11])
            fi[2] = h[5] - (m20 * ci[9] + m21 * ci[10] + m22 * ci[11])
        nrm = math.sqrt(w ** 2 + x ** 2 + y ** 2 + z ** 2)
        fi[3], fi[4], fi[5], fi[6] = w / nrm, x / nrm, y / nrm, z / nrm
    fs = frame[int(site[0])]
    m00, m01, m02, m10, m11, m12, m20, m21, m22 = _quat_mat(fs[3], fs[4], fs[5], fs[6])
    p_O[0] = fs[0] + m00 * site[1] + m01 * site[2] + m02 * site[3]
    p_O[1] = fs[1] + m10 * site[1] + m11 * site[2] + m12 * site[3]
    p_O[2] = fs[2] + m20 * site[1] + m21 * site[2] + m22 * site[3]
    s00, s01, s02, s10, s11, s12, s20, s21, s22 = _quat_mat(site[4], site[5], site[6], site[7])
    R[0, 0], R[0, 1], R[0, 2] = m00 * s00 + m01 * s10 + m02 * s20, m00 * s01 + m01 * s11 + m02 * s21, m00 * s02 + m01 * s12 + m02 * s22
    R[1, 0], R[1, 1], R[1, 2] = m10 * s00 + m11 * s10 + m12 * s20, m10 * s01 + m11 * s11 + m12 * s21, m10 * s02 + m11 * s12 + m12 * s22
    R[2, 0], R[2, 1], R[2, 2] = m20 * s00 + m21 * s10 + m22 * s20, m20 * s01 + m21 * s11 + m22 * s21, m20 * s02 + m21 * s12 + m22 * s22
    for j in range(J.shape[1]):
        h = hinge[j]
        a0, a1, a2 = h[0], h[1], h[2]
        r0, r1, r2 = p_O[0] - h[3], p_O[1] - h[4], p_O[2] - h[5]
        J[0, j], J[1, j], J[2, j] = a1 * r2 - a2 * r1, a2 * r0 - a0 * r2, a0 * r1 - a1 * r0
        J[3, j], J[4, j], J[5, j] = a0, a1, a2


@nb.njit(cache=True)
def fk_batch(chain, inp, p_O, R, J):
    """``_fk`` for every episode at the encoder readings in ``inp`` (B, 2n+6)."""
    nbody = chain.shape[0] - 1
    for b in range(inp.shape[0]):
        _fk(chain[:nbody], chain[nbody], inp[b], p_O[b], R[b], J[b])


