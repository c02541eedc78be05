"""The run configs' types (kinadapt_nn.config): strict, as the setup file's -- a wrong TOML type is
a one-line ``ConfigError``, never coerced; an integer is still a valid float."""

from __future__ import annotations

import pytest

from kinadapt_nn.config import load_config
from kinadapt_nn.errors import ConfigError


@pytest.mark.parametrize("override, given, expected", [
    ('run.tensorboard="no"', "a string", "a boolean"),
    ("run.figure=0", "an integer", "a boolean"),
    ('tool.mass_kg="0.4"', "a string", "a number"),
    ("run.seed=1.5", "a float", "an integer"),
    ('run.seed="3"', "a string", "an integer"),
])
def test_a_wrong_type_is_refused_naming_key_given_and_expected(override, given, expected):
    with pytest.raises(ConfigError) as exc:
        load_config(None, [override])
    msg = str(exc.value)
    assert override.split("=")[0] in msg and given in msg and expected in msg, msg


def test_integers_stay_numbers_and_arrays_tuples():
    cfg = load_config(None, ["run.duration_s=5", "tool.offset_f_m=[0, 0, 0.1]", "excite.segments=[[1, 0, 0, 0, 0, 0, 0]]"])
    assert cfg.run.duration_s == 5.0 and isinstance(cfg.run.duration_s, float)
    assert cfg.tool.offset_f_m == (0.0, 0.0, 0.1)
    assert cfg.excite.segments == ((1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),)
