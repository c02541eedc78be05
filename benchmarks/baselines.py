"""Baselines on the same start: oracle, frozen (5 mm wrong), composite, prediction, tracking.

Prints one row per (scenario, law) with seat time, forces, and the final lateral offset error.
Usage: python benchmarks/baselines.py [--jobs 2]
"""

from __future__ import annotations

import argparse
from concurrent.futures import ProcessPoolExecutor

SCENARIOS = {
    "bore (paper setting)": [],
    "socket + dither 0.05": ["scene.contact_model=socket", "control.dither_rad_s=[0.05,0.05,0.05]"],
}
LAWS = {
    "oracle": ["run.features=oracle"],
    "frozen": ["adaptation.mode=frozen"],
    "composite": ["adaptation.mode=composite"],
    "prediction": ["adaptation.mode=prediction"],
    "tracking": ["adaptation.mode=tracking"],
    "tracking G=8000": ["adaptation.mode=tracking", "adaptation.gamma=8000"],
}


def run(item):
    from kinadapt_nn.config import load_config
    from kinadapt_nn.runs.episode import run_episode

    scen, law = item
    s = run_episode(load_config(None, ["run.progress=false", *SCENARIOS[scen], *LAWS[law]])).summary
    return scen, law, s


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args()
    items = [(s, law) for s in SCENARIOS for law in LAWS]
    with ProcessPoolExecutor(max_workers=args.jobs) as ex:
        rows = list(ex.map(run, items))
    print(f"{'scenario':22s} {'law':16s} {'seated':>6s} {'seat_s':>7s} {'max|F|':>7s} {'max|Flat|':>9s} "
          f"{'max|M|':>7s} {'lat err0':>8s} {'lat errT':>8s} {'axial errT':>10s}")
    for scen, law, s in rows:
        seat = f"{s['seat_time_s']:.3f}" if s["seat_time_s"] else "-"
        print(f"{scen:22s} {law:16s} {str(s['success']):>6s} {seat:>7s} {s['max_force_N']:7.2f} "
              f"{s['max_lateral_force_N']:9.2f} {s['max_moment_Nm']:7.3f} "
              f"{1e3 * s['offset_error_lateral_initial_m']:7.2f}m {1e3 * s['offset_error_lateral_final_m']:7.2f}m "
              f"{1e3 * s['offset_error_final_m'][2]:+9.2f}m")
    print("(errors in mm)")


if __name__ == "__main__":
    main()
