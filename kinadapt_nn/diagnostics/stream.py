"""Chunked passes over a log: the regression's per-block sufficient statistics without its columns.

A design's columns (``(n, 6, k)`` per effect, ``(R, k)`` as rows) are never held for the whole
log. One pass evaluates every column source on a chunk of samples (``chunk`` samples, widened by
a halo on both sides), filters it with the rows' moving average, maps the chunk's rows through
``RowMap`` and adds each row's contribution to its cross-validation block's normal equations
``G_b = A_b^T A_b``, ``h_b = A_b^T y_b`` (columns unscaled, physical). Least squares, block
cross-validation and the block jackknife need nothing else (``selection.Stats``); the few per-row
series (held-out residual, the residual before/after ``--add``) come from a second pass over only
the columns with a non-zero coefficient (``BlockStats.combine``), whose rows are then kept for the
next such series (``ROW_CACHE_BYTES``).

Chunk-invariance: a sample's columns depend on the samples within ``halo_samples`` of it (the
Savitzky-Golay derivative of the kinematics, the moving average), so every row sees the same
inputs whatever the chunk size; what changes with the chunking is only the order of the sums
(the moving average's running sum and the Gram accumulation), i.e. rounding. Effects must be
sample-local in that sense (built-ins are); the hint shapes that use whole-log numbers (the time
span, the mean joint angle, an extra column's mean) read them from ``LogSignals.whole``.
"""

from __future__ import annotations

import dataclasses
from typing import Callable, NamedTuple

import numpy as np


#: samples per chunk (memory per chunk ~ chunk * 6 * columns * 8 B, plus the effects' own work)
CHUNK_SAMPLES = 20_000
#: [B] a design's rows of the sources its predictions use, kept between passes (``combine_rows``);
#: an hour at 1 kHz, its offset and one 4-parameter effect: 2.2e6 rows x 10 columns x 8 B = 170 MB
ROW_CACHE_BYTES = 256 * 2**20
#: [B] at most this much per chunk's column array (chunk * 6 * columns * 8 B): a design of many
#: columns (the hints' shapes, ~200) runs in shorter chunks (measured: 1.7 GB peak at 20000 samples)
CHUNK_BYTES = 32 * 2**20


def chunk_for(chunk: int | None, k: int) -> int:
    """Samples per chunk of a pass over ``k`` columns: ``chunk`` (default ``CHUNK_SAMPLES``) within
    ``CHUNK_BYTES``, never below 1000."""
    return max(1000, min(int(chunk or CHUNK_SAMPLES), CHUNK_BYTES // (48 * max(int(k), 1))))


class RowMap(NamedTuple):
    """Which samples become regression rows, and how (free space: the six wrench channels weighted
    by 1/noise; contact: the moment about the declared tip). ``apply`` maps any (n, 6, k) sample
    columns to (R, k) rows: effects, the residual and the hint shapes go through the same map.
    Row order: every free-space row's 6 channels (in time order), then every contact row's 3."""

    rows: np.ndarray  #: (r,) sample index of each row time (ascending)
    contact: np.ndarray  #: (r,) bool: contact rows
    k_smooth: int  #: moving-average length [samples]
    w_free: np.ndarray  #: (6,) weights of the free-space channels [1/N, 1/(N m)]
    w_tip: np.ndarray  #: (3,) weights of the tip-moment channels
    tip_map: np.ndarray  #: (3, 6)
    span_every: int = 1  #: the rows lie in every m-th span of ``RowCfg.span_s`` (1: every row time of the log)

    def apply(self, x: np.ndarray) -> np.ndarray:
        return self.rows_of(mean_at(x, self.k_smooth, self.rows), self.contact)

    def rows_of(self, xs: np.ndarray, con: np.ndarray) -> np.ndarray:
        """Filtered sample columns at row times (r, 6, k) -> (free rows * 6 + contact rows * 3, k)."""
        free = xs[~con] * self.w_free[None, :, None]
        tipm = np.einsum("ij,njk->nik", self.tip_map, xs[con]) * self.w_tip[None, :, None]
        return np.concatenate([free.reshape(-1, xs.shape[2]), tipm.reshape(-1, xs.shape[2])], axis=0)

    def channel_sq(self, xs: np.ndarray, con: np.ndarray) -> np.ndarray:
        """Filtered sample columns at row times (r, 6, k) -> (9, k): per channel of the rows (the six
        free-space wrench channels, then the three tip-moment channels), the sum of each column's
        square over the rows of that channel, unweighted (physical units)."""
        tipm = np.einsum("ij,njk->nik", self.tip_map, xs[con])
        return np.concatenate([np.einsum("nck,nck->ck", xs[~con], xs[~con]), np.einsum("nck,nck->ck", tipm, tipm)])

    def phase_rows(self) -> np.ndarray:
        """(9,) the number of rows of each channel (``channel_sq``'s order)."""
        nc = int(self.contact.sum())
        return np.array([len(self.contact) - nc] * 6 + [nc] * 3)

    def positions(self) -> np.ndarray:
        """(r,) the design position of each row's first channel (``apply``'s order)."""
        con = self.contact
        nf = int((~con).sum())
        return np.where(con, 6 * nf + 3 * (np.cumsum(con) - 1), 6 * (np.cumsum(~con) - 1))


class Source(NamedTuple):
    """Columns of a design: ``columns(signals chunk) -> (m, 6, k_all)``, of which ``cols`` are kept;
    ``depth(signals, idx (e,)) -> (e, k_all)``: the same parameters' columns in the extra rows
    (``ExtraRows``; None: zero there)."""

    name: str
    columns: Callable
    cols: list[int]
    depth: Callable | None = None


class ExtraRows(NamedTuple):
    """Rows of a design beside the wrench rows: e measurements of one scalar per row that the
    parameters move (a declared socket's releases: the tip's depth, ``release``), already weighted
    (row value = ``w`` * physical residual). They enter every block's normal equations
    (``block_stats``), not the design's ``y`` (whose rows are the wrench rows)."""

    idx: np.ndarray  #: (e,) the sample of each row
    y: np.ndarray  #: (e,) weighted residual
    w: np.ndarray  #: (e,) weight (1 / sd)
    block: np.ndarray  #: (e,) block of each row


def _add_extra(G: np.ndarray, h: np.ndarray, yy: np.ndarray, s, sources: list, extra: ExtraRows) -> None:
    """The extra rows' share of every block's normal equations (in place)."""
    A = np.concatenate([np.asarray(src.depth(s, extra.idx), dtype=float)[:, src.cols] if src.depth is not None
                        else np.zeros((len(extra.idx), len(src.cols))) for src in sources], axis=1)
    A = A * extra.w[:, None]
    for i, b in enumerate(extra.block):
        G[b] += np.outer(A[i], A[i])
        h[b] += A[i] * extra.y[i]
        yy[b] += float(extra.y[i]) ** 2


class BlockStats(NamedTuple):
    """Per-block normal equations of a design's columns ``[Z, X_e1, ...]`` (unscaled, physical) and
    its rows ``y``; ``combine(P (B, K)) -> (R,)``: each row's columns times its block's coefficients."""

    G: np.ndarray  #: (B, K, K)
    h: np.ndarray  #: (B, K)
    yy: np.ndarray  #: (B,)
    combine: Callable
    col_sq: np.ndarray | None  #: (9, K) per channel of the rows, each column's square summed (``RowMap.channel_sq``; when asked)
    n_samples: int
    chunk: int  #: samples per chunk of the passes
    sources: list  #: the ``Source`` of each column group, in column order
    rows: dict | None = None  #: source index -> its rows (R, k), where kept (``PassOpts.keep``, ``combine``)
    extra: ExtraRows | None = None  #: rows beside the wrench rows, in ``G``, ``h`` and ``yy`` (not in ``combine``)


def mean_at(x: np.ndarray, k: int, idx: np.ndarray, chunk: int | None = None) -> np.ndarray:
    """``moving_average(x, k)[idx]`` (the centred moving average of (n, ...) samples at the sorted
    samples ``idx``; a window ``[i - k // 2, i + k - k // 2)`` clipped to the log): the sums over
    the segments between consecutive window edges in one pass (``np.add.reduceat``), then their
    running sum over the segments only -- never a running sum of every sample. One chunk of
    ``idx`` at a time (memory O(chunk)); equal to rounding (the order of the sums)."""
    x = np.asarray(x)
    n = len(x)
    if k <= 1 or n < 2:
        return np.asarray(x[idx], dtype=float)
    idx = np.asarray(idx)
    out = np.empty((len(idx), *x.shape[1:]))
    step = int(chunk or CHUNK_SAMPLES)
    for a in range(0, len(idx), step):
        i = idx[a:a + step]
        lo, hi = np.clip(i - k // 2, 0, n), np.clip(i + (k - k // 2), 0, n)
        e = np.concatenate([lo, hi])
        e.sort(kind="stable")  # two ascending runs: merged in one pass (np.unique would sort from scratch)
        edges = e[np.r_[True, e[1:] != e[:-1]]]  # (e,) ascending, distinct; the last is hi.max()
        seg = _segment_sums(np.asarray(x[edges[0]:edges[-1]], dtype=float), edges - edges[0])
        P = np.concatenate([np.zeros((1, *x.shape[1:])), np.cumsum(seg, axis=0)])  # (e, ...) sums up to each edge
        out[a:a + step] = (P[np.searchsorted(edges, hi)] - P[np.searchsorted(edges, lo)]) / \
            (hi - lo).reshape((-1,) + (1,) * (x.ndim - 1))
    return out


def span_index(t_rel_s: np.ndarray, span_s: float) -> np.ndarray:
    """(r,) the span of ``span_s`` [s] each row time ``t_rel_s`` (r,) [s from the log's start] lies in."""
    return np.floor(np.asarray(t_rel_s) / span_s).astype(np.int64)


def every_mth_span(t_rel_s: np.ndarray, max_rows: int, span_s: float) -> tuple[np.ndarray | None, int]:
    """Rows at the times ``t_rel_s`` (r,) [s from the log's start], at most about ``max_rows`` of them:
    None and m = 1 when r <= ``max_rows``, else (the (r,) bool mask of the rows in every m-th span of
    ``span_s``, m = ceil(r / max_rows)). Chosen by time, so the same whatever the chunking (the
    ranking's rows of a long log, ``userlog.row_map``; the hint test's, ``completeness.hint_rows``)."""
    r = len(t_rel_s)
    if r <= max_rows:
        return None, 1
    m = -(-r // max_rows)
    return span_index(t_rel_s, span_s) % m == 0, m


def _segment_sums(x: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """(e - 1, ...) the sums of ``x`` over ``[edges[j], edges[j + 1])`` (``edges`` ascending from 0 to
    ``len(x)``): equal segments (rows at a constant stride) by a reshape, others by ``reduceat``
    (measured on (4000, 6, 219) columns: 1 us against 12 us a sample)."""
    d = np.diff(edges)
    if len(d) and np.all(d == d[0]):
        return x.reshape(len(d), int(d[0]), *x.shape[1:]).sum(axis=1)
    return np.add.reduceat(x, edges[:-1], axis=0)


def smooth(x: np.ndarray, k: int, chunk: int | None = None) -> np.ndarray:
    """``moving_average(x, k)`` of (n, ...) samples in chunks (``mean_at`` at every sample)."""
    return mean_at(x, k, np.arange(len(x)), chunk)


def halo_samples(s, k_smooth: int) -> int:
    """Samples on each side of a chunk that its rows' columns depend on (module docstring)."""
    from kinadapt_nn.diagnostics.physical import ACC_WINDOW_S

    if s.static:
        return 0
    dt = float(np.median(np.diff(s.t[: min(s.n, 10_001)])))
    return int(k_smooth) + 2 * (int(round(ACC_WINDOW_S / dt)) | 1) + 8


def whole(s) -> dict:
    """The whole-log numbers a chunk's shapes need (``LogSignals.whole``)."""
    return {"t_span": (float(np.min(s.t)), float(np.max(s.t))), "q_mean": s.q.mean(axis=0),
            "extra_mean": {k: float(np.mean(v)) for k, v in s.extra.items()}}


def slice_signals(s, a: int, b: int, w: dict | None = None):
    """``LogSignals`` of samples ``a:b`` (every per-sample array sliced; ``whole`` = ``w``)."""
    out = {}
    for f in dataclasses.fields(s):
        v = getattr(s, f.name)
        if f.name == "extra":
            out[f.name] = {k: x[a:b] for k, x in v.items()}
        elif f.name != "tip_map" and isinstance(v, np.ndarray) and v.ndim >= 1 and len(v) == s.n:
            out[f.name] = v[a:b].astype(float) if v.dtype == np.float32 else v[a:b]  # compact storage: double here
    if hasattr(s, "_qddot") and not s.static:  # each chunk its own, made when first read (``LogSignals.qddot``)
        out["_qddot"] = None
    return dataclasses.replace(s, **out, whole=w if w is not None else getattr(s, "whole", None))


def chunks(n: int, chunk: int) -> list[tuple[int, int]]:
    chunk = max(1, int(chunk))
    return [(a, min(a + chunk, n)) for a in range(0, n, chunk)]


def bounds(s, chunk: int, halo: int) -> list[tuple[int, int]]:
    """``chunks`` of ``LogSignals`` s, each interior boundary moved forward to the first sample
    with no declared-socket engagement within ``halo`` samples of it (module docstring); a
    boundary with none after it is dropped."""
    out = chunks(s.n, chunk)
    if len(out) == 1 or s.setup.contact.geometry == "none":
        return out
    from kinadapt_nn.effects.contact_model import socket_terms

    gate = socket_terms(s.setup.contact, s.R_ws, s.p_ws, s.setup.tool.tip_sensor_m).gate
    busy = np.convolve(gate.astype(float), np.ones(2 * halo + 1), "same") > 0  # engaged within the halo
    ok = np.flatnonzero(~busy)
    cuts = sorted({int(ok[i]) for a, _ in out[1:] if (i := np.searchsorted(ok, a)) < len(ok)})
    edges = [0, *[c for c in cuts if 0 < c < s.n], s.n]
    return [(a, b) for a, b in zip(edges[:-1], edges[1:]) if b > a]


def _chunk_rows(s, rm: RowMap, sources: list[Source], a: int, b: int, halo: int, w: dict
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rows of samples ``a:b``: (design positions (q,), row values (q, K), the columns' squares
    per channel of these rows (9, K): ``RowMap.channel_sq``). Only the samples within ``halo`` of
    the chunk's rows are evaluated (none when it has no row: a ``RowMap`` of spans)."""
    i0, i1 = np.searchsorted(rm.rows, [a, b])
    rows = rm.rows[i0:i1]
    K = sum(len(src.cols) for src in sources)
    if not len(rows):
        return np.zeros(0, np.int64), np.zeros((0, K)), np.zeros((9, K))
    # runs of rows: a gap wider than two halos (the spans of a long log) is not evaluated
    cut = np.flatnonzero(np.diff(rows) > 2 * halo + 1) + 1
    parts = []
    for run in np.split(rows, cut):
        lo, hi = max(0, a - halo, int(run[0]) - halo), min(s.n, b + halo, int(run[-1]) + 1 + halo)
        sub = slice_signals(s, lo, hi, w)
        C = np.concatenate([np.asarray(src.columns(sub), dtype=float)[:, :, src.cols] for src in sources], axis=2)
        parts.append(mean_at(C, rm.k_smooth, run - lo))
        del C, sub
    xs = parts[0] if len(parts) == 1 else np.concatenate(parts, axis=0)
    con = rm.contact[i0:i1]
    vals = rm.rows_of(xs, con)
    start = rm.positions()[i0:i1]
    pos = np.concatenate([(start[~con][:, None] + np.arange(6)).reshape(-1),
                          (start[con][:, None] + np.arange(3)).reshape(-1)])
    return pos, vals, rm.channel_sq(xs, con)


class PassOpts(NamedTuple):
    """What a ``block_stats`` pass keeps besides the normal equations, and what it adds to them."""

    squares: bool = False  #: ``BlockStats.col_sq`` (else None)
    #: the rows of the sources with the most columns, for ``combine`` (within ``ROW_CACHE_BYTES``): an
    #: effect's later predictions then need no pass (``encoder_offset``'s kinematics, say)
    keep: bool = False
    extra: ExtraRows | None = None  #: rows beside the wrench rows, added to the normal equations


def _channels(rm: RowMap, pos: np.ndarray, vals: np.ndarray) -> np.ndarray:
    """(q,) the channel (0-8) of each of a chunk's rows (``_chunk_rows``' order: free rows' six
    channels, then contact rows' three tip moments)."""
    nf = int(np.count_nonzero(pos < 6 * int((~rm.contact).sum())))
    return np.concatenate([np.tile(np.arange(6), nf // 6), np.tile(np.arange(6, 9), (len(pos) - nf) // 3)])


def _accumulate(G: np.ndarray, h: np.ndarray, A: np.ndarray, y: np.ndarray, key: np.ndarray) -> None:
    """``G_b += A_b^T A_b``, ``h_b += A_b^T y_b`` per block b = ``key // 9``, one channel
    (``key % 9``) at a time on the columns not zero in it: a column that lives in one channel (most
    hint shapes: one channel's row of ``_per_channel``) costs nothing in the others."""
    for kk in np.unique(key):
        m = key == kk
        Ab = A[m]
        nz = np.flatnonzero(np.any(Ab, axis=0))
        bb = int(kk) // 9
        if len(nz) == A.shape[1]:
            G[bb] += Ab.T @ Ab
            h[bb] += Ab.T @ y[m]
        elif len(nz):
            Az = Ab[:, nz]
            G[bb][np.ix_(nz, nz)] += Az.T @ Az
            h[bb][nz] += Az.T @ y[m]


def block_stats(s, rm: RowMap, sources: list[Source], y: np.ndarray, block: np.ndarray, n_blocks: int,
                chunk: int | None = None, opts: "PassOpts" = None) -> BlockStats:
    """One chunked pass: the per-block normal equations of ``sources``' columns (module docstring).
    ``y`` (R,), ``block`` (R,) the design's rows and their blocks; ``chunk`` samples per chunk
    (default ``CHUNK_SAMPLES``); ``opts``: what else the pass keeps and the rows beside the wrench rows
    (``PassOpts``)."""
    squares, keep, extra = opts or PassOpts()
    K = sum(len(src.cols) for src in sources)
    chunk = chunk_for(chunk, K)
    G, h = np.zeros((n_blocks, K, K)), np.zeros((n_blocks, K))
    yy = np.bincount(block, weights=y * y, minlength=n_blocks).astype(float)
    col_sq = np.zeros((9, K)) if squares else None
    offs = np.cumsum([0] + [len(src.cols) for src in sources])
    cache: dict = {}
    for i in sorted(range(len(sources)), key=lambda i: -len(sources[i].cols)) if keep else []:
        if sum(v.nbytes for v in cache.values()) + 8 * len(y) * len(sources[i].cols) <= ROW_CACHE_BYTES:
            cache[i] = np.zeros((len(y), len(sources[i].cols)))
    halo, w = halo_samples(s, rm.k_smooth), whole(s)
    for a, b in bounds(s, chunk, halo):
        pos, vals, sq = _chunk_rows(s, rm, sources, a, b, halo, w)
        if squares:
            col_sq += sq
        _accumulate(G, h, vals, y[pos], block[pos] * 9 + _channels(rm, pos, vals))
        for i, rows in cache.items():
            rows[pos] = vals[:, offs[i]:offs[i + 1]]

    if extra is not None:
        _add_extra(G, h, yy, s, sources, extra)

    def combine(P: np.ndarray) -> np.ndarray:
        return combine_rows(s, rm, sources, P, block, len(y), chunk, cache)

    return BlockStats(G, h, yy, combine, col_sq, s.n, chunk, list(sources), cache, extra)


def combine_rows(s, rm: RowMap, sources: list[Source], P: np.ndarray, block: np.ndarray, R: int,
                 chunk: int | None = None, cache: dict | None = None) -> np.ndarray:
    """(R,) each row's columns times its block's coefficients ``P`` (B, K); a pass over the log that
    evaluates only the sources with a non-zero coefficient. ``cache`` (a design's): each source's
    rows (R, k) kept after its first pass, while they fit ``ROW_CACHE_BYTES``
    (the held-out residual, the residual before and after ``--add`` and the tip check then take
    one pass between them)."""
    out = np.zeros(R)
    offs = np.cumsum([0] + [len(src.cols) for src in sources])
    used = [i for i in range(len(sources)) if np.any(P[:, offs[i]:offs[i + 1]])]
    if not used:
        return out
    if cache is not None:
        new = [i for i in used if i not in cache]
        k_new = int(sum(offs[i + 1] - offs[i] for i in new))
        if new and sum(v.nbytes for v in cache.values()) + 8 * R * k_new <= ROW_CACHE_BYTES:
            vals = np.zeros((R, k_new))
            halo, w = halo_samples(s, rm.k_smooth), whole(s)
            for a, b in bounds(s, chunk_for(chunk, vals.shape[1]), halo):
                pos, v, _ = _chunk_rows(s, rm, [sources[i] for i in new], a, b, halo, w)
                vals[pos] = v
            k0 = 0
            for i in new:
                k = int(offs[i + 1] - offs[i])
                cache[i] = vals[:, k0:k0 + k]
                k0 += k
        if all(i in cache for i in used):
            step = int(chunk or CHUNK_SAMPLES) * 6  # rows at a time: no (R, k) copy of the coefficients
            for i in used:
                Pi = P[:, offs[i]:offs[i + 1]]
                for a in range(0, R, step):
                    out[a:a + step] += np.einsum("rk,rk->r", cache[i][a:a + step], Pi[block[a:a + step]])
            return out
    keep = np.concatenate([np.arange(offs[i], offs[i + 1]) for i in used])
    Pk = P[:, keep]
    halo, w = halo_samples(s, rm.k_smooth), whole(s)
    for a, b in bounds(s, chunk_for(chunk, len(keep)), halo):
        pos, vals, _ = _chunk_rows(s, rm, [sources[i] for i in used], a, b, halo, w)
        out[pos] = np.einsum("rk,rk->r", vals, Pk[block[pos]])
    return out


def row_values(s, rm: RowMap, source: Source, chunk: int | None = None) -> np.ndarray:
    """(R, k) the rows of one column source (``RowMap.apply`` of its columns) from a chunked pass."""
    nf = int((~rm.contact).sum())
    out = np.zeros((6 * nf + 3 * (len(rm.rows) - nf), len(source.cols)))
    halo, w = halo_samples(s, rm.k_smooth), whole(s)
    for a, b in bounds(s, chunk_for(chunk, len(source.cols)), halo):
        pos, vals, _ = _chunk_rows(s, rm, [source], a, b, halo, w)
        out[pos] = vals
    return out


def sample_sum(s, sources: list[Source], coefs: list[np.ndarray], k_smooth: int = 1,
               chunk: int | None = None, channels: int = 6) -> np.ndarray:
    """(n, channels) the sum over ``sources`` of their kept columns times ``coefs`` (each (k,)), per
    sample, unfiltered (a chunked pass); ``channels`` = 3: the force only."""
    out = np.zeros((s.n, channels))
    if not sources:
        return out
    halo, w = halo_samples(s, k_smooth), whole(s)
    for a, b in bounds(s, chunk_for(chunk, max(len(src.cols) for src in sources)), halo):
        lo, hi = max(0, a - halo), min(s.n, b + halo)
        sub = slice_signals(s, lo, hi, w)
        for src, c in zip(sources, coefs):
            out[a:b] += np.asarray(src.columns(sub), dtype=float)[a - lo:b - lo][:, :channels][:, :, src.cols] @ c
    return out


__all__ = ["BlockStats", "every_mth_span", "span_index", "CHUNK_BYTES", "CHUNK_SAMPLES", "PassOpts", "ROW_CACHE_BYTES", "RowMap", "Source", "block_stats", "bounds",
           "chunk_for", "chunks", "combine_rows",
           "halo_samples", "mean_at", "row_values", "sample_sum", "slice_signals", "smooth", "whole"]
