"""``SceneBatch`` (the episode loop's world) against ``PegInHoleSim`` stepped alone: the same samples,
the same physics, the same per-step truth; MuJoCo warnings seen per episode."""

from __future__ import annotations

import numpy as np
import pytest

from kinadapt_nn.config import load_config
from kinadapt_nn.sim.adapter import PegInHoleSim
from kinadapt_nn.sim.scenes import SceneBatch, StepTruth

_CFGS = [
    ["start.lateral_w_m=[0.001, 0.0]", "effects.ft_bias_drift.enabled=true", "effects.ft_frame_rotation.enabled=true"],
    ["start.lateral_w_m=[-0.0008, 0.0005]", "scene.chamfer_m=0.0"],
]


def _down(sim: PegInHoleSim) -> np.ndarray:
    """(n,) joint direction that moves the true tip straight down by 1 m (at the start pose)."""
    import mujoco

    jp, jr = np.zeros((3, sim.model.nv)), np.zeros((3, sim.model.nv))
    mujoco.mj_jacSite(sim.model, sim.data, jp, jr, sim.ids.tip_site)
    J = np.vstack([jp, jr])[:, sim.ids.dof_adr]
    return np.linalg.pinv(J) @ np.array([0.0, 0.0, -1.0, 0.0, 0.0, 0.0])


def _servo_path(sim: PegInHoleSim, down: np.ndarray, k: int) -> np.ndarray:
    """A set-point that pushes the peg down onto the block at 50 mm/s (contact within ~0.4 s)."""
    return sim.q_start + down * 5e-5 * k


@pytest.mark.parametrize("nthread", [1, 2])
def test_a_batch_steps_each_scene_as_its_own_simulator_does(nthread):
    """Each episode of a batch (mujoco.batch; one episode alone: its own MjData) gives the samples
    (hidden sensor effects applied), the true tip and the contacts of a ``PegInHoleSim`` stepped
    alone with the same set-points, to the last bit."""
    cfgs = [load_config(None, c) for c in _CFGS]
    for group in ([cfgs[0]], cfgs):
        world = SceneBatch(group, nthread=nthread, persistent=True)
        alone = [PegInHoleSim(c) for c in group]
        B, n = len(group), world.n
        inp = np.zeros((B, 2 * n + 6))
        truth = StepTruth(np.zeros((B, 3)), np.zeros((B, 3)))
        active = np.ones(B, bool)
        touched = np.zeros(B, bool)
        downs = [_down(s) for s in alone]
        t = 0.0
        for k in range(600):
            world.sense_into(t, inp, active)
            truth.contact[:] = 0.0
            world.truth_into(slice(None), truth)
            for b, s in enumerate(alone):
                o, tr = s.sense(), s.truth()
                np.testing.assert_array_equal(inp[b], np.concatenate([o.q_rad, o.qdot_rad_s, o.wrench_raw_f]))
                np.testing.assert_array_equal(truth.tip_pos_w_m[b], tr.tip_pos_w_m)
                assert tuple(truth.contact[b]) == (tr.contact_face, tr.contact_bore, tr.contact_force_N)
                touched[b] |= tr.contact_force_N > 0
                s.apply(_servo_path(s, downs[b], k), np.zeros(n))
                s.step()
            world.apply(np.array([_servo_path(s, d, k) for s, d in zip(alone, downs)]), np.zeros((B, n)), active)
            world.step(t, active, True)
            t = t + world.sims[0].cfg.run.dt_s
        assert touched.all()  # the truth compared in contact, not only in free space
        np.testing.assert_array_equal(world.time_s, [s.time_s for s in alone])


@pytest.mark.parametrize("B", [1, 2])
def test_warned_names_the_episode_mujoco_warned_about(B, tmp_path, monkeypatch):
    """A non-finite state (MuJoCo resets it and counts a warning) is seen in that episode only, and
    only while the episode is active (a stopped one is not watched)."""
    monkeypatch.chdir(tmp_path)  # MuJoCo writes its warning to MUJOCO_LOG.TXT in the working directory
    world = SceneBatch([load_config(None, []) for _ in range(B)], persistent=True)
    active = np.ones(B, bool)
    world.step(0.0, active, True)
    assert not world.warned(active).any()
    world.qvel[B - 1, 0] = np.nan
    world.step(0.001, active, True)
    assert world.warned(active).tolist() == [False] * (B - 1) + [True]
    active[B - 1] = False
    assert not world.warned(active).any()
