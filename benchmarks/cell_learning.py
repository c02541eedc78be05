"""The work cell's learning curve (issue 21) and its done-when checks, from ``kinadapt compare``.

    python benchmarks/cell_learning.py [--seeds 1000 2000] [--out runs/cell_learning] [--figure PNG]
        [--draws-figure PNG]

Runs ``kinadapt compare --config online/compare_cell.toml --set seed=S`` for every seed (or reads
finished compare folders with ``--from DIR ...``) and prints, per seed and family, the median over
tools of the cell Jacobian error (held-out configurations, truth side) before the first insertion
and after each, per features type; the ratio neural / adjoint at the last insertion; the largest
rise from one insertion to the next (the never-worse check, 2 % allowed); and whether every
insertion seated; then issue 40's four checks per draw (``goals``). It writes only where it is told:
the compare folders under ``--out``; the first seed's ``cell_learning.png`` copied to ``--figure``
and, with several seeds, the median and range over the draws (``draws_figure``) to
``--draws-figure`` only when those are given (the README's figures:
``--figure docs/figures/cell_learning.png``, ``--draws-figure docs/figures/cell_learning_draws.png``).
"""

from __future__ import annotations

import argparse
import csv
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np

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


def goals(out: dict, label: str) -> bool:
    """Issue 40 part 3's checks on one draw's ``report``: (a) arm errors, neural / adjoint <= 0.5 at
    the last insertion; (b) the nominal family's final error <= 0.2 % for every features type; (c) no
    rise between consecutive insertions above both 2 % (relative) and 0.01 percentage points; (d)
    every insertion seated. Prints them; -> all met."""
    a, n = out.get(("arm_errors", "adjoint")), out.get(("arm_errors", "neural"))
    ok_a = bool(a and n and n["curve"][-1] <= 0.5 * a["curve"][-1])
    ok_b = all(v["curve"][-1] <= 0.002 for (fam, _), v in out.items() if fam == "nominal")
    failing = [f"{fam} {feat}" for (fam, feat), v in out.items()
               if any(y / x - 1.0 > 0.02 and 100 * (y - x) > 0.01 for x, y in zip(v["curve"][1:], v["curve"][2:]))]
    ok_d = all(v["seated"] for v in out.values())
    print(f"  checks ({label}): (a) neural <= 0.5x adjoint on arm errors: {ok_a}; (b) nominal <= 0.2 %: {ok_b}; "
          f"(c) no rise > 2 % and > 0.01 pp: {not failing}" + (f" (failing: {', '.join(failing)})" if failing else "")
          + f"; (d) every insertion seated: {ok_d}")
    return ok_a and ok_b and not failing and ok_d


def draws_figure(outs: list[dict], seeds: list[str], path: Path) -> None:
    """The cell error after each insertion over several draws: per family (panel) and features type
    (colour), the median over draws (thick) and the range over draws (band); each draw's curve is a
    median over its tools. Log scale [%]."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fams = list(dict.fromkeys(k[0] for o in outs for k in o))
    feats = list(dict.fromkeys(k[1] for o in outs for k in o))
    fig, axes = plt.subplots(1, len(fams), figsize=(6.2 * len(fams), 4.4), constrained_layout=True, squeeze=False)
    for ax, fam in zip(axes[0], fams):
        for j, feat in enumerate(feats):
            curves = np.array([100 * np.asarray(o[(fam, feat)]["curve"]) for o in outs if (fam, feat) in o])
            if not len(curves):
                continue
            x = np.arange(curves.shape[1])
            ax.fill_between(x, curves.min(0), curves.max(0), color=f"C{j}", alpha=0.18, lw=0)
            ax.plot(x, np.median(curves, 0), color=f"C{j}", lw=2.2, label=f"{feat} (median of {len(curves)} draws)")
        ax.set_yscale("log")
        ax.set_xticks(np.arange(0, curves.shape[1]))
        ax.set_xlabel("insertion (0 = before the first)")
        ax.set_ylabel("cell Jacobian error [%] (median over tools)")
        ax.set_title(f"{fam.replace('_', ' ')} family", fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(f"work cell, {len(outs)} draws of tools and arms (seeds {', '.join(seeds)}): "
                 "band = range over draws", fontsize=10)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    print(f"wrote {path}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1000, 2000])
    ap.add_argument("--out", default=str(ROOT / "runs" / "cell_learning"))
    ap.add_argument("--from", dest="from_", nargs="+", default=None, metavar="DIR", help="finished compare folders")
    ap.add_argument("--figure", default=None, metavar="PNG",
                    help="copy the first seed's cell_learning.png here (e.g. docs/figures/cell_learning.png)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="extra compare override")
    ap.add_argument("--draws-figure", default=None, metavar="PNG",
                    help="with several seeds: the curves' median and range over the draws, to this file")
    a = ap.parse_args()
    folders = [Path(f) for f in a.from_] if a.from_ else []
    if not folders:
        for seed in a.seeds:
            f = Path(a.out) / f"seed{seed}"
            cmd = [sys.executable, "-c", "import sys; from kinadapt_nn.app.cli import main; sys.exit(main())", "compare", "--config", str(ROOT / "online" / "compare_cell.toml"),
                   "--out", str(f), "--overwrite", "--set", f"seed={seed}", *sum((["--set", s] for s in a.set), [])]
            subprocess.run(cmd, check=True)
            folders.append(f)
    outs = []
    for f in folders:
        outs.append(report(f, str(f)))
        goals(outs[-1], f.name)
    if len(outs) > 1 and a.draws_figure:
        draws_figure(outs, [f.name.removeprefix("seed") for f in folders], Path(a.draws_figure))
    fig = folders[0] / "cell_learning.png"
    if fig.is_file() and a.figure:
        Path(a.figure).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(fig, a.figure)
        print(f"copied {fig} -> {a.figure}")
    elif fig.is_file():
        print(f"the figure: {fig} (--figure PNG copies it elsewhere)")


if __name__ == "__main__":
    main()
