"""The episode loop's truth logs (``SceneBatch.truth_into`` + ``tip_depths`` after the loop) against
``PegInHoleSim.truth()`` step by step, through contact, for the bore and the socket contact models."""

from __future__ import annotations

import numpy as np
import pytest

from kinadapt_nn.config import load_config
from kinadapt_nn.known import BORE_AXIS_W
from kinadapt_nn.runs.build import make_controller
from kinadapt_nn.sim.adapter import PegInHoleSim
from kinadapt_nn.sim.scenes import SceneBatch, StepTruth


@pytest.mark.parametrize("over", [[], ["scene.contact_model=socket", "control.dither_rad_s=[0.05,0.05,0.05]"]])
def test_truth_logs_equal_truth_samples_through_contact(over):
    cfg = load_config(None, ["run.progress=false", *over])
    world, ctrl = SceneBatch([cfg]), make_controller(cfg)  # one episode: the scene steps its own simulator
    sim = world.sims[0]
    n = ctrl.layout.n
    inp, on = ctrl.input_row, np.ones(1, bool)
    steps = 3500
    tips, rows = np.zeros((steps, 3)), np.zeros((steps, 3))
    want = []
    for k in range(steps):
        world.sense_into(sim.time_s, inp[None], on)
        cmd = ctrl.step(sim.time_s, inp[:n].copy(), inp[n:2 * n].copy(), inp[2 * n:].copy())
        world.apply(cmd.q_ref_rad[None], cmd.qdot_ref_rad_s[None], on)
        want.append(sim.truth())
        world.truth_into(slice(None), StepTruth(tips[k:k + 1], rows[k:k + 1]))
        world.step(sim.time_s, on, True)
    depth = sim.tip_depths(tips)
    for k, w in enumerate(want):  # the same numbers to the last bit
        assert tips[k].tolist() == w.tip_pos_w_m.tolist()
        assert depth[k] == w.tip_depth_m
        assert (bool(rows[k, 0]), bool(rows[k, 1]), rows[k, 2]) == (w.contact_face, w.contact_bore, w.contact_force_N)
    # the run reached contact (else the contact columns above were never tested)
    assert rows[:, 1].any() and rows[:, 2].max() > 1.0
    # the depth against an independent computation: the bore axis times (tip - true entrance)
    assert np.allclose(depth, (tips - sim.entry_w) @ BORE_AXIS_W, rtol=0, atol=1e-15)


def test_contact_sensor_truth_equals_the_contact_array_scan(monkeypatch):
    """The truth's contacts come from MuJoCo's contact sensor (``scene.TRUTH_CONTACT_SENSOR``):
    at every step of an insertion, its (normal force, position) rows equal ``mj_contactForce`` on
    the peg <-> block entries of the contact array, to the last bit and in the same order; with the
    slot limit forced below the contact count, ``contacts_of`` takes the scan and gives the same."""
    from kinadapt_nn.sim import adapter

    cfg = load_config(None, ["run.progress=false"])
    sim, ctrl = PegInHoleSim(cfg), make_controller(cfg)
    adr = sim.ids.contact_adr
    seen, most = 0, 0
    results = []
    slots = adapter.TRUTH_CONTACT_SLOTS
    for _k in range(3500):
        o = sim.sense()
        cmd = ctrl.step(sim.time_s, o.q_rad, o.qdot_rad_s, o.wrench_raw_f)
        sim.apply(cmd.q_ref_rad, cmd.qdot_ref_rad_s)
        scan = sim._contact_scan(sim.data)
        found = int(sim.data.sensordata[adr])
        assert found == len(scan)
        rows = sim.data.sensordata[adr:adr + 7 * found].reshape(found, 7)
        assert [(abs(r[1]), *r[4:7]) for r in rows.tolist()] == [(abs(f), *p) for f, *p in scan]
        if found:
            seen += 1
            most = max(most, found)
            results.append((sim.data.sensordata.copy(), sim.contacts_of(sim.data.sensordata, sim._own_data)))
            monkeypatch.setattr(adapter, "TRUTH_CONTACT_SLOTS", 0)  # the scan, from the same data
            assert sim.contacts_of(sim.data.sensordata, sim._own_data) == results[-1][1]
            monkeypatch.setattr(adapter, "TRUTH_CONTACT_SLOTS", slots)
        sim.step()
    assert seen > 500 and most >= 2  # in contact, with several contacts at once
    assert any(r[1][2] > 1.0 for r in results)
