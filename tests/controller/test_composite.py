"""The composite law (controller/laws/composite.py): identities of the paper checked against
independent numerics, on the law's own numba step."""

from __future__ import annotations

import numpy as np
import pytest

from kinadapt_nn.config import load_config
from kinadapt_nn.controller.laws import composite, prediction, tracking
from kinadapt_nn.controller.standalone import StandaloneLaw
from kinadapt_nn.runs.build import make_controller
from kinadapt_nn.runs.episode import run_episode
from kinadapt_nn.features.base import Features, KinState, Regressor
from tests.controller.law_reference import exact_qp_step, one_law_step


class PerEntryFeatures(Features):
    """J_ij = theta_ij^T psi(q) (the paper's per-entry blocks), psi a fixed random map of q.

    theta is stored flat in (i, j, k) order; p = m n k. A test double for the law's algebra."""

    name = "per_entry_test"

    def __init__(self, m: int, n: int, k: int, seed: int = 0) -> None:
        self.m, self.n, self.k = m, n, k
        self.n_params = m * n * k
        self.A = np.random.default_rng(seed).normal(size=(k, n))

    def psi(self, q: np.ndarray) -> np.ndarray:
        return np.tanh(self.A @ q)

    def jacobian(self, kin: KinState, theta: np.ndarray) -> np.ndarray:
        return np.einsum("ijk,k->ij", theta.reshape(self.m, self.n, self.k), self.psi(kin.q_rad))

    def regressor(self, kin: KinState, qdot: np.ndarray) -> Regressor:
        psi = self.psi(kin.q_rad)
        Phi = np.zeros((self.m, self.m, self.n, self.k))
        for i in range(self.m):
            Phi[i, i] = np.outer(qdot, psi)
        return Regressor(known=np.zeros(self.m), Phi=Phi.reshape(self.m, -1))


def _kin(q):
    return KinState(q_rad=q, p_w_O=np.zeros(3), R_wf=np.eye(3), J_arm=np.zeros((6, q.size)))


def test_trace_identity_eq_pred_trace_identity():
    """tr(theta~^T Y^T eps qdot^T) = (J~ qdot)^T eps, with Y as the per-entry tensor, and the same
    number through the regressor: theta~^T Phi^T eps."""
    rng = np.random.default_rng(1)
    m, n, k = 6, 7, 5
    feats = PerEntryFeatures(m, n, k)
    q, qdot, eps = rng.normal(size=n), rng.normal(size=n), rng.normal(size=m)
    th = rng.normal(size=(m, n, k))
    psi = feats.psi(q)
    # paper form: sum_ijk theta~_ijk (Y^T eps qdot^T)_ijk with (Y^T eps qdot^T)_ijk = psi_k eps_i qdot_j
    lhs = np.einsum("ijk,k,i,j->", th, psi, eps, qdot)
    J_tilde = feats.jacobian(_kin(q), th.ravel())
    assert lhs == pytest.approx((J_tilde @ qdot) @ eps, rel=1e-12)
    Phi = feats.regressor(_kin(q), qdot).Phi
    assert th.ravel() @ (Phi.T @ eps) == pytest.approx(lhs, rel=1e-12)


def test_prediction_step_equals_closed_form_for_per_entry_features():
    """eta = 1: the composite law's prediction step is eq. ident_qp_solution, Y^T eps qdot^T /
    (|psi|^2 |qdot|^2 + eps_norm), and also the exact QP minimiser Phi^T (Phi Phi^T + eps_norm I)^-1 eps
    (with F = 0 the tracking term is zero and theta_next = theta + d_pred)."""
    rng = np.random.default_rng(2)
    m, n, k = 6, 7, 4
    feats = PerEntryFeatures(m, n, k)
    q, qdot, eps = rng.normal(size=n), rng.normal(size=n), rng.normal(size=m)
    Phi = feats.regressor(_kin(q), qdot).Phi
    eps_norm = 1e-4
    theta_next, a, _ = one_law_step("composite", Phi, eps, eta=1.0, eps_norm=eps_norm)
    step, n2 = a.d_pred, a.phi_norm2
    psi = feats.psi(q)
    closed = np.einsum("k,i,j->ijk", psi, eps, qdot).ravel() / (psi @ psi * (qdot @ qdot) + eps_norm)
    np.testing.assert_allclose(step, closed, rtol=1e-12)
    np.testing.assert_allclose(step, exact_qp_step(Phi, eps, eps_norm), rtol=1e-10)
    np.testing.assert_array_equal(theta_next, step)
    assert not a.d_track.any() and a.gate == 1.0
    assert n2 == pytest.approx(psi @ psi * (qdot @ qdot), rel=1e-12)
    # fractional step: eta scales it and its size does not depend on Gamma
    for gamma in (100.0, 8000.0):
        _, half, _ = one_law_step("composite", Phi, eps, eta=0.5, eps_norm=eps_norm, gamma=gamma)
        np.testing.assert_allclose(half.d_pred, 0.5 * closed, rtol=1e-12)


def test_composite_step_is_the_sum_of_the_tracking_and_prediction_terms():
    """The numba step called from Python on numpy arrays (it is the reference the kernels call):
    theta_next = Proj_Omega(theta + d_track + d_pred), d_track = -dt Gamma gamma_d Phi_r^T F,
    d_pred = eta H^T e / (||H||_2^2 + eps_norm); prediction.py and tracking.py give their term only."""
    rng = np.random.default_rng(5)
    m, p = 6, 3
    H = rng.normal(size=(m, p))
    e, F, theta = rng.normal(size=m), rng.normal(size=m), 0.01 * rng.normal(size=p)
    PhiF = rng.normal(size=(m, p)).T @ F  # the realised regressor's Phi_r^T F
    lo, hi = np.full(p, -0.012), np.full(p, 0.012)
    dt, gamma, gamma_d, eta, eps_norm = 1e-3, 100.0, 1e-3, 0.5, 1e-4
    n2 = np.linalg.eigvalsh(H.T @ H)[-1]
    d_track = -dt * gamma * gamma_d * PhiF
    d_pred = eta * H.T @ e / (n2 + eps_norm)
    c_track = -dt * gamma * gamma_d
    consts = {"composite": np.array([c_track, eta, eps_norm]), "tracking": np.array([c_track]),
              "prediction": np.array([eta, eps_norm])}
    expect = {"composite": (d_track, d_pred, n2), "tracking": (d_track, 0 * d_pred, 0.0),
              "prediction": (0 * d_track, d_pred, n2)}
    for name, mod in (("composite", composite), ("tracking", tracking), ("prediction", prediction)):
        th = theta.copy()
        dtr, dpr = np.zeros(p), np.zeros(p)
        got = mod.step(th, np.ascontiguousarray(H.T), H.T @ H, e, PhiF, lo, hi, consts[name], np.zeros(0),
                       np.zeros(0, dtype=np.int64), np.full(1, np.nan), dtr, dpr)
        et, ep, en2 = expect[name]
        np.testing.assert_allclose(dtr, et, rtol=1e-13, atol=1e-18)
        np.testing.assert_allclose(dpr, ep, rtol=1e-13, atol=1e-18)
        assert got == pytest.approx(en2, rel=1e-12)
        np.testing.assert_allclose(th, np.clip(theta + et + ep, lo, hi), rtol=1e-13, atol=1e-18)


def test_nlms_step_contracts_the_parametric_error():
    """With b = 0 (eps = Phi theta~) one fractional step shrinks |Phi theta~| by (1 - eta) on
    per-entry features (normalised LMS is stable for 0 < eta < 2), whatever Gamma is."""
    rng = np.random.default_rng(3)
    feats = PerEntryFeatures(6, 7, 3)
    q, qdot = rng.normal(size=7), rng.normal(size=7)
    Phi = feats.regressor(_kin(q), qdot).Phi
    th_err = rng.normal(size=feats.n_params)
    for eta in (0.5, 1.0, 1.5):
        step = one_law_step("composite", Phi, Phi @ th_err, eta=eta, eps_norm=0.0)[1].d_pred
        after = Phi @ (th_err - step)
        assert np.linalg.norm(after) == pytest.approx(abs(1 - eta) * np.linalg.norm(Phi @ th_err), rel=1e-9)


def test_rigid_lyapunov_derivative_eq_composite_vdot():
    """Rigid case with the adjoint features and our law's increments: along qdot = J_hat^T F and
    s_dot = J qdot, d/dt [gamma_d V + |theta~|^2/(2 Gamma)] = -gamma_d |qdot|^2 - kappa |W J~ qdot|^2
    (eq. composite_vdot with the gamma_d weight), kappa = eta / (dt Gamma (|W Phi|^2 + eps_norm))."""
    cfg = load_config(None, ["sensing.filter_tau_s=1e-12"])  # no filter lag: the law sees eps = J~ qdot
    ctrl = make_controller(cfg)
    feats = ctrl.features
    rng = np.random.default_rng(4)
    for trial in range(5):
        q = np.array([0.1, -0.6, 0.05, -2.4, 0.02, 1.9, 0.7]) + 0.1 * rng.normal(size=7)
        kin = ctrl.kin(q)
        theta_true = np.array([0.003, -0.002, 0.1]) + 0.002 * rng.normal(size=3)
        theta_hat = theta_true + 0.005 * rng.normal(size=3)
        F = rng.normal(size=6) * np.array([10.0, 1e-4, 1e-4, 1e-3, 1e-3, 1e-3])  # [N, m, m, rad...]
        J_hat = feats.jacobian(kin, theta_hat)
        J_true = feats.jacobian(kin, theta_true)
        qdot = J_hat.T @ F  # eq. ft_control
        s_dot = J_true @ qdot
        law = StandaloneLaw.of(ctrl.known, feats, "composite")  # the controller's law, stand-alone
        w_contact = np.array([5.0, 0, 0, 0, 0, 0])  # gate open
        reg = feats.regressor(kin, qdot)
        theta_next, a = law.update(reg.known, reg.Phi, theta_hat, s_dot, F, w_contact)
        ad, dt = cfg.adaptation, cfg.run.dt_s
        G, gd = ad.gamma, ad.gamma_d
        theta_dot = (a.d_track + a.d_pred) / dt
        Vdot = gd * (-(F @ s_dot)) + (theta_hat - theta_true) @ theta_dot / G  # d/dt of 1/2 |theta~|^2 / Gamma
        kappa = ad.eta / (dt * G * (a.phi_norm2 + ad.eps_norm))
        expected = -gd * (qdot @ qdot) - kappa * np.sum((ctrl.W * ((J_true - J_hat) @ qdot)) ** 2)
        assert Vdot == pytest.approx(expected, rel=1e-6, abs=1e-14)  # filter alpha = 1 - 1e-9
        assert expected < 0.0


def test_gate_freezes_adaptation_in_free_space_and_projection_keeps_omega():
    cfg = load_config(None, [])
    ctrl = make_controller(cfg)
    lo, hi = ctrl.consts.pv[0], ctrl.consts.pv[1]
    kin = ctrl.kin(np.array([0.0, -0.6, 0.0, -2.4, 0.0, 1.9, 0.7]))
    reg = ctrl.features.regressor(kin, np.full(7, 0.1))
    th = np.array([0.007, -0.005, 0.1])
    big = np.full(6, 100.0)
    for name in ("kalman", "composite"):
        law = StandaloneLaw.of(ctrl.known, ctrl.features, name)  # the controller's law, stand-alone
        same, a = law.update(reg.known, reg.Phi, th, big, np.ones(6), np.zeros(6))  # no contact
        assert a.gate == 0.0 and np.array_equal(same, th)
        moved, a = law.update(reg.known, reg.Phi, th, big, np.ones(6), np.array([0, 0, 5.0, 0, 0, 0]))
        assert a.gate == 1.0 and a.d_pred.any()  # in contact the law adapts (kalman: its own estimate first)
        assert np.all(moved >= lo - 1e-15) and np.all(moved <= hi + 1e-15)


@pytest.fixture(scope="module")
def low_bias_runs():
    over = ["scene.contact_model=socket", "control.dither_rad_s=[0.05,0.05,0.05]", "run.progress=false"]
    return {g: run_episode(load_config(None, over + [f"adaptation.gamma={g}"])) for g in (100.0, 8000.0)}


def test_identification_where_the_bias_is_small(low_bias_runs):
    """Socket contact (S's own contact model) + commanded rotation: the 5 mm lateral error falls
    below 1 mm, as Theorem ft_rigid predicts when b / sigma_min is small."""
    s = low_bias_runs[100.0].summary
    assert s["success"]
    assert s["offset_error_lateral_initial_m"] == pytest.approx(0.005, abs=1e-9)
    assert s["offset_error_lateral_final_m"] < 1.0e-3
    assert abs(s["offset_error_final_m"][2]) < 1.0e-3


def test_gain_flat_gamma_100_and_8000_both_seat(low_bias_runs):
    """Gamma = 100 and 8000 both seat with the same seat time (normalised prediction step)."""
    a, b = low_bias_runs[100.0].summary, low_bias_runs[8000.0].summary
    assert a["success"] and b["success"]
    assert abs(a["seat_time_s"] - b["seat_time_s"]) < 0.1
    assert abs(a["offset_error_lateral_final_m"] - b["offset_error_lateral_final_m"]) < 0.5e-3


def test_default_run_seats_and_reports_identification(default_episode):
    """The paper's setting (bore, no dither), default (kalman) law: it seats; the report says how
    observable each axis was; the contact bias dominates, so nothing is identified and the
    Jacobian does not get worse (the paper's composite law ends 7x worse here: README)."""
    s = default_episode.summary
    assert s["success"] and s["law"] == "kalman" and s["features"] == "adjoint"
    assert s["identification"]["identified"] == 0 and "nothing identified" in s["identification"]["text"]
    assert s["jacobian_rel_error_final"] <= s["jacobian_rel_error_initial"] * 1.001
    g = s["regressor_gram"]
    assert g["axes"] == ["x_f", "y_f", "z_f"] and len(g["eigenvalues"]) == 3
    assert len(s["theta_sd_data_only"]) == 3
    assert s["certificate"]["windows"] > 50


def test_tracking_only_self_extinguishes_with_per_entry_features():
    """Remark cls_self_extinguish on the Panda's rigid tip-position loop: with per-entry RBF
    features the tracking-only law kills the command at the rate of eq. cls_command_decay while
    the error stays; the composite law removes it; the 3-parameter adjoint does not extinguish."""
    from kinadapt_nn.paper.rigid_demo import run_rigid_demo

    tr = run_rigid_demo("per_entry", "tracking", duration_s=0.6)
    k = np.searchsorted(tr.t_s, 0.02)
    measured = -np.log(tr.command_norm[k] / tr.command_norm[1]) / (tr.t_s[k] - tr.t_s[1])
    predicted = tr.predicted_rate[1:k].mean()
    assert measured == pytest.approx(predicted, rel=0.3)
    assert tr.command_norm[-1] < 1e-3 * tr.command_norm[0]
    assert tr.error_norm[-1] > 0.85 * tr.error_norm[0]  # stuck away from the goal
    comp = run_rigid_demo("per_entry", "composite", duration_s=0.6)
    assert comp.error_norm[-1] < 0.6 * comp.error_norm[0] and comp.command_norm[-1] > 0.2 * comp.command_norm[0]
    adj = run_rigid_demo("adjoint", "tracking", duration_s=0.6)
    assert adj.error_norm[-1] < 0.6 * adj.error_norm[0]
