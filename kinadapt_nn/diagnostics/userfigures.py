"""Figures of ``kinadapt diagnose LOG --setup SETUP``: model vs measurement per channel, and the
ranking with verdicts (plus the residual before/after ``--add``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

VERDICT_COLORS = {"present": "C3", "cannot_decide": "C1", "absent": "0.6"}


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _shade(ax, t, mask) -> None:
    if mask.any():
        ax.fill_between(t, 0, 1, where=mask, color="#ffe6cc", transform=ax.get_xaxis_transform(), step="mid",
                        label="contact (tip-moment rows)")


def model_vs_measurement(res, setup, path: Path) -> None:
    """Six panels (F x/y/z, M x/y/z, sensor frame, tool on sensor): the measured reading and the
    declared tool's prediction, contact shaded."""
    plt = _plt()
    prep = res.prep
    t = prep.t_s - prep.t_s[0]
    fig, ax = plt.subplots(2, 3, figsize=(15, 7), sharex=True, constrained_layout=True)
    names = ("F_x", "F_y", "F_z", "M_x", "M_y", "M_z")
    for i, a in enumerate(ax.ravel()):
        _shade(a, t, res.contact)
        a.plot(t, prep.r[:, i], lw=0.6, color="0.3", label="measured")
        a.plot(t, prep.w_nom[:, i], lw=1.0, color="C0", label="declared tool (model)")
        a.set_ylabel(f"{names[i]} [{'N' if i < 3 else 'N m'}]")
        if i >= 3:
            a.set_xlabel("time [s]")
    ax[0, 0].legend(fontsize=8, loc="best")
    fig.suptitle(f"wrench the tool exerts on the sensor (sensor frame) vs the declared tool "
                 f"({setup.tool.mass_kg:g} kg); the log's convention: {setup.log.wrench_acts}")
    fig.savefig(path, dpi=110)
    plt.close(fig)


def effects_figure(res, path: Path) -> None:
    """Ranking bars (held-out explained share, coloured by verdict) and, after ``--add``, the
    residual rows before/after per channel over time (physical units)."""
    plt = _plt()
    rows = [r for r in res.report["ranking"] if r.get("judged", True)]
    has_add = res.after is not None
    fig, ax = plt.subplots(1, 3 if has_add else 1, figsize=(17 if has_add else 7.5, 4.8), constrained_layout=True,
                           squeeze=False)
    a = ax[0, 0]
    names = [r["effect"] for r in rows][::-1]
    yy = np.arange(len(names))
    a.barh(yy, [max(r["explained_fraction"], 0.0) for r in rows][::-1],
           color=[VERDICT_COLORS[r["verdict"]] for r in rows][::-1])
    a.set_yticks(yy, [f"{r['effect']}  [{r['verdict']}]" for r in rows][::-1], fontsize=8)
    a.set_xlim(0, 1.05)
    a.set_xlabel("held-out share of the declared model's residual it explains (block CV)")
    a.set_title("which effect is missing (red present, orange cannot decide, grey absent)", fontsize=9)
    if has_add:
        des = res.design
        for col, chans, unit in ((1, (0, 1, 2), "N"), (2, (3, 4, 5, 6, 7, 8), "N m")):
            a = ax[0, col]
            for c in chans:
                m = des.channel == c
                if not m.any():
                    continue
                order = np.argsort(des.t_s[m])
                tt = des.t_s[m][order]
                line, = a.plot(tt, (res.before[m] / des.W[m])[order], ".", ms=1.5, alpha=0.35)
                a.plot(tt, (res.after[m] / des.W[m])[order], ".", ms=1.5, color=line.get_color(),
                       label=des.channel_names[c])
            a.set_xlabel("time [s]")
            a.set_ylabel(f"residual [{unit}]")
            a.set_title(f"before (faint) / after adding {', '.join(res.report['added'])}", fontsize=9)
            a.legend(fontsize=7, markerscale=5)
    fig.savefig(path, dpi=110)
    plt.close(fig)
