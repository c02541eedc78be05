"""Success rate and seat-time spread over seeds and start misalignments.

Each seed draws the start (lateral misalignment +- jitter, tilt +- jitter) from run.seed.
Usage: python benchmarks/seed_sweep.py [--seeds 20] [--jobs 2] [--set key=value ...]
"""

from __future__ import annotations

import argparse
from concurrent.futures import ProcessPoolExecutor

import numpy as np


def run(args):
    from kinadapt_nn.config import load_config
    from kinadapt_nn.runs.episode import run_episode

    seed, over = args
    return run_episode(load_config(None, ["run.progress=false", "adaptation.mode=composite", f"run.seed={seed}",
                                          *over])).summary


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--lateral-jitter", type=float, default=0.0003)
    ap.add_argument("--tilt-jitter", type=float, default=0.5)
    ap.add_argument("--set", action="append", default=[])
    a = ap.parse_args()
    over = [f"start.lateral_jitter_m={a.lateral_jitter}", f"start.tilt_jitter_deg={a.tilt_jitter}", *a.set]
    with ProcessPoolExecutor(max_workers=a.jobs) as ex:
        rows = list(ex.map(run, [(s, over) for s in range(a.seeds)]))
    print(f"{'seed':>4s} {'lateral [mm]':>14s} {'tilt [deg]':>12s} {'seated':>6s} {'failure':>10s} {'seat_s':>7s} "
          f"{'max|Flat|':>9s} {'max|M|':>7s} {'lat err T [mm]':>14s}")
    for r in rows:
        lat = ",".join(f"{1e3 * x:+.2f}" for x in r["start_lateral_w_m"])
        tilt = ",".join(f"{x:+.2f}" for x in r["start_tilt_deg"])
        seat = f"{r['seat_time_s']:.3f}" if r["seat_time_s"] else "-"
        print(f"{r['seed']:4d} {lat:>14s} {tilt:>12s} {str(r['success']):>6s} {r['failure']:>10s} {seat:>7s} "
              f"{r['max_lateral_force_N']:9.2f} {r['max_moment_Nm']:7.3f} {1e3 * r['offset_error_lateral_final_m']:14.2f}")
    ok = [r for r in rows if r["success"]]
    ts = np.array([r["seat_time_s"] for r in ok])
    fails = {}
    for r in rows:
        if not r["success"]:
            fails[r["failure"]] = fails.get(r["failure"], 0) + 1
    print(f"success_rate={len(ok)}/{len(rows)} seat_time_s: median={np.median(ts):.3f} "
          f"min={ts.min():.3f} max={ts.max():.3f} iqr={np.subtract(*np.percentile(ts, [75, 25])):.3f} failures={fails}"
          if len(ok) else f"success_rate=0/{len(rows)} failures={fails}")


if __name__ == "__main__":
    main()
