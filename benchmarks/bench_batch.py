"""Batched simulation throughput: >= 256 randomised-tool episodes stepped together.

Prints as its last line
    sim_steps_per_s=<a> episodes_per_s=<b> raw_physics_sim_steps_per_s=<c> ratio_median=<r> ratio_spread=<s>
where ``c`` is the same batch (same models, same split over processes, one thread each) stepped
without the controller, replaying the controlled run's servo set-points so the contacts are alike.
The two are timed in ``--rounds`` alternating rounds in the same processes (controlled, raw,
controlled, raw, ...; the processes start each phase together), so a shared machine's load
falls on both alike; ``r`` is the median over
rounds of raw wall / controlled wall (= a / c), ``s`` the spread (max - min) of the per-round
ratios, and ``a``, ``c`` are the medians. Target: a / c >= 0.6. Also checks a sample of episodes against the
single-episode path (success, seat time): the batch runs the same kernels, so they agree.
Usage: python benchmarks/bench_batch.py [--episodes 256] [--processes 2] [--check 8] [--set key=value]

``--profile``: instead, where one process's controlled loop goes (``--episodes`` of the same
configs in one process, ``--rounds`` runs): wall seconds of the loop and of its two big parts --
the controller's step kernel (``Kernels.control``) and the physics step (``SceneBatch.step``:
MuJoCo's batch step and the F/T sensor's realised-acceleration correction) --, each also in us
per episode-step (sim steps), the rest being sensing, the watch, the logs and the loop's Python.
Prints per round ``profile: loop_wall_s=... control_s=... physics_s=... control_us=...
physics_us=... rest_us=...`` and the medians of the per-episode-step figures last.
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import time
from concurrent.futures import ProcessPoolExecutor

# one process per core: BLAS/LAPACK (the kalman law's eigh every 20 steps) must not start its own
# spinning thread pools, or the processes fight over the cores
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

from kinadapt_nn.config import load_config
from kinadapt_nn.runs.batch import run_batch
from kinadapt_nn.runs.episode import run_episode
from kinadapt_nn.runs.sweep import SweepCfg, tool_overrides
from kinadapt_nn.sim.scenes import SceneBatch


def raw_physics(cfgs, ctrl_log: np.ndarray, steps: np.ndarray) -> float:
    """Step the same models with mujoco.batch, replaying ``ctrl_log`` (T, B, n); episode b for
    ``steps[b]`` steps (as in the controlled run). -> wall seconds of the stepping loop."""
    world = SceneBatch(cfgs, nthread=1)  # the same start as run_batch's (two episodes or more: one mujoco.batch)
    scene, ctrl_b = world.physics, world.ctrl
    t0 = time.perf_counter()
    for k in range(len(ctrl_log)):
        ctrl_b[:] = ctrl_log[k]
        scene.step(np.flatnonzero(steps > k))
    return time.perf_counter() - t0


def _chunk(job):
    """``rounds`` alternating (controlled, raw) timings of one process's share; every process
    starts each phase together (``barrier``), so a controlled phase never shares the machine with
    another process's raw phase. -> (the last controlled result, [controlled loop wall], [raw wall])."""
    cfgs, rounds, barrier = job
    walls, raws = [], []
    for _ in range(rounds):
        barrier.wait()
        res = run_batch(cfgs, nthread=1, record_ctrl=True)
        steps = np.array([s["steps"] for s in res.summaries])
        walls.append(res.wall_s)
        barrier.wait()
        raws.append(raw_physics(cfgs, res.ctrl_log, steps))
    return res._replace(ctrl_log=None), walls, raws


def profile(cfgs, rounds: int) -> None:
    """``--profile`` (module docstring): the controlled loop of ``cfgs`` in this process, its
    controller and physics calls timed from outside (numba's kernels cannot be profiled inside)."""
    from kinadapt_nn.runs import loop
    from kinadapt_nn.runs.batch import compile_loop
    from kinadapt_nn.runs.build import one_blas_thread

    compile_loop(cfgs[0])
    rows = []
    for _ in range(rounds):
        with one_blas_thread():
            lp = loop.setup(cfgs, None, traces=False, nthread=1)
            spent = {"control": 0.0, "physics": 0.0}

            def timed(fn, key):
                def call(*args):
                    t0 = time.perf_counter()
                    fn(*args)
                    spent[key] += time.perf_counter() - t0
                return call

            lp.kn.control = timed(lp.kn.control, "control")
            lp.world.step = timed(lp.world.step, "physics")
            t0 = time.perf_counter()
            loop.run(lp, loop.SummaryLog(lp))
            wall = time.perf_counter() - t0
        n = int(lp.watch["n_sim"].sum())
        us = [1e6 * v / n for v in (spent["control"], spent["physics"], wall - sum(spent.values()))]
        rows.append(us)
        print(f"profile: loop_wall_s={wall:.2f} control_s={spent['control']:.2f} physics_s={spent['physics']:.2f} "
              f"control_us={us[0]:.3f} physics_us={us[1]:.3f} rest_us={us[2]:.3f} sim_steps={n}", flush=True)
    med = np.median(np.array(rows), axis=0)
    print(f"episodes={len(cfgs)} rounds={rounds} control_us_per_episode_step={med[0]:.3f} "
          f"physics_us_per_episode_step={med[1]:.3f} rest_us_per_episode_step={med[2]:.3f}")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--episodes", type=int, default=256)
    ap.add_argument("--processes", type=int, default=2, help="one single-threaded batch per process")
    ap.add_argument("--rounds", type=int, default=5, help="alternating controlled/raw timing rounds")
    ap.add_argument("--check", type=int, default=8, help="episodes re-run on the single path for comparison")
    ap.add_argument("--set", action="append", default=[], help="config override key=value (e.g. adaptation.mode=composite)")
    ap.add_argument("--profile", action="store_true", help="where one process's controlled loop goes (docstring)")
    a = ap.parse_args()
    sw = SweepCfg()
    base = ["run.progress=false", "start.lateral_jitter_m=0.0003", "start.tilt_jitter_deg=0.5", "run.stop_after_seat_s=0.1",
            *a.set]
    cfgs = [load_config(None, [*base, *tool_overrides(sw, s), f"run.seed={s}"]) for s in range(a.episodes)]
    if a.profile:
        profile(cfgs, a.rounds)
        return
    chunks = [cfgs[i::a.processes] for i in range(a.processes) if cfgs[i::a.processes]]
    with multiprocessing.Manager() as mgr, ProcessPoolExecutor(max_workers=len(chunks)) as ex:
        barrier = mgr.Barrier(len(chunks))
        parts = list(ex.map(_chunk, [(c, a.rounds, barrier) for c in chunks]))
    summaries = [s for res, _, _ in parts for s in res.summaries]
    sim_steps = sum(res.sim_steps for res, _, _ in parts)
    walls = [max(w[r] for _, w, _ in parts) for r in range(a.rounds)]  # per round: the slower process
    raws = [max(x[r] for _, _, x in parts) for r in range(a.rounds)]
    ratios = [x / w for w, x in zip(walls, raws)]
    wall, raw = float(np.median(walls)), float(np.median(raws))
    ok = sum(s["success"] for s in summaries)
    seats = np.array([s["seat_time_s"] for s in summaries if s["seat_time_s"] is not None])
    print(f"episodes={a.episodes} law={summaries[0]['law']} seated={ok} seat_time_median_s={np.median(seats):.3f} "
          f"setup_s={max(r.setup_s for r, _, _ in parts):.1f} loop_wall_s={wall:.2f} raw_physics_wall_s={raw:.2f} "
          f"sim_steps={sim_steps}")
    print("per-round controlled / raw throughput ratio: " + " ".join(f"{r:.3f}" for r in ratios))
    by_seed = {s["seed"]: s for s in summaries}
    d_seat, same = [], 0
    for c in cfgs[: a.check]:
        e, s = run_episode(c).summary, by_seed[c.run.seed]
        same += e["success"] == s["success"]
        if e["seat_time_s"] is not None and s["seat_time_s"] is not None:
            d_seat.append(abs(e["seat_time_s"] - s["seat_time_s"]))
    if a.check:
        print(f"single-path check: {same}/{a.check} same outcome, max |seat time difference| = "
              f"{max(d_seat) if d_seat else float('nan'):.4f} s")
    print(f"sim_steps_per_s={sim_steps / wall:.0f} episodes_per_s={a.episodes / wall:.2f} "
          f"raw_physics_sim_steps_per_s={sim_steps / raw:.0f} ratio_median={np.median(ratios):.3f} "
          f"ratio_spread={max(ratios) - min(ratios):.3f}")


if __name__ == "__main__":
    main()
