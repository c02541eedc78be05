"""TensorBoard logging: the same tag names for every features type, so runs overlay."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from kinadapt_nn.sensing import CHANNEL_NAMES
from kinadapt_nn.trace import Trace

#: TensorBoard sample period [s] (the trace itself keeps every step)
TB_PERIOD_S = 0.01


def write_tensorboard(log_dir: Path, trace: Trace, summary: dict, hparams: dict, figure=None) -> None:
    """Scalars at 100 Hz (step = simulated milliseconds), the summary as hparams, the figure."""
    from torch.utils.tensorboard import SummaryWriter

    t = trace["t_s"]
    if len(t) == 0:
        return
    dt = float(trace.meta.get("dt_s", t[1] - t[0] if len(t) > 1 else 1e-3))
    stride = max(1, int(round(TB_PERIOD_S / dt)))
    idx = np.arange(0, len(t), stride)
    steps = np.round(t[idx] * 1e3).astype(int)
    s, eps = trace["s"], trace["s_dot_meas"] - trace["s_dot_pred"]
    series: dict[str, np.ndarray] = {}
    for i, name in enumerate(CHANNEL_NAMES):
        series[f"sensor/{name}"] = s[idx, i]
        series[f"pred_error/{name}"] = eps[idx, i]
    series["truth/tip_depth_m"] = trace["truth_tip_depth_m"][idx]
    series["truth/contact_force_N"] = trace["truth_contact_force_N"][idx]
    series["value/V_J"] = trace["V"][idx]
    series["stability/lambda_min"] = trace["lambda_min"][idx]
    # the same meaning for every features type: the Jacobian error (evaluation) and theta's
    # remaining uncertainty (fraction of the prior; kalman law); theta itself as a histogram
    series["learning/jacobian_rel_error"] = trace["truth_jacobian_rel_error"][idx]
    if "theta_uncertainty" in trace.arrays:
        series["learning/theta_uncertainty"] = trace["theta_uncertainty"][idx]
    hist_stride = max(1, int(round(0.1 / dt)))
    for name in ("depth_ok", "force_ok", "moment_ok"):
        series[f"success/{name}"] = trace[name][idx].astype(float)
    with SummaryWriter(log_dir=str(log_dir)) as wr:
        for tag, vals in series.items():
            for st, v in zip(steps, vals):
                if np.isfinite(v):
                    wr.add_scalar(tag, float(v), int(st))
        theta = trace["theta"]
        for i in range(0, len(t), hist_stride):  # theta as a histogram at 10 Hz (not p charts)
            wr.add_histogram("learning/theta", theta[i], int(round(t[i] * 1e3)))
        if figure is not None:
            wr.add_figure("rollout", figure, close=False)
        metrics = {
            f"summary/{k}": float(v)
            for k, v in summary.items()
            if isinstance(v, (int, float)) and not isinstance(v, bool) and v is not None
        }
        metrics["summary/success"] = float(summary["success"])
        wr.add_hparams({k: v for k, v in hparams.items()}, metrics, run_name=".")
