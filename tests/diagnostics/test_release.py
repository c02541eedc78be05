"""A declared socket's releases read from the data (``diagnostics.release``), the effects' depth columns
against finite differences of the declared depth, and the socket's anchors moved with the tip
(``contact_model.anchor_shift``) against finite differences of the socket's wrench."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from kinadapt_nn.diagnostics import release, signals, stream
from kinadapt_nn.diagnostics.readers import UserLog
from kinadapt_nn.diagnostics.setup import SetupCfg
from kinadapt_nn.effects import contact_model
from kinadapt_nn.effects.builtin import encoder_offset, tool_tilt

SOCKET = {"geometry": "socket", "entry_w_m": [0.0, 0.0, 0.0], "axis_w": [0.0, 0.0, -1.0],
          "stiffness_lat_N_per_m": 2000.0, "stiffness_rot_Nm_per_rad": 5.0}


def test_a_step_of_the_force_is_a_release_and_a_ramp_is_not():
    """``_drops``: a 5 N step from one sample to the next on a drifting, noisy force is found at the
    last sample before it; the same 5 N lost over 50 ms (a ramp) and a 5 N one-sample spike are not."""
    rng = np.random.default_rng(3)
    n = 3000
    f = np.zeros((n, 3))
    f[:, 0] = 0.002 * np.arange(n) * 1e-1  # a drift of 0.2 N/s at 1 kHz
    f[200:1000, 1] = 5.0  # released at once after sample 999
    f[1500:2000, 2] = 5.0
    f[2000:2050, 2] = np.linspace(5.0, 0.0, 50)  # let go over 50 ms
    f[2500, 1] = 5.0  # a spike
    f += rng.normal(0.0, 0.01, f.shape)
    k, size = release._drops(f, 1.0)
    # 199 and 1499: the steps into contact are steps as well (``find`` takes the last one of an engagement)
    assert list(k) == [199, 999, 1499], k
    np.testing.assert_allclose(size, 5.0, atol=0.05)


def _socket_log(shift_m: float, n: int = 4000, dt: float = 1e-3):
    """A declared tip that descends 6 mm into a socket and rises out at 20 mm/s (no rotation), and the
    force a socket would show were the true tip ``shift_m`` deeper along the axis than the declared one:
    a lateral spring force while the true tip is engaged (from depth 0 until back 1 mm above)."""
    t = np.arange(n) * dt
    depth = 0.006 - np.abs(t - t[n // 2]) * 0.02  # declared tip depth [m], peak at the middle
    tip_s = np.array([0.0, 0.0, 0.1])
    p_ws = np.zeros((n, 3))
    p_ws[:, 2] = -depth - tip_s[2]  # the sensor above the tip; the axis is -z
    p_ws[:, 0] = 0.001 * np.sin(t)  # a slow lateral motion
    R_ws = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
    true_depth = depth + shift_m
    gate = contact_model._engaged(true_depth)
    wrench = np.zeros((n, 6))
    wrench[gate, 0] = 4.0
    setup = SetupCfg.model_validate({"tool": {"tip_sensor_m": tip_s.tolist(), "mass_kg": 0.0},
                                     "contact": SOCKET})
    sock = contact_model.nominal_wrench(setup, R_ws, p_ws, t)
    s = SimpleNamespace(setup=setup, R_ws=R_ws, p_ws=p_ws, t=t, n=n, wrench=wrench, w_nom=sock, static=False,
                        has_time=True, contact=gate.copy())
    return s, depth, gate


def test_a_release_measures_the_declared_tips_depth():
    """``find``: where the data's force lets go, the declared tip sits ``shift`` above where the
    socket releases (-RELEASE_M): the depth read there is -RELEASE_M - shift within its sd (one sample's
    travel at 20 mm/s = 0.02 mm; ``SD_SAMPLES`` of it), and the residual row is +shift."""
    for shift in (0.002, -0.0015, 0.0):
        s, depth, gate = _socket_log(shift)
        rel = release.find(s, 0.01)
        assert rel is not None and len(rel.idx) == 1, shift
        assert rel.idx[0] == np.flatnonzero(gate)[-1]
        np.testing.assert_allclose(rel.depth_m, -contact_model.RELEASE_M - shift, atol=rel.sd_m[0])
        np.testing.assert_allclose(rel.residual_m, shift, atol=rel.sd_m[0])
        assert 0.02e-3 * release.SD_SAMPLES * 0.9 < rel.sd_m[0] < 0.02e-3 * release.SD_SAMPLES * 1.1


def test_a_release_inside_an_excluded_window_is_no_row():
    """``[analysis] exclude_s`` leaves a release out with the rest of its window: the same log with a
    window over the release (times from the first sample) finds none; a window elsewhere keeps it."""
    s, _, gate = _socket_log(0.001)
    t_rel = s.t[np.flatnonzero(gate)[-1]] - s.t[0]
    for window, kept in (((t_rel - 0.01, t_rel + 0.01), False), ((0.0, 0.1), True)):
        an = s.setup.analysis.model_copy(update={"exclude_s": (window,)})
        sx = SimpleNamespace(**{**vars(s), "setup": s.setup.model_copy(update={"analysis": an})})
        rel = release.find(sx, 0.01)
        assert (rel is not None) == kept, window


def test_no_release_without_a_declared_socket_or_a_step():
    s, _, _ = _socket_log(0.001)
    assert release.find(SimpleNamespace(**{**vars(s), "wrench": np.zeros_like(s.wrench)}), 0.01) is None
    bare = SetupCfg.model_validate({"tool": {"tip_sensor_m": [0.0, 0.0, 0.1], "mass_kg": 0.0}})
    assert release.find(SimpleNamespace(**{**vars(s), "setup": bare}), 0.01) is None


def _arm_log(n: int = 1500):
    rng = np.random.default_rng(5)
    t = np.arange(n) * 1e-3
    q0 = np.array([0.1, -0.4, 0.2, -2.0, 0.3, 1.8, 0.6])
    q = q0 + rng.uniform(0.1, 0.3, 7) * np.sin(2 * np.pi * rng.uniform(0.3, 1.2, 7) * t[:, None])
    setup = SetupCfg.model_validate({"tool": {"mass_kg": 0.5, "com_sensor_m": [0.0, 0.0, 0.05],
                                              "tip_sensor_m": [0.003, -0.002, 0.1]},
                                     "sensor": {"mount_known": True}, "contact": SOCKET})
    log = UserLog(t, q, None, np.zeros((n, 6)), "synthetic")
    return stream.slice_signals(signals.from_log(log, setup), 0, n), setup


def _declared_depth(s, q):
    kin = s.arm.series(q, s.qdot, s.clock)
    tip = np.asarray(s.setup.tool.tip_sensor_m)
    return (kin.p_ws + kin.R_ws @ tip - np.asarray(s.setup.contact.entry_w_m)) @ contact_model.socket_axis(s.setup.contact)


def test_the_encoder_offsets_depth_columns_are_the_depths_derivative():
    """``encoder_offset.depth`` equals central differences of the declared tip's depth (MuJoCo's
    kinematics rerun at ``q +- h e_j``), every joint but the one that turns about the sensor's z axis
    (zero, as its wrench column): to 1e-6 m/rad (the differences' truncation, h = 1e-5 rad, ~1e-10)."""
    s, _ = _arm_log()
    idx = np.array([0, 400, 1100, 1499])
    D = encoder_offset.depth(s, idx)
    zj = encoder_offset.sensor_z_joint(s)
    h = 1e-5
    for j in range(7):
        dq = np.zeros(7)
        dq[j] = h
        F = (_declared_depth(s, s.q + dq) - _declared_depth(s, s.q - dq))[idx] / (2 * h)
        np.testing.assert_allclose(D[:, j], 0.0 if j == zj else F, atol=1e-6, err_msg=f"joint {j + 1}")
    assert np.abs(D).max() > 0.1  # the columns are not all zero: the check checks something


def test_the_tilts_and_the_tips_depth_columns_are_the_depths_derivative():
    """``tool_tilt.depth`` and the tip nuisance's ``release.tip_depth``: the depth's change when the
    declared tip moves by ``delta x p`` and along each sensor axis (the declared depth recomputed with
    the moved tip), to 1e-9 m."""
    s, setup = _arm_log()
    idx = np.array([3, 700, 1200])
    tip = np.asarray(setup.tool.tip_sensor_m)
    h = 1e-6

    def depth_with(tip_new):  # the declared depth with the tip at tip_new (sensor frame)
        return (s.p_ws + s.R_ws @ tip_new - np.asarray(setup.contact.entry_w_m)) @ contact_model.socket_axis(setup.contact)

    T = tool_tilt.depth(s, idx)
    P = release.tip_depth(s, idx)
    for j in range(2):
        e = np.eye(3)[j]
        F = (depth_with(tip + h * np.cross(e, tip)) - depth_with(tip - h * np.cross(e, tip)))[idx] / (2 * h)
        np.testing.assert_allclose(T[:, j], F, atol=1e-9)
    for j in range(3):
        F = (depth_with(tip + h * np.eye(3)[j]) - depth_with(tip - h * np.eye(3)[j]))[idx] / (2 * h)
        np.testing.assert_allclose(P[:, j], F, atol=1e-9)


def test_the_anchors_move_with_the_tip_as_the_socket_wrench_does():
    """``contact_model.anchor_shift``: a tip moved along the axis crosses the entrance at another time, so
    the anchored pose moves. Against finite differences of the socket's wrench with the tip moved by
    +-h along the axis, where h moves the crossing by tens of samples (so the anchor's sample moves, as
    it does in the data): on the engaged samples away from the gate's own flips, equal to 2 % of the
    largest entry (the anchor's sample is quantised to 1 of ~40 samples, and the pose's rates are
    central differences)."""
    n, dt = 4000, 1e-3
    t = np.arange(n) * dt
    depth = 0.006 - np.abs(t - t[n // 2]) * 0.02
    tip_s = np.array([0.0, 0.0, 0.1])
    p_ws = np.zeros((n, 3))
    p_ws[:, 2] = -depth - tip_s[2]
    p_ws[:, 0] = 0.01 * np.sin(3.0 * t)  # lateral motion while entering: the anchor's position matters
    ang = 0.05 * np.sin(2.0 * t)  # the tool turns about x while entering: the anchor's orientation matters
    R_ws = np.stack([np.eye(3)] * n)
    R_ws[:, 1, 1], R_ws[:, 1, 2], R_ws[:, 2, 1], R_ws[:, 2, 2] = np.cos(ang), -np.sin(ang), np.sin(ang), np.cos(ang)
    setup = SetupCfg.model_validate({"tool": {"tip_sensor_m": tip_s.tolist(), "mass_kg": 0.0}, "contact": SOCKET})
    n_ax = contact_model.socket_axis(setup.contact)
    dtip_w = np.broadcast_to(n_ax[None, :, None], (n, 3, 1))  # the tip moved 1 m along the axis (per unit)
    A = contact_model.anchor_shift(setup, R_ws, p_ws, t, dtip_w)[:, :, 0]
    h = 0.0008  # 0.8 mm: the crossing moves by 40 samples at 20 mm/s
    w = [contact_model.nominal_wrench(setup, R_ws, p_ws + sg * h * n_ax, t) for sg in (1.0, -1.0)]
    # the part of the difference that the anchors make: the spring's wrench at fixed anchors does not
    # change with a tip moved along the axis (the lateral spring sees only lateral motion)
    F = (w[0] - w[1]) / (2 * h)
    gate = contact_model.socket_terms(setup.contact, R_ws, p_ws, tip_s).gate
    g_up = contact_model.socket_terms(setup.contact, R_ws, p_ws + h * n_ax, tip_s).gate
    g_dn = contact_model.socket_terms(setup.contact, R_ws, p_ws - h * n_ax, tip_s).gate
    inner = gate & g_up & g_dn
    assert inner.sum() > 300
    np.testing.assert_allclose(A[inner], F[inner], atol=0.02 * np.abs(F[inner]).max())
    assert np.abs(A[inner]).max() > 1.0  # N per m of tip: the check checks something


def test_the_summary_names_the_releases_it_fitted():
    """The summary says which releases became rows and how far the declared socket's own release is
    from them (``summary._accounts_text`` over the report's ``contact.releases``); nothing without."""
    from kinadapt_nn.diagnostics import summary

    s, _, _ = _socket_log(0.002)
    rel = release.find(s, 0.01)
    text = " ".join(summary._accounts_text({"contact": {"releases": rel.to_json()}}))
    assert "releases the data show (1, at " in text and "rows of the fit" in text
    late = rel.t_declared_s[0] - rel.t_s[0]
    assert late < 0 and f"{late:+.2f} s from them" in text  # the true tip 2 mm deeper leaves later
    assert summary._accounts_text({"contact": {"releases": None}}) == []


def test_the_encoder_offsets_exact_change_has_its_columns_as_derivative():
    """``encoder_offset.exact`` (the declared model at ``q + p`` less at ``q``, for the exact re-estimate
    and the choice between tied joints, ``diagnostics.nonlinear``): its central differences at p = 0
    are the effect's first-order columns (1e-6 of their largest entry: the differences' truncation at
    h = 1e-6 rad), and at 1 deg it differs from the columns' prediction by a second-order amount
    (between 1e-4 and 3e-2 of the change)."""
    from kinadapt_nn.effects.builtin import BUILTINS

    s, _ = _arm_log()
    eff = BUILTINS["encoder_offset"]
    C = np.asarray(eff.columns(s), dtype=float)  # (n, 6, dof)
    h = 1e-6
    for j in range(C.shape[2]):
        e = np.zeros(C.shape[2])
        e[j] = h
        num = (eff.exact(s, e) - eff.exact(s, -e)) / (2 * h)
        if not np.abs(C[:, :, j]).any():  # the sensor's z joint: no column (module docstring)
            continue
        np.testing.assert_allclose(num, C[:, :, j], atol=1e-6 * np.abs(C).max())
    p = np.zeros(C.shape[2])
    p[3] = np.deg2rad(1.0)
    change = eff.exact(s, p)
    second = np.abs(change - C @ p).max() / np.abs(change).max()
    assert 1e-4 < second < 3e-2, second
