"""Forward kinematics of the bare arm in the kernel: a chain of hinges read once from MuJoCo's
compiled ``MjModel`` (:func:`arm_chain`), evaluated with MuJoCo's own formulas (:func:`_fk`:
``mj_kinematics`` + ``mj_comPos`` + ``mj_jacSite``; equal to ~1e-15, ``tests/controller/test_core.py``).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from kinadapt_nn.controller.dense import vcopy

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
def _quat_mul(a, b, out):
    a0, a1, a2, a3, b0, b1, b2, b3 = a[0], a[1], a[2], a[3], b[0], b[1], b[2], b[3]
    out[0] = a0 * b0 - a1 * b1 - a2 * b2 - a3 * b3
    out[1] = a0 * b1 + a1 * b0 + a2 * b3 - a3 * b2
    out[2] = a0 * b2 - a1 * b3 + a2 * b0 + a3 * b1
    out[3] = a0 * b3 + a1 * b2 - a2 * b1 + a3 * b0


@nb.njit(cache=True)
def _quat_mat(q, M):
    q0, q1, q2, q3 = q[0], q[1], q[2], q[3]
    M[0, 0] = q0 * q0 + q1 * q1 - q2 * q2 - q3 * q3
    M[0, 1] = 2.0 * (q1 * q2 - q0 * q3)
    M[0, 2] = 2.0 * (q1 * q3 + q0 * q2)
    M[1, 0] = 2.0 * (q1 * q2 + q0 * q3)
    M[1, 1] = q0 * q0 - q1 * q1 + q2 * q2 - q3 * q3
    M[1, 2] = 2.0 * (q2 * q3 - q0 * q1)
    M[2, 0] = 2.0 * (q1 * q3 - q0 * q2)
    M[2, 1] = 2.0 * (q2 * q3 + q0 * q1)
    M[2, 2] = q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3


@nb.njit(cache=True)
def _fk(chain, site, q, p_O, R, J):
    """Flange pose and geometric Jacobian (6, n) at q: body frames down the chain (body pos/quat,
    hinge rotation about its anchor), then column j = [a_j x (p_O - anchor_j); a_j]."""
    nbody = chain.shape[0]
    xpos = np.zeros((nbody, 3))
    xquat = np.zeros((nbody, 4))
    xquat[0, 0] = 1.0
    axes = np.zeros((J.shape[1], 3))
    anchors = np.zeros((J.shape[1], 3))
    M = np.empty((3, 3))
    tmp = np.empty(4)
    ql = np.empty(4)
    for i in range(1, nbody):
        par = int(chain[i, 0])
        _quat_mat(xquat[par], M)
        for r in range(3):
            xpos[i, r] = xpos[par, r] + M[r, 0] * chain[i, 1] + M[r, 1] * chain[i, 2] + M[r, 2] * chain[i, 3]
        _quat_mul(xquat[par], chain[i, 4:8], xquat[i])
        adr = int(chain[i, 8])
        if adr >= 0:
            _quat_mat(xquat[i], M)
            for r in range(3):
                axes[adr, r] = M[r, 0] * chain[i, 12] + M[r, 1] * chain[i, 13] + M[r, 2] * chain[i, 14]
                anchors[adr, r] = xpos[i, r] + M[r, 0] * chain[i, 9] + M[r, 1] * chain[i, 10] + M[r, 2] * chain[i, 11]
            half = 0.5 * (q[adr] - chain[i, 15])
            sh = math.sin(half)
            ql[0], ql[1], ql[2], ql[3] = math.cos(half), chain[i, 12] * sh, chain[i, 13] * sh, chain[i, 14] * sh
            _quat_mul(xquat[i], ql, tmp)
            vcopy(xquat[i], tmp)
            _quat_mat(xquat[i], M)
            for r in range(3):  # off-centre rotation: the anchor stays put
                xpos[i, r] = anchors[adr, r] - (M[r, 0] * chain[i, 9] + M[r, 1] * chain[i, 10] + M[r, 2] * chain[i, 11])
        nrm = math.sqrt(xquat[i, 0] ** 2 + xquat[i, 1] ** 2 + xquat[i, 2] ** 2 + xquat[i, 3] ** 2)
        for r in range(4):
            xquat[i, r] /= nrm
    sb = int(site[0])
    _quat_mat(xquat[sb], M)
    for r in range(3):
        p_O[r] = xpos[sb, r] + M[r, 0] * site[1] + M[r, 1] * site[2] + M[r, 2] * site[3]
    Ms = np.empty((3, 3))
    _quat_mat(site[4:8], Ms)
    for r in range(3):
        for c_ in range(3):
            R[r, c_] = M[r, 0] * Ms[0, c_] + M[r, 1] * Ms[1, c_] + M[r, 2] * Ms[2, c_]
    for j in range(J.shape[1]):
        a0, a1, a2 = axes[j, 0], axes[j, 1], axes[j, 2]
        r0, r1, r2 = p_O[0] - anchors[j, 0], p_O[1] - anchors[j, 1], p_O[2] - anchors[j, 2]
        J[0, j], J[1, j], J[2, j] = a1 * r2 - a2 * r1, a2 * r0 - a0 * r2, a0 * r1 - a1 * r0
        J[3, j], J[4, j], J[5, j] = a0, a1, a2


@nb.njit(cache=True)
def fk_batch(chain, inp, p_O, R, J):
    """``_fk`` for every episode at the encoder readings in ``inp`` (B, 2n+6)."""
    nbody = chain.shape[0] - 1
    for b in range(inp.shape[0]):
        _fk(chain[:nbody], chain[nbody], inp[b], p_O[b], R[b], J[b])


