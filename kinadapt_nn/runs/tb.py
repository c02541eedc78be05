"""TensorBoard logging: the same tag names for every features type, so runs overlay; a run's
TensorBoard (``write_run``: trace, work cell, monitor events, figure, hparams) is one event file.

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
    stride = max(1, int(round(TB_PERIOD_S / _dt_s(trace))))
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


def write_run(log_dir: Path, trace: Trace, summary: dict, hparams: dict, png_path: Path | None = None) -> None:
    """A run's TensorBoard, one event file: the trace's scalars at 100 Hz (step = simulated
    milliseconds) and theta as a histogram at 10 Hz; a work cell's learning curve
    (``cell/jacobian_error_median``, ``cell/seated``, ``cell/jacobian_error_p90``; step = insertion,
    0 = before the first, so runs of every features type overlay); the live monitor's events as
    text (``monitor/events``, step = the event's time in ms); the saved figure ``png_path`` as the
    image ``rollout`` (embedded as is: no second rendering); the summary as hparams. What is
    written is gathered first, then written in one go."""
    t = trace["t_s"]
    steps, series = tensorboard_series(trace) if len(t) else (np.zeros(0, int), {})
    tags = list(series)
    table = np.column_stack([series[k] for k in tags]).astype(float) if tags else np.zeros((0, 0))  # (steps, tags)
    hist = range(0, len(t), max(1, int(round(HIST_PERIOD_S / _dt_s(trace)))))  # theta as a histogram, not p charts
    cell, texts = _cell_curve(summary), _monitor_events(summary)
    png = None if png_path is None else _png(Path(png_path))
    metrics = {f"summary/{k}": float(v) for k, v in summary.items()
               if isinstance(v, (int, float)) and not isinstance(v, bool)}
    metrics["summary/success"] = float(summary["success"])
    with EventWriter(log_dir) as wr:
        for st, row in zip(steps.tolist(), table):
            wr.add_scalars_at(st, dict(zip(tags, row.tolist())))
        for i in hist:
            wr.add_histogram("learning/theta", trace["theta"][i], int(round(t[i] * 1e3)))
        for k, vals in enumerate(cell):
            wr.add_scalars_at(k, vals)
        for step, line in texts:
            wr.add_text("monitor/events", line, step)
        if png is not None:
            data, (width, height) = png
            wr.add_png("rollout", data, height, width)
        wr.add_hparams(dict(hparams), metrics)


def _dt_s(trace: Trace) -> float:
    """The trace's control period [s] (its meta, else its first step; 1 ms for a one-row trace)."""
    t = trace["t_s"]
    return float(trace.meta.get("dt_s", t[1] - t[0] if len(t) > 1 else 1e-3))


def _png(path: Path) -> tuple[bytes, tuple[int, int]]:
    """A saved PNG's bytes (embedded as they are: no second rendering) and its (width, height) [px],
    read by Pillow (matplotlib's own image library) from the file's header."""
    from PIL import Image

    with Image.open(path) as im:
        size = im.size
    return path.read_bytes(), size


def _cell_curve(summary: dict) -> list[dict[str, float]]:
    """A work cell's scalars per insertion (0 = before the first): the Jacobian error, and after an
    insertion whether it seated and the p90 error; empty for one insertion."""
    cell = summary.get("cell")
    if not cell:
        return []
    rows = []
    for k, e in enumerate(cell["jacobian_error_cell_median"]):
        vals = {"cell/jacobian_error_median": float(e)}
        if k:
            row = summary["insertions"][k - 1]
            vals["cell/seated"] = float(row["success"])
            if row.get("jacobian_error_cell_p90") is not None:
                vals["cell/jacobian_error_p90"] = float(row["jacobian_error_cell_p90"])
        rows.append(vals)
    return rows


def _monitor_events(summary: dict) -> list[tuple[int, str]]:
    """The live monitor's event lines as (step = the event's time in ms, line), or the line saying
    there was none; empty without a monitor."""
    mon = summary.get("monitor")
    if not mon:
        return []
    if not mon["events"]:
        return [(0, "no event: the wrench stayed within the model's noise")]
    return [(int(round(1e3 * e["t_s"])), e["line"]) for e in mon["events"]]
