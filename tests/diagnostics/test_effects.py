"""The effect library (issue 5): hidden effects in the simulator, their regressor columns, the
ranking against a calibrated nominal model, ``--add``, and effects adapted online."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from kinadapt_nn.app.cli import main
from kinadapt_nn.config import load_config
from kinadapt_nn.diagnostics import ranking as rk
from kinadapt_nn.features.effect_library import LIBRARY, nominal_parts
from kinadapt_nn.diagnostics.library import analyse_effects, design_of, signals_of
from kinadapt_nn.diagnostics.importers import RawLog
from kinadapt_nn.runs.episode import run_episode
from kinadapt_nn.errors import ConfigError

REPO = Path(__file__).resolve().parents[2]
EXCITE = REPO / "online" / "excite.toml"
QUIET = ["run.tensorboard=false", "run.figure=false", "run.progress=false"]


def _run(sets, duration=14.0):
    cfg = load_config(EXCITE, [*QUIET, f"run.duration_s={duration}", *sets])
    tr = run_episode(cfg).trace
    log = RawLog(tr["t_s"], tr["q_rad"], tr["qdot_rad_s"], tr["wrench_raw_f"], None, "test")
    model_cfg = cfg.model_copy(update={"effects": type(cfg.effects)()})  # the model does not know them
    return model_cfg, signals_of(log, model_cfg), tr


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
    _, sig0, _ = free_space_pair["none"]
    cfg1, sig1, _ = free_space_pair[name]
    meas = nominal_parts(sig1)[0] - nominal_parts(sig0)[0]
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
    """Calibrate on one run without effects; diagnose another seed (start jitter) with and
    without a hidden sensor rotation."""
    rc = rk.RankCfg()
    cfg0, sig0, _ = _run([])
    calib = rk.calibrate(design_of(sig0, cfg0, rc), rc)
    jitter = ["run.seed=3", "start.lateral_jitter_m=0.0005", "start.tilt_jitter_deg=1.0"]
    out = {}
    for key, sets, add in (("none", jitter, []),
                           ("rot", [*jitter, "effects.ft_frame_rotation.enabled=true"], ["ft_frame_rotation"])):
        cfg, sig, _ = _run(sets)
        out[key] = analyse_effects(design_of(sig, cfg, rc), calib, add, rc)
    return out


def test_no_hidden_effect_nothing_significant(ranked):
    assert not [r["effect"] for r in ranked["none"]["ranking"] if r["significant"]]


def test_hidden_sensor_rotation_is_found_estimated_and_removed(ranked):
    res = ranked["rot"]
    top = res["ranking"][0]
    assert top["effect"] == "ft_frame_rotation" and top["significant"]
    p_hat = np.array(top["estimate_params"]["value"])
    p_true = LIBRARY["ft_frame_rotation"].default(load_config(None).effects)
    assert np.linalg.norm(p_hat - p_true) <= 0.2 * np.linalg.norm(p_true)
    before = res["residual_rms_before"]["total_w"]
    after = res["residual_rms_after"]["total_w"]
    nominal = ranked["none"]["residual_level_rms"]["total_w"]
    assert before > 1.1 * nominal, (before, nominal)  # the effect is visible
    # --add removes most of the excess residual energy over the run without the effect
    assert before**2 - after**2 >= 0.7 * (before**2 - nominal**2), (before, after, nominal)
    for r in res["ranking"]:  # every entry has the contract's keys
        assert {"effect", "explained_fraction", "significant", "estimate", "excitation"} <= set(r)


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


def test_diagnose_cli_add_baseline_and_errors(tmp_path, capsys):
    base, run = tmp_path / "base", tmp_path / "run"
    common = ["--config", str(EXCITE), "--quiet", "--set", "run.duration_s=10", "--set", "run.tensorboard=false",
              "--set", "run.figure=false"]
    assert main(["online", "--out", str(base), *common]) == 0
    assert main(["online", "--out", str(run), *common, "--set", "effects.tool_gravity.enabled=true"]) == 0
    out = tmp_path / "diag"
    assert main(["diagnose", str(run), "--baseline", str(base), "--add", "tool_gravity", "--out", str(out), "--quiet"]) == 0
    d = json.loads((out / "diagnosis.json").read_text())
    assert d["ranking"][0]["effect"] == "tool_gravity" and d["ranking"][0]["significant"]
    assert d["residual_rms_after"]["total_w"] < 0.5 * d["residual_rms_before"]["total_w"]
    assert {"residual_rms_by_channel", "residual_rms_by_phase", "confusion"} <= set(d)
    assert (out / "effects.png").stat().st_size > 10_000
    capsys.readouterr()
    assert main(["diagnose", str(run), "--add", "gravity_typo", "--baseline", str(base), "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "unknown effect" in err[0] and not (tmp_path / "x").exists()
    assert main(["diagnose", str(run), "--baseline", str(run), "--out", str(tmp_path / "y")]) == 2
    assert "hidden effects" in capsys.readouterr().err
    # a calibration file: written from the baseline, used instead of --baseline, refused when corrupt
    cal = tmp_path / "cal.json"
    assert main(["diagnose", str(base), "--no-calibration", "--save-calibration", str(cal), "--out",
                 str(tmp_path / "c0"), "--quiet"]) == 0
    assert "excite" in json.loads(cal.read_text())["programs"]
    assert main(["diagnose", str(run), "--calibration", str(cal), "--out", str(tmp_path / "c1"), "--quiet"]) == 0
    d1 = json.loads((tmp_path / "c1" / "diagnosis.json").read_text())
    assert d1["ranking"][0]["effect"] == "tool_gravity"
    cal.write_text('{"programs": {"excite": {"params": {"tool_gravity": "x"}}}}')
    capsys.readouterr()
    assert main(["diagnose", str(run), "--calibration", str(cal), "--out", str(tmp_path / "c2")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "malformed" in err[0] and not (tmp_path / "c2").exists()
    # --rerun: the online run again with the effect in the model, same TensorBoard tags
    assert main(["diagnose", str(run), "--baseline", str(base), "--add", "tool_gravity", "--rerun", "--out",
                 str(tmp_path / "r"), "--quiet"]) == 0
    rr = json.loads((tmp_path / "r" / "diagnosis.json").read_text())["rerun"]
    assert rr["model_effects"] == ["tool_gravity"] and len(rr["model_effect_params"]) == 4
    assert (tmp_path / "r" / "rerun" / "summary.json").is_file() and (tmp_path / "r" / "rerun" / "tb").is_dir()


def test_effects_config_errors_are_one_line():
    with pytest.raises(ConfigError, match="model.effects"):
        load_config(None, ['model.effects=["gravity"]'])
    with pytest.raises(ConfigError, match="effects.contact_stiffness.factor"):
        load_config(None, ["effects.contact_stiffness.factor=-1"])
    with pytest.raises(ConfigError, match="excite.segments"):
        load_config(None, ["excite.segments=[[0, 0, 0, 0, 0, 0, 0]]"])


def test_effect_terms_batch_equals_a_loop_of_single_samples():
    """The online model evaluates each effect on a one-sample Signals per control step
    (kinadapt_nn.features.effects); the diagnosis on the whole log at once. Same numbers (gravity's
    acceleration terms need a history, so samples are taken where the arm is still)."""
    from kinadapt_nn.features.effect_library import Signals

    _, sig, _ = _run(["effects.tool_gravity.enabled=true"], duration=11.5)  # free space, then contact
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


def test_encoder_columns_differentiate_the_calibrated_prediction():
    """A joint zero offset moves the model's q everywhere, the calibrated part of the prediction
    ``sum_e X_e(q) p_e^calib`` included. ``calibration_derivative`` (signals moved to first order
    along the 5 ms-grid derivatives) equals central differences of the effects' terms on Signals
    recomputed from shifted encoder readings (the arm's kinematics at every sample); the design's
    ``dX_dq`` are those derivatives through the same rows; ``calibrated_design`` adds
    ``sum_e dX_e/dq_j p_e`` to the encoder columns once and leaves the calibrated residual alone."""
    from kinadapt_nn.features.effect_library import (_wrench_to_s, calibration_derivative, encoder_derivatives,
                                                 shifted_signals, tip_twist_map)
    from kinadapt_nn.sensing import channel_metric

    cfg, sig, _ = _run([], duration=11.5)  # free space, then contact
    assert (sig.gate > 0).any() and (sig.gate == 0).any()
    n, h = len(sig.t_s), 1e-4
    i_tare = int(np.clip(np.searchsorted(sig.t_s, sig.t_tare_s), 0, n - 1))

    def exact(j: int, dq: float):
        q = sig.q_rad.copy()
        q[:, j] += dq
        R, tw = np.empty((n, 3, 3)), np.empty((n, 6))
        for i in range(n):
            k = sig.kin.update(q[i])
            R[i], tw[i] = k.R_wf, tip_twist_map(k.R_wf, k.J_arm, sig.l_nom_f) @ sig.qdot_rad_s[i]
        w = np.concatenate([np.einsum("nij,nj->ni", R, sig.r_tared_f[:, :3]),
                            np.einsum("nij,nj->ni", R, sig.r_tared_f[:, 3:])], axis=1)
        s = sig.s.copy()
        ws = _wrench_to_s(w, sig.S)
        s[:, 1:3], s[:, 3:] = ws[:, :2], ws[:, 3:]
        return sig._replace(R_wf=R, twist_tip_w=tw, w_env_w=w, s=s, R_tare=R[i_tare].copy(), q_rad=q)

    names = [m for m in LIBRARY if m != "encoder_offset"]
    derivs = encoder_derivatives(sig)
    fd = list(calibration_derivative(sig, names, h=h, derivs=derivs))
    assert len(fd) == 6
    for j in (0, 3):
        plus, minus = exact(j, h), exact(j, -h)
        for name in names:
            for a, b, d in zip(LIBRARY[name].terms(plus), LIBRARY[name].terms(minus), fd[j][name]):
                assert (a is None) == (d is None), name
                if a is not None:
                    ref = (a - b) / (2 * h)
                    assert np.abs(ref).max() > 0, (name, j)
                    np.testing.assert_allclose(d, ref, rtol=0, atol=1e-3 * np.abs(ref).max(),
                                               err_msg=f"{name} joint {j + 1}")

    rc = rk.RankCfg()
    des = design_of(sig, cfg, rc)
    assert set(des.dX_dq) == set(names) and des.encoder_calibration is None
    W6 = channel_metric(cfg.sensing)
    j = 3
    for name in ("tool_tilt", "ft_frame_rotation"):
        up = rk.build_design(shifted_signals(sig, *derivs[j], h, j), W6, rc, [name]).X[name]
        dn = rk.build_design(shifted_signals(sig, *derivs[j], -h, j), W6, rc, [name]).X[name]
        np.testing.assert_allclose(des.dX_dq[name][:, :, j], (up - dn) / (2 * h), rtol=0,
                                   atol=1e-9 * np.abs(up).max() / h)
    calib = {m: list(0.3 * LIBRARY[m].default(load_config(None).effects) + 1e-3) for m in LIBRARY}
    cal = rk.calibrated_design(des, calib)
    shift = sum(np.einsum("rkj,k->rj", des.dX_dq[m], np.asarray(calib[m])) for m in names)
    np.testing.assert_allclose(cal.X["encoder_offset"], des.X["encoder_offset"] + shift)
    assert np.abs(shift).max() > 0
    assert all(cal.X[m] is des.X[m] for m in names)
    assert rk.calibrated_design(cal, calib) is cal and rk.calibrated_design(des, None) is des
    np.testing.assert_allclose(rk.calibrated_residual(cal, calib), rk.calibrated_residual(des, calib))
