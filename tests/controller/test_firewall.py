"""The truth firewall: the controller's commands depend on the sensor stream only."""

from __future__ import annotations

import mujoco
import numpy as np
from numba.core.dispatcher import Dispatcher

from kinadapt_nn.config import load_config
from kinadapt_nn.controller.controller import Controller
from kinadapt_nn.runs.build import make_features
from kinadapt_nn.known import KnownCfg
from kinadapt_nn.sim.adapter import PegInHoleSim


def _record_stream(overrides: list[str], n_steps: int = 1500):
    """Run the closed loop and record exactly what the controller was given."""
    cfg = load_config(None, overrides)
    sim = PegInHoleSim(cfg)
    feats, theta0 = make_features(cfg)
    ctrl = Controller(KnownCfg.of(cfg), feats, theta0)
    stream, cmds = [], []
    obs = sim.sense()
    for _ in range(n_steps):
        sample = (sim.time_s, obs.q_rad.copy(), obs.qdot_rad_s.copy(), obs.wrench_raw_f.copy())
        cmd = ctrl.step(*sample)
        stream.append(sample)
        cmds.append(np.concatenate([cmd.q_ref_rad, cmd.qdot_ref_rad_s]))
        sim.apply(cmd.q_ref_rad, cmd.qdot_ref_rad_s)
        sim.step()
        obs = sim.sense()
    return cfg, theta0, stream, np.array(cmds)


# hidden truth that differs: tool geometry, grasp tilt, mass, friction, contact softness, start
_OTHER_TRUTH = [
    "tool.offset_f_m=[-0.004, 0.001, 0.110]",
    "tool.tilt_deg=[1.0, -0.5]",
    "tool.mass_kg=0.35",
    "tool.side_m=0.019",
    "scene.friction=0.8",
    "scene.contact_timeconst_s=0.005",
    "start.lateral_w_m=[-0.0005, 0.0004]",
    "start.tilt_deg=[0.5, 1.0]",
    # and every hidden effect of the library (kinadapt_nn.sim.effects)
    *[f"effects.{n}.enabled=true" for n in ("tool_gravity", "ft_bias_drift", "ft_frame_rotation", "tool_tilt",
                                            "contact_stiffness", "contact_friction_couple", "grasp_compliance",
                                            "encoder_offset")],
]


def test_identical_streams_give_identical_commands_under_different_truth():
    """Replaying a recorded sensor stream into a controller built beside a different hidden truth
    gives bit-identical commands (the controller has no other input)."""
    cfg_a, theta0, stream, cmds_a = _record_stream(["run.progress=false"])
    cfg_b = load_config(None, _OTHER_TRUTH)
    sim_b = PegInHoleSim(cfg_b)  # a different world exists at the same time
    for _ in range(50):
        sim_b.step()
    feats_b, _ = make_features(cfg_b)
    ctrl_b = Controller(KnownCfg.of(cfg_b), feats_b, theta0)  # same declared theta0
    cmds_b = np.array([np.concatenate(ctrl_b.step(*sample)) for sample in stream])
    np.testing.assert_array_equal(cmds_a, cmds_b)
    # and the stream really did contain contact (otherwise the test would be weak)
    assert max(np.linalg.norm(s[3][:3] - stream[0][3][:3]) for s in stream) > 0.5


def test_different_streams_give_different_commands():
    """Control check for the test above: a different sensor stream changes the commands."""
    _, theta0, stream, cmds_a = _record_stream(["run.progress=false"], n_steps=800)
    cfg = load_config(None, [])
    feats, _ = make_features(cfg)
    ctrl = Controller(KnownCfg.of(cfg), feats, theta0)
    bump = np.array([0.0, 0.0, 0.5, 0.0, 0.0, 0.0])  # after the tare, so it is not tared away
    perturbed = [(t, q, qd, w + bump * (t > 0.4)) for (t, q, qd, w) in stream]
    cmds_b = np.array([np.concatenate(ctrl.step(*s)) for s in perturbed])
    assert np.abs(cmds_a - cmds_b).max() > 1e-6


def _walk(obj, seen, depth=0):
    if id(obj) in seen or depth > 6 or isinstance(obj, Dispatcher):  # a compiled law step is code, not world
        return
    seen.add(id(obj))
    yield obj
    children = []
    if isinstance(obj, dict):
        children = list(obj.values())
    elif isinstance(obj, (list, tuple, set)):
        children = list(obj)
    elif hasattr(obj, "__dict__") and not isinstance(obj, type):
        children = list(vars(obj).values())
    for c in children:
        yield from _walk(c, seen, depth + 1)


def test_controller_holds_no_reference_to_the_world():
    """The controller's object graph holds no simulator and no MuJoCo model with the tool or block."""
    cfg = load_config(None, [])
    feats, theta0 = make_features(cfg)
    ctrl = Controller(KnownCfg.of(cfg), feats, theta0)
    for obj in _walk(ctrl, set()):
        assert not isinstance(obj, PegInHoleSim)
        if isinstance(obj, mujoco.MjModel):
            names = [mujoco.mj_id2name(obj, mujoco.mjtObj.mjOBJ_BODY, i) for i in range(obj.nbody)]
            assert "tool" not in names and "bore_block" not in names, names
            assert obj.nsensor == 0
