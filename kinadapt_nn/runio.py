"""Run folders: written completely or not at all; TensorBoard event files (``EventWriter``).

Everything is written into a sibling staging folder; only when all files are in place is
it renamed to the requested name. An existing folder is refused unless ``overwrite`` is
set, and even then it is replaced only after the new run has been written.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import socket
import struct
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterator, Mapping

import google_crc32c
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
#: TensorBoard's HParams records: their tags and plugin-data version (``tensorboard.plugins.hparams.metadata``:
#: EXPERIMENT_TAG, SESSION_START_INFO_TAG, SESSION_END_INFO_TAG, PLUGIN_DATA_VERSION)
HPARAMS_TAGS = ("_hparams_/experiment", "_hparams_/session_start_info", "_hparams_/session_end_info")
HPARAMS_PLUGIN_DATA_VERSION = 0


def _masked_crc(data: bytes) -> int:
    """TFRecord's masked CRC-32C of ``data``."""
    crc = google_crc32c.value(data)
    return (((crc >> 15) | (crc << 17)) + 0xA282EAD8) & 0xFFFFFFFF


def _pb_varint(n: int) -> bytes:
    """A protobuf varint (int64: a negative ``n`` as its 64-bit two's complement, 10 bytes)."""
    if n < 0:
        n += 1 << 64
    out = bytearray()
    while n > 0x7F:
        out.append((n & 0x7F) | 0x80)
        n >>= 7
    out.append(n)
    return bytes(out)


def _pb_bytes(field: int, data: bytes) -> bytes:
    """A length-delimited protobuf field (string, bytes or message)."""
    return _pb_varint(field << 3 | 2) + _pb_varint(len(data)) + data


def _pb_float(v: float) -> bytes:
    """A protobuf ``float`` (32-bit little-endian), rounded from ``v`` as protobuf's C cast
    rounds it: beyond the float range, +-inf (where ``struct`` would refuse)."""
    try:
        return struct.pack("<f", v)
    except OverflowError:
        return struct.pack("<f", math.copysign(math.inf, v))


class EventWriter:
    """A TensorBoard event file in ``log_dir``: scalars, histograms, PNG images, hparams.

    A drop-in for the few ``SummaryWriter`` methods the package uses (``add_scalar``,
    ``add_histogram``, ``add_hparams``) plus ``add_scalars_at`` (many tags in one event) and
    ``add_png`` (an already encoded image). Use as a context manager (flushes and closes)."""

    def __init__(self, log_dir: Path | str):
        from tensorboard.compat.proto import event_pb2, summary_pb2

        Path(log_dir).mkdir(parents=True, exist_ok=True)
        self._ev, self._pb = event_pb2, summary_pb2
        # TensorBoard's own file name pattern; one file per writer (a counter keeps two apart)
        EventWriter._count += 1
        name = f"events.out.tfevents.{time.time():010.0f}.{socket.gethostname()}.{os.getpid()}.{EventWriter._count}"
        self._fh = open(Path(log_dir) / name, "wb")
        self._tag_head: dict[str, bytes] = {}  # tag -> its Summary.value field's bytes before the value
        self._write(self._ev.Event(wall_time=time.time(), file_version="brain.Event:2"))

    _count = 0

    def __enter__(self) -> EventWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        if not self._fh.closed:
            self._fh.close()

    def _write(self, event) -> None:
        """One TFRecord of the event proto ``event`` (:meth:`_write_bytes`)."""
        self._write_bytes(event.SerializeToString())

    def _write_bytes(self, data: bytes) -> None:
        """One TFRecord: length, its masked CRC-32C, the serialised event ``data``, its masked
        CRC-32C (CRC-32C in C, ``google_crc32c``: TensorBoard's pure-Python one was ~70 % of a
        run's event writing)."""
        header = struct.pack("<Q", len(data))
        self._fh.write(header + struct.pack("<I", _masked_crc(header)) + data + struct.pack("<I", _masked_crc(data)))

    def _add(self, values: list, step: int, wall_time: float | None = None) -> None:
        ev = self._ev.Event(wall_time=time.time() if wall_time is None else wall_time, step=int(step),
                            summary=self._pb.Summary(value=values))
        self._write(ev)

    def add_scalar(self, tag: str, value: float, step: int) -> None:
        self._add([self._pb.Summary.Value(tag=tag, simple_value=float(value))], step)

    def add_scalars_at(self, step: int, values: Mapping[str, float], wall_time: float | None = None) -> None:
        """Every (tag, value) of ``values`` at one step, in one event (non-finite values skipped).

        The event is encoded here, byte for byte what ``Event(wall_time, step, summary=Summary(
        value=[Summary.Value(tag, simple_value), ...])).SerializeToString()`` gives (tested): a
        run's ~500 scalar events took 30 of its 36 ms of TensorBoard writing through the protos."""
        parts = []
        for k, v in values.items():
            v = float(v)
            if not math.isfinite(v):
                continue
            head = self._tag_head.get(k)
            if head is None:  # Summary.value (1): a Summary.Value of tag (1) and simple_value (2, 32-bit)
                tag = _pb_bytes(1, k.encode()) if k else b""
                head = self._tag_head[k] = b"\x0a" + _pb_varint(len(tag) + 5) + tag + b"\x15"
            parts.append(head + _pb_float(v))
        if not parts:
            return
        summary = b"".join(parts)
        step = int(step)
        self._write_bytes(b"\x09" + struct.pack("<d", time.time() if wall_time is None else wall_time)  # wall_time (1)
                          + (b"\x10" + _pb_varint(step) if step else b"")  # step (2), omitted at 0
                          + b"\x2a" + _pb_varint(len(summary)) + summary)  # summary (5)

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

    def _hparams_metadata(self, data):
        """The ``SummaryMetadata`` of an ``HParamsPluginData`` record, as TensorBoard's
        ``plugins.hparams.metadata.create_summary_metadata`` makes it (plugin "hparams", the record
        at plugin-data version 0 as its content): written here because importing that module
        costs ~0.13 s (it loads TensorBoard's TensorFlow stub and fsspec) for four lines."""
        content = type(data)()
        content.CopyFrom(data)
        content.version = HPARAMS_PLUGIN_DATA_VERSION
        meta = self._pb.SummaryMetadata
        return meta(plugin_data=meta.PluginData(plugin_name="hparams", content=content.SerializeToString()))

    def add_hparams(self, hparams: Mapping[str, float | int | str | bool], metrics: Mapping[str, float]) -> None:
        """The run's hyperparameters and final metrics for TensorBoard's HParams tab (the
        experiment, session-start and session-end records, as ``SummaryWriter.add_hparams``
        writes them), and each metric as a scalar at step 0."""
        from tensorboard.plugins.hparams import api_pb2, plugin_data_pb2

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
        for tag, data in ((HPARAMS_TAGS[0], plugin_data_pb2.HParamsPluginData(experiment=exp)),
                          (HPARAMS_TAGS[1], plugin_data_pb2.HParamsPluginData(session_start_info=ssi)),
                          (HPARAMS_TAGS[2], plugin_data_pb2.HParamsPluginData(session_end_info=sei))):
            self._add([self._pb.Summary.Value(tag=tag, metadata=self._hparams_metadata(data))], 0)
        self.add_scalars_at(0, metrics)
