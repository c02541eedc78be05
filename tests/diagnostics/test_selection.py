"""The verdict engine on synthetic designs whose answer is known by construction."""

from __future__ import annotations

import numpy as np

from kinadapt_nn.diagnostics import selection as sel


def _design(y, X, Z=None, blocks=20, one_of=None, scale=None, W=None):
    R = len(y)
    block = np.minimum(np.arange(R) * blocks // R, blocks - 1)
    return sel.Design(y, X, np.zeros((R, 0)) if Z is None else Z, block, blocks,
                      scale or {n: np.ones(x.shape[1]) for n, x in X.items()},
                      one_of or {n: False for n in X}, np.ones(R) if W is None else W,
                      np.zeros(R, int), ("y",), np.arange(R) * 0.01)


def _smooth_cols(rng, R, k):
    t = np.linspace(0, 1, R)[:, None]
    return np.sin(2 * np.pi * (rng.uniform(1, 4, k) * t + rng.uniform(0, 1, k)))


def test_present_absent_and_estimate():
    rng = np.random.default_rng(0)
    R = 4000
    X = {"a": _smooth_cols(rng, R, 2), "b": _smooth_cols(rng, R, 3), "c": _smooth_cols(rng, R, 1)}
    p_true = np.array([2.0, -1.5])
    y = X["a"] @ p_true + rng.normal(0, 0.3, R)
    res = sel.select(_design(y, X))
    v = {e["effect"]: e for e in res.entries}
    assert v["a"]["verdict"] == "present" and v["a"]["significant"]
    assert v["b"]["verdict"] == "absent" and v["c"]["verdict"] == "absent"
    assert res.entries[0]["effect"] == "a"
    np.testing.assert_allclose(res.present["a"][1], p_true, rtol=0.05)
    # the jackknife sd is of the right size (independent noise: sd ~ sigma / sqrt(R) / col rms)
    assert 0.2 < res.present["a"][2][0] / (0.3 / np.sqrt(R / 2)) < 5


def test_two_effects_both_and_jointly_reestimated():
    rng = np.random.default_rng(1)
    R = 4000
    Xa = _smooth_cols(rng, R, 1)
    Xb = 0.6 * Xa + 0.8 * _smooth_cols(rng, R, 1)  # correlated with a: a separate fit of a would be biased
    y = Xa[:, 0] * 1.0 + Xb[:, 0] * 2.0 + rng.normal(0, 0.1, R)
    res = sel.select(_design(y, {"a": Xa, "b": Xb}))
    assert {n for n in res.present} == {"a", "b"}
    np.testing.assert_allclose(res.present["a"][1], [1.0], rtol=0.05)
    np.testing.assert_allclose(res.present["b"][1], [2.0], rtol=0.05)


def test_identical_columns_are_a_near_tie_not_an_answer():
    rng = np.random.default_rng(2)
    R = 4000
    x = _smooth_cols(rng, R, 1)
    y = 1.5 * x[:, 0] + rng.normal(0, 0.1, R)
    res = sel.select(_design(y, {"a": x, "b": x.copy() * 2.0}))
    v = {e["effect"]: e for e in res.entries}
    assert v["a"]["verdict"] == v["b"]["verdict"] == "cannot_decide"
    assert "b" in v["a"]["indistinguishable_from"] and "a" in v["b"]["indistinguishable_from"]
    assert not res.present


def test_unexcited_direction_is_cannot_decide_and_stays_at_zero():
    rng = np.random.default_rng(3)
    R = 2000
    y = rng.normal(0, 1.0, R)
    X = {"seen": _smooth_cols(rng, R, 1), "unseen": np.zeros((R, 2))}
    X["unseen"][:, 0] = _smooth_cols(rng, R, 1)[:, 0]  # one column excited, one never
    res = sel.select(_design(y, X))
    v = {e["effect"]: e for e in res.entries}
    assert v["seen"]["verdict"] == "absent"
    assert v["unseen"]["verdict"] == "cannot_decide" and v["unseen"]["excitation"]["weak_parameters"] == [1]
    assert np.all(np.isfinite(v["unseen"]["params"])) and abs(v["unseen"]["params"][1]) < 1e-6


def test_below_relevant_magnitude_is_not_present():
    """A significant but tiny estimate (below the stated relevant magnitude) is not an effect."""
    rng = np.random.default_rng(4)
    R = 4000
    x = _smooth_cols(rng, R, 1)
    y = 0.05 * x[:, 0] + rng.normal(0, 0.01, R)
    res = sel.select(_design(y, {"a": x}, scale={"a": np.array([1.0])}))
    assert not res.present
    res2 = sel.select(_design(y, {"a": x}, scale={"a": np.array([0.01])}))
    assert "a" in res2.present


def test_implausible_estimate_is_never_present():
    rng = np.random.default_rng(5)
    R = 3000
    x = _smooth_cols(rng, R, 1)
    y = -2.0 * x[:, 0] + rng.normal(0, 0.1, R)
    res = sel.select(_design(y, {"mass": x}), plausible=lambda n, p: "negative" if p[0] < 0 else None)
    e = res.entries[0]
    assert e["verdict"] == "cannot_decide" and "impossible" in e["reason"]


def test_nuisance_is_always_fitted_and_not_an_effect():
    rng = np.random.default_rng(6)
    R = 3000
    Z = np.ones((R, 1))
    X = {"const_like": np.ones((R, 1)) + 1e-3 * _smooth_cols(rng, R, 1)}
    y = 5.0 + rng.normal(0, 0.1, R)
    res = sel.select(_design(y, X, Z=Z))
    assert not res.present
    np.testing.assert_allclose(res.nuisance, [5.0], rtol=0.01)


def test_refit_reports_the_fall():
    rng = np.random.default_rng(7)
    R = 2000
    X = {"a": _smooth_cols(rng, R, 2), "j": np.column_stack([np.zeros(R), _smooth_cols(rng, R, 1)[:, 0]])}
    y = X["j"][:, 1] * 3.0 + rng.normal(0, 0.1, R)
    before, after, fitted = sel.refit(_design(y, X, one_of={"a": False, "j": True}), ["j"])
    assert fitted["j"][0] == [1]
    np.testing.assert_allclose(fitted["j"][1], [0.0, 3.0], atol=0.05)
    assert np.sqrt(np.mean(after**2)) < 0.15 < np.sqrt(np.mean(before**2))


def test_a_column_that_grows_with_the_log_does_not_shrink_the_nuisance():
    """A drift column (rate x time) over a long log has an energy ~T^3 times the others'; the ridge
    is per column, so it neither shrinks the unit-norm offset nor biases the other effects: the
    selection's estimates equal ordinary least squares on [offset, a] (an hour-long tared log
    gave a wrong tool mass and a false frame rotation while one large column set a common ridge)."""
    rng = np.random.default_rng(8)
    R = 4000
    t = np.linspace(0.0, 3600.0, R)[:, None]  # [s] an hour
    X = {"a": _smooth_cols(rng, R, 2), "drift": t, "c": _smooth_cols(rng, R, 1)}
    Z = np.ones((R, 1))
    y = 4.0 + X["a"] @ np.array([2.0, -1.5]) + rng.normal(0, 0.3, R)
    res = sel.select(_design(y, X, Z=Z))
    v = {e["effect"]: e["verdict"] for e in res.entries}
    assert v == {"a": "present", "drift": "absent", "c": "absent"}
    ls = np.linalg.lstsq(np.column_stack([Z, X["a"]]), y, rcond=None)[0]
    np.testing.assert_allclose(res.present["a"][1], ls[1:], rtol=1e-6)
    np.testing.assert_allclose(res.nuisance, ls[:1], rtol=1e-6)


def test_an_impossible_selection_leaves_the_model_and_the_next_explanation_is_found():
    """An effect selected first whose estimate is physically impossible is no explanation: it is
    reported ``cannot_decide`` with that reason and left out of the final model, and the selection
    runs again without it, so the effect that is there is found (before, the impossible one stayed in
    the model beside it and the residual read as explained)."""
    rng = np.random.default_rng(7)
    R = 4000
    xb = _smooth_cols(rng, R, 1)
    xa = 0.9 * xb + 0.2 * _smooth_cols(rng, R, 1)  # a fits what b does nearly as well, and a bit more
    y = -3.0 * xa[:, 0] + 0.2 * xb[:, 0] + rng.normal(0, 0.05, R)  # a's fit is negative: impossible
    res = sel.select(_design(y, {"a": xa, "b": xb}), plausible=lambda n, p: "negative" if n == "a" and p[0] < 0 else None)
    v = {e["effect"]: e for e in res.entries}
    assert v["a"]["verdict"] == "cannot_decide" and v["a"]["left_out"], v["a"]
    assert v["a"]["reason"].startswith(sel.IMPOSSIBLE) and "left out of the model" in v["a"]["reason"]
    assert v["a"]["selected_round"] is None and "a" not in res.present
    assert v["b"]["verdict"] == "present", v["b"]
    assert v["b"]["selected_round"] == 0


def test_a_one_of_column_is_chosen_again_given_the_final_model():
    """A one-of effect's column is chosen when the effect is selected, given the effects selected before
    it; an effect selected later can make another column the better one (a joint's encoder offset
    against a parallel joint's, told apart once the tool's tilt is in the model). Constructed so that,
    alone, column 0 explains more (it shares a part with the later effect ``t``), while given ``t``
    column 1 explains everything and column 0 leaves its own third direction: the final model holds
    column 1 at its true value, and column 0 is no near-tie."""
    rng = np.random.default_rng(11)
    R = 4000
    x = np.linspace(0, 1, R)
    c1, t, u = (np.sin(2 * np.pi * f * x + ph) for f, ph in ((3, 0.2), (5, 0.9), (7, 1.7)))  # nearly orthogonal
    c0 = c1 + 0.5 * t + 0.3 * u
    y = 1.0 * c1 + 1.0 * t + rng.normal(0, 0.02, R)
    des = _design(y, {"enc": np.stack([c0, c1], axis=1), "t": t[:, None]}, one_of={"enc": True, "t": False},
                  scale={"enc": np.array([0.3, 0.3]), "t": np.array([0.3])})  # relevant sizes below the truth
    st = sel.Stats(des)
    alone = sel._test(st, des, "enc", st.z_idx, st.cv(st.z_idx, 1e-9)[0], sel.SelCfg())
    assert alone.cols == [0]  # what the forward round picks before t is in the model
    res = sel.select(des)
    v = {e["effect"]: e for e in res.entries}
    assert v["enc"]["verdict"] == "present" and v["t"]["verdict"] == "present", (v["enc"], v["t"])
    assert v["enc"]["columns_used"] == [1]
    np.testing.assert_allclose(res.present["enc"][1], [1.0], atol=0.02)
    np.testing.assert_allclose(res.present["t"][1], [1.0], atol=0.02)
    assert "indistinguishable_from" not in v["enc"]
