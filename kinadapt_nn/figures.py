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
    fig, ax = plt.subplots(3, 3, figsize=(13, 9.5), sharex=True, constrained_layout=True)
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
    theta = trace["theta"]
    true = np.asarray(trace.meta.get("truth_offset_f_m", [np.nan] * 3))
    if theta.shape[1] == 3:
        a = ax[2, 0]
        for i, (n, col) in enumerate(zip("xy", ("C0", "C1"))):
            a.plot(t, 1e3 * theta[:, i], col, label=f"estimate {n}_f")
            a.axhline(1e3 * true[i], color=col, ls="--", lw=0.8, label=f"true {n}_f")
        a.set_ylabel("lateral offset [mm]")
        a.set_xlabel("time [s]")
        a.legend(fontsize=7, ncol=2)
        a.set_title("offset estimate vs truth (flange frame)")
        a = ax[2, 1]
        a.plot(t, 1e3 * theta[:, 2], "C2", label="estimate z_f")
        a.axhline(1e3 * true[2], color="C2", ls="--", lw=0.8, label="true z_f (length)")
        a.set_ylabel("axial offset [mm]")
        a.set_xlabel("time [s]")
        a.legend(fontsize=7)
        a.set_title("tool length estimate vs truth")
        a = ax[2, 2]
        err = np.hypot(theta[:, 0] - true[0], theta[:, 1] - true[1])
        a.semilogy(t, 1e3 * np.maximum(err, 1e-6), "k", label="|lateral error|")
        a.axhline(1.0, color="r", ls=":", lw=0.8, label="1 mm")
        a2 = a.twinx()
        a2.fill_between(t, 0, trace["adapt_gate"], color="C1", alpha=0.15, step="post", label="adapting (contact)")
        a2.set_yticks([])
        a.set_ylabel("lateral offset error [mm]")
        a.set_xlabel("time [s]")
        a.legend(fontsize=7, loc="lower left")
        a.set_title("identification")
    else:
        a = ax[2, 0]
        a.plot(t, np.linalg.norm(trace["eps_w"], axis=1), "k", lw=0.6)
        a.set_ylabel("|W eps|")
        a.set_xlabel("time [s]")
        a.set_title("prediction error (W-scaled)")
        for a in (ax[2, 1], ax[2, 2]):
            a.axis("off")
    done = "COMPLETED" if summary.get("program") == "excite" else "SEATED"
    status = done if summary["success"] else f"FAILED ({summary['failure']})"
    fig.suptitle(
        f"kinadapt online - features={summary['features']}, law={summary['law']}, seed={summary['seed']}: {status}"
    )
    return fig


def save_figure(fig: plt.Figure, path: Path) -> None:
    fig.savefig(path, dpi=120)
    plt.close(fig)
