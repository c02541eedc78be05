"""The composite adaptation law (eq. ft_composite), written once on the regressor ``Phi``.

Per control step k (dt), with ``Phi_r = Phi(q_k, qdot_k)`` on the *realised* (measured)
joint velocity, ``Phi_f`` the same regressor through the rate filter, and the W-scaled
prediction error ``e = W (s_dot_meas - (known_f + Phi_f theta))`` (eq. ft_pred):

    tracking    d_track = - dt * Gamma * gamma_d * Phi_r^T F             (eq. ft_composite, 1st term)
    prediction  d_pred  = eta * (W Phi_f)^T e / (||W Phi_f||_2^2 + eps_norm)
                                                         (fractional step of eq. ident_qp_solution)
    theta_{k+1} = Proj_Omega( theta_k + g_k * (d_track + d_pred) )

``||.||_2`` is the spectral norm: for per-entry features (rows of Phi mutually orthogonal with
equal norms) ``||Phi||_2^2 = ||psi||^2 ||qdot||^2`` and ``d_pred`` with ``eta = 1`` *is* the
closed form of eq. ident_qp_solution with ``eps_norm = 1/(kappa gamma)``; the size of the step
does not grow with ``Gamma`` (a naive ``dt kappa Gamma`` step at Gamma = 8000 would exceed the
normalised-LMS stability limit ``eta < 2``).

``g_k`` is the contact gate (the free-space rule): the nominal map S models a contact, so in
free space (no sensed contact: ``|F| < contact_force_N`` and ``|M| < contact_moment_Nm``) the
F/T channels carry no information about the offset and S's prediction is not even meant to
hold; adaptation is frozen there (the tracking term vanishes there anyway, since F_lat = M = 0).

``gamma_d`` is the weight of ``V(s)`` in ``V_aug = gamma_d V(s) + 1/2 |theta~|^2 / Gamma`` (the
paper's Results section writes it but never gives it); it makes V [J] and the parameter energy
[m^2 / Gamma] commensurate. The certificate is unchanged by it: scaling every mechanical
storage (V, kinetic, contact) by gamma_d is the same as using ``Gamma * gamma_d`` in the
tracking term.

``Omega`` (paper appendix, eq. QPaug) is a box about the nominal offset: lateral components
within ``omega_lateral_m``, axial within ``omega_axial_m``. For the adjoint features any theta
gives a full-row-rank ``J_hat = S Ad(theta) J_arm`` (Ad is invertible), so Omega only encodes
the physical envelope of the tool; the projection is the Euclidean one (a clip).

Modes: ``composite`` (both terms), ``prediction`` (d_pred only), ``tracking`` (d_track only),
``frozen`` (theta constant), and the default ``kalman``:

**kalman: a law that knows what it does not know** (changes eq. ft_composite's gain and its
prediction step; docs/equations.md). ``theta`` carries a covariance ``P`` (p, p), started at the
features' prior (adjoint: the declared tolerance of the tool offset; neural: the covariance of the
pretraining heads; RBF: the adjoint's prior pushed through the RBF fit, plus a small isotropic
part). In contact, with ``H = W Phi_f`` (m, p) and the innovation ``e = W (s_dot_meas - known_f -
Phi_f theta)``::

    R     = diag(r2 + floor) * n_eff           measured residual level r2 times the samples per
                                               independent observation: n_eff = max(corr_s/dt,
                                               (2 tau_m/dt) r1^2 / r2), r1 the residual's mean
                                               over tau_m (a persistent residual -- a bias that
                                               keeps its sign -- is one observation per 2 tau_m)
    K     = P H^T (H P H^T + R)^-1
    theta = Proj_Omega(theta + K e  - dt gamma_d P Phi_r^T F)    (tracking term with Gamma = P)
    P     = (1 - K H) P

and the controller acts only on the **identified** part of that estimate: in the prior's
whitened coordinates, the directions whose posterior sd has fallen below ``act_sd_ratio`` of the
prior sd (re-evaluated at 50 Hz, 10 Hz for p > 30); elsewhere J_hat keeps the prior. ``theta`` in the trace is what
the controller used.

``r2`` (m,) is an exponential average (``resid_tau_s``) of ``e^2`` over contact samples: the
residual level the data show, bias included. A direction of theta moves only as far as its
accumulated information ``sum H^T R^-1 H`` exceeds the prior's ``P0^-1``; where the bias
dominates (R large against the parametric signal) or nothing excites it (H has no component),
theta stays at the prior. The paper's certificate with ``Gamma -> P(t)``: with
``d/dt P^-1 = H^T R^-1 H`` and no bias, ``V_aug = gamma_d V + 1/2 theta~^T P^-1 theta~`` has
``dV_aug/dt <= -1/2 |H theta~|^2_{R^-1}`` (the tracking term still cancels the cross term); the
bias enters as before (``- theta~^T H^T R^-1 b``), now divided by the measured residual level.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from kinadapt_nn.features.base import Features, KinState, Regressor
from kinadapt_nn.sensing import LowPass

MODES = ("kalman", "composite", "prediction", "tracking", "frozen")


class AdaptStep(NamedTuple):
    """What one adaptation step did (for the trace)."""

    s_dot_pred: np.ndarray  #: (m,) filtered prediction known_f + Phi_f theta (before the update)
    eps_w: np.ndarray  #: (m,) W-scaled filtered prediction error before the update
    d_track: np.ndarray  #: (p,) tracking increment (before the gate)
    d_pred: np.ndarray  #: (p,) prediction increment (before the gate)
    gate: float  #: 1 in contact, 0 in free space
    phi_norm2: float  #: ||W Phi_f||_2^2


def lambda_max_sym3(G: np.ndarray) -> float:
    """Largest eigenvalue of a symmetric 3x3 matrix (lower triangle read, as ``eigvalsh``), closed
    form: trigonometric solution of the characteristic cubic (Smith 1961) in Python floats.
    ~1 us against ~6 us for ``np.linalg.eigvalsh``; relative error ~1e-15 on PSD Grams."""
    (a, _, _), (b, d, _), (c, e, f) = G.tolist()
    p1 = b * b + c * c + e * e
    q = (a + d + f) / 3.0
    if p1 == 0.0:  # diagonal
        return max(a, d, f)
    a, d, f = a - q, d - q, f - q
    p = math.sqrt((a * a + d * d + f * f + 2.0 * p1) / 6.0)
    a, b, c, d, e, f = a / p, b / p, c / p, d / p, e / p, f / p  # B = (G - q I) / p
    r = 0.5 * (a * (d * f - e * e) - b * (b * f - e * c) + c * (b * e - d * c))  # det(B) / 2
    r = -1.0 if r < -1.0 else (1.0 if r > 1.0 else r)
    return q + 2.0 * p * math.cos(math.acos(r) / 3.0)


def _spectral_norm2(G: np.ndarray) -> float:
    """``lambda_max`` of a Gram matrix: closed form for 3x3 (the adjoint, p = 3), else eigvalsh."""
    if G.shape == (3, 3):
        return lambda_max_sym3(G)
    return float(np.linalg.eigvalsh(G)[-1])


def prediction_step(Phi_w: np.ndarray, eps_w: np.ndarray, eta: float, eps_norm: float) -> tuple[np.ndarray, float]:
    """Fractional normalised step of the exact per-sample identification QP.

    ``Phi_w`` (m, p) and ``eps_w`` (m,) already W-scaled. Returns (d_theta (p,), ||Phi_w||_2^2).
    """
    m, p = Phi_w.shape
    G = Phi_w.T @ Phi_w if p <= m else Phi_w @ Phi_w.T
    n2 = _spectral_norm2(G)
    return eta * (Phi_w.T @ eps_w) / (n2 + eps_norm), n2


def exact_qp_step(Phi_w: np.ndarray, eps_w: np.ndarray, eps_norm: float) -> np.ndarray:
    """The exact minimiser of eq. ident_qp (with Gamma = gamma I, eps_norm = 1/(kappa gamma)):
    ``Phi^T (Phi Phi^T + eps_norm I)^{-1} eps`` (push-through form). Reference for tests."""
    m = Phi_w.shape[0]
    return Phi_w.T @ np.linalg.solve(Phi_w @ Phi_w.T + eps_norm * np.eye(m), eps_w)


def kalman_update(P: np.ndarray, Ht: np.ndarray, e: np.ndarray, r: np.ndarray) -> np.ndarray:
    """One Kalman measurement update of a parameter estimate. ``P`` (p, p) covariance (updated
    in place to ``(1 - K H) P``, symmetrised), ``Ht`` (p, m) = H^T, ``e`` (m,) innovation, ``r``
    (m,) diagonal measurement variance. Returns the parameter increment ``K e`` (p,), with
    ``K = P H^T (H P H^T + diag r)^-1``. Raises ``LinAlgError`` for a singular innovation matrix."""
    PHt = P.dot(Ht)  # (p, m)
    S = Ht.T.dot(PHt)  # (m, m) = H P H^T
    S[np.diag_indices_from(S)] += r
    K = np.linalg.solve(S, PHt.T).T  # (p, m); S symmetric
    P -= K.dot(PHt.T)
    P += P.T
    P *= 0.5
    return K.dot(e)


class CompositeLaw:
    """Composite tracking + prediction adaptation of ``theta`` on ``Features``.

    Filter state: ``known_f`` and ``Phi_f`` live in one stacked array ``filter_state`` (1 + p, m)
    = ``[known_f; Phi_f^T]`` (``Phi_f.z`` is a transposed view). ``Controller`` passes a slice of
    its own buffer so that the measured-rate filter and these two are updated in one pass
    (``Controller.step``) and then calls :meth:`step_filtered`; :meth:`update` is the stand-alone
    entry point (filters the regressor itself).
    """

    def __init__(
        self,
        features: Features,
        mode: str,
        gamma: float,
        gamma_d: float,
        eta: float,
        eps_norm: float,
        W: np.ndarray,
        filter_tau_s: float,
        dt_s: float,
        theta_nominal: np.ndarray,
        omega_half_width: np.ndarray,
        contact_force_N: float,
        contact_moment_Nm: float,
        filter_state: np.ndarray | None = None,
        prior_cov: np.ndarray | None = None,
        corr_s: float = 0.05,
        resid_tau_s: float = 1.0,
        resid_floor_w: float = 1e-4,
        persist_tau_s: float = 0.5,
        act_sd_ratio: float = 0.4,
    ) -> None:
        if mode not in MODES:
            raise ValueError(f"adaptation mode {mode!r} not in {MODES}")
        self.features = features
        self.mode = mode
        self.gamma = float(gamma)
        self.gamma_d = float(gamma_d)
        self._track_gain = self.gamma * self.gamma_d
        self._c_track = -float(dt_s) * self._track_gain  # d_track = c_track * Phi_r^T F
        self.eta = float(eta)
        self.eps_norm = float(eps_norm)
        self.W = np.asarray(W, dtype=float)
        self._W_col = self.W[:, None]
        self.dt = float(dt_s)
        p = features.n_params
        m = self.W.shape[0]
        self.lo = np.asarray(theta_nominal, dtype=float) - omega_half_width
        self.hi = np.asarray(theta_nominal, dtype=float) + omega_half_width
        if filter_state is None:
            filter_state = np.zeros((1 + p, m))
        elif filter_state.shape != (1 + p, m):
            raise ValueError(f"filter_state shape {filter_state.shape} != {(1 + p, m)}")
        self._Phi_fT = filter_state[1:]  # (p, m) = Phi_f^T, C-contiguous rows
        self.known_f = LowPass(filter_tau_s, dt_s, (m,), z=filter_state[0])
        self.Phi_f = LowPass(filter_tau_s, dt_s, (m, p), z=self._Phi_fT.T)
        self.f_gate = contact_force_N
        self.m_gate = contact_moment_Nm
        self._use_track = mode in ("composite", "tracking")
        self._use_pred = mode in ("composite", "prediction")
        self._zero_p = np.zeros(p)
        #: sum over gated (contact) steps of (W Phi_f)^T (W Phi_f): the regressor Gram <Phi^T Phi>
        self.gram_sum = np.zeros((p, p))
        self.gram_n = 0
        # kalman mode: covariance of theta, the measured residual level, the decorrelation factor
        if mode == "kalman" and prior_cov is None:
            raise ValueError("the kalman law needs the features' prior covariance")
        self.P0 = None if prior_cov is None else np.array(prior_cov, dtype=float)
        self.P = None if self.P0 is None else self.P0.copy()
        self._n_corr = max(1.0, float(corr_s) / self.dt)
        self._r_alpha = min(1.0, self.dt / float(resid_tau_s))
        self._r_floor = float(resid_floor_w)
        self.r2 = np.zeros(m)
        self.r1 = np.zeros(m)
        self._r2_primed = False
        self._m_alpha = min(1.0, self.dt / float(persist_tau_s))
        self.theta_kf: np.ndarray | None = None
        self.theta_prior: np.ndarray | None = None
        self._act_ratio = float(act_sd_ratio)
        # the identified set is re-evaluated at 50 Hz (10 Hz for large p: an eigh of p x p)
        self._act_every = max(1, int(round((0.02 if p <= 30 else 0.1) / self.dt)))
        self._k_act = 0
        self._act_proj: np.ndarray | None = None
        if self.P0 is not None:
            self._trP0 = float(np.trace(self.P0))
            self._L0 = np.linalg.cholesky(self.P0)
            self._L0inv = np.linalg.inv(self._L0)
        self._n_persist = 2.0 * float(persist_tau_s) / self.dt

    def carry_from(self, other: "CompositeLaw") -> None:
        """Take over what ``other`` learned about theta (its covariance and residual level) for
        the next insertion of the same tool (``run.insertions``); filters start afresh."""
        if other.P is not None and self.P is not None and other.P.shape == self.P.shape:
            self.P[...] = other.P
        self.r2[...] = other.r2
        self.r1[...] = other.r1
        self._r2_primed = other._r2_primed
        if other.theta_kf is not None:
            self.theta_kf = other.theta_kf.copy()
            self.theta_prior = other.theta_prior.copy()

    def identified_directions(self) -> int | None:
        """How many directions of theta the controller acts on (kalman law), else None."""
        if self.P is None or self._act_proj is None:
            return None if self.P is None else 0
        return int(round(float(np.trace(self._act_proj))))

    def uncertainty_ratio(self) -> float:
        """``sqrt(tr P / tr P0)``: the remaining uncertainty of theta as a fraction of the prior;
        means the same for every features type (NaN for the laws without a covariance)."""
        if self.P is None:
            return math.nan
        return math.sqrt(max(float(np.trace(self.P)), 0.0) / self._trP0)

    def information_sd(self) -> np.ndarray | None:
        """Posterior standard deviation of each parameter, sqrt(diag P) (kalman mode), else None."""
        return None if self.P is None else np.sqrt(np.clip(np.diag(self.P), 0.0, None))

    def project(self, theta: np.ndarray) -> np.ndarray:
        """Euclidean projection onto the box Omega."""
        return np.minimum(np.maximum(theta, self.lo), self.hi)

    def update(
        self,
        kin: KinState,
        qdot: np.ndarray,
        theta: np.ndarray,
        s: np.ndarray,
        s_dot_meas: np.ndarray,
        F: np.ndarray,
        w_env: np.ndarray,
        reg: Regressor | None = None,
    ) -> tuple[np.ndarray, AdaptStep]:
        """One step of eq. ft_composite. Returns (theta_next (p,), AdaptStep).

        ``s_dot_meas`` is the filtered measured rate, ``F`` the value force (raw units),
        ``w_env`` the tared contact wrench (for the contact gate); ``reg`` the regressor on the
        realised velocity ``qdot`` if the caller already has it.
        """
        if reg is None:
            reg = self.features.regressor(kin, qdot)
        self.known_f(reg.known)
        self.Phi_f(reg.Phi)
        return self.step_filtered(theta, reg.Phi.T, s_dot_meas, F, w_env)

    def step_filtered(
        self, theta: np.ndarray, Phi_r_T: np.ndarray, s_dot_meas: np.ndarray, F: np.ndarray, w_env: np.ndarray
    ) -> tuple[np.ndarray, AdaptStep]:
        """eq. ft_composite after the filters have run (``known_f``, ``Phi_f`` hold this step's
        values). ``Phi_r_T`` (p, m) is the realised (unfiltered) regressor, transposed."""
        Phi_fT = self._Phi_fT
        pred = theta.dot(Phi_fT)
        pred += self.known_f.z  # known_f + Phi_f theta
        eps_w = s_dot_meas - pred
        eps_w *= self.W  # eq. ft_pred, W-scaled
        w0, w1, w2, w3, w4, w5 = w_env.tolist()
        fn = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
        mn = math.sqrt(w3 * w3 + w4 * w4 + w5 * w5)
        if not (fn >= self.f_gate or mn >= self.m_gate):  # free space: gate g_k = 0
            return theta, AdaptStep(pred, eps_w, self._zero_p, self._zero_p, 0.0, 0.0)
        Phi_wT = Phi_fT * self.W  # (W Phi_f)^T
        G = Phi_wT.dot(Phi_wT.T)  # (W Phi_f)^T (W Phi_f), shared by the Gram log and ||W Phi_f||_2^2
        self.gram_sum += G  # observability: <Phi^T Phi> over the contact phase
        self.gram_n += 1
        if self.mode == "frozen":
            return theta, AdaptStep(pred, eps_w, self._zero_p, self._zero_p, 1.0, 0.0)
        if self.mode == "kalman":
            return self._kalman(theta, Phi_wT, Phi_r_T, eps_w, F, pred, G)
        if self._use_track:
            d_track = Phi_r_T.dot(F)
            d_track *= self._c_track  # eq. ft_composite, 1st term: -dt Gamma gamma_d Phi_r^T F
            theta_next = theta + d_track
        else:
            d_track, theta_next = self._zero_p, theta.copy()
        if self._use_pred:
            n2 = _spectral_norm2(G) if Phi_wT.shape[0] <= Phi_wT.shape[1] else _spectral_norm2(Phi_wT.T.dot(Phi_wT))
            d_pred = Phi_wT.dot(eps_w)
            d_pred *= self.eta / (n2 + self.eps_norm)  # eq. ident_qp_solution (fractional, normalised)
            theta_next += d_pred
        else:
            d_pred, n2 = self._zero_p, 0.0
        np.maximum(theta_next, self.lo, out=theta_next)  # Proj_Omega (clip)
        np.minimum(theta_next, self.hi, out=theta_next)
        return theta_next, AdaptStep(pred, eps_w, d_track, d_pred, 1.0, n2)

    def _kalman(self, theta: np.ndarray, Phi_wT: np.ndarray, Phi_r_T: np.ndarray, eps_w: np.ndarray, F: np.ndarray,
                pred: np.ndarray, G: np.ndarray) -> tuple[np.ndarray, AdaptStep]:
        """The information-weighted step (module docstring). Phi_wT (p, m) = (W Phi_f)^T."""
        e2 = eps_w * eps_w
        if not self._r2_primed:
            self.r2[:] = e2
            self.r1[:] = 0.0
            self._r2_primed = True
        else:
            self.r2 += self._r_alpha * (e2 - self.r2)  # measured residual level (bias included)
            self.r1 += self._m_alpha * (eps_w - self.r1)  # its slow mean: the persistent part
        # samples per independent observation: corr_s/dt, or more where the residual persists
        # (a bias that keeps its sign is one observation per 2 tau_m, not one per step)
        n_eff = np.maximum(self._n_corr, self._n_persist * (self.r1 * self.r1) / (self.r2 + self._r_floor))
        P = self.P
        if self.theta_kf is None:  # the filter's own estimate (the controller acts on its identified part)
            self.theta_kf = theta.copy()
            self.theta_prior = theta.copy()
        th = self.theta_kf
        e_kf = eps_w - (th - theta).dot(Phi_wT)  # innovation of the filter's estimate
        try:
            d_pred = kalman_update(P, Phi_wT, e_kf, (self.r2 + self._r_floor) * n_eff)  # updates P in place
        except np.linalg.LinAlgError:
            return theta, AdaptStep(pred, eps_w, self._zero_p, self._zero_p, 1.0, 0.0)
        th += d_pred
        if self.gamma_d > 0.0:
            d_track = P.dot(Phi_r_T.dot(F))
            d_track *= -self.dt * self.gamma_d  # eq. ft_composite's tracking term with Gamma = P
            th += d_track
        else:
            d_track = self._zero_p
        np.maximum(th, self.lo, out=th)  # Proj_Omega (clip)
        np.minimum(th, self.hi, out=th)
        self._k_act += 1
        if self._k_act >= self._act_every or self._act_proj is None:
            self._k_act = 0
            self._act_proj = self._identified_projector()
        theta_next = self.theta_prior + self._act_proj.dot(th - self.theta_prior)
        n2 = float(np.trace(G))
        return theta_next, AdaptStep(pred, eps_w, d_track, d_pred, 1.0, n2)

    def _identified_projector(self) -> np.ndarray:
        """Projector (p, p) onto the directions of theta the data have identified: in the prior's
        whitened coordinates (``P0 = L L^T``), the eigen-directions of ``L^-1 P L^-T`` whose
        posterior sd has fallen below ``act_sd_ratio`` of the prior sd. The controller acts on
        the estimate only there; elsewhere theta stays at the prior."""
        if self._act_ratio >= 1.0:
            return np.eye(len(self.P))
        M = self._L0inv.dot(self.P).dot(self._L0inv.T)
        lam, V = np.linalg.eigh(0.5 * (M + M.T))
        U = V[:, lam < self._act_ratio**2]  # identified, whitened
        Lw = self._L0.dot(U)  # back to theta coordinates: span L U, oblique projector along the rest
        return Lw.dot(U.T).dot(self._L0inv)
