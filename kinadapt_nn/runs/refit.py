"""Between the insertions of a work cell: refit theta on every logged insertion (measured data only).

The online law sees each sample once, in order, and carries its conclusions forward; between two
insertions a robot has time to look at everything it has measured so far. ``Refit`` keeps, per
insertion, the law's own regression data on the contact samples (``adapt_gate = 1``), decimated
to ``decimate_s``:

    H_k = W Phi_f(q_k, qdot_k)          (m, p)   the law's filtered regressor, W-scaled
    y_k = eps_w,k + H_k theta_k         (m,)     = W (s_dot_meas - known_f): what Phi_f theta must explain

(``eps_w`` and ``theta`` are the logged prediction error and the estimate the controller used),
and solves the regularised least-squares problem of all insertions together (information form,
the batch counterpart of the kalman law; docs/equations.md#cell-refit):

    Lambda = P0^-1 + sum_j sum_k H_k^T R_j^-1 H_k / n_eff
    theta* = theta_prior + Lambda^-1 sum_j sum_k H_k^T R_j^-1 (y_k - H_k theta_prior) / n_eff,  P* = Lambda^-1

with R_j (m,) the residual variance of insertion j at the current solution (bias included, three
passes) and n_eff = corr_s / decimate_s the samples per independent observation. As the kalman law
does, the controller then acts on theta* only in the directions the data identified (posterior sd
below ``act_sd_ratio`` x the prior's, in the prior's whitened coordinates); elsewhere the prior
stays. Nothing here reads the truth: the trace's ``truth_*`` channels are never touched.

``timing_sd_s > 0`` (``cell.refit_timing_sd_s``) adds one unknown shared by all insertions: the
timing offset delta [s] between the F/T reading and the encoders, entering as one more column
``W d/dt(s_dot_pred)`` (the controller's own filtered prediction, differentiated): the measured rate
is modelled as the prediction delta seconds later, ``y ~ H theta + delta W d(s_dot_pred)/dt``, with
the prior delta ~ N(0, timing_sd_s^2): delta > 0 is a lead of the measured rate. On the simulated
cell the estimate is +1.20 ms (adjoint, nominal arm; -0.79 ms before the one-instant sensor of
4b95480, whose two 1-ms lags it removed: docs/cell.md): a bias proportional to the tip
acceleration that the 12 neural directions otherwise absorb.

Two options for the neural features (off by default; docs/cell.md "Five draws"):
``max_directions > 0`` (``cell.refit_max_directions_neural``) acts on at most that many of the
best-identified directions. ``alt_prior_cov`` with ``alt_evidence_per_insertion > 0``
(``cell.refit_neural_prior_choice``; the checkpoint's calibrated-arm prior) solves the same data
under that prior too. It acts on that estimate unless the features' own prior gains more than
``alt_evidence_per_insertion`` x (insertions pooled) in log marginal likelihood, computed with the
residual weights of the last pass.

``step_sd > 0`` (an attribute, set from ``cell.refit_step_sd``, default 0.5) is a trust region on what the controller acts
on: after the first refit, the acted estimate moves from the one it acted on before towards the new
refit by at most ``step_sd`` in the new posterior's metric, ``|d|_{P*^-1} = sqrt(d^T P*^-1 d) <=
step_sd``; the kalman law goes on from the acted estimate. The pooled estimate follows the part of
the data the model does not contain (the lateral-force bias) from one insertion to the next, and
the cell error then rose by up to 42 % between insertions (docs/cell.md). The region is a chosen
cap, not a test: it is smaller than the step a consistent estimate takes early on (about
sqrt(p / (k - 1)) posterior sd after insertion k), so it also slows the learning it keeps
never-worse (docs/cell.md: measured over five draws, with what it costs). The region bounds the
steps of one pooled estimate: a refit whose prior choice (the evidence prior above) differs from
the refit before it acts on its own estimate as it is. Across a change of prior the two estimates
belong to different models, and the new posterior's metric puts the old one far outside the region
in the directions the new prior holds near fixed (measured: 258-278 sd on the nominal tools of
seed 3000, where one insertion favoured the features' own prior and two the calibrated-arm one):
the region then held the acted estimate at the first refit's (docs/cell.md).
"""

from __future__ import annotations

import numpy as np

from kinadapt_nn.controller.controller import Controller, prior_cov_of
from kinadapt_nn.controller.laws import kalman


class Refit:
    """Pooled refit of theta over a work cell's logged insertions (see the module docstring)."""

    def __init__(self, ctrl: Controller, channels=(1, 2), prior_weight: float = 1.0, decimate_s: float = 0.01,
                 timing_sd_s: float = 0.0, max_directions: int = 0, alt_prior_cov: np.ndarray | None = None,
                 alt_evidence_per_insertion: float = 0.0) -> None:
        self.ctrl = ctrl
        ad = ctrl.known.adaptation
        self.P0 = np.asarray(prior_cov_of(ctrl.features), dtype=float)
        self.theta_prior = ctrl.theta0.copy()
        self._P0inv = np.linalg.inv(self.P0)
        self._L = np.linalg.cholesky(self.P0)
        self._Linv = np.linalg.inv(self._L)
        self.decimate_s = float(decimate_s)
        self.n_eff = max(1.0, ad.corr_s / self.decimate_s)
        self.act_ratio = float(ad.act_sd_ratio)
        self.r_floor = float(ad.resid_floor_w)
        self.channels = np.asarray(channels, dtype=int)
        self.max_directions = int(max_directions)  # > 0: act on at most this many best-identified directions
        self.prior_weight = float(prior_weight)
        self.data: list[tuple[np.ndarray, np.ndarray]] = []  # per insertion: H (N, m, p[+1]), y (N, m)
        # the sensor timing offset (F/T against encoders) as one more unknown, prior N(0, sd^2)
        self.timing_sd_s = float(timing_sd_s)
        p = len(self.theta_prior)
        self._prior_a = np.r_[self.theta_prior, 0.0] if self.timing_sd_s > 0 else self.theta_prior
        self._P0inv_a = self.prior_weight * self._P0inv
        if self.timing_sd_s > 0:
            self._P0inv_a = np.zeros((p + 1, p + 1))
            self._P0inv_a[:p, :p] = self.prior_weight * self._P0inv
            self._P0inv_a[p, p] = 1.0 / self.timing_sd_s**2
        self.timing_s = 0.0  #: [s] the estimated lead of the F/T rate over the encoders' prediction
        # A simpler prior (the neural checkpoint's calibrated-arm one: the tool offset only), used
        # unless the measured data favour the features' own prior by more than
        # ``alt_evidence_per_insertion`` x (insertions pooled) in log marginal likelihood.
        self.alt = None
        if alt_prior_cov is not None and alt_evidence_per_insertion > 0:
            if self.timing_sd_s > 0:
                raise ValueError("the refit's prior choice and its timing offset are not combined")
            C = np.asarray(alt_prior_cov, dtype=float)
            Lc = np.linalg.cholesky(C)
            self.alt = {"P0inv": self.prior_weight * np.linalg.inv(C), "L": Lc, "Linv": np.linalg.inv(Lc),
                        "per_insertion": float(alt_evidence_per_insertion)}
        self.log_evidence_gain = float("nan")  #: own prior minus the simpler one (the last solve)
        self.chose_alt = False  #: the last solve acted on the simpler prior's estimate
        self.identified = 0  #: directions the last solve acts on (the trace of its projector)
        self.step_sd = 0.0  #: > 0: the trust region on the acted estimate's step [posterior sd]; set by the caller
        self.acted: np.ndarray | None = None  #: the estimate acted on after the last refit
        self.acted_alt = False  #: that estimate is the simpler prior's
        self.step = float("nan")  #: the last refit's full step |d|_{P*^-1} (before the trust region)

    def add(self, trace) -> int:
        """Keep one insertion's contact samples (``trace`` from ``run_episode(keep_regressor=True)``;
        its ``law_Phi_fT`` is taken out of the trace). -> samples kept."""
        PhiT = trace.arrays.pop("law_Phi_fT")  # (N, p, m)
        dt = float(trace.meta["dt_s"])
        stride = max(1, int(round(self.decimate_s / dt)))
        on = np.flatnonzero((trace["adapt_gate"] > 0) & (trace["drive_scale"] > 0))
        on = on[::stride]
        W = self.ctrl.W
        H = PhiT[on].transpose(0, 2, 1) * W[None, :, None]  # (N, m, p)
        y = trace["eps_w"][on] + np.einsum("kmp,kp->km", H, trace["theta"][on])
        if self.timing_sd_s > 0:  # d/dt of the controller's own prediction: the timing offset's column
            g = np.gradient(trace["s_dot_pred"], dt, axis=0)[on] * W[None, :]
            H = np.concatenate([H, g[:, :, None]], axis=2)
        H, y = H[:, self.channels], y[:, self.channels]
        ok = np.all(np.isfinite(y), axis=1) & np.all(np.isfinite(H), axis=(1, 2))
        self.data.append((H[ok], y[ok]))
        return int(ok.sum())

    def solve(self, data=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The pooled estimate on ``data`` (default: every insertion kept). -> (theta* (p,),
        P* (p, p), the theta the controller acts on (p,))."""
        data = self.data if data is None else data
        p = len(self.theta_prior)
        prior = self._prior_a
        theta = prior.copy()
        for _ in range(3):  # residual levels at the current solution
            Lam = self._P0inv_a.copy()
            eta = np.zeros(len(prior))
            G = np.zeros_like(Lam)
            quad = 0.0
            for H, y in data:
                if not len(y):
                    continue
                r = y - np.einsum("kmp,p->km", H, theta)
                R = np.mean(r * r, axis=0) + self.r_floor  # (m,) bias included
                w = 1.0 / (R * self.n_eff)
                Hw = H * w[None, :, None]
                yc = y - np.einsum("kmp,p->km", H, prior)
                G += np.einsum("kmp,kmq->pq", Hw, H)
                eta += np.einsum("kmp,km->p", Hw, yc)
                quad += float(np.sum(yc * yc * w[None, :]))
            Lam += G
            theta = prior + np.linalg.solve(Lam, eta)
        L, Linv = self._L, self._Linv  # the prior acted on: the features' own, or the simpler one
        if self.alt is not None and len(data):  # the same data and weights under the simpler prior
            lam_a = self.alt["P0inv"] + G
            gain = self._log_evidence(quad, eta, Lam, G, self._L / np.sqrt(self.prior_weight)) \
                - self._log_evidence(quad, eta, lam_a, G, self.alt["L"] / np.sqrt(self.prior_weight))
            self.log_evidence_gain = float(gain)
            self.chose_alt = gain <= self.alt["per_insertion"] * len(data)
            if self.chose_alt:
                Lam, L, Linv = lam_a, self.alt["L"], self.alt["Linv"]
                theta = prior + np.linalg.solve(Lam, eta)
        P = np.linalg.inv(Lam)
        P = 0.5 * (P + P.T)
        if len(theta) > p:  # the timing offset: kept for the report; theta's marginal covariance
            self.timing_s = float(theta[p])
            theta, P = theta[:p], np.ascontiguousarray(P[:p, :p])
        lo, hi = self.ctrl.consts.pv[0], self.ctrl.consts.pv[1]
        theta = np.clip(theta, lo, hi)  # Proj_Omega, as the law
        A = self._identified(P, L, Linv)
        self.identified = int(round(float(np.trace(A))))  #: directions acted on at the last solve
        return theta, P, self.theta_prior + A @ (theta - self.theta_prior)

    def trust_step(self, acted: np.ndarray, new: np.ndarray, P: np.ndarray) -> np.ndarray:
        """The trust region (``step_sd > 0``): ``acted + d min(1, step_sd / |d|_{P^-1})``, d = new -
        acted (both (p,), P (p, p) the new posterior covariance); records ``|d|_{P^-1}`` in
        ``self.step``. ``step_sd = 0``: ``new``."""
        d = new - acted
        self.step = float(np.sqrt(max(0.0, d @ np.linalg.solve(P, d))))
        if self.step_sd <= 0 or self.step <= self.step_sd:
            return new
        return acted + d * (self.step_sd / self.step)

    @staticmethod
    def _log_evidence(quad: float, eta: np.ndarray, Lam: np.ndarray, G: np.ndarray, Lp: np.ndarray) -> float:
        """log p(y) of the linear-Gaussian model with fixed residual weights, up to the terms that
        do not depend on the prior: -1/2 yc'R^-1 yc + 1/2 eta' Lam^-1 eta - 1/2 log det(I + Lp' G Lp)
        (prior covariance Lp Lp', G = sum H'R^-1 H, eta = sum H'R^-1 yc, Lam = prior^-1 + G)."""
        p = len(eta)
        return float(-0.5 * quad + 0.5 * eta @ np.linalg.solve(Lam, eta)
                     - 0.5 * np.linalg.slogdet(np.eye(p) + Lp.T @ G @ Lp)[1])

    def _identified(self, P: np.ndarray, L: np.ndarray, Linv: np.ndarray) -> np.ndarray:
        """Projector (p, p) onto the identified directions: the kalman law's own
        (``kalman.identified_projector`` on the Cholesky factor ``L`` of the prior acted on)."""
        if 0 < self.max_directions < len(P):  # the cap: the k best-identified of those past the threshold
            M = Linv @ P @ Linv.T
            lam, V = np.linalg.eigh(0.5 * (M + M.T))  # ascending: the best-identified first
            sel = (lam < self.act_ratio**2) & (np.arange(len(lam)) < self.max_directions)
            U = V[:, sel]
            return L @ U @ U.T @ Linv
        A = np.empty_like(P)
        kalman.identified_projector(np.ascontiguousarray(P), L, Linv, self.act_ratio, A)
        return A

    def after_insertion(self, trace) -> dict:
        """Add the insertion, refit, and hand the controller the result (theta, and for the kalman
        law its covariance and filter estimate). -> a summary row fragment."""
        n = self.add(trace)
        theta_kf, P, theta_act = self.solve()
        # the prior acted on changed: another model's estimate, acted on as it is (module docstring)
        switched = self.alt is not None and self.acted is not None and self.chose_alt != self.acted_alt
        if self.acted is not None:
            bounded = self.trust_step(self.acted, theta_act, P)  # records the full step either way
            if self.step_sd > 0 and not switched:
                theta_act = theta_kf = bounded  # the law goes on from the estimate acted on
        self.acted, self.acted_alt = theta_act.copy(), self.chose_alt
        self.ctrl.state.theta[0] = theta_act
        law = self.ctrl._law_state
        if "P" in law.blocks:  # a law with a covariance (kalman): hand it the pooled posterior
            law.blocks["P"][0] = P
        if "theta_kf" in law.blocks:
            law.blocks["theta_kf"][0] = theta_kf
            law.blocks["theta_prior"][0] = self.theta_prior  # the refit's prior is the law's
            law.counters["kf_init"][0] = 1
        row = {"samples": n, "insertions_pooled": len(self.data), "identified": self.identified}
        if self.step_sd > 0 and len(self.data) > 1:  # the refit's full step, in posterior sd (before the region)
            row["step_posterior_sd"] = self.step
        if self.timing_sd_s > 0:
            row["timing_offset_s"] = self.timing_s
        if self.alt is not None:
            row["log_evidence_gain"] = self.log_evidence_gain
            row["simpler_prior"] = bool(self.chose_alt)
            row["prior_switched"] = bool(switched)
        return row
