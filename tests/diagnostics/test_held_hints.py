"""Hints beside the undecided effects a complete model holds (``completeness.held_undecided``): sought only
where, without those effects, a relevant structured residual is left (``completeness.without_held``). The
snag's side (a hint found there, the pull and its point recovered) is ``tests/monitor/test_agreement.py``'s
slow snag case; this is the other side: an effect-free excitation run, whose model holds an undecided
``tool_tilt`` (the nominal tool is not the true one) that stands in for nothing relevant, gets no hint."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]


@pytest.mark.slow
def test_effect_free_run_holding_an_undecided_effect_gets_no_hint():
    from kinadapt_nn.config import load_config
    from kinadapt_nn.diagnostics import ownrun, userlog
    from kinadapt_nn.diagnostics.importers import RawLog
    from kinadapt_nn.runs.episode import run_episode

    cfg = load_config(REPO / "online" / "excite.toml", ["run.tensorboard=false", "run.figure=false",
                                                         "run.progress=false", "run.seed=0"])
    tr = run_episode(cfg).trace
    raw = RawLog(*(np.asarray(tr[k]) for k in ("t_s", "q_rad", "qdot_rad_s", "wrench_raw_f")), "effect-free")
    log, setup = ownrun.as_log(raw, cfg)
    rep = userlog.diagnose(log, setup, hints=True).report
    held = [e["effect"] for e in rep["ranking"] if e.get("selected_round") is not None and e["verdict"] != "present"]
    assert rep["model_complete"] is True and not [e for e in rep["ranking"] if e["verdict"] == "present"]
    if not held:  # nothing held: the rule is not exercised by this run (the excitation or the tool changed)
        pytest.skip("the final model holds no undecided effect on this run")
    assert rep["summary"].find(f"only with effects it cannot decide ({', '.join(held)})") >= 0
    assert not rep["unexplained"]["hints"], [h["shape"] for h in rep["unexplained"]["hints"]]
    assert "Fitted beside them" not in rep["summary"]
