"""The effect-library verdicts on package runs under the one pipeline, beside the deleted own-run
pipeline's (issue 37).

    python benchmarks/onepipe_compare.py RUNS_DIR [--out benchmarks/results]

``RUNS_DIR`` holds runs of ``online/excite.toml`` (clean, seed 0): ``none`` (no hidden effect) and
one folder per library effect named after it, each made by
``kinadapt online --config online/excite.toml --out RUNS_DIR/NAME --set effects.NAME.enabled=true``
(``none``: no --set; ``--set run.tensorboard=false --set run.figure=false`` change nothing measured).
One pipeline: ``userlog.diagnose`` on ``ownrun.as_log`` with the tip calibrated on ``none``
(``ownrun.calibrated_tip``), as ``kinadapt diagnose RUN --baseline RUNS_DIR/none``. The own-run
pipeline (``diagnostics/library.py`` with the shipped calibration, deleted in issue 37) cannot run
any more: its verdicts are read from the committed ``onepipe_compare.json`` of commit 8573f33
(``OLD``), measured on the same nine runs. Prints one row per run: the injected effect, the old
significant set, the new present set, the injected effect's verdict and estimate.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import time
from pathlib import Path

NAMES = ("tool_gravity", "ft_bias_drift", "ft_frame_rotation", "tool_tilt", "contact_stiffness",
         "contact_friction_couple", "grasp_compliance", "encoder_offset")
OLD = "8573f33"  #: the commit whose onepipe_compare.json holds the own-run pipeline's verdicts
REPO = Path(__file__).resolve().parents[1]


def old_rows() -> dict:
    """The own-run pipeline's verdicts per run, from ``OLD``'s committed result."""
    text = subprocess.run(["git", "-C", str(REPO), "show", f"{OLD}:benchmarks/results/onepipe_compare.json"],
                          capture_output=True, text=True, check=True).stdout
    return {r["injected"]: {"significant": r["old_significant"], "injected": r["old"]} for r in json.loads(text)["rows"]}


def new_verdicts(run: Path, tip) -> dict:
    from kinadapt_nn.diagnostics import ownrun, userlog

    log, setup = ownrun.as_log(run, tip_sensor_m=tip)
    rep = userlog.diagnose(log, setup, hints=False).report
    out = {r["effect"]: {"verdict": r["verdict"], "estimate": (r.get("estimate_params") or {}).get("value"),
                         "sd": (r.get("estimate_params") or {}).get("sd")} for r in rep["ranking"]}
    return out | {"_model_complete": rep.get("model_complete"), "_tip_check": rep["tip_contact_check"]["ok"],
                  "_blocked": rep["blocked"], "_warnings": rep["warnings"]}


def main() -> None:
    from kinadapt_nn.diagnostics import ownrun

    ap = argparse.ArgumentParser()
    ap.add_argument("runs")
    ap.add_argument("--out", default=str(REPO / "benchmarks" / "results"))
    a = ap.parse_args()
    root = Path(a.runs)
    t0 = time.time()
    old = old_rows()
    tip = ownrun.calibrated_tip(root / "none")
    print(f"tip calibrated on none: {[round(1000 * float(v), 2) for v in tip]} mm")
    rows = []
    for name in ("none", *NAMES):
        run = root / name
        if not run.is_dir():
            continue
        new = new_verdicts(run, tip)
        new_pres = [n for n, v in new.items() if not n.startswith("_") and v["verdict"] == "present"]
        o = old.get(name, {})
        row = {"injected": name, "old_significant": o.get("significant"), "new_present": new_pres,
               "old": o.get("injected"), "new": new.get(name),
               "new_all": {n: v["verdict"] for n, v in new.items() if not n.startswith("_")},
               "new_tip_check_ok": new["_tip_check"], "new_model_complete": new["_model_complete"],
               "new_blocked": new["_blocked"], "new_warnings": new["_warnings"]}
        rows.append(row)
        agree = "-" if name == "none" else ("agree" if row["new"] and row["new"]["verdict"] == "present" else "DIFFER")
        print(f"{name:25s} old significant {o.get('significant')}  new present {new_pres}  "
              f"new verdict {row['new']['verdict'] if row['new'] else '-'}  {agree}  [{time.time() - t0:.0f} s]",
              flush=True)
    Path(a.out).mkdir(parents=True, exist_ok=True)
    (Path(a.out) / "onepipe_compare.json").write_text(json.dumps({"tip_m": [float(v) for v in tip], "old_from": OLD,
                                                                  "rows": rows}, indent=1, default=float))


if __name__ == "__main__":
    main()
