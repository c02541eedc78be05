"""Import cost of the TensorBoard writers ``runio.EventWriter`` could be built on, in fresh processes.

Prints one line per candidate: the cumulative import time of its top-level imports as
``python -X importtime`` reports them (min and median of ``--repeats`` fresh interpreters):

* TensorBoard's own writer (``EventFileWriter``) and the summary builders ``EventWriter`` uses
  (histogram, text, hparams) -- what ``runio.EventWriter`` imports;
* ``tensorboard.summary`` (its experimental ``Writer``: scalars only);
* ``torch.utils.tensorboard.SummaryWriter`` (the same ``EventFileWriter`` underneath, plus torch).

    python benchmarks/tb_import_cost.py [--repeats 5]
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys

CANDIDATES = {
    "tensorboard EventFileWriter + summary builders (runio.EventWriter)":
        "import tensorboard.summary.writer.event_file_writer, tensorboard.plugins.histogram.summary_v2, "
        "tensorboard.plugins.text.summary_v2, tensorboard.plugins.hparams.summary_v2",
    "tensorboard.summary (experimental Writer)": "import tensorboard.summary",
    "torch.utils.tensorboard.SummaryWriter": "from torch.utils.tensorboard import SummaryWriter",
}


def import_seconds(stmt: str) -> float:
    """[s] the cumulative import time of ``stmt``'s top-level imports in a fresh interpreter."""
    err = subprocess.run([sys.executable, "-X", "importtime", "-c", stmt], capture_output=True, text=True,
                         check=True).stderr
    total = 0
    for line in err.splitlines():
        if line.startswith("import time:") and "|" in line:
            _, cumulative, name = line.split("|", 2)
            if cumulative.strip().isdigit() and not name.startswith("  "):  # a top-level import
                total += int(cumulative)
    return total * 1e-6


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=5)
    a = ap.parse_args()
    for name, stmt in CANDIDATES.items():
        ts = [import_seconds(stmt) for _ in range(a.repeats)]
        print(f"{name}: import min {min(ts):.2f} s median {statistics.median(ts):.2f} s ({a.repeats} fresh processes)")


if __name__ == "__main__":
    main()
