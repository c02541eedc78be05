"""kinadapt diagnose: replay of raw logs, CSV import, residual analysis, outputs."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from kinadapt_nn.app.cli import main
from kinadapt_nn.config import load_config
from kinadapt_nn.diagnostics.importers import COLUMNS, read_csv_log, write_csv_log
from kinadapt_nn.diagnostics.residual import analyse, ljung_box, load_log, replay
from kinadapt_nn.runs.episode import run_episode
from kinadapt_nn.errors import KinadaptError
from kinadapt_nn.sensing import channel_metric


@pytest.fixture(scope="module")
def oracle_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("diag") / "run"
    assert main(["online", "--out", str(out), "--quiet", "--set", "run.features=oracle", "--set", "run.duration_s=2.5",
                 "--set", "run.tensorboard=false", "--set", "run.figure=false"]) in (0, 1)
    return out


def test_replay_reproduces_the_online_sensing_exactly(oracle_run):
    """Replaying the raw log (encoders + raw F/T only) through the frozen controller gives the
    online run's s, measured and predicted rates bit for bit: one pipeline, no truth."""
    from kinadapt_nn.trace import Trace

    tr = Trace.load(oracle_run / "trace.npz")
    cfg = load_config(oracle_run / "config.toml")
    rep = replay(load_log(oracle_run), cfg, np.asarray(cfg.tool.offset_f_m))
    np.testing.assert_array_equal(rep.s, tr["s"])
    np.testing.assert_array_equal(rep.s_dot_meas, tr["s_dot_meas"])
    np.testing.assert_array_equal(rep.s_dot_pred, tr["s_dot_pred"])


def test_csv_round_trip_and_column_errors(oracle_run, tmp_path):
    log = load_log(oracle_run)
    p = tmp_path / "log.csv"
    write_csv_log(p, log)
    back = read_csv_log(p)
    np.testing.assert_array_equal(back.q_rad, log.q_rad)
    np.testing.assert_array_equal(back.wrench_raw_f, log.wrench_raw_f)
    lines = p.read_text().splitlines()
    header = lines[0].split(",")
    bad = tmp_path / "missing.csv"
    bad.write_text("\n".join(",".join(x for j, x in enumerate(r.split(",")) if header[j] != "fz") for r in lines[:50]))
    with pytest.raises(KinadaptError, match="lacks column 'fz'"):
        read_csv_log(bad)
    garbled = tmp_path / "garbled.csv"
    rows = [r.split(",") for r in lines[:50]]
    rows[7][COLUMNS.index("q3")] = "abc"
    garbled.write_text("\n".join(",".join(r) for r in rows))
    with pytest.raises(KinadaptError, match="row 8: column 'q3' is not a number"):
        read_csv_log(garbled)


def test_residual_grows_with_a_wrong_offset_where_the_motion_excites_it():
    """Socket contact + dither: the residual with a 5 mm wrong offset is larger than with the true
    one, in the force/moment channels (the parametric part of eq. ft_pred)."""
    cfg = load_config(None, ["scene.contact_model=socket", "control.dither_rad_s=[0.05,0.05,0.05]",
                             "run.features=oracle", "run.duration_s=2.5", "run.progress=false"])
    r = run_episode(cfg)
    from kinadapt_nn.diagnostics.importers import RawLog

    tr = r.trace
    log = RawLog(tr["t_s"], tr["q_rad"], tr["qdot_rad_s"], tr["wrench_raw_f"], None, "mem")
    W = channel_metric(cfg.sensing)
    true = np.asarray(cfg.tool.offset_f_m)
    good = analyse(replay(log, cfg, true), W)["residual_rms_by_channel"]
    wrong = analyse(replay(log, cfg, true + np.array([0.004, -0.003, 0.0])), W)["residual_rms_by_channel"]
    assert wrong["F_lat_x"] > 2 * good["F_lat_x"] and wrong["F_lat_y"] > 2 * good["F_lat_y"]


def test_ljung_box_tells_white_from_correlated():
    rng = np.random.default_rng(0)
    white = rng.normal(size=4000)
    _, p_white = ljung_box(white)
    _, p_ar = ljung_box(np.convolve(white, np.ones(20) / 20, "same"))
    assert p_white > 0.01 and p_ar < 1e-6


def test_diagnose_cli_outputs(oracle_run, tmp_path, capsys):
    out = tmp_path / "diag"
    assert main(["diagnose", str(oracle_run), "--out", str(out)]) == 0
    d = json.loads((out / "diagnosis.json").read_text())
    for key in ("summary", "residual_rms_by_channel", "residual_rms_by_phase", "largest_windows", "whiteness",
                "cross_correlation"):
        assert key in d
    assert set(d["residual_rms_by_channel"]) == {"d", "F_lat_x", "F_lat_y", "M_x", "M_y", "M_z"}
    assert (out / "residual.png").stat().st_size > 20_000
    cap = capsys.readouterr()
    assert "% of the (W-scaled) residual" in cap.out
    stages = re.findall(r"^kinadapt diagnose \[\s*[\d.]+ s\] (.+)$", cap.err, flags=re.MULTILINE)  # never silent:
    want = ["reading the log", "replaying the log through the known model", "residual by channel and phase",
            "ranking the library's effects (held-out, block cross-validation)", "writing diagnosis.json and the figures"]
    assert [x for x in stages if x in want] == want, cap.err  # each stage as it starts (issue 41)
    assert d["calibration"].startswith("shipped")  # a simulated run: the shipped nominal calibration
    csv = tmp_path / "log.csv"  # an external (e.g. real-robot) log: no calibration unless one is given
    write_csv_log(csv, load_log(oracle_run))
    assert main(["diagnose", str(csv), "--out", str(tmp_path / "dcsv"), "--quiet"]) == 0
    dc = json.loads((tmp_path / "dcsv" / "diagnosis.json").read_text())
    assert dc["calibration"].startswith("none") and "bare nominal model" in dc["summary"] and dc["ranking"]
    assert main(["diagnose", str(tmp_path / "nothing"), "--out", str(tmp_path / "x"), "--quiet"]) == 2
    assert main(["diagnose", str(oracle_run), "--theta", "1,2", "--out", str(tmp_path / "y"), "--quiet"]) == 2
