"""Figures a paper can use (matplotlib, Agg backend; nothing needs a display)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from kinadapt_nn.config import ExperimentCfg  # noqa: E402
from kinadapt_nn.trace import Trace  # noqa: E402


def rollout_figure(trace: Trace, summary: dict, cfg: ExperimentCfg) -> plt.Figure:
    """Six panels: depth (sensor vs truth), lateral force, moment, axial force, the success
    channels, and lambda_min of the estimated Jacobian. Time axis in seconds."""
    t = trace["t_s"]
    s = trace["s"]
    w = trace["w_env_w"]
    sc = cfg.success
    fig, ax = plt.subplots(2, 3, figsize=(13, 6.5), sharex=True, constrained_layout=True)
    a = ax[0, 0]
    a.plot(t, 1e3 * s[:, 0], label="sensor depth d (encoders)")
    a.plot(t, 1e3 * trace["truth_tip_depth_m"], "--", label="true tip depth (truth)")
    a.axhline(1e3 * sc.depth_m, color="k", lw=0.8, ls=":", label=f"target {1e3 * sc.depth_m:.0f} mm")
    a.set_ylabel("depth [mm]")
    a.legend(fontsize=8)
    a.set_title("insertion depth")
    a = ax[0, 1]
    a.plot(t, s[:, 1], label="F_lat x")
    a.plot(t, s[:, 2], label="F_lat y")
    a.plot(t, np.hypot(s[:, 1], s[:, 2]), "k", lw=0.8, label="|F_lat|")
    a.axhline(sc.max_lateral_force_N, color="r", lw=0.8, ls=":")
    a.set_ylabel("force [N]")
    a.legend(fontsize=8)
    a.set_title("lateral contact force")
    a = ax[0, 2]
    for i, n in enumerate("xyz"):
        a.plot(t, s[:, 3 + i], label=f"M {n}")
    a.plot(t, np.linalg.norm(s[:, 3:], axis=1), "k", lw=0.8, label="|M|")
    a.axhline(sc.max_moment_Nm, color="r", lw=0.8, ls=":")
    a.set_ylabel("moment about O [N m]")
    a.legend(fontsize=8)
    a.set_title("wrist moment")
    a = ax[1, 0]
    a.plot(t, -w[:, 2], label="axial force on tool (sensor)")
    a.plot(t, trace["truth_contact_force_N"], "--", lw=0.8, label="total normal contact (truth)")
    a.set_ylabel("force [N]")
    a.set_xlabel("time [s]")
    a.legend(fontsize=8)
    a.set_title("axial / contact force")
    a = ax[1, 1]
    for off, name in enumerate(("depth_ok", "force_ok", "moment_ok")):
        a.step(t, trace[name].astype(float) + 1.2 * off, where="post", label=name)
    if summary.get("seat_time_s") is not None:
        a.axvline(summary["seat_time_s"], color="g", lw=1.0, label=f"seated {summary['seat_time_s']:.2f} s")
    a.set_yticks([])
    a.set_xlabel("time [s]")
    a.legend(fontsize=8, loc="upper left")
    a.set_title("success channels (sensor side)")
    a = ax[1, 2]
    act = trace["drive_scale"] > 0
    a.semilogy(t[act], trace["lambda_min"][act])
    a.axhline(1e-6, color="r", lw=0.8, ls=":", label="rank gate 1e-6")
    a.set_ylabel("lambda_min(W J_hat J_hat^T W)")
    a.set_xlabel("time [s]")
    a.legend(fontsize=8)
    a.set_title("stability margin")
    status = "SEATED" if summary["success"] else f"FAILED ({summary['failure']})"
    fig.suptitle(f"kinadapt online - features={summary['features']}, seed={summary['seed']}: {status}")
    return fig


def save_figure(fig: plt.Figure, path: Path) -> None:
    fig.savefig(path, dpi=120)
    plt.close(fig)
