"""Foreign logs through ``kinadapt diagnose LOG --setup``: the confusion table (case x effect
verdict), parameter errors and the wall time per log, for rig A (csv.gz and Parquet) and, when
``examples/foreign_rig.py`` offers it, rig B.

    python benchmarks/foreign_logs.py [--rigs A B] [--out benchmarks/results/foreign_logs]

Each log is diagnosed by the CLI in a fresh process (what a user runs; the time includes Python's
start and the imports). Writes ``foreign_logs.json`` and ``foreign_logs.md``.
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
from kinadapt_nn.effects.builtin import BUILTINS  # noqa: E402  (the one registry of effect names)

EFFECTS = tuple(BUILTINS)
SHORT = {"present": "P", "absent": ".", "cannot_decide": "?", None: "-"}


def _rig():
    spec = importlib.util.spec_from_file_location("foreign_rig", ROOT / "examples" / "foreign_rig.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules["foreign_rig"] = mod
    spec.loader.exec_module(mod)
    return mod


def _errors(truth: dict, rep: dict) -> dict:
    """Worst relative error (absolute in deg for rotations) of each true effect's parameters."""
    out = {}
    for name, params in truth.items():
        e = next((x for x in rep["ranking"] if x["effect"] == name), None)
        if e is None:
            continue
        errs = []
        for k, v in params.items():
            if k not in e["estimate"]:
                errs.append(float("inf"))
                continue
            got = e["estimate"][k]["value"]
            if name == "ft_frame_rotation":
                errs.append(abs(got - v))
            elif name == "tool_inertia":  # relative to the tensor's largest entry (off-diagonals may be 0)
                errs.append(abs(got - v) / max(max(abs(x) for x in params.values()), 1e-12))
            elif name == "tool_gravity" and k.startswith("com"):
                errs.append(abs(got - v) / max(np.linalg.norm([params[c] for c in ("com_x", "com_y", "com_z")]), 1e-9))
            else:
                errs.append(abs(got - v) / max(abs(v), 1e-12))
        out[name] = max(errs) if errs else None
    return out


def run(rigs: list[str], out: Path) -> dict:
    rig = _rig()
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        for rig_name in rigs:
            kw = {} if rig_name == "A" else {"rig": rig_name}
            cases = rig.CASES if rig_name == "A" else getattr(rig, "CASES_B", {})
            for case in cases:
                try:
                    d = rig.make_case(case, Path(tmp) / rig_name, seed=0, **kw)
                except TypeError:
                    print(f"rig {rig_name}: not offered by examples/foreign_rig.py", file=sys.stderr)
                    break
                truth = json.loads((d / "truth.json").read_text())
                variants = [("csv.gz", "log.csv.gz", "setup_csv.toml"), ("parquet", "log.parquet", "setup_parquet.toml")]
                if not (d / "log.csv.gz").exists():
                    variants = [("csv", "log.csv", "setup.toml")]
                for fmt, log, setup in variants:
                    o = Path(tmp) / "out" / rig_name / case / fmt
                    t0 = time.perf_counter()
                    p = subprocess.run([sys.executable, "-m", "kinadapt_nn.app.cli", "diagnose", str(d / log), "--setup",
                                        str(d / setup), "--out", str(o), "--quiet"], capture_output=True, text=True)
                    wall = time.perf_counter() - t0
                    if p.returncode:
                        results.append({"rig": rig_name, "case": case, "format": fmt, "error": p.stderr.strip()})
                        continue
                    rep = json.loads((o / "diagnosis.json").read_text())
                    tr = truth.get("truth_parquet", truth["effects"]) if fmt == "parquet" else truth["effects"]
                    v = {e["effect"]: e["verdict"] for e in rep["ranking"]}
                    results.append({"rig": rig_name, "case": case, "format": fmt, "truth": sorted(truth["effects"]),
                                    "detectable": truth.get("detectable", True), "verdicts": v,
                                    "present": sorted(n for n, x in v.items() if x == "present"),
                                    "ties": {e["effect"]: e["indistinguishable_from"] for e in rep["ranking"]
                                             if e.get("indistinguishable_from")},
                                    "param_error": _errors(tr, rep) if truth.get("detectable", True) else {},
                                    "wall_s": wall, "model_complete": rep.get("model_complete"),
                                    "warnings": rep.get("warnings", [])})
                    print(f"{rig_name} {case:24s} {fmt:8s} present {results[-1]['present']} "
                          f"errors {results[-1]['param_error']} {wall:.1f} s", flush=True)
    ok = [r for r in results if "error" not in r]
    right = [r for r in ok if r["present"] == (sorted(r["truth"]) if r["detectable"] else [])]
    complete = [r for r in ok if r.get("model_complete")]
    summary = {"logs": len(results), "right_present_set": len(right), "failed_runs": len(results) - len(ok),
               "model_complete": len(complete),
               "wall_s_max": max((r["wall_s"] for r in ok), default=None),
               "wall_s_median": float(np.median([r["wall_s"] for r in ok])) if ok else None}
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps({"summary": summary, "results": results}, indent=1))
    lines = ["| rig | case | format | " + " | ".join(EFFECTS) + " | model complete | worst param error | wall [s] |",
             "|---|---|---|" + "---|" * len(EFFECTS) + "---|---|---|"]
    for r in results:
        if "error" in r:
            lines.append(f"| {r['rig']} | {r['case']} | {r['format']} | error: {r['error']} |")
            continue
        errs = ", ".join(f"{k} {v:.2g}{' deg' if k == 'ft_frame_rotation' else ''}" for k, v in r["param_error"].items()
                         if v is not None)
        lines.append(f"| {r['rig']} | {r['case']} | {r['format']} | "
                     + " | ".join(SHORT[r["verdicts"].get(e)] for e in EFFECTS)
                     + f" | {'yes' if r.get('model_complete') else 'NO'} | {errs or '-'} | {r['wall_s']:.1f} |")
    lines += ["", "P present, ? cannot_decide, . absent, - not judged for this set-up.",
              f"Right set of present effects: {summary['right_present_set']}/{summary['logs']}; model complete (no "
              f"false alarm): {summary['model_complete']}/{summary['logs']}; "
              f"wall time per log (fresh process) median {summary['wall_s_median']:.1f} s, max {summary['wall_s_max']:.1f} s."]
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return summary


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rigs", nargs="+", default=["A", "B"])
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "foreign_logs"))
    a = ap.parse_args()
    run(a.rigs, Path(a.out))


if __name__ == "__main__":
    main()
