"""The live monitor against ``kinadapt diagnose`` of the same run (``kinadapt_nn.monitor.agreement``;
``benchmarks/monitor_agreement.py`` measures it on the five onset scenarios): the map between the two
vocabularies, what each side names, and -- slow -- agreement on the scenarios where it holds."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from kinadapt_nn.diagnostics.builtin import BUILTINS
from kinadapt_nn.diagnostics.completeness import SHAPES as HINT_SHAPES
from kinadapt_nn.monitor.agreement import OFFLINE_NAME, agreement, diagnosis_names, monitor_names
from kinadapt_nn.monitor.shapes import SHAPES

REPO = Path(__file__).resolve().parents[2]


def test_every_monitor_shape_has_one_offline_name_of_the_diagnosis():
    """One to one, every shape mapped, and each name one the diagnosis gives: a built-in effect or a
    hint shape."""
    assert set(OFFLINE_NAME) == set(SHAPES)
    assert len(set(OFFLINE_NAME.values())) == len(OFFLINE_NAME)
    for kind, name in OFFLINE_NAME.values():
        assert name in (BUILTINS if kind == "effect" else HINT_SHAPES), (kind, name)


def _report(verdicts: dict, hints: list[str]) -> dict:
    return {"ranking": [{"effect": e, "verdict": v} for e, v in verdicts.items()],
            "unexplained": {"hints": [{"shape": h} for h in hints]}}


def test_names_on_each_side():
    """The diagnosis names its present effects and its leading hint only; the monitor its open events."""
    rep = _report({"tool_gravity": "present", "tool_tilt": "cannot_decide", "ft_offset": "absent"},
                  ["world_force", "wrench_linear"])
    assert diagnosis_names(rep) == ["effect:tool_gravity", "hint:world_force"]
    mon = {"events": [{"shape": "world_force", "open": True}, {"shape": "tool_gravity", "open": True},
                      {"shape": "ft_bias_drift", "open": False}]}
    assert monitor_names(mon) == ["effect:tool_gravity", "hint:world_force"]
    a = agreement(mon, rep)
    assert a.agree and a.contained and a.monitor == ["world_force", "tool_gravity"]
    b = agreement(mon, _report({"tool_gravity": "present"}, ["wrench_linear", "world_force"]))  # a world force second
    assert not b.agree and not b.contained and b.diagnosis == ["effect:tool_gravity", "hint:wrench_linear"]
    assert agreement({"events": []}, _report({}, [])).agree  # nothing on either side


#: (scenario, seed, which diagnosis agrees on it) where benchmarks/results/monitor_agreement_*.txt measured
#: agreement: "whole" the run folder's ``kinadapt diagnose``, "segment" the log from the monitor's onset on
AGREES = [("payload", 0, "segment"), ("drift", 1, "whole")]


@pytest.mark.slow
@pytest.mark.parametrize("name,seed,which", AGREES)
def test_monitor_and_diagnosis_agree_where_measured(tmp_path, name, seed, which):
    """``kinadapt online --monitor`` then ``kinadapt diagnose`` of the run (or of its log from the
    monitor's onset on): the same names at the end of the run."""
    sys.path.insert(0, str(REPO / "benchmarks"))
    from monitor_agreement import SETTLE_S, run_and_diagnose, segment_report

    r = run_and_diagnose(name, seed, tmp_path)
    opened = [e for e in r["monitor"]["events"] if e["open"]]
    assert opened, r["monitor"]["alarms"]
    rep = r["report"] if which == "whole" else segment_report(r["run"], opened[0]["onset_s"] + SETTLE_S)
    a = agreement(r["monitor"], rep)
    assert a.agree, a
