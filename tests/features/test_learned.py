"""RBF and neural features, pretraining, checkpoints, arm errors, compare."""

from __future__ import annotations

import json
from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch

from kinadapt_nn.config import load_config
from kinadapt_nn.runs.build import make_controller, make_features
from kinadapt_nn.runs.episode import run_episode
from kinadapt_nn.errors import ModelFileError
from kinadapt_nn.learning.weights import read_checkpoint_file
from kinadapt_nn.robot import MODELS_DIR
from tests.controller.law_reference import one_law_step

Q0 = np.array([0.05, -0.55, 0.02, -2.45, 0.03, 1.95, 0.75])
TEST_DATA = Path(__file__).resolve().parent.parent / "data"  # torch .pt checkpoints the shipped models were converted from


def _kin_and_qdot(seed=0):
    rng = np.random.default_rng(seed)
    ctrl = make_controller(load_config(None, []))
    q = Q0 + 0.05 * rng.normal(size=7)
    return ctrl, ctrl.kin(q), 0.2 * rng.normal(size=7), rng


@pytest.mark.parametrize("kind", ["rbf", "neural"])
def test_learned_regressor_matches_jacobian_and_finite_differences(kind):
    """J_hat(theta) qdot = known + Phi theta, and Phi is the derivative of J_hat qdot in theta."""
    _, kin, qdot, rng = _kin_and_qdot(1)
    feats, theta0 = make_features(load_config(None, [f"run.features={kind}"]))
    theta = theta0 + 0.01 * rng.normal(size=feats.n_params) * (np.abs(theta0).max() + 1.0)
    reg = feats.regressor(kin, qdot)
    J = feats.jacobian(kin, theta)
    np.testing.assert_allclose(J @ qdot, reg.known + reg.Phi @ theta, rtol=1e-10, atol=1e-9)
    h = 1e-3
    for k in rng.choice(feats.n_params, 5, replace=False):
        e = np.zeros(feats.n_params)
        e[k] = h
        fd = (feats.jacobian(kin, theta + e) @ qdot - feats.jacobian(kin, theta - e) @ qdot) / (2 * h)
        np.testing.assert_allclose(reg.Phi[:, k], fd, rtol=1e-7, atol=1e-9)
    assert np.all(reg.Phi[0] == 0.0)  # the depth row is never adapted


def test_rbf_prediction_step_is_the_closed_form():
    """Per-entry RBF rows are orthogonal with norm |psi||qdot|: the step is eq. ident_qp_solution."""
    _, kin, qdot, rng = _kin_and_qdot(2)
    feats, _ = make_features(load_config(None, ["run.features=rbf"]))
    Phi = feats.regressor(kin, qdot).Phi
    eps = rng.normal(size=6)
    _, a, _ = one_law_step("prediction", Phi, eps, eta=1.0, eps_norm=1e-4)  # the law's numba step
    step, n2 = a.d_pred, a.phi_norm2
    psi = feats.psi(kin.q_rad)
    assert n2 == pytest.approx((psi @ psi) * (qdot @ qdot), rel=1e-10)
    np.testing.assert_allclose(step, Phi.T @ eps / (n2 + 1e-4), rtol=1e-12)
    assert feats.n_params == 5 * 7 * len(feats.centres)


def test_neural_fast_path_equals_the_torch_network():
    """The numpy per-step body reproduces the checkpoint's torch network (Y(q) theta exactly)."""
    from kinadapt_nn.learning.checkpoint import load_checkpoint

    ckpt = MODELS_DIR / "neural_default.safetensors"
    net, meta = load_checkpoint(ckpt)
    feats, theta0 = make_features(load_config(None, ["run.features=neural"]))
    rng = np.random.default_rng(3)
    qs = Q0 + 0.05 * rng.normal(size=(20, 7))
    theta = np.asarray(meta["theta_mean"])  # any theta; the mean head is a non-trivial one
    with torch.no_grad():
        res_t = net.residual(torch.as_tensor(qs), torch.as_tensor(theta)).numpy()  # W-scaled rows 1..5
    w = np.asarray(meta["w_rows"])[:, None]
    for q, rt in zip(qs, res_t):
        y = feats.body(q)
        np.testing.assert_allclose(y @ theta, rt / w, rtol=1e-12, atol=1e-12)
    assert feats.n_params == meta["n_params_online"]


def test_body_is_bit_identical_after_an_online_run():
    """Only theta adapts: the network weights do not change during an episode."""
    cfg = load_config(None, ["run.features=neural", "run.duration_s=2.0", "scene.contact_model=socket",
                             "control.dither_rad_s=[0.05,0.05,0.05]"])
    ctrl = make_controller(cfg)
    feats = ctrl.features
    before = [a.copy() for a in (feats.W1, feats.b1, feats.W2, feats.b2, feats.W3, feats.b3)]
    ckpt_before = read_checkpoint_file(feats.checkpoint).state
    from kinadapt_nn.sim.adapter import PegInHoleSim

    sim = PegInHoleSim(cfg)
    obs = sim.sense()
    for _ in range(1500):
        cmd = ctrl.step(sim.time_s, obs.q_rad, obs.qdot_rad_s, obs.wrench_raw_f)
        sim.apply(cmd.q_ref_rad, cmd.qdot_ref_rad_s)
        sim.step()
        obs = sim.sense()
    after = (feats.W1, feats.b1, feats.W2, feats.b2, feats.W3, feats.b3)
    assert all(np.array_equal(a, b) for a, b in zip(before, after))
    ckpt_after = read_checkpoint_file(feats.checkpoint).state
    assert all(np.array_equal(ckpt_before[k], ckpt_after[k]) for k in ckpt_before)
    assert not np.array_equal(ctrl.theta, ctrl.theta0)  # ... while theta did move


def _copy_of_default(path):
    """The shipped default checkpoint saved again by ``save_checkpoint`` (this torch, this code)."""
    from kinadapt_nn.learning.checkpoint import load_checkpoint, save_checkpoint

    net, meta = load_checkpoint(MODELS_DIR / "neural_default.safetensors")
    save_checkpoint(path, net, np.asarray(meta["theta_mean"]),
                    {k: v for k, v in meta.items() if k not in ("format", "version", "theta_mean", "theta_std")},
                    np.asarray(meta["theta_std"]))
    return net, meta


def test_checkpoint_round_trip(tmp_path):
    from kinadapt_nn.learning.checkpoint import load_checkpoint

    p = tmp_path / "copy.safetensors"
    net, meta = _copy_of_default(p)
    net2, meta2 = load_checkpoint(p)
    assert all(torch.equal(a, b) for a, b in zip(net.state_dict().values(), net2.state_dict().values()))
    assert meta2 == meta
    from safetensors.numpy import load_file

    assert sorted(load_file(p)) == sorted(net.state_dict())  # a plain safetensors file, torch's names


@pytest.mark.parametrize("name", ["neural_default", "neural_cell"])
def test_converted_models_give_the_old_features_bit_for_bit(tmp_path, name):
    """The shipped safetensors model holds torch.load's tensors and metadata of the .pt it was
    converted from (tests/data), as the conversion writes them, and NeuralFeatures built from
    either give the same Y(q) to the last bit."""
    from kinadapt_nn.features.neural import NeuralFeatures
    from kinadapt_nn.learning.checkpoint import convert_torch_checkpoint
    from kinadapt_nn.sensing import channel_metric

    old, new = TEST_DATA / f"{name}.pt", MODELS_DIR / f"{name}.safetensors"
    blob = torch.load(old, map_location="cpu", weights_only=True)
    state, meta = read_checkpoint_file(new)
    assert meta == blob["meta"] and sorted(state) == sorted(blob["state_dict"])
    for k, v in blob["state_dict"].items():
        assert state[k].dtype == v.numpy().dtype and np.array_equal(state[k], v.numpy())
    again = read_checkpoint_file(convert_torch_checkpoint(old, tmp_path / "c.safetensors"))  # what conversion writes
    assert again.meta == meta and all(np.array_equal(again.state[k], v) for k, v in state.items())

    cfg = load_config(None, ["run.features=neural"])
    base, _ = make_features(cfg)
    feats = {p: NeuralFeatures(base.known, base.prior, p, channel_metric(cfg.sensing)) for p in (old, new)}
    rng = np.random.default_rng(7)
    for q in [Q0, *(Q0 + 0.3 * rng.normal(size=(6, 7)))]:
        y_old, y_new = feats[old].body(q), feats[new].body(q)
        assert y_new.shape == y_old.shape and np.array_equal(y_new, y_old)
    assert feats[old].meta == feats[new].meta


def _damaged(tmp_path):
    """A damaged safetensors checkpoint per way it can be wrong -> (path, what the message names)."""
    from safetensors.numpy import save_file

    from kinadapt_nn.learning.weights import content_hash

    good = tmp_path / "good.safetensors"
    _copy_of_default(good)
    raw = good.read_bytes()
    state, meta = read_checkpoint_file(good)

    def header(tensors, meta):  # metadata with a correct hash: only the named fault remains
        meta_json = json.dumps(meta, sort_keys=True)
        return {"meta": meta_json, "sha256": content_hash(tensors, meta_json)}

    renamed = {("l9.weight" if k == "l1.weight" else k): v for k, v in state.items()}
    files = {"truncated": (raw[: len(raw) - 100], "not a readable safetensors"),
             "flipped": (raw[:-1000] + bytes([raw[-1000] ^ 0xFF]) + raw[-999:], "content hash"),
             "junk": (b"\x00" * 100, "not a readable safetensors"),
             "empty": (b"", "not a readable safetensors")}
    for what, (tensors, md, msg) in {
        "no_metadata": (state, None, "not a kinadapt checkpoint"),
        "no_json": (state, {"meta": "{not json", "sha256": "0"}, "not JSON"),
        "wrong_keys": (renamed, header(renamed, meta), "l1.weight .*missing.*unexpected l9.weight"),
        "wrong_format": (state, header(state, dict(meta, format="other")), "format 'other'"),
    }.items():
        p = tmp_path / f"{what}.safetensors"
        save_file(tensors, p, metadata=md)
        files[what] = (p.read_bytes(), msg)
    return files


def test_bad_checkpoints_are_one_line_errors(tmp_path):
    """Truncated, flipped, junk, without metadata, wrong tensors, wrong format: a one-line
    ModelFileError naming what is wrong, from the torch-free reader, the torch loader, the
    features and the CLI (exit 2)."""
    from kinadapt_nn.app.cli import main
    from kinadapt_nn.learning.checkpoint import load_checkpoint
    from kinadapt_nn.learning.legacy import torch_state_hash
    from kinadapt_nn.learning.weights import load_checkpoint_arrays

    files = _damaged(tmp_path)
    for what, (data, msg) in files.items():
        p = tmp_path / f"bad_{what}.safetensors"
        p.write_bytes(data)
        for load in (load_checkpoint_arrays, load_checkpoint):
            with pytest.raises(ModelFileError, match=msg) as err:
                load(p)
            assert "\n" not in str(err.value), what
    # a damaged or foreign torch .pt: the same, through torch.load(weights_only=True)
    raw = bytearray((TEST_DATA / "neural_default.pt").read_bytes())
    raw[len(raw) // 2] ^= 0xFF
    (tmp_path / "bad.pt").write_bytes(bytes(raw))
    sd = {"w": torch.zeros(2)}
    torch.save({"state_dict": sd, "meta": {"format": "x"}, "sha256": torch_state_hash(sd, {"format": "x"})},
               tmp_path / "foreign.pt")
    for p, msg in ((tmp_path / "bad.pt", "content hash|corrupt"), (tmp_path / "foreign.pt", "format 'x'")):
        with pytest.raises(ModelFileError, match=msg):
            load_checkpoint_arrays(p)
    bad = tmp_path / "bad_truncated.safetensors"
    with pytest.raises(ModelFileError):
        make_features(load_config(None, ["run.features=neural", f"features.neural_checkpoint='{bad}'"]))
    out = tmp_path / "run"
    rc = main(["online", "--out", str(out), "--quiet", "--set", "run.features=neural",
               "--set", f"features.neural_checkpoint='{bad}'"])
    assert rc == 2 and not out.exists()


def test_a_torch_checkpoint_without_torch_names_the_fix():
    """A .pt checkpoint where torch is not installed: one line saying to install it or convert."""
    import subprocess
    import sys

    code = ("import sys; sys.modules['torch'] = None\n"
            "from kinadapt_nn.errors import ModelFileError\n"
            "from kinadapt_nn.learning.weights import load_checkpoint_arrays\n"
            f"try: load_checkpoint_arrays({str(TEST_DATA / 'neural_default.pt')!r})\n"
            "except ModelFileError as e: print(e)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.count("\n") == 1 and "torch is not installed" in out
    assert "python -m kinadapt_nn.learning.checkpoint" in out


def test_a_shipped_model_named_by_its_old_pt_name_is_its_conversion():
    old, _ = make_features(load_config(None, ["run.features=neural", "features.neural_checkpoint=neural_cell.pt"]))
    assert old.checkpoint == MODELS_DIR / "neural_cell.safetensors"


def test_neural_features_are_built_without_importing_torch():
    """An online run with neural features reads its checkpoint without torch (~1.2 s import)."""
    import subprocess
    import sys

    code = ("import sys; from kinadapt_nn.config import load_config; from kinadapt_nn.runs.build import make_features; "
            "f, th = make_features(load_config(None, ['run.features=neural'])); "
            "print(f.n_params, 'torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    feats, _ = make_features(load_config(None, ["run.features=neural"]))
    assert out == [str(feats.n_params), "False"]


def test_pretraining_resume_equals_uninterrupted(tmp_path):
    """Deterministic from the seed; an interrupted run resumed from train_state.pt ends bit-identical."""
    from kinadapt_nn.learning.checkpoint import checkpoint_bytes_equal
    from kinadapt_nn.learning.pretrain import load_pretrain_config, pretrain

    cfg = load_pretrain_config(None, ["data.n_train=12", "data.n_heldout=4", "data.n_support=8", "data.n_query=4",
                                      "train.steps=12", "train.batch_instances=4", "train.eval_every=4",
                                      "train.checkpoint_every=3", "net.hidden=16", "net.n_features=4"])
    a, b = tmp_path / "a", tmp_path / "b"
    m = pretrain(cfg, a, progress=False)
    assert m["steps"] == 12 and (a / "model.safetensors").is_file() and not (a / "train_state.pt").exists()
    partial = pretrain(cfg, b, progress=False, stop_after=6)
    assert partial == {"interrupted_at": 6} and (b / "train_state.pt").is_file()
    pretrain(cfg, b, progress=False)
    assert checkpoint_bytes_equal(a / "model.safetensors", b / "model.safetensors")
    metrics = json.loads((a / "metrics.json").read_text())
    assert metrics["n_params_online"] == 4 and metrics["heldout_rel_jacobian_error_median"] < 1.0


def test_arm_errors_simulator_and_truth_agree():
    """The true sensor Jacobian with arm errors equals S times the simulated tip twist of a scene
    built with the same errors (rows 1..5), and differs from the nominal one."""
    from kinadapt_nn.geometry import adjoint_offset
    from kinadapt_nn.sensing import nominal_sensor_map
    from kinadapt_nn.known import BORE_AXIS_W
    from kinadapt_nn.sim.adapter import PegInHoleSim
    from kinadapt_nn.sim.truth import TrueSensorJacobian

    link = [0.002, -0.001, 0.0015, 0.0, 0.001, -0.002, 0.001, 0.0005]
    joint = [0.004, -0.003, 0.002, 0.005, -0.004, 0.003, -0.002]
    cfg = load_config(None, [f"arm.link_length_error_m={link}", f"arm.joint_offset_rad={joint}"])
    sim = PegInHoleSim(cfg)
    S = nominal_sensor_map(cfg.sensing, BORE_AXIS_W)
    truth = TrueSensorJacobian(S, np.asarray(cfg.sensing.nominal_offset_f_m), np.asarray(cfg.tool.offset_f_m),
                               MODELS_DIR / "panda.xml", link, joint)
    rng = np.random.default_rng(5)
    m, d = sim.model, sim.data
    for _ in range(5):
        q = Q0 + 0.05 * rng.normal(size=7)
        qd = 0.3 * rng.normal(size=7)
        d.qpos[sim.ids.qpos_adr], d.qvel[sim.ids.dof_adr] = q, qd
        mujoco.mj_forward(m, d)
        v6 = np.zeros(6)
        mujoco.mj_objectVelocity(m, d, mujoco.mjtObj.mjOBJ_SITE, sim.ids.tip_site, v6, 0)
        tip_twist = np.concatenate([v6[3:], v6[:3]])
        np.testing.assert_allclose(truth(q)[1:] @ qd, S[1:] @ tip_twist, rtol=1e-9, atol=1e-9)
        nominal = S @ adjoint_offset(np.zeros(3))  # sanity: errors matter
        assert nominal.shape == (6, 6)
    ctrl = make_controller(load_config(None, []))
    J_nom = ctrl.features.jacobian(ctrl.kin(q), np.asarray(cfg.tool.offset_f_m))
    assert np.linalg.norm(J_nom[1:] - truth(q)[1:]) / np.linalg.norm(truth(q)[1:]) > 1e-3


def test_compare_writes_table_figure_and_tensorboard(tmp_path):
    from kinadapt_nn.app.cli import main

    out = tmp_path / "cmp"
    rc = main(["compare", "--out", str(out), "--quiet", "--set", "n_tools=1", "--set", "jobs=1",
               "--set", "features=['adjoint','neural']", "--set", "scenarios={short=['run.duration_s=1.0']}"])
    assert rc == 0
    import csv

    rows = list(csv.DictReader(open(out / "comparison.csv")))
    need = {"features", "tool_family", "episodes", "success_rate", "seat_time_s_median",
            "jacobian_rel_error_final_median", "pred_error_rms_median", "n_params", "wall_time_s_median"}
    assert need <= set(rows[0])
    assert {(r["features"], r["tool_family"]) for r in rows} == {
        ("adjoint", "nominal"), ("adjoint", "arm_errors"), ("neural", "nominal"), ("neural", "arm_errors")}
    assert (out / "comparison.md").read_text().startswith("| scenario | features")
    assert (out / "jacobian_error.png").stat().st_size > 10_000
    assert len(list((out / "tb").rglob("events.out.tfevents*"))) >= 4


def test_default_neural_run_works_from_the_shipped_checkpoint():
    r = run_episode(load_config(None, ["run.features=neural", "run.duration_s=1.5"]))
    assert r.summary["n_params"] == 12 and r.summary["features"] == "neural"
    assert np.isfinite(r.summary["jacobian_rel_error_final"])


def _head(feats, kin_of, truth, qs, W):
    """Least-squares head of ``truth`` on the neural basis: min sum_q |W (J_true - K(q) - Y(q) theta)|^2
    over rows 1..5 (an independent fit: the truth's Jacobian, not the pretraining data)."""
    A, y = [], []
    for q in qs:
        J0 = feats.jacobian(kin_of(q), np.zeros(feats.n_params))
        Y = feats.body(q)  # (5, n, p), raw units
        A.append((W[1:, None, None] * Y).reshape(-1, feats.n_params))
        y.append((W[1:, None] * (truth(q)[1:] - J0[1:])).ravel())
    return np.linalg.lstsq(np.concatenate(A), np.concatenate(y), rcond=None)[0]


def test_calibrated_arm_prior_spans_the_tools_of_a_nominal_arm_only():
    """``features.neural_prior = "calibrated_arm"``: the prior is the nominal-arm heads' second moment,
    rank 3 (a rigid tool's Jacobian is linear in its offset, eq. ft_factor). The head fitted to the
    true Jacobian of a held-out tool on the nominal arm lies in its span; on an arm with kinematic
    errors it does not -- and the pooled prior (every training arm) covers both."""
    from kinadapt_nn.sensing import channel_metric, nominal_sensor_map
    from kinadapt_nn.known import BORE_AXIS_W
    from kinadapt_nn.sim.truth import TrueSensorJacobian

    cfg = load_config(None, ["run.features=neural", "features.neural_prior=calibrated_arm"])
    feats, _ = make_features(cfg)
    ctrl = make_controller(cfg)
    lam, V = np.linalg.eigh(feats.P0)
    assert lam[-3] > 1e4 * lam[-4]  # rank 3 (to the precision of the fitted heads)
    U = V[:, -3:]
    S = nominal_sensor_map(cfg.sensing, BORE_AXIS_W)
    W = channel_metric(cfg.sensing)
    rng = np.random.default_rng(11)
    qs = [feats.q_mean + rng.normal(size=7) / feats.q_inv_std for _ in range(12)]  # the training distribution
    tool = np.array([0.004, -0.003, 0.102])
    out_of_span = {}
    for name, link, joint in [("nominal", None, None),
                              ("arm_errors", 0.001 * rng.normal(size=8), 0.004 * rng.normal(size=7))]:
        truth = TrueSensorJacobian(S, np.asarray(cfg.sensing.nominal_offset_f_m), tool, MODELS_DIR / "panda.xml", link, joint)
        th = _head(feats, ctrl.kin, truth, qs, W)
        out_of_span[name] = np.linalg.norm(th - U @ (U.T @ th)) / np.linalg.norm(th)
    assert out_of_span["nominal"] < 0.02, out_of_span
    assert out_of_span["arm_errors"] > 0.2, out_of_span
    pooled, _ = make_features(load_config(None, ["run.features=neural"]))
    assert np.linalg.eigvalsh(pooled.P0)[-4] > 1e-3 * np.linalg.eigvalsh(pooled.P0)[-1]  # more than 3 directions


def test_calibrated_arm_prior_missing_from_a_checkpoint_is_a_one_line_error(tmp_path):
    from kinadapt_nn.learning.checkpoint import load_checkpoint, save_checkpoint

    net, meta = load_checkpoint(MODELS_DIR / "neural_default.safetensors")
    meta = {k: v for k, v in meta.items() if not k.startswith("theta_moment_calibrated_arm")}
    path = tmp_path / "old.safetensors"
    save_checkpoint(path, net, np.asarray(meta["theta_mean"]), meta, np.asarray(meta["theta_std"]))
    cfg = load_config(None, ["run.features=neural", f"features.neural_checkpoint={path}",
                             "features.neural_prior=calibrated_arm"])
    with pytest.raises(ModelFileError, match="no calibrated-arm prior.*kinadapt_nn.learning.prior"):
        make_features(cfg)
