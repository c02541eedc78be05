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

Selection: the rows ``y'`` and the (calibrated) columns are handed to ``selection.select``, the
forward selection a user's log gets too (block cross-validation over ``n_blocks`` contiguous
blocks of whole anchor windows, Hotelling-type tests with the block-jackknife covariance,
Benjamini-Hochberg, near-ties, verdicts present / cannot_decide / absent with the equivalence
test). Each parameter is scaled by its relevant size (``RELEVANT``): the smallest change from the
calibration worth reporting; "absent" means every parameter's interval lies inside +- it. An
estimate is physically impossible (``implausible_own``) on the total, calibration + change.
``rank`` returns the entries in this package's format (``library.analyse_effects``).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import NamedTuple

import numpy as np

from kinadapt_nn.config import EffectsCfg
from kinadapt_nn.diagnostics.effects import headline_errors
from kinadapt_nn.features.effect_library import (AXIAL, LEVEL_CHANNELS, LIBRARY, Signals, calibration_derivative,
                                             cumulative, encoder_derivatives, moving_average,
                                             nominal_parts, physical_report)
from kinadapt_nn.diagnostics import selection as sel
from kinadapt_nn.errors import KinadaptError

ENCODER = "encoder_offset"
DEFAULT_CALIBRATION = Path(__file__).resolve().parents[2] / "models" / "nominal_calibration.json"


class RankCfg(NamedTuple):
    """The rows of the regression (``build_design``) and the selection's settings (``selection.SelCfg``,
    the same forward selection as a user's log)."""

    anchor_s: float = 1.0  #: [s] anchor window of the increments
    stride_s: float = 0.005  #: [s] row spacing
    n_blocks: int = 40  #: CV blocks at most (contiguous, whole anchor windows)
    guard_s: float = 0.3  #: [s] rows this close to a contact-gate change are left out
    smooth_s: float = 0.02  #: [s] centred moving average applied to the levels AND the columns (same linear operator)
    selection: sel.SelCfg = sel.SelCfg()  #: alpha, min_explained, near-tie and equivalence settings, ridge

    def as_dict(self) -> dict:
        """JSON-ready: the row settings and ``selection`` as a dict."""
        return {**self._asdict(), "selection": self.selection._asdict()}


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


#: [-] relative Tikhonov term of the calibration's joint fit of the whole library (default-magnitude
#: scaled columns): the library's columns overlap (e.g. contact stiffness and grasp compliance), and
#: the calibration only has to reproduce the prediction, not to separate them
CALIBRATION_RIDGE = 1e-4


def calibrate(des: Design, rc: RankCfg) -> dict[str, list[float]]:
    """Joint fit of the whole library on a run without hidden effects (the calibrated nominal):
    every column of every effect, each scaled by its parameter's default magnitude (a zero default:
    the column's norm, taken to the size of the effect's default signature), ``CALIBRATION_RIDGE``."""
    names = list(des.X)
    X = np.concatenate([des.X[n] for n in names], axis=1)
    scale = []
    for n in names:
        d = np.abs(LIBRARY[n].default(EffectsCfg()))
        norm = np.linalg.norm(des.X[n], axis=0)
        fallback = 1.0 / np.where(norm > 0, norm, 1.0)
        scale.append(np.where(d > 0, d, fallback * (np.linalg.norm(des.X[n] @ d) if d.any() else 1.0)))
    scale = np.concatenate(scale)
    Xs = X * scale
    G = Xs.T @ Xs
    lam = CALIBRATION_RIDGE * (np.trace(G) / max(len(G), 1) + 1e-300)
    p = scale * np.linalg.solve(G + lam * np.eye(len(G)), Xs.T @ des.y)
    out, i = {}, 0
    for n in names:
        k = des.X[n].shape[1]
        out[n] = [float(v) for v in p[i:i + k]]
        i += k
    return out


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


#: Relevant size of each parameter (``selection``: the smallest change from the calibration worth
#: reporting, in the parameter's units; an estimate must reach it to be selected, and "absent"
#: means every parameter's confidence interval lies inside +- it). Where an effect is also built
#: in for a user's log (``kinadapt_nn.diagnostics.builtin``) the size is that one's (encoder
#: offset: half of it, see there); the injected default magnitudes (``effects`` config,
#: ``LIBRARY[n].default``) are 1.4-17 times these.
RELEVANT: dict[str, tuple[float, ...]] = {
    # 30 g of payload; 30 g at 50 mm of first moment (builtin.tool_gravity)
    "tool_gravity": (0.03, 0.0015, 0.0015, 0.0015),
    # 0.03 N/s, 0.003 N m/s: ~1 N / 0.1 N m over a 30 s run (builtin.ft_bias_drift)
    "ft_bias_drift": (0.03, 0.03, 0.03, 0.003, 0.003, 0.003),
    # 1 deg of sensor mounting rotation: 1.7 % of a force leaks into the other axes (builtin.ft_frame_rotation)
    "ft_frame_rotation": (np.deg2rad(1.0),) * 3,
    # 1 deg of tool tilt in the grasp: 2 mm of tip at a 0.1 m tool (builtin.tool_tilt)
    "tool_tilt": (np.deg2rad(1.0),) * 2,
    # 10 % of the nominal contact stiffness
    "contact_stiffness": (0.1,),
    # 1 mm of torsional friction radius: 0.01 N m of couple per 10 N of contact force, the size of
    # the moment noise (the injected default is 5 mm)
    "contact_friction_couple": (1e-3,),
    # 1 mrad/(N m): a grasp of 1000 N m/rad, tilting 1 mrad per N m of contact moment (0.1 mm at the
    # tip of a 0.1 m tool); the injected default is 5 mrad/(N m) (200 N m/rad)
    "grasp_compliance": (1e-3,),
    # 0.25 deg of joint zero: ~2 mm at the tip of a 0.5 m arm, more than a peg-hole clearance. Half of
    # the user path's 0.5 deg (builtin.encoder_offset): there the log is a robot's, here the
    # injected default offset is 0.5 deg and the estimate must reach the relevant size to be selected
    "encoder_offset": (np.deg2rad(0.25),) * 6,
}


def relevant_size(name: str) -> np.ndarray:
    """(k,) relevant size of each parameter of library effect ``name`` (``RELEVANT``; an effect not
    listed there: 20 % of its default magnitude, a zero default entry taking the effect's largest)."""
    k = LIBRARY[name].k
    if name in RELEVANT:
        r = np.asarray(RELEVANT[name], dtype=float)
        if r.shape != (k,) or not np.all(r > 0):
            raise KinadaptError(f"ranking.RELEVANT['{name}'] must be {k} positive sizes")
        return r
    d = 0.2 * np.abs(LIBRARY[name].default(EffectsCfg()))
    if not d.any():
        raise KinadaptError(f"library effect '{name}' has no relevant size (add it to ranking.RELEVANT)")
    return np.where(d > 0, d, d.max())


def selection_design(des: Design, y: np.ndarray) -> sel.Design:
    """The rows of ``des`` for ``selection``: ``y`` (the calibrated residual) against the effect
    columns (use a ``calibrated_design``), no nuisance columns (anchoring already removed the
    level at the start of each window), each parameter scaled by its ``relevant_size``."""
    names = list(des.X)
    return sel.Design(y=y, X=des.X, Z=np.zeros((len(y), 0)), block=des.block, n_blocks=des.n_blocks,
                      scale={n: relevant_size(n) for n in names}, one_of={n: LIBRARY[n].one_of for n in names},
                      W=des.W, channel=des.channel, channel_names=tuple(LEVEL_CHANNELS), t_s=des.t_s)


def _hints(names: list[str]) -> dict:
    return {**{n: LIBRARY[n].excite_hint for n in names}, "_params": {n: LIBRARY[n].params for n in names}}


def _floats(a) -> list[float]:
    return [float(v) for v in np.asarray(a, dtype=float).ravel()]


def rank(des: Design, y: np.ndarray, rc: RankCfg, calib: dict | None = None) -> list[dict]:
    """Forward selection over the library with verdicts: ``selection.select`` on
    ``selection_design(calibrated_design(des, calib), y)`` (``y`` = ``calibrated_residual``),
    ``plausible`` = ``implausible_own`` of the total (calibration + change).

    Entries (one per effect): ``effect``, ``verdict`` (present / cannot_decide / absent) and
    ``reason``, ``explained_fraction`` (held-out, given the effects selected before it),
    ``explained_fraction_alone``, ``p_value``/``p_adjusted`` (its last test), ``significant``
    (verdict present), ``selected``/``selected_round``, ``estimate`` (physical, +- sd: the change
    from the calibration; jointly re-estimated for a selected effect), ``columns_used`` (parameter
    names), ``estimate_params`` (names, units, value, sd, calibration), ``excitation`` (ratio,
    enough, weak_parameters, and ``to_excite`` when not enough), ``equivalence`` (an unselected
    effect's intervals and relevant sizes), ``indistinguishable_from``/``to_separate`` on a
    near-tie, ``below_relevant`` when significant but small. Selected effects come first, in
    selection order, then the rest by explained fraction."""
    des = calibrated_design(des, calib)  # idempotent: the encoder columns of the calibrated model
    names = list(des.X)
    cal = {n: np.asarray((calib or {}).get(n, [0.0] * LIBRARY[n].k), dtype=float) for n in names}
    result = sel.select(selection_design(des, y), rc.selection,
                        plausible=lambda n, p: implausible_own(n, p, cal[n]), hints=_hints(names))
    res = []
    for e in result.entries:
        n = e["effect"]
        lib = LIBRARY[n]
        p, sd = np.asarray(e["params"], dtype=float), np.asarray(e["sd"], dtype=float)
        exc = e["excitation"]
        out = {
            "effect": n,
            "verdict": e["verdict"],
            **({"reason": e["reason"]} if e.get("reason") else {}),
            **({k: e[k] for k in ("indistinguishable_from", "to_separate") if k in e}),
            "explained_fraction": e["explained_fraction"],
            "explained_fraction_alone": e["explained_fraction_alone"],
            "p_value": e["p_value"],
            "p_adjusted": e["p_adjusted"],
            "significant": e["significant"],
            "selected": e["selected_round"] is not None,
            "selected_round": e["selected_round"],
            **({"below_relevant": True} if e.get("below_relevant") else {}),
            "estimate": physical_report(n, p, sd),
            "columns_used": [lib.params[c] for c in e["columns_used"]],
            "estimate_params": {"names": list(lib.params), "units": list(lib.units), "value": _floats(p),
                                "sd": _floats(sd), "calibration": _floats(cal[n])},
            "excitation": {"ratio": float(exc["ratio"]), "enough": bool(exc["enough"]),
                           "weak_parameters": [lib.params[j] for j in exc["weak_parameters"]],
                           **({} if exc["enough"] else {"to_excite": lib.excite_hint})},
        }
        if "equivalence" in e:
            q = e["equivalence"]
            out["equivalence"] = {"ci_low": _floats(q["ci_low"]), "ci_high": _floats(q["ci_high"]),
                                  "relevant": _floats(q["relevant"]), "level": float(q["level"])}
        res.append(out)
    res.sort(key=lambda r: (r["selected_round"] is None, r["selected_round"] or 0, -r["explained_fraction"]))
    return res


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


def refit(des: Design, y: np.ndarray, names: list[str], rc: RankCfg,
          cols: dict[str, list[str]] | None = None) -> tuple[np.ndarray, dict]:
    """Fit the named effects jointly on all rows (``--add``; ``selection.refit``). A "one of"
    effect keeps the column ``cols[name]`` names (parameter names: the ranking's ``columns_used``)
    when given, else its best single column. ``des``: a ``calibrated_design``; ``y``: the
    calibrated residual. -> (residual after (R,), {effect: full parameter vector (k,), the change
    from the calibration})."""
    named = {n: [LIBRARY[n].params.index(c) for c in cs] for n, cs in (cols or {}).items() if n in names and cs}
    _, after, fitted = sel.refit(selection_design(des, y), list(names), rc.selection, named)
    return after, {n: p for n, (_, p, _) in fitted.items()}


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
           "rms_by_channel", "confusion", "load_calibration", "headline_errors", "DEFAULT_CALIBRATION", "RELEVANT",
           "relevant_size", "selection_design"]
