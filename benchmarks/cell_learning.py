"""The work cell's learning curve (issue 21) and its done-when checks, from ``kinadapt compare``.

    python benchmarks/cell_learning.py [--seeds 1000 2000] [--out runs/cell_learning] [--figure docs/figures/cell_learning.png]

Runs ``kinadapt compare --config online/compare_cell.toml --set seed=S`` for every seed (or reads
finished compare folders with ``--from DIR ...``) and prints, per seed and family, the median over
tools of the cell Jacobian error (held-out configurations, truth side) before the first insertion
and after each, per features type; the ratio neural / adjoint at the last insertion; the largest
rise from one insertion to the next (the never-worse check, 2 % allowed); and whether every
insertion seated. The first seed's ``cell_learning.png`` is copied to ``--figure``.
"""

from __future__ import annotations

import argparse
import csv
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _table(folder: Path) -> list[dict]:
    with open(folder / "comparison.csv") as fh:
        return list(csv.DictReader(fh))


def report(folder: Path, label: str) -> dict:
    rows = [r for r in _table(folder) if r["insertion"] not in ("", "all")]
    curves: dict[tuple[str, str], list[float]] = {}
    seated: dict[tuple[str, str], bool] = {}
    for r in rows:
        key = (r["tool_family"], r["features"])
        curves.setdefault(key, []).append(float(r["jacobian_error_cell_median"]))
        if r["success_rate"] not in ("", None):
            seated[key] = seated.get(key, True) and float(r["success_rate"]) == 1.0
    out = {}
    print(f"== {label}: cell Jacobian error, median over tools (insertion 0 = before the first)")
    for fam in dict.fromkeys(k[0] for k in curves):
        for feat in dict.fromkeys(k[1] for k in curves):
            c = curves.get((fam, feat))
            if c is None:
                continue
            rise = max((b / a - 1.0 for a, b in zip(c[1:], c[2:])), default=0.0)
            out[(fam, feat)] = {"curve": c, "max_rise": rise, "seated": seated.get((fam, feat), False)}
            print(f"  {fam:10s} {feat:8s} {100 * c[0]:.3f} % -> " + " ".join(f"{100 * e:.3f}" for e in c[1:])
                  + f" %   largest rise between insertions {100 * rise:+.1f} %   every insertion seated: "
                  f"{seated.get((fam, feat), False)}")
        a, n = out.get((fam, "adjoint")), out.get((fam, "neural"))
        if a and n:
            print(f"  {fam:10s} neural / adjoint at the last insertion: {n['curve'][-1] / a['curve'][-1]:.2f}"
                  f"   (adjoint {100 * a['curve'][-1]:.3f} %, neural {100 * n['curve'][-1]:.3f} %)")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1000, 2000])
    ap.add_argument("--out", default=str(ROOT / "runs" / "cell_learning"))
    ap.add_argument("--from", dest="from_", nargs="+", default=None, metavar="DIR", help="finished compare folders")
    ap.add_argument("--figure", default=str(ROOT / "docs" / "figures" / "cell_learning.png"))
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="extra compare override")
    a = ap.parse_args()
    folders = [Path(f) for f in a.from_] if a.from_ else []
    if not folders:
        for seed in a.seeds:
            f = Path(a.out) / f"seed{seed}"
            cmd = [sys.executable, "-c", "import sys; from kinadapt_nn.app.cli import main; sys.exit(main())", "compare", "--config", str(ROOT / "online" / "compare_cell.toml"),
                   "--out", str(f), "--overwrite", "--set", f"seed={seed}", *sum((["--set", s] for s in a.set), [])]
            subprocess.run(cmd, check=True)
            folders.append(f)
    for f in folders:
        report(f, str(f))
    fig = folders[0] / "cell_learning.png"
    if fig.is_file() and a.figure:
        Path(a.figure).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(fig, a.figure)
        print(f"copied {fig} -> {a.figure}")


if __name__ == "__main__":
    main()
