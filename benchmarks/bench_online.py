"""Time ``kinadapt online`` end to end against its own episode and the imports it cannot avoid.

In one run, ``--repeats`` times (median reported), each in a fresh subprocess:
  (a) the import of mujoco + numpy + matplotlib,
  (b) ``kinadapt online`` (default config, adjoint features, a temp output folder), process start
      to exit,
  (c) that run's episode wall (``wall_time_s`` of its summary.json).
Last line:
    online_wall_s=<b> episode_wall_s=<c> import_mnm_s=<a> ratio=<b/(c+a)>
Target: ratio <= 2.0 (issue 39: the rollout figure drawn in the process itself, once; 1.5 under issue 13
with the figure drawn by a forked worker beside the episode).

The machine is shared and has 2 cores; timings vary by +-30 % between runs.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

IMPORT_MNM = "import mujoco, numpy, matplotlib.pyplot"


def _timed(cmd: list[str], env: dict | None = None) -> float:
    """Wall seconds of ``cmd`` in a fresh process (``env``: its environment, default ours)."""
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    if proc.returncode not in (0, 1):  # 1: ran to the end, not seated
        raise SystemExit(f"{' '.join(cmd)} failed (exit {proc.returncode}):\n{proc.stderr}")
    return wall


def online_args(doc: str) -> tuple[argparse.Namespace, list[str]]:
    """The ``--repeats`` / ``--config`` options of the online benchmarks, and the command the
    ``kinadapt`` console script runs."""
    ap = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--config", help="an online config (default: the built-in defaults)")
    return ap.parse_args(), [sys.executable, "-m", "kinadapt_nn.app.cli"]


def main() -> None:
    args, base = online_args(__doc__)
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-online-") as tmp:
        _timed([sys.executable, "-c", IMPORT_MNM])  # page cache warm, as for every later run
        for k in range(args.repeats):
            imp = _timed([sys.executable, "-c", IMPORT_MNM])
            out = Path(tmp) / f"run{k}"
            cmd = [*base, "online", "--out", str(out), "--quiet", *(["--config", args.config] if args.config else [])]
            wall = _timed(cmd)
            episode = float(json.loads((out / "summary.json").read_text())["wall_time_s"])
            rows.append((wall, episode, imp))
            print(f"# run {k}: online_wall_s={wall:.3f} episode_wall_s={episode:.3f} import_mnm_s={imp:.3f} "
                  f"ratio={wall / (episode + imp):.2f}", flush=True)
    wall, episode, imp = (statistics.median(r[i] for r in rows) for i in range(3))
    print(f"online_wall_s={wall:.3f} episode_wall_s={episode:.3f} import_mnm_s={imp:.3f} "
          f"ratio={wall / (episode + imp):.2f}")


if __name__ == "__main__":
    main()
