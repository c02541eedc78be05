"""Time the default episode against raw MuJoCo physics in the same scene, in one run.

Prints, per features type (adjoint, rbf, neural; the neural pair last), a comment line and:
    step_latency_p50_us=<a> step_latency_p99_us=<b>
    episode_wall_s=<x> sim_time_s=<t> raw_physics_s=<y> ratio=<median over rounds of x/y>

Targets: adjoint (issues 2/3) <= 0.3 s wall per 5 s simulated, ratio <= 5, controller p99 <= 100 us;
neural (issue 4) <= 0.6 s per 5 s episode, ratio <= 10.
Run single-threaded for a "one core" figure:  taskset -c 0 python benchmarks/bench_episode.py

Measured (shared 2-core VM; before = the numpy controller at 2858a89, after = the numba kernels
of kinadapt_nn/controller/core.py; one session, back to back):

=====================  ====================  ====================
                       before                after
=====================  ====================  ====================
adjoint p50 / p99 [us] 26.5 / 153            8.9-9.0 / 17-23
adjoint ratio          19.7                  4.5-4.8
neural ratio           23.8                  9.0
rbf ratio              34.9                  27.2
=====================  ====================  ====================

Where a step goes now (adjoint, ~33 us/step): mj_step ~7 us; the controller ~9 us (one numba
dispatch: intake, bare-arm kinematics, sense, regressor, drive, admittance, joint reference, law,
rank gate); the episode loop's own work (runs/loop.py: the samples, the watch, the logged step's
copies, the servo set-point, the truth's contacts) ~10 us; set-up and the offline evaluation
~25 ms per episode. The episode is a batch of one (``run_episodes([cfg])[0]``), stepping its own
MjData with mj_step like the raw physics here.
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from kinadapt_nn.config import load_config  # noqa: E402
from kinadapt_nn.runs.build import make_controller
from kinadapt_nn.runs.episode import run_episode  # noqa: E402
from kinadapt_nn.sim.adapter import PegInHoleSim  # noqa: E402


def raw_physics_seconds(cfg, qpos_traj: np.ndarray, ctrl_traj: np.ndarray) -> float:
    """mj_step for the same number of steps in the same scene, replaying the episode's controls
    open loop (so the contacts are similar); no controller, no logging."""
    sim = PegInHoleSim(cfg)
    m, d = sim.model, sim.data
    t0 = time.perf_counter()
    for u in ctrl_traj:
        d.ctrl[:] = u
        mujoco.mj_step(m, d)
    return time.perf_counter() - t0


def step_latencies_us(cfg) -> np.ndarray:
    """Controller.step latency over a closed-loop default episode (sensor I/O excluded)."""
    sim = PegInHoleSim(cfg)
    ctrl = make_controller(cfg)
    n = int(round(cfg.run.duration_s / cfg.run.dt_s))
    lat = np.empty(n)
    obs = sim.sense()
    for k in range(n):
        t = sim.time_s
        t0 = time.perf_counter()
        cmd = ctrl.step(t, obs.q_rad, obs.qdot_rad_s, obs.wrench_raw_f)
        lat[k] = time.perf_counter() - t0
        sim.apply(cmd.q_ref_rad, cmd.qdot_ref_rad_s)
        sim.step()
        obs = sim.sense()
    return lat * 1e6


def kinematics_cost_us(n: int = 20000) -> tuple[float, float]:
    """Per-call cost of the bare arm's FK + flange Jacobian at encoder readings: MuJoCo's own
    (mj_kinematics + mj_comPos + mj_jacSite from Python, ``ArmKinematics.update``) against the
    kernel's chain (``controller.core.fk_batch`` at B = 1, the same formulas on MuJoCo's model
    constants; equal to mj_jacSite to ~1e-15, tests/controller/test_core.py). -> (mujoco, kernel) [us]."""
    from kinadapt_nn.controller import core
    from kinadapt_nn.robot import FLANGE_SITE, PANDA_MJCF, Q_HOME_RAD, ArmKinematics

    kin = ArmKinematics(PANDA_MJCF)
    site = mujoco.mj_name2id(kin.model, mujoco.mjtObj.mjOBJ_SITE, FLANGE_SITE)
    chain = core.arm_chain(kin.model, site)
    qs = Q_HOME_RAD + 0.1 * np.random.default_rng(0).standard_normal((n, 7))
    inp = np.zeros((1, 2 * 7 + 6))
    p_O, R, J = np.zeros((1, 3)), np.zeros((1, 3, 3)), np.zeros((1, 6, 7))
    core.fk_batch(chain, inp, p_O, R, J)  # compile / load from the cache
    t0 = time.perf_counter()
    for q in qs:
        kin.update(q)
    t_mj = time.perf_counter() - t0
    t0 = time.perf_counter()
    for q in qs:
        inp[0, :7] = q
        core.fk_batch(chain, inp, p_O, R, J)
    t_k = time.perf_counter() - t0
    return 1e6 * t_mj / n, 1e6 * t_k / n


def bench_one(features: str, repeats: int, extra: list[str]) -> None:
    """Print the two lines for one features type: ``repeats`` alternating rounds (episode, then
    the raw physics replaying it), so a shared machine's load falls on both alike; the ratio is
    the median over rounds of episode wall / raw wall, the walls are the medians."""
    cfg = load_config(None, ["run.progress=false", "run.stop_after_seat_s=0.0", f"run.features={features}", *extra])
    run_episode(cfg)  # kernels loaded, first-call costs out of the rounds
    walls, raws = [], []
    res = None
    for _ in range(repeats):
        t0 = time.perf_counter()
        res = run_episode(cfg)
        walls.append(time.perf_counter() - t0)
        raws.append(raw_physics_seconds(cfg, res.trace["q_rad"], res.trace["q_ref_rad"]))
    steps = res.summary["steps"]
    sim_time = res.summary["sim_time_s"]
    ratios = np.array(walls) / np.array(raws)
    lat = step_latencies_us(load_config(None, ["run.progress=false", "run.duration_s=5.0", f"run.features={features}", *extra]))
    wall, raw = float(np.median(walls)), float(np.median(raws))
    print(f"# features={features} n_params={res.summary['n_params']} success={res.summary['success']} "
          f"seat_time_s={res.summary['seat_time_s']} steps={steps} wall_per_5s_sim={wall * 5.0 / sim_time:.3f} "
          f"rounds={repeats} ratio_spread={ratios.max() - ratios.min():.2f}")
    print(f"step_latency_p50_us={np.percentile(lat, 50):.1f} step_latency_p99_us={np.percentile(lat, 99):.1f}")
    print(f"episode_wall_s={wall:.3f} sim_time_s={sim_time:.3f} raw_physics_s={raw:.3f} ratio={np.median(ratios):.2f}")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=7, help="alternating rounds (episode, raw physics); medians")
    ap.add_argument("--features", nargs="+", default=["adjoint", "rbf", "neural"],
                    help="features types, one pair of lines each (the neural line last by default)")
    ap.add_argument("--set", action="append", default=[], help="config override key=value")
    args = ap.parse_args()
    mj_us, k_us = kinematics_cost_us()
    print(f"# arm kinematics per call: mujoco_calls_us={mj_us:.2f} kernel_fk_us={k_us:.2f}")
    for f in args.features:
        bench_one(f, args.repeats, args.set)


if __name__ == "__main__":
    main()
