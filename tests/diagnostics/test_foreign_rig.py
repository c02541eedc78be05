"""The foreign-rig fixtures (examples/foreign_rig.py): physics, conventions and files.

The generator is independent of the package; only these tests use ``kinadapt_nn`` (to load the
setup files it writes).
"""

from __future__ import annotations

import gzip
import json
import math
from pathlib import Path

import mujoco
import numpy as np
import pyarrow.parquet as pq
import pytest

from kinadapt_nn.diagnostics.setup import load_setup
from tests.diagnostics.example_scripts import load_example

ROOT = Path(__file__).resolve().parents[2]
RIG_PY = ROOT / "examples" / "foreign_rig.py"
SEED = 3
GENERATED = ("none", "encoder_offset", "tared_rotation", "ft_bias_drift")


fr = load_example("foreign_rig")


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


# inside the segments (finite differences across a C2 join are only O(h) accurate)
_MOVING_TS = {"A": (0.8, 1.95, 2.77, 4.3, 5.5, 6.6, 8.05, 9.2, 11.3, 12.6),
              "B": (0.5, 1.3, 2.1, 3.0, 4.0, 5.0, 6.0, 7.0, 7.9, 8.6, 9.2, 10.3, 11.6)}


@pytest.mark.parametrize("rig", ["A", "B"])
def test_moving_reading_matches_newton_euler(rig):
    """In motion (no contact): tool-on-sensor = (m (g - a_c), -(c x m a'_c + I alpha + w x I w))
    with the tool's motion from finite differences of MuJoCo's forward kinematics."""
    rg = fr.RIGS[rig]
    tr = fr.trajectory(rig)
    m = fr.build_model(rig=rig)
    d = mujoco.MjData(m)
    sid, bid = m.site("ft").id, m.body("tool").id
    ts, h = np.array(_MOVING_TS[rig]), 1e-4
    w = fr.inverse_dynamics_wrench(m, *tr.eval(ts))
    g = np.array([0.0, 0.0, -9.81])
    ixx, iyy, izz, ixy, ixz, iyz = rg.tool_inertia_com_kg_m2
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
        f_sensor_on_tool = rg.tool_mass_kg * (a_c - g)
        i_w = r @ i_s @ r.T
        tau_c = i_w @ al + np.cross(om, i_w @ om)
        tau_o = tau_c + np.cross(pc - po, f_sensor_on_tool)
        expect = -np.r_[r.T @ f_sensor_on_tool, r.T @ tau_o]
        np.testing.assert_allclose(w[k], expect, atol=2e-5)
        a_max = max(a_max, float(np.linalg.norm(a_c)))
        al_max = max(al_max, float(np.linalg.norm(al)))
    assert a_max > 0.5 and al_max > 2.0, (a_max, al_max)  # really moving


@pytest.mark.parametrize("rig", ["A", "B"])
def test_contact_acts_at_the_tip(rig):
    tr = fr.trajectory(rig)
    m = fr.build_model(rig=rig)
    idx = np.nonzero(np.any(tr.f_tip_w != 0.0, axis=1))[0][::97]
    with_c = fr.inverse_dynamics_wrench(m, tr.q[idx], tr.qd[idx], tr.qdd[idx], tr.f_tip_w[idx])
    no_c = fr.inverse_dynamics_wrench(m, tr.q[idx], tr.qd[idx], tr.qdd[idx])
    r = _sensor_rotation(m, tr.q[idx])
    fs = np.einsum("nji,nj->ni", r, tr.f_tip_w[idx])
    tip = np.asarray(fr.RIGS[rig].tool_tip_s_m)
    np.testing.assert_allclose(with_c - no_c, np.hstack([fs, np.cross(tip, fs)]), atol=1e-9)
    np.testing.assert_allclose(with_c, np.asarray(fr.true_wrench(None, rig))[idx], atol=1e-12)


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


# ==================================================================================================
# rig B: flipped sensor, offset probe, 1 kHz plain csv without velocities, tared at power-up
# ==================================================================================================
GENERATED_B = ("none", "encoder_offset", "ft_bias_drift", "rotation_z_only")
LSB_B = np.array([1 / 64] * 3 + [1e-3] * 3)


@pytest.fixture(scope="module")
def case_dirs_b(tmp_path_factory) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("foreign_rig_b")
    return {n: fr.make_case(n, out, seed=SEED, rig="B") for n in GENERATED_B}


def _read_csv_b(path: Path) -> tuple[list[str], np.ndarray]:
    """(header, the columns (N, 14))."""
    with open(path) as fh:
        header = fh.readline().strip().split(",")
    return header, np.loadtxt(path, delimiter=",", skiprows=1)


def _weight_wrench(m: mujoco.MjModel, q: np.ndarray, mass: float, com) -> np.ndarray:
    """(N, 6) tool-on-sensor wrench of a point mass at ``com`` (sensor frame) at rest."""
    r = _sensor_rotation(m, q)
    fg = mass * np.einsum("nji,j->ni", r, np.array([0.0, 0.0, -9.81]))
    return np.hstack([fg, np.cross(np.asarray(com), fg)])


def test_rig_b_self_test_and_mount():
    err = fr.self_test(rig="B")
    assert max(err.values()) < 1e-9
    # flipped: the sensor's z axis points back into the flange, the tool lies at negative s z
    r_fs = fr.rpy_matrix_deg(fr.B_SENSOR_RPY_F_DEG)
    np.testing.assert_allclose(r_fs[:, 2], [0.0, 0.0, -1.0], atol=1e-15)
    assert fr.B_TOOL_COM_S_M[2] < 0.0 and fr.B_TOOL_TIP_S_M[2] < 0.0


def test_rig_b_trajectory_shape_limits_and_table():
    tr = fr.trajectory("B")
    m = fr.build_model(rig="B")
    assert tr.q.shape == (12001, 7) and tr.t[-1] == pytest.approx(12.0) and tr.t[1] == pytest.approx(1e-3)
    lo, hi = m.jnt_range[:, 0], m.jnt_range[:, 1]
    assert np.all(tr.q > lo + 0.1) and np.all(tr.q < hi - 0.1)
    assert np.all(np.abs(tr.qd).max(0) < np.asarray(fr.QDOT_LIMIT))
    assert np.all(np.abs(tr.qdd).max(0) < np.asarray(fr.QDDOT_LIMIT))
    assert np.all(tr.q[: int(fr._B_T_START_HOLD * 1000)] == np.asarray(fr.B_Q_HOME))
    # the tool (= -s z) points roughly down at home
    r_home = _sensor_rotation(m, np.asarray([fr.B_Q_HOME]))[0]
    assert math.degrees(math.acos(-r_home[2, 2] * -1.0)) < 20.0
    # phase 2 (wiggle) moves joints 2, 4, 6 only
    t2 = fr._B_T_START_HOLD + sum(x[3] + x[4] for x in fr._B_PHASE1_TARGETS)
    wig = (tr.t > t2) & (tr.t < t2 + fr._B_WIGGLE_S)
    moved = np.ptp(tr.q[wig], axis=0)
    assert np.all(moved[[1, 3, 5]] > 0.1) and np.all(moved[[0, 2, 4, 6]] == 0.0)
    # the table: tilted 10 deg about world x; the tip on it while pressed, above it otherwise
    n = tr.table_normal_w
    np.testing.assert_allclose(n, [0.0, -math.sin(math.radians(10)), math.cos(math.radians(10))], atol=1e-15)
    on = np.any(tr.f_tip_w != 0.0, axis=1)
    assert np.all(tr.f_tip_w[tr.t < t2 + fr._B_WIGGLE_S] == 0.0)
    height = (tr.tip_w - tr.table_point_w) @ n
    assert np.abs(height[on]).max() < 1e-5 and height[~on].min() > -1e-5
    fn = tr.f_tip_w @ n
    assert fn.max() == pytest.approx(fr.B_NORMAL_FORCE_N) and fn.min() >= 0.0
    ft = np.linalg.norm(tr.f_tip_w - fn[:, None] * n[None, :], axis=1)
    assert np.all(ft <= fr.B_MU * fn + 1e-12) and ft.max() > 0.99 * fr.B_MU * fr.B_NORMAL_FORCE_N
    # a circle of radius 2 cm in the table plane (in-plane extent 4 cm x 4 cm)
    u, v = np.array([1.0, 0.0, 0.0]), np.cross(n, [1.0, 0.0, 0.0])
    for ax in (u, v):
        assert np.ptp(tr.tip_w[on] @ ax) == pytest.approx(2 * fr.B_CIRCLE_RADIUS_M, abs=2e-4)
    # the tare pose is nowhere in the log
    assert np.abs(tr.q - np.asarray(fr.B_TARE_Q)).max(axis=1).min() > 0.5
    # derivatives are those of q
    ts, h = np.array([0.5, 2.1, 4.0, 6.0, 7.9, 8.6, 9.7, 10.8]), 1e-5
    q, qd, qdd = tr.eval(ts)
    qp, qdp, _ = tr.eval(ts + h)
    qm, qdm, _ = tr.eval(ts - h)
    np.testing.assert_allclose((qp - qm) / (2 * h), qd, atol=1e-7)
    np.testing.assert_allclose((qdp - qdm) / (2 * h), qdd, atol=1e-5)


def test_rig_b_static_reading_is_the_tool_weight(case_dirs_b):
    """At rest: tool-on-sensor = the weight in the (flipped) sensor frame; the logged file is that
    plus the tare constant, quantised, with noise of the stated sigma."""
    tr = fr.trajectory("B")
    m = fr.build_model(rig="B")
    rest = np.all(tr.qd == 0.0, axis=1) & np.all(tr.qdd == 0.0, axis=1) & np.all(tr.f_tip_w == 0.0, axis=1)
    idx = np.nonzero(rest)[0]
    assert len(idx) > 1000
    expect = _weight_wrench(m, tr.q[idx], fr.B_TOOL_MASS_KG, fr.B_TOOL_COM_S_M)
    sig = fr.case_signals("none", seed=SEED, rig="B")
    np.testing.assert_allclose(sig["w_tool_on_sensor_s"][idx], expect, atol=1e-9)
    # the flipped sensor at home (tool down, s z up): the tool pulls the sensor along -s z (rig A: +s z)
    assert expect[0, 2] < -0.9 * fr.B_TOOL_MASS_KG * 9.81
    _, data = _read_csv_b(case_dirs_b["none"] / "log.csv")
    np.testing.assert_array_equal(data[:, 8:], sig["wrench"])
    hold = idx[idx < 250]
    res = data[hold, 8:] - sig["tare"] - expect[: len(hold)]
    sd = np.array([fr.B_SIGMA_FORCE_N] * 3 + [fr.B_SIGMA_TORQUE_NM] * 3)
    assert np.all(np.abs(res.mean(axis=0)) < 5 * sd / math.sqrt(len(hold)) + LSB_B / 2)
    assert np.std(res[:, :3]) == pytest.approx(fr.B_SIGMA_FORCE_N, rel=0.15)
    assert np.std(res[:, 3:]) == pytest.approx(fr.B_SIGMA_TORQUE_NM, rel=0.15)
    # quantised to 1/64 N and 1/1000 N m
    k = data[:, 8:] / LSB_B
    assert np.abs(k - np.round(k)).max() < 1e-6


@pytest.mark.parametrize("case", ["none", "tool_gravity", "ft_frame_rotation"])
def test_rig_b_tare_arithmetic(case):
    """The tare pose is not in the log: logged (noiseless) = reading + tare, tare = offset - reading at
    the tare pose (rotated like the reading), the reading there being the static weight."""
    m = fr.build_model(rig="B")
    h = fr._HIDDEN_B[case]
    mass, com = fr.B_TOOL_MASS_KG, np.asarray(fr.B_TOOL_COM_S_M)
    w_tare = _weight_wrench(m, np.asarray([fr.B_TARE_Q]), mass, com)[0]
    if h.payload is not None:
        w_tare = w_tare + _weight_wrench(m, np.asarray([fr.B_TARE_Q]), *h.payload)[0]
    np.testing.assert_allclose(fr.tare_wrench_b(h.payload), w_tare, atol=1e-9)
    r = fr.rotvec_matrix(np.deg2rad(h.rotvec_deg)) if h.rotvec_deg is not None else np.eye(3)
    tare = np.asarray(fr.B_TARE_OFFSET) - np.r_[r.T @ w_tare[:3], r.T @ w_tare[3:]]
    sig = fr.case_signals(case, noise=False, rig="B")
    np.testing.assert_allclose(sig["tare"], tare, atol=1e-9)
    w = np.array(fr.true_wrench(h.payload, "B"))
    expect = np.hstack([w[:, :3] @ r, w[:, 3:] @ r]) + tare
    assert np.all(np.abs(sig["wrench"] - expect) <= LSB_B / 2 + 1e-12)
    assert np.abs(sig["tare"]).max() > 1.0  # a visible, arbitrary constant


def test_rig_b_files_and_setup(case_dirs_b):
    for case, d in case_dirs_b.items():
        assert sorted(x.name for x in d.iterdir()) == ["log.csv", "setup.toml", "truth.json"]
        header, data = _read_csv_b(d / "log.csv")
        assert header == ["t", *[f"q{j}" for j in range(1, 8)], "fx", "fy", "fz", "tx", "ty", "tz"]
        assert data.shape == (12001, 14)
        np.testing.assert_allclose(data[:, 0], 3.7 + np.arange(12001) / 1000, atol=1e-9)
        sig = fr.case_signals(case, seed=SEED, rig="B")
        np.testing.assert_allclose(data[:, 1:8], sig["q"], atol=1e-9)
        np.testing.assert_array_equal(data[:, 8:], sig["wrench"])
        cfg = load_setup(d / "setup.toml")
        assert cfg.log.time == "t" and cfg.log.time_scale_s == 1.0 and cfg.log.qdot == ()
        assert cfg.log.wrench_acts == "tool_on_sensor" and cfg.log.angle_unit == "rad" and cfg.log.tared is True
        assert cfg.tool.mass_kg == pytest.approx(0.48)
        assert cfg.tool.com_sensor_m == pytest.approx((0.012, 0.0, -0.07))
        assert cfg.tool.tip_sensor_m == pytest.approx((0.0, 0.02, -0.21))
        assert cfg.tool.inertia_com_kg_m2 == pytest.approx((0.0011, 0.0012, 0.0003, 0.0001, 0.0, 0.0))
        m = fr.build_model(rig="B")
        dd = mujoco.MjData(m)
        dd.qpos[:] = fr.B_Q_HOME
        mujoco.mj_kinematics(m, dd)
        r_wf = dd.site_xmat[m.site("flange").id].reshape(3, 3)
        np.testing.assert_allclose(r_wf.T @ dd.site_xmat[m.site("ft").id].reshape(3, 3), cfg.sensor.R_fs(), atol=1e-12)
        p_f = r_wf.T @ (dd.site_xpos[m.site("ft").id] - dd.site_xpos[m.site("flange").id])
        np.testing.assert_allclose(p_f, cfg.sensor.position_flange_m, atol=1e-12)
        truth = json.loads((d / "truth.json").read_text())
        assert truth["rig"] == "B" and truth["tared"] is True and truth["case"] == case
        assert truth["experiment"]["tare_added_log"] == pytest.approx(list(sig["tare"]))
    t = {n: json.loads((case_dirs_b[n] / "truth.json").read_text()) for n in GENERATED_B}
    assert t["none"]["effects"] == {}
    assert t["encoder_offset"]["effects"] == {"encoder_offset": {"offset_joint6": 0.8}}
    assert t["rotation_z_only"]["effects"] == {"ft_frame_rotation": {"rot_x": 0.0, "rot_y": 0.0, "rot_z": 2.0}}
    assert t["ft_bias_drift"]["effects"]["ft_bias_drift"] == pytest.approx(
        {"rate_fx": -0.08, "rate_fy": 0.05, "rate_fz": 0.12, "rate_tx": 0.004, "rate_ty": -0.003, "rate_tz": 0.002})
    assert set(fr.CASES_B) == {"none", "tool_gravity", "ft_frame_rotation", "ft_bias_drift", "encoder_offset",
                               "encoder_offset_joint1", "pair", "rotation_z_only"}
    assert all(h.tared for h in fr._HIDDEN_B.values())


def test_rig_b_effects():
    """Same seed, same noise: encoder offsets shift one joint; the drift is rate * (t - t_first) (log
    convention); the z-only rotation and the 1.5 deg rotation turn the none reading; the payload adds
    its weight at rest. Up to the quantisation (one LSB)."""
    none = fr.case_signals("none", seed=SEED, rig="B")
    t = none["t"] - fr.B_T0_S
    for case, j, off in (("encoder_offset", 6, 0.8), ("encoder_offset_joint1", 1, 1.5)):
        s = fr.case_signals(case, seed=SEED, rig="B")
        diff = s["q"] - none["q"]
        np.testing.assert_allclose(diff[:, j - 1], -math.radians(off), atol=1e-12)
        assert np.abs(np.delete(diff, j - 1, axis=1)).max() == 0.0
        np.testing.assert_array_equal(s["wrench"], none["wrench"])
    pair = fr.case_signals("pair", seed=SEED, rig="B")
    np.testing.assert_allclose(pair["q"][:, 1] - none["q"][:, 1], -math.radians(0.7), atol=1e-12)
    rates = np.array([-0.08, 0.05, 0.12, 0.004, -0.003, 0.002])
    for case in ("ft_bias_drift", "pair"):
        s = fr.case_signals(case, seed=SEED, rig="B")
        assert np.all(np.abs(s["wrench"] - none["wrench"] - t[:, None] * rates) <= LSB_B + 1e-12)
    w_none = np.array(fr.true_wrench(None, "B"))  # noiseless, unquantised, declared axes
    for case, rotvec in (("rotation_z_only", (0.0, 0.0, 2.0)), ("ft_frame_rotation", fr._ROT_B)):
        s = fr.case_signals(case, noise=False, rig="B")
        r = fr.rotvec_matrix(np.deg2rad(rotvec))
        expect = np.hstack([w_none[:, :3] @ r, w_none[:, 3:] @ r]) + s["tare"]
        assert np.all(np.abs(s["wrench"] - expect) <= LSB_B / 2 + 1e-12)
        assert np.abs(s["wrench"] - s["tare"] - w_none).max() > 0.1  # a visible change
    assert np.linalg.norm(fr._ROT_B) == pytest.approx(1.5)
    tr = fr.trajectory("B")
    rest = np.nonzero(np.all(tr.qd == 0.0, axis=1) & np.all(tr.f_tip_w == 0.0, axis=1))[0]
    g = fr.case_signals("tool_gravity", noise=False, rig="B")
    expect = _weight_wrench(fr.build_model(rig="B"), tr.q[rest], 0.12, (-0.02, 0.01, -0.04))
    got = (g["wrench"] - g["tare"]) - w_none
    assert np.all(np.abs(got[rest] - expect) <= LSB_B / 2 + 1e-9)
