"""The monitor's ``encoder_offset`` shape (``shapes.columns``): its columns against central differences of the
monitor's own nominal model (``kernel.predict``) on the arm's kinematics, the joint axes the kernel keeps in
its ring rows (``kernel.G_AX``), and the one-joint fit."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from kinadapt_nn.config import MonitorCfg, load_config
from kinadapt_nn.diagnostics.ownrun import setup_of_run
from kinadapt_nn.diagnostics.physical import ArmModel
from kinadapt_nn.monitor import kernel as K
from kinadapt_nn.monitor import shapes
from kinadapt_nn.monitor.monitor import Monitor, consts

REPO = Path(__file__).resolve().parents[2]
DT = 1e-3
Q0 = np.array([0.3, -0.5, 0.4, -2.0, 0.6, 1.9, 0.7])  # [rad] a pose with no joint axis along gravity or z_s


@pytest.fixture(scope="module")
def rig():
    """The package's set-up (the nominal peg as the declared tool), its arm and the monitor's constants."""
    setup = setup_of_run(load_config(REPO / "online" / "monitor.toml", ["run.progress=false"]))
    c = consts(setup, MonitorCfg(), DT)
    tool = shapes.Tool(float(c[K.C_M]), c[K.C_MC:K.C_MC + 3].copy(), c[K.C_IO:K.C_IO + 9].reshape(3, 3).copy())
    assert abs(tool.m) > 0.05 and np.linalg.norm(tool.mc) > 1e-3 and np.linalg.norm(tool.I_O) > 1e-6  # a real tool
    return setup, ArmModel(setup), c, tool


def _kernel_rows(c, arm: ArmModel, qs: np.ndarray, qds: np.ndarray) -> np.ndarray:
    """Ring rows the kernel pushes (``loop_sample``: the flange pose, the arm Jacobian [Jp; Jr], a zero reading)
    for samples at ``qs`` (N, 7) with rates ``qds``: the N - 1 judged ones."""
    st, ring = K.new_state(qs.shape[1])
    st[K.S_MODE] = K.MODE_WATCH  # past the calibration (noise sd 1, offset 0)
    st[K.S_SD:K.S_SD + 6] = 1.0
    c = c.copy()
    c[K.C_H] = c[K.C_HROT] = np.inf  # no alarm
    R, x, Jp, Jr = arm._frames(qs)  # noqa: SLF001
    for k in range(len(qs)):
        inp = np.concatenate([qs[k], qds[k], np.zeros(6)])
        K.loop_sample(k * DT, inp, R[k], x[k], np.concatenate([Jp[k], Jr[k]]), c, st, ring)
    return K.ring_rows(st, ring, -1.0)


def _predict(c, R, om, al, ga) -> np.ndarray:
    out = np.empty(6)
    K.predict(c, K.new_state()[0], 0.0, R, om, al, ga, out)
    return out


def test_the_kernel_keeps_each_joints_axis_in_the_sensor_frame(rig):
    """The ring's axes are ``R_ws^T z_j`` of the judged sample (not the next one's): unit vectors, and the
    last joint's is the flange's z axis (the sensor sits at O with the flange's axes in a package run)."""
    _, arm, c, _ = rig
    qs = np.stack([Q0, Q0 + 0.05])  # two samples far apart: a mix-up of the two would show
    rows = _kernel_rows(c, arm, qs, np.zeros_like(qs))
    R, _, _, Jr = arm._frames(qs)  # noqa: SLF001
    want = np.einsum("ji,jk->ki", R[0], Jr[0])  # (7, 3): z_j in s of the first sample
    assert np.allclose(shapes.joint_axes(rows)[0], want, atol=1e-12)
    assert np.allclose(np.linalg.norm(want, axis=1), 1.0)
    assert np.allclose(want[-1], [0.0, 0.0, 1.0], atol=1e-9)


@pytest.mark.parametrize("joint", range(6))
def test_columns_at_rest_are_the_models_derivative_in_the_joint(rig, joint):
    """At rest the column is the derivative of the monitor's own model (``kernel.predict``: gravity only)
    in the joint's angle, the kinematics from the arm at ``q +- h e_j``: central differences, h = 1e-5 rad,
    agree to 1e-7 of the tool's weight (their error, |d3 w / dq3| h^2 / 6 ~ |w| 2e-11). The base joint turns
    about gravity: its column is zero at rest, as the differences are."""
    _, arm, c, tool = rig
    rows = _kernel_rows(c, arm, np.stack([Q0, Q0]), np.zeros((2, 7)))
    col = shapes.columns("encoder_offset", rows, tool, 0.0, joint)[0, :, 0]
    h = 1e-5
    w = []
    for s in (+1.0, -1.0):
        q = Q0.copy()
        q[joint] += s * h
        R = arm._frames(q[None])[0][0]  # noqa: SLF001
        w.append(_predict(c, R, np.zeros(3), np.zeros(3), R.T @ arm.g_w))
    fd = (w[0] - w[1]) / (2 * h)
    weight = tool.m * np.linalg.norm(arm.g_w)
    assert np.allclose(col, fd, atol=1e-7 * weight)
    assert np.linalg.norm(col) > 0.05 * weight if joint > 0 else np.linalg.norm(col) < 1e-9 * weight


def _turn(v: np.ndarray, a: np.ndarray, ang: float) -> np.ndarray:
    """v seen from a frame turned by ``ang`` about the unit axis ``a`` (Rodrigues, the frame's inverse)."""
    c, s = np.cos(ang), np.sin(ang)
    return v * c - s * np.cross(a, v) + (1 - c) * a * (a @ v)


@pytest.mark.parametrize("joint", [0, 3, 5])
def test_columns_moving_turn_the_models_vectors(rig, joint):
    """Moving, the column is the model's change with g - a, omega and alpha seen from the sensor frame turned
    about the joint's axis (module docstring of ``shapes``): central differences of ``kernel.predict`` with
    the three vectors turned by +-h about the ring's axis agree to 1e-7 of the column's size; and the
    inertial part is not zero there (this fast a motion: 2 rad/s, 20 rad/s^2)."""
    _, arm, c, tool = rig
    qd = np.array([0.8, -1.2, 1.0, 0.9, -1.5, 2.0, 1.1])
    qs = np.stack([Q0, Q0 + qd * DT])
    qds = np.stack([qd, qd * 1.02])  # an acceleration
    rows = _kernel_rows(c, arm, qs, qds)
    col = shapes.columns("encoder_offset", rows, tool, 0.0, joint)[0, :, 0]
    R = rows[0, K.G_R:K.G_R + 9].reshape(3, 3)
    om, al, ga = rows[0, K.G_OM:K.G_OM + 3], rows[0, K.G_AL:K.G_AL + 3], rows[0, K.G_GA:K.G_GA + 3]
    a = shapes.joint_axes(rows)[0, joint]
    h = 1e-5
    w = [_predict(c, R, _turn(om, a, s * h), _turn(al, a, s * h), _turn(ga, a, s * h)) for s in (+1.0, -1.0)]
    fd = (w[0] - w[1]) / (2 * h)
    assert np.allclose(col, fd, atol=1e-7 * np.linalg.norm(col))
    still = _predict(c, R, np.zeros(3), np.zeros(3), _turn(ga, a, h)) - _predict(c, R, np.zeros(3), np.zeros(3),
                                                                                  _turn(ga, a, -h))
    assert np.linalg.norm(fd - still / (2 * h)) > 1e-4  # the turned omega and alpha count


def test_the_z_joint_and_rows_without_axes_have_no_column(rig):
    """The flange joint turns about z_s (``ft_frame_rotation``'s rot_z): it is left out, as the diagnosis leaves
    it out; ring rows without axes (``new_state()``) give the shape no joint, and ``best`` leaves it out."""
    _, arm, c, tool = rig
    rows = _kernel_rows(c, arm, np.stack([Q0, Q0 + 0.01, Q0 + 0.02]), np.zeros((3, 7)))
    assert shapes.encoder_joints(rows) == [0, 1, 2, 3, 4, 5]
    bare = rows[:, :K.NCOL]
    assert shapes.encoder_joints(bare) == []
    bare = bare.copy()
    bare[:, K.G_E:K.G_E + 6] = np.random.default_rng(1).standard_normal((len(bare), 6))
    _, fits = shapes.best(bare, np.ones(6), tool, 0.0, shapes=shapes.END_SHAPES)
    assert "encoder_offset" not in [f.shape for f in fits]


def test_an_offset_is_found_at_its_joint_and_size(rig):
    """A 2 deg offset of joint 3 on a slow sweep of every joint (the residual its column makes, plus noise):
    the one-joint fit picks joint 3 and its estimate is within 4 sd of 2 deg; named best among every shape of
    the end-of-run look."""
    _, arm, c, tool = rig
    n = 600
    t = np.linspace(0.0, 1.0, n)
    qs = Q0[None, :] + 0.6 * np.sin(2 * np.pi * np.outer(t, np.linspace(0.5, 1.2, 7)) + np.arange(7))
    rows = _kernel_rows(c, arm, qs, np.zeros_like(qs))  # still kinematics at each pose: gravity only
    sd = np.array([0.02, 0.02, 0.02, 0.002, 0.002, 0.002])
    rng = np.random.default_rng(5)
    rows[:, K.G_E:K.G_E + 6] = (shapes.columns("encoder_offset", rows, tool, 0.0, 2)[:, :, 0] * np.deg2rad(2.0)
                                + sd * rng.standard_normal((len(rows), 6)))
    f = shapes.fit("encoder_offset", rows, sd, tool, 0.0)
    assert f.joint == 2
    assert abs(np.rad2deg(f.p[0]) - 2.0) < 4 * np.rad2deg(np.sqrt(f.cov[0, 0]))
    best, _ = shapes.best(rows, sd, tool, 0.0, shapes=shapes.END_SHAPES)
    assert best.shape == "encoder_offset" and best.joint == 2
    text, est = shapes.describe(best, tool, "world")
    assert est["joint"] == 3 and "joint 3" in text


def test_follow_and_loop_keep_the_same_axes(rig):
    """``Monitor.sample`` with the axes (``--follow``) and ``Monitor.loop_step`` (a package run) fill the same
    ring columns from the same encoders."""
    setup, arm, c, tool = rig
    qs = Q0[None, :] + 0.01 * np.arange(5)[:, None]
    R, x, Jp, Jr = arm._frames(qs)  # noqa: SLF001
    a, b = Monitor(setup, MonitorCfg(), DT), Monitor(setup, MonitorCfg(), DT)
    for m in (a, b):
        m.st[K.S_MODE], m.st[K.S_SD:K.S_SD + 6] = K.MODE_WATCH, 1.0
    for k in range(5):
        a.sample(k * DT, R[k], x[k], np.zeros(3), np.zeros(3), np.zeros(6), Jr[k])
        b.loop_step(k * DT, np.concatenate([qs[k], np.zeros(7), np.zeros(6)]), R[k], x[k], np.concatenate([Jp[k], Jr[k]]))
    ra, rb = K.ring_rows(a.st, a.ring, -1.0), K.ring_rows(b.st, b.ring, -1.0)
    assert len(ra) == 4 and np.allclose(shapes.joint_axes(ra), shapes.joint_axes(rb), atol=1e-12)


def _wrist_rows(n: int, tool: shapes.Tool, axis_s: np.ndarray) -> np.ndarray:
    """Ring rows (n, NCOL + 3) of a slow turn (gravity turns by up to 40 deg in s; no acceleration) with one
    joint whose axis stays ``axis_s`` in s (a joint beyond the ones that move): R_ws, gravity in s, the
    declared tool's reading, a zero residual."""
    t = np.linspace(0.0, 1.0, n)
    ax, ay = np.deg2rad(40.0) * np.sin(2 * np.pi * t), np.deg2rad(40.0) * np.sin(np.pi * t)
    rows = np.zeros((n, K.NCOL + 3))
    for i in range(n):
        cx, sx, cy, sy = np.cos(ax[i]), np.sin(ax[i]), np.cos(ay[i]), np.sin(ay[i])
        R = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]]) @ np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
        g_s = R.T @ np.array([0.0, 0.0, -9.81])
        rows[i, K.G_R:K.G_R + 9] = R.ravel()
        rows[i, K.G_GA:K.G_GA + 3] = g_s
        rows[i, K.G_RM:K.G_RM + 3] = tool.m * g_s
        rows[i, K.G_RM + 3:K.G_RM + 6] = np.cross(tool.mc, g_s)
    rows[:, K.G_T] = 1.0 + t
    rows[:, K.G_AX:K.G_AX + 3] = axis_s
    rows[:, K.G_FREE] = 1.0
    return rows


SD6 = np.array([0.02, 0.02, 0.02, 0.002, 0.002, 0.002])  # [N, N m] the sensor's noise
AXIS = np.array([0.6, 0.8, 0.0])  # [-] the joint's axis in s (not z_s)


def test_the_end_look_ties_an_offset_a_turned_mount_cannot_be_told_from():
    """A tool with its centre of mass at O (no gravity moment): an offset of a joint whose axis stays fixed in s
    turns the weight in s exactly as the mount turned about that axis does (``m g_s x a`` both), so a 2 deg
    offset's residual is named ``ft_frame_rotation`` (the end look names a live shape) with ``encoder_offset``
    among its near-ties (nested: the turn about a fixed axis is one of the mount's turns)."""
    tool = shapes.Tool(1.0, np.zeros(3), np.zeros((3, 3)))
    rows = _wrist_rows(1500, tool, AXIS)
    rng = np.random.default_rng(11)
    rows[:, K.G_E:K.G_E + 6] = (shapes.columns("encoder_offset", rows, tool, 1.0, 0)[:, :, 0] * np.deg2rad(2.0)
                                + SD6 * rng.standard_normal((len(rows), 6)))
    best, fits, tied = shapes.end_look(rows, SD6, tool, 1.0)
    assert fits[0].shape == "encoder_offset"  # the least BIC: one parameter
    assert best.shape == "ft_frame_rotation" and "encoder_offset" in tied


def test_the_tools_gravity_moment_tells_a_turned_mount_from_an_offset():
    """The same turn of the mount with the tool's centre of mass 50 mm along z_s (0.1 kg): the mount turns the
    reading's moment too, ``(mc x g_s) x a``, while an offset turns gravity about the tool, ``mc x (g_s x a)``;
    the two differ by ``|mc| g`` per radian (0.86 noise sd at 2 deg here), so the offset does not tie the turn
    (what decides the frame rotation's seed 2 in the agreement benchmark, docs/monitor.md)."""
    tool = shapes.Tool(0.1, np.array([0.0, 0.0, 0.005]), np.zeros((3, 3)))
    rows = _wrist_rows(1500, tool, AXIS)
    rng = np.random.default_rng(12)
    rows[:, K.G_E:K.G_E + 6] = (shapes.columns("ft_frame_rotation", rows, tool, 1.0) @ (np.deg2rad(2.0) * AXIS)
                                + SD6 * rng.standard_normal((len(rows), 6)))
    best, fits, tied = shapes.end_look(rows, SD6, tool, 1.0)
    assert best.shape == "ft_frame_rotation" and "encoder_offset" not in tied
    enc = next(f for f in fits if f.shape == "encoder_offset")
    assert enc.bic - best.bic > 10.0


def test_an_offset_is_a_turned_mount_plus_a_turned_first_moment(rig):
    """At rest, on the declared tool's own reading: an offset ``delta`` about ``a`` is the mount turned by
    ``delta a`` (``ft_frame_rotation``: ``r x delta a``) plus the tool's first moment turned about ``a``
    (``tool_gravity``'s ``dmc = delta a x mc``): the Jacobi identity ``mc x (g x a) = (mc x g) x a + (a x mc)
    x g``, the forces alike. So with the tool's first moment free the two shapes differ only where ``a`` turns
    in s (``benchmarks/monitor_encoder_rivals.py``)."""
    _, arm, c, tool = rig
    qs = Q0[None, :] + 0.3 * np.sin(np.linspace(0.0, 3.0, 40))[:, None] * np.linspace(1.0, 0.4, 7)
    rows = _kernel_rows(c, arm, qs, np.zeros_like(qs))
    for i, r in enumerate(rows):  # the reading: the declared tool's wrench at that pose
        out = np.empty(6)
        K.predict(c, K.new_state()[0], 0.0, r[K.G_R:K.G_R + 9].reshape(3, 3), np.zeros(3), np.zeros(3),
                  r[K.G_GA:K.G_GA + 3], out)
        rows[i, K.G_RM:K.G_RM + 6] = out
    for j in (1, 2, 4):
        a = shapes.joint_axes(rows)[:, j]  # (n, 3)
        enc = shapes.columns("encoder_offset", rows, tool, 0.0, j)[:, :, 0]
        turn = np.einsum("nij,nj->ni", shapes.columns("ft_frame_rotation", rows, tool, 0.0), a)
        moment = np.einsum("nij,nj->ni", shapes.columns("tool_gravity", rows, tool, 0.0)[:, :, 1:], np.cross(a, tool.mc))
        assert np.linalg.norm(enc - turn) > 1e-4  # not the turn alone: the tool's gravity moment
        assert np.allclose(enc, turn + moment, atol=1e-12)


@pytest.mark.parametrize("seed", range(4))
def test_moving_the_column_leaves_out_the_accelerations_change(rig, seed):
    """Moving, the model's exact derivative in the joint's angle (the kernel's whole path -- kinematics, the
    twist's difference, ``kernel.predict`` -- at encoders ``q +- h e_j``, h = 1e-6 rad) also holds how the
    sensor's acceleration changes with the angle (centripetal, at constant rates here), which the column
    leaves out: relative to the column it is of order ``|qdot|^2 L / |g|`` (L ~ 1 m, the arm's reach), so at
    0.5 rad/s the two agree within twice that, 5 %."""
    _, arm, c, tool = rig
    rng = np.random.default_rng(seed)
    q0 = Q0 + 0.3 * rng.standard_normal(7)
    qd = rng.standard_normal(7)
    qd *= 0.5 / np.linalg.norm(qd)
    qs = np.stack([q0, q0 + qd * DT])
    qds = np.stack([qd, qd])
    rows = _kernel_rows(c, arm, qs, qds)
    bound = 2.0 * 0.5 ** 2 * 1.0 / 9.81
    for j in range(1, 6):
        h = 1e-6
        pred = []
        for s in (+1.0, -1.0):
            shifted = qs.copy()
            shifted[:, j] += s * h
            r = _kernel_rows(c, arm, shifted, qds)[0]
            pred.append(_predict(c, r[K.G_R:K.G_R + 9].reshape(3, 3), r[K.G_OM:K.G_OM + 3], r[K.G_AL:K.G_AL + 3],
                                 r[K.G_GA:K.G_GA + 3]))
        fd = (pred[0] - pred[1]) / (2 * h)
        col = shapes.columns("encoder_offset", rows, tool, 0.0, j)[0, :, 0]
        assert np.linalg.norm(col - fd) <= bound * np.linalg.norm(col), (j, np.linalg.norm(col - fd) / np.linalg.norm(col))
