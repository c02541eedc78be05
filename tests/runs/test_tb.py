"""TensorBoard output and the ``kinadapt online`` import diet: the adjoint default path runs
without torch (or matplotlib: the figure is drawn in a second process), and its event files
read back in TensorBoard with the tags, steps and values of the trace."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]

#: modules the online path with adjoint features must not import (numba itself imports ``scipy``
#: and, for np.linalg inside the controller's kernels, ``scipy.linalg.cython_blas/lapack``)
NOT_IMPORTED = ("torch", "matplotlib", "scipy.stats", "scipy.optimize", "scipy.signal", "pyarrow", "rosbags",
                "tensorflow", "tensorboard.compat.tensorflow_stub")

_PROBE = """
import sys
from kinadapt_nn.app.cli import main
rc = main(["online", "--out", sys.argv[1], "--quiet", "--set", "run.duration_s=1.0"])
bad = [m for m in {mods!r} if m in sys.modules]
print("IMPORTED", ",".join(bad))
sys.exit(0 if rc in (0, 1) and not bad else 9)
"""


def test_online_adjoint_path_imports_no_torch_and_tensorboard_reads_it_back(tmp_path):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    from kinadapt_nn.runs.tb import TB_PERIOD_S
    from kinadapt_nn.trace import Trace

    out = tmp_path / "run"
    proc = subprocess.run([sys.executable, "-c", _PROBE.format(mods=NOT_IMPORTED), str(out)], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "IMPORTED \n" in proc.stdout  # none of them
    assert (out / "rollout.png").stat().st_size > 10_000  # drawn by the figure process

    tr = Trace.load(out / "trace.npz")
    ea = EventAccumulator(str(out / "tb"), size_guidance={"scalars": 0, "histograms": 0, "images": 0})
    ea.Reload()
    tags = ea.Tags()
    for tag in ("sensor/d", "sensor/F_lat_x", "pred_error/M_z", "truth/tip_depth_m", "value/V_J",
                "stability/lambda_min", "learning/jacobian_rel_error", "success/depth_ok", "summary/success"):
        assert tag in tags["scalars"], tag
    assert tags["histograms"] == ["learning/theta"]
    assert tags["images"] == ["rollout"]
    # scalars at TB_PERIOD_S, step = simulated ms, values those of the trace
    d = ea.Scalars("sensor/d")
    steps = np.array([e.step for e in d])
    stride = int(round(TB_PERIOD_S / tr.meta["dt_s"]))
    idx = np.arange(0, len(tr), stride)
    np.testing.assert_array_equal(steps, np.round(tr["t_s"][idx] * 1e3).astype(int))
    np.testing.assert_allclose([e.value for e in d], tr["s"][idx, 0], rtol=1e-6, atol=1e-9)
    # theta as a histogram: every sample holds the p entries of theta, within [min, max]
    h = ea.Histograms("learning/theta")
    assert len(h) >= 9
    first = h[0].histogram_value
    theta0 = tr["theta"][0]
    assert first.num == theta0.size and np.isclose(first.min, theta0.min()) and np.isclose(first.max, theta0.max())
    assert sum(first.bucket) == theta0.size
    # the hparams plugin records (what the HParams tab reads)
    assert {"_hparams_/experiment", "_hparams_/session_start_info"} <= set(ea.summary_metadata)
    img = ea.Images("rollout")[0]
    assert img.width == 1680 and img.height == 1200


def test_event_record_crc_is_tensorboards():
    """The event records' masked CRC-32C (google_crc32c) equals TensorBoard's own pure-Python one."""
    from tensorboard.compat.tensorflow_stub.pywrap_tensorflow import masked_crc32c

    from kinadapt_nn.runio import _masked_crc

    rng = np.random.default_rng(0)
    for n in (0, 1, 8, 33, 1000):
        data = rng.integers(0, 256, n, dtype=np.uint8).tobytes()
        assert _masked_crc(data) == masked_crc32c(data)


def test_hparams_records_are_tensorboards(tmp_path):
    """The three HParams records carry TensorBoard's own metadata (``create_summary_metadata``,
    its tags) byte for byte, and TensorBoard's HParams plugin parses them back to the values."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
    from tensorboard.plugins.hparams import metadata, plugin_data_pb2

    from kinadapt_nn.runio import HPARAMS_TAGS, EventWriter

    assert HPARAMS_TAGS == (metadata.EXPERIMENT_TAG, metadata.SESSION_START_INFO_TAG, metadata.SESSION_END_INFO_TAG)
    with EventWriter(tmp_path) as wr:
        data = plugin_data_pb2.HParamsPluginData(session_start_info=plugin_data_pb2.SessionStartInfo())
        data.session_start_info.hparams["law"].string_value = "kalman"
        assert wr._hparams_metadata(data).SerializeToString() == metadata.create_summary_metadata(data).SerializeToString()
        wr.add_hparams({"features": "rbf", "seed": 3, "fused": True}, {"summary/seat_time_s": 4.5})
    ea = EventAccumulator(str(tmp_path))
    ea.Reload()
    start = metadata.parse_session_start_info_plugin_data(
        ea.summary_metadata[metadata.SESSION_START_INFO_TAG].plugin_data.content)
    assert start.hparams["features"].string_value == "rbf" and start.hparams["seed"].number_value == 3.0
    assert start.hparams["fused"].bool_value is True
    exp = metadata.parse_experiment_plugin_data(ea.summary_metadata[metadata.EXPERIMENT_TAG].plugin_data.content)
    assert [m.name.tag for m in exp.metric_infos] == ["summary/seat_time_s"]
    assert ea.Scalars("summary/seat_time_s")[0].value == 4.5


def test_scalar_events_are_the_protos_bytes(tmp_path):
    """``add_scalars_at`` encodes its event itself: the bytes equal the TensorBoard protos'
    ``SerializeToString`` -- steps 0 (omitted), large and negative, empty and non-ASCII tags,
    -0.0, values beyond float32 (inf), non-finite values (left out) -- and read back."""
    from tensorboard.compat.proto import event_pb2, summary_pb2

    from kinadapt_nn.runio import EventWriter

    cases = [(0, {"a": 1.5}), (7, {"sensor/d": -0.0, "x": 1e300, "y": -1e300}), (2**40 + 3, {"é/ü": 3.25e-12}),
             (-5, {"": 2.0, "b": float("nan"), "c": float("inf"), "d": np.float64(0.1)}), (300, {"q": 0.0})]
    sent = []
    with EventWriter(tmp_path) as wr:
        n0 = wr._fh.tell()
        for step, vals in cases:
            wr.add_scalars_at(step, vals, wall_time=1234.5)
    written = next(tmp_path.iterdir()).read_bytes()
    for step, vals in cases:
        ev = event_pb2.Event(wall_time=1234.5, step=step, summary=summary_pb2.Summary(value=[
            summary_pb2.Summary.Value(tag=k, simple_value=float(v)) for k, v in vals.items() if np.isfinite(v)]))
        sent.append(ev.SerializeToString())
    pos, got = n0, []
    while pos < len(written):  # the TFRecords: length (8), its crc (4), data, the data's crc (4)
        size = int.from_bytes(written[pos:pos + 8], "little")
        got.append(written[pos + 12:pos + 12 + size])
        pos += 16 + size
    assert got == sent
    back = event_pb2.Event.FromString(got[1])
    assert [(v.tag, v.simple_value) for v in back.summary.value] == [("sensor/d", 0.0), ("x", float("inf")),
                                                                      ("y", -float("inf"))]
