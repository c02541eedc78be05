"""Repeated insertions (a work cell): the same tool on the same arm N times with theta and its
covariance carried over (``run.insertions``), per features type and tool family, default law.

    python benchmarks/repeated_insertions.py [--n 5] [--jobs 2] [--out docs/figures/repeated_insertions.png]

Prints one line per (features, family) with the Jacobian error at the start of insertion 1 and
at the end of every insertion, and draws the error against the insertion number.
"""

from __future__ import annotations

import argparse
import json
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = ["scene.contact_model=socket", "control.dither_rad_s=[0.05,0.05,0.05]"]
#: one held-out tool (not the default one) and one arm with kinematic errors (compare's draw, seed 1000)
TOOL = ["tool.offset_f_m=[0.0031, -0.0042, 0.1012]"]
ARM = ["arm.link_length_error_m=[0.0008,-0.0011,0.0004,0.0009,-0.0006,0.0012,-0.0003,0.0007]",
       "arm.joint_offset_rad=[0.003,-0.004,0.002,0.005,-0.003,0.004,-0.002]"]


def _one(job):
    from kinadapt_nn.config import load_config
    from kinadapt_nn.runs.insertions import run_insertions

    feats, fam, n, extra = job
    over = ["run.progress=false", "run.tensorboard=false", "run.figure=false", f"run.features={feats}",
            f"run.insertions={n}", *SCENARIO, *TOOL, *(ARM if fam == "arm_errors" else []), *extra]
    s = run_insertions(load_config(None, over)).summary
    rows = s.get("insertions") or [{"insertion": 1, "success": s["success"],
                                     "jacobian_rel_error_initial": s["jacobian_rel_error_initial"],
                                     "jacobian_rel_error_final": s["jacobian_rel_error_final"]}]
    return feats, fam, s["law"], rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=5)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", default=str(ROOT / "docs" / "figures" / "repeated_insertions.png"))
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="extra online-config override")
    a = ap.parse_args()
    if a.n < 1 or a.jobs < 1:
        ap.error("--n and --jobs must be >= 1")
    jobs = [(f, fam, a.n, a.set) for f in ("adjoint", "rbf", "neural") for fam in ("nominal", "arm_errors")]
    with ProcessPoolExecutor(max_workers=a.jobs) as ex:
        results = list(ex.map(_one, jobs))
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4), constrained_layout=True, sharey=True)
    out = []
    for feats, fam, law, rows in results:
        errs = [rows[0]["jacobian_rel_error_initial"]] + [r["jacobian_rel_error_final"] for r in rows]
        ok = all(r["success"] for r in rows)
        out.append({"features": feats, "family": fam, "law": law, "errors": errs, "all_seated": ok})
        print(f"{feats:8s} {fam:10s} law={law} seated={ok} jacobian_rel_error: start {errs[0]:.4f} -> "
              + " ".join(f"{e:.4f}" for e in errs[1:]))
        ax = axes[0 if fam == "nominal" else 1]
        ax.semilogy(range(len(errs)), errs, "o-", label=feats)
    for ax, fam in zip(axes, ("nominal", "arm_errors")):
        ax.set_xlabel("insertion (0 = start of the first)")
        ax.set_title(f"socket + dither, {fam} tool: theta and P carried over")
        ax.set_xticks(range(a.n + 1))
        ax.grid(alpha=0.3)
        ax.legend()
    axes[0].set_ylabel("|W (J_hat - J_true)| / |W J_true| at the end of each insertion")
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(a.out, dpi=110)
    Path(a.out).with_suffix(".json").write_text(json.dumps(out, indent=1))
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
