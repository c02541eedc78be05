"""The nominal model's analytic joint derivative (``physical.wrench_dq``, behind the built-in
``encoder_offset``) against central differences of the whole kinematics and tool model."""

from __future__ import annotations

import numpy as np
import pytest

from kinadapt_nn.diagnostics import signals, stream
from kinadapt_nn.diagnostics.readers import UserLog
from kinadapt_nn.diagnostics.setup import SetupCfg


@pytest.mark.parametrize("static", [False, True])
def test_wrench_dq_matches_central_differences(static):
    """``LogSignals.nominal_wrench_dq`` equals ``(w_nom(q + h e_j) - w_nom(q - h e_j)) / 2h`` with
    the joint rates and times held (``nominal_wrench``: MuJoCo's kinematics rerun, Savitzky-Golay
    accelerations), every joint, a moving log and a static one. Tolerance: 1e-5 of the largest
    column entry (measured 3e-7: the stored single-precision base point; the differences' own
    truncation and rounding are ~1e-10)."""
    rng = np.random.default_rng(4)
    n = 1500
    t = np.arange(n) * 1e-3
    q0 = np.array([0.1, -0.4, 0.2, -2.0, 0.3, 1.8, 0.6])
    amp, freq = rng.uniform(0.2, 0.6, 7), rng.uniform(0.3, 1.2, 7)
    q = q0 + amp * np.sin(2 * np.pi * freq * t[:, None])
    setup = SetupCfg.model_validate({"tool": {"mass_kg": 0.8, "com_sensor_m": [0.01, -0.02, 0.06],
                                              "inertia_com_kg_m2": [2e-3, 3e-3, 1e-3, 1e-4, 0.0, 2e-4]},
                                     "log": {"static": static}})
    log = UserLog(None if static else t, q, None, np.zeros((n, 6)), "synthetic", static=static)
    s = signals.from_log(log, setup)
    sub = stream.slice_signals(s, 0, n)  # double precision, as an effect sees it
    C = sub.nominal_wrench_dq()
    h = 1e-5
    for j in range(7):
        dq = np.zeros(7)
        dq[j] = h
        F = (sub.nominal_wrench(sub.q + dq) - sub.nominal_wrench(sub.q - dq)) / (2 * h)
        np.testing.assert_allclose(C[:, :, j], F, rtol=0, atol=1e-5 * np.abs(C).max(), err_msg=f"joint {j + 1}")


def test_signals_turned_into_another_mount_equal_the_kinematics_rerun():
    """``signals.in_mount`` (the stored series turned by ``R_fs_old^T R_fs_new``, the declared tool's
    wrench computed again) equals ``from_log`` run again with the sensor turned on the flange (MuJoCo's
    kinematics and the Savitzky-Golay accelerations from the encoders): every series to 1e-6 of its
    largest entry (the single-precision storage, relative 6e-8, twice), the encoders, time and
    wrench shared unchanged. A set-up that differs in more than the mount's orientation is refused
    (``can_turn``)."""
    rng = np.random.default_rng(7)
    n = 3000
    t = np.arange(n) * 1e-3
    q0 = np.array([0.1, -0.4, 0.2, -2.0, 0.3, 1.8, 0.6])
    q = q0 + rng.uniform(0.2, 0.6, 7) * np.sin(2 * np.pi * rng.uniform(0.3, 1.2, 7) * t[:, None])
    tool = {"mass_kg": 0.8, "com_sensor_m": [0.01, -0.02, 0.06], "inertia_com_kg_m2": [2e-3, 3e-3, 1e-3, 1e-4, 0.0, 2e-4]}
    setup = SetupCfg.model_validate({"tool": tool, "sensor": {"rpy_flange_deg": [0.0, 0.0, 0.0]}})
    turned = SetupCfg.model_validate({"tool": tool, "sensor": {"rpy_flange_deg": [4.0, -7.0, 33.0]}})
    log = UserLog(t, q, None, rng.standard_normal((n, 6)), "synthetic")
    s = signals.from_log(log, setup)
    assert signals.can_turn(s, turned)
    got, want = signals.in_mount(s, turned), signals.from_log(log, turned)
    for k in ("R_ws", "p_ws", "g_s", "a_s", "omega_s", "alpha_s", "w_nom", "qdot"):
        a, b = np.asarray(getattr(got, k), float), np.asarray(getattr(want, k), float)
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-6 * np.abs(b).max(), err_msg=k)
    assert got.wrench is s.wrench and got.q is s.q and got.setup == turned
    other = SetupCfg.model_validate({"tool": {**tool, "mass_kg": 0.9}, "sensor": {"rpy_flange_deg": [4.0, -7.0, 33.0]}})
    assert not signals.can_turn(s, other)
