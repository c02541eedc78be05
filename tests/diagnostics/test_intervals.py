"""Block-robust intervals from per-block normal equations (``diagnostics.intervals``): the sandwich
against the rows' own cluster formula, and against the spread of the estimate over many noise draws when
the rows' errors are correlated within a block (where the white-noise sd is too small)."""

from __future__ import annotations

import numpy as np
import pytest

from kinadapt_nn.diagnostics.intervals import honest_sd, sandwich_cov, white_cov


def _stats(X: np.ndarray, y: np.ndarray, block: np.ndarray, B: int):
    G = np.stack([X[block == b].T @ X[block == b] for b in range(B)])
    h = np.stack([X[block == b].T @ y[block == b] for b in range(B)])
    yy = np.array([y[block == b] @ y[block == b] for b in range(B)])
    return G, h, yy


def _rows(rng: np.random.Generator, n: int, B: int, rho: float):
    """n rows in B contiguous blocks; 2 slow regressors and AR(1) errors (coefficient rho) within a block."""
    t = np.linspace(0.0, 1.0, n)
    X = np.stack([np.sin(7 * t) + 0.3, np.cos(3 * t) * t], axis=1)
    block = np.minimum((t * B).astype(int), B - 1)
    e = np.zeros(n)
    w = rng.normal(size=n)
    for i in range(n):
        e[i] = (rho * e[i - 1] if i and block[i] == block[i - 1] else 0.0) + w[i]
    return X, X @ np.array([1.0, -2.0]) + e, block


def test_sandwich_is_the_cluster_formula_of_the_rows():
    """From the statistics it equals the rows' ``(X^T X)^-1 (sum_b X_b^T e_b e_b^T X_b) (X^T X)^-1 B/(B-k)``."""
    rng = np.random.default_rng(0)
    X, y, block = _rows(rng, 600, 12, 0.5)
    theta = np.linalg.lstsq(X, y, rcond=None)[0]
    e = y - X @ theta
    meat = sum(np.outer(X[block == b].T @ e[block == b], X[block == b].T @ e[block == b]) for b in range(12))
    Ai = np.linalg.inv(X.T @ X)
    G, h, yy = _stats(X, y, block, 12)
    np.testing.assert_allclose(sandwich_cov(G, h, theta), Ai @ meat @ Ai * 12 / 10, rtol=1e-8)
    s2 = e @ e / (600 - 2)
    np.testing.assert_allclose(white_cov(G, h, yy, theta, 600), s2 * Ai, rtol=1e-8)


def test_honest_sd_covers_correlated_errors_where_white_noise_does_not():
    """AR(1) errors (rho 0.95) within 40 blocks: the white-noise sd is several times the estimates' true
    spread too small; the honest sd is within 35 % of it and its intervals hold the truth in >= 88 % of 300
    draws."""
    rng = np.random.default_rng(1)
    est, sd_w, sd_h = [], [], []
    for _ in range(300):
        X, y, block = _rows(rng, 2000, 40, 0.95)
        G, h, yy = _stats(X, y, block, 40)
        theta = np.linalg.solve(G.sum(0), h.sum(0))
        est.append(theta)
        sd_w.append(np.sqrt(np.diag(white_cov(G, h, yy, theta, 2000))))
        sd_h.append(honest_sd(G, h, yy, theta, 2000))
    est, sd_w, sd_h = map(np.array, (est, sd_w, sd_h))
    spread = est.std(axis=0)
    assert np.all(sd_w.mean(0) < 0.5 * spread)  # white noise: far too small
    assert np.all(np.abs(np.sqrt((sd_h**2).mean(0)) / spread - 1.0) < 0.35)
    cover = np.mean(np.abs(est - [1.0, -2.0]) < 1.96 * sd_h, axis=0)
    assert np.all(cover >= 0.88), cover


def test_too_few_blocks_is_a_one_line_error_and_honest_sd_falls_back():
    rng = np.random.default_rng(2)
    X, y, block = _rows(rng, 100, 3, 0.0)
    G, h, yy = _stats(X, y, block, 3)
    theta = np.linalg.solve(G.sum(0), h.sum(0))
    with pytest.raises(ValueError, match="more blocks than parameters"):
        sandwich_cov(G, h, theta)
    np.testing.assert_allclose(honest_sd(G, h, yy, theta, 100), np.sqrt(np.diag(white_cov(G, h, yy, theta, 100))))


def test_contact_point_sd_carries_the_calibration_covariance():
    """A point contact at p behind a tool model with 4 uncertain parameters (a force offset and a moment
    offset along x, y): the spread of the point over 400 calibrations drawn from their covariance (the
    contact wrench noise-free) matches the sd ``with_calibration`` adds, within 15 %; the noise-free point
    alone has sd 0."""
    from kinadapt_nn.diagnostics.contact_point import ContactPoint, estimate, with_calibration

    rng = np.random.default_rng(4)
    n, p_true = 400, np.array([0.01, -0.02, 0.15])
    f = rng.normal(0.0, 5.0, (n, 3)) + [0.0, 0.0, -10.0]
    w_c = np.concatenate([f, np.cross(p_true, f)], axis=1)
    basis = np.zeros((4, 6))
    basis[0, 0], basis[1, 1], basis[2, 3], basis[3, 4] = 1.0, 1.0, 1.0, 1.0  # [N, N, N m, N m] offsets
    L = rng.normal(size=(4, 4)) * [0.05, 0.05, 0.005, 0.005]
    cov_x = L @ L.T
    def model_at(dx):  # the fitted model is 0
        return np.broadcast_to(dx @ basis, (n, 6))

    contact = np.ones(n, bool)
    pt = estimate(w_c, contact)
    pt = ContactPoint(pt.point_s_m, np.zeros(3), None, pt.samples, 0.0, 0.0)
    sd = with_calibration(pt, w_c, model_at, contact, cov_x).sd_m
    draws = np.array([estimate(w_c - model_at(-e), contact).point_s_m
                      for e in rng.multivariate_normal(np.zeros(4), cov_x, 400)])
    np.testing.assert_allclose(sd, draws.std(axis=0), rtol=0.15)
    assert np.all(sd > 0)


def test_explained_rows_fit_is_least_squares_on_the_other_channels():
    """``completeness.explained_rows`` (issue 51): the fit of a design with one channel's rows left out is the
    plain least squares (numpy) on the rows of the other channels -- a bias carried by that channel alone
    (here a constant 0.5 in channel 1) is then not in the estimate, which stays within noise of the truth."""
    from kinadapt_nn.diagnostics import selection as sel
    from kinadapt_nn.diagnostics.completeness import explained_rows

    rng = np.random.default_rng(3)
    n_t, B = 400, 10
    t = np.repeat(np.linspace(0.0, 1.0, n_t), 2)  # two channels per row time
    channel = np.tile(np.arange(2), n_t)
    X = np.stack([np.sin(5 * t + channel), t * (1 + channel)], axis=1)
    theta = np.array([0.8, -1.5])
    y = X @ theta + 0.01 * rng.normal(size=len(t)) + 0.5 * (channel == 1)
    block = np.minimum((t * B).astype(int), B - 1)
    des = sel.Design(y, {"e": X}, np.zeros((len(y), 0)), block, B, {"e": np.array([0.1, 0.1])}, {"e": False},
                     np.ones(len(y)), channel, ("c0", "c1"), t)
    dx = explained_rows(None, None, des, [1])
    st = sel.Stats(dx)
    p = st.fit(st.idx["e"], 0.0) * 0.1
    keep = channel == 0
    ref = np.linalg.lstsq(X[keep], y[keep], rcond=None)[0]
    assert np.allclose(p, ref, rtol=1e-7, atol=1e-10), (p, ref)
    assert np.all(np.abs(ref - theta) < 0.01) and not np.all(np.abs(np.linalg.lstsq(X, y, rcond=None)[0] - theta) < 0.01)


def test_rows_left_in_one_block_pin_nothing_and_do_not_raise():
    """The rows the unexplained channels spare may all fall in one block (an iiwa14 calibration log with a
    wrong mount declared known raised ZeroDivisionError in the block jackknife): the fit then reports an
    infinite sd -- every parameter undetermined by those rows -- instead of failing."""
    from kinadapt_nn.diagnostics import selection as sel
    from kinadapt_nn.diagnostics.completeness import _fit, explained_rows

    n_t, B = 40, 4
    t = np.repeat(np.linspace(0.0, 1.0, n_t), 2)
    channel = np.tile(np.arange(2), n_t)
    X = np.stack([np.sin(5 * t + channel), t * (1 + channel)], axis=1)
    y = X @ np.array([0.8, -1.5])
    block = np.where(channel == 0, 0, np.minimum((t * B).astype(int), B - 1))  # channel 0's rows: one block
    des = sel.Design(y, {"e": X}, np.zeros((len(y), 0)), block, B, {"e": np.array([0.1, 0.1])}, {"e": False},
                     np.ones(len(y)), channel, ("c0", "c1"), t)
    st = sel.Stats(explained_rows(None, None, des, [1]))
    p, sd = _fit(st, st.idx["e"], sel.SelCfg())
    assert p.shape == (2,) and np.all(np.isinf(sd))
    p_all, sd_all = _fit(sel.Stats(des), sel.Stats(des).idx["e"], sel.SelCfg())
    assert np.all(np.isfinite(sd_all))
