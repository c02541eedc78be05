"""Config validation and the CLI's bad-input contract: one line, exit 2, nothing half-written."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import pytest

from kinadapt_nn.app.cli import main
from kinadapt_nn.config import ExperimentCfg, config_to_toml, load_config
from kinadapt_nn.errors import ConfigError, ModelFileError

REPO = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize(
    ("overrides", "fragment"),
    [
        (["control.gain_trns=1e-4"], "unknown config key 'control.gain_trns'"),
        (["nonsense.key=1"], "unknown config key 'nonsense'"),
        (["run.seed=abc"], "run.seed"),
        (["control.gain_trans=-2e-4"], "control.gain_trans"),
        (["run.dt_s=0"], "run.dt_s"),
        (["tool.side_m=0.03"], "tool.side_m"),
        (["tool.offset_f_m=[0.0, 0.1]"], "tool.offset_f_m"),
        (["sensing.channel_scale=[0.01, 10, 10, 1, 1, 0]"], "channel_scale"),
        (["novalue"], "expected key=value"),
    ],
)
def test_bad_config_values_raise_one_line_config_error(overrides, fragment):
    with pytest.raises(ConfigError) as exc:
        load_config(None, overrides)
    msg = str(exc.value)
    assert fragment in msg
    assert "\n" not in msg


def test_shipped_rollout_config_equals_the_defaults_and_round_trips(tmp_path):
    """online/rollout.toml is the default experiment; config.toml written by a run reloads equal."""
    cfg = load_config(REPO / "online" / "rollout.toml")
    assert cfg == ExperimentCfg()
    p = tmp_path / "c.toml"
    p.write_text(config_to_toml(load_config(None, ["run.seed=7", "start.tilt_deg=[0.5, 1.5]"])))
    again = load_config(p)
    assert again.run.seed == 7 and again.start.tilt_deg == (0.5, 1.5)


def test_missing_and_broken_config_files(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        load_config(tmp_path / "nope.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[run\nseed = 1\n")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_config(bad)


def test_missing_model_file_is_a_model_file_error(tmp_path):
    from kinadapt_nn.sim.adapter import PegInHoleSim

    cfg = load_config(None, [f"scene.arm_mjcf='{tmp_path / 'missing.xml'}'"])
    with pytest.raises(ModelFileError, match="not found"):
        PegInHoleSim(cfg)
    broken = tmp_path / "broken.xml"
    broken.write_text("<mujoco><worldbody><body></mujoco>")
    with pytest.raises(ModelFileError, match="could not be parsed"):
        PegInHoleSim(load_config(None, [f"scene.arm_mjcf='{broken}'"]))


def _run_cli(args, capsys):
    rc = main(args)
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


@pytest.mark.parametrize(
    "extra",
    [
        ["--set", "control.k_depth_N_per_m=-5"],
        ["--set", "run.dt_s=0"],
        ["--set", "unknown.key=1"],
        ["--config", "does/not/exist.toml"],
        ["--set", "scene.arm_mjcf='/nonexistent/panda.xml'"],
    ],
)
def test_cli_bad_input_is_one_line_exit_2_and_writes_nothing(tmp_path, capsys, extra):
    out = tmp_path / "run"
    rc, stdout, err = _run_cli(["online", "--out", str(out), "--quiet", *extra], capsys)
    assert rc == 2
    assert err.startswith("kinadapt: error: ") and err.count("\n") == 1
    assert "Traceback" not in err
    assert not out.exists()
    assert list(tmp_path.iterdir()) == []  # no staging leftovers either


def test_cli_existing_output_needs_overwrite_and_is_left_untouched(tmp_path, capsys):
    out = tmp_path / "run"
    out.mkdir()
    (out / "precious.txt").write_text("keep me")
    rc, _, err = _run_cli(["online", "--out", str(out), "--quiet"], capsys)
    assert rc == 2 and "already exists" in err and "--overwrite" in err
    assert (out / "precious.txt").read_text() == "keep me"


def test_cli_run_writes_the_run_outputs_contract(tmp_path, capsys):
    """A real (short) run writes config.toml, summary.json, trace.npz, rollout.png and tb/."""
    from kinadapt_nn.trace import Trace

    out = tmp_path / "run"
    rc, stdout, _ = _run_cli(["online", "--out", str(out), "--set", "run.duration_s=1.0"], capsys)
    assert rc == 1  # 1 s is not enough to seat: exit 1, outputs still written
    assert "NOT SEATED (timeout)" in stdout
    summary = json.loads((out / "summary.json").read_text())
    for key in (
        "success", "seat_time_s", "final_depth_m", "max_force_N", "max_moment_Nm", "min_lambda_JJt",
        "offset_error_final_m", "jacobian_rel_error_final", "pred_error_rms", "features", "law",
        "n_params", "seed", "steps", "sim_time_s", "wall_time_s",
    ):
        assert key in summary, key
    assert summary["success"] is False and summary["seat_time_s"] is None
    assert set(summary["pred_error_rms"]) == {"d", "F_lat_x", "F_lat_y", "M_x", "M_y", "M_z"}
    cfg = tomllib.loads((out / "config.toml").read_text())
    assert cfg["run"]["duration_s"] == 1.0
    tr = Trace.load(out / "trace.npz")
    assert tr.meta["format"] == "kinadapt-trace" and tr.meta["version"] == 1
    assert len(tr) == summary["steps"]
    assert (out / "rollout.png").stat().st_size > 10_000
    assert any(p.name.startswith("events.out.tfevents") for p in (out / "tb").iterdir())
    # --overwrite replaces the folder completely
    rc2, _, _ = _run_cli(["online", "--out", str(out), "--overwrite", "--quiet", "--set", "run.duration_s=0.5"], capsys)
    assert rc2 == 1
    assert json.loads((out / "summary.json").read_text())["sim_time_s"] == pytest.approx(0.5, abs=2e-3)
    assert [p.name for p in tmp_path.iterdir()] == ["run"]


def test_trace_loader_rejects_garbage(tmp_path):
    from kinadapt_nn.errors import KinadaptError
    from kinadapt_nn.trace import Trace

    p = tmp_path / "x.npz"
    p.write_bytes(b"not a zip")
    with pytest.raises(KinadaptError, match="not a readable"):
        Trace.load(p)
