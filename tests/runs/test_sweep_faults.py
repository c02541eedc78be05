"""Sweeps (resumable, aggregated), sensor faults, and bad input everywhere (property-based)."""

from __future__ import annotations

import json
import math
import signal
import subprocess
import sys
import time
import zipfile

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from kinadapt_nn.app.cli import main
from kinadapt_nn.config import load_config
from kinadapt_nn.runs.episode import run_episode
from kinadapt_nn.errors import ConfigError, KinadaptError
from kinadapt_nn.runs.sweep import load_sweep_config, run_sweep, wilson_interval


def test_wilson_interval_against_known_values():
    """Wilson 95 %: 0/10 -> [0, 0.278]; 10/10 -> [0.722, 1]; 50/100 -> [0.404, 0.596]."""
    assert wilson_interval(0, 10) == pytest.approx((0.0, 0.2775), abs=1e-3)
    assert wilson_interval(10, 10) == pytest.approx((0.7225, 1.0), abs=1e-3)
    assert wilson_interval(50, 100) == pytest.approx((0.4038, 0.5962), abs=1e-3)


def test_faults_never_let_nan_into_theta_or_the_command():
    """10 % dropouts (NaN samples) plus noise: the episode runs, theta and q_ref stay finite, the
    dropouts are counted; a long NaN burst stops the episode cleanly as divergence."""
    r = run_episode(load_config(None, ["faults.ft_dropout_prob=0.1", "faults.ft_noise_N=0.5", "run.duration_s=3.0"]))
    assert r.summary["sensor_dropouts"] > 100
    assert np.isfinite(r.trace["theta"]).all() and np.isfinite(r.trace["q_ref_rad"]).all()
    assert np.isfinite(r.trace["xi"]).all()
    from kinadapt_nn.runs.build import make_controller

    ctrl = make_controller(load_config(None, []))
    q = np.array([0.0, -0.5, 0.0, -2.3, 0.0, 1.8, 0.8])
    ctrl.step(0.0, q, np.zeros(7), np.zeros(6))
    bad = np.full(6, np.nan)
    for k in range(ctrl.max_hold_steps):
        cmd = ctrl.step(0.001 * (k + 1), q, np.zeros(7), bad)
        assert np.isfinite(cmd.q_ref_rad).all()
    with pytest.raises(KinadaptError, match="in a row"):
        ctrl.step(1.0, q, np.zeros(7), bad)


def test_fault_latency_delays_the_samples():
    from kinadapt_nn.config import FaultsCfg
    from kinadapt_nn.sim.adapter import SensorSample
    from kinadapt_nn.sim.adapter import SensorFaults

    f = SensorFaults(FaultsCfg(latency_steps=2), seed=0, bias_onset_s=0.3)
    seen = [f(0.001 * k, SensorSample(np.full(7, k), np.zeros(7), np.zeros(6))).q_rad[0] for k in range(6)]
    assert seen == [0, 0, 0, 1, 2, 3]


def test_sweep_aggregates_and_resumes(tmp_path):
    cfg = load_sweep_config(None, ["seeds=2", "jobs=1", "base=['run.duration_s=1.0']",
                                   "groups={a=[], b=['faults.ft_noise_N=0.5']}"])
    out = tmp_path / "sw"
    s = run_sweep(cfg, out, progress=False)
    assert s["episodes"] == 4 == s["episodes_expected"]
    assert set(s["groups"]) == {"a", "b"} and s["groups"]["a"]["failures"] == {"timeout": 2}
    lines = (out / "sweep.csv").read_text().strip().splitlines()
    assert len(lines) == 5 and lines[0].startswith("id,group,seed")
    first = (out / "episodes" / "a-s0.json").stat().st_mtime_ns
    (out / "episodes" / "b-s1.json").unlink()
    s2 = run_sweep(cfg, out, progress=False)  # only b-s1 is run again
    assert s2["episodes"] == 4 and (out / "episodes" / "a-s0.json").stat().st_mtime_ns == first
    other = load_sweep_config(None, ["seeds=3"])
    with pytest.raises(KinadaptError, match="different sweep"):
        run_sweep(other, out, progress=False)


def test_batched_sweep_records_what_the_episode_by_episode_sweep_records(tmp_path):
    """``batch = true``: the groups' seeds stepped together (faults on, one group's seeds split
    over two tasks) give every column they share with the episode-by-episode sweep, to the last
    digit, and the same aggregate; resuming runs only what is missing."""
    import csv

    from kinadapt_nn.runs.sweep import episode_jobs, sweep_tasks

    over = ["seeds=3", "jobs=2", "base=['run.stop_after_seat_s=0.05','start.lateral_jitter_m=0.0003']",
            "groups={a=[], b=['faults.ft_noise_N=0.5','faults.ft_dropout_prob=0.05']}"]
    one = run_sweep(load_sweep_config(None, over), tmp_path / "one", progress=False)
    cfg = load_sweep_config(None, [*over, "batch=true", "batch_size=2"])
    tasks = sweep_tasks(cfg, episode_jobs(cfg))
    assert [len(t.jobs) for t in tasks] == [2, 1, 2, 1] and all(len({j.group for j in t.jobs}) == 1 for t in tasks)
    assert [t.episodes for t in tasks] == [2, 1, 2, 1]
    bat = run_sweep(cfg, tmp_path / "bat", progress=False)
    for k in ("total", "groups"):
        assert bat[k] == one[k]
    rows = {n: {r["id"]: r for r in csv.DictReader(open(tmp_path / n / "sweep.csv"))} for n in ("one", "bat")}
    cols = [c for c in next(iter(rows["bat"].values())) if c not in ("wall_time_s", "compile_time_s")]  # wall times
    assert {"success", "failure", "seat_time_s", "max_force_N", "offset_error_final_m_0", "steps"} <= set(cols)
    assert all(rows["bat"][i][c] == rows["one"][i][c] for i in rows["one"] for c in cols)
    assert bat["total"]["successes"] == 6
    (tmp_path / "bat" / "episodes" / "b-s2.json").unlink()
    assert run_sweep(cfg, tmp_path / "bat", progress=False)["episodes"] == 6


def test_sweep_of_repeated_insertions_runs_every_insertion_batched_or_not(tmp_path):
    """``run.insertions = 2`` in a sweep: each record is the whole run judged from the first
    insertion's start to the last one's end (both seated, insertions_seated = 2), what
    run_insertions gives; ``batch = true`` steps the seeds' insertions together
    (runs.insertions.run_cells) and records the same, to the last digit."""
    import csv

    from kinadapt_nn.runs.insertions import run_insertions
    from kinadapt_nn.runs.sweep import episode_jobs

    over = ["seeds=2", "jobs=1", "base=['run.stop_after_seat_s=0.05','start.lateral_jitter_m=0.0003',"
            "'run.insertions=2']"]
    one = run_sweep(load_sweep_config(None, over), tmp_path / "one", progress=False)
    bat = run_sweep(load_sweep_config(None, [*over, "batch=true"]), tmp_path / "bat", progress=False)
    rows = {n: {r["id"]: r for r in csv.DictReader(open(tmp_path / n / "sweep.csv"))} for n in ("one", "bat")}
    cols = [c for c in next(iter(rows["one"].values())) if c not in ("wall_time_s", "compile_time_s")]  # wall times
    assert {"insertions_seated", "success", "failure", "seat_time_s"} <= set(cols)
    assert all(rows["bat"][i][c] == rows["one"][i][c] for i in rows["one"] for c in cols)
    assert one["total"] == bat["total"] and one["total"]["successes"] == 2
    job = episode_jobs(load_sweep_config(None, over))[1]
    alone = run_insertions(load_config(None, job.overrides)).summary
    assert len(alone["insertions"]) == 2 and rows["one"][job.id]["insertions_seated"] == "2"
    assert float(rows["one"][job.id]["seat_time_s"]) == alone["seat_time_s"]  # the last insertion's


def test_killed_sweep_completes_every_episode_exactly_once(tmp_path):
    """SIGINT mid-way, then the same command: every episode once, finished ones not rerun."""
    out = tmp_path / "kill"
    n = 16  # enough episodes that the interrupt lands mid-way (an episode takes ~0.2 s)
    cmd = [sys.executable, "-m", "kinadapt_nn.app.cli", "sweep", "--out", str(out), "--quiet",
           "--set", f"seeds={n}", "--set", "jobs=1", "--set", "base=['run.duration_s=5.0']"]
    # SIGINT at its default in the child: a shell that starts the tests in the background sets it to
    # SIG_IGN, which the child would inherit (and then finish every episode)
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    t0 = time.time()
    while time.time() - t0 < 60:
        if len(list((out / "episodes").glob("*.json"))) >= 2:
            break
        time.sleep(0.05)
    p.send_signal(signal.SIGINT)
    p.wait(timeout=60)
    before = {f.name: f.stat().st_mtime_ns for f in (out / "episodes").glob("*.json")}
    assert 2 <= len(before) < n
    assert subprocess.run(cmd, capture_output=True).returncode == 0
    after = {f.name: f.stat().st_mtime_ns for f in (out / "episodes").glob("*.json")}
    assert len(after) == n and all(after[k] == v for k, v in before.items())
    rows = (out / "sweep.csv").read_text().strip().splitlines()[1:]
    ids = [r.split(",")[0] for r in rows]
    assert sorted(ids) == sorted(set(ids)) and len(ids) == n
    assert not list(out.rglob("*.tmp"))


# ------------------------------------------------------------------ property-based bad input
KEYS = ["run.seed", "run.dt_s", "run.duration_s", "control.gain_trans", "tool.offset_f_m", "start.tilt_deg",
        "adaptation.eta", "adaptation.mode", "sensing.channel_scale", "faults.latency_steps", "nonsense.key",
        "arm.joint_offset_rad", "features.rbf_n_centres", "scene.friction", "tool.tilt_deg", "start.lateral_w_m",
        "scene.bore_entry_w_m", "sensing.nominal_offset_f_m", "adaptation.initial_error_dir_f", "control.dither_rad_s",
        "excite.segments"]
VALUES = st.one_of(st.integers(-10**6, 10**6), st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=12),
                   st.lists(st.floats(-1, 1), max_size=9), st.booleans(),
                   st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=2, max_size=7))


def _toml(value) -> str:
    """A value as TOML text (JSON, with TOML's nan/inf spellings)."""
    if isinstance(value, float) and not math.isfinite(value):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf")
    if isinstance(value, list):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    return json.dumps(value)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(key=st.sampled_from(KEYS), value=VALUES)
def test_any_override_is_valid_or_a_one_line_config_error(key, value):
    text = _toml(value) if not isinstance(value, str) else value
    try:
        load_config(None, [f"{key}={text}"])
    except ConfigError as exc:
        assert "\n" not in str(exc) and len(str(exc)) < 400
        return
    finite = [v for v in (value if isinstance(value, list) else [value]) if isinstance(v, float)]
    assert all(math.isfinite(v) for v in finite), f"{key}={text} was accepted"  # NaN/inf never gets through


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(blob=st.binary(max_size=400))
def test_garbage_config_trace_and_checkpoint_files_are_one_line_errors(tmp_path, blob):
    from kinadapt_nn.learning.checkpoint import load_checkpoint
    from kinadapt_nn.trace import Trace

    p = tmp_path / "f"
    p.write_bytes(blob)
    for loader in (lambda: load_config(p), lambda: Trace.load(p), lambda: load_checkpoint(p)):
        try:
            loader()
        except KinadaptError as exc:
            assert "\n" not in str(exc).strip()


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(members=st.dictionaries(st.sampled_from(["meta", "t_s", "q_rad", "x"]), st.binary(max_size=64), max_size=4))
def test_zip_files_that_are_not_traces(tmp_path, members):
    from kinadapt_nn.trace import Trace

    p = tmp_path / "t.npz"
    with zipfile.ZipFile(p, "w") as z:
        for k, v in members.items():
            z.writestr(k + ".npy", v)
    with pytest.raises(KinadaptError):
        Trace.load(p)


def test_cli_exit_2_on_bad_sweep_and_compare_configs(tmp_path, capsys):
    assert main(["sweep", "--out", str(tmp_path / "s"), "--set", "groups={g=['tool.side_m=1']}", "--quiet"]) == 2
    assert main(["compare", "--out", str(tmp_path / "c"), "--set", "features=['bogus']", "--quiet"]) == 2
    assert main(["pretrain", "--out", str(tmp_path / "p"), "--set", "train.steps=-1", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("kinadapt: error:") == 3 and "Traceback" not in err
    assert not any(tmp_path.iterdir())


@pytest.mark.slow
def test_ray_sweep_matches_the_local_sweep(tmp_path):
    """For real: ``--executor ray`` without ``--address`` starts a Ray of the command's own (on
    127.0.0.1) and stops it at the end -- no other Ray on the machine is touched; 32 episodes,
    the same rows as the local executor."""
    ray = pytest.importorskip("ray")
    import csv

    sets = ["--set", "seeds=16", "--set", "groups={a=[], b=['faults.ft_noise_N=0.5']}", "--quiet"]
    assert main(["sweep", "--out", str(tmp_path / "ray"), "--executor", "ray", *sets]) == 0
    assert not ray.is_initialized()  # the command's own Ray is shut down
    assert main(["sweep", "--out", str(tmp_path / "local"), *sets]) == 0

    def rows(p):
        return {r["id"]: {k: v for k, v in r.items() if k not in ("wall_time_s", "compile_time_s")} for r in csv.DictReader(open(p))}

    a, b = rows(tmp_path / "ray" / "sweep.csv"), rows(tmp_path / "local" / "sweep.csv")
    assert len(a) == 32 and a == b
