"""Between-insertion variants on one held-out tool of the work cell (docs/cell.md, issue 21).

    python benchmarks/cell_refit_variants.py [--insertions 10] [--variants threshold cv timing]

For the tool and arm errors of ``benchmarks/cell_channels.py`` (adjoint and neural on the cell
basis, nominal arm and arm with kinematic errors), runs the work cell of ``online/cell.toml`` in
closed loop with theta refitted between insertions (``kinadapt_nn.runs.refit.Refit``, lateral-force
channels), one variant at a time, and prints the cell Jacobian error (truth side) before the first
insertion and after each, its largest rise between insertions, and what the variant chose:

* ``threshold`` -- the shipped refit: act on the directions whose posterior sd is below
  ``act_sd_ratio`` x the prior's (the kalman law's rule);
* ``cv`` -- act on the k best-identified directions, k chosen by leave-one-insertion-out
  prediction of the lateral forces (measured data only; two halves of the first insertion);
* ``timing`` -- the shipped refit with the F/T-vs-encoder timing offset as one more unknown
  (``cell.refit_timing_sd_s = 0.005``); prints the estimated offset.

``--effects NAME ...``: instead, the ``threshold`` variant with each named library effect in the
online model (``model.effects``), one at a time; ``--features`` limits the features types.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from cell_channels import cell_setup


def _cv_rank(rf) -> int:
    """k in 0..(the threshold's count): leave one insertion out (two halves of the only one),
    refit on the rest, predict the left-out samples with theta acted on along the k
    best-identified directions of that refit."""
    def ranked(P):
        M = rf._Linv @ P @ rf._Linv.T
        lam, V = np.linalg.eigh(0.5 * (M + M.T))
        return np.sqrt(np.clip(lam, 0.0, None)), V

    def at_rank(theta, V, k):
        U = V[:, :k]
        return rf.theta_prior + rf._L @ U @ U.T @ rf._Linv @ (theta - rf.theta_prior)

    theta, P, _ = rf.solve()
    sd, V = ranked(P)
    k_max = int(np.sum(sd < rf.act_ratio))
    kept = [(H, y) for H, y in rf.data if len(y) >= 2]
    if len(kept) >= 2:
        folds = [(kept[:j] + kept[j + 1:], kept[j]) for j in range(len(kept))]
    else:
        H, y = kept[0]
        h = len(y) // 2
        folds = [([(H[:h], y[:h])], (H[h:], y[h:])), ([(H[h:], y[h:])], (H[:h], y[:h]))]
    r_all = np.concatenate([y - np.einsum("kmp,p->km", H, theta) for H, y in kept])
    w = 1.0 / (np.mean(r_all * r_all, axis=0) + rf.r_floor)
    err = np.zeros(k_max + 1)
    for train, (Ht, yt) in folds:
        th_f, P_f, _ = rf.solve(train)
        _, V_f = ranked(P_f)
        for k in range(k_max + 1):
            r = yt - np.einsum("kmp,p->km", Ht, at_rank(th_f, V_f, k))
            err[k] += float(np.sum(r * r * w[None, :]))
    k = int(np.argmin(err))
    return k, np.clip(at_rank(theta, V, k), rf.ctrl.consts.pv[0], rf.ctrl.consts.pv[1])


def one(features: str, family: str, variant: str, n: int, extra: tuple[str, ...] = ()) -> None:
    from kinadapt_nn.runs.insertions import run_insertion
    from kinadapt_nn.runs.refit import Refit

    cfg, ctrl, cell = cell_setup(features, family, extra)
    rf = Refit(ctrl, channels=(1, 2), timing_sd_s=0.005 if variant == "timing" else 0.0)
    curve, chose = [cell.median(ctrl)], []
    t0 = time.perf_counter()
    for i in range(n):
        note = rf.after_insertion(run_insertion(cfg, ctrl, i, keep_regressor=True).trace)
        if variant == "cv":
            k, theta = _cv_rank(rf)
            ctrl.state.theta[0] = theta
            chose.append(k)
        else:
            chose.append(note["identified"])
        curve.append(cell.median(ctrl))
    rise = max(b / a - 1.0 for a, b in zip(curve[1:], curve[2:]))
    label = variant + "".join(" " + e for e in extra)
    extra = f"   timing offset {1e3 * rf.timing_s:+.2f} ms" if variant == "timing" else ""
    print(f"{features:8s} {family:10s} {label:9s} {100 * curve[0]:.3f} % -> " + " ".join(f"{100 * e:.3f}" for e in curve[1:])
          + f" %   largest rise {100 * rise:+.1f} %   directions acted on {chose}{extra}   ({time.perf_counter() - t0:.0f} s)",
          flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--insertions", type=int, default=10)
    ap.add_argument("--variants", nargs="+", default=["threshold", "cv", "timing"], choices=["threshold", "cv", "timing"])
    ap.add_argument("--effects", nargs="+", default=[], metavar="NAME", help="library effects, one run each")
    ap.add_argument("--features", nargs="+", default=["adjoint", "neural"], choices=["adjoint", "neural"])
    a = ap.parse_args()
    for feats in a.features:
        for fam in ("nominal", "arm_errors"):
            if a.effects:
                for e in a.effects:
                    one(feats, fam, "threshold", a.insertions, (f'model.effects=["{e}"]',))
            else:
                for v in a.variants:
                    one(feats, fam, v, a.insertions)


if __name__ == "__main__":
    main()
