"""The controller's per-step maths, written once over B episodes (numba kernels).

One control period of episode b (eq. names as in docs/method.md and ``kinadapt_nn.controller.laws``):

    intake       non-finite samples are held (at most ``max_dropout_s``), never let in
    w_env        = [R (r_f - r0_f); R (r_m - r0_m)]                    tared wrench, world, at O
    s            = [n . (p_O + R l_nom) - n . p_entry ;  G w_env]      (kinadapt_nn.sensing)
    filters      y, known_f, Phi_f += alpha (input - state);  s_dot_meas = (s - y) / (tau + dt)
    F            = -grad V(s)                                          eq. ft_force
    drive        = J_hat_xi^T F = (S Ad(R theta))^T F (adjoint, fused) eq. cp_admittance's drive
    xi+          = (M xi + dt (rho drive - w_env)) / (M + dt D)        eq. cp_admittance
    qdot_ref     = J^+ xi + (I - J^+ J) k_ns (q_0 - q)
    theta+       = the law's step (kinadapt_nn.controller.laws: kalman | composite | ...) in contact

Shapes: B episodes, n joints, m = 6 sensor channels, p parameters. All state lives in one
``ControllerState`` (float rows ``x`` (B, NX) and counters ``k`` (B, NK)); its named views
(``xi``, ``q_ref``, ``filt``, ``theta``, ``law_x``, ...) are what the wrappers read. Constants are
bundled into few arrays (``CoreConsts``) so a kernel call costs one dispatch.

Laws: the law-independent part of a law step is here (``_law``: the contact gate, eq. ft_pred,
the Gram log, the tracking rows); the law's own step (``controller/laws/<name>.py``) is called
through its native address (``CoreConsts.law_fn``, ``laws.base.law_step_fn``), so these kernels
compile -- and are cached -- once for every law, registered ones included. A law's state is its
own block of the state rows (``Layout``'s ``law`` block and counters, declared by the law).

Features: the adjoint's regressor and drive are computed in the kernel (``FEAT_ADJOINT``), and so
are the neural basis (``FEAT_NEURAL``: the frozen MLP body evaluated here, ``neural_consts``) and
the per-entry Gaussian RBF (``FEAT_RBF``: ``rbf_consts``);
other features supply ``[known; Phi^T]`` and either ``J_hat_xi`` (``FEAT_TWIST``) or ``J_hat``
(``FEAT_JHAT``) from Python between :func:`sense_kernel` and :func:`act_kernel`.

The controller side only: this module imports no simulator, no episode, no experiment config.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np

from kinadapt_nn import compiled
from kinadapt_nn.controller.dense import chol, chol_solve, dot, gram_sparse_log, mm, mm_nt, sym_eigmin, vcopy, vfill
from kinadapt_nn.controller.laws.base import law_step_fn
from kinadapt_nn.controller.twocore import compile_two_cores, kernel_opt_level

#: the paper's kinematic gate on lambda_min(W J_hat J_hat^T W) (Results, "A separate kinematic gate")
RANK_GATE = 1e-6
# -- feature kinds ----------------------------------------------------------------------------
FEAT_ADJOINT, FEAT_TWIST, FEAT_JHAT, FEAT_NEURAL, FEAT_RBF = 0, 1, 2, 3, 4
# -- scalar constants: indices into CoreConsts.c -----------------------------------------------
(DT, T_SETTLE, T_TARE0, RAMP, D_STAR, K_D, F_MAX, C_F, C_M, V_MAX, W_MAX, K_NS, DAMP, ALPHA, INV_TAU,
 N_ENTRY, RIGID, DITHER_ON, TWO_PI_F, EXCITE, BLEND, F_GATE, M_GATE, MAX_HOLD, FEAT, RANK_ON, RANK_GATE_V) = range(27)
# small vectors, at these offsets of c
V_N = 27  # bore axis n (3)
V_LNOM = 30  # nominal offset l_nom, f (3)
V_M = 33  # virtual inertia M (6)
V_INVDEN = 39  # 1 / (M + dt D) (6)
V_GRIGID = 45  # rigid loop DC gain g / (1 + beta) (6)
V_W = 51  # channel metric W (6)
V_D = 57  # damping D (6)
V_DITHER = 63  # dither amplitudes (3)
N_C = 66

# -- counters: columns of ControllerState.k (the law's own counters follow, from N_K) -----------
(K_TARE_N, K_TARED, K_PRIMED, K_STARTED, K_HAVE_HELD, K_BAD_RUN, K_DROPOUTS, K_HOLDING, K_ERROR, K_GRAM_N,
 K_DONE) = range(11)
N_K = 11


class Layout:
    """Offsets of the named state blocks in a ``ControllerState.x`` row and of the per-step
    outputs in an ``out`` row (n joints, m channels, p parameters); ``law_sizes`` (nx, nk): the
    law's own float block ``law`` and its counters (``LawSpec.sizes``)."""

    def __init__(self, n: int, m: int, p: int, law_sizes: tuple[int, int] = (0, 0)) -> None:
        self.n, self.m, self.p = n, m, p
        self.law_nx, self.law_nk = law_sizes
        o = 0
        blocks = {}
        for name, size in (("xi", 6), ("q_ref", n), ("q_post", n), ("tare_sum", 6), ("tare", 6),
                           ("filt", (2 + p) * m), ("theta", p), ("gram_sum", p * p), ("unc", 1), ("law", self.law_nx),
                           ("held", 2 * n + 6)):
            blocks[name] = (o, size)
            o += size
        self.x_blocks, self.nx = blocks, o
        o = 0
        outs = {}
        for name, size in (("s", m), ("s_dot_meas", m), ("s_dot_pred", m), ("F", m), ("xi_cmd", 6), ("w_env", 6),
                           ("theta_used", p), ("rho", 1), ("eps_w", m), ("d_track", p), ("d_pred", p), ("gate", 1),
                           ("phi_norm2", 1), ("qdot_ref", n), ("lam_min", 1), ("uncertainty", 1)):
            outs[name] = (o, size)
            o += size
        self.out_blocks, self.nout = outs, o
        # the kernels' view: [n, m, p, law nx, law nk, offsets of x blocks..., offsets of out blocks...]
        self.arr = np.array([n, m, p, self.law_nx, self.law_nk] + [blocks[k][0] for k in blocks]
                            + [outs[k][0] for k in outs], dtype=np.int64)


# offsets into Layout.arr
(L_N, L_M, L_P, L_LNX, L_LNK, X_XI, X_QREF, X_QPOST, X_TSUM, X_TARE, X_FILT, X_TH, X_GRAM, X_UNC, X_LAW, X_HELD,
 O_S, O_SDM, O_SDP, O_F, O_XI, O_WENV, O_TH, O_RHO, O_EPS, O_DTR, O_DPR, O_GATE, O_N2, O_QDR, O_LAM,
 O_UNC) = range(32)


class ControllerState:
    """All filter and law state of B controllers, one owner: ``x`` (B, NX) float rows and ``k``
    (B, N_K + law nk) counters; the named blocks are views into them (shapes with a leading B).
    The law's own state: ``law_x`` (B, nx), ``law_k`` (B, nk), ``unc`` (B,) (``laws.base.law_state``
    names its blocks)."""

    def __init__(self, layout: Layout, B: int) -> None:
        self.layout = layout
        self.x = np.zeros((B, layout.nx))
        self.k = np.zeros((B, N_K + layout.law_nk), dtype=np.int64)
        m, p = layout.m, layout.p
        shapes = {"filt": (2 + p, m), "gram_sum": (p, p)}
        for name, (o, size) in layout.x_blocks.items():
            setattr(self, name, self.x[:, o:o + size].reshape((B, *shapes.get(name, (size,)))))
        # the filter rows: y (rate filter of s), known_f, Phi_f^T
        self.y, self.known_f, self.Phi_fT = self.filt[:, 0], self.filt[:, 1], self.filt[:, 2:]
        self.law_x, self.law_k, self.unc = self.law, self.k[:, N_K:], self.unc[:, 0]


@dataclass(frozen=True)
class CoreConsts:
    """The known constants the kernels read (built once by the wrappers)."""

    c: np.ndarray  #: (N_C,) scalars and small vectors (indices above)
    mats: np.ndarray  #: (2, 6, 6): S; G (row 0 zero, s[1:] = G[1:] w_env)
    pv: np.ndarray  #: (3, p): Omega's lo, hi; the tracking term's row mask
    lc: np.ndarray  #: (nc,) the law's own constants (``LawSpec.constants``)
    #: (1,) int64: the law step's native address (``LawSpec.address``), valid only in the process
    #: that built it (and its forks): never save it or send it to another process
    law_fn: np.ndarray
    seg: np.ndarray  #: (nseg, 7): excite program [end time s, twist (6)]


# ================================================================================================
@nb.njit(cache=True)
def intake_kernel(inp, x, k, lay, c):
    """Hold non-finite samples: ``inp`` (B, 2n+6) = [q; qdot; wrench] is replaced in place by the
    last valid sample (or a zero wrench before any); flags K_HOLDING, K_ERROR (dropout too long)."""
    for b in range(inp.shape[0]):
        _intake(b, inp, x, k, lay, c)


@nb.njit(cache=True)
def _intake(b, inp, x, k, lay, c):
    """Episode b's sample: kept (and remembered) when finite, else the last valid one is held."""
    n = lay[L_N]
    hd = lay[X_HELD]
    enc, wr = 0.0, 0.0
    for i in range(2 * n):
        enc += inp[b, i] * inp[b, i]
    for i in range(2 * n, 2 * n + 6):
        wr += inp[b, i] * inp[b, i]
    k[b, K_HOLDING] = 0
    if math.isfinite(enc + wr):
        k[b, K_BAD_RUN] = 0
        vcopy(x[b, hd:hd + 2 * n + 6], inp[b])
        k[b, K_HAVE_HELD] = 1
        return
    k[b, K_DROPOUTS] += 1
    k[b, K_BAD_RUN] += 1
    if k[b, K_BAD_RUN] > c[MAX_HOLD] or not (k[b, K_HAVE_HELD] == 1 or math.isfinite(enc)):
        k[b, K_ERROR] = 1
        return
    k[b, K_HOLDING] = 1
    if k[b, K_HAVE_HELD] == 1:
        vcopy(inp[b], x[b, hd:hd + 2 * n + 6])
    else:  # the very first samples: valid encoders, no valid wrench yet -> zero wrench, no tare
        vfill(inp[b, 2 * n:], 0.0)


@nb.njit(cache=True)
def _sense(t, b, inp, p_O, R, x, k, lay, c, mats, out):
    """Tare, w_env and s of episode b (written to out); returns rho."""
    n = lay[L_N]
    q, wrench = inp[b, :n], inp[b, 2 * n:2 * n + 6]
    xs, o = x[b], out[b]
    if k[b, K_STARTED] == 0:  # the first sample: the joint reference and the posture start at q
        vcopy(xs[lay[X_QREF]:lay[X_QREF] + n], q)
        vcopy(xs[lay[X_QPOST]:lay[X_QPOST] + n], q)
        k[b, K_STARTED] = 1
    w_env = o[lay[O_WENV]:lay[O_WENV] + 6]
    tare = xs[lay[X_TARE]:lay[X_TARE] + 6]
    if t < c[T_SETTLE]:  # tare: average the free-space reading (tool weight) while holding still
        if t >= c[T_TARE0] and k[b, K_HOLDING] == 0:
            for i in range(6):
                xs[lay[X_TSUM] + i] += wrench[i]
            k[b, K_TARE_N] += 1
        rho = 0.0
        vfill(w_env, 0.0)
    else:
        if k[b, K_TARED] == 0:
            for i in range(6):
                tare[i] = xs[lay[X_TSUM] + i] / max(k[b, K_TARE_N], 1)
            k[b, K_TARED] = 1
        rho = min(1.0, (t - c[T_SETTLE]) / c[RAMP]) if c[RAMP] > 0 else 1.0
        Rb = R[b]
        for i in range(3):  # tool -> environment, world, about O: [R (r_f - r0_f); R (r_m - r0_m)]
            w_env[i] = (Rb[i, 0] * (wrench[0] - tare[0]) + Rb[i, 1] * (wrench[1] - tare[1])
                        + Rb[i, 2] * (wrench[2] - tare[2]))
            w_env[3 + i] = (Rb[i, 0] * (wrench[3] - tare[3]) + Rb[i, 1] * (wrench[4] - tare[4])
                            + Rb[i, 2] * (wrench[5] - tare[5]))
    s = o[lay[O_S]:lay[O_S] + 6]
    G = mats[1]
    for i in range(1, 6):  # F_lat = -P f_env ; M = -m_env
        v = 0.0
        for j in range(6):
            v += G[i, j] * w_env[j]
        s[i] = v
    dep = -c[N_ENTRY]
    for i in range(3):  # d = n . (p_O + R l_nom) - n . p_entry
        lw = R[b, i, 0] * c[V_LNOM] + R[b, i, 1] * c[V_LNOM + 1] + R[b, i, 2] * c[V_LNOM + 2]
        dep += c[V_N + i] * (p_O[b, i] + lw)
    s[0] = dep
    o[lay[O_RHO]] = rho
    return rho


@nb.njit(cache=True)
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


@nb.njit(cache=True)
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
def _excite_drive(t_rel, b, R, c, seg, drive):
    """D xi_ref of the excitation program (Controller.excite_twist, moved from the tip to O)."""
    x = np.zeros(6)
    ns = seg.shape[0]
    if t_rel >= 0.0 and ns > 0:
        kk = 0
        while kk < ns and seg[kk, 0] <= t_rel:
            kk += 1
        start = seg[kk - 1, 0] if kk > 0 else 0.0
        for i in range(6):
            cur = seg[kk, 1 + i] if kk < ns else 0.0
            prev = seg[kk - 1, 1 + i] if kk > 0 else 0.0
            if c[BLEND] > 0.0 and t_rel - start < c[BLEND]:  # linear blend: bounded acceleration
                x[i] = prev + (t_rel - start) / c[BLEND] * (cur - prev)
            else:
                x[i] = cur
    l0, l1, l2 = _lever(b, R, c)
    x[0] -= x[4] * l2 - x[5] * l1  # v_O = v_tip - omega x (R l_nom)
    x[1] -= x[5] * l0 - x[3] * l2
    x[2] -= x[3] * l1 - x[4] * l0
    for i in range(6):
        drive[i] = c[V_D + i] * x[i]


@nb.njit(cache=True)
def _act_head(b, J, x, k, lay, c, out):
    """Rate filter and value force of episode b (after ``_sense``), written to ``out``; returns
    the Cholesky factor L (6, 6) of J J^T + damp I for :func:`_act_tail`."""
    n, m, p = lay[L_N], lay[L_M], lay[L_P]
    xs, o = x[b], out[b]
    filt = xs[lay[X_FILT]:lay[X_FILT] + (2 + p) * m].reshape((2 + p, m))
    s = o[lay[O_S]:lay[O_S] + m]
    sdm = o[lay[O_SDM]:lay[O_SDM] + m]
    F = o[lay[O_F]:lay[O_F] + m]
    theta = xs[lay[X_TH]:lay[X_TH] + p]
    vcopy(o[lay[O_TH]:lay[O_TH] + p], theta)
    # -- the rate filter (sensing.RateFilter): s_dot_meas = (s - y) / (tau + dt); y += alpha (s - y)
    if k[b, K_PRIMED] == 0:
        vcopy(filt[0], s)
        k[b, K_PRIMED] = 1
    for i in range(m):
        sdm[i] = (s[i] - filt[0, i]) * c[INV_TAU]  # s_dot_meas = (s - y) / (tau + dt)
        filt[0, i] += c[ALPHA] * (s[i] - filt[0, i])
    # -- value force, eq. ft_force: F = -grad V = [-sat(k_d (d - d*)); -c_F F_lat; -c_M M]
    F[0] = -min(max(c[K_D] * (s[0] - c[D_STAR]), -c[F_MAX]), c[F_MAX])
    F[1], F[2] = -c[C_F] * s[1], -c[C_F] * s[2]
    F[3], F[4], F[5] = -c[C_M] * s[3], -c[C_M] * s[4], -c[C_M] * s[5]
    # -- L L^T = J J^T + damp I (J^+ = J^T (J J^T + damp I)^-1)
    Jb = J[b]
    Lc = np.empty((6, 6))
    for i in range(6):
        for j in range(i + 1):
            v = 0.0
            for r in range(n):
                v += Jb[i, r] * Jb[j, r]
            Lc[i, j] = v
        Lc[i, i] += c[DAMP]
    chol(Lc, 6)
    return Lc


@nb.njit(cache=True)
def _ext_drive(b, J, Lc, ext_J, lay, c, out, drive):
    """The drive J_hat_xi^T F from the features' ``ext_J`` (FEAT_TWIST: J_hat_xi (m, 6); else
    J_hat (m, n): J_hat_xi^T F = (J J^T + damp)^-1 J J_hat^T F)."""
    m = lay[L_M]
    F = out[b, lay[O_F]:lay[O_F] + m]
    if int(c[FEAT]) == FEAT_TWIST:
        for j in range(6):
            v = 0.0
            for i in range(m):
                v += ext_J[b, i, j] * F[i]
            drive[j] = v
        return
    _jhat_drive(b, J, Lc, ext_J[b], lay, out, drive)


@nb.njit(cache=True)
def _act_tail(t, b, rho, drive, Lc, inp, J, x, lay, c, out):
    """eq. cp_admittance with the drive J_hat_xi^T F (read with theta before this step's law
    update), the speed limits, the dither and the joint reference of episode b."""
    n = lay[L_N]
    xs, o = x[b], out[b]
    w_env = o[lay[O_WENV]:lay[O_WENV] + 6]
    Jb = J[b]
    # -- eq. cp_admittance: M (xi+ - xi)/dt + D xi+ = rho drive - w_env (implicit in the damping)
    xi = xs[lay[X_XI]:lay[X_XI] + 6]
    for i in range(6):
        if c[RIGID] > 0.0:  # eq. ft_control: the commanded twist is realised, no contact feedback
            xi[i] = c[V_GRIGID + i] * rho * drive[i]
        else:
            xi[i] = (c[V_M + i] * xi[i] + c[DT] * (rho * drive[i] - w_env[i])) * c[V_INVDEN + i]
    vn = math.sqrt(xi[0] * xi[0] + xi[1] * xi[1] + xi[2] * xi[2])
    if vn > c[V_MAX]:
        for i in range(3):
            xi[i] *= c[V_MAX] / vn
    wn = math.sqrt(xi[3] * xi[3] + xi[4] * xi[4] + xi[5] * xi[5])
    if wn > c[W_MAX]:
        for i in range(3, 6):
            xi[i] *= c[W_MAX] / wn
    xc = o[lay[O_XI]:lay[O_XI] + 6]
    vcopy(xc, xi)
    if c[DITHER_ON] > 0.0 and rho > 0.0:  # commanded excitation (Remark ft_excitation), not stored
        ph = c[TWO_PI_F] * (t - c[T_SETTLE])
        xc[3] += rho * c[V_DITHER] * math.sin(ph)
        xc[4] += rho * c[V_DITHER + 1] * math.cos(ph)
        xc[5] += rho * c[V_DITHER + 2] * math.sin(1.7 * ph)
    # -- joint reference: qdot_ref = J^T y + z, (J J^T + damp) y = xi - J z, z = k_ns (q_0 - q)
    q = inp[b, :n]
    qpost = xs[lay[X_QPOST]:lay[X_QPOST] + n]
    z = np.empty(n)
    for j in range(n):
        z[j] = (qpost[j] - q[j]) * c[K_NS]
    y = np.empty(6)
    for i in range(6):
        v = 0.0
        for j in range(n):
            v += Jb[i, j] * z[j]
        y[i] = xc[i] - v
    chol_solve(Lc, 6, y)
    qdr = o[lay[O_QDR]:lay[O_QDR] + n]
    qref = xs[lay[X_QREF]:lay[X_QREF] + n]
    for j in range(n):
        v = 0.0
        for i in range(6):
            v += y[i] * Jb[i, j]
        qdr[j] = v + z[j]
        qref[j] = qref[j] + c[DT] * qdr[j]


@nb.njit(cache=True)
def _filter_regressor(b, reg, x, lay, c):
    """known_f, Phi_f^T += alpha (input - state) (the same filter as the measured rate)."""
    m, p = lay[L_M], lay[L_P]
    filt = x[b, lay[X_FILT]:lay[X_FILT] + (2 + p) * m].reshape((2 + p, m))
    for r in range(1 + p):
        for i in range(m):
            filt[1 + r, i] += c[ALPHA] * (reg[b, r, i] - filt[1 + r, i])


@nb.njit(cache=True)
def _law(b, reg, x, k, lay, c, pv, lc, law_fn, out):
    """The law-independent part of a law step on this step's filtered rows -- a held sample adapts
    nothing; eq. ft_pred; the contact gate; the Gram log; Phi_r^T F on the tracking rows -- then,
    in contact, the law's own step (``laws.base``: the step contract) at address ``law_fn[0]``;
    theta_{k+1} is written to the state (used next step)."""
    m, p = lay[L_M], lay[L_P]
    xs, o = x[b], out[b]
    filt = xs[lay[X_FILT]:lay[X_FILT] + (2 + p) * m].reshape((2 + p, m))
    known_f, Phi_fT = filt[1], filt[2:]
    theta = xs[lay[X_TH]:lay[X_TH] + p]
    sdm, F = o[lay[O_SDM]:lay[O_SDM] + m], o[lay[O_F]:lay[O_F] + m]
    pred, eps = o[lay[O_SDP]:lay[O_SDP] + m], o[lay[O_EPS]:lay[O_EPS] + m]
    d_track, d_pred = o[lay[O_DTR]:lay[O_DTR] + p], o[lay[O_DPR]:lay[O_DPR] + p]
    vfill(d_track, 0.0)
    vfill(d_pred, 0.0)
    o[lay[O_GATE]] = 0.0
    o[lay[O_N2]] = 0.0
    if k[b, K_HOLDING] == 1:  # a held sample carries no new information: theta stays
        vcopy(pred, sdm)
        vfill(eps, 0.0)
        return
    W = c[V_W:V_W + m]
    for i in range(m):  # eq. ft_pred: e = W (s_dot_meas - (known_f + Phi_f theta))
        v = 0.0
        for j in range(p):
            v += theta[j] * Phi_fT[j, i]
        pred[i] = v + known_f[i]
        eps[i] = (sdm[i] - pred[i]) * W[i]
    w_env = o[lay[O_WENV]:lay[O_WENV] + 6]
    fn = math.sqrt(w_env[0] ** 2 + w_env[1] ** 2 + w_env[2] ** 2)
    mn = math.sqrt(w_env[3] ** 2 + w_env[4] ** 2 + w_env[5] ** 2)
    if not (fn >= c[F_GATE] or mn >= c[M_GATE]):  # free space: gate g_k = 0
        return
    o[lay[O_GATE]] = 1.0
    Phi_wT = np.empty((p, m))  # (W Phi_f)^T
    for j in range(p):
        for i in range(m):
            Phi_wT[j, i] = Phi_fT[j, i] * W[i]
    # G (p, p) = (W Phi_f)^T (W Phi_f), added to the observability log <Phi^T Phi> over the contact phase
    G = gram_sparse_log(Phi_wT, xs[lay[X_GRAM]:lay[X_GRAM] + p * p].reshape((p, p)))
    k[b, K_GRAM_N] += 1
    lo, hi, mask = pv[0], pv[1], pv[2]
    PhiF = np.zeros(p)  # Phi_r^T F, on the realised (unfiltered) regressor, tracking rows only
    for j in range(p):
        v = 0.0
        for i in range(m):
            v += reg[b, 1 + j, i] * F[i]
        PhiF[j] = v * mask[j]
    step = law_step_fn(law_fn[0])
    lx, lk = lay[X_LAW], N_K + lay[L_LNK]
    o[lay[O_N2]] = step(theta, Phi_wT, G, eps, PhiF, lo, hi, lc, xs[lx:lx + lay[L_LNX]], k[b, N_K:lk],
                        xs[lay[X_UNC]:lay[X_UNC] + 1], d_track, d_pred)


@nb.njit(cache=True)
def law_kernel(reg, x, k, lay, c, pv, lc, law_fn, out):
    """The law alone for B episodes (``controller.standalone.StandaloneLaw``): filter the regressor
    rows ``reg`` (B, 1+p, m) and step the law, as ``act_kernel`` does; ``out`` holds this step's
    s_dot_meas, F and w_env."""
    for b in range(reg.shape[0]):
        _filter_regressor(b, reg, x, lay, c)
        _law(b, reg, x, k, lay, c, pv, lc, law_fn, out)
        out[b, lay[O_UNC]] = x[b, lay[X_UNC]]


@nb.njit(cache=True)
def _rank_margin_adjoint(b, R, J, x, lay, c, mats, out):
    """The rank gate of the next step's J_hat = S Ad(R theta) J."""
    theta = x[b, lay[X_TH]:lay[X_TH] + 3]
    _rank_margin(b, mm(_adjoint_twist_jacobian(b, R, theta, c, mats), J[b]), c, out, lay)


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
    return mm(_adjoint_twist_jacobian(b, R, fx[2:5], c, mats), J[b])


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


@nb.njit(cache=True)
def _adjoint_twist_jacobian(b, R, theta, c, mats):
    """S Ad(R theta) (6, 6) with the depth row on the nominal lever (AdjointFeatures.twist_jacobian)."""
    S = mats[0]
    Rb = R[b]
    a = np.empty(3)
    for i in range(3):
        a[i] = Rb[i, 0] * theta[0] + Rb[i, 1] * theta[1] + Rb[i, 2] * theta[2]
    l0, l1, l2 = _lever(b, R, c)
    Jx = np.empty((6, 6))  # S Ad(l) = [S_v, S_w - S_v [l]x]
    for i in range(6):
        vcopy(Jx[i], S[i])
    for i in range(6):
        if i == 0:
            v0, v1, v2, a0, a1, a2 = S[0, 0], S[0, 1], S[0, 2], l0, l1, l2
        else:
            v0, v1, v2, a0, a1, a2 = S[i, 0], S[i, 1], S[i, 2], a[0], a[1], a[2]
        Jx[i, 3] -= v1 * a2 - v2 * a1  # row i of S_v [a]x is v^T [a]x = (v x a)^T
        Jx[i, 4] -= v2 * a0 - v0 * a2
        Jx[i, 5] -= v0 * a1 - v1 * a0
    return Jx


@nb.njit(cache=True)
def _rank_margin(b, Jh, c, out, lay):
    """lambda_min(W J_hat J_hat^T W) (the rank gate); with RANK_ON = 2 only the gate (Cholesky)."""
    WJ = np.empty(Jh.shape)
    for i in range(6):
        for j in range(Jh.shape[1]):
            WJ[i, j] = Jh[i, j] * c[V_W + i]
    G = mm_nt(WJ, WJ)
    if c[RANK_ON] == 2.0:  # gate only: lambda_min > gate  <=>  G - gate I is positive definite
        for i in range(6):
            G[i, i] -= c[RANK_GATE_V]
        if chol(G, 6):
            out[b, lay[O_LAM]] = np.inf
            return
        G = mm_nt(WJ, WJ)
    out[b, lay[O_LAM]] = sym_eigmin(G)


# ================================================================================================
@nb.njit(cache=True)
def sense_kernel(t, inp, p_O, R, x, k, lay, c, mats, out):
    """Tare, w_env, s for every episode (the generic path: features run in Python next)."""
    for b in range(inp.shape[0]):
        if k[b, K_ERROR] == 0:
            _sense(t, b, inp, p_O, R, x, k, lay, c, mats, out)


@nb.njit(cache=True)
def act_kernel(t, inp, p_O, R, J, reg, ext_J, x, k, lay, c, mats, pv, lc, law_fn, seg, out):
    """The rest of the step after ``sense_kernel`` for features computed in Python: the regressor
    rows ``reg`` (B, 1+p, m) = [known; Phi^T] and ``ext_J`` (J_hat_xi: FEAT_TWIST, or J_hat:
    FEAT_JHAT) (``lc``, ``law_fn``: the law's constants and its step's address)."""
    for b in range(inp.shape[0]):
        if k[b, K_ERROR] != 0 or k[b, K_DONE] != 0:  # diverged, or a batch episode that has stopped
            continue
        _filter_regressor(b, reg, x, lay, c)
        rho = out[b, lay[O_RHO]]
        Lc = _act_head(b, J, x, k, lay, c, out)
        drive = np.empty(6)
        if c[EXCITE] > 0.0:  # the scripted program replaces V's drive (control.program = "excite")
            _excite_drive(t - c[T_SETTLE], b, R, c, seg, drive)
        else:
            _ext_drive(b, J, Lc, ext_J, lay, c, out, drive)
        _act_tail(t, b, rho, drive, Lc, inp, J, x, lay, c, out)
        _law(b, reg, x, k, lay, c, pv, lc, law_fn, out)
        out[b, lay[O_UNC]] = x[b, lay[X_UNC]]  # theta's remaining uncertainty (the law's; NaN: none)


@nb.njit(cache=True)
def _front(t, b, inp, chain, p_O, R, J, x, k, lay, c, mats, out):
    """Intake (dropout hold), forward kinematics of the bare arm and sense of episode b; False
    when it has diverged (nothing more this step)."""
    if k[b, K_ERROR] == 0:
        _intake(b, inp, x, k, lay, c)
    if k[b, K_ERROR] != 0:
        return False
    nbody = chain.shape[0] - 1
    _fk(chain[:nbody], chain[nbody], inp[b], p_O[b], R[b], J[b])
    _sense(t, b, inp, p_O, R, x, k, lay, c, mats, out)
    return True


@nb.njit(cache=True)
def step_adjoint(t, inp, chain, p_O, R, J, reg, x, k, lay, c, mats, pv, lc, law_fn, seg, fx, out):
    """One whole period for B episodes with the adjoint features (one dispatch): intake,
    forward kinematics of the bare arm, sense, regressor, act, law, rank gate (``fx``: unused,
    the fused kernels share one signature)."""
    p = lay[L_P]
    for b in range(inp.shape[0]):
        if k[b, K_DONE] != 0 or not _front(t, b, inp, chain, p_O, R, J, x, k, lay, c, mats, out):
            continue
        _adjoint_regressor(b, inp, R, J, lay, c, mats, reg[b, 0], reg[b, 1:])
        _filter_regressor(b, reg, x, lay, c)
        rho = out[b, lay[O_RHO]]
        Lc = _act_head(b, J, x, k, lay, c, out)
        drive = np.empty(6)
        if c[EXCITE] > 0.0:
            _excite_drive(t - c[T_SETTLE], b, R, c, seg, drive)
        else:
            _adjoint_drive(b, R, x[b, lay[X_TH]:lay[X_TH] + p], out[b, lay[O_F]:lay[O_F] + 6], c, mats, drive)
        _act_tail(t, b, rho, drive, Lc, inp, J, x, lay, c, out)
        _law(b, reg, x, k, lay, c, pv, lc, law_fn, out)
        out[b, lay[O_UNC]] = x[b, lay[X_UNC]]
        if c[RANK_ON] > 0.0 and rho > 0.0:  # the rank gate on the next step's J_hat
            _rank_margin_adjoint(b, R, J, x, lay, c, mats, out)


@nb.njit(cache=True)
def step_neural(t, inp, chain, p_O, R, J, reg, x, k, lay, c, mats, pv, lc, law_fn, seg, fx, out):
    """``step_adjoint`` for the neural basis (``fx``: ``neural_consts``): Y(q) once per step for
    the regressor, J_hat for the drive and the rank gate."""
    n, p = lay[L_N], lay[L_P]
    for b in range(inp.shape[0]):
        if k[b, K_DONE] != 0 or not _front(t, b, inp, chain, p_O, R, J, x, k, lay, c, mats, out):
            continue
        Y = _neural_body(fx, inp[b, :n], n)
        _neural_rows(b, inp, R, J, Y, lay, c, mats, fx, reg[b, 0], reg[b, 1:])
        Kq = _jhat_prior(b, R, J, c, mats, fx)  # once: the drive's J_hat and the rank gate's share it
        Jh = _neural_jhat(Kq, Y, x[b, lay[X_TH]:lay[X_TH] + p])
        _filter_regressor(b, reg, x, lay, c)
        rho = out[b, lay[O_RHO]]
        Lc = _act_head(b, J, x, k, lay, c, out)
        drive = np.empty(6)
        if c[EXCITE] > 0.0:
            _excite_drive(t - c[T_SETTLE], b, R, c, seg, drive)
        else:  # J_hat (m, n): J_hat_xi^T F = (J J^T + damp)^-1 J J_hat^T F
            _jhat_drive(b, J, Lc, Jh, lay, out, drive)
        _act_tail(t, b, rho, drive, Lc, inp, J, x, lay, c, out)
        _law(b, reg, x, k, lay, c, pv, lc, law_fn, out)
        out[b, lay[O_UNC]] = x[b, lay[X_UNC]]
        if c[RANK_ON] > 0.0 and rho > 0.0:
            _rank_margin(b, _neural_jhat(Kq, Y, x[b, lay[X_TH]:lay[X_TH] + p]), c, out, lay)


@nb.njit(cache=True)
def step_rbf(t, inp, chain, p_O, R, J, reg, x, k, lay, c, mats, pv, lc, law_fn, seg, fx, out):
    """``step_neural`` for the per-entry Gaussian RBF (``fx``: ``rbf_consts``): psi(q) once per
    step for the regressor, J_hat for the drive and the rank gate."""
    n, p = lay[L_N], lay[L_P]
    for b in range(inp.shape[0]):
        if k[b, K_DONE] != 0 or not _front(t, b, inp, chain, p_O, R, J, x, k, lay, c, mats, out):
            continue
        psi = _rbf_psi(fx, inp[b, :n], n)
        _rbf_rows(b, inp, R, J, psi, lay, c, mats, fx, reg[b, 0], reg[b, 1:])
        Kq = _jhat_prior(b, R, J, c, mats, fx)
        Jh = _rbf_jhat(Kq, psi, x[b, lay[X_TH]:lay[X_TH] + p])
        _filter_regressor(b, reg, x, lay, c)
        rho = out[b, lay[O_RHO]]
        Lc = _act_head(b, J, x, k, lay, c, out)
        drive = np.empty(6)
        if c[EXCITE] > 0.0:
            _excite_drive(t - c[T_SETTLE], b, R, c, seg, drive)
        else:
            _jhat_drive(b, J, Lc, Jh, lay, out, drive)
        _act_tail(t, b, rho, drive, Lc, inp, J, x, lay, c, out)
        _law(b, reg, x, k, lay, c, pv, lc, law_fn, out)
        out[b, lay[O_UNC]] = x[b, lay[X_UNC]]
        if c[RANK_ON] > 0.0 and rho > 0.0:
            _rank_margin(b, _rbf_jhat(Kq, psi, x[b, lay[X_TH]:lay[X_TH] + p]), c, out, lay)


# step_adjoint, step_neural, step_rbf and act_kernel spell out the same act / law sequence around their own
# drive on purpose: one more helper level (measured: _begin_act / _end_act) adds ~3 s to a first
# run's compile, because numba optimises and emits a callee's code again in every caller
#: the fused step kernel of each in-kernel features kind (FEAT_ADJOINT, FEAT_NEURAL, FEAT_RBF); each compiles
#: only its own features' code, on first use
FUSED = {FEAT_ADJOINT: step_adjoint, FEAT_NEURAL: step_neural, FEAT_RBF: step_rbf}


@nb.njit(cache=True)
def _jhat_drive(b, J, Lc, Jh, lay, out, drive):
    """J_hat_xi^T F = (J J^T + damp)^-1 J J_hat^T F for J_hat (m, n)."""
    n, m = lay[L_N], lay[L_M]
    F = out[b, lay[O_F]:lay[O_F] + m]
    g = np.zeros(n)
    for j in range(n):
        for i in range(m):
            g[j] += Jh[i, j] * F[i]
    for i in range(6):
        v = 0.0
        for j in range(n):
            v += J[b, i, j] * g[j]
        drive[i] = v
    chol_solve(Lc, 6, drive)


# ================================================================================================
# forward kinematics of the bare arm in the kernel (a chain of hinges; mj_kinematics' formulas)
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


#: [s] the one-time compile of the adjoint's step kernel and the kalman law (two processes), measured
#: on the 2-core CI VM (bench_first_run.py); the estimate shown until this machine has measured its
#: own (``compile_record``)
COMPILE_ESTIMATE_S = 17.0


def _compile_record_path():
    """Where the last measured compile time is kept: numba's cache folder for this module
    (``NUMBA_CACHE_DIR`` when set, else ``__pycache__`` beside this file, else numba's user-wide one)."""
    folder = compiled.cache_dir(step_adjoint)
    return None if folder is None else folder / "kinadapt_compile_s.json"


def compile_record() -> float:
    """[s] this machine's last measured compile of the kernels, else :data:`COMPILE_ESTIMATE_S`."""
    import json

    path = _compile_record_path()
    try:
        return float(json.loads(path.read_text())["seconds"])
    except Exception:
        return COMPILE_ESTIMATE_S


_COMPILING = [False]  # a compile phase is open (nested phases add nothing)


class compiling:
    """Context manager: the one-time compile phase of a run (the law's step, built with the
    controller, and the step kernels). With ``progress`` and a cold cache it is one bar in seconds
    against the expected compile time (this machine's last measured one, else
    :data:`COMPILE_ESTIMATE_S`) and, at the end, one line with the measured time, which is recorded
    for the next estimate. A warm cache shows nothing."""

    def __init__(self, progress: bool = False) -> None:
        self.progress = progress
        self.wall_s = 0.0
        self._cold = False

    @property
    def cold(self) -> bool:
        """True when this phase compiled (the outermost phase, a cold cache): its ``wall_s`` is then
        the one-time compile, not the loading of cached code."""
        return self._cold

    def __enter__(self) -> "compiling":
        import threading
        import time

        self._outer = not _COMPILING[0]
        if self._outer:  # numba checks a kernel's own file only: drop code cached with an edited callee
            drop_stale_kernels()
        self._cold = self._outer and not kernels_cached()
        _COMPILING[0] = True
        self._t0 = time.perf_counter()
        self._stop = threading.Event()
        self._bar = None
        if self.progress and self._cold:
            self._tick_honestly(compile_record())
        return self

    def _tick_honestly(self, expected_s: float) -> None:
        """One status line, refreshed twice a second: the time spent and the last measured
        compile -- no percentage (numba does not say how far it is, and a loaded machine
        compiles slower than the last time)."""
        import threading
        import time

        from tqdm import tqdm

        bar = self._bar = tqdm(total=None, leave=False, bar_format="{desc}",
                               desc="compiling the controller (first run only, cached after)")
        t0, stop = self._t0, self._stop

        def tick() -> None:
            while not stop.wait(0.5):
                dt = time.perf_counter() - t0
                more = "" if dt <= expected_s else ", still compiling"
                bar.set_description_str(f"compiling the controller (first run only, cached after): {dt:4.0f} s "
                                        f"so far (the last compile here took {expected_s:.0f} s{more})")

        threading.Thread(target=tick, daemon=True).start()

    def __exit__(self, *exc) -> None:
        import json
        import sys
        import time

        self.wall_s = time.perf_counter() - self._t0
        if not self._outer:
            return
        _COMPILING[0] = False
        self._stop.set()
        if self._bar is not None:
            self._bar.close()
        if self._cold and exc[0] is None:
            try:
                _compile_record_path().write_text(json.dumps({"seconds": round(self.wall_s, 2)}))
            except Exception:  # a read-only cache location: the next estimate stays the default
                pass
            if self.progress:
                print(f"compiled the controller's kernels in {self.wall_s:.0f} s (cached: later runs start at once)",
                      file=sys.stderr, flush=True)


def compile_calls(calls, progress: bool = False, law=None) -> float:
    """Compile (or load from numba's cache) each ``(name, dispatcher, args)`` for the types of
    ``args``, inside a :class:`compiling` phase; ``law`` (a ``LawSpec``): its step too. A cold
    cache is compiled by two processes (``twocore.compile_two_cores``: the kernels' callees shared,
    then the law's step there while the kernels compile here; else the law's step alone aside,
    ``LawSpec.compile_aside``); the law is loaded here after. -> wall seconds."""
    with compiling(progress) as phase, kernel_opt_level():  # LLVM at level 1: the same code, compiled sooner
        if not compile_two_cores(calls, law):  # a cold cache: the kernels' callees on two cores
            aside = law.compile_aside() if law is not None else None
            try:
                for _name, fn, args in calls:
                    compiled.compile_for(fn, args)
            finally:
                if aside is not None:
                    aside.wait()
        if law is not None:
            law.address()  # (from the cache the second process wrote; compiled here if it failed)
    return phase.wall_s


def entry_point(fn, args):
    """The machine code's entry of the compiled ``fn`` for the numba types of ``args`` (the
    dispatcher's type resolution skipped): only for arguments whose types never change (a
    controller's own buffers, ``t`` a float); the dispatcher itself when ``fn`` is not compiled for
    them (``compiled.entry_point``)."""
    return compiled.entry_point(fn, args)


def calls_cached(calls, law=None) -> bool:
    """True when every ``(name, dispatcher, args)`` of ``calls`` (for the types of ``args``) and
    ``law``'s step (a ``LawSpec``) are in numba's on-disk cache, so a process can load them
    instead of compiling; False when not, or when that cannot be told."""
    from kinadapt_nn.controller.laws.base import STEP_SIG

    if law is not None and not law._address and not compiled.in_cache(law.step, STEP_SIG):
        return False
    return all(compiled.in_cache(fn, compiled.signature_of(args)) for _name, fn, args in calls)


#: more kernels a compile phase must find cached to be warm (``cache_probe``: the episode loop's)
_CACHE_PROBES: list = []


def cache_probe(dispatchers) -> None:
    """Register numba dispatchers (a layer above this one: the episode loop's, the scenes') that
    :func:`kernels_cached` checks too, so that a compile phase that compiles them is cold and shown."""
    _CACHE_PROBES.extend(dispatchers)


def kernels_cached() -> bool:
    """True when the step kernel's compiled code (and every :func:`cache_probe` kernel's) is in
    numba's on-disk cache (the first run on a machine compiles it, once); True also when that
    cannot be told (no message then)."""
    told = [compiled.cached_any(f) for f in (step_adjoint, *_CACHE_PROBES)]
    return None in told or all(told)  # None: numba's cache internals moved, say nothing


def _controller_kernels() -> list:
    """Every numba kernel of the controller's loaded modules (``core``, ``dense``, the laws')."""
    import sys

    mods = [m for name, m in list(sys.modules.items()) if name.startswith("kinadapt_nn.controller") and m is not None]
    return [f for m in mods for f in vars(m).values()
            if compiled.is_kernel(f) and f.py_func.__module__ == m.__name__]


def drop_stale_kernels() -> bool:
    """Drop the controller kernels' cached code when any of the controller's source files changed
    since it was cached (``compiled.invalidate_stale``: numba itself checks a kernel's own file
    only, and a cached kernel holds its callees from other files). -> True when some was dropped."""
    from pathlib import Path

    kernels = _controller_kernels()
    sources = {Path(f.py_func.__code__.co_filename) for f in kernels}  # the files that define them
    return compiled.invalidate_stale(kernels, sources, step_adjoint)
