"""Exact re-estimates of effects whose columns are a first-order model (Gauss-Newton on the selection).

An effect's columns are linear in its parameters; for some the physics is not (a rotation of the sensor
axes, ``ft_frame_rotation``: ``r_meas = R(delta)^T r`` with the columns the first-order ``r x delta``).
Such an effect may give ``exact(s, p) -> (n, 6)``: the wrench change its parameters ``p`` make exactly.
Once the selection has chosen its model, ``refine`` iterates Gauss-Newton steps: the residual rows less
the remainder ``exact(p) - columns p`` (through the same row map as everything else), the selected
columns refitted jointly. The first-order estimate's bias (the second-order term projected onto the
columns) goes; the sd (the columns' jackknife) is unchanged to first order.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from kinadapt_nn.diagnostics import selection as sel


def _selected(result: sel.Selection) -> list[tuple[str, list[int]]]:
    """The selected effects and their columns, in the order of the final model's columns."""
    ent = [e for e in result.entries if e.get("selected_round") is not None]
    return [(e["effect"], list(e["columns_used"])) for e in sorted(ent, key=lambda e: e["selected_round"])]


def refine(result: sel.Selection, des: sel.Design, rm, s, lib: dict, cols: dict, rc: sel.SelCfg,
           iters: int = 4) -> sel.Selection:
    """``result`` with the present effects re-estimated exactly where a selected effect has ``exact``
    (module docstring); unchanged otherwise. ``rm``: the design's ``stream.RowMap`` ((n, 6, k) sample
    columns -> (R, k) rows); ``cols``: effect -> its column source (``stream.Source``, a streamed
    design) or its (n, 6, k) sample columns. A one-of effect near-tied between its own columns is
    first judged on the exact models (``_tie_between_columns``)."""
    chosen = _selected(result)
    if not any(getattr(lib[n], "exact", None) is not None for n, _ in chosen):
        return result
    cx = _Ctx(sel.Stats(des), des, rm, s, lib, cols, rc, iters)
    result = _tie_between_columns(result, cx)
    p_full, _, _ = _gauss_newton(cx, _selected(result))
    return _with_params(result, _split(p_full, _selected(result), len(cx.st.z_idx)))


class _Ctx(NamedTuple):
    """What every exact fit of one selection needs (``refine``'s arguments, the design's ``Stats``)."""

    st: sel.Stats
    des: sel.Design
    rm: object  #: the design's ``stream.RowMap``
    s: object  #: the log's signals
    lib: dict
    cols: dict
    rc: sel.SelCfg
    iters: int


def _gauss_newton(cx: _Ctx, chosen: list) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The model ``chosen`` ([(effect, cols)]) fitted with the exact changes of its effects that give
    ``exact``: -> (the estimate (nuisance then effects; physical for the effects, scaled for the
    nuisance), its columns in ``Stats`` order, the remainder rows (R,) at it)."""
    st, des, rm, s, lib, cols, rc = cx.st, cx.des, cx.rm, cx.s, cx.lib, cx.cols, cx.rc
    base = st.z_idx
    idx = np.concatenate([base, *[st.idx[n][c] for n, c in chosen]])
    scale = np.concatenate([np.ones(len(base)), *[np.asarray(des.scale[n])[c] for n, c in chosen]])
    G = st.Gt[np.ix_(idx, idx)]
    p = st.fit(idx, rc.ridge) * scale
    exact = [(n, c) for n, c in chosen if getattr(lib[n], "exact", None) is not None]
    y_rem = np.zeros(len(des.y))
    for _ in range(cx.iters):
        y_rem = _remainder_rows(s, rm, lib, exact, cols, _split(p, chosen, len(base)), des)
        p = st.solve(idx, G, st.ht[idx] - _cross(st, des, s, rm, y_rem, idx), rc.ridge) * scale
    y_rem = _remainder_rows(s, rm, lib, exact, cols, _split(p, chosen, len(base)), des)
    return p, idx, y_rem


def _block_sse(st: sel.Stats, des: sel.Design, p: np.ndarray, idx: np.ndarray, y_rem: np.ndarray,
               scale: np.ndarray) -> np.ndarray:
    """(B,) the wrench rows' in-sample SSE per block of the model ``p`` on the columns ``idx`` (physical
    ``p``; ``scale`` turns it to ``Stats`` units) with the exact remainder ``y_rem`` (R,)."""
    P = np.tile(p / scale, (len(st.yy), 1))
    r = des.y - st.predict(idx, P) - y_rem
    return np.bincount(des.block, weights=r * r, minlength=len(st.yy)).astype(float)


def _tie_between_columns(result: sel.Selection, cx: _Ctx) -> sel.Selection:
    """A selected one-of effect with ``exact`` whose column the first-order columns leave near-tied with
    others of its own (labels ``effect:param``): each of those columns is fitted with its exact change
    (``_gauss_newton``) and the wrench rows' residuals compared block by block. The column whose exact
    model leaves less than every other, each beaten below ``tie_p`` (``sel.paired_p``), is kept and the
    tie resolved; otherwise the tie stands. (An encoder offset of one joint against a parallel joint's:
    alike to first order, apart where the declared socket's anchors and engagement move with the tip.)"""
    st, des, lib, rc = cx.st, cx.des, cx.lib, cx.rc
    for e in result.entries:
        n = e["effect"]
        labels = [x for x in e.get("indistinguishable_from") or [] if x.startswith(f"{n}:")]
        if e.get("selected_round") is None or not des.one_of[n] or lib[n].exact is None or not labels:
            continue
        params = list(lib[n].params)
        cands = [tuple(e["columns_used"])] + [(params.index(x.partition(":")[2]),) for x in labels
                                              if x.partition(":")[2] in params]
        fits, sse = {}, {}
        for c in cands:
            chosen = [(m, list(c) if m == n else cc) for m, cc in _selected(result)]
            p, idx, y_rem = _gauss_newton(cx, chosen)
            scale = np.concatenate([np.ones(len(st.z_idx)), *[np.asarray(des.scale[m])[cc] for m, cc in chosen]])
            fits[c], sse[c] = (chosen, p, idx, scale), _block_sse(st, des, p, idx, y_rem, scale)
        best = min(sse, key=lambda c: float(sse[c].sum()))
        e["exact_column_sse"] = {params[c[0]]: float(sse[c].sum()) for c in cands}
        if not all(sel.paired_p(sse[best], sse[c]) < rc.tie_p for c in cands if c != best):
            continue
        e["tie_resolved"] = (f"{params[best[0]]}: its exact model leaves less than {', '.join(params[c[0]] for c in cands if c != best)} "
                             f"in every comparison of the blocks (p < {rc.tie_p:g}); the first-order columns had chosen "
                             f"{params[cands[0][0]]}")
        result = _resolved(result, e, n, best, fits[best], cx, labels)
    return result


def _resolved(result: sel.Selection, e: dict, n: str, best: tuple, fit: tuple, cx: _Ctx, labels: list) -> sel.Selection:
    """``result`` with the one-of effect ``n``'s entry ``e`` on the column ``best`` (its exact model beat
    the others): the column and estimate, its sd (the column's block jackknife, at least the sd the
    round's column had), the labels gone, and the verdict the tie held back -- ``present`` only where the
    estimate reaches the relevant size and differs from zero at the selection's level, as any other."""
    st, rc = cx.st, cx.rc
    chosen, p, idx, scale = fit
    k0 = len(st.z_idx) + sum(len(cc) for m, cc in chosen[:[m for m, _ in chosen].index(n)])
    _, reps, _ = st.cv(idx, rc.ridge)
    sd_new = float(np.sqrt(max(sel.jackknife_cov(reps)[k0, k0], 0.0))) * float(scale[k0])
    old = list(e["columns_used"])
    sd = max(sd_new, float(np.asarray(e["sd"])[old].max()))
    e["params"] = np.zeros(len(e["params"]))
    e["params"][best[0]] = p[k0]
    e["sd"] = np.zeros(len(e["params"]))
    e["sd"][best[0]] = sd
    e["columns_used"] = list(best)
    rest = [x for x in e["indistinguishable_from"] if x not in labels]
    e.pop("to_separate", None)
    if rest:
        e["indistinguishable_from"] = rest
    else:
        e.pop("indistinguishable_from")
        if (e.get("reason") or "").startswith("a near-tie"):
            e["verdict"], e["reason"], e["significant"] = _untied_verdict(p[k0], sd, float(np.asarray(cx.des.scale[n])[best[0]]),
                                                                          rc.ci_level)
    present = dict(result.present)
    if e["verdict"] == "present":
        present[n] = (list(best), np.array([p[k0]]), np.array([sd]))
    return result._replace(present=present)


def _untied_verdict(p: float, sd: float, relevant: float, level: float) -> tuple[str, str | None, bool]:
    """(verdict, reason, significant) of a one-of effect whose tie the exact models resolved: the estimate
    ``p`` (sd ``sd``) must reach ``relevant`` and differ from zero at ``level`` (``selection``'s rules)."""
    if not sel._distinct_from_zero(([0], [p], [sd]), level):
        return "cannot_decide", sel.WITHIN_SD, False
    if abs(p) < relevant:
        return "cannot_decide", sel.BELOW_RELEVANT, True
    return "present", None, True


def _remainder_rows(s, rm, lib: dict, exact: list[tuple[str, list[int]]], cols: dict, p_phys: dict,
                    des: sel.Design) -> np.ndarray:
    """(R,) the rows (``rm``) of the exact changes of the ``exact`` effects at ``p_phys`` less their
    first-order columns. A streamed design: one chunked pass (``stream.row_values``; the remainder
    is sample-local like any column), never an (n, 6) series of the whole log; held columns: per
    sample, then mapped."""
    fulls = {}
    for n, c in exact:
        fulls[n] = np.zeros(lib[n].k)
        fulls[n][c] = p_phys[n]
    if any(isinstance(cols[n], np.ndarray) for n, _ in exact):
        rem = np.zeros_like(s.wrench)  # (n, 6) exact change less its first-order columns, per sample
        for n, _ in exact:
            rem += lib[n].exact(s, fulls[n]) - _first_order(s, cols[n], fulls[n], des)
        return rm.apply(rem[:, :, None])[:, 0]
    from kinadapt_nn.diagnostics import stream

    def remainder(sub) -> np.ndarray:  # (m, 6, 1) of a chunk's signals
        out = np.zeros((sub.n, 6))
        for n, _ in exact:
            full = fulls[n]
            out += lib[n].exact(sub, full) - np.asarray(cols[n].columns(sub), dtype=float)[:, :, :len(full)] @ full
        return out[:, :, None]

    chunk = des.stats.chunk if des.stats is not None else None
    return stream.row_values(s, rm, stream.Source("_remainder", remainder, [0]), chunk)[:, 0]


def _first_order(s, src, full: np.ndarray, des: sel.Design) -> np.ndarray:
    """(n, 6) an effect's columns times ``full`` (k,), per sample: from its source in chunks (a
    streamed design) or from its held (n, 6, k) columns."""
    if isinstance(src, np.ndarray):
        return src @ full
    from kinadapt_nn.diagnostics import stream

    chunk = des.stats.chunk if des.stats is not None else None
    return stream.sample_sum(s, [src._replace(cols=list(range(len(full))))], [full], 1, chunk)


def _cross(st: sel.Stats, des: sel.Design, s, rm, y: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """(len(idx),) the design's scaled columns ``idx`` times the rows ``y`` (R,): ``A^T y`` from the
    held columns, or one chunked pass over the log that evaluates only the sources of those columns
    (a streamed design)."""
    if st.A is not None:
        return (st.A.T @ y)[idx]
    from kinadapt_nn.diagnostics import stream

    bs = des.stats
    offs = np.cumsum([0] + [len(src.cols) for src in bs.sources])
    kept = bs.rows or {}
    srcs, where, out = [], [], {}  # the sources of the columns idx (not kept), each with only those columns
    for i, src in enumerate(bs.sources):
        mine = [int(c) for c in idx if offs[i] <= c < offs[i + 1]]
        if mine and i in kept:  # the design pass kept its rows: no pass
            out.update(zip(mine, kept[i][:, [c - offs[i] for c in mine]].T @ y))
        elif mine:
            srcs.append(src._replace(cols=[src.cols[c - offs[i]] for c in mine]))
            where += mine
    if srcs:
        out.update(zip(where, stream.block_stats(s, rm, srcs, y, des.block, des.n_blocks, bs.chunk).h.sum(0)))
    return np.array([out[int(c)] for c in idx]) * st.col_scale[idx]


def _split(p: np.ndarray, chosen: list[tuple[str, list[int]]], k0: int) -> dict[str, np.ndarray]:
    out, i = {}, k0
    for n, c in chosen:
        out[n] = p[i:i + len(c)]
        i += len(c)
    return out


def _with_params(result: sel.Selection, p_phys: dict[str, np.ndarray]) -> sel.Selection:
    present = dict(result.present)
    for e in result.entries:
        n = e["effect"]
        if n not in p_phys:
            continue
        full = np.array(e["params"], dtype=float)
        full[e["columns_used"]] = p_phys[n]
        e["params"] = full
        if n in present:
            c, _, sd = present[n]
            present[n] = (c, p_phys[n], sd)
    return result._replace(present=present)


__all__ = ["refine"]
