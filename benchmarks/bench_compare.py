"""Time the default ``kinadapt compare`` against one warm ``kinadapt online``, in one run.

Both as a user runs them (fresh processes, kernels already in numba's cache: a warm-up online run
first), each with a temporary output folder:
  (a) ``kinadapt online --quiet`` (default config), ``--online-repeats`` times, median;
  (b) ``kinadapt compare --quiet`` (default config: 3 features x 2 tool families x 4 tools x 3
      scenarios = 72 runs, 120 insertions, ``jobs = 2``), once.
Last line:
    compare_wall_s=<b> online_wall_s=<a> ratio=<b/a>
Target (issue 22): ratio <= 15.

The machine is shared and has 2 cores; timings vary by +-30 % between runs.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_online import _timed  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--online-repeats", type=int, default=3)
    ap.add_argument("--set", action="append", default=[], help="compare override key=value (e.g. n_tools=2)")
    args = ap.parse_args()
    base = [sys.executable, "-m", "kinadapt_nn.app.cli"]
    with tempfile.TemporaryDirectory(prefix="bench-compare-") as tmp:
        _timed([*base, "online", "--out", str(Path(tmp) / "warm"), "--quiet"])  # kernels cached, page cache warm
        online = []
        for k in range(args.online_repeats):
            online.append(_timed([*base, "online", "--out", str(Path(tmp) / f"online{k}"), "--quiet"]))
            print(f"# online run {k}: {online[-1]:.3f} s", flush=True)
        sets = [a for s in args.set for a in ("--set", s)]
        compare = _timed([*base, "compare", "--out", str(Path(tmp) / "compare"), "--quiet", *sets])
    on = statistics.median(online)
    print(f"compare_wall_s={compare:.2f} online_wall_s={on:.3f} ratio={compare / on:.1f}")


if __name__ == "__main__":
    main()
