"""TensorBoard output and the ``kinadapt online`` import diet: the adjoint default path runs
without torch (matplotlib it imports for its figure), and its event files read back in
TensorBoard with the tags, steps and values of the trace."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]

#: modules the online path with adjoint features must not import (numba itself imports ``scipy``
#: and, for np.linalg inside the controller's kernels, ``scipy.linalg.cython_blas/lapack``;
#: TensorBoard's writer loads its TensorFlow stub, not TensorFlow)
NOT_IMPORTED = ("torch", "scipy.stats", "scipy.optimize", "scipy.signal", "scipy.spatial", "pyarrow", "rosbags",
                "tensorflow", "kinadapt_nn.effects.builtin")  # (the built-in effects: only when model.effects names one)

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
    from tensorboard.util import tensor_util

    from kinadapt_nn.runs.tb import TB_PERIOD_S
    from kinadapt_nn.trace import Trace

    out = tmp_path / "run"
    proc = subprocess.run([sys.executable, "-c", _PROBE.format(mods=NOT_IMPORTED), str(out)], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "IMPORTED \n" in proc.stdout  # none of them
    assert (out / "rollout.png").stat().st_size > 10_000

    tr = Trace.load(out / "trace.npz")
    assert len(list((out / "tb").iterdir())) == 1  # the run's TensorBoard, one event file (runs.tb.write_run)
    ea = EventAccumulator(str(out / "tb"), size_guidance={"scalars": 0, "tensors": 0, "images": 0})
    ea.Reload()
    tags = ea.Tags()
    for tag in ("sensor/d", "sensor/F_lat_x", "pred_error/M_z", "truth/tip_depth_m", "value/V_J",
                "stability/lambda_min", "learning/jacobian_rel_error", "success/depth_ok", "summary/success"):
        assert tag in tags["scalars"], tag
    assert "learning/theta" in tags["tensors"]
    assert ea.SummaryMetadata("learning/theta").plugin_data.plugin_name == "histograms"
    assert tags["images"] == ["rollout"]
    # scalars at TB_PERIOD_S, step = simulated ms, values those of the trace
    d = ea.Scalars("sensor/d")
    steps = np.array([e.step for e in d])
    stride = int(round(TB_PERIOD_S / tr.meta["dt_s"]))
    idx = np.arange(0, len(tr), stride)
    np.testing.assert_array_equal(steps, np.round(tr["t_s"][idx] * 1e3).astype(int))
    np.testing.assert_allclose([e.value for e in d], tr["s"][idx, 0], rtol=1e-6, atol=1e-9)
    # theta as a histogram: every sample holds the p entries of theta, within [min, max]
    h = ea.Tensors("learning/theta")
    assert len(h) >= 9
    first = tensor_util.make_ndarray(h[0].tensor_proto)  # (buckets, 3): left edge, right edge, count
    theta0 = tr["theta"][0]
    assert first[:, 2].sum() == theta0.size
    assert np.isclose(first[0, 0], theta0.min()) and np.isclose(first[-1, 1], theta0.max())
    # the hparams plugin records (what the HParams tab reads)
    assert {"_hparams_/experiment", "_hparams_/session_start_info"} <= set(ea.summary_metadata)
    img = ea.Images("rollout")[0]
    assert img.width == 1680 and img.height == 1200


def _events(log_dir: Path) -> list:
    """The events of the one event file in ``log_dir`` as written, read by TensorBoard's own
    loader (the legacy one: it leaves ``simple_value`` as it is, not migrated to a tensor)."""
    from tensorboard.backend.event_processing.event_file_loader import LegacyEventFileLoader

    (path,) = log_dir.iterdir()
    return list(LegacyEventFileLoader(str(path)).Load())


def test_hparams_records_are_tensorboards(tmp_path):
    """The three HParams records under TensorBoard's tags, parsed back by its HParams plugin to
    the values, their types and the metrics; the metrics also as scalars at step 0."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
    from tensorboard.plugins.hparams import api_pb2, metadata

    from kinadapt_nn.runio import EventWriter

    with EventWriter(tmp_path) as wr:
        wr.add_hparams({"features": "rbf", "seed": 3, "fused": True, "gain": 0.5}, {"summary/seat_time_s": 4.5})
    ea = EventAccumulator(str(tmp_path))
    ea.Reload()
    meta = ea.summary_metadata
    assert {metadata.EXPERIMENT_TAG, metadata.SESSION_START_INFO_TAG, metadata.SESSION_END_INFO_TAG} <= set(meta)
    assert all(meta[t].plugin_data.plugin_name == metadata.PLUGIN_NAME
               for t in (metadata.EXPERIMENT_TAG, metadata.SESSION_START_INFO_TAG, metadata.SESSION_END_INFO_TAG))
    start = metadata.parse_session_start_info_plugin_data(meta[metadata.SESSION_START_INFO_TAG].plugin_data.content)
    assert start.hparams["features"].string_value == "rbf" and start.hparams["seed"].number_value == 3.0
    assert start.hparams["fused"].bool_value is True and start.hparams["gain"].number_value == 0.5
    assert start.group_name == ""  # each run its own group (TensorBoard groups by the session's name)
    exp = metadata.parse_experiment_plugin_data(meta[metadata.EXPERIMENT_TAG].plugin_data.content)
    assert [m.name.tag for m in exp.metric_infos] == ["summary/seat_time_s"]
    assert {h.name: api_pb2.DataType.Name(h.type) for h in exp.hparam_infos} == {
        "features": "DATA_TYPE_STRING", "seed": "DATA_TYPE_FLOAT64", "fused": "DATA_TYPE_BOOL",
        "gain": "DATA_TYPE_FLOAT64"}
    end = metadata.parse_session_end_info_plugin_data(meta[metadata.SESSION_END_INFO_TAG].plugin_data.content)
    assert end.status == api_pb2.STATUS_SUCCESS
    (seat,) = ea.Scalars("summary/seat_time_s")
    assert (seat.step, seat.value) == (0, 4.5)


def test_hparams_refuse_other_types(tmp_path):
    import pytest

    from kinadapt_nn.runio import EventWriter

    with EventWriter(tmp_path) as wr, pytest.raises(TypeError, match="'shape' is a list; use int, float, str or bool"):
        wr.add_hparams({"shape": [1, 2]}, {})


def test_scalar_events_read_back(tmp_path):
    """``add_scalars_at`` writes one event per step, read back by TensorBoard's loader with its
    wall time, step and (tag, value)s -- steps 0, large and negative, empty and non-ASCII tags,
    -0.0, values beyond float32 (inf), non-finite values (left out), a step with none (no event)."""
    from kinadapt_nn.runio import EventWriter

    cases = [(0, {"a": 1.5}), (7, {"sensor/d": -0.0, "x": 1e300, "y": -1e300}), (2**40 + 3, {"é/ü": 3.25e-12}),
             (-5, {"": 2.0, "b": float("nan"), "c": float("inf"), "d": np.float64(0.1)}), (8, {"n": float("nan")}),
             (300, {"q": 0.0})]
    with EventWriter(tmp_path) as wr:
        for step, vals in cases:
            wr.add_scalars_at(step, vals, wall_time=1234.5)
        wr.add_scalar("single", 2.5, 9)
    first, *events = _events(tmp_path)
    assert first.file_version == "brain.Event:2"
    got = [(e.step, e.wall_time, [(v.tag, v.simple_value) for v in e.summary.value]) for e in events[:-1]]
    f32 = [float(np.float32(v)) for v in (3.25e-12, 0.1)]
    assert got == [(0, 1234.5, [("a", 1.5)]),
                   (7, 1234.5, [("sensor/d", -0.0), ("x", float("inf")), ("y", -float("inf"))]),
                   (2**40 + 3, 1234.5, [("é/ü", f32[0])]),
                   (-5, 1234.5, [("", 2.0), ("d", f32[1])]),
                   (300, 1234.5, [("q", 0.0)])]
    assert np.signbit(events[1].summary.value[0].simple_value)  # -0.0 kept
    assert (events[-1].step, [(v.tag, v.simple_value) for v in events[-1].summary.value]) == (9, [("single", 2.5)])


def test_histogram_and_image_read_back(tmp_path):
    """A histogram (TensorBoard's buckets: counts and range) and a PNG image read back by TensorBoard's accumulator."""
    import pytest
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
    from tensorboard.util import tensor_util

    from kinadapt_nn.runio import HIST_BINS, EventWriter

    values = np.array([[0.0, 1.0, 2.0], [3.0, np.nan, 4.0]])
    with EventWriter(tmp_path) as wr:
        wr.add_histogram("learning/theta", values, 20)
        wr.add_histogram("empty", np.array([np.nan]), 20)  # nothing finite: no event
        wr.add_png("rollout", b"\x89PNG-bytes", height=3, width=4, step=2)
    ea = EventAccumulator(str(tmp_path), size_guidance={"tensors": 0, "images": 0})
    ea.Reload()
    assert ea.Tags()["tensors"] == ["learning/theta"]
    (h,) = ea.Tensors("learning/theta")
    assert h.step == 20 and ea.SummaryMetadata("learning/theta").plugin_data.plugin_name == "histograms"
    edges = tensor_util.make_ndarray(h.tensor_proto)  # (HIST_BINS, 3): left edge, right edge, count
    assert edges.shape == (HIST_BINS, 3) and edges[:, 2].sum() == 5 and (edges[0, 0], edges[-1, 1]) == (0.0, 4.0)
    np.testing.assert_allclose(edges[1:, 0], edges[:-1, 1])  # adjacent buckets
    centres = 0.5 * (edges[:, 0] + edges[:, 1])
    assert np.average(centres, weights=edges[:, 2]) == pytest.approx(2.0, abs=4.0 / HIST_BINS)  # the mean of 0..4
    (img,) = ea.Images("rollout")
    assert (img.step, img.height, img.width, img.encoded_image_string) == (2, 3, 4, b"\x89PNG-bytes")
