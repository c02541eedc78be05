"""``kinadapt diagnose`` outputs: diagnosis.json, figures, TensorBoard."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from kinadapt_nn.diagnostics.residual import PHASES, Replay
from kinadapt_nn.sensing import CHANNEL_NAMES, CHANNEL_UNITS


def residual_figure(rep: Replay, path: Path) -> None:
    """Levels (full 6-axis wrench incl. axial force), measured vs predicted rates, residuals,
    with the contact phases shaded."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = rep.t_s
    fig, ax = plt.subplots(4, 3, figsize=(14, 11), sharex=True, constrained_layout=True)
    colors = dict(zip(PHASES, ("0.95", "#fff3d6", "#dff0ff", "#ffe0e0", "#e0ffe0", "#f0e0ff")))
    for a in ax.ravel():
        for k, name in enumerate(PHASES):
            m = rep.phase == k
            if m.any():
                a.fill_between(t, 0, 1, where=m, color=colors[name], transform=a.get_xaxis_transform(), step="mid")
    a = ax[0, 0]
    for i, n in enumerate("xyz"):
        a.plot(t, rep.w_env[:, i], label=f"f_{n} (tool -> env)")
    a.set_ylabel("force [N]")
    a.legend(fontsize=7)
    a.set_title("levels: contact force at O (axial included)")
    a = ax[0, 1]
    for i, n in enumerate("xyz"):
        a.plot(t, rep.w_env[:, 3 + i], label=f"m_{n}")
    a.set_ylabel("moment [N m]")
    a.legend(fontsize=7)
    a.set_title("levels: contact moment about O")
    a = ax[0, 2]
    a.plot(t, 1e3 * rep.s[:, 0], "k")
    a.set_ylabel("d [mm]")
    a.set_title("depth (encoders)")
    for i in range(1, 6):
        r, c = divmod(i - 1, 3)
        a = ax[1 + r, c]
        a.plot(t, rep.s_dot_meas[:, i], lw=0.8, label="measured")
        a.plot(t, rep.s_dot_pred[:, i], lw=0.8, label="predicted")
        a.plot(t, rep.residual[:, i], "k", lw=0.6, alpha=0.7, label="residual")
        a.set_ylabel(f"d/dt {CHANNEL_NAMES[i]} [{CHANNEL_UNITS[i]}/s]")
        a.legend(fontsize=7)
    a = ax[2, 2]
    a.plot(t, rep.residual[:, 0] * 1e3, "k", lw=0.6)
    a.set_ylabel("d residual [mm/s]")
    a = ax[3, 0]
    a.plot(t, rep.qdot_norm, "C2")
    a.set_ylabel("|qdot| [rad/s]")
    a.set_xlabel("time [s]")
    a = ax[3, 1]
    a.step(t, rep.phase, where="post")
    a.set_yticks(range(len(PHASES)))
    a.set_yticklabels(PHASES, fontsize=7)
    a.set_xlabel("time [s]")
    a.set_title("contact phase (sensor side)")
    ax[3, 2].axis("off")
    fig.suptitle("model vs measurement: sensor rates and the residual (bias b of eq. ft_pred)")
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_tb(log_dir: Path, rep: Replay) -> None:
    from torch.utils.tensorboard import SummaryWriter

    idx = np.arange(0, len(rep.t_s), 10)
    with SummaryWriter(log_dir=str(log_dir)) as wr:
        for i, n in enumerate(CHANNEL_NAMES):
            for k in idx:
                st = int(round(rep.t_s[k] * 1e3))
                wr.add_scalar(f"pred_error/{n}", float(rep.residual[k, i]), st)
                wr.add_scalar(f"diagnose/measured_rate/{n}", float(rep.s_dot_meas[k, i]), st)
                wr.add_scalar(f"diagnose/predicted_rate/{n}", float(rep.s_dot_pred[k, i]), st)
