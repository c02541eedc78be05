"""The kalman law: a law that knows what it does not know (the default; docs/equations.md#kalman).

It changes eq. ft_composite's gain and its prediction step. ``theta`` carries a covariance ``P``
(p, p), started at the features' prior ``P0`` (adjoint: the declared tolerance of the tool offset;
neural: the covariance of the pretraining heads; RBF: the adjoint's prior pushed through the RBF
fit, plus a small isotropic part). In contact, with ``H = W Phi_f`` (m, p), ``e_w = W (s_dot_meas
- known_f - Phi_f theta)`` (eq. ft_pred, theta: what the controller used) and the innovation of
the filter's own estimate ``e = e_w - H (theta_kf - theta)``::

    r2    <- EMA over resid_tau_s of e_w^2 ; r1 <- EMA over persist_tau_s of e_w   (per channel)
    R     = diag(r2 + floor) * n_eff,  n_eff = max(corr_s/dt, (2 tau_m/dt) r1^2 / (r2 + floor))
    K     = P H^T (H P H^T + R)^-1
    theta_kf = Proj_Omega(theta_kf + K e - dt gamma_d P Phi_r^T F)   (tracking term, Gamma -> P)
    P     = (1 - K H) P

``n_eff`` is the number of samples per independent observation: a residual that keeps its sign (a
bias) counts once per 2 tau_m, not once per step. The controller acts only on the *identified*
part of the estimate, ``theta = theta_prior + Pi (theta_kf - theta_prior)``: ``Pi`` projects, in
the prior's whitened coordinates, onto the eigen-directions whose posterior sd has fallen below
``act_sd_ratio`` of the prior sd (re-evaluated at 50 Hz, 10 Hz for p > 30); elsewhere J_hat keeps
the prior.

A direction of theta moves only as far as its accumulated information ``sum H^T R^-1 H`` exceeds
``P0^-1``; where the bias dominates (R large against the parametric signal) or nothing excites it
(H has no component), theta stays at the prior. The certificate with ``Gamma -> P(t)``: with
``d/dt P^-1 = H^T R^-1 H`` and no bias, ``V_aug = gamma_d V + 1/2 theta~^T P^-1 theta~`` has
``dV_aug/dt <= -1/2 |H theta~|^2_{R^-1}``; the bias enters as ``- theta~^T H^T R^-1 b``.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from kinadapt_nn.controller.dense import SMALL, chol, chol_solve_cols, mm, mm_nt, vcopy
from kinadapt_nn.controller.laws import tracking
from kinadapt_nn.controller.laws.base import LawSpec, LawState, LawView, config_key

#: consts indices (scalars; then P0, L and L^-1 (p, p) each, L L^T = P0)
(DT, GAMMA_D, N_CORR, R_ALPHA, R_FLOOR, M_ALPHA, N_PERSIST, ACT_RATIO, ACT_EVERY, TR_P0) = range(10)
N_SCALARS = 10
#: counters
(R2_PRIMED, KF_INIT, ACT_K, ACT_INIT) = range(4)
COUNTERS = ("r2_primed", "kf_init", "act_k", "act_init")


def blocks(m: int, p: int) -> tuple[tuple[str, tuple[int, ...]], ...]:
    """The law's state, in the order :func:`_views` reads it."""
    return (("P", (p, p)), ("theta_kf", (p,)), ("theta_prior", (p,)), ("act_proj", (p, p)), ("r2", (m,)),
            ("r1", (m,)), ("R", (m,)))


class Params(tracking.Weight):
    """The kalman law's parameters (flat config keys): gamma_d (tracking.py), then its own."""

    corr_s: float = config_key("corr_s")  # [s] adaptation.corr_s: residual correlation time
    resid_tau_s: float = config_key("resid_tau_s")  # [s] adaptation.resid_tau_s: the residual level's time constant
    resid_floor_w: float = config_key("resid_floor_w")  # [W-scaled^2] adaptation.resid_floor_w: its floor
    persist_tau_s: float = config_key("persist_tau_s")  # [s] adaptation.persist_tau_s: the residual mean's window
    act_sd_ratio: float = config_key("act_sd_ratio")  # [-] adaptation.act_sd_ratio: act once sd < this x prior sd


def constants(params: Params, m: int, p: int) -> np.ndarray:
    """Scalars (N_SCALARS,), then P0, L, L^-1 (p * p each)."""
    dt = params.dt_s
    P0 = np.asarray(params.prior_cov, dtype=float)
    if P0.shape != (p, p):
        raise ValueError(f"the kalman law needs theta's prior covariance (p, p) = {(p, p)}, got {P0.shape}")
    L = np.linalg.cholesky(P0)
    scal = [dt, params.gamma_d, max(1.0, params.corr_s / dt), min(1.0, dt / params.resid_tau_s), params.resid_floor_w,
            min(1.0, dt / params.persist_tau_s), 2.0 * params.persist_tau_s / dt, params.act_sd_ratio,
            max(1, int(round((0.02 if p <= 30 else 0.1) / dt))), float(np.trace(P0))]
    return np.concatenate([np.array(scal, dtype=float), P0.ravel(), L.ravel(), np.linalg.inv(L).ravel()])


def _P0(consts: np.ndarray, p: int) -> np.ndarray:
    return consts[N_SCALARS:N_SCALARS + p * p].reshape(p, p)


@nb.njit(cache=True)
def _views(x, m, p):
    """(P (p, p), theta_kf, theta_prior, act_proj (p, p), r2, r1, R) views of the state x."""
    pp = p * p
    o = 2 * pp + 2 * p
    return (x[:pp].reshape((p, p)), x[pp:pp + p], x[pp + p:pp + 2 * p], x[pp + 2 * p:o].reshape((p, p)),
            x[o:o + m], x[o + m:o + 2 * m], x[o + 2 * m:o + 3 * m])


@nb.njit(cache=True)
def step(theta, H_T, G, e, PhiF, lo, hi, consts, x, k, unc, d_track, d_pred):
    """The information-weighted step (module docstring; laws.base: the step contract). Returns
    tr(H^T H)."""
    p, m = H_T.shape
    c = consts
    P, th, prior, A, r2, r1, R = _views(x, m, p)
    n2 = 0.0
    for j in range(p):
        n2 += G[j, j]
    _residual_level(e, r2, r1, k, c)
    if k[KF_INIT] == 0:  # the filter's own estimate starts where the controller's is
        vcopy(th, theta)
        vcopy(prior, theta)
        k[KF_INIT] = 1
    e_kf = _noise_and_innovation(th, theta, H_T, e, r2, r1, R, c)
    if not _measurement_update(P, H_T, e_kf, R, d_pred):
        return n2
    for j in range(p):
        th[j] += d_pred[j]
    if c[GAMMA_D] > 0.0:
        _tracking_term(P, PhiF, c, d_track, th)
    for j in range(p):  # Proj_Omega (clip)
        th[j] = min(max(th[j], lo[j]), hi[j])
    k[ACT_K] += 1
    if k[ACT_K] >= c[ACT_EVERY] or k[ACT_INIT] == 0:
        k[ACT_K] = 0
        k[ACT_INIT] = 1
        pp = p * p
        o = N_SCALARS + pp
        identified_projector(P, c[o:o + pp].reshape((p, p)), c[o + pp:o + 2 * pp].reshape((p, p)), c[ACT_RATIO], A,
                             True)
    _act_identified(theta, th, prior, A)
    tr = 0.0
    for j in range(p):
        tr += P[j, j]
    unc[0] = math.sqrt(max(tr, 0.0) / c[TR_P0])
    return n2


@nb.njit(cache=True)
def _noise_and_innovation(th, theta, H_T, e, r2, r1, R, c):
    """R = diag(r2 + floor) n_eff, n_eff = max(corr_s/dt, (2 tau_m/dt) r1^2 / r2), into ``R``
    (m,). -> the innovation of the filter's estimate, e - H (theta_kf - theta) (m,)."""
    p, m = H_T.shape
    e_kf = np.empty(m)
    for i in range(m):
        n_eff = max(c[N_CORR], c[N_PERSIST] * (r1[i] * r1[i]) / (r2[i] + c[R_FLOOR]))
        R[i] = (r2[i] + c[R_FLOOR]) * n_eff
        v = 0.0
        for j in range(p):
            v += (th[j] - theta[j]) * H_T[j, i]
        e_kf[i] = e[i] - v
    return e_kf


@nb.njit(cache=True)
def _tracking_term(P, PhiF, c, d_track, th):
    """eq. ft_composite's tracking term with Gamma = P: d_track = -dt gamma_d P PhiF, added to
    ``th``. P PhiF as sum_j PhiF_j P[j, :] (P is exactly symmetric: rows are columns; contiguous
    row sweeps vectorise)."""
    p = th.shape[0]
    g = -c[DT] * c[GAMMA_D]
    if p <= SMALL:  # (dense.SMALL: the same sums in scalars)
        for i in range(p):
            v = 0.0
            for j in range(p):
                v += PhiF[j] * P[j, i]
            d_track[i] = v * g
            th[i] += d_track[i]
        return
    for i in range(p):
        d_track[i] = 0.0
    for j in range(p):
        v = PhiF[j]
        Pj = P[j]
        for i in range(p):
            d_track[i] += v * Pj[i]
    for i in range(p):
        d_track[i] *= g
        th[i] += d_track[i]


@nb.njit(cache=True)
def _act_identified(theta, th, prior, A):
    """theta = prior + Pi (th - prior): act on the identified part only, Pi dth = sum_j dth_j
    Pi[:, j] (``A`` holds Pi^T)."""
    p = th.shape[0]
    if p <= SMALL:  # (dense.SMALL: the same sums in scalars)
        for i in range(p):
            v = 0.0
            for j in range(p):
                d = th[j] - prior[j]
                if d != 0.0:
                    v += d * A[j, i]
            theta[i] = prior[i] + v
        return
    for i in range(p):  # theta (written only: neither th nor prior) sums Pi dth first
        theta[i] = 0.0
    for j in range(p):
        v = th[j] - prior[j]
        if v != 0.0:
            Aj = A[j]
            for i in range(p):
                theta[i] += v * Aj[i]
    for i in range(p):
        theta[i] = prior[i] + theta[i]


@nb.njit(cache=True)
def _residual_level(e, r2, r1, k, c):
    """r2 <- EMA over resid_tau_s of e^2 (the measured residual level, bias included), r1 <- EMA
    over persist_tau_s of e (its persistent part); primed with the first sample. e, r2, r1: (m,)."""
    m = e.shape[0]
    if k[R2_PRIMED] == 0:
        for i in range(m):
            r2[i] = e[i] * e[i]
            r1[i] = 0.0
        k[R2_PRIMED] = 1
    else:
        for i in range(m):
            r2[i] += c[R_ALPHA] * (e[i] * e[i] - r2[i])
            r1[i] += c[M_ALPHA] * (e[i] - r1[i])


@nb.njit(cache=True)
def _measurement_update(P, H_T, e_kf, R, d_pred):
    """K = P H^T (H P H^T + diag R)^-1: d_pred = K e_kf and P = (1 - K H) P, symmetric, in place.
    False (nothing changed) when H P H^T + diag R is not positive definite.

    Written for the sparse rows of per-entry features (the RBF's row i touches only its own block
    of theta): the products with a zero of H are skipped (each sum runs over H's non-zeros in
    order), the rank-m downdate is formed on the lower triangle and mirrored (P stays exactly
    symmetric)."""
    p, m = H_T.shape
    HP = _h_times(H_T, P)  # H P = (P H^T)^T, P symmetric
    S = _h_times(H_T, HP.T)  # H P H^T
    for i in range(len(R)):
        S[i, i] += R[i]
    if not chol(S, m):
        return False
    X = HP.copy()  # K^T = S^-1 (H P), every column at once
    chol_solve_cols(S, m, X)
    for j in range(p):  # K e
        v = 0.0
        for i in range(m):
            v += X[i, j] * e_kf[i]
        d_pred[j] = v
    _downdate_lower(P, X, HP)
    for i in range(p):
        for j in range(i):
            P[j, i] = P[i, j]
    return True


@nb.njit(cache=True)
def _h_times(H_T, X):
    """H X (m, q) for X (p, q): entry (j, i) = sum_r H[j, r] X[r, i], summed from 0.0 over H's non-zeros in
    r's order: up to ``dense.SMALL`` parameters in scalars, else by row sweeps (the same sums). H P is
    ``_h_times(H_T, P)``; H P H^T is ``_h_times(H_T, HP.T)``."""
    p, m = H_T.shape
    q = X.shape[1]
    out = np.zeros((m, q))
    for j in range(m):
        if p <= SMALL:
            for i in range(q):
                v = 0.0
                for r in range(p):
                    h = H_T[r, j]
                    if h != 0.0:
                        v += h * X[r, i]
                out[j, i] = v
            continue
        oj = out[j]
        for r in range(p):
            h = H_T[r, j]
            if h != 0.0:
                Xr = X[r]
                for i in range(q):
                    oj[i] += h * Xr[i]
    return out


@nb.njit(cache=True)
def _downdate_lower(P, X, HP):
    """P[i, :i+1] -= sum_r X[r, i] HP[r, :i+1] for every row i (the lower triangle of P - K H P,
    K^T = X (m, p), HP (m, p)): the terms with X[r, i] = 0 left out, the others summed from 0.0 in
    r's order. For m = 6 every row is one pass (a straight-line sum per entry that vectorises: 22
    -> 14 us at p = 210) of all six terms: a term X[r, i] HP[r, j] with X[r, i] = 0 is an exact
    zero (HP is finite), and adding a zero to a sum that starts at +0.0 changes no bit (the sum is
    never -0.0), so the result is the sum of the non-zero terms, to the bit. Any other m: one pass
    per non-zero term."""
    p = P.shape[0]
    m = X.shape[0]
    if m == 6:
        for i in range(p):
            a0, a1, a2, a3, a4, a5 = X[0, i], X[1, i], X[2, i], X[3, i], X[4, i], X[5, i]
            Pi = P[i]
            for j in range(i + 1):
                Pi[j] -= (((((0.0 + a0 * HP[0, j]) + a1 * HP[1, j]) + a2 * HP[2, j]) + a3 * HP[3, j])
                          + a4 * HP[4, j]) + a5 * HP[5, j]
        return
    row = np.empty(p)
    for i in range(p):
        for j in range(i + 1):
            row[j] = 0.0
        for r in range(m):
            kr = X[r, i]
            if kr == 0.0:
                continue
            for j in range(i + 1):
                row[j] += kr * HP[r, j]
        for j in range(i + 1):
            P[i, j] -= row[j]


@nb.njit(cache=True)
def identified_projector(P, L, Linv, ratio, A, transposed=False):
    """A = the projector (p, p) onto the directions of theta the data have identified: in the
    prior's whitened coordinates (``P0 = L L^T``), the eigen-directions of ``L^-1 P L^-T`` whose
    posterior sd has fallen below ``ratio`` of the prior sd; oblique along the rest.
    ``transposed``: A = the projector's transpose (its columns as rows: the law's state, which
    sums them with contiguous row sweeps)."""
    p = P.shape[0]
    if ratio >= 1.0:
        _diagonal(A, 1.0)
        return
    M = mm_nt(mm(Linv, P), Linv)
    for i in range(p):
        for j in range(i + 1):
            M[i, j] = M[j, i] = 0.5 * (M[i, j] + M[j, i])
    lam, V = np.linalg.eigh(M)
    U, Ut = _identified(lam, V, ratio * ratio)
    if U.shape[1] == 0:
        _diagonal(A, 0.0)
        return
    LUL = mm(mm(L, U), mm(Ut, Linv))  # L U U^T L^-1: products with the selected directions only
    for i in range(p):
        for j in range(p):
            if transposed:
                A[j, i] = LUL[i, j]
            else:
                A[i, j] = LUL[i, j]


@nb.njit(cache=True)
def _diagonal(A, v):
    """A = v I (p, p)."""
    p = A.shape[0]
    for i in range(p):
        for j in range(p):
            A[i, j] = v if i == j else 0.0


@nb.njit(cache=True)
def _identified(lam, V, below):
    """The eigenvectors (columns of V) whose eigenvalue lam is below ``below``. -> (U (p, sel) as
    columns, Ut (sel, p) as rows)."""
    p = lam.shape[0]
    sel = 0
    for kk in range(p):
        if lam[kk] < below:
            sel += 1
    U = np.empty((p, sel))
    Ut = np.empty((sel, p))
    s_ = 0
    for kk in range(p):
        if lam[kk] < below:
            for i in range(p):
                U[i, s_] = V[i, kk]
                Ut[s_, i] = V[i, kk]
            s_ += 1
    return U, Ut


def reset(consts: np.ndarray, state: LawState, carried: bool) -> None:
    """P = P0 and the residual level unprimed; ``carried``: keep P, the residual level and the
    filter's estimate (the next insertion of the same tool). The identified set is re-evaluated
    at the first step in contact either way."""
    P = state.blocks["P"]
    p = P.shape[-1]
    if not carried:
        state.x[...] = 0.0
        state.k[...] = 0
        P[...] = _P0(consts, p)
    state.blocks["act_proj"][...] = 0.0
    state.counters["act_k"][...] = 0
    state.counters["act_init"][...] = 0
    state.unc[...] = np.sqrt(np.maximum(np.trace(P, axis1=1, axis2=2), 0.0) / consts[TR_P0])


class KalmanView(LawView):
    """The kalman law's state, for the summary and offline replays (one episode)."""

    has_covariance = True

    @property
    def P(self) -> np.ndarray:
        """(p, p) theta's covariance."""
        return self.blocks["P"]

    @property
    def theta_kf(self) -> np.ndarray | None:
        """(p,) the filter's own estimate (None before the first step in contact)."""
        return self.blocks["theta_kf"] if self.counters["kf_init"][0] else None

    @property
    def R(self) -> np.ndarray:
        """(m,) the measurement variance of the last update, diag((r2 + floor) n_eff)."""
        return self.blocks["R"]

    def identified_directions(self) -> int:
        """Directions of theta the controller acts on (0 before the first step in contact)."""
        if not self.counters["act_init"][0]:
            return 0
        return int(round(float(np.trace(self.blocks["act_proj"]))))

    def information_sd(self) -> np.ndarray:
        """sqrt(diag P)."""
        return np.sqrt(np.clip(np.diag(self.P), 0.0, None))

    def residual_rms(self) -> float:
        """sqrt(mean r2): the W-scaled residual level measured in contact (NaN before contact)."""
        return float(np.sqrt(np.mean(self.blocks["r2"]))) if self.counters["r2_primed"][0] else math.nan

    def identified_criterion(self) -> str:
        return f"posterior sd < {self.consts[ACT_RATIO]:g} x prior"


LAW = LawSpec(name="kalman", doc="information-weighted: theta moves only where the data beat the prior (default)",
              step=step, params=Params, constants=constants, blocks=blocks, counters=COUNTERS, reset=reset, view=KalmanView)
