"""The controller's step sequence for B episodes (numba kernels): intake, sense, act (rate filter,
value force, drive, admittance, joint reference), the law-independent part of a law step, the rank
gate; and the kernels that run it (``step_adjoint``, ``step_neural``, ``step_rbf``: one dispatch
per period; ``sense_kernel`` / ``act_kernel`` around features computed in Python; ``law_kernel``
for ``StandaloneLaw``). ``controller/core.py`` describes the sequence; the constants and state
they index are declared in ``controller/layout.py``.

The sequence is written once (``_step``); what a features kind changes in it is four small parts
(front, rows, drive, rank gate), and each kernel is ``_step``'s code compiled with its kind's parts
(``_kernel``): the code numba emits is what the sequence written out per kind gave (one level, the
parts called directly), so speed and compile time are unchanged and each kind compiles only its own.

The small parts a period calls once per episode -- intake, sense, the regressor filter and the
adjoint's regressor and drive (``features_kernels``) -- are inlined by numba (``inline="always"``):
a call passes each array as 7-11 values, which cost more than these parts' arithmetic; the same
numbers to the bit, and the cold compile as long (benchmarks/results/
bench_batch_2026-11-29_small_products.txt). Inlining more (``_front``, the rank gate's parts) ran
the kernel ~0.15 us per episode-step faster and compiled ~2 s longer; ``_act_head``, ``_act_tail``,
``_law`` and the law's own parts, no faster and seconds longer: not inlined.
"""

from __future__ import annotations

import math
import types

import numba as nb
import numpy as np
from numba import types as nbt

from kinadapt_nn.controller.arm_chain import _fk
from kinadapt_nn.controller.dense import (chol, chol_solve, gram_lower, gram_sparse_log, mirror_lower, sym_eigmin, vcopy,
                                          vfill)
from kinadapt_nn.controller.features_kernels import (_adjoint_drive, _adjoint_regressor, _adjoint_twist_jacobian,
                                                     _jhat_prior, _lever, _neural_body, _neural_jhat, _neural_rows,
                                                     _rbf_jhat, _rbf_psi, _rbf_rows, _twist_jacobian_times)
from kinadapt_nn.controller.layout import (ALPHA, BLEND, C_F, C_M, DAMP, DITHER_ON, DT, D_STAR, EXCITE, FEAT,
                                           FEAT_ADJOINT, FEAT_NEURAL, FEAT_RBF, FEAT_TWIST, F_GATE, F_MAX, INV_TAU,
                                           K_BAD_RUN, K_D, K_DONE, K_DROPOUTS, K_ERROR, K_GRAM_N, K_HAVE_HELD,
                                           K_HOLDING, K_NS, K_PAUSED, K_PRIMED, K_STARTED, K_TARED, K_TARE_N, L_LNK,
                                           L_LNX, L_M, L_N, L_P, MAX_HOLD, M_GATE, N_ENTRY, N_K, O_DPR, O_DTR, O_EPS,
                                           O_F, O_GATE, O_LAM, O_N2, O_QDR, O_RHO, O_S, O_SDM, O_SDP, O_TH, O_UNC,
                                           O_WENV, O_XI, RAMP, RANK_GATE_V, RANK_ON, RIGID, TWO_PI_F, T_SETTLE,
                                           T_TARE0, V_D, V_DITHER, V_GRIGID, V_INVDEN, V_LNOM, V_M, V_MAX, V_N, V_W,
                                           W_MAX, X_FILT, X_GRAM, X_HELD, X_LAW, X_QPOST, X_QREF, X_TARE, X_TH, X_TSUM,
                                           X_UNC, X_XI)
from kinadapt_nn.controller.laws.base import law_step_fn

@nb.njit(cache=True)
def intake_kernel(inp, x, k, lay, c):
    """Hold non-finite samples: ``inp`` (B, 2n+6) = [q; qdot; wrench] is replaced in place by the
    last valid sample (or a zero wrench before any); flags K_HOLDING, K_ERROR (dropout too long)."""
    for b in range(inp.shape[0]):
        _intake(b, inp, x, k, lay, c)


@nb.njit(cache=True, inline="always")
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


@nb.njit(cache=True, inline="always")
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


@nb.njit(cache=True, inline="always")
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
    nothing; eq. ft_pred; a paused law (``K_PAUSED``) adapts nothing; the contact gate; the Gram log;
    Phi_r^T F on the tracking rows -- then,
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
    if k[b, K_PAUSED] != 0:  # paused from outside (monitor.pause_law: an event open): theta and the law's state stay
        return
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
def _rank_margin(b, Jh, c, out, lay):
    """lambda_min(W J_hat J_hat^T W) (the rank gate); with RANK_ON = 2 only the gate (Cholesky).
    ``Jh`` (6, n): the caller's own new array, scaled by W in place. The Gram is summed on its
    lower triangle, all the Cholesky reads (``dense.gram_lower``: mm_nt's sums, to the bit)."""
    n = Jh.shape[1]
    for i in range(6):
        w = c[V_W + i]
        for j in range(n):
            Jh[i, j] *= w
    G = np.empty((6, 6))
    gram_lower(Jh, G)
    if c[RANK_ON] == 2.0:  # gate only: lambda_min > gate  <=>  G - gate I is positive definite
        for i in range(6):
            G[i, i] -= c[RANK_GATE_V]
        if chol(G, 6):
            out[b, lay[O_LAM]] = np.inf
            return
        gram_lower(Jh, G)
    mirror_lower(G)
    out[b, lay[O_LAM]] = sym_eigmin(G)


# ================================================================================================
@nb.njit(cache=True)
def sense_kernel(t, inp, p_O, R, x, k, lay, c, mats, out):
    """Tare, w_env, s for every episode (the generic path: features run in Python next)."""
    for b in range(inp.shape[0]):
        if k[b, K_ERROR] == 0:
            _sense(t, b, inp, p_O, R, x, k, lay, c, mats, out)


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


def _step(t, inp, chain, p_O, R, J, reg, x, k, lay, c, mats, pv, lc, law_fn, seg, fx, out):
    """The step sequence for B episodes, written once. Not compiled itself: :func:`_kernel` compiles
    it once per features kind with that kind's four parts bound to ``front_fn`` (intake, kinematics,
    sense; False: nothing more this step), ``rows_fn`` (the regressor rows [known; Phi^T] into
    ``reg[b]`` -> what its drive and rank gate reuse), ``drive_fn`` (J_hat_xi^T F, with theta before
    this step's law update) and ``rank_fn`` (the rank gate on the next step's J_hat)."""
    p = lay[L_P]
    for b in range(inp.shape[0]):
        if k[b, K_DONE] != 0 or not front_fn(t, b, inp, chain, p_O, R, J, x, k, lay, c, mats, out):  # noqa: F821
            continue
        st = rows_fn(b, inp, R, J, reg, lay, c, mats, fx)  # noqa: F821  (the parts: bound by _kernel)
        _filter_regressor(b, reg, x, lay, c)
        rho = out[b, lay[O_RHO]]
        Lc = _act_head(b, J, x, k, lay, c, out)
        drive = np.empty(6)
        if c[EXCITE] > 0.0:  # the scripted program replaces V's drive (control.program = "excite")
            _excite_drive(t - c[T_SETTLE], b, R, c, seg, drive)
        else:
            drive_fn(b, R, J, Lc, st, x[b, lay[X_TH]:lay[X_TH] + p], lay, c, mats, fx, out, drive)  # noqa: F821
        _act_tail(t, b, rho, drive, Lc, inp, J, x, lay, c, out)
        _law(b, reg, x, k, lay, c, pv, lc, law_fn, out)
        out[b, lay[O_UNC]] = x[b, lay[X_UNC]]  # theta's remaining uncertainty (the law's; NaN: none)
        if c[RANK_ON] > 0.0 and rho > 0.0:  # the rank gate on the next step's J_hat
            rank_fn(b, R, J, st, x[b, lay[X_TH]:lay[X_TH] + p], lay, c, mats, out)  # noqa: F821


# -- the parts of each features kind -------------------------------------------------------------
@nb.njit(cache=True)
def _ready(t, b, inp, chain, p_O, R, J, x, k, lay, c, mats, out):
    """Features computed in Python: intake and sense ran in ``sense_kernel``; False once diverged."""
    return k[b, K_ERROR] == 0


@nb.njit(cache=True)
def _rows_given(b, inp, R, J, reg, lay, c, mats, fx):
    """Features computed in Python: their rows are in ``reg`` already."""
    return 0


@nb.njit(cache=True)
def _drive_given(b, R, J, Lc, st, theta, lay, c, mats, fx, out, drive):
    """Features computed in Python: the drive from their ``ext_J`` (here ``fx``)."""
    _ext_drive(b, J, Lc, fx, lay, c, out, drive)


@nb.njit(cache=True)
def _no_rank(b, R, J, st, theta, lay, c, mats, out):
    """Features computed in Python: their rank gate is computed there."""
    return


@nb.njit(cache=True)
def _adjoint_rows(b, inp, R, J, reg, lay, c, mats, fx):
    _adjoint_regressor(b, inp, R, J, lay, c, mats, reg[b, 0], reg[b, 1:])
    return 0


@nb.njit(cache=True)
def _adjoint_drive_part(b, R, J, Lc, st, theta, lay, c, mats, fx, out, drive):
    _adjoint_drive(b, R, theta, out[b, lay[O_F]:lay[O_F] + 6], c, mats, drive)


@nb.njit(cache=True)
def _adjoint_rank(b, R, J, st, theta, lay, c, mats, out):
    """The rank gate of the next step's J_hat = S Ad(R theta) J."""
    _rank_margin(b, _twist_jacobian_times(_adjoint_twist_jacobian(b, R, theta[:3], c, mats), J[b]), c, out, lay)


def _learned_rows(b, inp, R, J, reg, lay, c, mats, fx):
    """The learned features' rows (neural, RBF; not compiled itself: :func:`_compiled` binds
    ``basis_fn``, ``learned_rows_fn``): the basis once per step (Y(q) or psi(q)) for the regressor,
    and J_hat's prior part K(q), both kept for the drive and the rank gate."""
    n = lay[L_N]
    basis = basis_fn(fx, inp[b, :n], n)  # noqa: F821  (bound by _compiled)
    learned_rows_fn(b, inp, R, J, basis, lay, c, mats, fx, reg[b, 0], reg[b, 1:])  # noqa: F821
    return basis, _jhat_prior(b, R, J, c, mats, fx)


def _learned_drive(b, R, J, Lc, st, theta, lay, c, mats, fx, out, drive):
    """The drive through J_hat (m, n) = ``jhat_fn``(K(q), basis, theta) (bound by :func:`_compiled`)."""
    _jhat_drive(b, J, Lc, jhat_fn(st[1], st[0], theta), lay, out, drive)  # noqa: F821


def _learned_rank(b, R, J, st, theta, lay, c, mats, out):
    """The rank gate on J_hat = ``jhat_fn``(K(q), basis, theta) (bound by :func:`_compiled`)."""
    _rank_margin(b, jhat_fn(st[1], st[0], theta), c, out, lay)  # noqa: F821


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


# -- the kernels: the one sequence with each kind's parts -----------------------------------------
def _compiled(py_fn, name: str, doc: str, **parts):
    """The numba kernel ``name``: ``py_fn``'s code with ``parts`` (kernels) as its globals. numba calls a
    global kernel directly (in line, as if written there) and caches the kernel under its own name,
    so each is what writing the code out with those parts gave, compiled on its first use."""
    fn = types.FunctionType(py_fn.__code__, {**globals(), **parts}, name)
    fn.__qualname__, fn.__doc__ = name, doc
    return nb.njit(cache=True)(fn)


def _kernel(name: str, doc: str, front_fn, rows_fn, drive_fn, rank_fn, st_type):
    """The step kernel ``name``: :func:`_step` with a features kind's four parts. ``st_type``: the numba
    type of what ``rows_fn`` returns (``st``, which the drive and rank gate take), the kernel's
    ``local_types``: the cold compile's plan types those parts with it (``core.callee_plan``; a wrong
    type leaves a second signature, which tests/controller/test_twocore.py checks)."""
    kernel = _compiled(_step, name, doc, front_fn=front_fn, rows_fn=rows_fn, drive_fn=drive_fn, rank_fn=rank_fn)
    kernel.local_types = {"st": st_type}
    return kernel


#: ``st`` of the kinds whose rows part keeps nothing for the drive (the literal 0 it returns), and of the
#: learned kinds: (basis, K(q)) -- the neural Y(q) (m, n, p) or the RBF psi(q) (p,), and K(q) (m, n)
_ST_NONE = nbt.literal(0)
_ST_NEURAL = nbt.Tuple((nbt.Array(nbt.float64, 3, "C"), nbt.Array(nbt.float64, 2, "C")))
_ST_RBF = nbt.Tuple((nbt.Array(nbt.float64, 1, "C"), nbt.Array(nbt.float64, 2, "C")))


#: the learned features' parts, one code for both (the basis, its rows and J_hat are each kind's own)
_neural_rows_part = _compiled(_learned_rows, "_neural_rows_part", "_learned_rows with the neural basis Y(q).",
                              basis_fn=_neural_body, learned_rows_fn=_neural_rows)
_neural_drive = _compiled(_learned_drive, "_neural_drive", "_learned_drive with the neural J_hat.",
                          jhat_fn=_neural_jhat)
_neural_rank = _compiled(_learned_rank, "_neural_rank", "_learned_rank with the neural J_hat.", jhat_fn=_neural_jhat)
_rbf_rows_part = _compiled(_learned_rows, "_rbf_rows_part", "_learned_rows with the RBF psi(q).",
                           basis_fn=_rbf_psi, learned_rows_fn=_rbf_rows)
_rbf_drive = _compiled(_learned_drive, "_rbf_drive", "_learned_drive with the RBF J_hat.", jhat_fn=_rbf_jhat)
_rbf_rank = _compiled(_learned_rank, "_rbf_rank", "_learned_rank with the RBF J_hat.", jhat_fn=_rbf_jhat)


#: one whole period for B episodes with the adjoint features (one dispatch): intake, forward kinematics of
#: the bare arm, sense, regressor, act, law, rank gate (``fx``: unused; the fused kernels share one signature)
step_adjoint = _kernel("step_adjoint", "The step sequence (``_step``) with the adjoint features.",
                       _front, _adjoint_rows, _adjoint_drive_part, _adjoint_rank, _ST_NONE)
#: ``step_adjoint`` for the neural basis (``fx``: ``neural_consts``)
step_neural = _kernel("step_neural", "The step sequence (``_step``) with the neural basis (fx: neural_consts).",
                      _front, _neural_rows_part, _neural_drive, _neural_rank, _ST_NEURAL)
#: ``step_adjoint`` for the per-entry Gaussian RBF (``fx``: ``rbf_consts``)
step_rbf = _kernel("step_rbf", "The step sequence (``_step``) with the per-entry Gaussian RBF (fx: rbf_consts).",
                   _front, _rbf_rows_part, _rbf_drive, _rbf_rank, _ST_RBF)
#: the sequence after ``sense_kernel`` for features computed in Python (``fx``: their ``ext_J``)
_step_given = _kernel("_step_given", "The step sequence (``_step``) after sense_kernel, features from Python.",
                      _ready, _rows_given, _drive_given, _no_rank, _ST_NONE)


@nb.njit(cache=True)
def act_kernel(t, inp, p_O, R, J, reg, ext_J, x, k, lay, c, mats, pv, lc, law_fn, seg, out):
    """The rest of the step after ``sense_kernel`` for features computed in Python: the regressor
    rows ``reg`` (B, 1+p, m) = [known; Phi^T] and ``ext_J`` (J_hat_xi: FEAT_TWIST, or J_hat:
    FEAT_JHAT) (``lc``, ``law_fn``: the law's constants and its step's address)."""
    _step_given(t, inp, J, p_O, R, J, reg, x, k, lay, c, mats, pv, lc, law_fn, seg, ext_J, out)


#: the fused step kernel of each in-kernel features kind (FEAT_ADJOINT, FEAT_NEURAL, FEAT_RBF); each compiles
#: only its own features' code, on first use
FUSED = {FEAT_ADJOINT: step_adjoint, FEAT_NEURAL: step_neural, FEAT_RBF: step_rbf}
