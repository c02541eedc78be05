"""Which channels of s should the between-insertion refit fit? (docs/cell.md, issue 21)

    python benchmarks/cell_channels.py [--insertions 6]

For one held-out tool (compare's seed-1000 draw), per features type (adjoint, neural on the cell
basis) and family (nominal arm, arm with kinematic errors): runs the work cell of
``online/cell.toml`` with theta carried (default law), keeps every insertion's measured regression
data (``kinadapt_nn.runs.refit.Refit``), then prints

* the cell Jacobian error of the online estimate, of the best possible theta (a least-squares fit
  of J_hat to the TRUE Jacobians on the held-out configurations: what the basis can represent),
  and of the pooled refit on each channel set (prior weight 1);
* the residual RMS per channel at the best theta against the signal the offset/basis moves
  there: a channel whose residual at the best theta is large against its signal carries
  something the model's constant S does not contain (a bias);
* leave-one-insertion-out prediction error on the lateral-force channels for each channel set
  (measured data only: what a robot could use to choose).
"""

from __future__ import annotations

import argparse

import numpy as np

CELL = ("cell.bores_w_m=[[0.45,0.0,0.30],[0.55,0.15,0.25],[0.55,-0.15,0.25],[0.38,0.2,0.35],[0.38,-0.2,0.35],"
        "[0.6,0.0,0.2]]")
TOOL = "tool.offset_f_m=[0.0031,-0.0042,0.1012]"
ARM = ["arm.link_length_error_m=[0.0008,-0.0011,0.0004,0.0009,-0.0006,0.0012,-0.0003,0.0007]",
       "arm.joint_offset_rad=[0.003,-0.004,0.002,0.005,-0.003,0.004,-0.002]"]
SETS = {"F_lat (1,2)": [1, 2], "F_lat+M_xy (1-4)": [1, 2, 3, 4], "F_lat+M (1-5)": [1, 2, 3, 4, 5], "M (3-5)": [3, 4, 5]}


def _fit(data, th0, P0inv, ch, n_eff):
    th = th0.copy()
    for _ in range(3):
        Lam, eta = P0inv.copy(), np.zeros(len(th0))
        for H, y in data:
            H, y = H[:, ch], y[:, ch]
            r = y - np.einsum("kmp,p->km", H, th)
            w = 1.0 / ((np.mean(r * r, axis=0) + 1e-4) * n_eff)
            Lam += np.einsum("kmp,kmq->pq", H * w[None, :, None], H)
            eta += np.einsum("kmp,km->p", H * w[None, :, None], y - np.einsum("kmp,p->km", H, th0))
        th = th0 + np.linalg.solve(Lam, eta)
    return th


def cell_setup(features: str, family: str, extra=()):
    """The work cell of ``online/cell.toml`` for the held-out tool above. -> (cfg, controller,
    its CellJacobianError)."""
    from kinadapt_nn.config import load_config
    from kinadapt_nn.runs.build import make_controller
    from kinadapt_nn.runs.cell import CellJacobianError

    cfg = load_config(None, ["run.progress=false", "scene.contact_model=socket", "control.dither_rad_s=[0.05,0.05,0.05]",
                             TOOL, CELL, f"run.features={features}", "features.neural_checkpoint=neural_cell.safetensors",
                             *(ARM if family == "arm_errors" else []), *extra])
    ctrl = make_controller(cfg)
    return cfg, ctrl, CellJacobianError(cfg, ctrl)


def one(features: str, family: str, n: int) -> None:
    from kinadapt_nn.runs.insertions import run_insertion
    from kinadapt_nn.runs.refit import Refit

    cfg, ctrl, cell = cell_setup(features, family)
    rf = Refit(ctrl, channels=(0, 1, 2, 3, 4, 5))
    for i in range(n):
        rf.add(run_insertion(cfg, ctrl, i, keep_regressor=True).trace)
    th0, p = rf.theta_prior, len(rf.theta_prior)
    # the best theta the basis allows (truth side): J_hat is affine in theta for these features
    h = 1e-3 if features == "adjoint" else 1.0
    J0 = np.stack([ctrl.features.jacobian(k, th0) for k in cell._kin])
    A = np.stack([(np.stack([ctrl.features.jacobian(k, th0 + h * e) for k in cell._kin]) - J0) / h
                  for e in np.eye(p)], axis=-1)
    Ww = ctrl.W[None, :, None] / cell._den[:, None, None]
    x, *_ = np.linalg.lstsq((Ww[..., None] * A).reshape(-1, p), (Ww * (cell.J_true - J0)).reshape(-1), rcond=None)
    th_best = th0 + x
    print(f"== {features} / {family}: cell error online (carried) {100 * cell.median(ctrl):.3f} %, "
          f"best theta {100 * cell.median(ctrl, th_best):.3f} %")
    Hs = np.concatenate([H for H, _ in rf.data])
    ys = np.concatenate([y for _, y in rf.data])
    res = np.sqrt(np.mean((ys - np.einsum("kmp,p->km", Hs, th_best)) ** 2, axis=0))
    sig = np.sqrt(np.mean(np.einsum("kmp,p->km", Hs, th_best - th0) ** 2, axis=0))
    print("   channel            d       F_x     F_y     M_x     M_y     M_z")
    print("   residual @ best  " + " ".join(f"{v:7.4f}" for v in res))
    print("   signal (best-0)  " + " ".join(f"{v:7.4f}" for v in sig))
    for name, ch in SETS.items():
        th = _fit(rf.data, th0, rf._P0inv, ch, rf.n_eff)
        cv = 0.0
        for j in range(len(rf.data)):
            tj = _fit(rf.data[:j] + rf.data[j + 1:], th0, rf._P0inv, ch, rf.n_eff)
            H, y = rf.data[j]
            cv += float(np.mean((y[:, 1:3] - np.einsum("kmp,p->km", H[:, 1:3], tj)) ** 2))
        print(f"   refit on {name:18s} cell error {100 * cell.median(ctrl, th):.3f} %   "
              f"leave-one-insertion-out F_lat prediction MSE {cv / len(rf.data):.3g}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--insertions", type=int, default=6)
    a = ap.parse_args()
    for feats in ("adjoint", "neural"):
        for fam in ("nominal", "arm_errors"):
            one(feats, fam, a.insertions)


if __name__ == "__main__":
    main()
