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
    design) or its (n, 6, k) sample columns."""
    chosen = _selected(result)
    if not any(getattr(lib[n], "exact", None) is not None for n, _ in chosen):
        return result
    st = sel.Stats(des)
    base = st.z_idx
    idx = np.concatenate([base, *[st.idx[n][c] for n, c in chosen]])
    scale = np.concatenate([np.ones(len(base)), *[np.asarray(des.scale[n])[c] for n, c in chosen]])
    G = st.Gt[np.ix_(idx, idx)]
    p_phys = _split(st.fit(idx, rc.ridge) * scale, chosen, len(base))
    for _ in range(iters):
        y_rem = _remainder_rows(s, rm, lib, [(n, c) for n, c in chosen if getattr(lib[n], "exact", None) is not None],
                                cols, p_phys, des)  # (R,) the remainder as rows
        p_phys = _split(st.solve(idx, G, st.ht[idx] - _cross(st, des, s, rm, y_rem, idx), rc.ridge) * scale, chosen, len(base))
    return _with_params(result, p_phys)


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
