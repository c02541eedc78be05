"""Which effect is missing: rank the library by the residual each explains *out of sample*.

Data. The level residual of the nominal model and each effect's level columns (both through the
same ``smooth_s`` moving average: white sensor noise averages out, the linear model is unchanged)
(``kinadapt_nn.features.effect_library``) are taken as *anchored increments*: rows every
``stride_s``, each minus its value at the start of its ``anchor_s`` window. Anchoring removes
what the model cannot know (the level at the start of a window, a constant offset) and bounds
the integration drift of the contact prediction; within a window the level is kept, so a slow
effect (drift, gravity) is fitted on levels, not on noisy rates. Channels ``F_lat``, ``M``,
scaled by the channel metric ``W``.

Calibrated nominal model. MuJoCo's contact is never exactly the nominal spring, and the real
tool is never the CAD tool: part of the residual of a run with *no* hidden effect is fitted by
library columns. The whole library is fitted once, jointly, on a reference run without a hidden
effect (``--baseline RUN`` or the shipped ``models/nominal_calibration.json``, per program) and
that fit is part of the nominal model: a later run is judged on ``r' = r - sum_e C_e p_e^base``,
so an effect is "missing" only if its parameters moved away from the calibration. A joint zero
offset moves the model's q everywhere, the calibrated part included, so against a calibrated
model the encoder-offset columns are ``C_enc_j + sum_e (dC_e/dq_j) p_e^base`` (``Design.dX_dq``,
``calibrated_design``; ``rank`` applies it).

Criterion: block cross-validation over ``n_blocks`` contiguous time blocks (whole anchor
windows, so a block's correlated residual stays together): fit on the other blocks, predict the
held-out one. ``explained_fraction`` = sum of held-out SSE reductions / SSE of ``r'`` (negative
when the columns only fit noise: extra columns are not free). Effects are selected forward
(``rank``): each round tests the remaining effects given the selected ones, so an effect that
only looks like the one already found is not reported as a second discovery, while two
separable effects are both found. The
estimate's change from the calibration is tested with its block-jackknife covariance (a
Hotelling-type F test over the blocks, so the residual's correlation within a block is
honoured), and the p-values of the whole library are corrected together (Benjamini-Hochberg,
``scipy.stats.false_discovery_control``).
``significant`` = adjusted p < ``alpha`` and explained_fraction >= ``min_explained``.
Uncertainty: block jackknife over the leave-one-block-out fits. Excitation: the smallest
eigenvalue of the effect's W-scaled Gram, with the parameters at their default magnitude,
relative to the held-out SSE the selected model leaves (``excitation.ratio``): below ``min_excitation`` the data cannot
decide about the effect's weakest direction, and the hint says which motion would excite it.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np

from kinadapt_nn.config import EffectsCfg
from kinadapt_nn.diagnostics.effects import headline_errors
from kinadapt_nn.features.effect_library import (AXIAL, LEVEL_CHANNELS, LIBRARY, Signals, calibration_derivative,
                                             cumulative, encoder_derivatives, moving_average,
                                             nominal_parts, physical_report)
from kinadapt_nn.diagnostics.selection import jackknife_cov, paired_p, wald_pvalue
from kinadapt_nn.errors import KinadaptError

ENCODER = "encoder_offset"
DEFAULT_CALIBRATION = Path(__file__).resolve().parents[2] / "models" / "nominal_calibration.json"


class RankCfg(NamedTuple):
    anchor_s: float = 1.0  #: [s] anchor window of the increments
    stride_s: float = 0.005  #: [s] row spacing
    n_blocks: int = 40  #: CV blocks at most (contiguous, whole anchor windows)
    alpha: float = 0.01  #: false-discovery level of the library test
    min_explained: float = 0.05  #: [-] smallest held-out explained fraction called an effect
    min_excitation: float = 0.05  #: [-] excitation_ratio below which the data cannot decide
    ridge: float = 1e-8  #: [-] relative Tikhonov term (default-magnitude scaled columns)
    guard_s: float = 0.3  #: [s] rows this close to a contact-gate change are left out
    smooth_s: float = 0.02  #: [s] centred moving average applied to the levels AND the columns (same linear operator)


class Design(NamedTuple):
    y: np.ndarray  #: (R,) W-scaled anchored residual increments, rows x channels flattened
    X: dict  #: effect -> (R, k) columns in the same rows
    block: np.ndarray  #: (R,) block index of each row
    n_blocks: int
    channel: np.ndarray  #: (R,) index into LEVEL_CHANNELS of each row
    W: np.ndarray  #: (R,) the metric weight of each row
    t_s: np.ndarray  #: (R,) time of each row [s]
    #: effect -> (R, k, 6): d X_e / d q_j, the derivative of each effect's columns in each joint's
    #: zero (same rows), for the encoder-offset columns of a calibrated model; None: not computed
    dX_dq: dict | None = None
    #: the calibration ``calibrated_design`` applied to X[ENCODER] (None: the plain columns)
    encoder_calibration: dict | None = None


def build_design(sig: Signals, W6: np.ndarray, rc: RankCfg, names: list[str] | None = None) -> Design:
    """Rows of the regression (module docstring): free-space rows are tared levels (the model
    predicts zero), contact rows are increments from ``max(contact entry, anchor window start)``
    of the level minus the integrated nominal prediction. Rows within ``guard_s`` of a contact
    gate change are left out (the gate is proprioceptive and the contact does not switch at
    exactly d = 0)."""
    names = list(LIBRARY) if names is None else names
    n = len(sig.t_s)
    gate = sig.gate > 0
    change = np.flatnonzero(np.diff(gate.astype(int)) != 0) + 1
    guard_n = int(round(rc.guard_s / sig.dt_s))
    near = np.zeros(n, bool)
    for c in change:
        near[max(0, c - guard_n):c + guard_n] = True
    ok = sig.active & ~near
    if ok.sum() < 10:
        raise KinadaptError("the log has too little data after the tare to fit effects (need at least 10 samples)")
    # start index of the current constant-gate run, and of the current anchor window
    idx = np.arange(n)
    run_start = np.maximum.accumulate(np.where(np.r_[True, np.diff(gate.astype(int)) != 0], idx, 0))
    win = np.floor((sig.t_s - sig.t_s[0]) / rc.anchor_s).astype(int)
    win_start = np.maximum.accumulate(np.where(np.r_[True, np.diff(win) != 0], idx, 0))
    anchor = np.minimum(np.maximum(run_start + guard_n, win_start), n - 1)
    stride = max(1, int(round(rc.stride_s / sig.dt_s)))
    rows = np.flatnonzero(ok)[::stride]
    rows = rows[~gate[rows] | (rows > anchor[rows])]
    a = anchor[rows]
    con = gate[rows][:, None]
    nc = len(LEVEL_CHANNELS)
    w = np.array([W6[1], W6[2], W6[1], W6[3], W6[4], W6[5]])  # F_axial weighted like F_lat
    use = np.ones((len(rows), nc), bool)
    use[:, AXIAL] = ~gate[rows]  # no axial model in contact
    use = use.ravel()
    k_s = max(1, int(round(rc.smooth_s / sig.dt_s)))
    meas, pint = (moving_average(x, k_s) for x in nominal_parts(sig))
    y = np.where(con, (meas[rows] - meas[a]) - (pint[rows] - pint[a]), meas[rows])
    y = (y * w).ravel()[use]
    con3 = con[:, :, None]

    def rows_of(lev: np.ndarray | None, integ: np.ndarray | None, k: int) -> np.ndarray:
        """(N, 6, k) level columns (closed form, integrated rate) -> (R, k) design columns."""
        C = np.zeros((len(rows), nc, k))
        if lev is not None:
            lev = moving_average(lev, k_s)
            C += np.where(con3, lev[rows] - lev[a], lev[rows])
        if integ is not None:
            integ = moving_average(integ, k_s)
            C += np.where(con3, integ[rows] - integ[a], 0.0)
        return (C * w[None, :, None]).reshape(-1, k)[use]

    derivs = encoder_derivatives(sig) if ENCODER in names else None  # shared by the encoder columns and dX
    X = {n: rows_of(*LIBRARY[n].columns(sig, **({"derivs": derivs} if n == ENCODER else {})), LIBRARY[n].k)
         for n in names}
    dX = None
    if ENCODER in names and len(names) > 1:  # the encoder columns of a calibrated model (calibrated_design)
        dX = {n: np.zeros((len(y), LIBRARY[n].k, 6)) for n in names if n != ENCODER}
        for j, terms in enumerate(calibration_derivative(sig, names, derivs=derivs)):
            for n, (lev, rate) in terms.items():
                dX[n][:, :, j] = rows_of(lev, None if rate is None else cumulative(rate, sig.dt_s), LIBRARY[n].k)
    n_win = int(win[rows].max()) + 1 if len(rows) else 1
    nb = max(2, min(rc.n_blocks, n_win))
    block = np.repeat(np.minimum((win[rows] * nb) // n_win, nb - 1), nc)[use]
    return Design(y, X, block, nb, np.tile(np.arange(nc), len(rows))[use], np.tile(w, len(rows))[use],
                  np.repeat(sig.t_s[rows], nc)[use], dX)


def _solve(X: np.ndarray, y: np.ndarray, scale: np.ndarray, ridge: float) -> np.ndarray:
    Xs = X * scale
    G = Xs.T @ Xs
    lam = ridge * (np.trace(G) / max(len(G), 1) + 1e-300)
    return scale * np.linalg.solve(G + lam * np.eye(len(G)), Xs.T @ y)


def _scale(name: str, X: np.ndarray) -> np.ndarray:
    """Column scaling for conditioning: the default magnitude of each parameter (or 1/column norm)."""
    d = np.abs(LIBRARY[name].default(EffectsCfg()))
    norm = np.linalg.norm(X, axis=0)
    fallback = 1.0 / np.where(norm > 0, norm, 1.0)
    return np.where(d > 0, d, fallback * (np.linalg.norm(X @ d) if d.any() else 1.0))


def _joint_fit(des: Design, y: np.ndarray, cols: dict[str, list[int]], ridge: float) -> tuple[np.ndarray, dict]:
    """One least-squares fit of the named effects' chosen columns together.
    -> (residual (R,), {effect: full parameter vector (k,), zero outside its chosen columns})."""
    X = np.concatenate([des.X[n][:, c] for n, c in cols.items()], axis=1)
    scale = np.concatenate([_scale(n, des.X[n])[c] for n, c in cols.items()])
    p = _solve(X, y, scale, ridge)
    out, i = {}, 0
    for n, c in cols.items():
        out[n] = np.zeros(LIBRARY[n].k)
        out[n][c] = p[i:i + len(c)]
        i += len(c)
    return y - X @ p, out


def calibrate(des: Design, rc: RankCfg) -> dict[str, list[float]]:
    """Joint fit of the whole library on a run without hidden effects (the calibrated nominal)."""
    _, p = _joint_fit(des, des.y, {n: list(range(X.shape[1])) for n, X in des.X.items()}, max(rc.ridge, 1e-4))
    return {n: [float(v) for v in pn] for n, pn in p.items()}


def _encoder_shift(des: Design, calib: dict[str, list[float]]) -> np.ndarray:
    """``sum_e (dX_e/dq_j) p_e^calib`` (R, 6): how the calibrated part of the prediction moves
    with each joint's zero."""
    out = np.zeros((len(des.y), 6))
    for n, p in calib.items():
        if n in (des.dX_dq or {}):
            out += np.einsum("rkj,k->rj", des.dX_dq[n], np.asarray(p, dtype=float))
    return out


def calibrated_design(des: Design, calib: dict[str, list[float]] | None) -> Design:
    """The design against the calibrated nominal model: a joint zero offset moves the model's q
    everywhere, so its columns are the derivative of the *whole* prediction, the calibrated part
    ``sum_e X_e(q) p_e^calib`` included: ``X_enc_j + sum_e (dX_e/dq_j) p_e^calib`` (the residual
    is measured minus predicted; ``effects.calibration_derivative``; the calibrated encoder
    offset's own derivative, second order, is left out). Idempotent; without a calibration or
    derivatives, ``des`` unchanged."""
    if not calib or des.dX_dq is None or ENCODER not in des.X or des.encoder_calibration is not None:
        return des
    return des._replace(X={**des.X, ENCODER: des.X[ENCODER] + _encoder_shift(des, calib)},
                        encoder_calibration=dict(calib))


def calibrated_residual(des: Design, calib: dict[str, list[float]] | None) -> np.ndarray:
    """``y' = y - sum_e X_e p_e^calib``, the columns of the prediction at the readings (a
    ``calibrated_design``'s encoder columns are taken back to the plain ones for this)."""
    y = des.y.copy()
    for n, p in (calib or {}).items():
        if n in des.X:
            X = des.X[n]
            if n == ENCODER and des.encoder_calibration is not None:
                X = X - _encoder_shift(des, des.encoder_calibration)
            y -= X @ np.asarray(p)
    return y


def _cv(X: np.ndarray, scale: np.ndarray, des: Design, y: np.ndarray, rc: RankCfg):
    """Leave-one-block-out fits of ``X`` (R, k) (k may be 0): (held-out SSE per block, the
    leave-one-block-out estimates (B, k), the full-data estimate (k,))."""
    sse, reps = [], []
    for b in range(des.n_blocks):
        m = des.block == b
        if not m.any():
            continue
        if X.shape[1]:
            p_b = _solve(X[~m], y[~m], scale, rc.ridge)
            e = y[m] - X[m] @ p_b
        else:
            p_b, e = np.zeros(0), y[m]
        reps.append(p_b)
        sse.append(float(e @ e))
    p = _solve(X, y, scale, rc.ridge) if X.shape[1] else np.zeros(0)
    return np.array(sse), np.array(reps).reshape(len(reps), X.shape[1]), p


def _choices(name: str, k: int) -> list[list[int]]:
    return [[j] for j in range(k)] if LIBRARY[name].one_of else [list(range(k))]


@dataclass
class EffectTest:
    """One effect tested given a selected set (``_test_given``); R rows, B blocks, k columns used."""

    cols: list[int]  #: the effect's columns used (all, or the best one for a "one of" effect)
    gain: np.ndarray  #: (B,) held-out SSE reduction over the selected model, per block
    sse: np.ndarray  #: (B,) held-out SSE of the selected model plus this effect
    reps: np.ndarray  #: (B, k) leave-one-block-out estimates of this effect's parameters
    p: np.ndarray  #: (k,) full-data estimate (joint with the selected effects)
    cov: np.ndarray  #: (k, k) block-jackknife covariance of ``p``
    p_value: float  #: Wald test of p = 0 (Bonferroni over a "one of" choice)
    p_adjusted: float = 1.0  #: Benjamini-Hochberg across the round
    selected_round: int | None = None  #: the forward-selection round that selected it


def _test_given(name: str, sel: list[tuple[str, list[int]]], des: Design, y: np.ndarray, rc: RankCfg,
                sse_sel: np.ndarray) -> EffectTest:
    """Effect ``name`` given the already selected effects ``sel``: held-out SSE reduction over
    the selected model, Wald test of its parameters in the joint fit, its estimate."""
    X_sel = [des.X[n][:, c] for n, c in sel]
    sc_sel = [_scale(n, des.X[n])[c] for n, c in sel]
    k_sel = sum(len(c) for _, c in sel)
    best = None
    choices = _choices(name, des.X[name].shape[1])
    for cols in choices:
        X = np.concatenate([*X_sel, des.X[name][:, cols]], axis=1)  # (R, k_sel + k)
        sc = np.concatenate([*sc_sel, _scale(name, des.X[name])[cols]])
        sse, reps, p = _cv(X, sc, des, y, rc)
        gain = sse_sel - sse
        if best is None or gain.sum() > best[1].sum():
            best = (cols, gain, sse, reps[:, k_sel:], p[k_sel:])
    cols, gain, sse, reps, p = best
    cov = jackknife_cov(reps)
    pval = min(1.0, wald_pvalue(p, cov, len(reps)) * len(choices))  # Bonferroni for the choice
    return EffectTest(cols, gain, sse, reps, p, cov, pval)


def rank(des: Design, y: np.ndarray, rc: RankCfg, calib: dict | None = None) -> list[dict]:
    """Forward selection over the library (module docstring), then every effect's entry.

    Round r tests every unselected effect *given* the selected ones (held-out SSE reduction over
    the selected model; Wald test of its parameters in the joint fit), corrects the round's
    p-values together (Benjamini-Hochberg), and selects the best one if it is significant
    (adjusted p < alpha) and explains >= min_explained of what the selected model leaves
    held-out; else it stops.
    Entries: ``explained_fraction`` (held-out, given the effects selected before it),
    ``explained_fraction_alone``, ``p_value``/``p_adjusted`` (its last test), ``significant``
    (selected), ``estimate`` (physical, +- block-jackknife sd, from its last test: deviations from
    the calibration), ``excitation``. Selected effects come first, in selection order, then the
    rest by explained fraction."""
    from scipy.stats import false_discovery_control

    des = calibrated_design(des, calib)  # idempotent: the encoder columns of the calibrated model
    names = list(des.X)
    sse_tot = float(y @ y) or 1e-300
    sse0, _, _ = _cv(np.zeros((len(y), 0)), np.zeros(0), des, y, rc)
    alone = {n: _test_given(n, [], des, y, rc, sse0) for n in names}
    last = dict(alone)
    selected: list[tuple[str, list[int]]] = []
    ties: dict[str, set[str]] = {}
    sse_sel = sse0
    while len(selected) < len(names):
        cand = [n for n in names if n not in {s for s, _ in selected}]
        tests = alone if not selected else {n: _test_given(n, selected, des, y, rc, sse_sel) for n in cand}
        tests = {n: tests[n] for n in cand}
        padj = false_discovery_control([tests[n].p_value for n in cand], method="bh")
        for n, pa in zip(cand, padj):
            tests[n].p_adjusted = float(pa)
            last[n] = tests[n]
        best = max(cand, key=lambda n: tests[n].gain.sum())
        t = tests[best]
        if not (t.p_adjusted < rc.alpha and t.gain.sum() / float(sse_sel.sum() or 1e-300) >= rc.min_explained):
            break
        t.selected_round = len(selected)
        # near-ties: a rival that explains nearly as much alone and nothing more once the best is in
        # the model, and is not beaten block by block (one-sided paired t over the blocks)
        for n in cand:
            if n == best or tests[n].gain.sum() < TIE_RATIO * t.gain.sum() or tests[n].gain.sum() <= 0:
                continue
            given = _test_given(n, [*selected, (best, t.cols)], des, y, rc, t.sse)
            if given.gain.sum() / (float(t.sse.sum()) or 1e-300) < rc.min_explained and paired_p(t.sse, tests[n].sse) > 0.01:
                ties.setdefault(best, set()).add(n)
                ties.setdefault(n, set()).add(best)
        selected.append((best, t.cols))
        sse_sel = t.sse
    sse_ref = float(sse_sel.sum()) or 1e-300  # what the selected model leaves held-out
    res = []
    for n in names:
        t = last[n]
        k = des.X[n].shape[1]
        cols = t.cols
        p_full, sd = np.zeros(k), np.zeros(k)
        p_full[cols] = t.p
        sd[cols] = np.sqrt(np.clip(np.diag(t.cov), 0.0, None))
        d = np.abs(LIBRARY[n].default(EffectsCfg()))
        dc = np.full(len(cols), d.max()) if LIBRARY[n].one_of else d[cols]
        Xd = des.X[n][:, cols] * np.where(dc != 0, dc, _scale(n, des.X[n])[cols])
        lam = np.linalg.eigvalsh(Xd.T @ Xd)
        exc = float(lam[0] / sse_ref)
        impossible = implausible_own(n, p_full, np.asarray((calib or {}).get(n, [0.0] * k), dtype=float))
        if t.selected_round is not None:
            verdict = "cannot_decide" if (impossible or n in ties) else "present"
        else:
            verdict = "cannot_decide" if (n in ties or exc < rc.min_excitation) else "absent"
        res.append({
            "effect": n,
            "verdict": verdict,
            **({"reason": f"physically impossible estimate: {impossible}"} if impossible and t.selected_round is not None
               else {"reason": "a near-tie: another explanation fits the data as well",
                     "indistinguishable_from": sorted(ties[n]),
                     "to_separate": " / ".join(LIBRARY[x].excite_hint for x in [n, *sorted(ties[n])])} if n in ties
               else {"reason": "not excited enough to rule out"} if verdict == "cannot_decide" else {}),
            "explained_fraction": float(t.gain.sum() / sse_tot),
            "explained_fraction_alone": float(alone[n].gain.sum() / sse_tot),
            "explained_fraction_of_remaining": float(t.gain.sum() / (float(t.sse.sum() + t.gain.sum()) or 1e-300)),
            "p_value": t.p_value,
            "p_adjusted": t.p_adjusted,
            "significant": verdict == "present",
            "selected": t.selected_round is not None,
            "selected_round": t.selected_round,
            "estimate": physical_report(n, p_full, sd),
            "columns_used": [LIBRARY[n].params[c] for c in cols],
            "estimate_params": {"names": list(LIBRARY[n].params), "units": list(LIBRARY[n].units),
                                "value": [float(v) for v in p_full], "sd": [float(v) for v in sd],
                                "calibration": list((calib or {}).get(n, [0.0] * k))},
            "excitation": {"ratio": exc, "enough": bool(exc >= rc.min_excitation),
                           "gram_eigenvalues_rel": [float(v / sse_ref) for v in lam],
                           **({} if exc >= rc.min_excitation else {"to_excite": LIBRARY[n].excite_hint})},
        })
    res.sort(key=lambda r: (r["selected_round"] is None, r["selected_round"] or 0, -r["explained_fraction"]))
    return res


#: a rival with this share of the best effect's held-out gain is checked for a near-tie
TIE_RATIO = 0.8


def implausible_own(name: str, p: np.ndarray, calib: np.ndarray) -> str | None:
    """Why an estimate (a change from the calibration ``calib``) is physically impossible, or None."""
    tot = p + calib
    if not np.all(np.isfinite(p)):
        return "the estimate is not finite"
    if name == "contact_stiffness" and 1.0 + tot[0] <= 0:
        return f"a stiffness factor of {1.0 + tot[0]:.3g} (must be > 0)"
    if name == "grasp_compliance" and tot[0] < 0:
        return f"a negative compliance {tot[0]:.3g} rad/(N m)"
    if name == "contact_friction_couple" and tot[0] < 0:
        return f"a negative friction radius {1e3 * tot[0]:.3g} mm"
    if name == "tool_gravity" and tot[0] < -0.1:
        return f"a payload of {tot[0]:.3g} kg"
    if name in ("ft_frame_rotation", "tool_tilt", "encoder_offset") and np.max(np.abs(tot)) > np.deg2rad(15.0):
        return f"{np.rad2deg(np.max(np.abs(tot))):.3g} deg is beyond a mounting/zero error (first-order model)"
    return None


def refit(des: Design, y: np.ndarray, names: list[str], rc: RankCfg) -> tuple[np.ndarray, dict]:
    """Fit the named effects jointly on all rows (``--add``). -> (residual after, params per effect)."""
    cols = {}
    for n in names:  # a "one of" effect keeps its best single column
        X = des.X[n]
        if LIBRARY[n].one_of:
            sc = _scale(n, X)
            sse = [float(np.sum((y - X[:, [j]] @ _solve(X[:, [j]], y, sc[[j]], rc.ridge)) ** 2)) for j in range(X.shape[1])]
            cols[n] = [int(np.argmin(sse))]
        else:
            cols[n] = list(range(X.shape[1]))
    return _joint_fit(des, y, cols, rc.ridge)


def rms_by_channel(des: Design, e: np.ndarray) -> dict:
    """RMS of the anchored level residual per channel, in channel units (W undone)."""
    out = {}
    for c, name in enumerate(LEVEL_CHANNELS):
        m = des.channel == c
        out[name] = float(np.sqrt(np.mean((e[m] / des.W[m]) ** 2))) if m.any() else None
    out["total_w"] = float(np.sqrt(np.mean(e**2))) if len(e) else None
    return out


def confusion(des: Design) -> dict:
    """Regressor overlap: ``c[i][j]`` = share of effect i's default-magnitude signature that effect
    j's columns can fit (1 = indistinguishable on this data, 0 = orthogonal)."""
    names = list(des.X)
    out = {}
    for i in names:
        d = LIBRARY[i].default(EffectsCfg())
        sig_i = des.X[i] @ d
        den = float(sig_i @ sig_i)
        row = {}
        for j in names:
            if den == 0.0:
                row[j] = None
                continue
            Xj = des.X[j]
            coef, *_ = np.linalg.lstsq(Xj, sig_i, rcond=None)
            fit = Xj @ coef
            row[j] = float(fit @ fit / den)
        out[i] = row
    return out


def load_calibration(path: Path, program: str) -> dict[str, list[float]]:
    """A calibration file: ``{"format": "kinadapt-calibration", "programs": {program: {effect: [..]}}}``."""
    try:
        data = json.loads(Path(path).read_text())
        return {k: [float(x) for x in v] for k, v in data["programs"][program]["params"].items()}
    except FileNotFoundError:
        raise KinadaptError(f"calibration '{path}' not found (give --baseline RUN or restore models/)") from None
    except KeyError:
        raise KinadaptError(f"calibration '{path}' has no entry for program '{program}' (give --baseline RUN)") from None
    except (ValueError, TypeError, AttributeError) as exc:
        raise KinadaptError(f"calibration '{path}' is malformed ({exc}); regenerate it (README)") from None


__all__ = ["RankCfg", "build_design", "calibrate", "calibrated_design", "calibrated_residual", "rank", "refit",
           "rms_by_channel", "confusion", "load_calibration", "headline_errors", "DEFAULT_CALIBRATION"]
