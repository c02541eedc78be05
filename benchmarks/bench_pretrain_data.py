"""Wall time of the pretraining data set: per-q MuJoCo (``TrueSensorJacobian``) vs batched
pytorch-kinematics, on the default pretrain config (``pretrain/default.toml``), one run each.

Prints as its last line ``old_s=<x> new_s=<y> ratio=<new/old>`` and checks that both give the
same arrays (max relative difference of ``r``).
Usage: python benchmarks/bench_pretrain_data.py [--torch-threads 1] [--set data.n_train=96 ...]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from kinadapt_nn.learning.pretrain import load_pretrain_config, make_dataset
from kinadapt_nn.learning.torch_kinematics import nominal_panda_chain


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--torch-threads", type=int, default=0, help="torch intra-op threads (0: torch's default)")
    ap.add_argument("--set", nargs="*", default=[], help="pretrain config overrides, e.g. data.n_train=96")
    a = ap.parse_args()
    if a.torch_threads > 0:
        torch.set_num_threads(a.torch_threads)
    cfg = load_pretrain_config(None, a.set)
    nominal_panda_chain()  # import-time costs out of both timings (built once per process either way)
    t0 = time.perf_counter()
    old = make_dataset(cfg, kinematics="mujoco")
    old_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    new = make_dataset(cfg, kinematics="torch")
    new_s = time.perf_counter() - t0
    rel = np.abs(new["r"] - old["r"]).max() / np.abs(old["r"]).max()
    same = all(np.array_equal(old[k], new[k]) for k in old if k not in ("r", "jn"))
    print(f"instances={len(old['q'])} configs_per_instance={old['q'].shape[1]} torch_threads={torch.get_num_threads()} "
          f"r_max_rel_diff={rel:.1e} other_arrays_identical={same}")
    print(f"old_s={old_s:.2f} new_s={new_s:.2f} ratio={new_s / old_s:.2f}")


if __name__ == "__main__":
    main()
