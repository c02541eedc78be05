"""Hints beside the undecided effects a complete model holds (``completeness.held_undecided``): sought only
where, without those effects, a relevant structured residual is left (``completeness.without_held``). The
snag's side (a hint found there, the pull and its point recovered) is ``tests/monitor/test_agreement.py``'s
slow snag case; this is the other side: an effect-free excitation run, whose model holds an undecided
``tool_tilt`` (the nominal tool is not the true one) that stands in for nothing relevant, gets no hint."""

from __future__ import annotations

import pytest

from tests.diagnostics.excite_runs import diagnosed_excite_run


@pytest.mark.slow
def test_effect_free_run_holding_an_undecided_effect_gets_no_hint():
    _, _, rep = diagnosed_excite_run(["run.seed=0"], hints=True, name="effect-free")
    held = [e["effect"] for e in rep["ranking"] if e.get("selected_round") is not None and e["verdict"] != "present"]
    assert rep["model_complete"] is True and not [e for e in rep["ranking"] if e["verdict"] == "present"]
    if not held:  # nothing held: the rule is not exercised by this run (the excitation or the tool changed)
        pytest.skip("the final model holds no undecided effect on this run")
    assert rep["summary"].find(f"only with effects it cannot decide ({', '.join(held)})") >= 0
    assert not rep["unexplained"]["hints"], [h["shape"] for h in rep["unexplained"]["hints"]]
    assert "Fitted beside them" not in rep["summary"]
