"""Identification floor vs the bias: does the final offset error follow O(b / sigma_min)?

Theorem ft_rigid: under persistent excitation the offset error converges to a residual set of
size O(b / sigma_min) on the excited directions. For a ladder of scenarios that change the bias
b (contact model, stiffness mismatch) and the excitation sigma_min (dither amplitude), this
script measures, in one run:

* b_rms       RMS of the W-scaled prediction error in contact with the TRUE offset
              (oracle run: there the prediction error is exactly the filtered bias b)
* sigma_min   sqrt(lambda_min <(W Phi)^T (W Phi)>) over the contact phase (oracle run)
* err         lateral offset error of the composite law, RMS over the last 1.5 s [m]
* ratio       err / (b_rms / sigma_min)   -- roughly constant if the floor is O(b/sigma_min)

Usage:  python benchmarks/identification_floor.py [--jobs 2] [--png out.png]
"""

from __future__ import annotations

import argparse
import json
from concurrent.futures import ProcessPoolExecutor


from kinadapt_nn.paper.floor import LADDER, floor_figure, measure  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--png", default=None)
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    with ProcessPoolExecutor(max_workers=args.jobs) as ex:
        rows = list(ex.map(measure, LADDER))
    print(f"{'scenario':34s} {'seat':>6s} {'b_rms':>9s} {'sigma_min':>10s} {'b/sigma [mm]':>13s} "
          f"{'err [mm]':>9s} {'ratio':>7s}")
    for r in rows:
        seat = f"{r['seat_time_s']:.2f}" if r["seat_time_s"] else "  -  "
        print(f"{r['scenario']:34s} {seat:>6s} {r['b_rms_w']:9.3g} {r['sigma_min']:10.3g} "
              f"{1e3 * r['b_over_sigma_m']:13.3g} {1e3 * r['lateral_error_rms_last_m']:9.3f} {r['ratio']:7.3g}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=1)
    if args.png:
        floor_figure(rows, args.png)


if __name__ == "__main__":
    main()
