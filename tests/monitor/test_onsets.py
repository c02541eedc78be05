"""Onset times of the truth-side effects (``sim.effects``): before the onset a run is the clean run,
after it the effect acts, with the size its closed form gives."""

from __future__ import annotations

import numpy as np
import pytest

from kinadapt_nn.config import load_config
from kinadapt_nn.runs.episode import run_episode

BASE = ["run.progress=false", "run.duration_s=3.0", "faults.ft_noise_N=0", "faults.ft_noise_Nm=0",
        "monitor.enabled=false"]
ONSET = 1.5


def _run(extra):
    return run_episode(load_config("online/monitor.toml", BASE + extra)).trace.arrays


@pytest.fixture(scope="module")
def clean():
    return _run([])


@pytest.mark.parametrize("name, keys", [
    ("tool_gravity", ["effects.tool_gravity.enabled=true"]),
    ("ft_bias_drift", ["effects.ft_bias_drift.enabled=true"]),
    ("ft_frame_rotation", ["effects.ft_frame_rotation.enabled=true"]),
    ("world_force", ["effects.world_force.enabled=true"]),
    ("grasp_slip", ["effects.grasp_slip.enabled=true"]),
])
def test_before_the_onset_the_run_is_the_clean_run(clean, name, keys):
    a = _run(keys + [f"effects.{name}.onset_s={ONSET}"])
    t = a["t_s"]
    pre, post = t < ONSET - 1e-9, t > ONSET + 0.2
    assert np.abs(a["wrench_raw_f"][pre] - clean["wrench_raw_f"][pre]).max() < 1e-9
    assert np.abs(a["q_rad"][pre] - clean["q_rad"][pre]).max() < 1e-12
    change = np.abs(a["wrench_raw_f"][post] - clean["wrench_raw_f"][post]).max()
    assert change > 1e-3, change  # the effect acts after its onset


def test_drift_grows_from_its_onset(clean):
    a = _run(["effects.ft_bias_drift.enabled=true", f"effects.ft_bias_drift.onset_s={ONSET}"])
    t = a["t_s"]
    d = a["wrench_raw_f"][:, 0] - clean["wrench_raw_f"][:, 0]
    post = t > ONSET
    # the reading is the sensor's own, the controller's motion unchanged by a sensor effect up to its
    # feedback: check the drift where the feedback has not yet acted (the first 50 ms)
    early = post & (t < ONSET + 0.05)
    np.testing.assert_allclose(d[early], 0.2 * (t[early] - ONSET), atol=2e-3)


def test_snag_pulls_with_its_world_force(clean):
    """Right after the onset (the arm has not moved yet) the reading changes by the pull: the flange holds
    the tool against it, F_f = -R^T f_w (the sensor reports the flange's wrench on the tool)."""
    a = _run(["effects.world_force.enabled=true", f"effects.world_force.onset_s={ONSET}"])
    t = a["t_s"]
    i = int(np.searchsorted(t, ONSET + 0.0025))
    d = a["wrench_raw_f"][i] - clean["wrench_raw_f"][i]
    assert abs(np.linalg.norm(d[:3]) - 1.5) < 0.1, d


def test_snag_acts_at_its_point(clean):
    """The pull's moment about O is p x f (p = point_f_m): with the tool pointing down (f z along -world
    z at this start) and f along world -y, the moment about f x is |f| p_z up to the tool's small tilt."""
    from kinadapt_nn.config import load_config as lc
    from kinadapt_nn.sim.adapter import PegInHoleSim

    cfg = lc("online/monitor.toml", BASE + ["effects.world_force.enabled=true", f"effects.world_force.onset_s={ONSET}"])
    sim = PegInHoleSim(cfg)
    import mujoco

    b = mujoco.mj_name2id(sim.model, mujoco.mjtObj.mjOBJ_BODY, "snag")
    np.testing.assert_allclose(sim.model.body_pos[b] + sim.model.body_ipos[b], cfg.effects.world_force.point_f_m)
    a = _run(["effects.world_force.enabled=true", f"effects.world_force.onset_s={ONSET}"])
    i = int(np.searchsorted(a["t_s"], ONSET + 0.0025))
    d = a["wrench_raw_f"][i] - clean["wrench_raw_f"][i]
    f_s = d[:3]
    p = np.asarray(cfg.effects.world_force.point_f_m)
    np.testing.assert_allclose(np.abs(d[3:]), np.abs(np.cross(p, f_s)), atol=5e-3)
