"""Traces for a bit-equal before/after check of a refactor of the step kernels or the episode loop.

    PYTHONPATH=BEFORE_TREE python benchmarks/trace_dump.py save before.npz
    PYTHONPATH=AFTER_TREE  python benchmarks/trace_dump.py save after.npz
    python benchmarks/trace_dump.py compare before.npz after.npz

``save`` runs 15 cases and writes every array they give: the traces of single episodes (adjoint
3 s; rbf, neural, oracle, adjoint with the ft_bias_drift effect column, composite, tracking with
rbf: 2 s each; online/excite.toml 6 s with adjoint and with rbf), three 3-episode summary batches
(adjoint, oracle, adjoint with the effect column: their servo set-points and numeric summary
fields) and ``Controller.step`` called directly on the oracle episode's samples (oracle, the
effect column, adjoint: the command, theta and the out row of every step). ``compare`` prints
how many arrays were compared and the names of those that differ in a bit (NaN equal to NaN);
its last line is ``arrays=<n> differing=<k>``. Run each ``save`` from its tree's root (the
excitation case reads ``online/excite.toml``).
"""

from __future__ import annotations

import argparse

import numpy as np

from kinadapt_nn.config import load_config
from kinadapt_nn.runs.batch import run_batch
from kinadapt_nn.runs.build import make_controller
from kinadapt_nn.runs.episode import run_episode

BASE = ["run.progress=false"]
EFFECT = 'model.effects=["ft_bias_drift"]'
EPISODES = {
    "adjoint": ["run.duration_s=3.0"],
    "rbf": ["run.duration_s=2.0", "run.features=rbf"],
    "neural": ["run.duration_s=2.0", "run.features=neural"],
    "oracle": ["run.duration_s=2.0", "run.features=oracle", "run.log_every=1"],
    "effects": ["run.duration_s=2.0", EFFECT],
    "composite": ["run.duration_s=2.0", "adaptation.mode=composite"],
    "tracking_rbf": ["run.duration_s=2.0", "adaptation.mode=tracking", "run.features=rbf"],
}


def _episodes(res: dict) -> None:
    for name, ov in EPISODES.items():
        for k, v in run_episode(load_config(None, BASE + ov)).trace.arrays.items():
            res[f"{name}/{k}"] = np.asarray(v)
    for feats in ("adjoint", "rbf"):
        r = run_episode(load_config("online/excite.toml", BASE + ["run.duration_s=6.0", f"run.features={feats}"]))
        for k, v in r.trace.arrays.items():
            res[f"excite_{feats}/{k}"] = np.asarray(v)


def _batches(res: dict) -> None:
    for name, feats, extra in (("batch_adj", "adjoint", []), ("batch_oracle", "oracle", []),
                               ("batch_eff", "adjoint", [EFFECT])):
        cfgs = [load_config(None, BASE + ["run.duration_s=2.0", f"run.features={feats}", f"run.seed={s}", *extra])
                for s in range(3)]
        br = run_batch(cfgs, nthread=1, record_ctrl=True)
        res[f"{name}/ctrl_log"] = np.asarray(br.ctrl_log)
        for i, s in enumerate(br.summaries):
            for k, v in s.items():
                if k not in ("wall_time_s", "compile_time_s") and isinstance(v, (int, float, bool)):
                    res[f"{name}/{i}/{k}"] = np.asarray(v)


def _direct(res: dict) -> None:
    """``Controller.step`` on the oracle episode's logged samples (every step: run.log_every=1)."""
    q, qd, w, t = (res[f"oracle/{k}"] for k in ("q_rad", "qdot_rad_s", "wrench_raw_f", "t_s"))
    for name, ov in (("direct_oracle", ["run.features=oracle"]), ("direct_eff", [EFFECT]), ("direct_adj", [])):
        ctrl = make_controller(load_config(None, BASE + ov))
        rows = []
        for j in range(len(t)):
            cmd = ctrl.step(float(t[j]), q[j], qd[j], w[j])
            rows.append(np.r_[cmd.q_ref_rad, cmd.qdot_ref_rad_s, ctrl.theta, ctrl.out[0]])
        res[f"{name}/rows"] = np.array(rows)


def main() -> None:
    ap = argparse.ArgumentParser()
    sub = ap.add_subparsers(dest="cmd", required=True)
    sub.add_parser("save").add_argument("out")
    c = sub.add_parser("compare")
    c.add_argument("a")
    c.add_argument("b")
    a = ap.parse_args()
    if a.cmd == "save":
        res: dict = {}
        _episodes(res)
        _batches(res)
        _direct(res)
        np.savez(a.out, **res)
        print(f"arrays={len(res)}")
        return
    x, y = np.load(a.a), np.load(a.b)
    names = sorted(set(x.files) | set(y.files))
    bad = [k for k in names if k not in x.files or k not in y.files or x[k].dtype != y[k].dtype
           or not np.array_equal(x[k], y[k], equal_nan=True)]
    for k in bad:
        print("differs:", k)
    print(f"arrays={len(names)} differing={len(bad)}")


if __name__ == "__main__":
    main()
