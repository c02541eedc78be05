"""The episode's truth logs (``PegInHoleSim.truth_into`` + ``tip_depths`` after the loop) against
``PegInHoleSim.truth()`` step by step, through contact, for the bore and the socket contact models."""

from __future__ import annotations

import numpy as np
import pytest

from kinadapt_nn.config import load_config
from kinadapt_nn.known import BORE_AXIS_W
from kinadapt_nn.runs.build import make_controller
from kinadapt_nn.sim.adapter import PegInHoleSim


@pytest.mark.parametrize("over", [[], ["scene.contact_model=socket", "control.dither_rad_s=[0.05,0.05,0.05]"]])
def test_truth_logs_equal_truth_samples_through_contact(over):
    cfg = load_config(None, ["run.progress=false", *over])
    sim, ctrl = PegInHoleSim(cfg), make_controller(cfg)
    n = ctrl.layout.n
    inp = ctrl.input_row
    steps = 3500
    tips, rows = np.zeros((steps, 3)), np.zeros((steps, 3))
    want = []
    for k in range(steps):
        sim.sense_into(inp[:n], inp[n:2 * n], inp[2 * n:])
        ctrl.advance_input(sim.time_s)
        sim.apply(ctrl.state.q_ref[0], ctrl._o["qdot_ref"])
        want.append(sim.truth())
        sim.truth_into(tips[k], rows[k])
        sim.step()
    depth = sim.tip_depths(tips)
    for k, w in enumerate(want):  # the same numbers to the last bit
        assert tips[k].tolist() == w.tip_pos_w_m.tolist()
        assert depth[k] == w.tip_depth_m
        assert (bool(rows[k, 0]), bool(rows[k, 1]), rows[k, 2]) == (w.contact_face, w.contact_bore, w.contact_force_N)
    # the run reached contact (else the contact columns above were never tested)
    assert rows[:, 1].any() and rows[:, 2].max() > 1.0
    # the depth against an independent computation: the bore axis times (tip - true entrance)
    assert np.allclose(depth, (tips - sim.entry_w) @ BORE_AXIS_W, rtol=0, atol=1e-15)
