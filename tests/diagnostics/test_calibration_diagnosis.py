"""``kinadapt diagnose`` on the independent calibration rig (examples/calibration_rig.py: its own
DH kinematics and statics, no kinadapt_nn, no MuJoCo): a 7-axis arm of another make (iiwa14, DH)
and a 6-axis UR5e (DH and URDF), static poses without a clock, an unknown sensor mount at large
angles, torques in N mm. Judged against the rig's truth and its own independent calibration."""

from __future__ import annotations

import json

import numpy as np
import pytest

from kinadapt_nn.app.cli import main
from kinadapt_nn.diagnostics.readers import read_log
from kinadapt_nn.diagnostics.setup import load_setup, rpy_matrix
from kinadapt_nn.diagnostics.userlog import diagnose
from tests.diagnostics.test_calibration_rig import cr

SEED = 11
CASES = {"iiwa14": ("mount_unknown", "mount_unknown_general", "mount_wrong_known", "tool_gravity", "encoder_offset",
                    "torque_unit_wrong", "torque_unit_wrong_nm", "force_unit_wrong"),
         "ur5e": ("mount_unknown", "encoder_offset_wrist", "ft_frame_rotation", "encoder_offset_joint1",
                  "moving_tool_gravity")}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("calib")
    out = {}
    for arm, names in CASES.items():
        for name in names:
            d = cr.make_case(arm, name, root, seed=SEED)
            setup = load_setup(d / "setup.toml")
            log = read_log(d / "log.csv", setup)
            out[(arm, name)] = (d, json.loads((d / "truth.json").read_text()), diagnose(log, setup).report, log, setup)
    return out


def _verdicts(rep):
    return {e["effect"]: e["verdict"] for e in rep["ranking"]}


def _impossible_anywhere(rep) -> list[str]:
    """Every estimate the report gives as a finding must be physical: a positive mass, a centre of
    mass within 1 m, finite numbers with finite sd."""
    bad = []
    for e in rep["ranking"]:
        if e["verdict"] != "present":
            continue
        for k, v in e["estimate"].items():
            if v.get("value") is not None and not (np.isfinite(v["value"]) and np.isfinite(v["sd"])):
                bad.append(f"{e['effect']}.{k} not finite")
        if e["effect"] == "tool_gravity":
            if e["estimate"]["total_mass"]["value"] <= 0:
                bad.append("total mass <= 0")
    sm = rep["sensor_mount"]
    if sm["plausible"]:
        if sm["tool_mass_kg"] <= 0 or np.linalg.norm(sm["tool_com_sensor_m"]) > 1.0:
            bad.append("sensor_mount implausible but not flagged")
        if not all(np.isfinite(sm["sd_deg"])) or not np.isfinite(sm["tool_mass_sd_kg"]):
            bad.append("sensor_mount sd not finite")
    return bad


@pytest.mark.parametrize("arm,name", [("iiwa14", "mount_unknown"), ("iiwa14", "mount_unknown_general"),
                                      ("ur5e", "mount_unknown")])
def test_unknown_mount_matches_an_independent_calibration(runs, arm, name):
    _, truth, rep, _, _ = runs[(arm, name)]
    sm, cal = rep["sensor_mount"], truth["calibration"]["estimate"]
    R_d, R_c = rpy_matrix(np.deg2rad(sm["rpy_flange_deg"])), rpy_matrix(np.deg2rad(cal["rpy_flange_deg"]))
    assert np.rad2deg(np.arccos(np.clip((np.trace(R_d.T @ R_c) - 1) / 2, -1, 1))) < 1.0
    assert abs(sm["tool_mass_kg"] / cal["tool_mass_kg"] - 1.0) < 0.02
    assert np.linalg.norm(np.subtract(sm["tool_com_sensor_m"], cal["tool_com_sensor_m"])) < 0.003
    # the residual in the log's units (forces N) against the calibration's (N): no worse than 1.3x
    assert np.sqrt(np.mean(np.square(sm["residual_rms"][:3]))) <= 1.3 * np.sqrt(np.mean(np.square(cal["residual_rms"][:3])))
    assert list(sm["offset_units"][3:]) == ["N mm"] * 3
    # the guessed mass is judged against the estimate: tool_gravity present, physical, the mount used
    assert _verdicts(rep)["tool_gravity"] == "present"
    assert "ft_frame_rotation" not in _verdicts(rep)
    assert not _impossible_anywhere(rep) and not rep["warnings"]
    # the verdict on the model leads (issue 50), then the estimated mount
    assert rep["summary"].startswith(("The model", "Something the model")), rep["summary"][:120]
    assert rep["summary"].index("Sensor mount estimated") < rep["summary"].index("Present")


def test_wrong_mount_declared_known_blocks_every_verdict(runs):
    _, truth, rep, _, _ = runs[("iiwa14", "mount_wrong_known")]
    sm = rep["sensor_mount"]
    assert sm["declared_consistent"] is False and truth["sensor_mount"]["declared_consistent"] is False
    assert abs(sm["rotation_from_declared_deg"] - truth["sensor_mount"]["rotation_from_declared_deg"]) < 1.0
    assert "present" not in _verdicts(rep).values()
    assert "rpy_flange_deg = [" in rep["summary"] and "off by" in rep["summary"]


@pytest.mark.parametrize("name", ["torque_unit_wrong", "torque_unit_wrong_nm", "force_unit_wrong"])
def test_wrong_unit_is_named_with_the_unit_that_fits(runs, name):
    """N mm logged as N m (a 60 m centre of mass), N m logged as N mm (0.09 mm: the finding the issue
    saw), lbf logged as N: a warning naming the unit that fits, and no verdict."""
    _, truth, rep, _, _ = runs[("iiwa14", name)]
    u = truth["units"]
    for key in ("force_unit", "torque_unit"):
        if u[f"{key}_declared"] != u[f"{key}_logged"]:
            assert any(f'set [log] {key} = "{u[f"likely_{key}"]}"' in w for w in rep["warnings"]), rep["warnings"]
    assert rep["blocked"] and "present" not in _verdicts(rep).values()
    if name == "torque_unit_wrong":
        assert rep["sensor_mount"]["plausible"] is False  # a 60 m centre of mass is flagged, never a finding


def test_a_static_log_may_leave_the_time_key_out(runs, tmp_path):
    """The setup without its time key (the log has no column 't'): no time axis, no drift judged,
    the same verdicts."""
    d, _, rep, _, _ = runs[("ur5e", "encoder_offset_wrist")]
    text = "\n".join(ln for ln in (d / "setup.toml").read_text().splitlines() if not ln.startswith("time = "))
    (tmp_path / "setup.toml").write_text(text)
    setup = load_setup(tmp_path / "setup.toml")
    assert setup.log.time == "t" and setup.log.static
    rep2 = diagnose(read_log(d / "log.csv", setup), setup).report
    assert not rep2["log"]["time_column"] and "ft_bias_drift" not in _verdicts(rep2)
    assert _verdicts(rep2) == _verdicts(rep)


@pytest.mark.parametrize("arm,name", [(a, n) for a, ns in CASES.items() for n in ns
                                      if n not in ("mount_wrong_known", "torque_unit_wrong", "torque_unit_wrong_nm",
                                                   "force_unit_wrong")])
def test_verdicts_match_the_truth(runs, arm, name):
    """The same table of verdicts as the Panda's foreign rig, on a 6-axis and another 7-axis arm."""
    _, truth, rep, _, _ = runs[(arm, name)]
    v = _verdicts(rep)
    for eff, ok in truth["expected_verdicts"].items():
        assert v.get(eff) in ok, (eff, v.get(eff), ok)
    assert not [n for n, x in v.items() if x == "present" and n not in truth["expected_verdicts"]]
    assert not _impossible_anywhere(rep)


def test_static_verdicts_do_not_depend_on_row_order(runs):
    _, _, rep, log, setup = runs[("iiwa14", "encoder_offset")]
    perm = np.random.default_rng(0).permutation(len(log.q_rad))
    shuffled = log._replace(q_rad=log.q_rad[perm], wrench_log=log.wrench_log[perm],
                            t_s=None if log.t_s is None else log.t_s[perm])
    rep2 = diagnose(shuffled, setup).report
    assert _verdicts(rep2) == _verdicts(rep)
    a = {e["effect"]: e["estimate_params"]["value"] for e in rep["ranking"] if "estimate_params" in e}
    b = {e["effect"]: e["estimate_params"]["value"] for e in rep2["ranking"] if "estimate_params" in e}
    assert a.keys() == b.keys() and all(np.allclose(a[k], b[k], rtol=1e-9, atol=1e-12) for k in a)
    assert rep["log"]["static"] and not rep["log"]["time_column"] and "ft_bias_drift" not in _verdicts(rep)


def test_cli_on_a_static_log(runs, tmp_path):
    d, _, _, _, _ = runs[("ur5e", "encoder_offset_wrist")]
    out = tmp_path / "o"
    assert main(["diagnose", str(d / "log.csv"), "--setup", str(d / "setup.toml"), "--out", str(out), "--quiet",
                 "--add", "encoder_offset"]) == 0
    rep = json.loads((out / "diagnosis.json").read_text())
    assert rep["sensor_mount"]["declared_consistent"] and (out / "residual.png").is_file()
    est = rep["added"]["encoder_offset"]["estimate"]
    assert len(est) == 1 and all(np.isfinite([v["value"], v["sd"]]).all() for v in est.values())
