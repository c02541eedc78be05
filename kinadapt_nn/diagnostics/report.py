"""``kinadapt diagnose`` outputs: diagnosis.json, figures, TensorBoard."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from kinadapt_nn.diagnostics.residual import PHASES, Replay
from kinadapt_nn.sensing import CHANNEL_NAMES, CHANNEL_UNITS

#: shading of the contact phases in the residual figure
PHASE_COLORS = dict(zip(PHASES, ("0.88", "#ffe2a8", "#bfe1ff", "#ffc4c4", "#c8f5c8", "#e6ccff")))


def residual_figure(rep: Replay, path: Path) -> None:
    """Levels (full 6-axis wrench incl. axial force), measured vs predicted rates, residuals,
    with the contact phases shaded (their colours: the legend of the last panel, which shows
    where each channel's residual comes from). Rate panels take robust y-limits: spikes beyond
    the 0.5-99.5 % range are clipped and marked."""
    import matplotlib.pyplot as plt

    fig = _residual_fig(rep)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _residual_fig(rep: Replay):
    """The figure of ``residual_figure`` (built, not saved)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from kinadapt_nn.figures import set_robust_ylim

    t = rep.t_s
    fig, ax = plt.subplots(4, 3, figsize=(14, 12), constrained_layout=True)
    time_axes = list(ax.ravel()[:-1])
    for a in time_axes[1:]:
        a.sharex(time_axes[0])
    present = [k for k in range(len(PHASES)) if (rep.phase == k).any()]
    for a in time_axes:
        for k in present:
            a.fill_between(t, 0, 1, where=rep.phase == k, color=PHASE_COLORS[PHASES[k]], lw=0,
                           transform=a.get_xaxis_transform(), step="mid", zorder=0)
    a = ax[0, 0]
    for i, n in enumerate("xyz"):
        a.plot(t, rep.w_env[:, i], label=f"f_{n} (tool -> env)")
    set_robust_ylim(a, t, [rep.w_env[:, i] for i in range(3)], unit="N", headroom=0.3)
    a.set_ylabel("force [N]")
    a.legend(fontsize=7, ncol=3, loc="upper left")
    a.set_title("levels: contact force at O (axial included)")
    a = ax[0, 1]
    for i, n in enumerate("xyz"):
        a.plot(t, rep.w_env[:, 3 + i], label=f"m_{n}")
    set_robust_ylim(a, t, [rep.w_env[:, 3 + i] for i in range(3)], unit="N m", headroom=0.3)
    a.set_ylabel("moment [N m]")
    a.legend(fontsize=7, ncol=3, loc="upper left")
    a.set_title("levels: contact moment about O")
    a = ax[0, 2]
    a.plot(t, 1e3 * rep.s[:, 0], "k", label="d (encoders)")
    a.set_ylabel("d [mm]")
    a.legend(fontsize=7, loc="best")
    a.set_title("depth below the entrance")
    for i in range(1, 6):
        r, c = divmod(i - 1, 3)
        a = ax[1 + r, c]
        a.plot(t, rep.s_dot_meas[:, i], lw=0.8, label="measured")
        a.plot(t, rep.s_dot_pred[:, i], lw=0.8, label="predicted")
        a.plot(t, rep.residual[:, i], "k", lw=0.6, alpha=0.7, label="residual")
        unit = f"{CHANNEL_UNITS[i]}/s"
        set_robust_ylim(a, t, [rep.s_dot_meas[:, i], rep.s_dot_pred[:, i], rep.residual[:, i]], unit=unit,
                        headroom=0.35)
        a.set_ylabel(f"d/dt {CHANNEL_NAMES[i]} [{unit}]")
        a.legend(fontsize=7, ncol=2, loc="upper left")
        a.set_title(f"rate of {CHANNEL_NAMES[i]}: measured vs model", fontsize=10)
    a = ax[2, 2]
    a.plot(t, rep.residual[:, 0] * 1e3, "k", lw=0.6, label="residual")
    set_robust_ylim(a, t, [rep.residual[:, 0] * 1e3], unit="mm/s", headroom=0.35)
    a.set_ylabel("d residual [mm/s]")
    a.legend(fontsize=7, loc="upper left")
    a.set_title("rate of d: residual", fontsize=10)
    a = ax[3, 0]
    a.plot(t, rep.qdot_norm, "C2", label="|qdot|")
    a.set_ylabel("|qdot| [rad/s]")
    a.set_xlabel("time [s]")
    a.legend(fontsize=7, loc="best")
    a.set_title("joint speed", fontsize=10)
    a = ax[3, 1]
    a.step(t, rep.phase, where="post", color="k", lw=1.0)
    a.set_yticks(range(len(PHASES)), PHASES, fontsize=7)
    a.set_xlabel("time [s]")
    a.set_title("contact phase (sensor side; shading in every panel)", fontsize=10)
    for a in time_axes:
        a.tick_params(labelbottom=True)
    _phase_share(ax[3, 2], rep, present)
    fig.suptitle("model vs measurement: sensor rates and the residual (bias b of eq. ft_pred); "
                 "shading = contact phase, red triangles = spikes beyond the axis")
    return fig


def _phase_share(a, rep: Replay, present: list[int]) -> None:
    """Stacked bars: the share of the time, and of each channel's squared residual (drive on),
    spent in each contact phase -- the colour key of the phase shading."""
    act = rep.active if rep.active.any() else np.ones(len(rep.t_s), bool)
    ph, res = rep.phase[act], rep.residual[act]
    rows = ["time"] + list(CHANNEL_NAMES)
    yy = np.arange(len(rows))[::-1]
    left = np.zeros(len(rows))
    for k in present:
        m = ph == k
        share = [m.mean()] + [float((res[m, i] ** 2).sum() / max((res[:, i] ** 2).sum(), 1e-300))
                              for i in range(res.shape[1])]
        a.barh(yy, share, left=left, color=PHASE_COLORS[PHASES[k]], edgecolor="0.35", lw=0.5, label=PHASES[k])
        left += share
    a.set_yticks(yy, rows, fontsize=8)
    a.set_xlim(0, 1)
    a.set_xlabel("share (drive on)")
    a.set_title("where the residual is: share of time and of each\nchannel's squared residual per contact phase",
                fontsize=9)
    a.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=3, title="contact phase (shading)",
             title_fontsize=7)


def write_tb(log_dir: Path, rep: Replay) -> None:
    from kinadapt_nn.runio import EventWriter

    idx = np.arange(0, len(rep.t_s), 10)
    with EventWriter(log_dir) as wr:
        for k in idx:
            row = {}
            for i, n in enumerate(CHANNEL_NAMES):
                row[f"pred_error/{n}"] = float(rep.residual[k, i])
                row[f"diagnose/measured_rate/{n}"] = float(rep.s_dot_meas[k, i])
                row[f"diagnose/predicted_rate/{n}"] = float(rep.s_dot_pred[k, i])
            wr.add_scalars_at(int(round(rep.t_s[k] * 1e3)), row)
