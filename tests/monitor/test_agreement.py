"""The live monitor against ``kinadapt diagnose`` of the same run (``kinadapt_nn.monitor.agreement``;
``benchmarks/monitor_agreement.py`` measures it on the five onset scenarios): the map between the two
vocabularies, what each side names, and -- slow -- agreement on the scenarios where it holds."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from kinadapt_nn.effects.builtin import BUILTINS
from kinadapt_nn.diagnostics.completeness import SHAPES as HINT_SHAPES
from kinadapt_nn.monitor.agreement import OFFLINE_NAME, agreement, diagnosis_names, monitor_names
from kinadapt_nn.monitor.shapes import END_SHAPES, SHAPES

REPO = Path(__file__).resolve().parents[2]


def test_every_monitor_shape_has_one_offline_name_of_the_diagnosis():
    """One to one, every shape mapped, and each name one the diagnosis gives: a built-in effect or a
    hint shape (the end-of-run look's shapes: the live ones and ``encoder_offset``)."""
    assert set(OFFLINE_NAME) == set(END_SHAPES) and set(SHAPES) < set(END_SHAPES)
    assert len(set(OFFLINE_NAME.values())) == len(OFFLINE_NAME)
    for kind, name in OFFLINE_NAME.values():
        assert name in (BUILTINS if kind == "effect" else HINT_SHAPES), (kind, name)


def _report(verdicts: dict, hints: list[str], ties: dict | None = None) -> dict:
    ties = ties or {}
    return {"ranking": [{"effect": e, "verdict": v, "indistinguishable_from": ties.get(e)} for e, v in verdicts.items()],
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
    assert a.agree and a.same_ties and a.names_equal and a.contained and a.monitor == ["world_force", "tool_gravity"]
    b = agreement(mon, _report({"tool_gravity": "present"}, ["wrench_linear", "world_force"]))  # a world force second
    assert not b.agree and not b.contained and b.diagnosis == ["effect:tool_gravity", "hint:wrench_linear"]
    assert agreement({"events": []}, _report({}, [])).agree  # nothing on either side


def test_the_end_of_run_look_is_what_the_monitor_says_at_the_end():
    """An open event's end-of-run look (``at_end``) replaces its live shape and ties; without one the live
    ones stand."""
    ev = {"shape": "sensor_constant", "open": True, "ties": ["ft_bias_drift"],
          "at_end": {"shape": "ft_frame_rotation", "ties": []}}
    a = agreement({"events": [ev]}, _report({"ft_frame_rotation": "present"}, []))
    assert a.agree and a.monitor == ["ft_frame_rotation"] and a.undecided == {}
    live = {**ev, "at_end": None}
    b = agreement({"events": [live]}, _report({"ft_offset": "present"}, []))
    assert b.monitor_as_offline == ["effect:ft_offset"] and b.undecided == {"effect:ft_offset": ["effect:ft_bias_drift"]}
    assert not b.agree  # the monitor leaves it undecided, the diagnosis finds it present


def test_an_undecided_event_agrees_with_a_near_tie():
    """The monitor cannot tell the tilt from a payload shape; the diagnosis leaves tool_tilt undecided as a
    near-tie: agree, with the same ties when the diagnosis's tie set within the monitor's vocabulary is the
    monitor's (``tool_inertia``, which the monitor has no shape for, does not count; ``encoder_offset``, a rival
    of its end-of-run look, does). A tilt the diagnosis finds present, or cannot decide for too little
    excitation (no near-tie), does not agree."""
    mon = {"events": [{"shape": "tool_tilt", "open": True, "at_end": {"shape": "tool_tilt", "ties": ["tool_gravity"]}}]}
    pair = _report({"tool_tilt": "cannot_decide", "tool_gravity": "cannot_decide"}, [],
                   {"tool_tilt": ["tool_gravity", "tool_inertia"]})
    a = agreement(mon, pair)
    assert a.agree and a.same_ties and not a.names_equal and a.compatible
    enc = _report({"tool_tilt": "cannot_decide"}, [], {"tool_tilt": ["tool_gravity", "encoder_offset"]})
    assert agreement(mon, enc).agree and not agreement(mon, enc).same_ties
    three = _report({"tool_tilt": "cannot_decide"}, [], {"tool_tilt": ["tool_gravity", "ft_offset"]})
    b = agreement(mon, three)
    assert b.agree and not b.same_ties
    assert not agreement(mon, _report({"tool_tilt": "present"}, [])).agree
    assert not agreement(mon, _report({"tool_tilt": "cannot_decide"}, [])).agree
    decided = {"events": [{"shape": "tool_tilt", "open": True, "at_end": {"shape": "tool_tilt", "ties": []}}]}
    assert not agreement(decided, pair).agree  # the monitor decided what the diagnosis cannot


def test_the_monitors_effect_file_names_its_hint_shape():
    """``kinadapt diagnose --effects monitor_world_force.py``: that effect judged present names the world
    force, as a leading hint would."""
    snag = {"events": [{"shape": "world_force", "open": True, "at_end": {"shape": "world_force", "ties": []}}]}
    rep = _report({"monitor_world_force": "present", "ft_offset": "absent"}, [])
    assert diagnosis_names(rep) == ["hint:world_force"]
    assert agreement(snag, rep).agree
    assert not agreement(snag, _report({"monitor_world_force": "cannot_decide"}, [])).agree


def _payload_event(mass_kg: float, com_s_m: list[float]) -> dict:
    return {"shape": "tool_gravity", "open": True,
            "estimate": {"mass_kg": mass_kg, "mass_sd_kg": 1e-4, "com_s_m": com_s_m}}


def test_a_payload_implies_its_inertia_where_relevant():
    """A payload of m at c adds at least m (|c|^2 - c_i^2) to the inertia's diagonal about O (a point mass,
    parallel axes): 0.5 kg 50 mm along z -> 1.25e-3 kg m^2 about x and y, beyond tool_inertia's relevant
    5e-4, so the event names tool_inertia too; 0.1 kg 50 mm out (2.5e-4) or 0.5 kg at O does not."""
    from kinadapt_nn.diagnostics.userlog import BUILTINS as LIB
    from kinadapt_nn.monitor.agreement import implied_names, payload_inertia_kg_m2

    ev = _payload_event(0.5, [0.0, 0.0, 0.05])
    m = 0.5 - 2e-4  # the mass less 2 sd
    assert np.allclose(payload_inertia_kg_m2(ev["estimate"]), [m * 0.05**2, m * 0.05**2, 0.0], rtol=1e-12, atol=1e-15)
    assert max(LIB["tool_inertia"].relevant[:3]) < m * 0.05**2
    assert implied_names(ev) == ["effect:tool_inertia"]
    assert monitor_names({"events": [ev]}) == ["effect:tool_gravity", "effect:tool_inertia"]
    assert implied_names(_payload_event(0.1, [0.05, 0.0, 0.0])) == []  # 2.5e-4 about y and z: below relevance
    assert implied_names(_payload_event(0.5, [0.0, 0.0, 0.0])) == []
    assert implied_names({"shape": "world_force", "open": True, "estimate": {"size_N": 1.5}}) == []
    # implied, not measured: the diagnosis may confirm it or leave it undecided, not find it absent
    mon = {"events": [ev]}
    assert agreement(mon, _report({"tool_gravity": "present", "tool_inertia": "present"}, [])).agree
    undecided = agreement(mon, _report({"tool_gravity": "present", "tool_inertia": "cannot_decide"}, []))
    assert undecided.agree and not undecided.names_equal
    assert not agreement(mon, _report({"tool_gravity": "present", "tool_inertia": "absent"}, [])).agree


def test_compatible_is_no_contradiction():
    """Compatible: the diagnosis names nothing the monitor does not, and what the monitor names the
    diagnosis names or cannot decide on; a name the diagnosis judges absent is a contradiction."""
    mon = {"events": [{"shape": "ft_frame_rotation", "open": True}]}
    undecided = _report({"ft_frame_rotation": "cannot_decide", "ft_offset": "cannot_decide"}, [])
    a = agreement(mon, undecided)
    assert not a.agree and a.compatible
    assert not agreement(mon, _report({"ft_frame_rotation": "absent"}, [])).compatible
    assert not agreement(mon, _report({"ft_frame_rotation": "cannot_decide", "ft_offset": "present"}, [])).compatible
    snag = {"events": [{"shape": "world_force", "open": True}]}
    assert not agreement(snag, _report({}, ["wrench_linear", "world_force"])).compatible  # another shape leads
    assert not agreement(snag, _report({}, [])).compatible  # the model complete: nothing left for a world force
    assert agreement(snag, _report({"tool_gravity": "cannot_decide"}, ["world_force", "time"])).agree


#: (scenario, seed, what holds) where benchmarks/results/monitor_agreement_*.txt measured it for ``kinadapt
#: diagnose`` of the run folder (from the monitor's event on; the snag's with the monitor's effect file, and
#: its plain diagnosis too: the world force its leading hint, ``completeness.held_undecided``):
#: "agree" (the module docstring's rule), "same" (agree, with the same near-ties)
CASES = [("payload", 1, "agree"), ("drift", 2, "agree"), ("frame rotation", 1, "agree"), ("slip", 1, "same"),
         ("snag", 2, "agree")]


@pytest.mark.slow
@pytest.mark.parametrize("name,seed,holds", CASES)
def test_monitor_and_diagnosis_where_measured(tmp_path, name, seed, holds):
    """``kinadapt online --monitor`` then ``kinadapt diagnose`` of the run folder (the log from the
    monitor's first open event on, the part before its baseline; a hint-shaped event's effect file passed
    with ``--effects``): the names at the end of the run."""
    sys.path.insert(0, str(REPO / "benchmarks"))
    from monitor_agreement import onset_of, run_and_diagnose

    r = run_and_diagnose(name, seed, tmp_path)
    opened = [e for e in r["monitor"]["events"] if e["open"]]
    assert opened and all(e["at_end"] for e in opened), r["monitor"]["alarms"]
    win, log = r["report"]["window"], r["report"]["log"]
    onset = min(e["onset_s"] for e in opened)
    assert win["onset_s"] == onset and onset >= onset_of(seed) - 0.05  # the event at the effect's onset, not before
    assert log["duration_s"] < 6.0 - onset and win["before"]["present"] == []  # the window; an effect-free baseline
    a = agreement(r["monitor"], r["files"])
    assert a.same_ties if holds == "same" else a.agree, a
    if name == "snag":  # the plain diagnosis names it too: the leading hint beside the undecided ft_offset it holds
        assert r["files"] is not r["report"] and agreement(r["monitor"], r["report"]).agree
        from kinadapt_nn.config import load_config

        truth = load_config(r["run"] / "config.toml").effects.world_force  # the pull and its point (flange = sensor)
        fit = r["report"]["unexplained"]["hints"][0]["fitted"]
        np.testing.assert_allclose(fit["force_w"]["value"], truth.force_w_N, atol=0.05)
        np.testing.assert_allclose(fit["point_s"]["value"], truth.point_f_m, atol=0.005)
