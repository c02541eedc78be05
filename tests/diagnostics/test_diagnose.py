"""kinadapt diagnose on a package run: its log and CSV import, a wrong tool offset seen in the data, the outputs."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from kinadapt_nn.app.cli import main
from kinadapt_nn.config import load_config
from kinadapt_nn.diagnostics import userlog
from kinadapt_nn.diagnostics.importers import COLUMNS, RawLog, load_log, read_csv_log, write_csv_log
from kinadapt_nn.runs.episode import run_episode
from kinadapt_nn.errors import KinadaptError


@pytest.fixture(scope="module")
def oracle_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("diag") / "run"
    assert main(["online", "--out", str(out), "--quiet", "--set", "run.features=oracle", "--set", "run.duration_s=2.5",
                 "--set", "run.tensorboard=false", "--set", "run.figure=false"]) in (0, 1)
    return out


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


def test_a_wrong_tool_offset_shows_where_the_motion_excites_it():
    """The excitation program's first 14 s (free space, the descent into the socket, an axial press,
    lateral pushes): contacts act at the true tip; a tip declared 5 mm off across the tool is
    contradicted by the contact wrench (the calibration stage's contact point), the true one is not.
    (A short insertion's contact force keeps one direction: a tip error along it is invisible, and
    the report says the point is undetermined along that line.)"""
    from pathlib import Path

    from kinadapt_nn.diagnostics import ownrun, userlog
    from kinadapt_nn.diagnostics import signals as sg

    excite = Path(__file__).resolve().parents[2] / "online" / "excite.toml"
    cfg = load_config(excite, ["run.duration_s=14", "run.progress=false", "run.tensorboard=false",
                               "run.figure=false"])
    tr = run_episode(cfg).trace
    raw = RawLog(tr["t_s"], tr["q_rad"], tr["qdot_rad_s"], tr["wrench_raw_f"], "mem")
    true = np.asarray(cfg.tool.offset_f_m)
    out = {}
    for key, tip in (("good", true), ("wrong", true + np.array([0.004, -0.003, 0.0]))):
        log, setup = ownrun.as_log(raw, cfg, tip_sensor_m=tip)
        s = sg.from_log(log, setup)
        rc = userlog.RowCfg()
        cal = userlog.calibrate(log, s, setup, userlog.noise_sigma(s.wrench, rc), rc, lambda m: None)
        assert cal.contact_point is not None
        out[key] = userlog.effective_setup(setup, setup, cal.fit, cal.contact_point)["contact_point"]
    assert out["good"]["declared_tip_consistent"], out["good"]
    assert not out["wrong"]["declared_tip_consistent"] and out["wrong"]["declared_tip_distance_m"] > 0.003, out["wrong"]


def test_diagnose_cli_outputs(oracle_run, tmp_path, capsys):
    """``kinadapt diagnose RUN``: the one pipeline on a package run, its stages announced in order;
    the package's CSV of the same run (built-in config) is diagnosed the same way."""
    out = tmp_path / "diag"
    assert main(["diagnose", str(oracle_run), "--out", str(out)]) == 0
    d = json.loads((out / "diagnosis.json").read_text())
    for key in ("summary", "residual_rms_by_channel", "ranking", "segmentation", "effective_setup", "sensor_mount",
                "tip_contact_check", "library"):
        assert key in d
    assert d["kind"] == "package_run" and d["format"] == "kinadapt-diagnosis"
    assert set(d["residual_rms_by_channel"]) <= {*userlog.CHANNELS, "total_w"}
    assert {"F_x", "F_y", "F_z", "M_x", "M_y", "M_z", "total_w"} <= set(d["residual_rms_by_channel"])
    assert (out / "residual.png").stat().st_size > 20_000 and (out / "setup.toml").is_file()
    cap = capsys.readouterr()
    assert d["summary"] in cap.out
    stages = re.findall(r"^kinadapt diagnose \[\s*[\d.]+ s\] (.+)$", cap.err, flags=re.MULTILINE)  # never silent:
    want = ["reading the run; its set-up generated from its config", "free space found from the data (segmentation)",
            "effect columns", "completeness of the final model and hints", "writing diagnosis.json and the figures"]
    assert [x for x in stages if x in want] == want, cap.err  # each stage as it starts (issue 41)
    csv = tmp_path / "log.csv"  # the package's CSV of the run: the built-in config's set-up
    write_csv_log(csv, load_log(oracle_run))
    assert main(["diagnose", str(csv), "--config", str(oracle_run / "config.toml"), "--out", str(tmp_path / "dcsv"),
                 "--quiet"]) == 0
    dc = json.loads((tmp_path / "dcsv" / "diagnosis.json").read_text())
    assert [e["verdict"] for e in dc["ranking"]] == [e["verdict"] for e in d["ranking"]]
    assert main(["diagnose", str(tmp_path / "nothing"), "--out", str(tmp_path / "x"), "--quiet"]) == 2
    assert main(["diagnose", str(oracle_run), "--theta", "1,2", "--out", str(tmp_path / "y"), "--quiet"]) == 2
