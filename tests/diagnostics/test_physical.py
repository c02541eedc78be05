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
