"""The episode loop: a batch of N episodes (one ``mujoco.batch``) agrees with each episode run as a
batch of one (``run_episode``: its own MjData, ``mj_step``) -- the same kernels on physics the two
paths step differently, and a summaries-only batch (controllers built from the known config alone)
with the traced one."""

from __future__ import annotations

import numpy as np
import pytest

from kinadapt_nn.config import load_config
from kinadapt_nn.runs.batch import run_batch
from kinadapt_nn.runs.build import make_features
from kinadapt_nn.runs.episode import run_episode
from kinadapt_nn.runs.sweep import SweepCfg, tool_overrides


def test_batch_equals_single_episodes():
    """Randomised tools and starts: the same outcome and seat time as run_episode (the contact is
    chaotic, so this is a strong check that the vectorised controller is the same controller)."""
    base = ["run.progress=false", "start.lateral_jitter_m=0.0003", "start.tilt_jitter_deg=0.5", "run.stop_after_seat_s=0.05",
            "adaptation.mode=composite"]
    cfgs = [load_config(None, [*base, *tool_overrides(SweepCfg(), s), f"run.seed={s}"]) for s in range(4)]
    res = run_batch(cfgs, nthread=1)
    assert res.sim_steps > 4 * 4000
    for c, b in zip(cfgs, res.summaries):
        e = run_episode(c).summary
        assert b["success"] == e["success"]
        assert b["seat_time_s"] == pytest.approx(e["seat_time_s"], abs=2e-3)
        assert b["max_lateral_force_N"] == pytest.approx(e["max_lateral_force_N"], rel=0.05, abs=0.2)
        np.testing.assert_allclose(b["offset_error_final_m"], e["offset_error_final_m"], atol=1e-3)


def test_batch_runs_learned_features_and_the_kalman_law():
    """The batch is the same controller for every features type and law (rows from Python)."""
    cfgs = [load_config(None, ["run.progress=false", "run.features=neural", "run.duration_s=1.2", f"run.seed={s}"])
            for s in range(2)]
    res = run_batch(cfgs, nthread=1)
    assert res.theta_final.shape == (2, make_features(cfgs[0])[0].n_params)
    assert all(s["law"] == "kalman" for s in res.summaries) and np.all(np.isfinite(res.theta_final))


_TRUTH_SIDE = {
    "socket": ["scene.contact_model=socket", "control.dither_rad_s=[0.05,0.05,0.05]"],
    "faults": ["faults.ft_noise_N=0.5", "faults.ft_dropout_prob=0.05", "faults.ft_bias_N=[0.5,0,0]",
               "faults.encoder_resolution_rad=1e-5", "faults.latency_steps=2"],
    "hidden_effects": ["effects.ft_bias_drift.enabled=true", "effects.ft_frame_rotation.enabled=true",
                       "effects.tool_tilt.enabled=true"],
    "model_effects": ['model.effects=["contact_stiffness"]', "scene.contact_model=socket",
                      "control.dither_rad_s=[0.05,0.05,0.05]", "effects.contact_stiffness.enabled=true"],
    "dropout_divergence": ["faults.ft_dropout_prob=0.5", "sensing.max_dropout_s=0.002"],
    "rank_gate_model_effects": ['model.effects=["ft_bias_drift"]', "sensing.stiffness_rot_Nm_per_rad=0",
                                "sensing.stiffness_lat_N_per_m=1e-9"],
}


@pytest.mark.parametrize("case", list(_TRUTH_SIDE))
def test_batch_runs_the_truth_side_and_effect_columns_as_single_episodes(case):
    """Socket contact, simulated faults, hidden sensor and tool effects, library effect columns
    (per-episode features state, the rank gate from Python), a divergence by dropouts: each
    batch episode ends as run_episode does, to the last bit (seat time, peaks, final theta,
    control steps, failure class)."""
    from kinadapt_nn.runs.build import make_controller

    base = ["run.progress=false", "start.lateral_jitter_m=0.0003", "start.tilt_jitter_deg=0.5",
            "run.stop_after_seat_s=0.05", *_TRUTH_SIDE[case]]
    cfgs = [load_config(None, [*base, *tool_overrides(SweepCfg(), s), f"run.seed={s}"]) for s in range(2)]
    res = run_batch(cfgs, nthread=1)
    for c, b, theta_b in zip(cfgs, res.summaries, res.theta_final):
        ctrl = make_controller(c)
        e = run_episode(c, ctrl=ctrl).summary
        assert (b["success"], b["failure"], b["steps"]) == (e["success"], e["failure"], e["steps"])
        assert b["seat_time_s"] == e["seat_time_s"]
        assert (b["max_force_N"], b["max_moment_Nm"]) == (e["max_force_N"], e["max_moment_Nm"])
        np.testing.assert_array_equal(theta_b, ctrl.theta)
    expect = {"dropout_divergence": "divergence", "rank_gate_model_effects": "rank_gate"}.get(case, "none")
    assert [b["failure"] for b in res.summaries] == [expect] * 2


def _assert_same_episode(batch, single) -> None:
    """Every trace channel, the trace's meta and every summary field but the wall time equal."""
    assert set(batch.trace.arrays) == set(single.trace.arrays)
    for k, a in single.trace.arrays.items():
        np.testing.assert_array_equal(batch.trace.arrays[k], a, err_msg=k)
    assert batch.trace.meta == single.trace.meta
    sb, ss = dict(batch.summary), dict(single.summary)
    assert sb.pop("wall_time_s") > 0.0
    ss.pop("wall_time_s")
    sb.pop("compile_time_s", None), ss.pop("compile_time_s", None)  # the one-time compile: a wall time too
    assert repr(sb) == repr(ss)


_TRACED = {
    "adjoint": [],
    "rbf": ["run.features=rbf", "run.duration_s=1.5"],
    "neural_log_every_3": ["run.features=neural", "run.duration_s=1.5", "run.log_every=3"],
    **{k: _TRUTH_SIDE[k] for k in ("socket", "faults", "dropout_divergence", "rank_gate_model_effects")},
}


@pytest.mark.parametrize("case", list(_TRACED))
def test_run_episodes_equals_run_episode_to_the_last_bit(case):
    """``run_episodes`` of three (one batched physics, the truth from the batch's buffers and its
    contact sensor) gives each episode's whole trace and summary as the batch of one
    (``run_episode``) does, and leaves each controller in the same state; the episodes stop at
    different steps (seated, diverged, rank gate), so the masks of stopped episodes are used."""
    from kinadapt_nn.runs.batch import run_episodes
    from kinadapt_nn.runs.build import make_controller

    base = ["run.progress=false", "start.lateral_jitter_m=0.0003", "start.tilt_jitter_deg=0.5",
            "run.stop_after_seat_s=0.05", *_TRACED[case]]
    cfgs = [load_config(None, [*base, *tool_overrides(SweepCfg(), s), f"run.seed={s}"]) for s in range(3)]
    ctrls_b = [make_controller(c) for c in cfgs]
    got = run_episodes(cfgs, ctrls=ctrls_b, keep_regressor=True)
    steps = []
    for c, r, kb in zip(cfgs, got, ctrls_b):
        ks = make_controller(c)
        e = run_episode(c, ctrl=ks, keep_regressor=True)
        _assert_same_episode(r, e)
        np.testing.assert_array_equal(kb.state.x, ks.state.x)
        np.testing.assert_array_equal(kb.state.k, ks.state.k)
        steps.append(e.summary["steps"])
    if case in ("adjoint", "socket", "faults"):  # seated at different steps: stopped episodes masked
        assert len(set(steps)) > 1


def test_run_episodes_refuses_configs_that_cannot_share_a_batch():
    from kinadapt_nn.errors import ConfigError
    from kinadapt_nn.runs.batch import run_episodes

    with pytest.raises(ConfigError, match="run.log_every"):
        run_episodes([load_config(None, ["run.progress=false"]), load_config(None, ["run.progress=false", "run.log_every=2"])])
    with pytest.raises(ConfigError, match="KNOWN"):
        run_episodes([load_config(None, []), load_config(None, ["control.gain_trans=2.0"])])
    with pytest.raises(ConfigError, match="scene's structure"):  # the paper's contact: no pairs, pyramidal cone
        run_episodes([load_config(None, []), load_config(None, ["scene.contact_friction_timeconst_s=0"])])


def test_a_cold_first_run_prints_and_records_its_compile_once(monkeypatch, tmp_path, capsys):
    """A cold cache's compile is one phase: one "compiled ... in N s" line, and the record
    (kinadapt_compile_s.json, which bench_first_run reads) holds the summary's ``compile_time_s``
    -- not a second, near-zero phase's ("compiled ... in 23 s", then "... in 0 s", record 0.01)."""
    import json

    from kinadapt_nn.controller import core
    from kinadapt_nn.runs.batch import run_episodes

    record = tmp_path / "compile.json"
    monkeypatch.setattr(core, "_compile_record_path", lambda: record)  # not this machine's record
    monkeypatch.setattr(core, "kernels_cached", lambda: False)  # every phase cold, as a first run's
    cfg = load_config(None, ["run.tensorboard=false", "run.figure=false", "run.duration_s=0.05"])
    s = run_episodes([cfg], progress=True)[0].summary
    err = capsys.readouterr().err
    assert err.count("compiled the controller's kernels in") == 1, err
    assert json.loads(record.read_text())["seconds"] == round(s["compile_time_s"], 2) > 0.0


def test_the_warm_up_compiles_every_probed_kernel():
    """After ``compile_loop``'s warm-up (two free-space steps) every kernel a compile phase probes
    is compiled -- the contact's too -- so the cache reads warm for the rest of the process (a
    fresh process: nothing else has called them)."""
    import subprocess
    import sys

    code = ("from kinadapt_nn.config import load_config\n"
            "from kinadapt_nn.controller import core\n"
            "from kinadapt_nn.runs import batch\n"
            "core.kernels_cached = lambda: False\n"
            "core._compile_record_path = lambda: None\n"  # not this machine's record
            "batch.compile_loop(load_config(None, ['run.progress=false']))\n"
            "print([f.__name__ for f in core._CACHE_PROBES if not f.signatures])\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True)
    assert out.stdout.strip().splitlines()[-1] == "[]", out.stdout + out.stderr
