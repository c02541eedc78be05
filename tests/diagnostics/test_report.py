"""The ``Report`` is read-only all the way down, and writes the same JSON it was built from."""

from __future__ import annotations

import json

import numpy as np
import pytest

from kinadapt_nn.diagnostics.report import FORMAT, Provenance, Report, thaw

SECTIONS = {
    "ranking": [{"effect": "tool_gravity", "verdict": "present",
                 "estimate": {"mass": {"value": 0.25, "sd": 0.01, "unit": "kg"}}, "columns_used": [0, 1]}],
    "residual_rms_after": {"total_w": 1.5, "by_channel": [0.1, 0.2, 0.3, 0.01, 0.02, 0.03]},
    "warnings": [],
    "model_complete": True,
}


def _summary(sections) -> str:
    return f"{len(sections['ranking'])} effect(s)"


def test_nested_sections_refuse_writes():
    rep = Report.of(SECTIONS, _summary)
    writes = [
        lambda: rep["ranking"][0].__setitem__("verdict", "absent"),  # report["ranking"][0]["verdict"] = ...
        lambda: rep["ranking"][0]["estimate"]["mass"].__setitem__("value", 1.0),
        lambda: rep["ranking"].append({}),
        lambda: rep["ranking"].__setitem__(0, {}),
        lambda: rep["residual_rms_after"]["by_channel"].__setitem__(0, 9.0),
        lambda: rep["residual_rms_after"].pop("total_w"),
        lambda: rep.sections.__setitem__("warnings", ["x"]),
    ]
    for write in writes:
        with pytest.raises((TypeError, AttributeError)):
            write()
    assert rep["ranking"][0]["verdict"] == "present" and rep["residual_rms_after"]["by_channel"][0] == 0.1


def test_the_report_is_a_copy_and_arrays_are_read_only():
    sections = json.loads(json.dumps(SECTIONS))
    sections["series"] = np.arange(3.0)
    rep = Report.of(sections, _summary)
    sections["ranking"][0]["verdict"] = "absent"
    sections["series"][0] = 7.0
    assert rep["ranking"][0]["verdict"] == "present" and rep["series"][0] == 0.0
    with pytest.raises(ValueError, match="read-only"):
        rep["series"][1] = 5.0
    added = rep.with_section("rerun", {"model_effects": ["tool_gravity"]})
    with pytest.raises(AttributeError):
        added["rerun"]["model_effects"].append("x")
    assert "rerun" not in rep and added.summary == rep.summary


def test_to_json_gives_back_what_it_was_built_from():
    rep = Report.of(SECTIONS, _summary)
    js = rep.to_json(Provenance("user_log", "log.csv", "setup.toml"), 1.25)
    assert js["format"] == FORMAT and js["summary"] == "1 effect(s)" and js["wall_time_s"] == 1.25
    assert {k: js[k] for k in SECTIONS} == SECTIONS  # plain dicts and lists again, equal to the input
    assert json.loads(json.dumps(js))["ranking"] == SECTIONS["ranking"]
    js["ranking"][0]["verdict"] = "absent"  # the JSON is the caller's copy
    assert rep["ranking"][0]["verdict"] == "present" and thaw(rep["ranking"]) == SECTIONS["ranking"]


def test_a_report_pickles_and_stays_read_only():
    """A report crosses process boundaries (a pool of diagnoses): pickled and back, equal and still frozen."""
    import pickle

    rep = Report.of(SECTIONS, _summary)
    back = pickle.loads(pickle.dumps(rep))
    assert thaw(back.sections) == thaw(rep.sections) and back.summary == rep.summary
    with pytest.raises(TypeError):
        back["ranking"][0]["verdict"] = "absent"
    part = pickle.loads(pickle.dumps(rep["ranking"][0]["estimate"]))
    assert part["mass"]["value"] == 0.25
