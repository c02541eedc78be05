"""Per control step, what each online effect's columns cost (``features.effect_library.LIBRARY``: the
controller evaluates ``terms`` on a one-sample ``Signals`` every step with ``model.effects``; the
episode benchmark, ``bench_episode.py``, runs without effects).

The samples are the contact window of ``tests/data/online_columns_before_52.npz`` (160 steps of an
excitation run); per effect the best of ``--rounds`` passes over them, in microseconds per step.

Usage: python benchmarks/online_effect_step.py [--rounds 5]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    sys.path.insert(0, str(ROOT))
    from tests.features.test_builtin_online_columns import LIBRARY, _one, windows

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=5, help="passes over the window; the best is printed")
    a = ap.parse_args()
    sig = windows()["contact"]
    steps = [_one(sig, i) for i in range(len(sig.t_s))]
    for name, eff in LIBRARY.items():
        for one in steps[:20]:  # warm
            eff.terms(one)
        best = float("inf")
        for _ in range(a.rounds):
            t0 = time.perf_counter()
            for one in steps:
                eff.terms(one)
            best = min(best, (time.perf_counter() - t0) / len(steps))
        print(f"{name:24s} per_step_us={1e6 * best:.1f}")


if __name__ == "__main__":
    main()
