"""Run folders: written completely or not at all; TensorBoard event files (``EventWriter``, on
TensorBoard's own ``EventFileWriter``).

Everything is written into a sibling staging folder; only when all files are in place is
it renamed to the requested name. An existing folder is refused unless ``overwrite`` is
set, and even then it is replaced only after the new run has been written.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterator, Mapping

import numpy as np

from kinadapt_nn.errors import OutputExistsError


def check_output_dir(out: Path, overwrite: bool) -> None:
    """Refuse an existing output folder without ``overwrite`` (before any work is done)."""
    if out.exists() and not overwrite:
        raise OutputExistsError(f"output folder '{out}' already exists (pass --overwrite or choose another --out)")
    if out.exists() and not out.is_dir():
        raise OutputExistsError(f"output path '{out}' exists and is not a folder")


@contextmanager
def staged_output(out: Path, overwrite: bool) -> Iterator[Path]:
    """Yield a staging folder; on success it becomes ``out``; on error it is removed."""
    out = Path(out)
    check_output_dir(out, overwrite)
    out.parent.mkdir(parents=True, exist_ok=True)
    stage = out.parent / f".{out.name}.partial-{os.getpid()}"
    if stage.exists():
        shutil.rmtree(stage)
    stage.mkdir()
    try:
        yield stage
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        raise
    old = None
    if out.exists():
        old = out.parent / f".{out.name}.old-{os.getpid()}"
        os.replace(out, old)
    os.replace(stage, out)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def atomic_write(path: Path, write: Callable[[str], None], suffix: str = ".tmp") -> None:
    """Write a file atomically: ``write(tmp_path)`` fills a temp file beside ``path``, which is
    then renamed over it; on any error the temp file is removed and ``path`` is untouched."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=suffix)
    os.close(fd)
    try:
        write(tmp)
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def write_text_atomic(path: Path, text: str) -> None:
    """``atomic_write`` for text."""
    atomic_write(path, lambda tmp: Path(tmp).write_text(text))


def write_json(path: Path, obj: dict) -> None:
    path.write_text(json.dumps(obj, indent=2, sort_keys=False) + "\n")


#: bins of one histogram (TensorBoard)
HIST_BINS = 30


def _hparam_type(name: str, value) -> str:
    """The HParams ``DataType`` name of a hyperparameter's value (bool before int: a bool is an int)."""
    if isinstance(value, bool):
        return "DATA_TYPE_BOOL"
    if isinstance(value, (int, float)):
        return "DATA_TYPE_FLOAT64"
    if isinstance(value, str):
        return "DATA_TYPE_STRING"
    raise TypeError(f"hparam {name!r} is a {type(value).__name__}; use int, float, str or bool")


class EventWriter:
    """A TensorBoard event file in ``log_dir``: scalars, histograms, PNG images, text, hparams.

    TensorBoard's own summary writer does the work: its ``EventFileWriter`` (the file, its name,
    the records and an asynchronous flush; what ``torch.utils.tensorboard.SummaryWriter`` writes
    through, without importing torch: ``benchmarks/tb_import_cost.py``) and its plugins'
    summary builders (``histogram_pb``: TensorBoard's own binning; ``text_pb``; ``hparams_pb``).
    The methods are ``SummaryWriter``'s (``add_scalar``, ``add_histogram``, ``add_text``,
    ``add_hparams``) plus ``add_scalars_at`` (many tags in one event) and ``add_png`` (an already
    encoded image). Use as a context manager (closes the file)."""

    def __init__(self, log_dir: Path | str):
        from tensorboard.compat.proto import event_pb2, summary_pb2
        from tensorboard.summary.writer.event_file_writer import EventFileWriter

        Path(log_dir).mkdir(parents=True, exist_ok=True)
        self._ev, self._pb = event_pb2, summary_pb2
        self._file = EventFileWriter(str(log_dir))
        self._closed = False

    def __enter__(self) -> EventWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        if not self._closed:
            self._file.close()  # flushes the queue and closes the file
            self._closed = True

    def _add(self, summary, step: int, wall_time: float | None = None) -> None:
        ev = self._ev.Event(wall_time=time.time() if wall_time is None else wall_time, step=int(step), summary=summary)
        self._file.add_event(ev)

    def add_scalar(self, tag: str, value: float, step: int) -> None:
        self._add(self._pb.Summary(value=[self._pb.Summary.Value(tag=tag, simple_value=float(value))]), step)

    def add_scalars_at(self, step: int, values: Mapping[str, float], wall_time: float | None = None) -> None:
        """Every (tag, value) of ``values`` at one step, in one event (non-finite values skipped)."""
        floats = {k: float(v) for k, v in values.items()}
        finite = [self._pb.Summary.Value(tag=k, simple_value=v) for k, v in floats.items() if math.isfinite(v)]
        if finite:
            self._add(self._pb.Summary(value=finite), step, wall_time)

    def add_histogram(self, tag: str, values: np.ndarray, step: int, bins: int = HIST_BINS) -> None:
        """The finite entries of ``values`` (any shape) as a histogram of ``bins`` buckets
        (TensorBoard's ``histogram_pb``); nothing when none is finite."""
        from tensorboard.plugins.histogram.summary_v2 import histogram_pb

        v = np.ravel(np.asarray(values, dtype=float))
        v = v[np.isfinite(v)]
        if v.size:
            self._add(histogram_pb(tag, v, buckets=bins), step)

    def add_text(self, tag: str, text: str, step: int) -> None:
        """A text record (TensorBoard's ``text_pb``)."""
        from tensorboard.plugins.text.summary_v2 import text_pb

        self._add(text_pb(tag, text), step)

    def add_png(self, tag: str, png: bytes, height: int, width: int, step: int = 0) -> None:
        """An encoded PNG image (e.g. the bytes of a saved figure: no second rendering)."""
        img = self._pb.Summary.Image(height=int(height), width=int(width), colorspace=4, encoded_image_string=png)
        self._add(self._pb.Summary(value=[self._pb.Summary.Value(tag=tag, image=img)]), step)

    def add_hparams(self, hparams: Mapping[str, float | int | str | bool], metrics: Mapping[str, float]) -> None:
        """The run's hyperparameters and final metrics for TensorBoard's HParams tab (the
        experiment, session-start and session-end records, as ``SummaryWriter.add_hparams``
        writes them), and each metric as a scalar at step 0."""
        from tensorboard.plugins.hparams import api_pb2, metadata, plugin_data_pb2, summary_v2

        def record(tag: str, data: plugin_data_pb2.HParamsPluginData):
            """The HParams plugin's record ``data`` under ``tag`` (as ``summary_v2`` writes one)."""
            return self._pb.Summary.Value(tag=tag, metadata=metadata.create_summary_metadata(data),
                                          tensor=metadata.NULL_TENSOR)

        infos = [api_pb2.HParamInfo(name=k, type=api_pb2.DataType.Value(_hparam_type(k, v))) for k, v in hparams.items()]
        exp = api_pb2.Experiment(hparam_infos=infos,
                                 metric_infos=[api_pb2.MetricInfo(name=api_pb2.MetricName(tag=k)) for k in metrics])
        self._add(self._pb.Summary(value=[record(metadata.EXPERIMENT_TAG,
                                                 plugin_data_pb2.HParamsPluginData(experiment=exp))]), 0)
        # the session-start record; an empty group name (trial_id): each run is a group of its own
        # in the HParams tab, not merged with others of equal hparams (summary_v2's default)
        self._add(summary_v2.hparams_pb(dict(hparams), trial_id=""), 0)
        end = plugin_data_pb2.SessionEndInfo(status=api_pb2.STATUS_SUCCESS, end_time_secs=time.time())
        self._add(self._pb.Summary(value=[record(metadata.SESSION_END_INFO_TAG,
                                                 plugin_data_pb2.HParamsPluginData(session_end_info=end))]), 0)
        self.add_scalars_at(0, metrics)
