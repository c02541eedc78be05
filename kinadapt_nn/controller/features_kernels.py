"""The in-kernel features' numba code: the adjoint's regressor and drive, the neural basis and the
per-entry Gaussian RBF (``features.kernel``: "adjoint", "neural", "rbf"), called by the fused step
kernels (``controller/step_kernels.py``). Each is the kernel form of its features class
(``features/adjoint.py``, ``neural.py``, ``rbf.py``; ``tests/controller/test_core.py`` checks them
equal).

Shapes: n joints, m = 6 channels, p parameters; episode b's rows of the batch arrays.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from kinadapt_nn.controller.dense import dot, vcopy
from kinadapt_nn.controller.layout import (L_M, L_N, L_P, V_LNOM, V_N)

@nb.njit(cache=True, inline="always")
def _adjoint_regressor(b, inp, R, J, lay, c, mats, known, Phi_T):
    """Adjoint regressor on the realised velocity: known = S xi + e_0 n . (w x R l_nom),
    Phi = S_v [w]x R (Phi_T (p=3, m)), xi = J qdot."""
    n = lay[L_N]
    S = mats[0]
    xi = np.zeros(6)
    for i in range(6):
        v = 0.0
        for j in range(n):
            v += J[b, i, j] * inp[b, n + j]
        xi[i] = v
    for i in range(6):
        v = 0.0
        for j in range(6):
            v += S[i, j] * xi[j]
        known[i] = v
    w0, w1, w2 = xi[3], xi[4], xi[5]
    Rb = R[b]
    for jj in range(3):  # ([w]x R)[:, jj] = w x R[:, jj]
        c0, c1, c2 = Rb[0, jj], Rb[1, jj], Rb[2, jj]
        x0, x1, x2 = w1 * c2 - w2 * c1, w2 * c0 - w0 * c2, w0 * c1 - w1 * c0
        Phi_T[jj, 0] = 0.0  # depth row: not adapted
        for i in range(1, 6):
            Phi_T[jj, i] = S[i, 0] * x0 + S[i, 1] * x1 + S[i, 2] * x2
    lw0, lw1, lw2 = _lever(b, R, c)
    n0, n1, n2 = c[V_N], c[V_N + 1], c[V_N + 2]
    known[0] += n0 * (w1 * lw2 - w2 * lw1) + n1 * (w2 * lw0 - w0 * lw2) + n2 * (w0 * lw1 - w1 * lw0)


@nb.njit(cache=True)
def _lever(b, R, c):
    """R l_nom: the nominal lever, world."""
    Rb = R[b]
    return (Rb[0, 0] * c[V_LNOM] + Rb[0, 1] * c[V_LNOM + 1] + Rb[0, 2] * c[V_LNOM + 2],
            Rb[1, 0] * c[V_LNOM] + Rb[1, 1] * c[V_LNOM + 1] + Rb[1, 2] * c[V_LNOM + 2],
            Rb[2, 0] * c[V_LNOM] + Rb[2, 1] * c[V_LNOM + 1] + Rb[2, 2] * c[V_LNOM + 2])


@nb.njit(cache=True, inline="always")
def _adjoint_drive(b, R, theta, F, c, mats, drive):
    """(S Ad(R theta))^T F without forming it (AdjointFeatures.twist_drive): with a = R theta,
    u = S_v^T F, m = F_0 n: [S_v^T F + m; S_w^T F + a x u + lw x m]."""
    S = mats[0]
    for j in range(6):
        v = 0.0
        for i in range(6):
            v += S[i, j] * F[i]
        drive[j] = v
    u0, u1, u2 = drive[0] - S[0, 0] * F[0], drive[1] - S[0, 1] * F[0], drive[2] - S[0, 2] * F[0]  # S_v^T F
    Rb = R[b]
    a0 = Rb[0, 0] * theta[0] + Rb[0, 1] * theta[1] + Rb[0, 2] * theta[2]
    a1 = Rb[1, 0] * theta[0] + Rb[1, 1] * theta[1] + Rb[1, 2] * theta[2]
    a2 = Rb[2, 0] * theta[0] + Rb[2, 1] * theta[1] + Rb[2, 2] * theta[2]
    l0, l1, l2 = _lever(b, R, c)
    m0, m1, m2 = F[0] * c[V_N], F[0] * c[V_N + 1], F[0] * c[V_N + 2]
    drive[3] += (a1 * u2 - a2 * u1) + (l1 * m2 - l2 * m1)
    drive[4] += (a2 * u0 - a0 * u2) + (l2 * m0 - l0 * m2)
    drive[5] += (a0 * u1 - a1 * u0) + (l0 * m1 - l1 * m0)



@nb.njit(cache=True)
def _adjoint_twist_jacobian(b, R, theta, c, mats):
    """S Ad(R theta) (6, 6) with the depth row on the nominal lever (AdjointFeatures.twist_jacobian)."""
    S = mats[0]
    Rb = R[b]
    a0 = Rb[0, 0] * theta[0] + Rb[0, 1] * theta[1] + Rb[0, 2] * theta[2]
    a1 = Rb[1, 0] * theta[0] + Rb[1, 1] * theta[1] + Rb[1, 2] * theta[2]
    a2 = Rb[2, 0] * theta[0] + Rb[2, 1] * theta[1] + Rb[2, 2] * theta[2]
    l0, l1, l2 = _lever(b, R, c)
    Jx = np.empty((6, 6))  # S Ad(l) = [S_v, S_w - S_v [l]x]
    for i in range(6):
        vcopy(Jx[i], S[i])
    for i in range(6):
        if i == 0:
            v0, v1, v2, u0, u1, u2 = S[0, 0], S[0, 1], S[0, 2], l0, l1, l2
        else:
            v0, v1, v2, u0, u1, u2 = S[i, 0], S[i, 1], S[i, 2], a0, a1, a2
        Jx[i, 3] -= v1 * u2 - v2 * u1  # row i of S_v [a]x is v^T [a]x = (v x a)^T
        Jx[i, 4] -= v2 * u0 - v0 * u2
        Jx[i, 5] -= v0 * u1 - v1 * u0
    return Jx


@nb.njit(cache=True)
def _twist_jacobian_times(Jx, Jb):
    """Jx @ Jb (6, n) for Jx = S Ad(.) (6, 6) (:func:`_adjoint_twist_jacobian`; S mostly zeros) and
    the arm's Jacobian Jb (6, n): each entry summed from 0.0 over Jx's non-zeros in r's order.
    ``dense.mm``'s sums to the bit: a left-out term is an exact zero (Jb is finite: the forward
    kinematics of finite encoder readings), and adding a zero to a sum that starts at +0.0 changes
    no bit."""
    n = Jb.shape[1]
    out = np.empty((6, n))
    for i in range(6):
        for j in range(n):
            v = 0.0
            for r in range(6):
                a = Jx[i, r]
                if a != 0.0:
                    v += a * Jb[r, j]
            out[i, j] = v
    return out



# ================================================================================================
# neural features in the kernel: J_hat = K(q) + [0; Y(q) theta], K the adjoint at the prior offset
def neural_consts(features) -> np.ndarray:
    """The frozen MLP of ``NeuralFeatures`` (structure ``basis``) as one array for the kernel:
    [H, K, prior offset (3), q_mean (n), 1/q_std (n), W1, b1, W2, b2, W3, b3] (W3, b3 already
    scaled by W^-1 as in NeuralFeatures)."""
    H, n = features.W1.shape
    parts = [np.array([H, features.K], dtype=float), features.prior, features.q_mean, features.q_inv_std,
             features.W1.ravel(), features.b1, features.W2.ravel(), features.b2, features.W3.ravel(), features.b3]
    return np.ascontiguousarray(np.concatenate([np.asarray(a, dtype=float).ravel() for a in parts]))


@nb.njit(cache=True)
def _neural_body(fx, q, n):
    """Y(q) (5, n, K): y = W3 tanh(W2 tanh(W1 (q - mu)/sd + b1) + b2) + b3 (NeuralFeatures._body)."""
    H, K = int(fx[0]), int(fx[1])
    o = 5 + 2 * n
    x = np.empty(n)
    for j in range(n):
        x[j] = (q[j] - fx[5 + j]) * fx[5 + n + j]
    h1 = _affine(fx, o, H, n, x, True)
    o += H * n + H
    h2 = _affine(fx, o, H, H, h1, True)
    o += H * H + H
    return _affine(fx, o, 5 * n * K, H, h2, False).reshape((5, n, K))


@nb.njit(cache=True)
def _affine(fx, o, rows, cols, x, squash):
    """y = W x + b (tanh'd when ``squash``), W (rows, cols) then b (rows,) stored at fx[o:]."""
    y = np.empty(rows)
    ob = o + rows * cols
    for i in range(rows):
        v = dot(fx[o + i * cols:o + (i + 1) * cols], x) + fx[ob + i]
        y[i] = math.tanh(v) if squash else v
    return y


@nb.njit(cache=True)
def _neural_rows(b, inp, R, J, Y, lay, c, mats, fx, known, Phi_T):
    """Regressor of the neural basis: known = adjoint's known + Phi_adj l_prior; Phi rows 1..5 =
    qdot^T Y_i (NeuralFeatures.regressor)."""
    n, p = lay[L_N], lay[L_P]
    _known_at_prior(b, inp, R, J, lay, c, mats, fx, known)
    for kk in range(p):
        Phi_T[kk, 0] = 0.0
        for i in range(5):
            v = 0.0
            for j in range(n):
                v += inp[b, n + j] * Y[i, j, kk]
            Phi_T[kk, 1 + i] = v


@nb.njit(cache=True)
def _known_at_prior(b, inp, R, J, lay, c, mats, fx, known):
    """The learned features' known part of the regressor: the adjoint's known + Phi_adj l_prior
    (l_prior = fx[2:5]) (m,), written to ``known``."""
    PhiA = np.zeros((3, 6))
    _adjoint_regressor(b, inp, R, J, lay, c, mats, known, PhiA)
    for i in range(6):
        known[i] += PhiA[0, i] * fx[2] + PhiA[1, i] * fx[3] + PhiA[2, i] * fx[4]


@nb.njit(cache=True)
def _jhat_prior(b, R, J, c, mats, fx):
    """The learned features' known Jacobian K(q) = S Ad(R l_prior) J (6, n) (l_prior = fx[2:5])."""
    return _twist_jacobian_times(_adjoint_twist_jacobian(b, R, fx[2:5], c, mats), J[b])


@nb.njit(cache=True)
def _neural_jhat(Kq, Y, theta):
    """J_hat (6, n) = K(q) + [0; Y theta] (a new array; ``Kq`` from :func:`_jhat_prior`)."""
    n, K = Y.shape[1], Y.shape[2]
    Jh = np.empty((6, n))  # (a loop copy: .copy() costs compile, see dense.vcopy)
    for i in range(6):
        vcopy(Jh[i], Kq[i])
    for i in range(5):
        for j in range(n):
            v = 0.0
            for kk in range(K):
                v += Y[i, j, kk] * theta[kk]
            Jh[1 + i, j] += v
    return Jh


# ================================================================================================
# RBF features in the kernel: J_hat = K(q) + [0; Theta psi(q)], K the adjoint at the prior offset
def rbf_consts(features) -> np.ndarray:
    """The Gaussian RBF of ``RBFFeatures`` as one array for the kernel: [K, 1/(2 w^2), prior
    offset (3), centres (K n)] (the prior at the same place as in :func:`neural_consts`)."""
    parts = [np.array([features.K, features.inv2w2], dtype=float), features.prior, features.centres.ravel()]
    return np.ascontiguousarray(np.concatenate([np.asarray(a, dtype=float).ravel() for a in parts]))


@nb.njit(cache=True)
def _rbf_psi(fx, q, n):
    """psi (K,): psi_k = exp(-|q - c_k|^2 / (2 w^2)) (RBFFeatures.psi)."""
    K = int(fx[0])
    psi = np.empty(K)
    for kk in range(K):
        v = 0.0
        for j in range(n):
            d = fx[5 + kk * n + j] - q[j]
            v += d * d
        psi[kk] = math.exp(-v * fx[1])
    return psi


@nb.njit(cache=True)
def _rbf_rows(b, inp, R, J, psi, lay, c, mats, fx, known, Phi_T):
    """Regressor of the per-entry RBF: known = adjoint's known + Phi_adj l_prior; row 1 + i of Phi
    holds qdot_j psi_k in block i ((i, j, k) order) and zeros elsewhere (RBFFeatures.regressor)."""
    n, m, p = lay[L_N], lay[L_M], lay[L_P]
    K = psi.shape[0]
    _known_at_prior(b, inp, R, J, lay, c, mats, fx, known)
    for r in range(p):
        for i in range(m):
            Phi_T[r, i] = 0.0
    w = n * K
    for i in range(5):
        for j in range(n):
            qd = inp[b, n + j]
            for kk in range(K):
                Phi_T[i * w + j * K + kk, 1 + i] = qd * psi[kk]


@nb.njit(cache=True)
def _rbf_jhat(Kq, psi, theta):
    """J_hat (6, n) = K(q) + [0; Theta psi], Theta = theta as (5, n, K) (a new array; ``Kq`` from
    :func:`_jhat_prior`)."""
    n, K = Kq.shape[1], psi.shape[0]
    Jh = np.empty((6, n))
    for i in range(6):
        vcopy(Jh[i], Kq[i])
    for i in range(5):
        for j in range(n):
            v = 0.0
            o = (i * n + j) * K
            for kk in range(K):
                v += theta[o + kk] * psi[kk]
            Jh[1 + i, j] += v
    return Jh

