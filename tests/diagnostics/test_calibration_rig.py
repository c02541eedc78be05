"""The calibration-rig fixtures (examples/calibration_rig.py): physics, calibration and files.

The generator is independent of the package (no kinadapt_nn, no MuJoCo); only these tests use
``kinadapt_nn`` (to load the setup files it writes).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from kinadapt_nn.diagnostics.setup import load_setup
from tests.diagnostics.example_scripts import load_example

ROOT = Path(__file__).resolve().parents[2]
RIG_PY = ROOT / "examples" / "calibration_rig.py"
SEED = 4


cr = load_example("calibration_rig")
STATIC = tuple(cr.static_cases("ur5e"))


@pytest.fixture(scope="module")
def out_dir(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("calibration_rig")
    for arm in cr.ARMS:
        for name in STATIC:
            cr.make_case(arm, name, out, seed=SEED)
    cr.make_case("ur5e", "moving_none", out, seed=SEED)
    return out


def _read_csv(path: Path) -> tuple[list[str], np.ndarray]:
    lines = path.read_text().splitlines()
    return lines[0].split(","), np.array([[float(x) for x in ln.split(",")] for ln in lines[1:]])


def test_generator_is_standalone():
    src = RIG_PY.read_text()
    for mod in ("kinadapt_nn", "mujoco"):
        assert f"import {mod}" not in src and f"from {mod}" not in src


def test_self_test_passes_with_margin():
    err = cr.self_test()
    assert err["velocity_vs_jacobian"] < 1e-7 and err["acceleration_vs_recursion"] < 1e-6
    assert err["newton_euler_vs_point_masses"] < 1e-6 and err["newton_euler_at_hold"] == 0.0
    assert err["max_inertial_force_N"] > 1.0  # the moving log does excite the tool's inertia


@pytest.mark.parametrize("arm", ["ur5e", "iiwa14"])
@pytest.mark.parametrize("case", ["mount_unknown", "mount_unknown_general", "tool_gravity", "ft_frame_rotation"])
def test_independent_calibration_recovers_the_truth(out_dir, arm, case):
    """From the written files alone: the log's wrench (units per the truth), our FK of the logged
    joints, and the classic calibration -> the true mount, mass, COM and offset."""
    d = out_dir / arm / case
    truth = json.loads((d / "truth.json").read_text())
    header, data = _read_csv(d / "log.csv")
    n = cr.ARMS[arm].n
    q = np.deg2rad(data[:, :n]) if cr.STATIC_RIGS[arm].angle_unit == "deg" else data[:, :n]
    w = data[:, n:] / np.array([cr.FORCE_PER_N[truth["units"]["force_unit_logged"]]] * 3
                               + [cr.TORQUE_PER_NM[truth["units"]["torque_unit_logged"]]] * 3)
    cal = cr.calibrate(cr.frames(cr.ARMS[arm], q)[:, -1, :3, :3], w, truth["gravity_mps2"])
    tr = truth["calibration"]["truth"]
    assert abs(cal.mass_kg / tr["tool_mass_kg"] - 1) < 0.01
    assert cr.rotation_angle_deg(cr.rpy_matrix_deg(tr["rpy_flange_deg"]).T @ cal.R_fs) < 0.5
    assert np.linalg.norm(cal.com_s_m - tr["tool_com_sensor_m"]) < 1e-3
    assert np.abs(cal.offset - tr["offset"]).max() < 0.05
    # the stored estimate is this one, and the residual is the noise
    est = truth["calibration"]["estimate"]
    assert est["tool_mass_kg"] == pytest.approx(cal.mass_kg, rel=1e-6)
    assert np.allclose(est["residual_rms"], [cr.SIGMA_FORCE_N] * 3 + [cr.SIGMA_TORQUE_NM] * 3, rtol=0.2)
    assert truth["experiment"]["gravity_coverage_deg"] <= cr.COVERAGE_DEG


def test_truth_and_setups_agree(out_dir):
    for arm in cr.ARMS:
        for name in STATIC:
            d = out_dir / arm / name
            truth = json.loads((d / "truth.json").read_text())
            s = load_setup(d / "setup.toml")
            assert s.log.static and s.log.time == "" and s.log.tared and s.contact.mode == "none"
            assert s.log.torque_unit == truth["units"]["torque_unit_declared"]
            assert s.log.force_unit == truth["units"]["force_unit_declared"]
            assert s.sensor.mount_known == truth["sensor_mount"]["mount_known"]
            assert s.world.gravity_mps2 == truth["gravity_mps2"]
            assert len(s.log.q) == cr.ARMS[arm].n
            assert s.arm.kind == ("urdf" if truth["arm_model"] == "urdf" else "dh")
            if s.arm.kind == "dh":
                assert s.arm.dh.convention == cr.ARMS[arm].convention
            decl = cr.rpy_matrix_deg(s.sensor.rpy_flange_deg)
            angle = cr.rotation_angle_deg(decl.T @ cr.rpy_matrix_deg(truth["sensor_mount"]["true_rpy_flange_deg"]))
            assert angle == pytest.approx(truth["sensor_mount"]["rotation_from_declared_deg"], abs=1e-9)
            assert set(truth["expected_verdicts"]) == set(truth["effects"])
    t = json.loads((out_dir / "ur5e" / "torque_unit_wrong" / "truth.json").read_text())
    assert t["units"] == {"force_unit_logged": "N", "force_unit_declared": "N", "likely_force_unit": "N",
                          "torque_unit_logged": "N mm", "torque_unit_declared": "N m", "likely_torque_unit": "N mm"}
    t = json.loads((out_dir / "ur5e" / "force_unit_wrong" / "truth.json").read_text())
    assert (t["units"]["force_unit_logged"], t["units"]["force_unit_declared"]) == ("lbf", "N")
    _, data = _read_csv(out_dir / "ur5e" / "force_unit_wrong" / "log.csv")
    _, data_n = _read_csv(out_dir / "ur5e" / "torque_unit_wrong_nm" / "log.csv")  # the same draws, in N
    assert np.allclose(data[:, 6:9] * 4.4482216152605, data_n[:, 6:9], atol=5e-5)
    assert np.array_equal(data[:, 9:], data_n[:, 9:])
    t = json.loads((out_dir / "ur5e" / "mount_wrong_known" / "truth.json").read_text())
    assert t["sensor_mount"]["declared_consistent"] is False
    assert json.loads((out_dir / "ur5e" / "mount_declared" / "truth.json").read_text())["gravity_mps2"] == 9.80665
    s = load_setup(out_dir / "ur5e" / "moving_none" / "setup.toml")
    assert not s.log.static and len(s.log.qdot) == 6 and s.arm.dh.convention == "classic"


def test_mount_wrong_known_is_the_mount_unknown_log(out_dir):
    for arm in cr.ARMS:
        a = (out_dir / arm / "mount_unknown" / "log.csv").read_bytes()
        assert a == (out_dir / arm / "mount_wrong_known" / "log.csv").read_bytes()


def test_moving_log_at_rest_is_the_weight_plus_offset(out_dir):
    """The first hold (0-0.5 s) of moving_none: tool-on-sensor = m R_ws^T g + offset, in the file."""
    header, data = _read_csv(out_dir / "ur5e" / "moving_none" / "log.csv")
    assert header[0] == cr.MOVING_TIME_COL and data.shape == (6276, 19)
    assert np.allclose(np.diff(data[:, 0]), 1 / cr.RATE_HZ, atol=1e-9)
    hold = data[:, 0] < 0.45
    rig = cr.MOVING_RIG
    R_ws = cr.frames(cr.UR5E, np.array([cr.MOVING_Q_HOME]))[0, -1, :3, :3] @ cr.rpy_matrix_deg(rig.sensor_rpy_f_deg)
    F = rig.tool_mass_kg * R_ws.T @ np.array([0.0, 0.0, -cr.G_STD])
    expect = np.r_[F, np.cross(rig.tool_com_s_m, F)] + np.asarray(rig.offset)
    se = np.array([cr.SIGMA_FORCE_N] * 3 + [cr.SIGMA_TORQUE_NM] * 3) / math.sqrt(hold.sum())
    assert np.all(np.abs(data[hold, 13:].mean(axis=0) - expect) < 5 * se)


def _urdf_from_dh(arm, base_yaw_deg: float, tail_xyz, tail_rpy_deg) -> str:
    """A URDF of a classic-DH arm: joint i at Tx(a_{i-1}) Rx(alpha_{i-1}) Tz(d_i) in link i-1, the base
    turned about z and a fixed tail link (the URDF's last link is then the DH flange times that tail)."""
    joints, prev = [], ("0 0 0", f"0 0 {math.radians(base_yaw_deg)!r}")
    for i in range(arm.n):
        a, al = (arm.a_m[i - 1], arm.alpha_rad[i - 1]) if i else (0.0, 0.0)
        xyz = f"{a!r} {-arm.d_m[i] * math.sin(al)!r} {arm.d_m[i] * math.cos(al)!r}"
        origin = (xyz, f"{al!r} 0 0") if i else (f"0 0 {arm.d_m[0]!r}", prev[1])
        joints.append(("revolute", f"l{i}", f"l{i + 1}", origin))
    # the last DH frame (a_6 = alpha_6 = 0 for the ur5e), then the tail
    tail = (" ".join(map(repr, tail_xyz)), " ".join(repr(math.radians(x)) for x in tail_rpy_deg))
    joints.append(("fixed", f"l{arm.n}", "tool", tail))
    body = "".join(f'<link name="l{i}"/>' for i in range(arm.n + 1)) + '<link name="tool"/>'
    for kind, p, c, (xyz, rpy) in joints:
        axis = '<axis xyz="0 0 1"/>' if kind == "revolute" else ""
        body += (f'<joint name="{c}_j" type="{kind}"><parent link="{p}"/><child link="{c}"/>'
                 f'<origin xyz="{xyz}" rpy="{rpy}"/>{axis}</joint>')
    return f'<?xml version="1.0"?><robot name="t">{body}</robot>'


def test_urdf_match_finds_base_turn_and_flange_offset(tmp_path):
    p = tmp_path / "arm.urdf"
    p.write_text(_urdf_from_dh(cr.UR5E, 180.0, (0.01, -0.02, 0.03), (10.0, 0.0, 90.0)))
    m = cr.urdf_match(p, cr.UR5E)
    assert m.error < 1e-9 and m.base_yaw_deg == 180.0
    assert np.allclose(m.F, cr.homogeneous(cr.rpy_matrix_deg((10.0, 0.0, 90.0)), (0.01, -0.02, 0.03)), atol=1e-9)
    p.write_text(_urdf_from_dh(cr.UR5E, 0.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)))
    assert cr.urdf_match(p, cr.UR5E).error < 1e-9
