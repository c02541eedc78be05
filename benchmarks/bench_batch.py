"""Batched simulation throughput: >= 256 randomised-tool episodes stepped together.

Prints as its last line ``sim_steps_per_s=<x> episodes_per_s=<y>`` (target >= 50,000 sim-steps/s
on 2 cores with the analytic features). Also checks a sample of episodes against the
single-episode path (success, seat time).
Usage: python benchmarks/bench_batch.py [--episodes 256] [--threads 2] [--check 8]
"""

from __future__ import annotations

import argparse

import numpy as np

from kinadapt_nn.runs.batch import run_batch, run_batch_processes
from kinadapt_nn.config import load_config
from kinadapt_nn.runs.episode import run_episode
from kinadapt_nn.runs.sweep import SweepCfg, tool_overrides


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--episodes", type=int, default=256)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--check", type=int, default=8, help="episodes re-run on the single path for comparison")
    ap.add_argument("--mode", choices=["processes", "threads"], default="processes",
                    help="processes: one single-threaded batch per core (default, measured faster); threads: one batch")
    a = ap.parse_args()
    sw = SweepCfg()
    base = ["run.progress=false", "start.lateral_jitter_m=0.0003", "start.tilt_jitter_deg=0.5", "run.stop_after_seat_s=0.1",
            "adaptation.mode=composite"]  # the batch implements the paper's laws
    cfgs = [load_config(None, [*base, *tool_overrides(sw, s), f"run.seed={s}"]) for s in range(a.episodes)]
    res = run_batch_processes(cfgs, a.threads) if a.mode == "processes" else run_batch(cfgs, nthread=a.threads)
    ok = sum(s["success"] for s in res.summaries)
    seats = np.array([s["seat_time_s"] for s in res.summaries if s["seat_time_s"] is not None])
    print(f"episodes={a.episodes} seated={ok} seat_time_median_s={np.median(seats):.3f} setup_s={res.setup_s:.1f} "
          f"loop_wall_s={res.wall_s:.2f} control_steps={res.steps} sim_steps={res.sim_steps}")
    d_seat, same = [], 0
    for c, s in list(zip(cfgs, res.summaries))[: a.check]:
        e = run_episode(c).summary
        same += e["success"] == s["success"]
        if e["seat_time_s"] is not None and s["seat_time_s"] is not None:
            d_seat.append(abs(e["seat_time_s"] - s["seat_time_s"]))
    if a.check:
        print(f"single-path check: {same}/{a.check} same outcome, max |seat time difference| = "
              f"{max(d_seat) if d_seat else float('nan'):.4f} s")
    print(f"sim_steps_per_s={res.sim_steps / res.wall_s:.0f} episodes_per_s={a.episodes / res.wall_s:.2f}")


if __name__ == "__main__":
    main()
