"""The live monitor in the commands that run many episodes (``kinadapt compare --monitor``, ``kinadapt
sweep --monitor``, runs of several insertions and work cells) and on the batch path: each episode has
its own monitor fed its own row of the batch, so its events are the single episode's; the aggregates
say per run how many events and which shapes. A snag (``effects.world_force`` with an onset) gives one
``world_force`` event at its onset; a clean run none."""

from __future__ import annotations

import csv
import json
import tomllib
from pathlib import Path

import numpy as np
import pytest
import tomli_w

import kinadapt_nn.monitor.monitor  # noqa: F401  (registers the live monitor with the episode loop)
from kinadapt_nn.app.cli import main
from kinadapt_nn.config import load_config
from kinadapt_nn.runs.batch import run_batch, run_episodes
from kinadapt_nn.runs.episode import run_episode

REPO = Path(__file__).resolve().parents[2]
ONSET_S = 1.5
SNAG = ["effects.world_force.enabled=true", f"effects.world_force.onset_s={ONSET_S}"]


def _flat(path: Path) -> list[str]:
    """A TOML config as ``--set`` keys (a compare or sweep ``base``)."""
    return [f"{sec}.{k}={json.dumps(v)}" for sec, kv in tomllib.loads(path.read_text()).items() for k, v in kv.items()]


#: online/monitor.toml (free-space reorientations, sensor noise), 3.5 s
BASE = [*_flat(REPO / "online" / "monitor.toml"), "run.duration_s=3.5"]


def _one_snag_event(mon: dict) -> dict:
    """The single event of a snag run: a world force named at its onset."""
    assert [e["shape"] for e in mon["events"]] == ["world_force"], mon["alarms"]
    ev = mon["events"][0]
    assert ONSET_S <= ev["t_s"] < ONSET_S + 0.01
    return ev


def test_batch_path_gives_each_episode_the_single_episodes_events():
    """Three snags at different onsets stepped together -- traced (``run_episodes``: compare, cells) and
    summaries only (``run_batch``: a batched sweep) -- give each episode's monitor the events that
    episode gives alone (``run_episode``): the same samples (the batch is bit-identical to ``mj_step``),
    so the same times, channels and shapes exactly and the same estimates to rounding."""
    onsets = [1.2, 1.7, 2.2]
    cfgs = [load_config(REPO / "online/monitor.toml", ["run.progress=false", f"run.seed={s}", "run.duration_s=3.5",
                                                         "effects.world_force.enabled=true",
                                                         f"effects.world_force.onset_s={t}"])
            for s, t in enumerate(onsets)]
    traced = run_episodes(cfgs)
    summaries = run_batch(cfgs, nthread=1).summaries
    for c, t_on, tr, sm in zip(cfgs, onsets, traced, summaries):
        one = run_episode(c)
        ref = one.summary["monitor"]
        assert ref["events"] and t_on <= ref["events"][0]["t_s"] < t_on + 0.01  # caught at its onset (its name:
        # tests/monitor/test_monitor.py; here only that every path names it alike)
        for got in (tr.summary["monitor"], sm["monitor"]):
            assert [(e["t_s"], e["onset_s"], e["channels"], e["shape"]) for e in got["events"]] == \
                [(e["t_s"], e["onset_s"], e["channels"], e["shape"]) for e in ref["events"]]
            for e, r in zip(got["events"], ref["events"]):
                assert e["estimate"].keys() == r["estimate"].keys()
                for k, v in r["estimate"].items():  # every number of the estimate (the shape's parameters, sds)
                    if isinstance(v, (int, float, list)):
                        np.testing.assert_allclose(e["estimate"][k], v, rtol=1e-12, atol=1e-15, err_msg=k)
                    else:
                        assert e["estimate"][k] == v, k
            np.testing.assert_allclose(got["noise_sd"], ref["noise_sd"], rtol=1e-12)
        np.testing.assert_array_equal(tr.trace["monitor_z"], one.trace["monitor_z"])


def test_compare_monitor_reports_each_runs_events(tmp_path):
    """``kinadapt compare --monitor``: the table's monitor columns (events per run, the shapes),
    ``monitor.json`` and each run's TensorBoard (residual / noise scalars, the event as text)."""
    cfg = {"features": ["adjoint"], "families": ["nominal"], "n_tools": 2, "lateral_radius_m": 0.0,
           "length_spread_m": 0.0, "jobs": 1, "base": BASE, "scenarios": {"snag": SNAG, "clean": []}}
    (tmp_path / "compare.toml").write_text(tomli_w.dumps(cfg))
    out = tmp_path / "cmp"
    rc = main(["compare", "--config", str(tmp_path / "compare.toml"), "--monitor", "--out", str(out), "--quiet"])
    assert rc == 0
    rows = {r["scenario"]: r for r in csv.DictReader(open(out / "comparison.csv"))}
    assert (rows["snag"]["monitor_events"], rows["snag"]["monitor_shapes"]) == ("1 1", "world_force x2")
    assert (rows["clean"]["monitor_events"], rows["clean"]["monitor_shapes"]) == ("0 0", "-")
    runs = json.loads((out / "monitor.json").read_text())
    assert sorted(runs) == [f"{s}/nominal/adjoint/frozen/tool{i}" for s in ("clean", "snag") for i in (0, 1)]
    for i in (0, 1):
        _one_snag_event(runs[f"snag/nominal/adjoint/frozen/tool{i}"]["monitor"])
        assert runs[f"clean/nominal/adjoint/frozen/tool{i}"]["events"] == 0
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    acc = EventAccumulator(str(out / "tb" / "snag" / "nominal" / "adjoint" / "tool0"),
                           size_guidance={"tensors": 0, "scalars": 0})
    acc.Reload()
    assert "monitor/residual_over_noise_F_y" in acc.Tags()["scalars"]
    assert b"looks like world_force" in acc.Tensors("monitor/events")[0].tensor_proto.string_val[0]


@pytest.mark.parametrize("batch", [False, True])
def test_sweep_monitor_records_events_batched_or_not(tmp_path, batch):
    """``kinadapt sweep --monitor``, episode by episode and batched: each record's events, shapes and
    first event's time, and each group's monitor statistics."""
    cfg = {"seeds": 2, "random_tools": False, "jobs": 1, "batch": batch, "base": BASE,
           "groups": {"snag": SNAG, "clean": []}}
    (tmp_path / "sweep.toml").write_text(tomli_w.dumps(cfg))
    out = tmp_path / "sw"
    assert main(["sweep", "--config", str(tmp_path / "sweep.toml"), "--monitor", "--out", str(out), "--quiet"]) == 0
    recs = {r["id"]: r for r in csv.DictReader(open(out / "sweep.csv"))}
    for s in (0, 1):
        snag, clean = recs[f"snag-s{s}"], recs[f"clean-s{s}"]
        assert (snag["monitor_events"], snag["monitor_shapes"]) == ("1", "world_force")
        assert ONSET_S <= float(snag["monitor_first_event_s"]) < ONSET_S + 0.01
        assert (clean["monitor_events"], clean["monitor_shapes"], clean["monitor_first_event_s"]) == ("0", "", "")
    groups = json.loads((out / "sweep.json").read_text())["groups"]
    assert groups["snag"]["monitor"] == {"episodes": 2, "episodes_with_events": 2, "events": 2,
                                         "shapes": {"world_force": 2}}
    assert groups["clean"]["monitor"] == {"episodes": 2, "episodes_with_events": 0, "events": 0, "shapes": {}}


def test_each_insertion_has_its_own_monitor(tmp_path, capsys):
    """``kinadapt online --monitor`` of several insertions (a work cell's path): a new monitor each
    insertion, each insertion's row says what it found, and the summary lines list them."""
    out = tmp_path / "run"
    rc = main(["online", "--config", str(REPO / "online" / "monitor.toml"), "--monitor", "--out", str(out),
               "--set", "run.insertions=2", "--set", "run.duration_s=3.5", "--set", "run.progress=false",
               *[a for s in SNAG for a in ("--set", s)]])
    assert rc == 0
    summ = json.loads((out / "summary.json").read_text())
    assert [(r["monitor_events"], r["monitor_shapes"]) for r in summ["insertions"]] == [(1, ["world_force"])] * 2
    _one_snag_event(summ["monitor"])  # the last insertion's monitor
    assert "events per insertion: 1: 1 (world_force); 2: 1 (world_force)" in capsys.readouterr().out


def _set_flag() -> None:
    import os

    os.environ["KINADAPT_TEST_WORKER_SETUP"] = "ran"


def _flag_of(task, report) -> list:
    import os

    report(1)
    return [os.environ.get("KINADAPT_TEST_WORKER_SETUP")]


def test_runner_calls_the_setup_in_each_worker():
    """``runs.jobs.Runner(setup=...)``: the worker processes call it before their first task (how
    ``--monitor`` registers the live monitor in them); this process is left as it was."""
    import os

    from kinadapt_nn.runs.jobs import Runner, Task

    with Runner(1, setup=_set_flag) as runner:
        got = runner.run(_flag_of, [Task(jobs=(0,)), Task(jobs=(1,))], "probe")
    assert got == [["ran"], ["ran"]]
    assert "KINADAPT_TEST_WORKER_SETUP" not in os.environ
