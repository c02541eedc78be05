"""TensorBoard logging: the same tag names for every features type, so runs overlay.

Written with TensorBoard's own event writer and protos (``EventWriter``), not
``torch.utils.tensorboard``: importing torch costs seconds and the episode never needs it
(nothing here imports torch or tensorflow -- ``tests/test_config_cli.py`` checks the
``online`` path).
"""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

import numpy as np

from kinadapt_nn.sensing import CHANNEL_NAMES
from kinadapt_nn.trace import Trace

#: TensorBoard sample period of the scalars [s] (the trace itself keeps every step)
TB_PERIOD_S = 0.01
#: sample period of the theta histogram [s]
HIST_PERIOD_S = 0.1
#: bins of one theta histogram
HIST_BINS = 30


class EventWriter:
    """A TensorBoard event file in ``log_dir``: scalars, histograms, PNG images, hparams.

    A drop-in for the few ``SummaryWriter`` methods the package uses (``add_scalar``,
    ``add_histogram``, ``add_hparams``) plus ``add_scalars_at`` (many tags in one event) and
    ``add_png`` (an already encoded image). Use as a context manager (flushes and closes)."""

    def __init__(self, log_dir: Path | str):
        from tensorboard.compat.proto import event_pb2, summary_pb2
        from tensorboard.summary.writer.event_file_writer import EventFileWriter

        Path(log_dir).mkdir(parents=True, exist_ok=True)
        self._ev, self._pb = event_pb2, summary_pb2
        self._writer = EventFileWriter(str(log_dir))

    def __enter__(self) -> EventWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self._writer.close()

    def _add(self, values: list, step: int, wall_time: float | None = None) -> None:
        import time

        ev = self._ev.Event(wall_time=time.time() if wall_time is None else wall_time, step=int(step),
                            summary=self._pb.Summary(value=values))
        self._writer.add_event(ev)

    def add_scalar(self, tag: str, value: float, step: int) -> None:
        self._add([self._pb.Summary.Value(tag=tag, simple_value=float(value))], step)

    def add_scalars_at(self, step: int, values: Mapping[str, float]) -> None:
        """Every (tag, value) of ``values`` at one step, in one event (non-finite values skipped)."""
        vals = [self._pb.Summary.Value(tag=k, simple_value=float(v)) for k, v in values.items() if np.isfinite(v)]
        if vals:
            self._add(vals, step)

    def add_histogram(self, tag: str, values: np.ndarray, step: int, bins: int = HIST_BINS) -> None:
        """``values`` (any shape) as a histogram of ``bins`` equal bins over [min, max]."""
        v = np.ravel(np.asarray(values, dtype=float))
        v = v[np.isfinite(v)]
        if not v.size:
            return
        lo, hi = float(v.min()), float(v.max())
        if hi - lo <= 1e-12 * max(abs(lo), abs(hi), 1e-300):  # one value: a narrow bin around it
            half = 0.5 * max(abs(lo) * 1e-3, 1e-12)
            lo, hi = lo - half, hi + half
        counts, limits = np.histogram(v, bins=bins, range=(lo, hi))
        # TensorBoard stores right bucket limits only: an empty bucket first keeps the left edge
        hist = self._pb.HistogramProto(min=float(v.min()), max=float(v.max()), num=float(v.size),
                                       sum=float(v.sum()), sum_squares=float(v @ v),
                                       bucket_limit=limits.tolist(), bucket=[0.0, *counts.tolist()])
        self._add([self._pb.Summary.Value(tag=tag, histo=hist)], step)

    def add_png(self, tag: str, png: bytes, height: int, width: int, step: int = 0) -> None:
        """An encoded PNG image (e.g. the bytes of a saved figure: no second rendering)."""
        img = self._pb.Summary.Image(height=int(height), width=int(width), colorspace=4, encoded_image_string=png)
        self._add([self._pb.Summary.Value(tag=tag, image=img)], step)

    def add_hparams(self, hparams: Mapping[str, float | int | str | bool], metrics: Mapping[str, float]) -> None:
        """The run's hyperparameters and final metrics for TensorBoard's HParams tab (the
        experiment, session-start and session-end records, as ``SummaryWriter.add_hparams``
        writes them), and each metric as a scalar at step 0."""
        from tensorboard.plugins.hparams import api_pb2, metadata, plugin_data_pb2

        ssi = plugin_data_pb2.SessionStartInfo()
        infos = []
        for k, v in hparams.items():
            if isinstance(v, bool):
                ssi.hparams[k].bool_value, kind = v, "DATA_TYPE_BOOL"
            elif isinstance(v, (int, float)):
                ssi.hparams[k].number_value, kind = float(v), "DATA_TYPE_FLOAT64"
            elif isinstance(v, str):
                ssi.hparams[k].string_value, kind = v, "DATA_TYPE_STRING"
            else:
                raise TypeError(f"hparam {k!r} is a {type(v).__name__}; use int, float, str or bool")
            infos.append(api_pb2.HParamInfo(name=k, type=api_pb2.DataType.Value(kind)))
        exp = api_pb2.Experiment(hparam_infos=infos,
                                 metric_infos=[api_pb2.MetricInfo(name=api_pb2.MetricName(tag=k)) for k in metrics])
        sei = plugin_data_pb2.SessionEndInfo(status=api_pb2.Status.Value("STATUS_SUCCESS"))
        for tag, data in ((metadata.EXPERIMENT_TAG, plugin_data_pb2.HParamsPluginData(experiment=exp)),
                          (metadata.SESSION_START_INFO_TAG, plugin_data_pb2.HParamsPluginData(session_start_info=ssi)),
                          (metadata.SESSION_END_INFO_TAG, plugin_data_pb2.HParamsPluginData(session_end_info=sei))):
            self._add([self._pb.Summary.Value(tag=tag, metadata=metadata.create_summary_metadata(data))], 0)
        self.add_scalars_at(0, metrics)


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
    return steps, series


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
