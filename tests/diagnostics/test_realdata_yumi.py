"""A real arm's F/T-calibration poses (``../shared/realdata/yumi_gravitylog``: a 7-joint YuMi-type
arm, 13 802 poses at rest, wrist sensor raw (not tared), forces in N and torques in N mm, the mount
unknown; from Robotlib.jl, MIT, F. Bagge Carlson).

Declared as a user would (``static = true`` and NO time key: the log has no time column; the MJCF;
the mount unknown; the upstream demo's 0.2205 kg guess), the diagnosis runs and its calibration
(mass, centre of mass, mount) agrees with an independent gravity fit written here: forward
kinematics parsed from the MJCF (numpy, no package code), ``F = K g_f + f0`` by least squares
(``K = m R_fs^T``: the mass and the mount by the nearest rotation), then ``M = c x F_grav + m0``.
Declared in N m, the torques are named as N mm and no verdict is given.

The logs are public data that the project does not ship: the test skips when the folder is absent
(a user's clone has no ``../shared``).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

REAL = Path(__file__).resolve().parents[2] / ".." / "shared" / "realdata" / "yumi_gravitylog"
LOG = REAL / "gravitylog.csv.gz"
G = 9.81
pytestmark = pytest.mark.skipif(not LOG.is_file(),
                                reason="../shared/realdata/yumi_gravitylog is absent (public data, not shipped)")

SETUP = """
[log]
static = true
q = ["q1", "q2", "q3", "q4", "q5", "q6", "q7"]
wrench = ["f1", "f2", "f3", "f4", "f5", "f6"]
torque_unit = "N mm"
tared = true
[sensor]
mount_known = false
[tool]
mass_kg = 0.2205
[arm]
mjcf = "{mjcf}"
flange_site = "flange"
[contact]
mode = "none"
"""


def _quat(wxyz) -> np.ndarray:
    a, b, c, d = np.asarray(wxyz, float) / np.linalg.norm(np.asarray(wxyz, float))
    return np.array([[1 - 2 * (c * c + d * d), 2 * (b * c - a * d), 2 * (b * d + a * c)],
                     [2 * (b * c + a * d), 1 - 2 * (b * b + d * d), 2 * (c * d - a * b)],
                     [2 * (b * d - a * c), 2 * (c * d + a * b), 1 - 2 * (b * b + c * c)]])


def _rz(t: np.ndarray) -> np.ndarray:
    c, s, z, o = np.cos(t), np.sin(t), np.zeros_like(t), np.ones_like(t)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


def _flange_rotation(q: np.ndarray) -> np.ndarray:
    """(N, 7) -> (N, 3, 3) the flange site's axes in the world: the MJCF's body chain (each body's
    quat, then its hinge about z at the body origin), then the site's quat."""
    body = ET.parse(REAL / "yumi_left.xml").getroot().find("worldbody/body")
    R, j = np.repeat(np.eye(3)[None], len(q), axis=0), 0
    while body is not None:
        R = R @ _quat(body.get("quat", "1 0 0 0").split())
        if body.find("joint") is not None:
            assert body.find("joint").get("axis") == "0 0 1"
            R, j = R @ _rz(q[:, j]), j + 1
        if body.find("site") is not None:
            R = R @ _quat(body.find("site").get("quat").split())
        body = body.find("body")
    assert j == 7
    return R


def _rpy_deg(R: np.ndarray) -> np.ndarray:
    """``R = Rz(yaw) Ry(pitch) Rx(roll)`` -> (roll, pitch, yaw) [deg]."""
    return np.rad2deg([np.arctan2(R[2, 1], R[2, 2]), np.arcsin(-R[2, 0]), np.arctan2(R[1, 0], R[0, 0])])


def _rpy_matrix(rpy_deg) -> np.ndarray:
    r, p, y = np.deg2rad(rpy_deg)
    Rx = np.array([[1, 0, 0], [0, np.cos(r), -np.sin(r)], [0, np.sin(r), np.cos(r)]])
    Ry = np.array([[np.cos(p), 0, np.sin(p)], [0, 1, 0], [-np.sin(p), 0, np.cos(p)]])
    Rz = np.array([[np.cos(y), -np.sin(y), 0], [np.sin(y), np.cos(y), 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def independent_calibration() -> dict:
    """The classic two-stage linear calibration of the raw log (module docstring), SI."""
    data = np.loadtxt(LOG, delimiter=",", skiprows=1)  # NumPy reads .gz by the name
    q, F, M = data[:, :7], data[:, 21:24], data[:, 24:27] * 1e-3  # N, N mm -> N m
    g_f = np.einsum("nji,j->ni", _flange_rotation(q), [0.0, 0.0, -G])  # (N, 3) gravity in the flange frame
    coef = np.linalg.lstsq(np.c_[g_f, np.ones(len(q))], F, rcond=None)[0]  # F = K g_f + f0
    U, S, Vt = np.linalg.svd(coef[:3].T)  # K = m R_fs^T
    assert np.linalg.det(coef[:3]) > 0  # the tool pulls along gravity: the tool-on-sensor convention
    R_fs, m = (U @ Vt).T, float(S.mean())
    F_grav = m * g_f @ R_fs  # (N, 3) the tool's weight in the sensor frame
    A = np.zeros((len(q), 3, 6))  # M = c x F_grav + m0 = -[F_grav]x c + m0
    A[:, :, :3] = -np.cross(F_grav[:, None, :], np.eye(3)[None]).transpose(0, 2, 1)  # column k: -(F x e_k)
    A[:, :, 3:] = np.eye(3)
    sol = np.linalg.lstsq(A.reshape(-1, 6), M.reshape(-1), rcond=None)[0]
    return {"mass_kg": m, "com_m": sol[:3], "R_fs": R_fs, "rpy_deg": _rpy_deg(R_fs),
            "force_rms_N": np.sqrt(np.mean((F - F_grav - coef[3]) ** 2, axis=0))}


@pytest.fixture(scope="module")
def yumi(tmp_path_factory):
    from kinadapt_nn.diagnostics.readers import read_log
    from kinadapt_nn.diagnostics.setup import load_setup
    from kinadapt_nn.diagnostics.userlog import diagnose

    d = tmp_path_factory.mktemp("yumi")
    (d / "setup.toml").write_text(SETUP.format(mjcf=(REAL / "yumi_left.xml").resolve().as_posix()))
    setup = load_setup(d / "setup.toml")
    assert setup.log.static and setup.log.time == "t"  # time left out: the default, a column the log lacks
    log = read_log(LOG, setup)
    return d, log, setup, diagnose(log, setup).report


def test_static_log_without_a_time_column_runs(yumi):
    _, log, _, rep = yumi
    assert log.t_s is None and rep["log"]["static"] and not rep["log"]["time_column"]
    assert rep["log"]["samples"] == 13802 and rep["sensor_mount"]["plausible"] and not rep["warnings"]
    assert "ft_bias_drift" not in {e["effect"] for e in rep["ranking"]}  # no time axis, no drift judged


def test_calibration_agrees_with_an_independent_fit(yumi):
    sm, ind = yumi[3]["sensor_mount"], independent_calibration()
    assert abs(ind["mass_kg"] - 0.2232) < 0.002 and np.all(ind["force_rms_N"] < 0.1)  # the fit itself, as measured
    assert abs(sm["tool_mass_kg"] / ind["mass_kg"] - 1) < 0.01
    assert np.linalg.norm(np.subtract(sm["tool_com_sensor_m"], ind["com_m"])) < 0.001
    assert abs(np.linalg.norm(sm["tool_com_sensor_m"]) - np.linalg.norm(ind["com_m"])) < 0.0005
    R_pkg = _rpy_matrix(sm["rpy_flange_deg"])
    angle = np.rad2deg(np.arccos(np.clip((np.trace(R_pkg.T @ ind["R_fs"]) - 1) / 2, -1, 1)))
    assert angle < 1.0, (sm["rpy_flange_deg"], ind["rpy_deg"])


def test_torques_declared_in_n_m_are_named_n_mm(yumi):
    from kinadapt_nn.diagnostics.readers import read_log
    from kinadapt_nn.diagnostics.setup import load_setup
    from kinadapt_nn.diagnostics.userlog import diagnose

    setup = load_setup(yumi[0] / "setup.toml", ['log.torque_unit="N m"'])
    log = read_log(LOG, setup)
    rep = diagnose(log._replace(q_rad=log.q_rad[::8], wrench_log=log.wrench_log[::8]), setup).report  # 1726 poses
    assert any('set [log] torque_unit = "N mm"' in w for w in rep["warnings"]), rep["warnings"]
    assert rep["blocked"] and "present" not in {e["verdict"] for e in rep["ranking"]}
