"""What the diagnosis says to a person: a misspelt setup key or effect name gets the closest valid
one, and a near-tie inside one one-of effect names its two parameters, not the effect twice."""

from __future__ import annotations

import numpy as np
import pytest

from types import SimpleNamespace

from kinadapt_nn.diagnostics import selection, userlog
from kinadapt_nn.diagnostics.setup import load_setup
from kinadapt_nn.errors import ConfigError, KinadaptError


@pytest.mark.parametrize(
    ("override", "fragment"),
    [("log.tiem=t", "did you mean 'log.time'?"), ("sensr.rpy_flange_deg=[0, 0, 0]", "did you mean 'sensor'?"),
     ("analysis.exclude_efects=[]", "did you mean 'analysis.exclude_effects'?")],
)
def test_a_misspelt_setup_key_names_the_closest_key(override, fragment):
    with pytest.raises(ConfigError) as exc:
        load_setup(None, [override])
    assert fragment in str(exc.value) and "\n" not in str(exc.value)


def test_a_misspelt_effect_name_names_the_closest_effect():
    log = SimpleNamespace(extra={})
    with pytest.raises(KinadaptError, match=r"--add tool_gravty: unknown effect; did you mean 'tool_gravity'\?"):
        userlog._library_for(log, load_setup(None), ["tool_gravty"], ())
    setup = load_setup(None, ["analysis.exclude_effects=['encoder_ofset']"])
    with pytest.raises(KinadaptError, match=r"unknown effect 'encoder_ofset'; did you mean 'encoder_offset'\?"):
        userlog.judged(userlog.library(setup), setup)
    with pytest.raises(KinadaptError, match=r"did you mean 'offset_joint4'\?"):
        userlog._parse_add(["encoder_offset:offset_jiont4"], userlog.library(load_setup(None)))
    with pytest.raises(KinadaptError) as exc:  # nothing close: no guess
        userlog._library_for(log, load_setup(None), ["xyz"], ())
    assert "did you mean" not in str(exc.value)


def test_a_tie_inside_a_one_of_effect_names_the_two_parameters():
    rng = np.random.default_rng(4)
    R = 4000
    x = np.sin(2 * np.pi * np.linspace(0, 3, R))
    y = 3.0 * x + rng.normal(0, 0.3, R)  # both estimates above the relevant size 1
    X = {"enc": np.stack([x, 2.0 * x], axis=1)}  # two columns that fit the data equally well
    des = selection.Design(y, X, np.zeros((R, 0)), np.minimum(np.arange(R) * 20 // R, 19), 20, {"enc": np.ones(2)},
                           {"enc": True}, np.ones(R), np.zeros(R, int), ("y",), np.arange(R) * 0.01)
    entry = selection.select(des, hints={"_params": {"enc": ["offset_joint3", "offset_joint4"]}}).entries[0]
    own = [["offset_joint3", "offset_joint4"][c] for c in entry["columns_used"]]
    other = {"offset_joint3": "offset_joint4", "offset_joint4": "offset_joint3"}[own[0]]
    assert entry["verdict"] == "cannot_decide" and entry["indistinguishable_from"] == [f"enc:{other}"]
    assert selection.tie_words("enc", own, entry["indistinguishable_from"]) == \
        f"{own[0]} indistinguishable from {other}"
    assert selection.tie_words("a", ["p"], ["b"]) == "indistinguishable from b"  # another effect: as before


def test_the_user_log_summary_names_the_two_joints():
    e = {"effect": "encoder_offset", "verdict": "cannot_decide", "judged": True,
         "reason": "a near-tie: another explanation fits the data as well",
         "indistinguishable_from": ["encoder_offset:offset_joint4", "tool_tilt"],
         "estimate": {"offset_joint3": {"value": 0.5, "sd": 0.1, "unit": "deg"}}}
    txt = userlog.summary_text({"sign_check": {"ok": True}, "tip_contact_check": {"ok": True}, "ranking": [e]})
    assert "Cannot decide: encoder_offset (a near-tie: another explanation fits the data as well; offset_joint3 " \
           "indistinguishable from offset_joint4, tool_tilt)." in txt
    assert "encoder_offset:" not in txt  # never an effect indistinguishable from itself


def test_explained_only_by_undecided_effects_is_said():
    """A complete model whose final fit holds an effect the verdict leaves undecided does not read as
    an explained log: the summary names the undecided effects it needs (a snag window's ft_offset)."""
    from kinadapt_nn.diagnostics.summary import completeness_text

    rank = [{"effect": "ft_offset", "selected_round": 0, "verdict": "cannot_decide"},
            {"effect": "tool_tilt", "selected_round": None, "verdict": "cannot_decide"},
            {"effect": "tool_gravity", "selected_round": 1, "verdict": "present"}]
    txt = completeness_text({"model_complete": True, "ranking": rank})
    assert txt.startswith("The model explains the log only with effects it cannot decide (ft_offset)"), txt
    assert "tool_tilt" not in txt and "tool_gravity" not in txt
    rank[0]["verdict"] = "present"
    assert completeness_text({"model_complete": True, "ranking": rank}) == (
        "The model explains the log: no systematic residual of a relevant size is left.")


def test_a_hint_beside_undecided_effects_is_said():
    """A complete model that holds an undecided effect seeks hints beside it (``completeness.held_undecided``):
    a shape found there follows the sentence that names the undecided effects; none found, nothing more."""
    from kinadapt_nn.diagnostics.summary import completeness_text

    rank = [{"effect": "ft_offset", "selected_round": 0, "verdict": "cannot_decide"}]
    hint = {"shape": "world_force", "words": "a constant force in the world frame at a fixed point: a cable",
            "explains": 0.997, "effect_file": "hint_world_force.py"}
    txt = completeness_text({"model_complete": True, "ranking": rank, "unexplained": {"hints": [hint]}})
    assert txt.startswith("The model explains the log only with effects it cannot decide (ft_offset)"), txt
    assert txt.endswith(" Fitted beside them, a shape outside the library still explains what they leave: it looks "
                        "like world_force (a constant force in the world frame at a fixed point; explains 100% of "
                        "what they leave held-out, see hint_world_force.py)."), txt
    assert completeness_text({"model_complete": True, "ranking": rank, "unexplained": {"hints": []}}).endswith(
        "none of them is a finding.")
