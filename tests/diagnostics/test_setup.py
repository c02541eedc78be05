"""The setup file's types (kinadapt_nn.diagnostics.setup): a wrong TOML type is a one-line error
naming the key, what was given and the type expected -- never coerced (``"no"`` or ``0`` is not
false, ``"0.4"`` is not 0.4) -- while an integer stays a valid number (``mass_kg = 1``)."""

from __future__ import annotations

import pytest

from kinadapt_nn.app.cli import main
from kinadapt_nn.diagnostics.setup import load_setup
from kinadapt_nn.errors import ConfigError


@pytest.mark.parametrize("key, toml, given, expected", [
    ("sensor.mount_known", '"no"', "a string", "a boolean"),
    ("sensor.mount_known", "0", "an integer", "a boolean"),
    ("log.static", '"true"', "a string", "a boolean"),
    ("tool.mass_kg", '"0.4"', "a string", "a number"),
    ("tool.mass_kg", "true", "a boolean", "a number"),
    ("tool.com_sensor_m", '[0, "0.1", 0]', "a string", "a number"),
    ("log.time", "3", "an integer", "a string"),
    ("log.q", '"q1"', "a string", "an array"),
])
def test_a_wrong_toml_type_is_one_line_naming_key_given_and_expected(tmp_path, key, toml, given, expected):
    section, name = key.split(".")
    path = tmp_path / "setup.toml"
    path.write_text(f"[{section}]\n{name} = {toml}\n")
    with pytest.raises(ConfigError) as exc:
        load_setup(path)
    msg = str(exc.value)
    assert "\n" not in msg
    assert f"'{key}" in msg and given in msg and expected in msg, msg


def test_an_integer_is_a_number(tmp_path):
    path = tmp_path / "setup.toml"
    path.write_text("[tool]\nmass_kg = 1\ncom_sensor_m = [0, 0, 1]\n[sensor]\nmount_known = false\n")
    setup = load_setup(path)
    assert setup.tool.mass_kg == 1.0 and isinstance(setup.tool.mass_kg, float)
    assert setup.tool.com_sensor_m == (0.0, 0.0, 1.0)
    assert setup.sensor.mount_known is False


def test_a_wrong_type_on_the_cli_exits_2_with_one_line(tmp_path, capsys):
    (tmp_path / "setup.toml").write_text('[sensor]\nmount_known = "no"\n')
    rc = main(["diagnose", str(tmp_path / "log.csv"), "--setup", str(tmp_path / "setup.toml"), "--out",
               str(tmp_path / "d"), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "sensor.mount_known" in err and "'no'" in err, err
    assert not (tmp_path / "d").exists()


def test_setup_given_twice_is_one_line_not_the_last(tmp_path, capsys):
    for name in ("a.toml", "b.toml"):
        (tmp_path / name).write_text("")
    rc = main(["diagnose", str(tmp_path / "log.csv"), "--setup", str(tmp_path / "a.toml"), "--setup",
               str(tmp_path / "b.toml"), "--out", str(tmp_path / "d"), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "--setup" in err and "twice" in err, err
    assert not (tmp_path / "d").exists()
