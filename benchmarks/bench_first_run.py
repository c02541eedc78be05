"""The first ``kinadapt online`` on a machine (cold numba cache) against the same command warm.

    python benchmarks/bench_first_run.py [--repeats 3] [--config FILE]

In one run, each in a fresh subprocess with ``NUMBA_CACHE_DIR`` pointing at a new temporary
folder (so the first run compiles every kernel it uses, as on a fresh clone, whatever this
checkout's own ``__pycache__`` holds):
  (a) cold: ``kinadapt online`` with the empty cache, process start to exit, and the compile
      time it measured and recorded (``kinadapt_compile_s.json``);
  (b) warm: the same command ``--repeats`` times on the cache (a) filled (median).
Last line:
    cold_s=<a> compile_s=<recorded> warm_s=<b> ratio=<a/b>
Target (issue 22): ratio <= 4.

The machine is shared and has 2 cores; timings vary by +-30 % between runs.
"""

from __future__ import annotations

import json
import os
import statistics
import tempfile
from pathlib import Path

from bench_online import _timed, online_args  # the same fresh-process timing and options


def main() -> None:
    args, base = online_args(__doc__)
    with tempfile.TemporaryDirectory(prefix="bench-first-run-") as tmp:
        env = dict(os.environ, NUMBA_CACHE_DIR=str(Path(tmp) / "numba"))

        def online(k: str) -> float:
            return _timed([*base, "online", "--out", str(Path(tmp) / k), "--quiet",
                           *(["--config", args.config] if args.config else [])], env)

        cold = online("cold")
        rec = list(Path(tmp, "numba").rglob("kinadapt_compile_s.json"))
        compile_s = json.loads(rec[0].read_text())["seconds"] if rec else float("nan")
        warm = [online(f"warm{k}") for k in range(args.repeats)]
    w = statistics.median(warm)
    print(f"cold run (empty numba cache): {cold:.1f} s, of which the recorded compile {compile_s:.1f} s")
    print("warm runs: " + ", ".join(f"{x:.2f}" for x in warm) + " s")
    print(f"cold_s={cold:.2f} compile_s={compile_s:.2f} warm_s={w:.2f} ratio={cold / w:.2f}")


if __name__ == "__main__":
    main()
