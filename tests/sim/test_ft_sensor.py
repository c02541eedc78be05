"""The simulated wrist F/T sensor reads the wrench that produced the motion the encoders show
(``sim.ft_sensor``; issue 49).

Two independent checks:

* a second implementation: MuJoCo's own recursive Newton-Euler (``mj_rnePostConstraint`` and
  ``mj_sensorAcc``) on a copy of the step's start state with ``qacc`` set to the realised
  acceleration -- equal to rounding (the kernel adds a linear term to MuJoCo's reading; float64
  sums over ~10 bodies and 9 dofs: 1e-12 N is ~1000x the rounding seen, 1e-14);
* an independent Newton-Euler computation of the rigid tool from a logged trajectory
  (``benchmarks/sim_sensor_acceleration.py``: the config's tool, finite differences of the logged
  velocities, the bare arm's flange kinematics, the logged contact forces) in free space under
  fast reorientation and pressed and slid on the block's face. The finite difference is exactly
  the integrator's velocity update, so the only differences are float64 rounding through the
  kinematic chain (seen: <= 1e-13 N with contact forces up to ~200 N); 1e-9 N and 1e-9 N m
  leave four orders of margin and still fail by nine orders on MuJoCo's own sensor values, whose
  inertial part is 0.9-3.4x the motion's.
"""

from __future__ import annotations

import types
from pathlib import Path

import mujoco
import numpy as np
import pytest

from kinadapt_nn.config import load_config
from kinadapt_nn.sim.adapter import PegInHoleSim
from kinadapt_nn.sim.ft_sensor import SOURCE_FIELDS, RealisedSensor, sensor_chain
from kinadapt_nn.sim.scene import FORCE_SENSOR, TORQUE_SENSOR
from tests.diagnostics.example_scripts import load_script

BENCH = Path(__file__).resolve().parents[2] / "benchmarks" / "sim_sensor_acceleration.py"


@pytest.mark.parametrize("effects", [[], ["effects.grasp_compliance.enabled=true", "effects.tool_gravity.enabled=true"]])
def test_reading_equals_mujocos_newton_euler_with_the_realised_acceleration(effects):
    """Wrist sines without velocity feed-forward (the servos' implicit damping at work); with a
    compliant grasp the sensor's subtree has its own hinges, whose realised accelerations count too."""
    sim = PegInHoleSim(load_config(None, ["start.tip_height_m=0.03", *effects]))
    m, d = sim.model, sim.data
    ch = sensor_chain(m, FORCE_SENSOR, TORQUE_SENSOR)
    rs = RealisedSensor(types.SimpleNamespace(**{f: getattr(d, f)[None] for f in SOURCE_FIELDS}), ch, m.opt.timestep)
    pre = mujoco.MjData(m)
    worst, moved = 0.0, 0.0
    for k in range(400):
        t = k * m.opt.timestep
        d.ctrl[:7] = sim.q_start + np.array([0, 0, 0, 0, 0.1, 0.3, 0.4]) * np.sin(2 * np.pi * np.array([0, 0, 0, 0, 3, 4, 5]) * t)
        mujoco.mj_copyData(pre, m, d)
        rs.before_step()
        mujoco.mj_step(m, d)
        rs.after_step(np.zeros(1, np.int64))
        mujoco.mj_forward(m, pre)
        pre.qacc[:] = (d.qvel - pre.qvel) / m.opt.timestep
        mujoco.mj_rnePostConstraint(m, pre)
        mujoco.mj_sensorAcc(m, pre)
        ref = np.r_[pre.sensordata[ch.force_adr:ch.force_adr + 3], pre.sensordata[ch.torque_adr:ch.torque_adr + 3]]
        own = np.r_[d.sensordata[ch.force_adr:ch.force_adr + 3], d.sensordata[ch.torque_adr:ch.torque_adr + 3]]
        worst = max(worst, float(np.abs(rs.wrench[0] - ref).max()))
        moved = max(moved, float(np.abs(own - ref).max()))
    assert worst < 1e-12, worst
    assert moved > 0.05, moved  # MuJoCo's own values differ: the check can fail


@pytest.fixture(scope="module")
def bench():
    return load_script(BENCH, "sim_sensor_acceleration")


@pytest.fixture(scope="module")
def driven(bench):
    log, cfg = bench.record(2500)
    return log, bench.newton_euler(log, cfg.tool)


def test_free_space_fast_reorientation_matches_newton_euler(bench, driven):
    log, exp = driven
    rows = (np.arange(len(log.q) - 1) < 1000) & ~log.in_contact[:-1]
    assert rows.sum() > 900
    assert np.abs(exp.inertial[rows, :3]).max() > 0.5  # a real inertial load [N]
    diff = np.abs(log.wrench[:-1][rows] - exp.wrench[rows])
    assert diff[:, :3].max() < 1e-9 and diff[:, 3:].max() < 1e-9, diff.max(axis=0)
    np.testing.assert_allclose(bench.factors(log.wrench, exp, rows), 1.0, atol=1e-6)
    # MuJoCo's own values are not the motion's (what the package's sensor replaces)
    assert np.abs(bench.factors(log.mujoco_own, exp, rows) - 1.0).max() > 0.5


def test_in_contact_matches_newton_euler_with_the_logged_contact_forces(bench, driven):
    log, exp = driven
    rows = log.in_contact[:-1]
    assert rows.sum() > 500
    assert np.linalg.norm(log.contact_f_w[:-1][rows], axis=1).max() > 5.0  # pressed [N]
    diff = np.abs(log.wrench[:-1][rows] - exp.wrench[rows])
    assert diff[:, :3].max() < 1e-9 and diff[:, 3:].max() < 1e-9, diff.max(axis=0)
