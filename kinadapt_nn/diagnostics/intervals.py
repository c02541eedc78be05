"""Honest intervals of a linear fit from per-block normal equations (issue 38, "Honest numbers").

A least-squares fit ``theta = (sum_b G_b)^-1 sum_b h_b`` over B blocks of rows, with ``G_b = X_b^T X_b``
(k, k) and ``h_b = X_b^T y_b`` (k,) of each block (contiguous time spans: their residual is correlated
within, nearly independent across). Two covariances of ``theta``:

* white noise: ``s^2 G^-1`` (``s^2`` the residual variance per row) -- right only when the rows'
  errors are independent and the model holds;
* block-robust (sandwich, Liang & Zeger 1986 / Huber-White over clusters): ``G^-1 (sum_b g_b g_b^T)
  G^-1`` with the per-block scores ``g_b = h_b - G_b theta`` (= ``X_b^T e_b``), times ``B / (B - k)``
  (the small-sample factor). Its sd grows with a residual that is structured (a missing term of the
  model that moves with the motion, correlated noise), not only with the noise.

``honest_sd`` reports the larger of the two per parameter: the sandwich alone is noisy with few
blocks, the white-noise sd alone ignores the structure. The sandwich's variance is an average of B
block scores, so its sd is widened by ``t_{B-k}(0.975) / z(0.975)``: a 95 % interval ``+- 1.96 sd``
is then the t interval with B - k degrees of freedom. Everything takes the per-block statistics,
never the rows, so it works on streamed logs.
"""

from __future__ import annotations

import numpy as np


def _bread(G_blocks: np.ndarray, ridge: float) -> np.ndarray:
    G = np.asarray(G_blocks, float).sum(axis=0)
    lam = ridge * np.diagonal(G) + 1e-300  # per column: a large column does not shrink a small one
    return np.linalg.pinv(G + np.diag(lam))


def block_scores(G_blocks: np.ndarray, h_blocks: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """(B, k) per-block scores ``g_b = h_b - G_b theta`` of blocks' ``G_b`` (B, k, k), ``h_b`` (B, k) at
    ``theta`` (k,) (each block's ``X_b^T`` times its residual)."""
    return np.asarray(h_blocks, float) - np.einsum("bij,j->bi", np.asarray(G_blocks, float), theta)


def sandwich_cov(G_blocks: np.ndarray, h_blocks: np.ndarray, theta: np.ndarray, ridge: float = 1e-12) -> np.ndarray:
    """(k, k) block-robust covariance of ``theta`` (module docstring) from ``G_b`` (B, k, k) and ``h_b``
    (B, k); blocks without rows (all-zero ``G_b``) are not counted. Needs B > k + 1 blocks with rows,
    else a one-line ``ValueError``."""
    G_blocks, h_blocks = np.asarray(G_blocks, float), np.asarray(h_blocks, float)
    if G_blocks.ndim != 3 or h_blocks.shape != G_blocks.shape[:2] or G_blocks.shape[1] != G_blocks.shape[2]:
        raise ValueError(f"sandwich_cov: G_b must be (B, k, k) and h_b (B, k); got {G_blocks.shape} and "
                         f"{h_blocks.shape}")
    used = np.array([np.any(g) for g in G_blocks])
    B, k = int(used.sum()), G_blocks.shape[1]
    if B <= k + 1:
        raise ValueError(f"sandwich_cov: {B} block(s) with rows for {k} parameter(s); split the rows into more "
                         "blocks than parameters + 1")
    Ginv = _bread(G_blocks, ridge)
    g = block_scores(G_blocks[used], h_blocks[used], theta)
    meat = g.T @ g * (B / (B - k))
    return Ginv @ meat @ Ginv


def white_cov(G_blocks: np.ndarray, h_blocks: np.ndarray, yy_blocks: np.ndarray, theta: np.ndarray, rows: int,
              ridge: float = 1e-12) -> np.ndarray:
    """(k, k) white-noise covariance ``s^2 G^-1`` with ``s^2 = SSE / (rows - k)``; ``yy_b = y_b^T y_b`` (B,) of
    each block and ``rows`` the number of rows in all blocks."""
    G_blocks, h_blocks = np.asarray(G_blocks, float), np.asarray(h_blocks, float)
    G, h = G_blocks.sum(0), h_blocks.sum(0)
    sse = float(np.sum(yy_blocks)) - 2.0 * float(theta @ h) + float(theta @ G @ theta)
    s2 = max(sse, 0.0) / max(rows - len(theta), 1)
    return s2 * _bread(G_blocks, ridge)


def honest_sd(G_blocks: np.ndarray, h_blocks: np.ndarray, yy_blocks: np.ndarray, theta: np.ndarray, rows: int,
              ridge: float = 1e-12) -> np.ndarray:
    """(k,) per parameter the larger of the white-noise and the block-robust sd (widened to the t quantile of
    B - k degrees of freedom, module docstring); the white-noise sd alone where there are too few blocks for
    the sandwich."""
    var = np.diag(white_cov(G_blocks, h_blocks, yy_blocks, theta, rows, ridge))
    try:
        sw = np.diag(sandwich_cov(G_blocks, h_blocks, theta, ridge))
    except ValueError:
        return np.sqrt(np.clip(var, 0.0, None))
    B, k = int(sum(np.any(g) for g in np.asarray(G_blocks))), len(theta)
    var = np.maximum(var, sw * t_widen(B - k))  # the sandwich has B - k degrees of freedom
    return np.sqrt(np.clip(var, 0.0, None))


def t_widen(dof: int) -> float:
    """``(t_dof(0.975) / z(0.975))^2``: the factor on a variance estimated with ``dof`` degrees of freedom
    (a block jackknife over B blocks: B - 1; the sandwich: B - k) that makes ``estimate +- 1.96 sd`` the
    95 % t interval. 1 for ``dof`` of 1000 or more; infinite below 1."""
    from scipy.stats import norm, t

    if dof < 1:
        return float("inf")
    return float((t.ppf(0.975, dof) / norm.ppf(0.975)) ** 2) if dof < 1000 else 1.0


__all__ = ["block_scores", "given_significant", "honest_sd", "jackknife_cov", "paired_p", "sandwich_cov", "t_widen",
           "wald_pvalue", "white_cov"]


def given_significant(cv, sel_idx: np.ndarray, extra_idx: list[np.ndarray]
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The selected columns' joint estimate and block-jackknife covariance with the columns of effects that are
    significant but not selected (``extra_idx``) fitted beside them: what such an effect (below the share of
    the residual that makes it a finding, say) would bias is then not in the selected effects' estimates, and
    their sd carries its uncertainty. ``cv(idx) -> (held-out SSE (B,), leave-one-block-out estimates (B, k),
    estimate (k,))`` (``selection.Stats.cv``); -> (estimate (len(sel_idx),), covariance (len, len), the
    columns fitted (``sel_idx`` then the extra ones), the estimate of all of them)."""
    idx = np.concatenate([sel_idx, *extra_idx])
    _, reps, p = cv(idx)
    k = len(sel_idx)
    reps = reps[:, :k]
    B = len(reps)
    dev = reps - reps.mean(axis=0)
    return p[:k], (B - 1) / max(B, 1) * dev.T @ dev, idx, p


# The block statistics of the selection (``selection`` uses and re-exports them).


def wald_pvalue(p: np.ndarray, cov: np.ndarray, B: int) -> float:
    """Hotelling-type test of ``p = 0`` with a block-jackknife covariance from B blocks:
    ``F = (B - r) / (r (B - 1)) p^T cov^+ p ~ F(r, B - r)``, r the numerical rank of cov."""
    from scipy.stats import f as f_dist

    if len(p) == 0:
        return 1.0
    lam, V = np.linalg.eigh(cov)
    keep = lam > 1e-10 * max(lam.max(), 1e-300)
    r = int(keep.sum())
    if r == 0 or B - r < 1:
        return 1.0
    z = V[:, keep].T @ p
    t2 = float(np.sum(z**2 / lam[keep]))
    return float(f_dist.sf((B - r) / (r * (B - 1)) * t2, r, B - r))


def jackknife_cov(reps: np.ndarray) -> np.ndarray:
    B = len(reps)
    dev = reps - reps.mean(axis=0)
    return (B - 1) / B * dev.T @ dev


def paired_p(a: np.ndarray, b: np.ndarray) -> float:
    """One-sided p that ``a`` (per-block SSE) is smaller than ``b`` on average (t over blocks)."""
    from scipy.stats import t as t_dist

    d = b - a
    n = len(d)
    if n < 3:
        return 1.0
    sd = float(np.std(d, ddof=1))
    if sd == 0.0:
        return 0.0 if d.mean() > 0 else 1.0
    return float(t_dist.sf(d.mean() / (sd / np.sqrt(n)), n - 1))
