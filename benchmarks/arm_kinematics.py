"""The arm's kinematics per sample: MuJoCo's batched kinematics as ``ArmModel._frames`` uses it,
against a per-sample ``mj_kinematics`` + ``mj_comPos`` + ``mj_jacSite`` loop from Python (the
former implementation), on the same configurations in one process.

    python benchmarks/arm_kinematics.py [--samples 50000]

Prints the CPU time per sample of each and their ratio, and the largest difference (it must be
rounding).
"""

from __future__ import annotations

import argparse
import time

import mujoco
import numpy as np

from kinadapt_nn.diagnostics.physical import ArmModel
from kinadapt_nn.diagnostics.setup import load_setup


def _loop(arm: ArmModel, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    m, d = arm.model, mujoco.MjData(arm.model)
    jp, jr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
    n = len(q)
    R, x, Jp, Jr = np.empty((n, 3, 3)), np.empty((n, 3)), np.empty((n, 3, arm.dof)), np.empty((n, 3, arm.dof))
    for i in range(n):
        d.qpos[arm._qpos] = q[i]
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_jacSite(m, d, jp, jr, arm.site)
        R[i], x[i], Jp[i], Jr[i] = d.site_xmat[arm.site].reshape(3, 3), d.site_xpos[arm.site], jp[:, arm._cols], \
            jr[:, arm._cols]
    return R, x, Jp, Jr


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--samples", type=int, default=50_000)
    args = ap.parse_args(argv)
    arm = ArmModel(load_setup(None))  # the shipped Panda
    q = np.random.default_rng(0).uniform(-2.5, 2.5, (args.samples, arm.dof))
    arm._frames(q[:10])  # the batch made
    t = time.process_time()
    batched = arm._frames(q)
    t_batch = time.process_time() - t
    t = time.process_time()
    loop = _loop(arm, q)
    t_loop = time.process_time() - t
    diff = max(float(np.abs(a - b).max()) for a, b in zip(batched, loop))
    print(f"{args.samples} Panda configurations: batched {1e6 * t_batch / args.samples:.2f} us, per-sample loop "
          f"{1e6 * t_loop / args.samples:.2f} us CPU per sample (ratio {t_loop / t_batch:.2f}); largest difference "
          f"{diff:.1e}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
