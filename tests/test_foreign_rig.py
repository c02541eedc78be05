"""The foreign-rig fixtures (examples/foreign_rig.py): physics, conventions and files.

The generator is independent of the package; only these tests use ``kinadapt_nn`` (to load the
setup files it writes).
"""

from __future__ import annotations

import gzip
import importlib.util
import json
import math
import sys
from pathlib import Path

import mujoco
import numpy as np
import pyarrow.parquet as pq
import pytest

from kinadapt_nn.diagnostics.setup import load_setup

ROOT = Path(__file__).resolve().parents[1]
RIG_PY = ROOT / "examples" / "foreign_rig.py"
SEED = 3
GENERATED = ("none", "encoder_offset", "tared_rotation", "ft_bias_drift")


def _load_rig():
    name = "foreign_rig"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, RIG_PY)
        mod = importlib.util.module_from_spec(spec)
        sys.modules[name] = mod
        spec.loader.exec_module(mod)
    return sys.modules[name]


fr = _load_rig()


@pytest.fixture(scope="module")
def case_dirs(tmp_path_factory) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("foreign_rig")
    return {n: fr.make_case(n, out, seed=SEED) for n in GENERATED}


def _read_csv(path: Path) -> tuple[list[str], np.ndarray, np.ndarray]:
    """(header, stamps (N,) int64 [ns], the other columns (N, 20))."""
    with gzip.open(path, "rt") as fh:
        header = fh.readline().strip().split(",")
        rows = [line.split(",") for line in fh.read().splitlines()]
    stamps = np.array([int(r[0]) for r in rows], dtype=np.int64)
    data = np.array([[float(x) for x in r[1:]] for r in rows])
    return header, stamps, data


def _sensor_rotation(m: mujoco.MjModel, q: np.ndarray) -> np.ndarray:
    """(N, 3, 3) R_ws of the sensor site from MuJoCo's forward kinematics."""
    d = mujoco.MjData(m)
    sid = m.site("ft").id
    out = np.empty((len(q), 3, 3))
    for i, qi in enumerate(q):
        d.qpos[:] = qi
        mujoco.mj_kinematics(m, d)
        out[i] = d.site_xmat[sid].reshape(3, 3)
    return out


def _static_samples(tr) -> np.ndarray:
    """Indices where the arm is exactly at rest and out of contact."""
    rest = np.all(tr.qd == 0.0, axis=1) & np.all(tr.qdd == 0.0, axis=1) & (tr.f_tip_w[:, 2] == 0.0)
    return np.nonzero(rest)[0]


def test_generator_does_not_import_the_package():
    src = RIG_PY.read_text()
    assert "import kinadapt_nn" not in src and "from kinadapt_nn" not in src


def test_self_test_sign_and_frame():
    err = fr.self_test()
    assert max(err.values()) < 1e-9


def test_trajectory_shape_and_limits():
    tr = fr.trajectory()
    m = fr.build_model()
    assert tr.q.shape == (7501, 7) and tr.t[-1] == pytest.approx(15.0)
    lo, hi = m.jnt_range[:, 0], m.jnt_range[:, 1]
    assert np.all(tr.q > lo + 0.1) and np.all(tr.q < hi - 0.1)
    assert np.all(np.abs(tr.qd).max(0) < np.asarray(fr.QDOT_LIMIT))
    assert np.all(np.abs(tr.qdd).max(0) < np.asarray(fr.QDDOT_LIMIT))
    # the start pose is held through the tare instant; contact only in phase 3
    assert np.all(tr.q[: int(0.5 * fr.RATE_HZ)] == np.asarray(fr.Q_HOME))
    assert np.all(tr.f_tip_w[tr.t < 10.0] == 0.0)
    # the tip stays on the table while pressed (spline through IK knots)
    on = tr.f_tip_w[:, 2] > 0.0
    assert np.abs(tr.tip_w[on, 2] - tr.table_z_m).max() < 1e-5
    # the prescribed contact: normal force up to 15 N, Coulomb friction bounded by mu N
    assert tr.f_tip_w[:, 2].max() == pytest.approx(fr.NORMAL_FORCE_N)
    ft = np.linalg.norm(tr.f_tip_w[:, :2], axis=1)
    assert np.all(ft <= fr.MU * tr.f_tip_w[:, 2] + 1e-12) and ft.max() > 0.99 * fr.MU * fr.NORMAL_FORCE_N
    # the derivatives are those of q (central differences of eval)
    ts, h = np.array([0.9, 3.0, 5.2, 8.0, 9.1, 11.4, 12.5, 13.3]), 1e-5
    q, qd, qdd = tr.eval(ts)
    qp, qdp, _ = tr.eval(ts + h)
    qm, qdm, _ = tr.eval(ts - h)
    np.testing.assert_allclose((qp - qm) / (2 * h), qd, atol=1e-7)
    np.testing.assert_allclose((qdp - qdm) / (2 * h), qdd, atol=1e-5)


def test_static_reading_is_the_tool_weight(case_dirs):
    """(a) at rest: tool-on-sensor = (m R^T g, c x m R^T g) with R from the sensor site's xmat."""
    tr = fr.trajectory()
    idx = _static_samples(tr)
    assert len(idx) > 1000
    r = _sensor_rotation(fr.build_model(), tr.q[idx])
    fg = fr.TOOL_MASS_KG * np.einsum("nji,j->ni", r, np.array([0.0, 0.0, -9.81]))
    expect = np.hstack([fg, np.cross(np.asarray(fr.TOOL_COM_S_M), fg)])
    w = fr.case_signals("none", noise=False)["w_tool_on_sensor_s"]
    np.testing.assert_allclose(w[idx], expect, atol=1e-9)
    # the logged file (sensor_on_tool, noisy) around the same value: hold 0 - 0.5 s
    _, _, data = _read_csv(case_dirs["none"] / "log.csv.gz")
    hold = idx[idx < 250]
    mean = data[hold, 14:].mean(axis=0)
    se = np.array([fr.SIGMA_FORCE_N] * 3 + [fr.SIGMA_TORQUE_NM] * 3) / math.sqrt(len(hold))
    assert np.all(np.abs(mean + expect[0]) < 5 * se + 1e-6)
    assert np.std(data[hold, 14:17] + expect[0, :3]) == pytest.approx(fr.SIGMA_FORCE_N, rel=0.15)


def test_moving_reading_matches_newton_euler():
    """In motion (no contact): tool-on-sensor = (m (g - a_c), -(c x m a'_c + I alpha + w x I w))
    with the tool's motion from finite differences of MuJoCo's forward kinematics."""
    tr = fr.trajectory()
    m = fr.build_model()
    d = mujoco.MjData(m)
    sid, bid = m.site("ft").id, m.body("tool").id
    # inside the segments (finite differences across a C2 join are only O(h) accurate)
    ts, h = np.array([0.8, 1.95, 2.77, 4.3, 5.5, 6.6, 8.05, 9.2, 11.3, 12.6]), 1e-4
    w = fr.inverse_dynamics_wrench(m, *tr.eval(ts))
    g = np.array([0.0, 0.0, -9.81])
    ixx, iyy, izz, ixy, ixz, iyz = fr.TOOL_INERTIA_COM_KG_M2
    i_s = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])

    def pose(t):
        d.qpos[:] = tr.eval([t])[0][0]
        mujoco.mj_kinematics(m, d)
        return d.xipos[bid].copy(), d.site_xmat[sid].reshape(3, 3).copy(), d.site_xpos[sid].copy()

    def omega(t):
        return fr.matrix_rotvec(pose(t + h)[1] @ pose(t - h)[1].T) / (2 * h)

    a_max = al_max = 0.0
    for k, t in enumerate(ts):
        (pc, r, po), (pcp, _, _), (pcm, _, _) = pose(t), pose(t + h), pose(t - h)
        a_c = (pcp - 2 * pc + pcm) / h**2
        om, al = omega(t), (omega(t + h) - omega(t - h)) / (2 * h)
        f_sensor_on_tool = fr.TOOL_MASS_KG * (a_c - g)
        i_w = r @ i_s @ r.T
        tau_c = i_w @ al + np.cross(om, i_w @ om)
        tau_o = tau_c + np.cross(pc - po, f_sensor_on_tool)
        expect = -np.r_[r.T @ f_sensor_on_tool, r.T @ tau_o]
        np.testing.assert_allclose(w[k], expect, atol=2e-5)
        a_max = max(a_max, float(np.linalg.norm(a_c)))
        al_max = max(al_max, float(np.linalg.norm(al)))
    assert a_max > 0.5 and al_max > 2.0, (a_max, al_max)  # really moving

def test_contact_acts_at_the_tip():
    tr = fr.trajectory()
    m = fr.build_model()
    idx = np.nonzero(tr.f_tip_w[:, 2] > 0.0)[0][::97]
    with_c = fr.inverse_dynamics_wrench(m, tr.q[idx], tr.qd[idx], tr.qdd[idx], tr.f_tip_w[idx])
    no_c = fr.inverse_dynamics_wrench(m, tr.q[idx], tr.qd[idx], tr.qdd[idx])
    r = _sensor_rotation(m, tr.q[idx])
    fs = np.einsum("nji,nj->ni", r, tr.f_tip_w[idx])
    np.testing.assert_allclose(with_c - no_c, np.hstack([fs, np.cross(np.asarray(fr.TOOL_TIP_S_M), fs)]),
                               atol=1e-9)
    np.testing.assert_allclose(with_c, np.asarray(fr.true_wrench(None))[idx], atol=1e-12)


def test_tared_case_is_zero_at_tare_instant(case_dirs):
    """(b)"""
    i = int(round(fr.TARE_T_S * fr.RATE_HZ))
    _, stamps, data = _read_csv(case_dirs["tared_rotation"] / "log.csv.gz")
    assert (stamps[i] - stamps[0]) * 1e-9 == pytest.approx(0.2)
    assert np.all(data[i, 14:] == 0.0)
    tab = pq.read_table(case_dirs["tared_rotation"] / "log.parquet").to_pydict()
    assert tab["time_s"][i] == pytest.approx(0.2)
    assert all(tab[f"wrench_{k}"][i] == 0.0 for k in range(6))
    assert np.abs(data[:, 14:17]).max() > 5.0  # not zero elsewhere


@pytest.mark.parametrize("case", GENERATED)
def test_csv_and_parquet_hold_the_same_samples(case_dirs, case):
    """(c) same samples: ns stamps vs s, rad vs deg, sensor_on_tool vs tool_on_sensor."""
    header, stamps, data = _read_csv(case_dirs[case] / "log.csv.gz")
    assert header == ["stamp_ns", *[f"pos_j{j}" for j in range(1, 8)], *[f"vel_j{j}" for j in range(1, 8)],
                      "F_x", "F_y", "F_z", "T_x", "T_y", "T_z"]
    tab = pq.read_table(case_dirs[case] / "log.parquet")
    assert tab.column_names == ["time_s", *[f"a{j}" for j in range(1, 8)], *[f"wrench_{k}" for k in range(6)]]
    p = {k: np.asarray(v) for k, v in tab.to_pydict().items()}
    assert len(stamps) == len(p["time_s"]) == 7501
    np.testing.assert_allclose((stamps - stamps[0]) * 1e-9, p["time_s"], atol=1e-12)
    assert stamps[0] == fr.STAMP0_NS
    q_deg = np.stack([p[f"a{j}"] for j in range(1, 8)], axis=1)
    np.testing.assert_allclose(np.deg2rad(q_deg), data[:, :7], atol=1e-10)
    w_pq = np.stack([p[f"wrench_{k}"] for k in range(6)], axis=1)
    np.testing.assert_allclose(-w_pq, data[:, 14:], atol=1e-6)
    sig = fr.case_signals(case, seed=SEED)
    np.testing.assert_allclose(data[:, 7:14], sig["qdot"], atol=1e-8)


@pytest.mark.parametrize("case", GENERATED)
def test_setups_load_and_declare_the_nominal_rig(case_dirs, case):
    """(d)"""
    truth = json.loads((case_dirs[case] / "truth.json").read_text())
    for variant in ("csv", "parquet"):
        cfg = load_setup(case_dirs[case] / f"setup_{variant}.toml")
        assert cfg.tool.mass_kg == pytest.approx(1.10)
        assert cfg.tool.tip_sensor_m == pytest.approx((0.010, 0.0, 0.180))
        assert cfg.tool.com_sensor_m == pytest.approx((0.004, -0.002, 0.055))
        assert cfg.sensor.position_flange_m == pytest.approx((0.0, 0.0, 0.012))
        # the declared mount is the one built into the MuJoCo model
        m = fr.build_model()
        d = mujoco.MjData(m)
        mujoco.mj_kinematics(m, d)
        r_wf = d.site_xmat[m.site("flange").id].reshape(3, 3)
        r_ws = d.site_xmat[m.site("ft").id].reshape(3, 3)
        np.testing.assert_allclose(r_wf.T @ r_ws, cfg.sensor.R_fs(), atol=1e-12)
        p_f = r_wf.T @ (d.site_xpos[m.site("ft").id] - d.site_xpos[m.site("flange").id])
        np.testing.assert_allclose(p_f, cfg.sensor.position_flange_m, atol=1e-12)
        assert cfg.log.tared == truth["tared"]
        assert cfg.contact.mode == "tip"
    csv_cfg = load_setup(case_dirs[case] / "setup_csv.toml")
    assert csv_cfg.log.wrench_acts == "sensor_on_tool" and csv_cfg.log.angle_unit == "rad"
    assert csv_cfg.log.time_scale_s == 1e-9 and len(csv_cfg.log.qdot) == 7
    pq_cfg = load_setup(case_dirs[case] / "setup_parquet.toml")
    assert pq_cfg.log.wrench_acts == "tool_on_sensor" and pq_cfg.log.angle_unit == "deg"
    assert pq_cfg.log.qdot == () and pq_cfg.log.time == "time_s"


def test_truth_files(case_dirs):
    t = {n: json.loads((case_dirs[n] / "truth.json").read_text()) for n in GENERATED}
    assert t["none"]["effects"] == {} and t["none"]["detectable"] is True
    assert t["encoder_offset"]["effects"] == {"encoder_offset": {"offset_joint4": 1.0}}
    rot = t["tared_rotation"]["effects"]["ft_frame_rotation"]
    assert [rot["rot_x"], rot["rot_y"], rot["rot_z"]] == pytest.approx([2.0, 1.0, 2.0])
    assert t["tared_rotation"]["tared"] is True
    drift = t["ft_bias_drift"]
    assert drift["effects"]["ft_bias_drift"]["rate_fx"] == pytest.approx(0.15)
    assert drift["truth_parquet"]["ft_bias_drift"]["rate_fx"] == pytest.approx(-0.15)
    assert drift["truth_parquet"]["ft_bias_drift"]["rate_tz"] == pytest.approx(0.008)
    assert set(fr.CASES) == {"none", "tool_gravity", "ft_frame_rotation", "ft_bias_drift", "encoder_offset",
                             "encoder_offset_joint1", "pair", "tared_rotation"}


def test_encoder_offset_shifts_joint4_only(case_dirs):
    """(e) same seed, same noise: the logged q4 is the none case's minus 1 deg, nothing else differs."""
    _, _, a = _read_csv(case_dirs["none"] / "log.csv.gz")
    _, _, b = _read_csv(case_dirs["encoder_offset"] / "log.csv.gz")
    diff = b - a
    np.testing.assert_allclose(diff[:, 3], -math.radians(1.0), atol=2e-10)
    assert np.abs(np.delete(diff, 3, axis=1)).max() == 0.0
    pa_ = pq.read_table(case_dirs["none"] / "log.parquet").to_pydict()
    pb = pq.read_table(case_dirs["encoder_offset"] / "log.parquet").to_pydict()
    np.testing.assert_allclose(np.asarray(pb["a4"]) - np.asarray(pa_["a4"]), -1.0, atol=1e-9)


def test_frame_rotation_is_rotated_none_reading():
    """(f) noiseless: rotated = R(delta)^T none, rows of force and torque; noise is added last."""
    none = fr.case_signals("none", seed=SEED, noise=False)["wrench"]
    rot = fr.case_signals("ft_frame_rotation", seed=SEED, noise=False)["wrench"]
    r = fr.rotvec_matrix(np.deg2rad([2.0, 1.0, 2.0]))
    expect = np.hstack([(r.T @ none[:, :3].T).T, (r.T @ none[:, 3:].T).T])
    np.testing.assert_allclose(rot, expect, atol=1e-12)
    assert np.abs(rot - none).max() > 0.3  # a visible change
    noisy_none = fr.case_signals("none", seed=SEED)["wrench"]
    noisy_rot = fr.case_signals("ft_frame_rotation", seed=SEED)["wrench"]
    np.testing.assert_allclose(noisy_rot - rot, noisy_none - none, atol=1e-12)


def test_payload_and_drift_effects():
    """tool_gravity: static difference = the payload's weight and moment; drift = rate * t (csv)."""
    tr = fr.trajectory()
    idx = _static_samples(tr)
    base = fr.case_signals("none", noise=False)["wrench"]
    grav = fr.case_signals("tool_gravity", noise=False)["wrench"]
    r = _sensor_rotation(fr.build_model(), tr.q[idx])
    fg = 0.25 * np.einsum("nji,j->ni", r, np.array([0.0, 0.0, -9.81]))
    expect = -np.hstack([fg, np.cross(np.array([0.03, -0.02, 0.06]), fg)])  # csv: sensor_on_tool
    np.testing.assert_allclose(grav[idx] - base[idx], expect, atol=1e-6)
    drift = fr.case_signals("ft_bias_drift", noise=False)["wrench"]
    rates = np.array([0.15, -0.10, 0.20, 0.010, 0.006, -0.008])
    np.testing.assert_allclose(drift - base, tr.t[:, None] * rates, atol=1e-12)
