"""``kinadapt diagnose LOG --setup``: a foreign set-up's logs (examples/foreign_rig.py: another
tool and sensor mount, MuJoCo's own inverse dynamics, other column names and conventions) get the
right verdicts; the nominal model agrees with MuJoCo; bad input is one line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from kinadapt_nn.app.cli import main
from kinadapt_nn.diagnostics import physical as ph
from kinadapt_nn.diagnostics.readers import read_log
from kinadapt_nn.diagnostics.setup import load_setup
from kinadapt_nn.diagnostics.userlog import diagnose
from tests.diagnostics.example_scripts import load_example

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def rig():
    return load_example("foreign_rig")


@pytest.fixture(scope="module")
def cases(rig, tmp_path_factory):
    """Every case of rig A, generated once, diagnosed once from its csv.gz."""
    root = tmp_path_factory.mktemp("foreign")
    out = {}
    for name in rig.CASES:
        d = rig.make_case(name, root, seed=0)
        setup = load_setup(d / "setup_csv.toml")
        res = diagnose(read_log(d / "log.csv.gz", setup), setup)
        out[name] = (d, json.loads((d / "truth.json").read_text()), res.report)
    return out


def _verdicts(rep: dict) -> dict[str, str]:
    return {e["effect"]: e["verdict"] for e in rep["ranking"]}


def _entry(rep: dict, name: str) -> dict:
    return next(e for e in rep["ranking"] if e["effect"] == name)


def _without_payload_inertia(rep: dict, truth: dict) -> list[str]:
    """The present effects, ``tool_inertia`` left out where a payload is hidden: the point mass off the sensor
    origin adds ``dm (|c|^2 1 - c c^T)`` (~1e-3 kg m^2 about x and y on rig A) to the tool's inertia, the inertia
    part of the ten-parameter payload; it is present or cannot_decide, never absent."""
    present = [n for n, v in _verdicts(rep).items() if v == "present"]
    if "tool_gravity" in truth["effects"]:
        assert _entry(rep, "tool_inertia")["verdict"] in ("present", "cannot_decide")
        present = [n for n in present if n != "tool_inertia"]
    return present


def test_no_effect_nothing_present(cases):
    _, _, rep = cases["none"]
    assert not [n for n, v in _verdicts(rep).items() if v == "present"]
    assert rep["sign_check"]["ok"] and rep["tip_contact_check"]["ok"]
    # a joint-1 zero offset is invisible to gravity: the honest verdict is cannot_decide, not absent
    enc = _entry(rep, "encoder_offset")
    assert enc["verdict"] == "cannot_decide" and "offset_joint1" in enc["excitation"]["weak_parameters"]


@pytest.mark.parametrize("case", ["tool_gravity", "ft_frame_rotation", "ft_bias_drift", "encoder_offset", "tared_rotation"])
def test_one_effect_alone_first_and_within_tolerance(cases, case):
    _, truth, rep = cases[case]
    (name, params), = ((k, v) for k, v in truth["effects"].items() if k != "tool_inertia")
    present = _without_payload_inertia(rep, truth)
    if "tool_inertia" in truth["effects"]:  # the payload's inertia, where the rig's truth says it is relevant
        ti = truth["effects"]["tool_inertia"]
        got = _entry(rep, "tool_inertia")
        assert got["verdict"] == "present", got["verdict"]
        scale = max(abs(v) for v in ti.values())
        for k, v in ti.items():
            assert abs(got["estimate"][k]["value"] - v) <= 0.2 * scale, (k, got["estimate"][k], v)
    assert present == [name], (case, present)
    top = rep["ranking"][0]
    assert top["effect"] == name and top["significant"]
    est = top["estimate"]
    for k, v in params.items():
        if name == "ft_frame_rotation":
            assert abs(est[k]["value"] - v) < 0.5, (k, est[k], v)  # degrees
        elif name == "tool_gravity" and k.startswith("com"):
            assert abs(est[k]["value"] - v) <= 0.2 * np.linalg.norm([params["com_x"], params["com_y"], params["com_z"]])
        else:
            assert abs(est[k]["value"] - v) <= 0.2 * abs(v), (k, est[k], v)


def test_library_cases_leave_a_complete_model(cases):
    """No false alarm: with the hidden library effect selected (or none hidden), the final model
    explains the log and no hint is offered."""
    for name, (_, _, rep) in cases.items():
        assert rep["model_complete"] is True, (name, rep["unexplained"]["carried_by"])
        assert list(rep["unexplained"]["hints"]) == []
        assert rep["summary"].startswith("The model explains the log")


def test_undetectable_effect_is_cannot_decide_not_a_wrong_answer(cases):
    _, truth, rep = cases["encoder_offset_joint1"]
    assert truth["detectable"] is False
    assert not [n for n, v in _verdicts(rep).items() if v == "present"]
    assert _entry(rep, "encoder_offset")["verdict"] == "cannot_decide"


def test_two_effects_both_present_and_jointly_estimated(cases):
    _, truth, rep = cases["pair"]
    present = set(_without_payload_inertia(rep, truth))
    assert present == {"tool_gravity", "ft_frame_rotation"}
    g = _entry(rep, "tool_gravity")["estimate"]
    assert abs(g["mass"]["value"] - truth["effects"]["tool_gravity"]["mass"]) <= 0.2 * truth["effects"]["tool_gravity"]["mass"]
    r = _entry(rep, "ft_frame_rotation")["estimate"]
    for k, v in truth["effects"]["ft_frame_rotation"].items():
        assert abs(r[k]["value"] - v) < 0.5


def test_nominal_model_agrees_with_mujoco_inverse_dynamics(rig, cases):
    """Newton-Euler of the declared tool from the encoders (Savitzky-Golay accelerations) vs the
    rig's noiseless MuJoCo reading in free space: the same wrench, in RMS well below the sensor
    noise (0.04 N); the peaks are the 0.1 s derivative window smoothing the fastest moves."""
    d, _, _ = cases["none"]
    setup = load_setup(d / "setup_csv.toml")
    sig = rig.case_signals("none", 0, noise=False)
    t, q, qd = sig["t"], sig["q"], sig["qdot"]
    w_true = sig["w_tool_on_sensor_s"]
    arm = ph.ArmModel(setup)
    m, mc, I_O = ph.nominal_inertials(setup)
    w = ph.tool_wrench(arm.series(q, qd, t), m, mc, I_O)
    free = (t > 0.2) & (t < 9.5) & (t < t[-1] - 0.2)
    err = np.abs(w[free] - w_true[free])
    assert err[:, :3].max() < 0.1 and err[:, 3:].max() < 0.01, err.max(axis=0)
    assert np.sqrt(np.mean(err[:, :3] ** 2)) < 0.01 and np.sqrt(np.mean(err[:, 3:] ** 2)) < 0.001


def test_encoder_columns_identities(cases):
    """Joint 1 is invisible to a gravity/inertia model (rotation about the vertical); every other
    column is the central difference of the whole model (checked against a one-sided one)."""
    from kinadapt_nn.effects.builtin import BUILTINS
    from kinadapt_nn.diagnostics.signals import from_log

    d, _, _ = cases["none"]
    setup = load_setup(d / "setup_csv.toml")
    s = from_log(read_log(d / "log.csv.gz", setup), setup)
    C = BUILTINS["encoder_offset"].evaluate(s)
    assert np.abs(C[:, :, 0]).max() < 1e-6 * np.abs(C[:, :, 3]).max()
    m, mc, I_O = ph.nominal_inertials(setup)
    dq = np.zeros(7)
    dq[3] = 1e-4
    fd = (ph.tool_wrench(s.arm.series(s.q + dq, s.qdot, s.t), m, mc, I_O) - s.w_nom) / 1e-4
    np.testing.assert_allclose(C[:, :, 3], fd, atol=1e-3 * np.abs(fd).max())


def test_parquet_other_columns_and_convention_same_answer(cases, tmp_path):
    """The same samples as Parquet (other names, degrees, no qdot, the other wrench convention) ->
    the same verdicts; the drift is reported in each log's own convention."""
    d, truth, rep = cases["ft_bias_drift"]
    out = tmp_path / "pq"
    assert main(["diagnose", str(d / "log.parquet"), "--setup", str(d / "setup_parquet.toml"), "--out", str(out),
                 "--quiet"]) == 0
    rep_pq = json.loads((out / "diagnosis.json").read_text())
    assert _verdicts(rep_pq) == _verdicts(rep)
    est, est_pq = _entry(rep, "ft_bias_drift")["estimate"], _entry(rep_pq, "ft_bias_drift")["estimate"]
    for k, v in truth["truth_parquet"]["ft_bias_drift"].items():
        assert abs(est_pq[k]["value"] - v) <= 0.2 * abs(v)
        assert est_pq[k]["value"] == pytest.approx(-est[k]["value"], rel=0.02, abs=1e-4)
    assert (out / "setup.toml").is_file() and (out / "effects.png").is_file() and (out / "residual.png").is_file()


def test_add_makes_the_residual_fall(cases, tmp_path):
    d, _, _ = cases["tool_gravity"]
    out = tmp_path / "add"
    assert main(["diagnose", str(d / "log.csv.gz"), "--setup", str(d / "setup_csv.toml"), "--out", str(out),
                 "--add", "tool_gravity", "--quiet"]) == 0
    rep = json.loads((out / "diagnosis.json").read_text())
    assert rep["residual_rms_after"]["total_w"] < 0.3 * rep["residual_rms_before"]["total_w"]
    assert abs(rep["added"]["tool_gravity"]["estimate"]["mass"]["value"] - 0.25) < 0.05


def test_add_names_the_joint(cases, tmp_path, capsys):
    """``--add encoder_offset:joint4`` fits that joint; a parameter the effect lacks is one line."""
    d, _, _ = cases["encoder_offset"]
    out = tmp_path / "addj"
    assert main(["diagnose", str(d / "log.csv.gz"), "--setup", str(d / "setup_csv.toml"), "--out", str(out),
                 "--add", "encoder_offset:joint4", "--quiet"]) == 0
    est = json.loads((out / "diagnosis.json").read_text())["added"]["encoder_offset"]["estimate"]
    assert list(est) == ["offset_joint4"] and abs(est["offset_joint4"]["value"] - 1.0) < 0.1
    assert main(["diagnose", str(d / "log.csv.gz"), "--setup", str(d / "setup_csv.toml"), "--out",
                 str(tmp_path / "addx"), "--add", "encoder_offset:joint9", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "joint9" in err[0] and not (tmp_path / "addx" / "diagnosis.json").exists()


def test_flipped_sign_is_caught_not_diagnosed(cases, tmp_path, capsys):
    d, _, _ = cases["none"]
    out = tmp_path / "flip"
    assert main(["diagnose", str(d / "log.csv.gz"), "--setup", str(d / "setup_csv.toml"), "--out", str(out),
                 "--set", 'log.wrench_acts="tool_on_sensor"']) == 0
    err = capsys.readouterr().err
    assert "wrench_acts" in err and "weighs -" in err
    rep = json.loads((out / "diagnosis.json").read_text())
    assert not rep["sign_check"]["ok"]
    assert set(_verdicts(rep).values()) == {"cannot_decide"}


def test_torques_in_n_m_declared_n_mm_are_named_not_diagnosed(cases, tmp_path, capsys):
    """The moving log in N m declared N mm: the fit left a 2.8 mm centre of mass (declared 55 mm)
    and a tool_gravity finding; the declared inertia's moments, thousands of times the noise under
    N mm, name N m, and no verdict is given (exit 0: a warning, not an error)."""
    d, _, _ = cases["none"]
    out = tmp_path / "nmm"
    assert main(["diagnose", str(d / "log.csv.gz"), "--setup", str(d / "setup_csv.toml"), "--out", str(out),
                 "--set", 'log.torque_unit="N mm"']) == 0
    assert 'set [log] torque_unit = "N m"' in capsys.readouterr().err
    rep = json.loads((out / "diagnosis.json").read_text())
    assert rep["blocked"].startswith("the wrench units look wrong")
    assert "present" not in _verdicts(rep).values()


def test_wrong_tip_is_flagged_and_contact_left_out(cases, tmp_path, capsys):
    d, truth, _ = cases["tool_gravity"]
    out = tmp_path / "tip"
    assert main(["diagnose", str(d / "log.csv.gz"), "--setup", str(d / "setup_csv.toml"), "--out", str(out),
                 "--set", "tool.tip_sensor_m=[0.01, 0.0, 0.12]", "--quiet"]) == 0
    rep = json.loads((out / "diagnosis.json").read_text())
    assert not rep["tip_contact_check"]["ok"] and rep["contact"]["rows"].startswith("left out")
    assert _without_payload_inertia(rep, truth) == ["tool_gravity"]


def test_bad_input_is_one_line_and_writes_nothing(cases, tmp_path, capsys):
    d, _, _ = cases["none"]
    bad = tmp_path / "bad.toml"
    bad.write_text((d / "setup_csv.toml").read_text().replace("[tool]", "[tool]\nmass_kilo = 1.0"))
    out = tmp_path / "o"
    assert main(["diagnose", str(d / "log.csv.gz"), "--setup", str(bad), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "mass_kilo" in err and len(err.splitlines()) == 1 and not out.exists()
    nan = tmp_path / "nan.toml"
    nan.write_text((d / "setup_csv.toml").read_text().replace("mass_kg = 1.1", "mass_kg = nan"))
    assert main(["diagnose", str(d / "log.csv.gz"), "--setup", str(nan), "--out", str(out)]) == 2
    assert "mass_kg" in capsys.readouterr().err and not out.exists()
    wrong_col = tmp_path / "col.toml"
    wrong_col.write_text((d / "setup_csv.toml").read_text().replace('"F_x"', '"Fx"'))
    assert main(["diagnose", str(d / "log.csv.gz"), "--setup", str(wrong_col), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()  # progress lines, then the error: one line
    assert err[-1].startswith("kinadapt: error:") and "Fx" in err[-1] and not out.exists()
    assert not any("Traceback" in ln for ln in err)
    assert main(["diagnose", str(d / "log.csv.gz"), "--setup", str(d / "setup_csv.toml"), "--out", str(out),
                 "--add", "contact_stiffness"]) == 2
    assert "contact_stiffness" in capsys.readouterr().err and not out.exists()


def test_setup_template_loads_as_the_defaults(tmp_path, capsys):
    assert main(["setup-template"]) == 0
    p = tmp_path / "t.toml"
    p.write_text(capsys.readouterr().out)
    assert load_setup(p) == load_setup(None)
    for f in sorted((ROOT / "examples" / "setups").glob("*.toml")):
        load_setup(f)


def test_the_report_is_read_only_and_writes_itself(cases, tmp_path):
    """The stages' results are frozen and the report is put together once: nothing can write into
    it afterwards; ``to_json`` gives the header, the summary first, every section, the wall time --
    the same content ``kinadapt diagnose`` writes."""
    import dataclasses

    from kinadapt_nn.diagnostics.report import FORMAT, VERSION, Provenance, thaw

    d, _, rep = cases["tool_gravity"]
    with pytest.raises(TypeError):
        rep["ranking"] = []
    setup = load_setup(d / "setup_csv.toml")
    res = diagnose(read_log(d / "log.csv.gz", setup), setup, add=["tool_gravity"], hints=False)
    with pytest.raises(dataclasses.FrozenInstanceError):
        res.report = None
    js = res.report.to_json(Provenance("user_log", "log.csv.gz", "setup_csv.toml"), 1.5)
    assert list(js)[:6] == ["format", "version", "kind", "source", "setup_file", "summary"]
    assert (js["format"], js["version"], js["wall_time_s"]) == (FORMAT, VERSION, 1.5)
    assert js["summary"] == res.report["summary"] and "With tool_gravity added" in js["summary"]
    assert set(js) - {"format", "version", "kind", "source", "setup_file", "wall_time_s"} == set(res.report)
    js["ranking"][0]["verdict"] = "changed"  # a copy: the report stays as it was
    assert res.report["ranking"][0]["verdict"] != "changed"
    out = tmp_path / "d"
    assert main(["diagnose", str(d / "log.csv.gz"), "--setup", str(d / "setup_csv.toml"), "--out", str(out),
                 "--add", "tool_gravity", "--quiet"]) == 0
    written = json.loads((out / "diagnosis.json").read_text())
    assert set(written) == set(js) and written["ranking"] == json.loads(json.dumps(thaw(res.report["ranking"])))


def test_the_summary_never_hides_the_largest_parameter_and_says_how_many_are_left_out():
    """YuMi: ft_offset printed fx, fy, fz, tx and hid ty = 147.6 N mm, the largest; no "…" said so."""
    from kinadapt_nn.diagnostics.userlog import summary_text

    names = ["fx", "fy", "fz", "tx", "ty", "tz"]
    values = [0.11, -0.2, 0.3, 1.0, 147.6, 2.0]
    est = {n: {"value": v, "sd": 0.1, "unit": "N" if n[0] == "f" else "N mm"} for n, v in zip(names, values)}
    rep = {"sign_check": {"ok": True}, "tip_contact_check": {"ok": True}, "explained_by_present": 0.9,
           "ranking": [{"effect": "ft_offset", "verdict": "present", "estimate": est}]}
    txt = summary_text(rep)
    assert "ty 148 ± 0.1 N mm" in txt, txt
    assert "… (+2 more)" in txt, txt
    assert "fx 0.11" not in txt  # the smallest |value / sd| are the ones left out
    small = {n: est[n] for n in names[:4]}
    txt = summary_text({**rep, "ranking": [{**rep["ranking"][0], "estimate": small}]})
    assert "more)" not in txt and all(f"{n} " in txt for n in names[:4]), txt


def test_a_payload_is_said_once_as_the_whole_tool():
    """``tool_gravity`` in the summary: the whole tool (mass, centre of mass), the declared mass and
    the difference; a small difference is a correction of the declared tool, not a body placed far
    away; with the mount estimated the calibration's tool is not said a second time (issue 51)."""
    from kinadapt_nn.diagnostics.userlog import _payload_text

    def q(v, sd, unit):
        return {"value": v, "sd": sd, "unit": unit}

    est = {"mass": q(0.0451, 0.011, "kg"), "com_x": q(0.2413, 0.1, "m"), "com_y": q(0.0332, 0.1, "m"),
           "com_z": q(-0.3843, 0.1, "m"), "total_mass": q(0.4451, 0.011, "kg"),
           "total_com_x": q(0.0245, 0.0035, "m"), "total_com_y": q(0.0034, 0.0042, "m"),
           "total_com_z": q(-0.039, 0.0038, "m")}
    rep = {"setup_summary": {"tool_mass_kg": 0.4}}
    txt = _payload_text(est, rep)
    assert txt.startswith("the whole tool 0.4451 ± 0.011 kg, centre of mass [24.5, 3.4, -39.0]")
    assert "declared 0.4 kg: +0.0451" in txt and "correction of the declared tool" in txt and "241" not in txt
    big = {**est, "mass": q(0.25, 0.001, "kg"), "total_mass": q(0.65, 0.001, "kg")}
    assert "added at [241.3, 33.2, -384.3] mm" in _payload_text(big, rep)
