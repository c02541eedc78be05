"""``kinadapt diagnose RUN`` of a monitored run judges the log from the monitor's first open event on
(``ownrun.monitor_window``, ``ownrun.cut``), the part before as its baseline (docs/monitor.md,
"Agreement with the offline diagnosis")."""

from __future__ import annotations

import json

import numpy as np
import pytest

from kinadapt_nn.diagnostics import ownrun
from kinadapt_nn.diagnostics.importers import RawLog
from kinadapt_nn.errors import KinadaptError
from kinadapt_nn.monitor import monitor


def _event(onset: float, shape: str, open_: bool = True) -> dict:
    return {"onset_s": onset, "t_s": onset + 0.001, "shape": shape, "open": open_, "line": f"{onset:.2f} s: {shape}"}


def _folder(tmp_path, mon) -> object:
    (tmp_path / "summary.json").write_text(json.dumps({"success": True, **({} if mon is None else {"monitor": mon})}))
    return tmp_path


def test_the_window_starts_at_the_first_open_event(tmp_path):
    """Closed events do not count; the earliest open one sets the start (its onset + the monitor's settle
    time), the later ones are listed; the monitor's shapes in the order it raised them."""
    mon = {"events": [_event(0.8, "ft_bias_drift", open_=False), _event(3.1, "world_force"), _event(2.4, "tool_gravity")]}
    w = ownrun.monitor_window(_folder(tmp_path, mon))
    assert w.onset_s == 2.4 and w.from_s == pytest.approx(2.4 + monitor.SETTLE_S, abs=1e-15)
    assert w.later == (3.1,) and w.shapes == ("world_force", "tool_gravity") and w.line == "2.40 s: tool_gravity"


def test_no_window_without_an_open_event(tmp_path):
    assert ownrun.monitor_window(tmp_path) is None  # no summary.json
    assert ownrun.monitor_window(_folder(tmp_path, None)) is None  # a run without the monitor
    assert ownrun.monitor_window(_folder(tmp_path, {"events": [_event(1.0, "tool_tilt", open_=False)]})) is None
    (tmp_path / "summary.json").write_text("{not json")
    with pytest.raises(KinadaptError, match="not a run's summary.*--whole-log"):
        ownrun.monitor_window(tmp_path)


def test_settle_time_is_the_monitors():
    """The window leaves out what the monitor's own fit leaves out after an onset (one value, two layers)."""
    assert ownrun.SETTLE_S == monitor.SETTLE_S


def test_cut_keeps_the_samples_of_its_span():
    """from < t <= to, every channel the same rows (checked against the rows' own index), the source says
    which part; too few samples is a one-line error."""
    t = np.arange(0.0, 2.0, 0.001)
    idx = np.arange(len(t), dtype=float)
    raw = RawLog(t, np.tile(idx[:, None], (1, 7)), -np.tile(idx[:, None], (1, 7)), np.tile(idx[:, None], (1, 6)), "run")
    part = ownrun.cut(raw, 0.5, 1.25)
    rows = np.flatnonzero((t > 0.5) & (t <= 1.25))
    assert len(part.t_s) == len(rows) == 750 and np.array_equal(part.t_s, t[rows])
    assert np.array_equal(part.q_rad[:, 3], rows) and np.array_equal(part.wrench_raw_f[:, 5], rows)
    assert np.array_equal(part.qdot_rad_s[:, 0], -rows)
    assert part.source == "run (0.500 s to 1.250 s)"
    assert len(ownrun.cut(raw, None, 0.5).t_s) == 501 and ownrun.cut(raw, 1.5, None).source == "run (1.500 s to end)"
    with pytest.raises(KinadaptError, match="too few to diagnose"):
        ownrun.cut(raw, 1.9995, None)


def test_the_summary_leads_with_the_window():
    """A report with a ``window`` section says first where it starts and what the baseline showed."""
    from kinadapt_nn.diagnostics import summary as sm

    text = sm._window_text({"from_s": 2.93, "event": "2.91 s: a payload appeared", "later_onsets_s": [3.5],
                            "before": {"to_s": 2.91, "present": []}})
    assert text.startswith("From 2.93 s (the monitor's event, '2.91 s: a payload appeared'")
    assert "before 2.91 s no library effect is present" in text and "3.50 s fall inside" in text
    assert "names ft_offset already" in sm._window_text({"from_s": 1.0, "event": "e", "before": {"to_s": 0.98,
                                                                                                "present": ["ft_offset"]}})
    assert "not diagnosed (too short)" in sm._window_text({"from_s": 1.0, "event": "e",
                                                          "before": {"to_s": 0.98, "not_diagnosed": "too short"}})


def test_whole_log_is_for_package_runs(capsys):
    """``--whole-log`` with ``--setup`` (a user's log): one line saying it is for package runs, exit 2."""
    from kinadapt_nn.app.cli import main

    assert main(["diagnose", "log.csv", "--setup", "setup.toml", "--whole-log"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--whole-log is for this package's own runs" in err[0]
