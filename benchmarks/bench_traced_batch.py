"""Episodes with traces: ``run_episodes`` (one batch) against ``run_episode`` one after another.

    python benchmarks/bench_traced_batch.py [--episodes 8] [--rounds 3] [--features adjoint]

In one process, kernels warm: ``--rounds`` alternating rounds of (a) the episodes as one batch
with traces (``kinadapt_nn.runs.batch.run_episodes``, what ``kinadapt compare`` runs) and (b) the
same episodes by ``run_episode``; each round checks that every trace channel is equal. Both include
each episode's set-up (start pose) and post-processing (offline evaluation, summary).
Last line:
    episodes=<n> batch_s=<median a> single_s=<median b> ratio=<a/b>
No target: a measure of what batching the traced episodes buys on this machine.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from kinadapt_nn.config import load_config
from kinadapt_nn.runs.batch import run_episodes
from kinadapt_nn.runs.episode import run_episode
from kinadapt_nn.runs.sweep import SweepCfg, tool_overrides


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--episodes", type=int, default=8)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--features", default="adjoint")
    args = ap.parse_args()
    base = ["run.progress=false", "start.lateral_jitter_m=0.0003", "start.tilt_jitter_deg=0.5",
            f"run.features={args.features}"]
    cfgs = [load_config(None, [*base, *tool_overrides(SweepCfg(), s), f"run.seed={s}"]) for s in range(args.episodes)]
    run_episodes(cfgs[:2])  # warm: kernels loaded, imports done
    run_episode(cfgs[0])
    tb, ts = [], []
    for r in range(args.rounds):
        t0 = time.perf_counter()
        got = run_episodes(cfgs)
        tb.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        want = [run_episode(c) for c in cfgs]
        ts.append(time.perf_counter() - t0)
        same = all(np.array_equal(g.trace.arrays[k], w.trace.arrays[k], equal_nan=True)
                   for g, w in zip(got, want) for k in w.trace.arrays)
        steps = sum(w.summary["steps"] for w in want)
        print(f"round {r}: batch {tb[-1]:.3f} s, single {ts[-1]:.3f} s, {steps} control steps, traces equal: {same}")
    b, s = statistics.median(tb), statistics.median(ts)
    print(f"episodes={args.episodes} batch_s={b:.3f} single_s={s:.3f} ratio={b / s:.3f}")


if __name__ == "__main__":
    main()
