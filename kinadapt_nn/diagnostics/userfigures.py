"""Figures of ``kinadapt diagnose LOG --setup SETUP``: model vs measurement per channel, and the
ranking with verdicts (plus the residual before/after ``--add``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from kinadapt_nn.diagnostics.summary import undecided_in_model

VERDICT_COLORS = {"present": "C3", "cannot_decide": "C1", "absent": "0.6"}
#: at most about this many points per plotted series (a long log's series are decimated): a panel is
#: ~500 px wide, so 2000 min/max bins (4 a pixel) draw what every sample would; 20 000 took 7.4 s (cProfile) of
#: ``savefig`` on a 5-minute 1 kHz log
MAX_POINTS = 4_000


def envelope(t: np.ndarray, y: np.ndarray, max_points: int = MAX_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """A line's samples (n,) decimated for plotting: ``max_points / 2`` bins of consecutive
    samples, each drawn as its minimum and maximum at its first time (spikes stay visible);
    the series itself when it is short. -> (t, y)."""
    n = len(t)
    if n <= max_points:
        return t, y
    start = np.linspace(0, n, max_points // 2 + 1).astype(int)[:-1]
    lo, hi = np.minimum.reduceat(y, start), np.maximum.reduceat(y, start)
    return np.repeat(t[start], 2), np.column_stack([lo, hi]).ravel()


def every(n: int, max_points: int = MAX_POINTS) -> slice:
    """A stride that leaves at most ``max_points`` of ``n`` points (dot plots, shading)."""
    return slice(None, None, max(1, -(-n // max_points)))


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


#: the x axis of a static log's panels (``[log] static``: its rows, poses at rest, have no clock; the
#: diagnosis orders them by the direction of gravity in the sensor, ``signals.from_log``)
STATIC_XLABEL = "pose (grouped by gravity direction)"


def _shade(ax, t, mask, label: str = "contact (tip-moment rows)") -> None:
    if mask.any():
        k = every(len(t), 4 * MAX_POINTS)
        t, mask = t[k], mask[k]
        ax.fill_between(t, 0, 1, where=mask, color="#ffe6cc", transform=ax.get_xaxis_transform(), step="mid",
                        label=label)


#: the channels of the moment about the tip in the design (``userlog.CHANNELS``: free six, then tip three)
TIP_CHANNELS = (6, 7, 8)


def contact_rows_left_out(res) -> str | None:
    """Why the diagnosis left out the contact rows (moment about the tip) of a log with contact, in
    a few words -- the tip check failed (with its ratio), ``[contact] mode = "exclude"`` -- or None
    when it has them or the log has no contact."""
    des = res.design
    if not np.asarray(res.contact).any() or np.isin(des.channel, TIP_CHANNELS).any():
        return None
    chk = res.report.get("tip_contact_check") or {}
    if not chk.get("ok", True) and "residual_rms_w_tip_moment" in chk:
        ratio = chk["residual_rms_w_tip_moment"] / max(chk["residual_rms_w_free"], 1.0)
        return f"tip check failed: tip moment {ratio:.1f}x the free-space residual"
    rows = (res.report.get("contact") or {}).get("rows")
    if rows in ("exclude", "none"):
        return f'[contact] mode = "{rows}"'
    return str(rows or "no contact rows")


def model_vs_measurement(res, setup, path: Path) -> None:
    """Six panels (F x/y/z, M x/y/z, sensor frame, tool on sensor): the measured reading and the
    declared tool's prediction, contact shaded; robust y-limits (spikes beyond the 0.5-99.5 %
    range clipped and marked). Below them, what is unexplained, per phase (free-space force,
    free-space moment, contact moment about the tip): the residual of the declared model (faint),
    of the final model held-out or, with ``--add``, after the refit (solid), the relevant size
    (dashed) and the spans the completeness verdict marks as unexplained (red)."""
    plt = _plt()
    fig = _mvm_fig(res, setup)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _mvm_fig(res, setup):
    """The figure of ``model_vs_measurement`` (built, not saved)."""
    from kinadapt_nn.figures import set_robust_ylim

    plt = _plt()
    sig = res.signals
    static = bool(getattr(sig, "static", False))  # poses at rest: no clock, no order between rows
    t = sig.clock if static else sig.t - sig.t[0]  # a static log: the pose index, as the design's rows
    xlabel = STATIC_XLABEL if static else "time [s]"
    fig, ax_all = plt.subplots(3, 3, figsize=(15, 11), sharex=True, constrained_layout=True)
    ax = ax_all[:2]
    names = ("F_x", "F_y", "F_z", "M_x", "M_y", "M_z")
    _unexplained_row(ax_all[2], res, setup, xlabel)
    left_out = contact_rows_left_out(res)
    for i, a in enumerate(ax.ravel()):
        unit = "N" if i < 3 else "N m"
        _shade(a, t, res.contact, "contact (left out of the fit)" if left_out else "contact (tip-moment rows)")
        if static:  # each pose a point: a line would join poses that are not neighbours in anything
            k = every(len(t))
            a.plot(t[k], sig.wrench[k, i], ".", ms=3, color="0.3", label="measured")
            a.plot(t[k], sig.w_nom[k, i], "x", ms=3, color="C0", label="declared tool (model)")
        else:
            a.plot(*envelope(t, sig.wrench[:, i]), lw=0.6, color="0.3", label="measured")
            a.plot(*envelope(t, sig.w_nom[:, i]), lw=1.0, color="C0", label="declared tool (model)")
        set_robust_ylim(a, t, [sig.wrench[:, i], sig.w_nom[:, i]], unit=unit)
        a.set_ylabel(f"{names[i]} [{unit}]")
        a.set_title(names[i], fontsize=10)
        a.tick_params(labelbottom=True)
        a.set_xlabel(xlabel)
    shared: dict = {}
    for a in ax.ravel():
        hs, ls = a.get_legend_handles_labels()
        clipped = [(h, lab) for h, lab in zip(hs, ls) if lab.startswith("clipped")]
        shared.update({lab: h for h, lab in zip(hs, ls) if not lab.startswith("clipped")})
        if clipped:  # the panel's own note: what lies beyond its axis
            a.legend(*zip(*clipped), fontsize=7, loc="upper left")
    fig.legend(list(shared.values()), list(shared), loc="outside lower center", ncol=len(shared), fontsize=9)
    held = undecided_in_model(res.report)
    verdict = ("something the model does not contain is left (red spans)" if not res.report.get("model_complete", True)
               else f"the model explains the log only with undecided effects ({', '.join(held)})" if held
               else "the model explains the log")
    if left_out:  # then only free space was judged: "explains the log" would claim the contact too
        verdict = verdict.replace("the log", "free space") + f"; contact rows left out ({left_out})"
    fig.suptitle(f"wrench the tool exerts on the sensor (sensor frame) vs the declared tool "
                 f"({setup.tool.mass_kg:g} kg); the log's convention: {setup.log.wrench_acts}\nbottom row: {verdict}")
    return fig


def _unexplained_row(axes, res, setup, xlabel: str = "time [s]") -> None:
    """The bottom row of ``model_vs_measurement`` (its docstring)."""
    from kinadapt_nn.figures import set_robust_ylim

    des = res.design
    before = des.y if res.before is None else res.before
    if res.after is not None:
        after, what = res.after, f"after adding {', '.join(res.report['added'])}"
    else:
        after, what = (res.heldout if res.heldout is not None else des.y), "final model (held-out)"
    un = res.report.get("unexplained", {})
    groups = (((0, 1, 2), "free space: force", "N", setup.analysis.relevant_force_N),
              ((3, 4, 5), "free space: moment", "N m", setup.analysis.relevant_moment_Nm),
              ((6, 7, 8), "contact: moment about the tip", "N m", setup.analysis.relevant_moment_Nm))
    for a, (chans, title, unit, rel) in zip(axes, groups):
        pooled = []
        for c in chans:
            m = des.channel == c
            if not m.any():
                continue
            o = np.argsort(des.t_s[m])[every(int(m.sum()))]
            t = des.t_s[m][o]
            yb, ya = before[m][o] / des.W[m][o], after[m][o] / des.W[m][o]
            line, = a.plot(t, yb, ".", ms=1.2, alpha=0.25)
            a.plot(t, ya, ".", ms=1.5, color=line.get_color(), label=des.channel_names[c])
            pooled += [yb, ya]
            for w in un.get("channels", {}).get(des.channel_names[c], {}).get("spans_s", []):
                a.axvspan(w[0], w[1], color="red", alpha=0.12, lw=0)
        for sgn in (-1, 1):
            a.axhline(sgn * rel, color="k", ls="--", lw=0.7)
        if pooled:
            set_robust_ylim(a, des.t_s, [np.concatenate(pooled)], unit=unit, headroom=0.3)
        bad = [c for c in un.get("carried_by", []) if des.channel_names.index(c) in chans]
        a.set_ylabel(f"residual [{unit}]")
        a.set_xlabel(xlabel)
        if chans == TIP_CHANNELS and not pooled:  # no contact rows: what the log has, and why nothing is judged
            _contact_not_judged(a, res, setup, rel)
            continue
        a.set_title(f"{title}: " + (f"UNEXPLAINED in {', '.join(bad)}" if bad else "explained"), fontsize=9,
                    color="C3" if bad else "k")
        if pooled:
            a.legend(fontsize=7, ncol=3, loc="upper left", markerscale=5,
                     title=f"faint: declared model; solid: {what}; dashed: relevant size", title_fontsize=6)


def _contact_not_judged(a, res, setup, rel: float) -> None:
    """The contact panel of a diagnosis without contact rows: the declared model's residual moment
    about the declared tip over the contact samples (measured - declared tool, the free-space mean
    offset removed from a tared log), i.e. the contact moment the tip does not account for; the
    title says why nothing there is "explained" (``contact_rows_left_out``), or that the log has no
    contact."""
    from kinadapt_nn.diagnostics.physical import tip_moment_map
    from kinadapt_nn.figures import set_robust_ylim

    sig, contact = res.signals, np.asarray(res.contact, dtype=bool)
    why = contact_rows_left_out(res)
    if why is None:
        a.set_title("contact: moment about the tip: no contact in the log", fontsize=9)
        a.text(0.5, 0.5, "no contact samples", transform=a.transAxes, ha="center", va="center", color="0.4")
        return
    static = bool(getattr(sig, "static", False))
    t = sig.clock if static else sig.t - sig.t[0]
    r = np.asarray(sig.wrench, dtype=float) - np.asarray(sig.w_nom, dtype=float)  # (n, 6) [N, N m]
    if setup.log.tared and (~contact).any():
        r = r - r[~contact].mean(axis=0)  # the tared reading's offset, as free space gives it
    L = getattr(sig, "tip_map", None)
    L = tip_moment_map(setup.tool.tip_sensor_m) if L is None else np.asarray(L)  # (3, 6)
    m_tip = r[contact] @ L.T  # (k, 3) [N m] about the declared tip
    tc = t[contact]
    k = every(len(tc))
    for j, name in enumerate(("Mtip_x", "Mtip_y", "Mtip_z")):
        a.plot(tc[k], m_tip[k, j], ".", ms=1.5, color=f"C{j}", label=name)
    for sgn in (-1, 1):
        a.axhline(sgn * rel, color="k", ls="--", lw=0.7)
    set_robust_ylim(a, tc, [m_tip.ravel()], unit="N m", headroom=0.3)
    a.set_title(f"contact, moment about the tip: NOT JUDGED (rows left out)\n{why}", fontsize=8, color="C1")
    a.legend(fontsize=7, ncol=3, loc="upper left", markerscale=5, title_fontsize=6,
             title="measured - declared tool, about the declared tip (not fitted); dashed: relevant size")


def effects_figure(res, path: Path) -> None:
    """Ranking bars (held-out explained share, coloured by verdict, value beside each bar) and,
    after ``--add``, the residual rows before/after per channel over time (physical units,
    robust y-limits)."""
    plt = _plt()
    fig = _effects_fig(res)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _effects_fig(res):
    """The figure of ``effects_figure`` (built, not saved)."""
    from matplotlib.patches import Patch

    from kinadapt_nn.figures import bar_values, before_after_panel

    plt = _plt()
    rows = [r for r in res.report["ranking"] if r.get("judged", True)]
    has_add = res.after is not None
    fig, ax = plt.subplots(1, 3 if has_add else 1, figsize=(18 if has_add else 8, 5), constrained_layout=True,
                           squeeze=False, width_ratios=[1.1, 1, 1] if has_add else None)
    a = ax[0, 0]
    yy = np.arange(len(rows))[::-1]
    share = np.array([r["explained_fraction"] for r in rows], dtype=float)
    a.barh(yy, np.maximum(share, 0.0), color=[VERDICT_COLORS[r["verdict"]] for r in rows])
    a.set_yticks(yy, [f"{r['effect']}  [{r['verdict']}]" for r in rows], fontsize=8)
    a.set_xlim(0, 1.12)
    a.set_ylim(-0.7, len(rows) - 0.3)
    bar_values(a, yy, np.maximum(share, 0.0))
    a.set_xlabel("held-out share of the declared model's residual it explains (block CV; < 0 shown as 0)")
    a.set_title("which effect is missing", fontsize=10)
    present = {r["verdict"] for r in rows}
    a.legend(handles=[Patch(facecolor=c, label=v.replace("_", " ")) for v, c in VERDICT_COLORS.items() if v in present],
             fontsize=7, loc="lower right", title="verdict", title_fontsize=7)
    if has_add:
        des = res.design
        added = list(res.report["added"])
        for col, chans, unit in ((1, (0, 1, 2), "N"), (2, (3, 4, 5, 6, 7, 8), "N m")):
            k = np.concatenate([np.flatnonzero(des.channel == c)[every(int(np.sum(des.channel == c)))]
                                for c in chans])  # each channel's rows, decimated
            before_after_panel(ax[0, col], (des.t_s[k], des.channel[k], res.before[k] / des.W[k],
                                            res.after[k] / des.W[k]), chans, des.channel_names, unit, added, marker=".")
    return fig
