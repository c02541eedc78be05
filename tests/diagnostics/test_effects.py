"""The effects on package runs (issue 5, issue 37): hidden effects in the simulator, the online
model's effect columns against them, the one diagnosis pipeline on a package run (its set-up
generated from its config: ``ownrun``) with ``--add``, and effects adapted online."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from kinadapt_nn.app.cli import main
from kinadapt_nn.config import arm_mjcf_path, load_config
from kinadapt_nn.diagnostics import ownrun, userlog
from kinadapt_nn.diagnostics.importers import RawLog
from kinadapt_nn.effects.online import Signals, tip_twist_map, to_level
from kinadapt_nn.features.effect_library import LIBRARY
from kinadapt_nn.runs.episode import run_episode
from kinadapt_nn.runs.build import make_features
from kinadapt_nn.errors import ConfigError

REPO = Path(__file__).resolve().parents[2]
EXCITE = REPO / "online" / "excite.toml"
QUIET = ["run.tensorboard=false", "run.figure=false", "run.progress=false"]


def _online_signals(tr, cfg) -> Signals:
    """The online model's per-sample ``Signals`` of a whole run, from its trace (the controller's own
    s, tared wrench and drive flag) and the encoders (the controller's bare-arm kinematics)."""
    from kinadapt_nn.known import BORE_AXIS_W
    from kinadapt_nn.robot import ArmKinematics
    from kinadapt_nn.sensing import nominal_sensor_map

    kin = ArmKinematics(arm_mjcf_path(cfg.scene))
    q, qd, t = tr["q_rad"], tr["qdot_rad_s"], tr["t_s"] - tr["t_s"][0]
    n = len(t)
    R, twist = np.empty((n, 3, 3)), np.empty((n, 6))
    l_nom = np.asarray(cfg.sensing.nominal_offset_f_m, dtype=float)
    for i in range(n):
        k = kin.update(q[i])
        R[i], twist[i] = k.R_wf, tip_twist_map(k.R_wf, k.J_arm, l_nom) @ qd[i]
    w = tr["w_env_w"]
    r_tared = np.concatenate([np.einsum("nji,nj->ni", R, w[:, :3]), np.einsum("nji,nj->ni", R, w[:, 3:])], axis=1)
    t_tare = cfg.start.settle_s - 0.5 * cfg.sensing.tare_window_s
    i_tare = int(np.clip(np.searchsorted(t, t_tare), 0, n - 1))
    active = tr["drive_scale"] > 0
    gate = (active & (tr["s"][:, 0] >= 0.0)).astype(float)
    return Signals(t, float(np.median(np.diff(t))), tr["s"], w, r_tared, R, twist, gate, active, t_tare,
                   R[i_tare].copy(), nominal_sensor_map(cfg.sensing, BORE_AXIS_W), l_nom, q, qd, kin)


def _run(sets, duration=14.0):
    """An excitation run -> (config without its hidden effects, the online model's Signals, trace,
    the run as a RawLog)."""
    cfg = load_config(EXCITE, [*QUIET, f"run.duration_s={duration}", *sets])
    tr = run_episode(cfg).trace
    log = RawLog(tr["t_s"], tr["q_rad"], tr["qdot_rad_s"], tr["wrench_raw_f"], "test")
    model_cfg = cfg.model_copy(update={"effects": type(cfg.effects)()})  # the model does not know them
    return model_cfg, _online_signals(tr, model_cfg), tr, log


@pytest.fixture(scope="module")
def free_space_pair():
    """The free-space part of the excitation program (reorientation), with and without effects."""
    return {k: _run(s, duration=8.0) for k, s in {
        "none": [], "tool_gravity": ["effects.tool_gravity.enabled=true"],
        "ft_bias_drift": ["effects.ft_bias_drift.enabled=true"]}.items()}


@pytest.mark.parametrize("name", ["tool_gravity", "ft_bias_drift"])
def test_closed_form_columns_match_the_simulated_effect(free_space_pair, name):
    """MuJoCo's wrist sensor with a payload body / a drifting reading vs the library's closed form
    at the injected parameters: the tared wrench changes agree in free space at the holds between
    reorientations (quasi-static; the columns have no inertial terms). A wrong sign, lever or
    frame in the columns fails this by far more than the tolerance."""
    _, sig0, _, _ = free_space_pair["none"]
    cfg1, sig1, _, _ = free_space_pair[name]
    meas = to_level(sig1, sig1.w_env_w) - to_level(sig0, sig0.w_env_w)  # the measured (tared) levels
    lev, _ = LIBRARY[name].columns(sig1)
    pred = lev @ LIBRARY[name].default(load_config(None, [f"effects.{name}.enabled=true"]).effects)
    moving = np.linalg.norm(sig1.twist_tip_w[:, 3:], axis=1) > 0.01
    still = np.convolve(moving, np.ones(301), "same") == 0  # no rotation within +-150 ms
    m = sig1.active & (sig1.t_s > 0.6) & still
    err = np.abs(meas[m] - pred[m]).max(axis=0)
    scale = np.abs(meas[m]).max(axis=0)
    assert scale.max() > 0.5  # the effect is large enough to test (N)
    assert np.all(err <= 0.05 * scale.max() + 1e-3), (err, scale)


@pytest.fixture(scope="module")
def ranked():
    """The one pipeline on the excitation program's first 14 s (start jitter, seed 3) with and
    without a hidden sensor rotation, no baseline: the nominal tip is a first guess, the data's
    contact point is used and the tip fitted beside the effects (``ownrun``: ``tip_known = false``).
    (With a tip calibrated on seed 0's 14 s, z 98.6 mm against the true 100 mm, the effect-free run
    showed encoder_offset and ft_frame_rotation present: a wrong known tip is worse than none.)"""
    jitter = ["run.seed=3", "start.lateral_jitter_m=0.0005", "start.tilt_jitter_deg=1.0"]
    out = {}
    for key, sets, add in (("none", jitter, ["ft_frame_rotation"]),
                           ("rot", [*jitter, "effects.ft_frame_rotation.enabled=true"], ["ft_frame_rotation"])):
        cfg, _, _, raw = _run(sets)
        log, setup = ownrun.as_log(raw, cfg)
        out[key] = userlog.diagnose(log, setup, add, hints=False).report
    return out


def test_no_hidden_effect_nothing_present(ranked):
    """Was an expected failure while the simulated sensor read mj_forward's acceleration (~5x the
    realised one on the wrist joints: tool_inertia present); ``sim.ft_sensor`` reads the realised one."""
    assert not [r["effect"] for r in ranked["none"]["ranking"] if r["verdict"] == "present"]


def test_hidden_sensor_rotation_is_found_estimated_and_removed(ranked):
    res = ranked["rot"]
    top = next(r for r in res["ranking"] if r["effect"] == "ft_frame_rotation")
    assert top["verdict"] == "present", top
    p_hat = np.array(top["estimate_params"]["value"])
    p_true = LIBRARY["ft_frame_rotation"].default(load_config(None).effects)
    assert np.linalg.norm(p_hat - p_true) <= 0.2 * np.linalg.norm(p_true)
    before = res["residual_rms_before"]["total_w"]
    after = res["residual_rms_after"]["total_w"]
    level = ranked["none"]["residual_rms_after"]["total_w"]  # the effect-free run with the same refit
    assert after < before, (before, after)
    assert after <= 1.1 * level, (after, level)  # --add brings it to the effect-free level
    for r in res["ranking"]:  # every entry has the contract's keys
        assert {"effect", "verdict", "explained_fraction", "estimate", "excitation"} <= set(r)


def test_online_effect_columns_adapt_and_the_contact_prediction_error_falls():
    """model.effects=[contact_stiffness] beside a hidden half-stiff contact: the composite law's
    prediction step drives the effect parameter to about -0.5 (factor 0.5) and the prediction
    error in contact falls against the same run without the effect in the model."""
    base = ["effects.contact_stiffness.enabled=true", "adaptation.mode=prediction", *QUIET, "run.duration_s=16"]
    without = run_episode(load_config(EXCITE, base)).summary
    with_fx = run_episode(load_config(EXCITE, [*base, 'model.effects=["contact_stiffness"]'])).summary
    assert with_fx["model_effects"] == ["contact_stiffness"]
    assert abs(with_fx["model_effect_params"][0] - (-0.5)) < 0.1
    assert with_fx["pred_error_rms_contact_w"] < 0.7 * without["pred_error_rms_contact_w"]


def test_diagnose_cli_add_baseline_rerun_and_errors(tmp_path, capsys):
    """``kinadapt diagnose RUN``: a package run through the one pipeline, the tip calibrated on an
    effect-free run of the cell (--baseline); a hidden payload is present and --add removes it;
    --rerun repeats the online run with the effect adapted; bad names are one line."""
    base, run = tmp_path / "base", tmp_path / "run"
    common = ["--config", str(EXCITE), "--quiet", "--set", "run.duration_s=17", "--set", "run.tensorboard=false",
              "--set", "run.figure=false"]
    assert main(["online", "--out", str(base), *common]) == 0
    assert main(["online", "--out", str(run), *common, "--set", "effects.tool_gravity.enabled=true"]) == 0
    out = tmp_path / "diag"
    assert main(["diagnose", str(run), "--baseline", str(base), "--add", "tool_gravity", "--out", str(out), "--quiet"]) == 0
    d = json.loads((out / "diagnosis.json").read_text())
    assert d["kind"] == "package_run" and not d["blocked"]
    verdicts = {r["effect"]: r["verdict"] for r in d["ranking"]}
    assert verdicts["tool_gravity"] == "present", verdicts
    assert d["residual_rms_after"]["total_w"] < 0.5 * d["residual_rms_before"]["total_w"]
    assert {"residual_rms_by_channel", "effective_setup", "segmentation"} <= set(d)
    assert (out / "effects.png").stat().st_size > 10_000
    capsys.readouterr()
    assert main(["diagnose", str(run), "--add", "gravity_typo", "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "unknown effect" in err[0] and not (tmp_path / "x").exists()
    # --rerun: the online run again with the effect in the model, same TensorBoard tags
    assert main(["diagnose", str(run), "--baseline", str(base), "--add", "tool_gravity", "--rerun", "--out",
                 str(tmp_path / "r"), "--quiet"]) == 0
    rr = json.loads((tmp_path / "r" / "diagnosis.json").read_text())["rerun"]
    assert rr["model_effects"] == ["tool_gravity"] and len(rr["model_effect_params"]) == 4
    assert (tmp_path / "r" / "rerun" / "summary.json").is_file() and (tmp_path / "r" / "rerun" / "tb").is_dir()
    capsys.readouterr()
    assert main(["diagnose", str(run), "--add", "tool_inertia", "--rerun", "--out", str(tmp_path / "y")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "online model" in err[0] and not (tmp_path / "y").exists()


def test_effects_config_errors_are_one_line():
    with pytest.raises(ConfigError, match="model.effects"):  # looked up in the registry where the model is built
        make_features(load_config(None, ['model.effects=["gravity"]']))
    with pytest.raises(ConfigError, match="effects.contact_stiffness.factor"):
        load_config(None, ["effects.contact_stiffness.factor=-1"])
    with pytest.raises(ConfigError, match="excite.segments"):
        load_config(None, ["excite.segments=[[0, 0, 0, 0, 0, 0, 0]]"])


def test_effect_terms_batch_equals_a_loop_of_single_samples():
    """The online model evaluates each effect on a one-sample Signals per control step
    (kinadapt_nn.features.effects); the diagnosis on the whole log at once. Same numbers (gravity's
    acceleration terms need a history, so samples are taken where the arm is still)."""
    from kinadapt_nn.effects.online import Signals

    _, sig, _, _ = _run(["effects.tool_gravity.enabled=true"], duration=11.5)  # free space, then contact
    moving = np.linalg.norm(sig.twist_tip_w[:, 3:], axis=1) > 1e-3
    still = (np.convolve(moving, np.ones(41), "same") == 0) & sig.active & (np.arange(len(moving)) % 5 == 0)
    free, contact = np.flatnonzero(still & (sig.gate == 0)), np.flatnonzero(still & (sig.gate > 0))
    assert len(free) > 10 and len(contact) > 10
    # (encoder FD is evaluated on a 5 ms grid in the batch: the samples are on it)
    idx = np.r_[free[:: len(free) // 6][:6], contact[:: len(contact) // 6][:6]]
    for name, eff in LIBRARY.items():
        batch = eff.terms(sig)
        for i in idx:
            one = Signals(sig.t_s[i:i + 1], sig.dt_s, sig.s[i:i + 1], sig.w_env_w[i:i + 1], sig.r_tared_f[i:i + 1],
                          sig.R_wf[i:i + 1], sig.twist_tip_w[i:i + 1], sig.gate[i:i + 1], sig.active[i:i + 1],
                          sig.t_tare_s, sig.R_tare, sig.S, sig.l_nom_f, sig.q_rad[i:i + 1], sig.qdot_rad_s[i:i + 1],
                          sig.kin)
            single = eff.terms(one)
            for b, o in zip(batch, single):
                assert (b is None) == (o is None), name
                if b is not None:
                    # gravity: the batch adds the residual servo accelerations (< 0.02 m/s^2 when still)
                    atol = 0.02 if name == "tool_gravity" else 1e-9
                    np.testing.assert_allclose(o[0], b[i], rtol=1e-6, atol=atol, err_msg=name)


def test_hide_diagnose_add_and_the_residual_falls_to_the_effect_free_level(tmp_path, capsys):
    """The README's loop on the excitation program (34.4 s; ~30 s here): a hidden payload is found without a
    baseline (mass and centre of mass within 3 sd of the injected 0.5 kg at 50 mm; the tool's own
    first moment is off by its 3.6 mm offset, hence com_z only), and ``--baseline RUN0 --add`` brings
    the residual to the effect-free run's with the same refit: within 25 % of it, or -- the run has no
    sensor noise -- both under the noise floor the rows are weighted by (1; measured 154 -> 0.22 with
    the effect-free run at 0.025, 4b95480), which the summary then says; and the refit takes out more
    than 99 % of the residual (printed)."""
    quiet = ["--set", "run.tensorboard=false", "--set", "run.figure=false"]
    for name, sets in (("ex0", []), ("ex", ["--set", "effects.tool_gravity.enabled=true"])):
        main(["online", "--config", str(EXCITE), *quiet, *sets, "--out", str(tmp_path / name), "--quiet"])
    assert main(["diagnose", str(tmp_path / "ex"), "--out", str(tmp_path / "d1"), "--quiet"]) == 0
    rep = json.loads((tmp_path / "d1" / "diagnosis.json").read_text())
    tg = next(e for e in rep["ranking"] if e["effect"] == "tool_gravity")
    assert tg["verdict"] == "present", rep["summary"]
    est = tg["estimate"]
    assert abs(est["mass"]["value"] - 0.5) <= 3 * est["mass"]["sd"] + 1e-3, est["mass"]
    assert abs(est["com_z"]["value"] - 0.05) <= 3 * est["com_z"]["sd"] + 1e-3, est["com_z"]
    assert main(["diagnose", str(tmp_path / "ex"), "--baseline", str(tmp_path / "ex0"), "--add", "tool_gravity",
                 "tool_inertia", "--out", str(tmp_path / "d2")]) == 0
    out = capsys.readouterr().out
    lv = json.loads((tmp_path / "d2" / "diagnosis.json").read_text())["effect_free_level"]
    rep2 = json.loads((tmp_path / "d2" / "diagnosis.json").read_text())
    before, after = rep2["residual_rms_before"]["total_w"], rep2["residual_rms_after"]["total_w"]
    assert after < 0.01 * before, (before, after)
    if lv["under_noise_floor"]:
        assert after <= 1.0 and lv["residual_rms_total_w"] <= 1.0, lv
        assert "both under the noise floor" in out
    else:
        assert 0.75 <= lv["after_over_effect_free"] <= 1.25, lv
        assert "x the effect-free level" in out
