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
``frozen`` (theta constant).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from kinadapt_nn.features.base import Features, KinState, Regressor
from kinadapt_nn.sensing import LowPass

MODES = ("composite", "prediction", "tracking", "frozen")


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
