"""Figures a paper can use (matplotlib, Agg backend; nothing needs a display).

Conventions every figure here (and ``kinadapt diagnose``'s) follows: each panel has labelled ticks
and a legend or title that names every colour and shading; y-limits come from the 0.5-99.5 %
percentiles of the plotted data (``robust_limits``), so a few spikes do not flatten the bulk --
samples beyond the axis are marked by red triangles at its edge (``set_robust_ylim``); panels and
reference lines that do not apply to the run (e.g. the seat-depth target of the ``excite``
program) are not drawn. A series is drawn at most at the pixel width of its panel (``decimate``,
``envelope``: each pixel column's minimum and maximum, so spikes stay); one that chatters faster
than that is drawn as its range with a sliding mean through it (``band_and_mean``), and a boolean
channel as the fraction of a sliding window it is true (``fraction_lanes``), never as a barcode."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.ticker import (  # noqa: E402
    FuncFormatter,
    LogFormatterSciNotation,
    LogLocator,
    MaxNLocator,
    NullFormatter,
)

from kinadapt_nn.config import ExperimentCfg  # noqa: E402
from kinadapt_nn.trace import Trace  # noqa: E402

#: percentiles the y-limits are taken from
ROBUST_PCT = (0.5, 99.5)
#: most points one drawn line keeps (min and max of each bucket: spikes survive; the trace keeps all)
MAX_LINE_POINTS = 2000


def decimate(x: np.ndarray, y: np.ndarray, max_points: int = MAX_LINE_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """(x, y) thinned to at most ~``max_points`` for drawing: the first and last sample, each
    bucket's minimum and maximum (so a one-sample spike is still drawn), and every non-finite
    sample (so gaps stay gaps). Unchanged when already short enough."""
    x, y = np.asarray(x), np.asarray(y)
    n = len(y)
    if n <= max_points or y.ndim != 1:
        return x, y
    nb = max(1, max_points // 2 - 1)
    k = -(-n // nb)  # bucket length
    yf = y.astype(float)
    fin = np.isfinite(yf)
    lo = np.pad(np.where(fin, yf, np.inf), (0, nb * k - n), constant_values=np.inf).reshape(nb, k)
    hi = np.pad(np.where(fin, yf, -np.inf), (0, nb * k - n), constant_values=-np.inf).reshape(nb, k)
    start = np.arange(nb) * k
    idx = np.concatenate([start + lo.argmin(axis=1), start + hi.argmax(axis=1), np.flatnonzero(~fin), [0, n - 1]])
    idx = np.unique(idx[idx < n])
    return x[idx], y[idx]


def robust_limits(ys: Sequence[np.ndarray], pct: tuple[float, float] = ROBUST_PCT, margin: float = 0.08,
                  include: Sequence[float] = (), headroom: float = 0.0) -> tuple[float, float] | None:
    """y-limits from the ``pct`` percentiles of every finite value in ``ys`` (plus ``include``).

    A side keeps the full data range where the excursions past the percentile are modest (within
    half the percentile span): only real spikes are cut. ``headroom``: extra room above, as a
    fraction of the range (for a legend over dense data). None when there is no finite value."""
    parts = [np.ravel(np.asarray(y, dtype=float)) for y in ys]
    v = np.concatenate(parts) if parts else np.zeros(0)
    v = v[np.isfinite(v)]
    if not v.size:
        return None
    a, b = (float(x) for x in np.percentile(v, pct))
    span = b - a
    lo = float(v.min()) if v.min() >= a - 0.5 * span else a
    hi = float(v.max()) if v.max() <= b + 0.5 * span else b
    for x in include:
        if np.isfinite(x):
            lo, hi = min(lo, float(x)), max(hi, float(x))
    if hi - lo <= 1e-12 * max(abs(lo), abs(hi), 1e-300):
        half = 0.1 * abs(hi) if hi != 0 else 1.0
        return lo - half, hi + half
    pad = margin * (hi - lo)
    return lo - pad, hi + pad + headroom * (hi - lo)


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) of each run of True in ``mask``."""
    d = np.diff(np.r_[0, mask.astype(np.int8), 0])
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)))


def set_robust_ylim(ax, x: np.ndarray, ys: Sequence[np.ndarray], pct: tuple[float, float] = ROBUST_PCT,
                    include: Sequence[float] = (), unit: str = "", headroom: float = 0.0) -> tuple[float, float] | None:
    """Set ``ax``'s y-limits with ``robust_limits`` and mark what falls outside: one red triangle
    per excursion at the axis edge (up: above, down: below), labelled for the legend with the
    count and the most extreme value. Returns the limits (None: left to matplotlib)."""
    lim = robust_limits(ys, pct, include=include, headroom=headroom)
    if lim is None:
        return None
    ax.set_ylim(*lim)
    x = np.asarray(x, dtype=float)
    marks = {"^": [], "v": []}
    peak = 0.0
    for y in ys:
        y = np.asarray(y, dtype=float)
        if y.ndim != 1 or len(y) != len(x):
            continue
        for mask, key in ((y > lim[1], "^"), (y < lim[0], "v")):
            for i0, i1 in _runs(mask):
                k = i0 + int(np.argmax(np.abs(y[i0:i1])))
                marks[key].append(x[k])
                peak = y[k] if abs(y[k]) > abs(peak) else peak
    n = len(marks["^"]) + len(marks["v"])
    label = f"clipped: {n} spike{'s' * (n != 1)}, extreme {peak:.3g}{' ' + unit if unit else ''}"
    for key, yy in (("^", 0.985), ("v", 0.015)):
        if marks[key]:
            ax.plot(marks[key], np.full(len(marks[key]), yy), ls="none", marker=key, ms=5, color="red",
                    transform=ax.get_xaxis_transform(), clip_on=False, zorder=6, label=label)
            label = "_nolegend_"
    return lim


class LabelledLogLocator(LogLocator):
    """Major ticks of a log axis, at least ``n`` of them inside the view: the decades (every k-th on
    a wide axis) when enough lie inside, else, in each decade, the sparsest of 1-2-5, 1-1.5-2-3-5-7
    and 1-1.2-1.5-2-2.5-3-4-5-6-8 that gives ``n``, else evenly spaced values (an axis narrower
    than about a factor of two)."""

    SUBS = ((1.0, 2.0, 5.0), (1.0, 1.5, 2.0, 3.0, 5.0, 7.0), (1.0, 1.2, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 8.0))

    def __init__(self, n: int = 3) -> None:
        super().__init__(base=10.0)
        self.n = n

    def tick_values(self, vmin: float, vmax: float) -> np.ndarray:
        lo, hi = sorted((vmin, vmax))
        ticks = super().tick_values(lo, hi)  # the decades
        if lo <= 0 or ((ticks >= lo) & (ticks <= hi)).sum() >= self.n:
            return ticks
        decades = 10.0 ** np.arange(np.floor(np.log10(lo)), np.ceil(np.log10(hi)) + 1)
        for subs in self.SUBS:
            ticks = np.outer(decades, subs).ravel()
            if ((ticks >= lo) & (ticks <= hi)).sum() >= self.n:
                return ticks
        return MaxNLocator(nbins=self.n + 1, steps=[1, 2, 2.5, 5, 10], min_n_ticks=self.n).tick_values(lo, hi)


def labelled_ticks(axis, n: int = 3) -> None:
    """At least ``n`` labelled major ticks on ``axis`` (``ax.xaxis`` or ``ax.yaxis``), log or linear;
    call after the scale is set. A log axis spanning under a few decades otherwise labels one
    decade or none."""
    if axis.get_scale() == "log":
        axis.set_major_locator(LabelledLogLocator(n))
        axis.set_major_formatter(LogFormatterSciNotation(labelOnlyBase=False, minor_thresholds=(np.inf, np.inf)))
        axis.set_minor_formatter(NullFormatter())  # the labels are on the major ticks
    else:
        axis.set_major_locator(MaxNLocator(nbins="auto", steps=[1, 2, 2.5, 5, 10], min_n_ticks=n))


class Envelope(NamedTuple):
    """A series reduced to one (min, max) pair per pixel column (``envelope``)."""

    x: np.ndarray  # (C,) middle of each column's samples [x units]
    lo: np.ndarray  # (C,) smallest finite sample of the column (NaN: none)
    hi: np.ndarray  # (C,) largest finite sample of the column (NaN: none)


def envelope(x: np.ndarray, y: np.ndarray, columns: int) -> Envelope:
    """(x, y) reduced to at most ``columns`` equal-width columns of x (x non-decreasing): each
    column's minimum and maximum, so a band drawn between them keeps every spike and a series
    that chatters faster than a pixel shows as its range, not as a zigzag. Columns without a
    sample are left out; a column whose samples are all NaN gives NaN (a gap)."""
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    if not len(x):
        return Envelope(x, y, y)
    span = x[-1] - x[0]
    col = (np.minimum((x - x[0]) * (columns / span), columns - 1).astype(int) if span > 0
           else np.zeros(len(x), int))
    start = np.flatnonzero(np.r_[True, col[1:] != col[:-1]])
    stop = np.r_[start[1:], len(x)]
    with np.errstate(invalid="ignore"):  # (an all-NaN column)
        lo, hi = np.fmin.reduceat(y, start), np.fmax.reduceat(y, start)
    return Envelope(0.5 * (x[start] + x[stop - 1]), lo, hi)


def sliding_mean(y: np.ndarray, n: int) -> np.ndarray:
    """The mean of ``y`` over a centred window of ``n`` samples (shortened at the ends; NaN samples
    left out, NaN where the window has none). Of a boolean channel: the fraction of the window it
    is true. (N,) -> (N,)."""
    y = np.asarray(y, dtype=float)
    if n <= 1 or not len(y):
        return y.copy()
    fin = np.isfinite(y)
    total = np.r_[0.0, np.cumsum(np.where(fin, y, 0.0))]
    count = np.r_[0, np.cumsum(fin)]
    i = np.arange(len(y))
    lo, hi = np.clip(i - n // 2, 0, len(y)), np.clip(i - n // 2 + n, 0, len(y))
    k = count[hi] - count[lo]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(k > 0, (total[hi] - total[lo]) / k, np.nan)


def pixel_columns(a) -> int:
    """The width of axes ``a`` in pixels of the saved PNG (``SAVE_DPI``): the most columns a
    series drawn there can show."""
    return max(1, int(np.ceil(a.get_position().width * a.get_figure().get_figwidth() * SAVE_DPI)))


def band_and_mean(a, t: np.ndarray, y: np.ndarray, window: int, color: str, label: str) -> None:
    """A dense, maybe chattering series: its range per pixel column as a faint band (spikes kept)
    and its ``window``-sample sliding mean as the line (labelled)."""
    cols = pixel_columns(a)
    env = envelope(t, y, cols)
    a.fill_between(env.x, env.lo, env.hi, color=color, alpha=0.25, lw=0)
    a.plot(*decimate(t, sliding_mean(y, window), 2 * cols), color=color, lw=0.9, label=label)


def fraction_lanes(a, t: np.ndarray, lanes: Sequence[tuple[str, np.ndarray]], window: int) -> None:
    """Boolean channels stacked as lanes, each drawn as the fraction of a sliding ``window``
    (samples) it is true, from 0 (never) to 1 (throughout): readable however fast a channel
    switches, where spans of it would be a barcode. Each lane has labelled 0 % / 100 % ticks."""
    ticks, labels = [], []
    cols = pixel_columns(a)
    for off, (name, v) in enumerate(lanes):
        base = 1.5 * off
        tt, ff = decimate(t, sliding_mean(np.asarray(v, dtype=float), window), 2 * cols)
        a.fill_between(tt, base, base + ff, color=f"C{off}", alpha=0.3, lw=0)
        a.plot(tt, base + ff, color=f"C{off}", lw=1.0)
        ticks += [base, base + 1]
        labels += [f"{name}: 0 %", "100 %"]
    a.set_yticks(ticks, labels, fontsize=7)
    a.set_ylim(-0.3, 1.5 * (len(lanes) - 1) + 1.3)


def reference_line(ax, value: float, lim: tuple[float, float] | None, label: str, color: str = "r",
                   ls: str = ":") -> None:
    """A horizontal limit/target line when it lies on the axis; otherwise only a legend entry
    saying where it is (so a far-away limit does not flatten the data)."""
    if lim is not None and lim[0] <= value <= lim[1]:
        ax.axhline(value, color=color, lw=0.9, ls=ls, label=label)
    else:
        where = "above" if lim is not None and value > lim[1] else "below"
        ax.plot([], [], color=color, lw=0.9, ls=ls, label=f"{label} ({where} the axis)")


def plain_log_ticks(a) -> None:
    """Plain-text tick labels on a log y axis ('1e-06', '100'): matplotlib's default writes each
    as mathtext, which costs a parse per label."""
    from matplotlib.ticker import LogFormatter

    a.yaxis.set_major_formatter(LogFormatter())
    a.yaxis.set_minor_formatter(LogFormatter(labelOnlyBase=False, minor_thresholds=(1, 0.4)))


#: window of the rollout figure's sliding means and contact fractions [s]
WINDOW_S = 0.05
#: legend title of the panels drawn by ``band_and_mean``
BAND_NOTE = f"lines: {1e3 * WINDOW_S:.0f} ms means, bands: range"
#: size of the rollout figure [in] (width, height)
ROLLOUT_SIZE_IN = (14.0, 10.0)


@dataclass(frozen=True)
class _Rollout:
    """What the rollout figure's panels read: the run and what is derived from it once."""

    trace: Trace
    summary: dict
    cfg: ExperimentCfg
    insert: bool  # the insert program: the seat criteria (depth target, limits) apply
    held: bool  # theta held fixed (oracle features or a frozen model)
    offset_row: bool  # theta is the tool offset and adapts: the bottom row identifies it
    gate: np.ndarray  # (N,) bool, sensed contact (the law adapts)
    window: int  # samples in WINDOW_S

    @property
    def t(self) -> np.ndarray:
        return self.trace["t_s"]

    @property
    def true_offset(self) -> np.ndarray:
        return np.asarray(self.trace.meta.get("truth_offset_f_m", [np.nan] * 3))


def _rollout(trace: Trace, summary: dict, cfg: ExperimentCfg) -> _Rollout:
    t = trace["t_s"]
    held = cfg.run.features == "oracle" or cfg.adaptation.mode == "frozen"
    dt_s = float(np.median(np.diff(t))) if len(t) > 1 else 1.0
    return _Rollout(trace=trace, summary=summary, cfg=cfg, insert=cfg.control.program != "excite", held=held,
                    offset_row=trace["theta"].shape[1] == 3 and not held, gate=trace["adapt_gate"] > 0,
                    window=max(1, round(WINDOW_S / dt_s)))


def rollout_figure(trace: Trace, summary: dict, cfg: ExperimentCfg) -> plt.Figure:
    """Nine panels: depth (sensor vs truth), lateral force, moment, axial force, the success
    channels with sensed contact (insert program; the contact channels for ``excite``) as
    fractions of a 50 ms window, lambda_min of the estimated Jacobian, and the identification
    row (offset estimate vs truth) -- or, where theta is held fixed or is not an offset, the
    W-scaled prediction error. Time axis in seconds. Dense series are drawn at the PNG's pixel
    width: forces, moments and errors as a 50 ms mean over their range (``band_and_mean``)."""
    r = _rollout(trace, summary, cfg)
    title, footer = _rollout_texts(r)
    fig, ax = _rollout_axes(r.held, title_lines=title.count("\n") + 1, footer_lines=footer.count("\n") + 1)
    _depth_panel(ax[0, 0], r)
    _lateral_panel(ax[0, 1], r)
    _moment_panel(ax[0, 2], r)
    _axial_panel(ax[1, 0], r)
    _channels_panel(ax[1, 1], r)
    _margin_panel(ax[1, 2], r)
    (_offset_row if r.offset_row else _prediction_row)(ax[2], r)
    fig.suptitle(title)
    fig.text(0.01, 0.004, footer, fontsize=8, va="bottom", ha="left", color="0.25")
    return fig


def _rollout_texts(r: _Rollout) -> tuple[str, str]:
    """The suptitle and the footer (sensed contact's share; the contact's share and switching rate
    as summary.json records them; what was and was not identified, and why, in plain words: the
    summary's line)."""
    import textwrap

    s = r.summary
    done = "COMPLETED" if s.get("program") == "excite" else "SEATED"
    status = done if s["success"] else f"FAILED ({s['failure']})"
    title = (f"kinadapt online - program={r.cfg.control.program}, features={s['features']}, law={s['law']}, "
             f"seed={s['seed']}: {status}")
    theta = r.trace["theta"]
    if r.held and theta.shape[1] == 3 and len(theta):
        title += (f"\ntheta held fixed at ({', '.join(f'{1e3 * v:.1f}' for v in theta[-1])}) mm, "
                  f"true offset ({', '.join(f'{1e3 * v:.1f}' for v in r.true_offset)}) mm")
    g = r.gate
    share = 100 * g.mean() if len(g) else 0.0
    what = "sensed contact" if r.held else "sensed contact (the law adapts)"
    lines = ["; ".join(w for w in (f"{what}: {share:.0f} % of the run", _contact_words(s)) if w)]
    ident = (s.get("identification") or {}).get("text")
    if ident:
        lines += textwrap.wrap("identification: " + ident, 190)
    return title, "\n".join(lines)


def _contact_words(summary: dict) -> str:
    """How the peg touched, as summary.json says it (``runs.evaluate.contact_quality``: the
    simulator's contact from the first touch on) -- the footer's numbers are the record's."""
    if "contact_transitions_per_s" not in summary:  # a summary from before the field
        return ""
    rate = summary["contact_transitions_per_s"]
    if rate is None:
        return "no contact (simulator truth)"
    return (f"contact (simulator truth, from the first touch): {100 * summary['contact_fraction']:.0f} % of the "
            f"time, {rate:.3g} on/off switches per s, longest {summary['longest_contact_span_s']:.2f} s")


def _rollout_axes(held: bool, title_lines: int, footer_lines: int) -> tuple[plt.Figure, np.ndarray]:
    """The 3x3 grid with fixed margins, x shared by the time panels (all but a held run's bar
    chart) and labelled only where no time panel is below: text is most of the figure's cost,
    so the time tick labels are drawn once per column, not three times."""
    fig, ax = plt.subplots(3, 3, figsize=ROLLOUT_SIZE_IN)
    time_axes = [a for a in ax.ravel() if a is not ax[2, 2] or not held]
    for i, j in np.ndindex(ax.shape):
        a = ax[i, j]
        if a not in time_axes:
            continue
        if a is not ax[0, 0]:
            a.sharex(ax[0, 0])
        if i < 2 and ax[i + 1, j] in time_axes:
            a.tick_params(labelbottom=False)
        else:
            a.set_xlabel("time [s]")
    _fixed_margins(fig, title_lines, footer_lines, hgap=0.95 if held else 0.55)
    return fig, ax


def _depth_panel(a, r: _Rollout) -> None:
    t, sc, cols = r.t, r.cfg.success, 2 * pixel_columns(a)
    a.plot(*decimate(t, 1e3 * r.trace["s"][:, 0], cols), label="sensor depth d (encoders)")
    a.plot(*decimate(t, 1e3 * r.trace["truth_tip_depth_m"], cols), "--", label="true tip depth (truth)")
    if r.insert:
        a.axhline(1e3 * sc.depth_m, color="k", lw=0.8, ls=":",
                  label=f"target {1e3 * sc.depth_m:.0f} mm (seated: d >= {1e3 * (sc.depth_m - sc.depth_tol_m):.1f})")
    a.set_ylabel("depth below the entrance [mm]")
    a.legend(fontsize=8)
    a.set_title("insertion depth" if r.insert else "tip depth (excite program: no seat target)")


def _dense_panel(a, r: _Rollout, series: Sequence[tuple[str, np.ndarray, str]], unit: str,
                 limit: tuple[float, str] | None = None, headroom: float = 0.45, ncol: int = 2) -> None:
    """``band_and_mean`` of each (label, (N,) values, colour), robust y-limits over the samples,
    ``limit`` (value, label) as a reference line, and a legend of ``ncol`` columns."""
    for label, y, color in series:
        band_and_mean(a, r.t, y, r.window, color, label)
    lim = set_robust_ylim(a, r.t, [y for _, y, _ in series], unit=unit, headroom=headroom)
    if limit is not None:
        reference_line(a, limit[0], lim, limit[1])
    a.legend(fontsize=7, loc="upper left", ncol=ncol, title=BAND_NOTE, title_fontsize=7)


def _lateral_panel(a, r: _Rollout) -> None:
    s, sc = r.trace["s"], r.cfg.success
    limit = (sc.max_lateral_force_N, f"seat limit |F_lat| < {sc.max_lateral_force_N:g} N") if r.insert else None
    _dense_panel(a, r, [("F_lat x", s[:, 1], "C0"), ("F_lat y", s[:, 2], "C1"),
                        ("|F_lat|", np.hypot(s[:, 1], s[:, 2]), "k")], "N", limit)
    a.set_ylabel("force [N]")
    a.set_title("lateral contact force")


def _moment_panel(a, r: _Rollout) -> None:
    s, sc = r.trace["s"], r.cfg.success
    limit = (sc.max_moment_Nm, f"seat limit |M| < {sc.max_moment_Nm:g} N m") if r.insert else None
    _dense_panel(a, r, [*((f"M {n}", s[:, 3 + i], f"C{i}") for i, n in enumerate("xyz")),
                        ("|M|", np.linalg.norm(s[:, 3:], axis=1), "k")], "N m", limit)
    a.set_ylabel("moment about O [N m]")
    a.set_title("wrist moment")


def _axial_panel(a, r: _Rollout) -> None:
    _dense_panel(a, r, [("total normal contact (truth)", r.trace["truth_contact_force_N"], "C1"),
                        ("axial force on tool (sensor)", -r.trace["w_env_w"][:, 2], "C0")], "N", headroom=0.6,
                ncol=1)
    a.set_ylabel("force [N]")
    a.set_title("axial / contact force")


def _channels_panel(a, r: _Rollout) -> None:
    """Insert: sensed contact and the success channels; excite: sensed contact against the truth's
    contacts. Each as the fraction of a 50 ms window it is true (``fraction_lanes``)."""
    tr, s = r.trace, r.summary
    how = f"fraction true per {1e3 * WINDOW_S:.0f} ms"
    if r.insert:
        fraction_lanes(a, r.t, [("sensed contact", r.gate), *((n, tr[n]) for n in ("depth_ok", "force_ok", "moment_ok"))],
                       r.window)
        title = f"success channels (sensor side), {how}"
        if s.get("seat_time_s") is not None:
            a.axvline(s["seat_time_s"], color="k", ls="--", lw=1.0)
            title += f"\ndashed: seated at {s['seat_time_s']:.2f} s (all ok for {r.cfg.success.hold_s:g} s)"
    else:
        fraction_lanes(a, r.t, [("sensed contact", r.gate), ("truth: bore/socket", tr["truth_contact_bore"]),
                                ("truth: block face", tr["truth_contact_face"])], r.window)
        title = f"contact (sensor gate vs truth),\n{how}"
    a.set_title(title, fontsize=10)


def _margin_panel(a, r: _Rollout) -> None:
    act = r.trace["drive_scale"] > 0
    a.semilogy(*decimate(r.t[act], r.trace["lambda_min"][act], 2 * pixel_columns(a)), label="lambda_min (drive on)")
    a.axhline(1e-6, color="r", lw=0.8, ls=":", label="rank gate 1e-6")
    plain_log_ticks(a)
    a.set_ylabel("lambda_min(W J_hat J_hat^T W)")
    a.legend(fontsize=8)
    a.set_title("stability margin")


def _offset_row(ax: np.ndarray, r: _Rollout) -> None:
    """The adapting offset: lateral and axial estimates against the truth, the lateral error."""
    t, theta, true, cols = r.t, r.trace["theta"], r.true_offset, 2 * pixel_columns(ax[0])
    a = ax[0]
    for i, (n, col) in enumerate(zip("xy", ("C0", "C1"))):
        a.plot(*decimate(t, 1e3 * theta[:, i], cols), col, label=f"estimate {n}_f")
        a.axhline(1e3 * true[i], color=col, ls="--", lw=0.8, label=f"true {n}_f")
    a.set_ylabel("lateral offset [mm]")
    a.legend(fontsize=7, ncol=2)
    a.set_title("offset estimate vs truth (flange frame)")
    a = ax[1]
    a.plot(*decimate(t, 1e3 * theta[:, 2], cols), "C2", label="estimate z_f")
    a.axhline(1e3 * true[2], color="C2", ls="--", lw=0.8, label="true z_f (length)")
    a.set_ylabel("axial offset [mm]")
    a.legend(fontsize=7)
    a.set_title("tool length estimate vs truth")
    a = ax[2]
    err = 1e3 * np.hypot(theta[:, 0] - true[0], theta[:, 1] - true[1])
    floor = 1e-3
    a.semilogy(*decimate(t, np.maximum(err, floor), cols), "k",
               label="|lateral error|" + (f" (floored at {floor:g} mm)" if (err < floor).any() else ""))
    a.axhline(1.0, color="r", ls=":", lw=0.8, label="1 mm")
    plain_log_ticks(a)
    a.set_ylabel("lateral offset error [mm]")
    a.legend(fontsize=7, loc="lower left")
    a.set_title("identification")


def _prediction_row(ax: np.ndarray, r: _Rollout) -> None:
    """Theta held fixed or not an offset: the W-scaled prediction error over time, and by contact
    state (held) or the Jacobian's error against the truth (adapting)."""
    eps = r.trace["eps_w"]
    names = ("d", "F_lat x", "F_lat y", "M x", "M y", "M z")
    why = "theta held fixed" if r.held else f"{r.cfg.run.features} features"
    for a, chans, title in ((ax[0], (0, 1, 2), "depth and force"), (ax[1], (3, 4, 5), "moment")):
        _dense_panel(a, r, [(names[c], eps[:, c], f"C{c}") for c in chans], "")
        a.set_ylabel("W-scaled rate error [-]")
        a.set_title(f"prediction error, {title} (W-scaled; {why})", fontsize=10)
    a = ax[2]
    act = r.trace["drive_scale"] > 0
    if r.held:
        _rms_bars(a, eps[act & ~r.gate], eps[act & r.gate])
    else:
        a.semilogy(*decimate(r.t, np.maximum(r.trace["truth_jacobian_rel_error"], 1e-6), 2 * pixel_columns(a)), "k",
                   label="|J_hat - J| / |J| (truth)")
        plain_log_ticks(a)
        a.set_ylabel("Jacobian relative error")
        a.legend(fontsize=7)
        a.set_title("identification")


def _fixed_margins(fig: plt.Figure, title_lines: int, footer_lines: int, hgap: float = 0.95) -> None:
    """Place the 3x3 grid with fixed margins [in], sized for the widest content the rollout
    figure draws (two-line titles, 'truth: bore/socket: 0 %' tick labels, log-axis labels and a
    rotated y label left of each panel). Fixed rather than ``constrained_layout``: that solver
    measures every text object and, on ``savefig``, draws the whole figure a second time -- about
    half of the figure's cost. ``hgap``: between rows [in]; 0.95 holds x tick labels, the x label
    and a two-line title, 0.55 the title alone."""
    w, h = fig.get_size_inches()
    left, right, wgap = 0.85, 0.12, 1.3  # y tick labels + y label of the panel to the right
    top = 0.75 + 0.22 * (title_lines - 1)  # the suptitle (0.2 in below the edge) and the first row's titles
    bottom = 0.55 + (0.14 * footer_lines + 0.12 if footer_lines else 0.0)  # x labels (+ the footer)
    aw = (w - left - right - 2 * wgap) / 3
    ah = (h - top - bottom - 2 * hgap) / 3
    fig.subplots_adjust(left=left / w, right=1 - right / w, bottom=bottom / h, top=1 - top / h,
                        wspace=wgap / aw, hspace=hgap / ah)


def _rms_bars(a, free: np.ndarray, contact: np.ndarray) -> None:
    """RMS of the W-scaled prediction error per channel, free space vs sensed contact."""
    names = ("d", "F_lat x", "F_lat y", "M x", "M y", "M z")
    xx = np.arange(len(names))
    for k, (e, lab, col) in enumerate(((free, "free space", "0.55"), (contact, "sensed contact", "C1"))):
        rms = np.sqrt(np.mean(e**2, axis=0)) if len(e) else np.full(len(names), np.nan)
        a.bar(xx + (k - 0.5) * 0.4, rms, width=0.4, color=col, label=f"{lab} ({len(e)} samples)")
    a.set_xticks(xx, names, fontsize=8)
    a.set_yscale("log")
    plain_log_ticks(a)
    a.set_ylim(top=a.get_ylim()[1] * 30)  # room for the legend above the bars
    a.set_ylabel("RMS of the W-scaled rate error [-]")
    a.legend(fontsize=7, loc="upper left")
    a.set_title("prediction error by contact state (drive on)", fontsize=10)


#: resolution the figures are saved at [dots per inch]
SAVE_DPI = 120
#: zlib level of the saved PNGs (fast: each PNG is written once)
PNG_COMPRESS_LEVEL = 1


def save_figure(fig: plt.Figure, path: Path) -> None:
    fig.savefig(path, dpi=SAVE_DPI, pil_kwargs={"compress_level": PNG_COMPRESS_LEVEL})
    plt.close(fig)


def _with_gaps(t: np.ndarray, *ys: np.ndarray) -> tuple[np.ndarray, ...]:
    """NaN-separated copies so a line does not bridge gaps in the time base (> 3x its median step)."""
    if len(t) < 3:
        return (t, *ys)
    dt = np.diff(t)
    cut = np.flatnonzero(dt > 3 * max(float(np.median(dt)), 1e-12)) + 1
    return tuple(np.insert(np.asarray(v, dtype=float), cut, np.nan) for v in (t, *ys))


def before_after_panel(a, rows: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray], chans: Sequence[int],
                       names: Sequence[str], unit: str, added: Sequence[str], marker: str = "") -> None:
    """Residual rows per channel over time, before (faint) and after adding ``added``, robust
    y-limits over both; the legend names the channels and what faint/solid mean. ``rows``: (t [s],
    channel, before, after), each (N,) -- one residual row each."""
    from matplotlib.lines import Line2D

    t, channel, before, after = rows
    pooled = []
    for c in chans:
        m = channel == c
        if not m.any():
            continue
        order = np.argsort(t[m])
        tt, yb, ya = _with_gaps(t[m][order], before[m][order], after[m][order])
        style = dict(ls="none", marker=".", ms=1.5) if marker else dict(lw=0.8)
        line, = a.plot(tt, yb, alpha=0.3, **style)
        a.plot(tt, ya, color=line.get_color(), label=names[c], **style)
        pooled += [(tt, yb), (tt, ya)]
    if pooled:
        tt = np.concatenate([p[0] for p in pooled])
        set_robust_ylim(a, tt, [np.concatenate([p[1] for p in pooled])], unit=unit, headroom=0.3)
    handles, labels = a.get_legend_handles_labels()
    handles += [Line2D([], [], color="0.4", alpha=0.3, lw=2), Line2D([], [], color="0.4", lw=2)]
    labels += ["faint: before", f"solid: after adding {', '.join(added)}"]
    a.legend(handles, labels, fontsize=7, ncol=3, loc="upper left", markerscale=5)
    a.set_xlabel("time [s]")
    a.set_ylabel(f"residual [{unit}]")
    a.set_title(f"residual before / after adding {', '.join(added)}", fontsize=9)


def bar_values(a, y: np.ndarray, values: Sequence[float], fmt: str = "{:+.3f}") -> None:
    """Write each bar's value beside its end (a bar near zero is otherwise invisible)."""
    lo, hi = a.get_xlim()
    off = 0.01 * (hi - lo)
    for yy, v in zip(y, values):
        if np.isfinite(v):
            txt = fmt.format(v).replace("-", "+") if float(fmt.format(abs(v))) == 0 else fmt.format(v)
            a.text(v + (off if v >= 0 else -off), yy, txt, va="center", ha="left" if v >= 0 else "right",
                   fontsize=6.5, color="0.2")


def cell_learning_figure(results: Sequence[dict]) -> plt.Figure:
    """A work cell's learning curve: the cell Jacobian error (median over the held-out
    configurations) in % against the insertion -- % as the draws figure and the README give it --
    one panel per tool family, one colour per features type; thin lines per tool, the thick line the
    median over tools. ``results``: compare's per-episode records with a ``cell`` block
    (``kinadapt_nn.runs.compare``: the error there a fraction)."""
    recs = [r for r in results if r.get("cell")]
    fams = list(dict.fromkeys(r["tool_family"] for r in recs))
    feats = list(dict.fromkeys(r["features"] for r in recs))
    fig, axes = plt.subplots(1, len(fams), figsize=(5.6 * len(fams), 4.0), squeeze=False, sharey=True,
                             constrained_layout=True)
    for a, fam in enumerate(fams):
        ax = axes[0, a]
        for k, feat in enumerate(feats):
            curves = [100.0 * np.asarray(r["cell"]["jacobian_error_cell_median"]) for r in recs  # [%]
                      if (r["tool_family"], r["features"]) == (fam, feat)]
            if not curves:
                continue
            n = min(len(c) for c in curves)
            arr = np.stack([c[:n] for c in curves])
            x = np.arange(n)
            for c in arr:
                ax.semilogy(x, c, color=f"C{k}", lw=0.6, alpha=0.35)
            ax.semilogy(x, np.median(arr, axis=0), "o-", color=f"C{k}", lw=2.0, ms=3.5,
                        label=f"{feat} (median of {plural(len(arr), 'tool')})")
        ax.set_title(f"{fam.replace('_', ' ')} family")
        ax.set_xlabel("insertion (0 = before the first)")
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))  # insertions are whole: no tick at 0.5
        labelled_ticks(ax.yaxis)
        ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:.3g}"))  # 0.02, 0.5, 1: read as % directly
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8)
    axes[0, 0].set_ylabel("cell Jacobian error [%]\n(median over held-out configurations)")
    nb = len(recs[0]["cell"]["bores_w_m"])
    how = {"refit": "theta refitted", "carry": "theta and P carried"}.get(recs[0]["cell"].get("between"), "")
    fig.suptitle(f"work cell: {plural(nb, 'bore')}" + (f", {how} between insertions" if how else "")
                 + "; error = 100 |W(J_hat - J_true)| / |W J_true| %")
    return fig


#: offsets [points] tried for a point's label, nearest first (``place_labels``)
_LABEL_RADII_PT = (5.0, 10.0, 16.0, 24.0, 34.0, 46.0, 60.0)
#: directions tried on each ring, diagonals first
_LABEL_ANGLES = np.deg2rad([45, 135, -45, -135, 90, -90, 0, 180, 22.5, 157.5, -22.5, -157.5, 67.5, 112.5, -67.5, -112.5])


def place_labels(ax, x: Sequence[float], y: Sequence[float], texts: Sequence[str], fontsize: float = 8.0,
                 **text_kw) -> list:
    """A label beside each point ``(x[i], y[i])`` (data coordinates) that overlaps no other label,
    no point and no legend of ``ax``: tried on growing rings around the point, nearest first, inside
    the axes; a label set off beyond the second ring gets a thin leader line to its point. The
    figure's layout is settled first (one draw) and then frozen, so the placement holds when the
    figure is saved. -> the annotations, in ``texts``' order."""
    from matplotlib.transforms import Bbox

    fig = ax.get_figure()
    fig.canvas.draw()  # constrained layout, if any, puts the axes where they then stay
    fig.set_layout_engine("none")
    r = fig.canvas.get_renderer()
    px_per_pt = fig.dpi / 72.0
    pts = ax.transData.transform(np.column_stack([np.asarray(x, float), np.asarray(y, float)]))  # (N, 2) [px]
    inside = ax.get_window_extent(r)
    mark = 4.0 * px_per_pt  # a marker's half-width [px]
    taken = [Bbox.from_bounds(px - mark, py - mark, 2 * mark, 2 * mark) for px, py in pts]
    if ax.get_legend() is not None:
        taken.append(ax.get_legend().get_window_extent(r))
    out = []
    for (xi, yi), (px, py), s in zip(zip(x, y), pts, texts):
        probe = ax.text(0, 0, s, fontsize=fontsize, transform=None, **text_kw)
        bb = probe.get_window_extent(r)
        probe.remove()
        w, h = bb.width + 2.0, bb.height + 2.0
        place = None
        for k, rad in enumerate(_LABEL_RADII_PT):
            for ang in _LABEL_ANGLES:
                c, sn = np.cos(ang), np.sin(ang)
                dx = c * (rad * px_per_pt + w / 2 * abs(c))  # the box's centre: its edge clears the ring
                dy = sn * (rad * px_per_pt + h / 2 * abs(sn))
                box = Bbox.from_bounds(px + dx - w / 2, py + dy - h / 2, w, h)
                if (inside.x0 <= box.x0 and box.x1 <= inside.x1 and inside.y0 <= box.y0 and box.y1 <= inside.y1
                        and not any(box.overlaps(t) for t in taken)):
                    place = (dx, dy, k, box)
                    break
            if place:
                break
        if place is None:  # no free place within reach: beside the point, up-right
            d = _LABEL_RADII_PT[0] * px_per_pt + w / 2
            place = (d, d, 0, Bbox.from_bounds(px + d - w / 2, py + d - h / 2, w, h))
        dx, dy, k, box = place
        arrow = {"arrowstyle": "-", "lw": 0.5, "color": "0.4", "shrinkA": 1, "shrinkB": 3} if k >= 2 else None
        out.append(ax.annotate(s, (xi, yi), xytext=(dx / px_per_pt, dy / px_per_pt), textcoords="offset points",
                               ha="center", va="center", fontsize=fontsize, arrowprops=arrow, **text_kw))
        taken.append(box)
    return out


def plural(n: int, noun: str) -> str:
    """``"1 bore"``, ``"6 bores"``."""
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"
