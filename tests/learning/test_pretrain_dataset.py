"""The pretraining data set: the batched pytorch-kinematics path against per-q MuJoCo."""

from __future__ import annotations

import numpy as np
import pytest

from kinadapt_nn.config import ExperimentCfg
from kinadapt_nn.errors import ConfigError
from kinadapt_nn.known import BORE_AXIS_W
from kinadapt_nn.learning.pretrain import load_pretrain_config, make_dataset
from kinadapt_nn.robot import PANDA_MJCF
from kinadapt_nn.sensing import channel_metric, nominal_sensor_map
from kinadapt_nn.sim.truth import TrueSensorJacobian, sensor_jacobian_rows

SMALL = ["data.n_train=8", "data.n_heldout=4", "data.n_support=4", "data.n_query=2", "seed=3"]


@pytest.fixture(scope="module")
def cfg():
    return load_pretrain_config(None, SMALL)


@pytest.fixture(scope="module")
def data_torch(cfg):
    return make_dataset(cfg, kinematics="torch")


def _reference_targets(data: dict) -> tuple[np.ndarray, np.ndarray]:
    """r (I, N, 5, n) and jn (I,) from ``TrueSensorJacobian``, one configuration at a time."""
    exp = ExperimentCfg()
    S = nominal_sensor_map(exp.sensing, BORE_AXIS_W)
    W = channel_metric(exp.sensing)[1:, None]
    l_nom = np.asarray(exp.sensing.nominal_offset_f_m, dtype=float)
    r, jn = np.empty_like(data["r"]), np.empty_like(data["jn"])
    for i, qs in enumerate(data["q"]):
        truth = TrueSensorJacobian(S, l_nom, data["offset"][i], PANDA_MJCF, data["link"][i], data["joint"][i])
        jt = np.empty((len(qs), *data["r"].shape[2:]))
        for k, q in enumerate(qs):
            J_true = truth(q)
            _, R_n, J_n = truth.nominal(q)
            r[i, k] = W * (J_true[1:] - sensor_jacobian_rows(S[1:], R_n, J_n, l_nom))
            jt[k] = W * J_true[1:]
        jn[i] = np.sqrt(np.mean(np.sum(jt**2, axis=(1, 2))))
    return r, jn


def test_batched_targets_equal_per_q_mujoco(data_torch) -> None:
    arm = data_torch["arm_error"]
    assert arm.any() and (~arm).any()  # both kinds of instance are checked
    assert np.all(data_torch["link"][~arm] == 0) and np.all(data_torch["link"][arm] != 0)
    r_ref, jn_ref = _reference_targets(data_torch)
    scale = np.abs(r_ref).max(axis=(1, 2, 3), keepdims=True)  # per instance
    for kind in (arm, ~arm):
        np.testing.assert_allclose(data_torch["r"][kind] / scale[kind], r_ref[kind] / scale[kind], rtol=0, atol=1e-9)
    np.testing.assert_allclose(data_torch["jn"], jn_ref, rtol=1e-12, atol=0)


def test_both_kinematics_give_the_same_data_set(cfg, data_torch) -> None:
    data_mj = make_dataset(cfg, kinematics="mujoco")
    assert data_mj.keys() == data_torch.keys()
    for k, v in data_mj.items():
        assert v.shape == data_torch[k].shape and v.dtype == data_torch[k].dtype, k
        if k not in ("r", "jn"):  # the draws are shared: bit-identical
            assert np.array_equal(v, data_torch[k]), k
    np.testing.assert_allclose(data_torch["r"], data_mj["r"], rtol=0, atol=1e-9 * np.abs(data_mj["r"]).max())
    I, N = cfg.data.n_train + cfg.data.n_heldout, cfg.data.n_support + cfg.data.n_query
    assert data_torch["q"].shape == (I, N, 7) and data_torch["r"].shape == (I, N, 5, 7)


def test_deterministic_from_the_seed(cfg, data_torch) -> None:
    again = make_dataset(cfg, kinematics="torch")
    assert all(np.array_equal(again[k], data_torch[k]) for k in data_torch)


def test_unknown_kinematics_is_refused(cfg) -> None:
    with pytest.raises(ConfigError, match="torch"):
        make_dataset(cfg, kinematics="numpy")
