"""The law listens (``monitor.pause_law``, docs/monitor.md): while the live monitor has an alarm being
named or an event open, the adaptive law does not step -- theta stays bit for bit, the controller acts on
its last estimate -- and summary.json says when (``monitor.law_paused_s``). A snag (``effects.world_force``
with an onset) on ``online/monitor.toml``, 2.5 s, the Kalman law from a 5 mm initial error with its
contact gate at zero so that it adapts in free space before the snag too (theta changes outside the pause)."""

from __future__ import annotations

import numpy as np
import pytest

import kinadapt_nn.monitor.monitor  # noqa: F401  (registers the live monitor with the episode loop)
from kinadapt_nn.config import load_config
from kinadapt_nn.errors import ConfigError
from kinadapt_nn.runs.batch import run_batch, run_episodes
from kinadapt_nn.runs.episode import run_episode

ONSET_S = 1.5
DT = 0.001


def _cfg(pause: bool, onset_s: float = ONSET_S):
    return load_config("online/monitor.toml", [
        "run.progress=false", "run.duration_s=2.5", "effects.world_force.enabled=true",
        f"effects.world_force.onset_s={onset_s}", "adaptation.mode=kalman", "adaptation.initial_error_m=0.005",
        "adaptation.contact_force_N=0", "adaptation.contact_moment_Nm=0", f"monitor.pause_law={str(pause).lower()}"])


@pytest.fixture(scope="module")
def runs():
    return {pause: run_episode(_cfg(pause)) for pause in (False, True)}


def test_theta_is_held_while_the_event_is_open_and_adapts_outside(runs):
    res = runs[True]
    mon = res.summary["monitor"]
    assert [e["shape"] for e in mon["events"]] == ["world_force"]
    alarm = mon["alarms"][0]["t_s"]
    assert ONSET_S <= alarm < ONSET_S + 0.01
    # one pause, to the end: from the period after the one in which the alarm's sample was judged (the monitor
    # judges a sample when the next arrives, and the flag is read before the next period's law step)
    (start, end), = mon["law_paused_s"]
    assert start == pytest.approx(alarm + 2 * DT, abs=DT / 2)
    assert mon["law_paused_at_end"] and end == pytest.approx(2.5, abs=DT / 2)
    t, theta, gate = res.trace["t_s"], res.trace["theta"], res.trace["adapt_gate"]
    # the trace's theta is the one each period used (before its law step): constant from the pause's first period on
    held = t >= start - DT / 2
    assert held.sum() > 900
    assert np.array_equal(theta[held], np.broadcast_to(theta[held][0], theta[held].shape))
    assert not gate[t >= start + DT / 2].any()  # the law's gate shows it: no step while paused
    before = (t > 0.3) & (t < ONSET_S)
    assert np.ptp(theta[before][:, 2]) > 1e-4  # it adapted before the snag (m; the axial offset)
    assert gate[before].all()


def test_without_the_switch_theta_keeps_adapting_through_the_event(runs):
    paused, free = runs[True], runs[False]
    assert "law_paused_s" not in free.summary["monitor"]
    start = paused.summary["monitor"]["law_paused_s"][0][0]
    t, theta = free.trace["t_s"], free.trace["theta"]
    before = t < start - DT / 2
    # identical up to the pause (the switch changes nothing else) ...
    np.testing.assert_array_equal(theta[before], paused.trace["theta"][before])
    # ... and after it the law goes on moving theta (m; ~0.4 mm of the axial offset in the 1 s)
    assert np.ptp(theta[t >= start][:, 2]) > 1e-4


def test_the_batch_path_pauses_too(runs):
    """The summaries-only batch (``run_batch``: ``kinadapt sweep`` with batch = true) steps the same loop:
    its final theta is the traced run's at the pause, its pauses the same."""
    b = run_batch([_cfg(True)], nthread=1)
    mon = runs[True].summary["monitor"]
    assert b.summaries[0]["monitor"]["law_paused_s"] == mon["law_paused_s"]
    t = runs[True].trace["t_s"]
    np.testing.assert_array_equal(b.theta_final[0], runs[True].trace["theta"][t >= mon["law_paused_s"][0][0] - DT / 2][0])


def test_a_traced_batch_pauses_each_episode_on_its_own_monitor(runs):
    """Two snags with different onsets stepped together (``run_episodes``: compare, cells): each episode's law
    pauses at its own event, as it does alone."""
    late = 1.9
    res = run_episodes([_cfg(True), _cfg(True, late)])
    for r, onset in zip(res, (ONSET_S, late)):
        (start, _end), = r.summary["monitor"]["law_paused_s"]
        assert onset < start < onset + 0.01
        t, theta = r.trace["t_s"], r.trace["theta"]
        held = t >= start - DT / 2
        assert np.array_equal(theta[held], np.broadcast_to(theta[held][0], theta[held].shape))
        assert np.ptp(theta[(t > onset - 0.3) & (t < onset)][:, 2]) > 0.0  # the other's pause does not stop it
    assert res[0].summary["monitor"]["law_paused_s"] == runs[True].summary["monitor"]["law_paused_s"]
    np.testing.assert_allclose(res[0].trace["theta"], runs[True].trace["theta"], rtol=0, atol=1e-12)


def test_the_switch_needs_the_monitor():
    with pytest.raises(ConfigError, match="monitor.pause_law") as e:
        load_config(None, ["monitor.pause_law=true"])
    assert "\n" not in str(e.value)
