"""The built-in ``encoder_offset`` gives no column to a joint that turns about the sensor's z axis:
its offset and a sensor rotation about z_s (``ft_frame_rotation``'s ``rot_z``) are one finding."""

from __future__ import annotations

import mujoco
import numpy as np

from kinadapt_nn.diagnostics import signals, stream
from kinadapt_nn.effects.builtin import encoder_offset as eo
from kinadapt_nn.effects.builtin.ft_frame_rotation import ft_frame_rotation
from kinadapt_nn.diagnostics.readers import UserLog
from kinadapt_nn.diagnostics.setup import SetupCfg

TOOL = {"mass_kg": 0.8, "com_sensor_m": [0.002, -0.001, 0.06], "inertia_com_kg_m2": [2e-3, 2e-3, 1e-3, 0.0, 0.0, 0.0]}


def _signals(sensor: dict, n: int = 1500, seed: int = 4):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 1e-3
    q0 = np.array([0.1, -0.4, 0.2, -2.0, 0.3, 1.8, 0.6])
    q = q0 + rng.uniform(0.2, 0.6, 7) * np.sin(2 * np.pi * rng.uniform(0.3, 1.2, 7) * t[:, None])
    setup = SetupCfg.model_validate({"tool": TOOL, "sensor": sensor})
    s = signals.from_log(UserLog(t, q, None, np.zeros((n, 6)), "synthetic"), setup)
    sub = stream.slice_signals(s, 0, n)
    # the log's wrench: the declared tool's (a sensor that reads the model), so rot_z's column r x z_s is the model's
    return stream.slice_signals(signals.from_log(UserLog(t, q, None, sub.w_nom.astype(float), "synthetic"), setup), 0, n)


def _last_axis_in_site_frame(setup: SetupCfg) -> np.ndarray:
    """An independent look: MuJoCo's world axis of the arm's last hinge in the flange site's frame,
    at a random configuration, then in the sensor frame (R_fs^T)."""
    from kinadapt_nn.diagnostics.physical import ArmModel

    arm = ArmModel(setup)
    d = mujoco.MjData(arm.model)
    d.qpos[:] = np.random.default_rng(1).uniform(-1, 1, arm.model.nq)
    mujoco.mj_kinematics(arm.model, d)
    j = int(arm._jnt[-1])
    return arm.R_fs.T @ d.site_xmat[arm.site].reshape(3, 3).T @ d.xaxis[j]


def test_the_flange_joint_is_found_and_its_column_is_the_sensor_turn_about_z():
    """On the Panda with the sensor on the flange axis: the last joint's axis is +-z_s (MuJoCo's
    own axis, independently), ``sensor_z_joint`` names it, its analytic column (``nominal_wrench_dq``)
    is the rotation column ``r x z_s`` up to the tool's small asymmetry (correlation > 0.98), and the
    effect's column for it is zero; the other joints keep theirs."""
    s = _signals({"rpy_flange_deg": [0.0, 0.0, 20.0]})
    axis = _last_axis_in_site_frame(s.setup)
    assert abs(abs(axis[2]) - 1.0) < 1e-9
    assert eo.sensor_z_joint(s) == 6
    full = s.nominal_wrench_dq()
    rz = ft_frame_rotation(s)[:, :, 2]
    a, b = full[:, :, 6].ravel(), rz.ravel()
    assert abs(a @ b) / np.sqrt((a @ a) * (b @ b)) > 0.98
    C = eo.encoder_offset.columns(s)
    assert not np.any(C[:, :, 6])
    np.testing.assert_allclose(C[:, :, :6], full[:, :, :6], rtol=0, atol=1e-12)
    assert np.abs(C[:, :, 5]).max() > 0.1 * np.abs(full).max()  # a wrist joint that is not the turn about z_s


def test_a_tilted_sensor_or_an_unknown_mount_keeps_every_column():
    """A sensor tilted on the flange (its z_s off the last axis by 10 deg): no joint turns about z_s.
    An unknown mount (``ft_frame_rotation`` not judged): the column stays."""
    tilted = _signals({"rpy_flange_deg": [10.0, 0.0, 0.0]})
    assert eo.sensor_z_joint(tilted) is None
    assert np.any(eo.encoder_offset.columns(tilted)[:, :, 6])
    unknown = _signals({"rpy_flange_deg": [0.0, 0.0, 0.0], "mount_known": False})
    assert np.any(eo.encoder_offset.columns(unknown)[:, :, 6])
