"""Physics outside the library through ``kinadapt diagnose LOG --setup``: the completeness verdict,
the top hint, the user's own effect file and ``--add``, and the wall time per log.

    python benchmarks/outside_logs.py [--out benchmarks/results/outside_logs] [--seed 0]

The logs come from ``examples/foreign_rig_outside.py`` (rig A of the independent foreign rig, each
hiding one effect no built-in names; 15 s at 500 Hz). Every diagnosis is the CLI in a fresh process
(what a user runs: Python's start and the imports included). Per case: (1) the plain diagnosis:
``model_complete``, the hint shapes in rank order, the present effects and whether each carries
the "may stand in" warning; (2) where ``examples/effects/`` has the effect a user would write:
``--effects FILE --add NAME``: its verdict, the worst parameter error, other present effects,
``model_complete``, and the noise-weighted residual after ``--add`` against the effect-free log's
residual. Writes ``outside_logs.json`` and ``outside_logs.md``.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
USER_FILES = {"world_pull": "cable_pull", "crosstalk": "crosstalk", "temperature": "temperature_bias"}


def _load(name: str):
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, ROOT / "examples" / f"{name}.py")
        mod = importlib.util.module_from_spec(spec)
        sys.modules[name] = mod
        spec.loader.exec_module(mod)
    return sys.modules[name]


def _diagnose(d: Path, out: Path, extra: list[str]) -> tuple[dict | None, float, str]:
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-m", "kinadapt_nn.app.cli", "diagnose", str(d / "log.csv.gz"), "--setup",
                        str(d / "setup_csv.toml"), "--out", str(out), "--quiet", *extra], capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if p.returncode:
        return None, wall, p.stderr.strip()
    return json.loads((out / "diagnosis.json").read_text()), wall, ""


def _present(rep: dict) -> list[str]:
    return [e["effect"] for e in rep["ranking"] if e["verdict"] == "present"]


def run(out: Path, seed: int) -> dict:
    _load("foreign_rig")
    rig = _load("foreign_rig_outside")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        dirs = {c: rig.make_case(c, Path(tmp) / "logs", seed=seed) for c in rig.CASES}
        free_rep, _, err = _diagnose(dirs["effect_free"], Path(tmp) / "o" / "free", [])
        free_rms = free_rep["residual_rms_by_channel"]["total_w"] if free_rep else float("nan")
        for case, d in dirs.items():
            truth = json.loads((d / "truth.json").read_text())
            rep, wall, err = _diagnose(d, Path(tmp) / "o" / case, [])
            row = {"case": case, "wall_s": wall, "outside_library": truth.get("outside_library", False),
                   "acceptable_hint_shapes": truth.get("acceptable_hint_shapes", [])}
            if rep is None:
                rows.append({**row, "error": err})
                continue
            hints = [h["shape"] for h in rep["unexplained"]["hints"]]
            pres = [e for e in rep["ranking"] if e["verdict"] == "present"]
            row.update({"model_complete": rep["model_complete"], "hints": hints,
                        "hint_explains": [round(h["explains"], 3) for h in rep["unexplained"]["hints"]],
                        "carried_by": rep["unexplained"]["carried_by"], "present": [e["effect"] for e in pres],
                        "present_with_warning": all("warning" in e for e in pres)})
            if case in USER_FILES:
                name = USER_FILES[case]
                f = ROOT / "examples" / "effects" / f"{name}.py"
                rep2, wall2, err2 = _diagnose(d, Path(tmp) / "o" / f"{case}-user",
                                              ["--effects", str(f), "--add", name])
                if rep2 is None:
                    row["user_effect"] = {"error": err2}
                else:
                    e = next(x for x in rep2["ranking"] if x["effect"] == name)
                    tp = truth["effect_file"]["params"]
                    errs = {k: abs(e["estimate"][k]["value"] - v) / abs(v) for k, v in tp.items()}
                    row["user_effect"] = {
                        "file": f"examples/effects/{name}.py", "verdict": e["verdict"],
                        "worst_param_error": max(errs.values()), "others_present": [x for x in _present(rep2) if x != name],
                        "model_complete": rep2["model_complete"],
                        "residual_after_vs_effect_free": rep2["residual_rms_after"]["total_w"] / free_rms,
                        "wall_s": wall2}
            rows.append(row)
            print(json.dumps(row), flush=True)
    ok = [r for r in rows if "error" not in r]
    outside = [r for r in ok if r["outside_library"]]
    summary = {
        "logs": len(rows),
        "outside_incomplete": sum(1 for r in outside if r["model_complete"] is False),
        "outside_top_hint_right": sum(1 for r in outside if r["hints"] and r["hints"][0] in r["acceptable_hint_shapes"]),
        "outside_no_clean_finding": sum(1 for r in outside if r["present_with_warning"]),
        "outside": len(outside),
        "effect_free_complete": all(r["model_complete"] for r in ok if not r["outside_library"]),
        "wall_s_median": float(np.median([r["wall_s"] for r in ok])) if ok else None,
        "wall_s_max": max((r["wall_s"] for r in ok), default=None),
    }
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps({"summary": summary, "results": rows}, indent=1))
    lines = ["| case | model complete | hints (held-out share of what is left) | present (all with the warning?) | "
             "user effect: verdict, worst error, others present, complete, residual after / effect-free | wall [s] |",
             "|---|---|---|---|---|---|"]
    for r in rows:
        if "error" in r:
            lines.append(f"| {r['case']} | error: {r['error']} |")
            continue
        hs = ", ".join(f"{h} {x:.2f}" for h, x in zip(r["hints"], r["hint_explains"])) or "-"
        pres = ", ".join(r["present"]) or "-"
        u = r.get("user_effect")
        us = "-" if u is None else (f"error: {u['error']}" if "error" in u else
                                    f"{u['verdict']}, {100 * u['worst_param_error']:.1f} %, "
                                    f"{', '.join(u['others_present']) or 'none'}, {u['model_complete']}, "
                                    f"{u['residual_after_vs_effect_free']:.2f}")
        lines.append(f"| {r['case']} | {r['model_complete']} | {hs} | {pres} ({'yes' if r['present_with_warning'] else 'NO'}) "
                     f"| {us} | {r['wall_s']:.1f} |")
    lines += ["", f"Outside-library logs: incomplete {summary['outside_incomplete']}/{summary['outside']}, right top hint "
              f"{summary['outside_top_hint_right']}/{summary['outside']}, no clean library finding "
              f"{summary['outside_no_clean_finding']}/{summary['outside']}; effect-free log complete: "
              f"{summary['effect_free_complete']}; wall time per 15 s, 500 Hz log (fresh process, hints included) "
              f"median {summary['wall_s_median']:.1f} s, max {summary['wall_s_max']:.1f} s."]
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return {**summary, "cases": rows}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "outside_logs"))
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    run(Path(a.out), a.seed)


if __name__ == "__main__":
    main()
