"""Physics outside the library (examples/foreign_rig_outside.py: an independent rig that hides one
effect no built-in names): the model says it is incomplete and points at the right shape; the
user's own effect file, passed with --effects, is judged exactly like a built-in; bad effect files
are one line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from kinadapt_nn.app.cli import main
from kinadapt_nn.diagnostics.readers import read_log
from kinadapt_nn.diagnostics.setup import load_setup
from kinadapt_nn.diagnostics.userlog import diagnose
from tests.diagnostics.example_scripts import load_example

ROOT = Path(__file__).resolve().parents[2]
EFFECTS = ROOT / "examples" / "effects"
CASES = ("effect_free", "world_pull", "crosstalk", "temperature")
USER_FILE = {"world_pull": ("cable_pull.py", "cable_pull"), "crosstalk": ("crosstalk.py", "crosstalk"),
             "temperature": ("temperature_bias.py", "temperature_bias")}


@pytest.fixture(scope="module")
def logs(tmp_path_factory) -> dict[str, Path]:
    load_example("foreign_rig")
    outside = load_example("foreign_rig_outside")
    root = tmp_path_factory.mktemp("outside")
    return {c: outside.make_case(c, root, seed=0) for c in CASES}


def _diag(d: Path, files=(), add=()):
    setup = load_setup(d / "setup_csv.toml")
    return diagnose(read_log(d / "log.csv.gz", setup), setup, list(add), effects_files=[str(f) for f in files])


@pytest.fixture(scope="module")
def plain(logs) -> dict:
    return {c: _diag(logs[c]).report for c in CASES}


def _present(rep: dict) -> list[str]:
    return [e["effect"] for e in rep["ranking"] if e["verdict"] == "present"]


def test_effect_free_log_is_complete_and_absent_is_decidable(plain):
    rep = plain["effect_free"]
    assert rep["model_complete"] is True and not _present(rep)
    assert rep["summary"].startswith("The model explains the log")
    v = {e["effect"]: e["verdict"] for e in rep["ranking"] if e.get("judged", True)}
    # every interval inside its relevant size -> absent; the joint-1 offset (vertical axis) cannot be seen
    for name in ("tool_gravity", "ft_bias_drift", "ft_frame_rotation", "ft_offset", "tool_tilt"):
        assert v[name] == "absent", (name, v)
    enc = next(e for e in rep["ranking"] if e["effect"] == "encoder_offset")
    assert enc["verdict"] == "cannot_decide" and "offset_joint1" in enc["undecided_parameters"]
    for e in rep["ranking"]:
        if e["verdict"] == "absent":
            for par in e["equivalence"]["parameters"].values():
                assert -par["relevant"] < par["ci"][0] <= par["ci"][1] < par["relevant"]


@pytest.mark.parametrize("case,shape", [("world_pull", "world_force"), ("crosstalk", "wrench_linear"),
                                        ("temperature", "extra:temp_C")])
def test_outside_effect_is_incomplete_with_the_right_top_hint(plain, logs, case, shape):
    rep = plain[case]
    truth = json.loads((logs[case] / "truth.json").read_text())
    assert rep["model_complete"] is False
    assert rep["summary"].startswith("Something the model does not contain is left")
    hints = rep["unexplained"]["hints"]
    assert hints and hints[0]["shape"] == shape, [h["shape"] for h in hints]
    assert shape in truth["acceptable_hint_shapes"]
    assert rep["unexplained"]["carried_by"]
    for e in rep["ranking"]:  # no library effect is a clean finding
        if e["verdict"] == "present":
            assert "may stand in" in e["warning"] and e["explains_share"] is not None


def test_world_force_hint_recovers_the_pull_and_its_point(plain, logs):
    truth = json.loads((logs["world_pull"] / "truth.json").read_text())["params"]
    fit = plain["world_pull"]["unexplained"]["hints"][0]["fitted"]
    np.testing.assert_allclose(fit["force_w"]["value"], [truth["fx_w"], truth["fy_w"], truth["fz_w"]], atol=0.05)
    np.testing.assert_allclose(fit["point_s"]["value"], truth["clamp_s_m"], atol=0.005)


@pytest.mark.parametrize("case", ["world_pull", "crosstalk", "temperature"])
def test_users_effect_file_is_judged_like_a_builtin(plain, logs, case):
    fname, name = USER_FILE[case]
    res = _diag(logs[case], [EFFECTS / fname], add=[name])
    rep = res.report
    truth = json.loads((logs[case] / "truth.json").read_text())["effect_file"]["params"]
    assert _present(rep) == [name], _present(rep)
    assert rep["model_complete"] is True
    e = next(x for x in rep["ranking"] if x["effect"] == name)
    assert e["source"].endswith(fname)
    for k, v in truth.items():
        got = e["estimate"][k]["value"]
        assert abs(got - v) <= 0.2 * abs(v), (k, got, v)
        assert np.isfinite(e["estimate"][k]["sd"])
    # --add brings the residual down to the effect-free level
    free = plain["effect_free"]["residual_rms_by_channel"]["total_w"]
    assert rep["residual_rms_after"]["total_w"] <= 1.3 * free, (rep["residual_rms_after"]["total_w"], free)


def test_hint_file_round_trip_cli(logs, tmp_path, capsys):
    d = logs["world_pull"]
    out = tmp_path / "d1"
    assert main(["diagnose", str(d / "log.csv.gz"), "--setup", str(d / "setup_csv.toml"), "--out", str(out),
                 "--quiet"]) == 0
    hint = out / "hint_world_force.py"
    assert hint.is_file()
    out2 = tmp_path / "d2"
    assert main(["diagnose", str(d / "log.csv.gz"), "--setup", str(d / "setup_csv.toml"), "--out", str(out2),
                 "--effects", str(hint), "--add", "hint_world_force", "ft_offset", "--quiet"]) == 0
    rep = json.loads((out2 / "diagnosis.json").read_text())
    assert rep["model_complete"] is True and _present(rep) == ["hint_world_force"]
    assert set(rep["added"]) == {"hint_world_force", "ft_offset"}  # --add A B


BAD = {
    "raises.py": ("def f(s):\n    raise RuntimeError('boom')\n", "raised RuntimeError: boom"),
    "shape.py": ("def f(s):\n    return np.zeros((s.n, 6))\n", "returned shape"),
    "nonfinite.py": ("def f(s):\n    C = np.zeros((s.n, 6, 2))\n    C[5, 0, 1] = np.nan\n    return C\n",
                     "non-finite"),
}


@pytest.mark.parametrize("fname", list(BAD))
def test_bad_effect_file_is_one_line_and_writes_nothing(logs, tmp_path, capsys, fname):
    body, msg = BAD[fname]
    k = 1 if fname == "shape.py" else 2
    params = "{" + ", ".join(f"'p{i}': 'N'" for i in range(k)) + "}"
    f = tmp_path / fname
    f.write_text(f"import numpy as np\nfrom kinadapt_nn.diagnostics import effect\n\n"
                 f"@effect(params={params}, relevant={[0.1] * k}, doc='x')\n" + body.replace("def f", "def my_eff"))
    if fname == "shape.py":
        f.write_text(f.read_text().replace("params={'p0': 'N'}, relevant=[0.1]",
                                           "params={'p0': 'N', 'p1': 'N'}, relevant=[0.1, 0.1]"))
    d = logs["effect_free"]
    out = tmp_path / "o"
    assert main(["diagnose", str(d / "log.csv.gz"), "--setup", str(d / "setup_csv.toml"), "--out", str(out),
                 "--effects", str(f), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and msg in err[0] and "my_eff" in err[0] and fname in err[0], err
    assert not out.exists()


@pytest.mark.parametrize("text,msg", [
    ("@effect(params={'a': 'N', 'b': 'N'}, relevant=[0.1], doc='x')\ndef e(s):\n    return 0\n", "1 relevant size"),
    ("@effect(params={'a': 'N'}, relevant=[0.1], doc='x')\ndef tool_gravity(s):\n    return 0\n", "built-in"),
    ("def e(s)\n    return 0\n", "syntax error"),
    ("x = 1\n", "defines no effect"),
])
def test_effect_file_contract_errors(logs, tmp_path, capsys, text, msg):
    f = tmp_path / "eff.py"
    f.write_text("import numpy as np\nfrom kinadapt_nn.diagnostics import effect\n" + text)
    d = logs["effect_free"]
    assert main(["diagnose", str(d / "log.csv.gz"), "--setup", str(d / "setup_csv.toml"), "--out",
                 str(tmp_path / "o"), "--effects", str(f), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and msg in err[0], err


def test_extra_column_errors_are_one_line(logs, tmp_path, capsys):
    d = logs["temperature"]
    setup = tmp_path / "s.toml"
    setup.write_text((d / "setup_csv.toml").read_text().replace('extra = ["temp_C"]', 'extra = ["temp_K"]'))
    assert main(["diagnose", str(d / "log.csv.gz"), "--setup", str(setup), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "temp_K" in err and "temp_C" in err
