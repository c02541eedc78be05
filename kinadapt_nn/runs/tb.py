"""TensorBoard logging: the same tag names for every features type, so runs overlay.

Written with TensorBoard's own event writer and summaries (``runio.EventWriter``), not
``torch.utils.tensorboard``: importing torch costs seconds and the episode never needs it
(nothing here imports torch or tensorflow -- ``tests/app/test_config_cli.py`` checks the
``online`` path).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from kinadapt_nn.runio import EventWriter
from kinadapt_nn.sensing import CHANNEL_NAMES
from kinadapt_nn.trace import Trace

#: TensorBoard sample period of the scalars [s] (the trace itself keeps every step)
TB_PERIOD_S = 0.01
#: sample period of the theta histogram [s]
HIST_PERIOD_S = 0.1


def tensorboard_series(trace: Trace) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The scalars TensorBoard shows, sampled at ``TB_PERIOD_S``: (steps in simulated ms, tag -> values)."""
    t = trace["t_s"]
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
    for name in ("depth_ok", "force_ok", "moment_ok"):
        series[f"success/{name}"] = trace[name][idx].astype(float)
    if "monitor_z" in trace.arrays:  # the live monitor: residual / noise sd per channel (NaN: not judged)
        for i, name in enumerate(("F_x", "F_y", "F_z", "M_x", "M_y", "M_z")):  # (kinadapt_nn.monitor.shapes.CHANNELS)
            series[f"monitor/residual_over_noise_{name}"] = trace["monitor_z"][idx, i].astype(float)
    return steps, series


def write_monitor_events(log_dir: Path, summary: dict) -> None:
    """The live monitor's events as text (tag ``monitor/events``, step = the event's time in ms)."""
    mon = summary.get("monitor")
    if not mon:
        return
    with EventWriter(log_dir) as wr:
        lines = [e["line"] for e in mon["events"]] or ["no event: the wrench stayed within the model's noise"]
        for e, line in zip(mon["events"] or [None], lines):
            step = int(round(1e3 * e["t_s"])) if e else 0
            wr.add_text("monitor/events", line, step)


def write_tensorboard(log_dir: Path, trace: Trace, summary: dict, hparams: dict, figure=None) -> None:
    """Scalars at 100 Hz (step = simulated milliseconds), theta as a histogram at 10 Hz, the
    summary as hparams, and ``figure`` (a matplotlib figure) if given; a saved PNG is added by
    ``write_tensorboard_figure``."""
    t = trace["t_s"]
    if len(t) == 0:
        return
    steps, series = tensorboard_series(trace)
    dt = float(trace.meta.get("dt_s", t[1] - t[0] if len(t) > 1 else 1e-3))
    hist_stride = max(1, int(round(HIST_PERIOD_S / dt)))
    tags = list(series)
    table = np.column_stack([series[k] for k in tags]).astype(float)  # (steps, tags)
    metrics = {
        f"summary/{k}": float(v)
        for k, v in summary.items()
        if isinstance(v, (int, float)) and not isinstance(v, bool) and v is not None
    }
    metrics["summary/success"] = float(summary["success"])
    with EventWriter(log_dir) as wr:
        for st, row in zip(steps.tolist(), table):
            wr.add_scalars_at(st, dict(zip(tags, row.tolist())))
        theta = trace["theta"]
        for i in range(0, len(t), hist_stride):  # theta as a histogram (not p charts)
            wr.add_histogram("learning/theta", theta[i], int(round(t[i] * 1e3)))
        if figure is not None:  # a matplotlib figure: rendered here
            import io

            buf = io.BytesIO()
            figure.savefig(buf, format="png", dpi=100)
            png = buf.getvalue()
            width, height = (int.from_bytes(png[16 + 4 * k:20 + 4 * k], "big") for k in range(2))  # IHDR
            wr.add_png("rollout", png, height, width)
        wr.add_hparams(dict(hparams), metrics)


def write_tensorboard_figure(log_dir: Path, png_path: Path, tag: str = "rollout") -> None:
    """A saved PNG figure as a TensorBoard image (embedded as is: no second rendering)."""
    png = Path(png_path).read_bytes()
    width, height = (int.from_bytes(png[16 + 4 * k:20 + 4 * k], "big") for k in range(2))  # the IHDR chunk
    with EventWriter(log_dir) as wr:
        wr.add_png(tag, png, height, width)


def write_cell_tensorboard(log_dir: Path, summary: dict) -> None:
    """A work cell's learning curve: ``cell/jacobian_error_median`` (and ``cell/seated``) with
    step = insertion (0 = before the first), so runs of every features type overlay."""
    cell = summary.get("cell")
    if not cell:
        return
    with EventWriter(log_dir) as wr:
        for k, e in enumerate(cell["jacobian_error_cell_median"]):
            vals = {"cell/jacobian_error_median": float(e)}
            if k:
                row = summary["insertions"][k - 1]
                vals["cell/seated"] = float(row["success"])
                if row.get("jacobian_error_cell_p90") is not None:
                    vals["cell/jacobian_error_p90"] = float(row["jacobian_error_cell_p90"])
            wr.add_scalars_at(k, vals)
