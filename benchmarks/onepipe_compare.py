"""The effect-library verdicts on package runs, old pipeline against the one pipeline (issue 37).

    python benchmarks/onepipe_compare.py RUNS_DIR [--out benchmarks/results]

``RUNS_DIR`` holds runs of ``online/excite.toml`` (clean, seed 0): ``none`` (no hidden effect) and
one folder per library effect named after it, each made by
``kinadapt online --config online/excite.toml --out RUNS_DIR/NAME --set effects.NAME.enabled=true``
(``none``: no --set). Old: ``library.analyse_effects`` with the shipped calibration (as
``benchmarks/effect_library.py``). New: ``userlog.diagnose`` on ``ownrun.as_log`` with the tip
calibrated on ``none`` (``ownrun.calibrated_tip``). Prints one row per run: the injected effect,
the old significant set, the new present set, the injected effect's verdict and estimate in both.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

NAMES = ("tool_gravity", "ft_bias_drift", "ft_frame_rotation", "tool_tilt", "contact_stiffness",
         "contact_friction_couple", "grasp_compliance", "encoder_offset")


def old_verdicts(run: Path) -> dict:
    from kinadapt_nn.config import load_config
    from kinadapt_nn.diagnostics import ranking as rk
    from kinadapt_nn.diagnostics.library import analyse_effects, design_of, signals_of

    cfg = load_config(run / "config.toml")
    cfg = cfg.model_copy(update={"effects": type(cfg.effects)()})
    rc = rk.RankCfg()
    calib = rk.load_calibration(rk.DEFAULT_CALIBRATION, "excite")
    res = analyse_effects(design_of(signals_of(run, cfg), cfg, rc), calib, [], rc)
    return {r["effect"]: {"verdict": r.get("verdict"), "significant": r["significant"],
                          "estimate": r["estimate_params"]["value"]} for r in res["ranking"]}


def new_verdicts(run: Path, tip) -> dict:
    from kinadapt_nn.diagnostics import ownrun, userlog

    log, setup = ownrun.as_log(run, tip_sensor_m=tip)
    rep = userlog.diagnose(log, setup, hints=False).report
    return {r["effect"]: {"verdict": r["verdict"], "estimate": (r.get("estimate_params") or {}).get("value")}
            for r in rep["ranking"]} | {"_model_complete": rep.get("model_complete"),
                                        "_tip_check": rep["tip_contact_check"]["ok"]}


def main() -> None:
    from kinadapt_nn.diagnostics import ownrun

    ap = argparse.ArgumentParser()
    ap.add_argument("runs")
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent / "results"))
    a = ap.parse_args()
    root = Path(a.runs)
    t0 = time.time()
    tip = ownrun.calibrated_tip(root / "none")
    print(f"tip calibrated on none: {[round(1000 * v, 2) for v in tip]} mm")
    rows = []
    for name in ("none", *NAMES):
        run = root / name
        if not run.is_dir():
            continue
        old, new = old_verdicts(run), new_verdicts(run, tip)
        old_sig = [n for n, v in old.items() if v["significant"]]
        new_pres = [n for n, v in new.items() if not n.startswith("_") and v["verdict"] == "present"]
        row = {"injected": name, "old_significant": old_sig, "new_present": new_pres,
               "old": old.get(name), "new": new.get(name), "new_all": {n: v["verdict"] for n, v in new.items()
                                                                    if not n.startswith("_")},
               "new_tip_check_ok": new["_tip_check"]}
        rows.append(row)
        print(f"{name:25s} old significant {old_sig}  new present {new_pres}  "
              f"new verdict {row['new']['verdict'] if row['new'] else '-'}  [{time.time() - t0:.0f} s]", flush=True)
    Path(a.out).mkdir(parents=True, exist_ok=True)
    (Path(a.out) / "onepipe_compare.json").write_text(json.dumps({"tip_m": list(map(float, tip)), "rows": rows},
                                                                  indent=1, default=float))


if __name__ == "__main__":
    main()
