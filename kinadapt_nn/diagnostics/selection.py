"""Which effect is missing, with an honest verdict: forward selection by block cross-validation.

Data: rows ``y`` (R,) of a residual and, per effect, columns ``X_e`` (R, k_e) linear in its
physical parameters, plus nuisance columns ``Z`` (R, z) that are always in the model (e.g. a tared
log's unknown offset). Columns are scaled by each parameter's *relevant magnitude* (the smallest
value worth reporting), so a parameter of 1 in scaled units is "just worth reporting".

Criterion: block cross-validation over contiguous time blocks (a block's correlated residual
stays together). Everything is computed from per-block Gram matrices (``A_b^T A_b``, ``A_b^T y_b``,
``y_b^T y_b`` of all columns at once), so a leave-one-block-out fit of any column subset costs one
small solve.

Forward selection: each round tests every remaining candidate (an effect, or one column of a "one
of" effect) *given* the selected ones: held-out SSE reduction (``gain``), and a Hotelling-type test
of its parameters with the block-jackknife covariance (``p_value``; Bonferroni over a "one of"
choice; Benjamini-Hochberg across the round). The best candidate is selected when adjusted p <
``alpha``, it explains >= ``min_explained`` of what the selected model leaves held-out, and its
estimate reaches its relevant magnitude somewhere.

Verdicts (``verdict`` of each effect):
* ``present``: selected, its jointly re-estimated parameters physically possible, no near-tie, and
  its final estimate distinct from zero at ``ci_level`` given its final sd (the change each
  undecided effect makes counted: ``_with_model_sd``);
* ``cannot_decide``: a near-tie (another candidate explains nearly as much and nothing more once
  either is in the model: ``indistinguishable_from``), an impossible estimate, a failed sign
  check, or not selected while the confidence interval of some parameter crosses its relevant
  size (``undecided_parameters`` + the motion that would shrink it);
* ``absent``: not selected, and an equivalence test holds: every parameter's confidence interval
  (``ci_level``, given the final model) lies inside +- its relevant size. The interval's sd is the
  larger of the block-jackknife sd and the sd the data's information allows (the Schur
  complement of the effect's columns given the final model, at the held-out residual level), so
  a direction the log does not excite never looks "absent".
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, NamedTuple

import numpy as np

from kinadapt_nn.diagnostics import intervals
from kinadapt_nn.diagnostics.intervals import jackknife_cov, paired_p, wald_pvalue  # noqa: F401 (the block statistics; re-exported)


IMPOSSIBLE = "physically impossible estimate"  #: the reason's start for a selected effect found impossible
WITHIN_SD = ("selected, but in the final model (the nuisance and the undecided effects fitted beside it) its estimate "
             "lies within its uncertainty of zero")  #: the reason of a selection the final sd swallows
BELOW_RELEVANT = "significant, but its estimate stays below the relevant size"  #: the reason of a small one


class SelCfg(NamedTuple):
    alpha: float = 0.01  #: false-discovery level of each round's tests
    min_explained: float = 0.05  #: [-] smallest held-out share of the remaining residual called an effect
    tie_ratio: float = 0.8  #: [-] a runner-up with this share of the best gain may be a near-tie
    tie_p: float = 0.01  #: one-sided paired block test: best beats the runner-up below this p
    ridge: float = 1e-9  #: [-] relative Tikhonov term on the scaled Gram
    ci_level: float = 0.95  #: two-sided level of the equivalence test's intervals


class Design(NamedTuple):
    """Regression rows (R) of a residual, effect columns and nuisance columns."""

    y: np.ndarray  #: (R,) weighted residual rows
    X: dict  #: effect -> (R, k) columns (weighted, unscaled: physical parameters)
    Z: np.ndarray  #: (R, z) nuisance columns, always fitted
    block: np.ndarray  #: (R,) block index
    n_blocks: int
    scale: dict  #: effect -> (k,) relevant magnitude of each parameter
    one_of: dict  #: effect -> bool
    W: np.ndarray  #: (R,) weight of each row (row value = W * physical residual)
    channel: np.ndarray  #: (R,) channel index of each row
    channel_names: tuple  #: names of the channels
    t_s: np.ndarray  #: (R,) time of each row [s]
    #: a streamed design (``stream.BlockStats``): the per-block normal equations of ``[Z, X_e1, ...]``
    #: (unscaled); then ``X`` and ``Z`` hold ``Width`` (the columns' shape only), never the columns
    stats: object | None = None


class Width(NamedTuple):
    """Columns of a streamed design that are not held: only their shape (R, k)."""

    shape: tuple


class Stats:
    """Per-block Gram statistics of ``[Z, X_e1 * d_e1, ...]`` (scaled columns) and ``y``: from the
    columns (``A``), or from a streamed design's per-block normal equations (``A`` is None; rows
    then come from ``predict``)."""

    def __init__(self, des: Design) -> None:
        self.names = list(des.X)
        self.des = des
        if des.stats is not None:
            self._from_blocks(des)
            return
        blocks = [des.Z * (1.0 / np.maximum(np.linalg.norm(des.Z, axis=0), 1e-300))] if des.Z.shape[1] else []
        self.idx: dict[str, np.ndarray] = {}
        k0 = des.Z.shape[1]
        self.z_idx = np.arange(k0)
        self.z_scale = 1.0 / np.maximum(np.linalg.norm(des.Z, axis=0), 1e-300) if k0 else np.zeros(0)
        for n in self.names:
            k = des.X[n].shape[1]
            self.idx[n] = np.arange(k0, k0 + k)
            k0 += k
            blocks.append(des.X[n] * np.asarray(des.scale[n])[None, :])
        A = np.concatenate(blocks, axis=1) if blocks else np.zeros((len(des.y), 0))
        self.A = A
        B = des.n_blocks
        K = A.shape[1]
        self.G = np.zeros((B, K, K))
        self.h = np.zeros((B, K))
        self.yy = np.zeros(B)
        for b in range(B):
            m = des.block == b
            Ab, yb = A[m], des.y[m]
            self.G[b] = Ab.T @ Ab
            self.h[b] = Ab.T @ yb
            self.yy[b] = float(yb @ yb)
        self._totals()

    def _from_blocks(self, des: Design) -> None:
        """The same statistics from ``des.stats`` (unscaled per-block ``G_b``, ``h_b``, ``yy_b``): each
        column scaled as ``__init__`` scales it (nuisance by its norm, effects by their relevant size)."""
        bs = des.stats
        k0 = des.Z.shape[1]
        diag = np.diagonal(bs.G.sum(0))
        self.z_idx = np.arange(k0)
        self.z_scale = 1.0 / np.maximum(np.sqrt(diag[:k0]), 1e-300) if k0 else np.zeros(0)
        scales = [self.z_scale]
        self.idx = {}
        for n in self.names:
            k = des.X[n].shape[1]
            self.idx[n] = np.arange(k0, k0 + k)
            k0 += k
            scales.append(np.asarray(des.scale[n], dtype=float))
        self.col_scale = np.concatenate(scales) if scales else np.zeros(0)
        d = self.col_scale
        self.A = None
        self.G = bs.G * d[None, :, None] * d[None, None, :]
        self.h = bs.h * d[None, :]
        self.yy = np.asarray(bs.yy, dtype=float)
        self._totals()

    def _totals(self) -> None:
        B, K = self.G.shape[0], self.G.shape[1]
        self.Gt, self.ht, self.yyt = self.G.sum(0), self.h.sum(0), float(self.yy.sum())
        self.present = np.array([self.yy[b] > 0 or np.any(self.G[b]) for b in range(B)])
        #: (K,) absolute ridge floor of each column: an effect column whose energy is this small
        #: (relative to the median relevant-size effect column) is unexcited and its parameter stays
        #: at 0; the nuisance columns (unit norm, always fitted) have none. A median, not a mean: one
        #: column whose energy grows with the log (a drift rate over an hour: ~T^3) must not set the
        #: floor of the others (a mean-based floor was 0.079 of a tared log's unit-norm offset columns at 6 min)
        diag = np.diagonal(self.Gt)
        eff = np.ones(K, bool)
        eff[self.z_idx] = False
        ref = float(np.median(diag[eff])) if eff.any() else 0.0
        self.floor = np.where(eff, 1e-9 * (ref + 1e-300), 0.0)
        self.B = int(self.present.sum())

    def lam(self, idx: np.ndarray, G: np.ndarray, ridge: float) -> np.ndarray:
        """(len(idx),) the Tikhonov term of the columns ``idx`` (``G`` their Gram): ``ridge`` times
        each column's own energy (scale-free: a large column does not shrink a small one) plus the
        column's floor."""
        return ridge * np.diagonal(G) + self.floor[idx]

    def solve(self, idx: np.ndarray, G: np.ndarray, h: np.ndarray, ridge: float) -> np.ndarray:
        """The ridge solution of the columns ``idx`` with Gram ``G`` (k, k) and ``h`` (k,) -> (k,)."""
        if len(h) == 0:
            return np.zeros(0)
        Gr = G + np.diag(self.lam(idx, G, ridge))
        try:
            return np.linalg.solve(Gr, h)
        except np.linalg.LinAlgError:
            return np.linalg.lstsq(Gr, h, rcond=None)[0]

    def cv(self, idx: np.ndarray, ridge: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Leave-one-block-out fits of the columns ``idx``: (held-out SSE per block (B,), the
        estimates (B, k), the full-data estimate (k,)), parameters in scaled units."""
        G, h = self.Gt[np.ix_(idx, idx)], self.ht[idx]
        sse = np.zeros(len(self.yy))
        reps = np.zeros((len(self.yy), len(idx)))
        for b in range(len(self.yy)):
            if not self.present[b]:
                continue
            Gb, hb = self.G[b][np.ix_(idx, idx)], self.h[b][idx]
            p = self.solve(idx, G - Gb, h - hb, ridge)
            reps[b] = p
            sse[b] = self.yy[b] - 2.0 * p @ hb + p @ Gb @ p
        return sse, reps[self.present], self.solve(idx, G, h, ridge)

    def predict(self, idx: np.ndarray, P: np.ndarray) -> np.ndarray:
        """(R,) each row's columns ``idx`` times its block's coefficients ``P`` (B, len(idx)),
        scaled units. A streamed design: one pass over the log (``stream.combine_rows``)."""
        if self.A is not None:
            return np.einsum("rk,rk->r", self.A[:, idx], P[self.des.block])
        full = np.zeros((P.shape[0], len(self.col_scale)))
        full[:, idx] = P * self.col_scale[idx][None, :]
        return self.des.stats.combine(full)

    def sse_all(self, idx: np.ndarray, p: np.ndarray) -> float:
        """Sum of squares over all rows of ``y - A[:, idx] p`` from the normal equations."""
        G, h = self.Gt[np.ix_(idx, idx)], self.ht[idx]
        return float(self.yyt - 2.0 * p @ h + p @ G @ p)

    def fit(self, idx: np.ndarray, ridge: float) -> np.ndarray:
        return self.solve(idx, self.Gt[np.ix_(idx, idx)], self.ht[idx], ridge)

    def schur(self, cand: np.ndarray, base: np.ndarray) -> np.ndarray:
        """Gram of ``cand`` columns with ``base`` columns projected out (scaled units)."""
        Gcc = self.Gt[np.ix_(cand, cand)]
        if len(base) == 0:
            return Gcc
        Gbb = self.Gt[np.ix_(base, base)]
        Gbc = self.Gt[np.ix_(base, cand)]
        lam = 1e-12 * np.diagonal(Gbb) + 1e-300  # per column: a large column does not shrink a small one
        return Gcc - Gbc.T @ np.linalg.solve(Gbb + np.diag(lam), Gbc)


@dataclass
class Candidate:
    """One candidate tested given the selected set."""

    effect: str
    cols: list[int]  #: the effect's columns used
    gain: np.ndarray  #: (B,) held-out SSE reduction per block
    sse: np.ndarray  #: (B,) held-out SSE with it
    p: np.ndarray  #: (k_used,) full-data estimate (scaled units)
    cov: np.ndarray  #: (k_used, k_used) block-jackknife covariance (scaled)
    p_value: float
    p_adjusted: float = 1.0
    choice_gains: dict = field(default_factory=dict)  #: column -> total gain (one-of effects)


def _test(st: Stats, des: Design, name: str, base: np.ndarray, sse_base: np.ndarray, rc: SelCfg,
          only_cols: list[int] | None = None) -> Candidate:
    k = des.X[name].shape[1]
    choices = [[j] for j in range(k)] if des.one_of[name] else [list(range(k))]
    if only_cols is not None:
        choices = [only_cols]
    best = None
    gains = {}
    for cols in choices:
        idx = np.concatenate([base, st.idx[name][cols]])
        sse, reps, p = st.cv(idx, rc.ridge)
        gain = sse_base - sse
        gains[tuple(cols)] = float(gain.sum())
        if best is None or gain.sum() > best[1].sum():
            best = (cols, gain, sse, reps[:, len(base):], p[len(base):])
    cols, gain, sse, reps, p = best
    cov = jackknife_cov(reps)
    pval = min(1.0, wald_pvalue(p, cov, len(reps)) * (len(choices) if only_cols is None else 1))
    return Candidate(name, list(cols), gain, sse, p, cov, pval, choice_gains=gains)


class Selection(NamedTuple):
    """The outcome of ``select`` (everything in scaled units; ``report`` turns it physical)."""

    entries: list  #: one dict per effect (see ``select``)
    present: dict  #: effect -> (cols, joint estimate (k,) physical, sd (k,) physical)
    sse_total: float  #: SSE of the residual after the nuisance fit
    sse_after: float  #: held-out SSE of the final model
    nuisance: np.ndarray  #: (z,) nuisance estimate (physical column units)
    nuisance_sd: np.ndarray  #: (z,) its sd
    heldout: np.ndarray | None = None  #: (R,) held-out residual rows of the final model (each block predicted
    #: by the fit on the other blocks)
    final_idx: np.ndarray | None = None  #: the final model's columns in ``Stats`` order (nuisance first)
    below_relevant: list | None = None  #: effects significant but below their relevant size (in ``heldout``'s model)


def select(des: Design, rc: SelCfg = SelCfg(), plausible: Callable[[str, np.ndarray], str | None] | None = None,
           hints: dict | None = None, block_all: str | None = None) -> Selection:
    """Forward selection and verdicts (module docstring). ``plausible(effect, params_physical)``
    returns why an estimate is impossible (or None); ``hints`` effect -> the motion that excites
    it; ``block_all``: a reason that makes every verdict ``cannot_decide`` (e.g. a failed sign
    check). Steps: ``_forward`` (rounds, near-ties) -> ``_below_relevant`` -> ``_joint`` (the
    final model re-estimated) -> ``_entry`` per effect (excitation, equivalence, verdict)."""
    hints = hints or {}
    st = Stats(des)
    base = st.z_idx.copy()
    sse0, _, _ = st.cv(base, rc.ridge)
    sse_total = float(sse0.sum()) or 1e-300
    alone = {n: _test(st, des, n, base, sse0, rc) for n in st.names}
    left_out: dict[str, dict] = {}  # selected, then physically impossible: no explanation, selected again without
    while True:
        fw = _rechosen(st, des, rc, base, _forward(st, des, rc, base, sse0, alone, hints, exclude=set(left_out)), hints)
        small = _below_relevant(st, des, st.names, fw.selected, fw.sse_sel, base, rc)
        jt = _joint(st, des, rc, base, fw)
        ctx = _EntryCtx(st, des, rc, base, fw, jt, small, sse_total, alone, plausible, hints, block_all)
        entries = [_entry(ctx, n) for n in st.names]
        bad = [e for e in entries if e["selected_round"] is not None and (e["reason"] or "").startswith(IMPOSSIBLE)]
        if not bad or block_all:
            break
        left_out.update({e["effect"]: e for e in bad})
    entries = [_left_out_entry(left_out[e["effect"]]) if e["effect"] in left_out else e for e in entries]
    jt = _with_model_sd(st, des, rc, jt, fw, entries)
    for e in entries:  # the final sd (the undecided effects' change counted) may swallow a selection
        if e["verdict"] == "present" and not _distinct_from_zero(jt.joint[e["effect"]], rc.ci_level):
            e["verdict"], e["significant"] = "cannot_decide", False
            e["reason"] = WITHIN_SD
    present = {e["effect"]: jt.joint[e["effect"]] for e in entries if e["verdict"] == "present"}
    order = {"present": 0, "cannot_decide": 1, "absent": 2}
    entries.sort(key=lambda e: (e["selected_round"] is None, e["selected_round"] or 0, order[e["verdict"]],
                                -e["explained_fraction"]))
    small_idx = np.concatenate([jt.idx, *[st.idx[s][c] for s, c in small.items()]]) if small else jt.idx
    return Selection(entries, present, sse_total, float(jt.sse.sum()), jt.nuisance, jt.nuisance_sd,
                     heldout_residual(st, des, small_idx, rc), jt.idx, list(small))


def _left_out_entry(e: dict) -> dict:
    """The entry of an effect selected and then found physically impossible: ``cannot_decide``, its
    estimate as selected, and out of the final model (the selection ran again without it)."""
    return {**e, "selected_round": None, "left_out": True,
            "reason": f"{e['reason']}; left out of the model (the selection ran again without it)"}


class _Forward(NamedTuple):
    """What the forward rounds found."""

    selected: list  #: [(effect, cols)] in the order selected
    ties: dict  #: effect -> set of effects it is near-tied with
    tie_labels: dict  #: effect -> ["effect:param"] near-tied columns of a one-of effect
    sse_sel: np.ndarray  #: (B,) held-out SSE of the selected model
    last: dict  #: effect -> its last ``Candidate`` test


def _rechosen(st: Stats, des: Design, rc: SelCfg, base: np.ndarray, fw: _Forward, hints: dict) -> _Forward:
    """``fw`` with each selected one-of effect's column chosen again given the final model less itself:
    the round that selected it chose among its columns given the effects selected before it, and an
    effect selected later can change which column explains best (a joint's encoder offset against a
    parallel joint's, told apart only once the tool's tilt is in the model). The column with the
    largest held-out gain replaces the round's choice when it beats it block by block (``paired_p``
    below ``tie_p``); the near-tied columns are judged again beside the column kept."""
    selected, tie_labels = list(fw.selected), dict(fw.tie_labels)
    for i, (n, cols) in enumerate(fw.selected):
        if not des.one_of[n]:
            continue
        others = np.concatenate([base, *[st.idx[s][c] for s, c in selected if s != n]])
        sse_o, _, _ = st.cv(others, rc.ridge)
        t = _test(st, des, n, others, sse_o, rc)
        kept = _test(st, des, n, others, sse_o, rc, only_cols=list(cols))
        if t.cols != list(cols) and paired_p(t.sse, kept.sse) < rc.tie_p:
            selected[i] = (n, list(t.cols))
            kept = t
        labels = []
        for c, g in t.choice_gains.items():
            if list(c) == kept.cols or g < rc.tie_ratio * kept.gain.sum():
                continue
            if paired_p(kept.sse, _test(st, des, n, others, sse_o, rc, only_cols=list(c)).sse) > rc.tie_p:
                labels.append(f"{n}:{des_param(des, n, c[0], hints)}")
        if labels:
            tie_labels[n] = labels
        else:
            tie_labels.pop(n, None)
    if selected == fw.selected and tie_labels == fw.tie_labels:
        return fw
    sse_sel, _, _ = st.cv(np.concatenate([base, *[st.idx[s][c] for s, c in selected]]), rc.ridge)
    return fw._replace(selected=selected, tie_labels=tie_labels, sse_sel=sse_sel)


def _forward(st: Stats, des: Design, rc: SelCfg, base: np.ndarray, sse0: np.ndarray, alone: dict,
             hints: dict, exclude: set = frozenset()) -> _Forward:
    """Forward selection (module docstring): each round tests the remaining candidates given the
    selected ones (BH across the round) and selects the best eligible one, noting near-ties.
    ``exclude``: effects never candidates (a physically impossible estimate, ``select``)."""
    from scipy.stats import false_discovery_control

    names = st.names
    last = dict(alone)
    selected: list[tuple[str, list[int]]] = []
    ties: dict[str, set[str]] = {}
    tie_labels: dict[str, list[str]] = {}
    sse_sel = sse0
    while len(selected) < len(names) - len(exclude):
        cand = [n for n in names if n not in {s for s, _ in selected} and n not in exclude]
        cur = np.concatenate([base, *[st.idx[s][c] for s, c in selected]]) if selected else base
        tests = alone if not selected else {n: _test(st, des, n, cur, sse_sel, rc) for n in cand}
        tests = {n: tests[n] for n in cand}
        padj = false_discovery_control([tests[n].p_value for n in cand], method="bh") if cand else []
        for n, pa in zip(cand, padj):
            tests[n].p_adjusted = float(pa)
            last[n] = tests[n]
        rest = float(sse_sel.sum()) or 1e-300
        ok = [n for n in cand if _eligible(tests[n], rest, rc)]
        if not ok:
            break
        best = max(ok, key=lambda n: tests[n].gain.sum())
        t = tests[best]
        rivals, labels = _near_ties(st, des, rc, tests, best, cur, sse_sel, hints)
        if labels:
            tie_labels.setdefault(best, []).extend(labels)
        if rivals:
            grp = {best, *rivals}
            for n in grp:
                ties.setdefault(n, set()).update(grp - {n})
        selected.append((best, t.cols))
        sse_sel = t.sse
    return _Forward(selected, ties, tie_labels, sse_sel, last)


def _eligible(t: Candidate, rest: float, rc: SelCfg) -> bool:
    """Significant, explains ``min_explained`` of ``rest`` held-out, and reaches its relevant size."""
    big = np.max(np.abs(t.p)) >= 1.0 if len(t.p) else False  # scaled: 1 = relevant magnitude
    return t.p_adjusted < rc.alpha and t.gain.sum() / rest >= rc.min_explained and big


def _near_ties(st: Stats, des: Design, rc: SelCfg, tests: dict, best: str, cur: np.ndarray,
               sse_sel: np.ndarray, hints: dict) -> tuple[list[str], list[str]]:
    """Near-ties of the round's ``best`` among the round's candidates ``tests``: another effect, or
    another column of a one-of effect, that explains nearly as much and nothing more once the best
    is in the model (and is not significantly worse block by block), while the best explains
    nothing more once it is in the model either -- when the best still explains a significant part
    of what the rival leaves, the data tell them apart (a payload against a constant offset: alike
    in contact, apart where the sensor turns in free space) and they are not tied. -> (rival
    effects, ``best:param`` labels)."""
    t = tests[best]
    cand = list(tests)
    rivals: list[str] = []
    for n in cand:
        if n == best or tests[n].gain.sum() < rc.tie_ratio * t.gain.sum() or tests[n].gain.sum() <= 0:
            continue
        cur_b = np.concatenate([cur, st.idx[best][t.cols]])
        given = _test(st, des, n, cur_b, t.sse, rc)
        if given.gain.sum() / (float(t.sse.sum()) or 1e-300) < rc.min_explained and \
                paired_p(t.sse, tests[n].sse) > rc.tie_p and not _tells_apart(st, des, rc, tests[n], best, cur):
            rivals.append(n)
    labels: list[str] = []
    if des.one_of[best]:
        for cols, g in t.choice_gains.items():
            if list(cols) == t.cols or g < rc.tie_ratio * t.gain.sum():
                continue
            alt = _test(st, des, best, cur, sse_sel, rc, only_cols=list(cols))
            if paired_p(t.sse, alt.sse) > rc.tie_p:
                labels.append(f"{best}:{des_param(des, best, cols[0], hints)}")
    return rivals, labels


def _tells_apart(st: Stats, des: Design, rc: SelCfg, rival: Candidate, best: str, cur: np.ndarray) -> bool:
    """Does ``best`` explain a significant part (p < alpha, at least ``min_explained``) of what
    ``rival`` leaves, held-out?"""
    back = _test(st, des, best, np.concatenate([cur, st.idx[rival.effect][rival.cols]]), rival.sse, rc)
    return back.p_value < rc.alpha and back.gain.sum() / (float(rival.sse.sum()) or 1e-300) >= rc.min_explained


class _Joint(NamedTuple):
    """The final model re-estimated jointly."""

    sse: np.ndarray  #: (B,) held-out SSE
    idx: np.ndarray  #: its columns (nuisance first)
    joint: dict  #: effect -> (cols, estimate physical, sd physical)
    nuisance: np.ndarray  #: (z,) nuisance estimate (physical column units)
    nuisance_sd: np.ndarray  #: (z,) its sd (physical column units; as the effects' sd)


def _joint(st: Stats, des: Design, rc: SelCfg, base: np.ndarray, fw: _Forward) -> _Joint:
    """Joint re-estimate of everything selected (block-jackknife sd), with the significant effects
    the forward rounds left out fitted beside them (``intervals.given_significant``)."""
    selected, last = fw.selected, fw.last
    sel_idx = np.concatenate([base, *[st.idx[s][c] for s, c in selected]]) if selected else base
    sse_fin, reps, p_all = st.cv(sel_idx, rc.ridge)
    cov_all = jackknife_cov(reps)
    fit_idx, p_fit = sel_idx, p_all
    chosen = {s for s, _ in selected}  # significant effects left out: fitted beside the selected (intervals.py)
    extra = [st.idx[n][last[n].cols] for n in st.names if n not in chosen and last[n].p_adjusted < rc.alpha]
    if selected and extra:
        p_all, cov_all, fit_idx, p_fit = intervals.given_significant(lambda ii: st.cv(ii, rc.ridge), sel_idx, extra)
    var = _honest_var(st, cov_all, len(reps), fit_idx, p_fit, len(sel_idx)) if selected else np.diag(cov_all)
    joint: dict[str, tuple] = {}
    i = len(base)
    for s, c in selected:
        sc = np.asarray(des.scale[s])[c]
        k = len(c)
        joint[s] = (c, p_all[i:i + k] * sc, np.sqrt(np.clip(var[i:i + k], 0, None)) * sc)
        i += k
    nuis = p_all[:len(base)] * st.z_scale if len(base) else np.zeros(0)
    nuis_sd = np.sqrt(np.clip(var[:len(base)], 0, None)) * st.z_scale if len(base) else np.zeros(0)
    return _Joint(sse_fin, sel_idx, joint, nuis, nuis_sd)


def _with_model_sd(st: Stats, des: Design, rc: SelCfg, jt: _Joint, fw: _Forward, entries: list) -> _Joint:
    """The final model's estimates given the choice the data could not make: each effect the verdict
    leaves ``cannot_decide`` (a near-tie, too little excitation) is fitted beside the final model in
    turn, and the largest change it makes to each selected parameter and nuisance joins that
    parameter's sd in quadrature (``model_sd`` in the entry). An estimate conditional on a model the
    data did not choose is reported with the spread of that choice, not only the noise's."""
    cands = [e["effect"] for e in entries if e["verdict"] == "cannot_decide" and e["effect"] not in jt.joint
             and not e.get("left_out")]  # an impossible estimate is no alternative model
    if not cands:
        return jt
    p0 = st.fit(jt.idx, rc.ridge)
    dmax = np.zeros(len(jt.idx))
    for n in cands:
        p2 = st.fit(np.concatenate([jt.idx, st.idx[n][fw.last[n].cols]]), rc.ridge)[:len(jt.idx)]
        dmax = np.maximum(dmax, np.abs(p2 - p0))
    z = len(st.z_idx)
    joint, i = {}, z
    by_name = {e["effect"]: e for e in entries}
    for s, (c, est, sd) in jt.joint.items():
        d = dmax[i:i + len(c)] * np.asarray(des.scale[s])[c]
        joint[s] = (c, est, np.sqrt(sd ** 2 + d ** 2))
        e = by_name[s]
        e["sd"] = np.asarray(e["sd"], dtype=float).copy()
        e["sd"][c] = joint[s][2]
        e["model_sd"] = np.zeros(len(e["sd"]))
        e["model_sd"][c] = d
        i += len(c)
    nuis_sd = np.sqrt(jt.nuisance_sd ** 2 + (dmax[:z] * st.z_scale) ** 2) if z else jt.nuisance_sd
    return jt._replace(joint=joint, nuisance_sd=nuis_sd)


def _honest_var(st: Stats, cov_jk: np.ndarray, n_blocks: int, fit_idx: np.ndarray, p_fit: np.ndarray, k: int
                ) -> np.ndarray:
    """(k,) the variances reported for the first ``k`` of the fitted columns ``fit_idx`` (estimate ``p_fit``,
    scaled units): the block jackknife's (``cov_jk``, its B - 1 degrees of freedom turned into a t interval,
    ``intervals.t_widen``), at least the white-noise and the block-robust sandwich ones
    (``intervals.honest_sd``): ``refit``'s three sd (its jackknife without the t quantile), so that a structured residual (a mostly-contact
    log, a model that misfits) widens the interval instead of leaving it to the noise alone."""
    var = np.diag(cov_jk)[:k] * intervals.t_widen(n_blocks - 1)
    rows = int(st.des.y.shape[0])
    var_h = intervals.honest_sd(st.G[:, fit_idx][:, :, fit_idx], st.h[:, fit_idx], st.yy, p_fit, rows) ** 2
    return np.maximum(var, var_h[:k])


class _EntryCtx(NamedTuple):
    """Everything an effect's entry is judged from."""

    st: Stats
    des: Design
    rc: SelCfg
    base: np.ndarray
    fw: _Forward
    jt: _Joint
    small: dict
    sse_total: float
    alone: dict
    plausible: Callable | None
    hints: dict
    block_all: str | None


def _entry(cx: _EntryCtx, n: str) -> dict:
    """One effect's entry: fractions, p-values, estimate, excitation, equivalence and verdict."""
    des, fw = cx.des, cx.fw
    t = fw.last[n]
    k = des.X[n].shape[1]
    scale = np.asarray(des.scale[n])
    e: dict = {"effect": n, "explained_fraction": float(t.gain.sum() / cx.sse_total),
               "explained_fraction_alone": float(cx.alone[n].gain.sum() / cx.sse_total),
               "p_value": float(t.p_value), "p_adjusted": float(t.p_adjusted)}
    sel = n in cx.jt.joint
    if sel:
        c, pv, sd = cx.jt.joint[n]
    else:
        c, pv = t.cols, t.p * scale[t.cols]
        sd = np.sqrt(np.clip(np.diag(t.cov), 0, None)) * scale[c]
    p_full, sd_full = np.zeros(k), np.zeros(k)
    p_full[c], sd_full[c] = pv, sd
    e["params"], e["sd"], e["columns_used"] = p_full, sd_full, list(c)
    undecided = _excitation(cx, n, e, sel)
    verdict, reason = _verdict(cx, n, p_full, sel, undecided)
    if n in cx.small and verdict != "present":
        e["below_relevant"] = True
    e["verdict"], e["reason"] = verdict, reason
    e["significant"] = verdict == "present"
    e["selected_round"] = next((r for r, (s, _) in enumerate(fw.selected) if s == n), None)
    if n in fw.ties or n in fw.tie_labels:
        e["indistinguishable_from"] = sorted(fw.ties.get(n, set())) + fw.tie_labels.get(n, [])
        e["to_separate"] = " / ".join(cx.hints.get(x.split(":")[0], "") for x in [n, *sorted(fw.ties.get(n, set()))])
    if verdict == "cannot_decide" and undecided and not sel:
        e["to_excite"] = cx.hints.get(n, "")
    return e


def _excitation(cx: _EntryCtx, n: str, e: dict, sel: bool) -> list[int]:
    """Excitation and (not selected) the equivalence test: each parameter given the final model
    minus itself; writes ``e["excitation"]`` (and ``e["equivalence"]``). -> undecided parameters."""
    st, des = cx.st, cx.des
    k = des.X[n].shape[1]
    scale = np.asarray(des.scale[n])
    sse_ref = max(float(cx.jt.sse.sum()), 1e-4 * len(des.y))
    others = np.concatenate([cx.base, *[st.idx[s][cc] for s, cc in cx.fw.selected if s != n]])
    eq = equivalence(st, des, n, others, cx.jt.sse, cx.rc) if not sel else None
    if des.one_of[n]:
        lam = np.array([float(st.schur(st.idx[n][[j]], others)[0, 0]) for j in range(k)])
        ratio = float(lam.min() / sse_ref)
    else:
        ratio = float(np.linalg.eigvalsh(st.schur(st.idx[n], others))[0] / sse_ref)
    undecided = [] if eq is None else [j for j in range(k) if not eq["inside"][j]]
    if des.one_of[n]:  # a column the effect leaves zero here is no parameter of this log (encoder_offset's z_s joint)
        undecided = [j for j in undecided if lam[j] > 0.0]
    e["excitation"] = {"ratio": ratio, "enough": not undecided, "weak_parameters": undecided}
    if eq is not None:
        e["equivalence"] = {"ci_low": eq["lo"] * scale, "ci_high": eq["hi"] * scale, "relevant": scale,
                            "level": cx.rc.ci_level}
    return undecided


def _verdict(cx: _EntryCtx, n: str, p_full: np.ndarray, sel: bool, undecided: list[int]) -> tuple[str, str | None]:
    """present / cannot_decide / absent and the reason (module docstring)."""
    tie = "a near-tie: another explanation fits the data as well"
    reason = None
    if cx.block_all:
        verdict, reason = "cannot_decide", cx.block_all
    elif sel:
        why = cx.plausible(n, p_full) if cx.plausible else None
        if why:
            verdict, reason = "cannot_decide", f"{IMPOSSIBLE}: {why}"
        elif n in cx.fw.ties or n in cx.fw.tie_labels:
            verdict, reason = "cannot_decide", tie
        else:
            verdict = "present"
    elif n in cx.fw.ties:
        verdict, reason = "cannot_decide", tie
    elif undecided:
        verdict = "cannot_decide"
        reason = "its confidence interval crosses the relevant size: not excited enough to rule out"
    else:
        verdict = "absent"
    if n in cx.small and verdict == "cannot_decide":
        reason = BELOW_RELEVANT
    return verdict, reason


def _distinct_from_zero(joint: tuple, level: float) -> bool:
    """Whether a selected effect's final estimate (``_Joint.joint[name]``: columns, estimate (k,), sd (k,))
    differs from zero at ``level``: the Wald statistic of its parameters with their final sd (the
    nuisance and the undecided effects' change counted, ``_with_model_sd``) against chi-square(k).
    A selection that the final model's uncertainty swallows is no finding."""
    from scipy.stats import chi2

    _, p, sd = joint
    p, sd = np.asarray(p, dtype=float), np.asarray(sd, dtype=float)
    keep = sd > 0
    if not keep.any():
        return True
    return float(np.sum((p[keep] / sd[keep]) ** 2)) > float(chi2.ppf(level, int(keep.sum())))


def _below_relevant(st: Stats, des: Design, names: list[str], selected: list, sse_sel: np.ndarray, base: np.ndarray,
                    rc: SelCfg) -> dict[str, list[int]]:
    """Forward selection continued past the final model with the relevant-size requirement
    dropped: library effects that are significant and explain ``min_explained`` but whose
    estimate stays below the relevant size. They are not findings, but the library explains
    them, so the completeness verdict judges the residual with them in the model."""
    from scipy.stats import false_discovery_control

    chosen = {s_: c for s_, c in selected}
    small: dict[str, list[int]] = {}
    while True:
        cand = [n for n in names if n not in chosen and n not in small]
        if not cand:
            break
        cur = np.concatenate([base, *[st.idx[s_][c] for s_, c in {**chosen, **small}.items()]])
        tests = {n: _test(st, des, n, cur, sse_sel, rc) for n in cand}
        padj = false_discovery_control([tests[n].p_value for n in cand], method="bh")
        rest = float(sse_sel.sum()) or 1e-300
        ok = [n for n, pa in zip(cand, padj) if pa < rc.alpha and tests[n].gain.sum() / rest >= rc.min_explained]
        if not ok:
            break
        best = max(ok, key=lambda n: tests[n].gain.sum())
        small[best] = tests[best].cols
        sse_sel = tests[best].sse
    return small


def equivalence(st: Stats, des: Design, name: str, others: np.ndarray, sse_fin: np.ndarray, rc: SelCfg) -> dict:
    """Confidence intervals (scaled units: 1 = the relevant size) of ``name``'s parameters given
    the ``others`` columns (module docstring). A one-of effect: each column on its own.
    -> {"lo" (k,), "hi" (k,), "inside" (k,) bool}."""
    from scipy.stats import t as t_dist

    k = des.X[name].shape[1]
    n_rows = max(len(des.y), 1)
    s2 = max(float(sse_fin.sum()), 1e-300) / n_rows  # held-out residual variance per row (scaled rows)
    groups = [[j] for j in range(k)] if des.one_of[name] else [list(range(k))]
    lo, hi = np.zeros(k), np.zeros(k)
    for cols in groups:
        idx = np.concatenate([others, st.idx[name][cols]])
        _, reps, p = st.cv(idx, rc.ridge)
        p = p[len(others):]
        cov_j = jackknife_cov(reps[:, len(others):])
        S = st.schur(st.idx[name][cols], others)
        ev, V = np.linalg.eigh(S)
        inv = (V / np.maximum(ev, 1e-300)) @ V.T  # information-limited covariance (per unit s2)
        var = np.maximum(np.diag(cov_j), s2 * np.diag(inv))
        q = float(t_dist.ppf(0.5 + rc.ci_level / 2, max(len(reps) - 1, 1)))
        lo[cols], hi[cols] = p - q * np.sqrt(var), p + q * np.sqrt(var)
    return {"lo": lo, "hi": hi, "inside": (lo > -1.0) & (hi < 1.0)}


def heldout_residual(st: Stats, des: Design, idx: np.ndarray, rc: SelCfg) -> np.ndarray:
    """(R,) residual rows of the columns ``idx``, each block predicted by the fit on the others."""
    out = des.y.copy()
    G, h = st.Gt[np.ix_(idx, idx)], st.ht[idx]
    P = np.zeros((len(st.yy), len(idx)))
    for b in range(len(st.yy)):
        m = des.block == b
        if not m.any() or len(idx) == 0:
            continue
        p = st.solve(idx, G - st.G[b][np.ix_(idx, idx)], h - st.h[b][idx], rc.ridge)
        if st.A is None:
            P[b] = p
        else:
            out[m] = des.y[m] - st.A[m][:, idx] @ p
    if st.A is None and len(idx):
        out = des.y - st.predict(idx, P)
    return out


def des_param(des: Design, name: str, col: int, hints: dict) -> str:
    """Label of one column of a one-of effect (``param_names`` in ``hints['_params']``)."""
    params = hints.get("_params", {}).get(name)
    return params[col] if params else f"col{col}"


def tie_words(effect: str, own: list[str], ties: list[str]) -> str:
    """A near-tie in words. A tie with another column of the same one-of effect (the label
    ``effect:param``) names the two parameters (``offset_joint3 indistinguishable from
    offset_joint4``), never the effect as indistinguishable from itself."""
    same = [t.partition(":")[2] for t in ties if t.startswith(f"{effect}:")]
    rest = [t for t in ties if not t.startswith(f"{effect}:")]
    subject = f"{' / '.join(own)} " if same and own else ""
    return f"{subject}indistinguishable from {', '.join(same + rest)}"


def refit(des: Design, names: list[str], rc: SelCfg = SelCfg(), cols: dict | None = None
          ) -> tuple[np.ndarray, np.ndarray, dict]:
    """Fit the nuisance alone and with ``names`` (a one-of effect keeps the column ``cols[name]``
    when given -- the one the selection named -- else its best column on all rows) on all rows. -> (residual rows before (R,), after (R,), {effect: (cols, params physical (k,), sd
    physical (k,))}); the sd is the largest of the block-jackknife, the least-squares and the block-robust
    (sandwich, ``intervals.honest_sd``) one (finite)."""
    st = Stats(des)
    base = st.z_idx
    p0 = st.fit(base, rc.ridge)
    before = des.y - _rows(st, base, p0)
    idx = [base]
    chosen = {}
    for n in names:
        k = des.X[n].shape[1]
        if des.one_of[n] and cols and cols.get(n):
            chosen[n] = list(cols[n])
        elif des.one_of[n]:
            sse = []
            for j in range(k):
                ii = np.concatenate([base, st.idx[n][[j]]])
                p = st.fit(ii, rc.ridge)
                sse.append(float(np.sum((des.y - st.A[:, ii] @ p) ** 2)) if st.A is not None else st.sse_all(ii, p))
            chosen[n] = [int(np.argmin(sse))]
        else:
            chosen[n] = list(range(k))
        idx.append(st.idx[n][chosen[n]])
    ii = np.concatenate(idx)
    p = st.fit(ii, rc.ridge)
    after = des.y - _rows(st, ii, p)
    _, reps, _ = st.cv(ii, rc.ridge)
    var_j = np.diag(jackknife_cov(reps)) if len(reps) > 1 else np.zeros(len(ii))
    G = st.Gt[np.ix_(ii, ii)]
    s2 = float(after @ after) / max(len(after) - len(ii), 1)
    var_ls = s2 * np.diag(np.linalg.pinv(G + np.diag(st.lam(ii, G, rc.ridge)))) if len(G) else np.zeros(0)
    var_h = intervals.honest_sd(st.G[:, ii][:, :, ii], st.h[:, ii], st.yy, p, len(after)) ** 2 if len(ii) else np.zeros(0)
    sd_all = np.sqrt(np.maximum.reduce([var_j, var_ls, var_h]))
    out, i = {}, len(base)
    for n in names:
        c = chosen[n]
        sc = np.asarray(des.scale[n])[c]
        full, sd = np.zeros(des.X[n].shape[1]), np.zeros(des.X[n].shape[1])
        full[c] = p[i:i + len(c)] * sc
        sd[c] = sd_all[i:i + len(c)] * sc
        out[n] = (c, full, sd)
        i += len(c)
    return before, after, out


def _rows(st: Stats, idx: np.ndarray, p: np.ndarray) -> np.ndarray:
    """(R,) the rows of columns ``idx`` times one coefficient vector ``p`` (scaled units)."""
    if st.A is not None:
        return st.A[:, idx] @ p
    if len(idx) == 0:
        return np.zeros(len(st.des.y))
    return st.predict(idx, np.tile(p, (len(st.yy), 1)))
