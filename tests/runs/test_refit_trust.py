"""The refit's trust region between insertions (``cell.refit_step_sd``, docs/cell.md): the estimate
the controller acts on moves towards each new refit by at most ``step_sd`` posterior sd. Checked
against an independent computation of the step's length (the posterior's eigen-decomposition) and
against the refit's own estimate without the trust region."""

from __future__ import annotations

import numpy as np
import pytest

from kinadapt_nn.config import load_config
from kinadapt_nn.runs.build import make_controller
from kinadapt_nn.runs.refit import Refit

BORES = "cell.bores_w_m=[[0.45,0.0,0.30],[0.55,0.15,0.25],[0.38,-0.2,0.35]]"


@pytest.fixture(scope="module")
def ctrl():
    return make_controller(load_config(None, [BORES, "cell.heldout_per_bore=1", "cell.between=refit"]))


def _refit(ctrl, step_sd: float, **kw) -> Refit:
    rf = Refit(ctrl, **kw)
    rf.step_sd = step_sd
    return rf


def _mahalanobis(d: np.ndarray, P: np.ndarray) -> float:
    lam, V = np.linalg.eigh(P)
    return float(np.sqrt(np.sum((V.T @ d) ** 2 / lam)))


def test_trust_step_is_bounded_in_the_posterior_metric(ctrl):
    rng = np.random.default_rng(3)
    A = rng.normal(size=(3, 3)) * 1e-3
    P = A @ A.T + 1e-8 * np.eye(3)  # a posterior covariance [m^2]
    acted = rng.normal(size=3) * 1e-3
    rf = _refit(ctrl, 0.5)
    far = acted + 4.0 * np.linalg.cholesky(P) @ rng.normal(size=3)  # several sd away
    out = rf.trust_step(acted, far, P)
    assert _mahalanobis(far - acted, P) > 1.0
    assert rf.step == pytest.approx(_mahalanobis(far - acted, P), rel=1e-9)
    assert _mahalanobis(out - acted, P) == pytest.approx(0.5, rel=1e-9)  # on the boundary
    t = (out - acted) @ (far - acted) / ((far - acted) @ (far - acted))
    assert 0.0 < t < 1.0 and np.allclose(out, acted + t * (far - acted), atol=1e-15)  # on the segment
    near = acted + 0.2 * (far - acted) / _mahalanobis(far - acted, P)  # 0.2 sd: inside
    assert np.array_equal(rf.trust_step(acted, near, P), near)
    assert np.array_equal(_refit(ctrl, 0.0).trust_step(acted, far, P), far)  # off


def _insertion(rng, th_true: np.ndarray, rows: int = 40) -> tuple[np.ndarray, np.ndarray]:
    H = rng.normal(size=(rows, 2, 3)) * 30.0
    return H, np.einsum("kmp,p->km", H, th_true) + rng.normal(size=(rows, 2)) * 0.05


def test_after_insertion_acts_on_the_bounded_step_and_hands_it_to_the_law(ctrl):
    """First refit: acted on as it is. Later: the acted estimate moves from the last acted one
    towards the unbounded refit (the same data without the trust region) by step_sd posterior sd
    when the full step is larger; the kalman law then goes on from the acted estimate."""
    rng = np.random.default_rng(4)
    th_true = ctrl.theta0 + np.array([0.004, -0.003, 0.002])
    # the later insertions see another theta: something the model does not contain moves the refit
    ins = [_insertion(rng, th_true)] + [_insertion(rng, th_true + np.array([0.003, 0.003, -0.003])) for _ in range(2)]
    free = _refit(ctrl, 0.0, channels=(1, 2))
    rf = _refit(ctrl, 0.5, channels=(1, 2))
    law = ctrl._law_state
    prev = None
    for k, d in enumerate(ins):
        for r in (free, rf):
            r.add = lambda trace, r=r, d=d: (r.data.append(d), len(d[1]))[1]  # the logged rows, synthetic
        free.after_insertion(None)
        want = ctrl.state.theta[0].copy()  # the unbounded refit's acted estimate
        _, P, _ = rf.solve(ins[:k + 1])
        rf.after_insertion(None)
        got = ctrl.state.theta[0].copy()
        if k == 0:
            assert np.array_equal(got, want)
        else:
            full = _mahalanobis(want - prev, P)
            assert full > 0.5  # these insertions move the estimate by more than the region
            assert _mahalanobis(got - prev, P) == pytest.approx(0.5, rel=1e-6)
            assert np.allclose(got, prev + (0.5 / full) * (want - prev), rtol=0, atol=1e-12)
            assert np.array_equal(law.blocks["theta_kf"][0], got)
        prev = got


def test_the_cell_config_hands_the_trust_region_to_the_refit():
    from kinadapt_nn.runs.insertions import _Cell

    for over, want in (([], 0.5), (["cell.refit_step_sd=0"], 0.0), (["cell.refit_step_sd=2"], 2.0)):
        cfg = load_config(None, [BORES, "cell.heldout_per_bore=1", "cell.between=refit", *over])
        assert _Cell(cfg, make_controller(cfg)).refit.step_sd == want


def test_a_change_of_prior_is_acted_on_as_it_is(ctrl):
    """The evidence prior (``alt_prior_cov``): a refit whose prior choice differs from the refit
    before acts on its own estimate unbounded (the step between two models' estimates is not a step
    of one pooled estimate); the next refit under the same prior is bounded again. Checked against
    the same refit without the trust region and against the step's length in the posterior metric."""
    rng = np.random.default_rng(5)
    from kinadapt_nn.controller.controller import prior_cov_of

    L0 = np.linalg.cholesky(np.asarray(prior_cov_of(ctrl.features), dtype=float))
    alt = L0 @ np.diag([1.0, 1e-6, 1e-6]) @ L0.T  # the simpler prior: direction 1 only
    th_true = ctrl.theta0 + L0 @ np.array([0.5, 1.5, -1.5])  # needs the directions the simpler one holds
    weak = _insertion(rng, th_true, rows=3)
    weak = (weak[0] * 1e-3, np.einsum("kmp,p->km", weak[0] * 1e-3, th_true) + rng.normal(size=(3, 2)) * 0.05)
    ins = [weak, _insertion(rng, th_true), _insertion(rng, th_true + L0 @ np.array([0.0, 0.3, 0.3]))]
    kw = dict(channels=(1, 2), alt_prior_cov=alt, alt_evidence_per_insertion=5.0)
    free, rf = _refit(ctrl, 0.0, **kw), _refit(ctrl, 0.5, **kw)
    law = ctrl._law_state
    prev, notes = None, []
    for k, d in enumerate(ins):
        for r in (free, rf):
            r.add = lambda trace, r=r, d=d: (r.data.append(d), len(d[1]))[1]  # the logged rows, synthetic
        free.after_insertion(None)
        want = ctrl.state.theta[0].copy()
        want_kf = law.blocks["theta_kf"][0].copy()
        notes.append(rf.after_insertion(None))
        got = ctrl.state.theta[0].copy()
        _, P, _ = rf.solve(ins[:k + 1])
        if k == 1:  # the weak first insertion chose the simpler prior, the second the features' own
            assert notes[0]["simpler_prior"] and not notes[1]["simpler_prior"] and notes[1]["prior_switched"]
            assert _mahalanobis(want - prev, P) > 5.0  # the region would have held it
            assert np.array_equal(got, want) and np.array_equal(law.blocks["theta_kf"][0], want_kf)
        elif k == 2:  # the same prior again: bounded
            assert not notes[2]["simpler_prior"] and not notes[2]["prior_switched"]
            full = _mahalanobis(want - prev, P)
            assert full > 0.5
            assert np.allclose(got, prev + (0.5 / full) * (want - prev), rtol=0, atol=1e-12)
        prev = got
