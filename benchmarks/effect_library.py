"""The effect library's must-holds, measured (issue 5), and the shipped nominal calibration.

    python benchmarks/effect_library.py --calibrate        # writes models/nominal_calibration.json
    python benchmarks/effect_library.py [--jobs 2] [--seeds 20] [--out benchmarks/results]
    python benchmarks/effect_library.py --insert-fp        # false positives on the plain insertion

Measures, with the shipped calibration:
* every effect at its default magnitude on the excitation experiment (online/excite.toml),
  noise-free and with F/T noise (0.5 N, 0.02 N m): rank, held-out explained fraction, adjusted
  p, parameter error vs the injected value, and the residual fall after ``--add`` as a fraction
  of the excess over the same-seed run without the effect;
* false positives: runs without a hidden effect over ``--seeds`` seeds (start jitter +-0.5 mm,
  +-1 deg) at both noise levels: how many report any significant effect;
* two effects at once (gravity + sensor rotation, stiffness + friction couple);
* the empirical confusion under the plain insertion and under the excitation experiment (the
  top-ranked effect for each injected one) and the regressor-overlap confusion of one run each.
Results: ``OUT/effect_library.json`` and ``OUT/effect_library.md``.
"""

from __future__ import annotations

import argparse
import json
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
EXCITE = REPO / "online" / "excite.toml"
NOISE = ["faults.ft_noise_N=0.5", "faults.ft_noise_Nm=0.02"]
QUIET = ["run.tensorboard=false", "run.figure=false", "run.progress=false"]
JITTER = ["start.lateral_jitter_m=0.0005", "start.tilt_jitter_deg=1.0"]


def _config(program: str, sets: list[str]):
    from kinadapt_nn.config import load_config

    return load_config(EXCITE if program == "excite" else None, [*QUIET, *sets])


def _signals(program: str, sets: list[str]):
    from kinadapt_nn.diagnostics.library import signals_of
    from kinadapt_nn.diagnostics.importers import RawLog
    from kinadapt_nn.runs.episode import run_episode

    cfg = _config(program, sets)
    tr = run_episode(cfg).trace
    log = RawLog(tr["t_s"], tr["q_rad"], tr["qdot_rad_s"], tr["wrench_raw_f"], None, "sim")
    # the diagnosis sees the config without [effects]: the model does not know them
    return cfg.model_copy(update={"effects": type(cfg.effects)()}), signals_of(log, cfg)


def diagnose(job: tuple) -> dict:
    """One run + diagnosis. job = (program, sets, add)."""
    from kinadapt_nn.diagnostics import ranking as rk
    from kinadapt_nn.diagnostics.library import analyse_effects, design_of

    program, sets, add = job
    cfg, sig = _signals(program, sets)
    calib = rk.load_calibration(rk.DEFAULT_CALIBRATION, program)
    rc = rk.RankCfg()
    res = analyse_effects(design_of(sig, cfg, rc), calib, add, rc)
    res.pop("_series", None)
    return {"program": program, "sets": sets, "add": add, **res}


def calibrate() -> None:
    from kinadapt_nn.diagnostics import ranking as rk
    from kinadapt_nn.diagnostics.library import design_of, save_calibration

    rc = rk.RankCfg()
    for program in ("insert", "excite"):
        cfg, sig = _signals(program, [])
        calib = rk.calibrate(design_of(sig, cfg, rc), rc)
        save_calibration(rk.DEFAULT_CALIBRATION, program, calib,
                         f"benchmarks/effect_library.py --calibrate: {program}, seed 0, no hidden effect")
        print(program, json.dumps(calib))


def insert_fp(a) -> None:
    """False positives on the plain insertion: no hidden effect, start jitter, both noise levels."""
    jobs = {f"{noise}/{s}": ("insert", [f"run.seed={s}", "start.lateral_jitter_m=0.0003", "start.tilt_jitter_deg=0.5", *nz], [])
            for noise, nz in (("clean", []), ("noise", NOISE)) for s in range(1, a.seeds + 1)}
    with ProcessPoolExecutor(max_workers=a.jobs) as ex:
        res = dict(zip(jobs, ex.map(diagnose, jobs.values())))
    out = {}
    for noise in ("clean", "noise"):
        flagged = [[x["effect"] for x in r["ranking"] if x["significant"]] for k, r in res.items() if k.startswith(noise)]
        out[noise] = {"runs": len(flagged), "runs_with_any_significant": sum(bool(f) for f in flagged), "flagged": flagged}
        print(f"insert, {noise}: {out[noise]['runs_with_any_significant']}/{out[noise]['runs']} runs with a significant effect "
              f"{flagged}")
    Path(a.out).mkdir(parents=True, exist_ok=True)
    (Path(a.out) / "effect_library_insert_fp.json").write_text(json.dumps(out, indent=1))


def _jobs(a: argparse.Namespace, names: list[str]) -> dict[str, tuple]:
    """Every run of the benchmark: name -> (program, overrides, effects added)."""
    jobs: dict[str, tuple] = {}
    for noise, nz in (("clean", []), ("noise", NOISE)):
        jobs[f"excite/none/{noise}"] = ("excite", [*nz], [])
        for n in names:
            jobs[f"excite/{n}/{noise}"] = ("excite", [f"effects.{n}.enabled=true", *nz], [n])
        for s in range(1, a.seeds + 1):
            jobs[f"fp/excite/{noise}/{s}"] = ("excite", [f"run.seed={s}", *JITTER, *nz], [])
    jobs["two/gravity+rotation"] = ("excite", ["effects.tool_gravity.enabled=true", "effects.ft_frame_rotation.enabled=true"],
                                    ["tool_gravity", "ft_frame_rotation"])
    jobs["two/stiffness+friction"] = ("excite", ["effects.contact_stiffness.enabled=true",
                                                 "effects.contact_friction_couple.enabled=true"],
                                      ["contact_stiffness", "contact_friction_couple"])
    if not a.skip_plain:
        jobs["insert/none/clean"] = ("insert", [], [])
        for n in names:
            jobs[f"insert/{n}/clean"] = ("insert", [f"effects.{n}.enabled=true"], [n])
    return jobs


def _top(r):
    return r["ranking"][0]["effect"]


def _row_of(r, n):
    return next(x for x in r["ranking"] if x["effect"] == n)


def _table(results: dict, names: list[str]) -> list[dict]:
    """Per (noise, injected effect): its rank, explained fraction, significance, parameter error
    and how much of the residual's excess over the nominal level adding it removes."""
    from kinadapt_nn.config import EffectsCfg
    from kinadapt_nn.diagnostics.effects import headline_errors
    from kinadapt_nn.features.effect_library import LIBRARY

    table = []
    for noise in ("clean", "noise"):
        base = results[f"excite/none/{noise}"]
        for n in names:
            r = results[f"excite/{n}/{noise}"]
            e = _row_of(r, n)
            rank = [x["effect"] for x in r["ranking"]].index(n) + 1
            p_true = LIBRARY[n].default(EffectsCfg())
            err = headline_errors(n, np.asarray(e["estimate_params"]["value"]), p_true)
            before, after = r["residual_rms_before"]["total_w"], r["residual_rms_after"]["total_w"]
            nominal = base["residual_level_rms"]["total_w"]
            # fall as a share of the excess, in SSE terms (rms^2), and in rms terms
            fall_sse = (before**2 - after**2) / max(before**2 - nominal**2, 1e-300)
            fall_rms = (before - after) / max(before - nominal, 1e-300)
            table.append({"noise": noise, "effect": n, "rank": rank, "explained_fraction": e["explained_fraction"],
                          "p_adjusted": e["p_adjusted"], "significant": e["significant"], "verdict": e["verdict"],
                          "param_error": err, "residual_before": before, "residual_after": after,
                          "residual_nominal": nominal, "fall_of_excess_sse": fall_sse, "fall_of_excess_rms": fall_rms,
                          "excitation_ratio": e["excitation"]["ratio"]})
    return table


def _false_positives(results: dict, seeds: int) -> dict:
    fp = {}
    for noise in ("clean", "noise"):
        runs = [results[f"fp/excite/{noise}/{s}"] for s in range(1, seeds + 1)]
        flagged = [[x["effect"] for x in r["ranking"] if x["significant"]] for r in runs]
        fp[noise] = {"runs": len(runs), "runs_with_any_significant": sum(bool(f) for f in flagged), "flagged": flagged}
    return fp


def _two_effects(results: dict) -> dict:
    two = {}
    for k in ("two/gravity+rotation", "two/stiffness+friction"):
        r = results[k]
        two[k] = {"significant": [x["effect"] for x in r["ranking"] if x["significant"]],
                  "top2": [x["effect"] for x in r["ranking"][:2]],
                  "estimates": {n: _row_of(r, n)["estimate"] for n in r["add"]}}
    return two


def _confusion(results: dict, names: list[str], plain: bool) -> dict:
    confusion = {"excite_empirical_top1": {n: _top(results[f"excite/{n}/clean"]) for n in names},
                 "excite_regressor_overlap": results["excite/none/clean"]["confusion"]}
    if plain:
        confusion["insert_empirical_top1"] = {n: _top(results[f"insert/{n}/clean"]) for n in names}
        confusion["insert_regressor_overlap"] = results["insert/none/clean"]["confusion"]
        confusion["insert_rows"] = {n: {k: _row_of(results[f"insert/{n}/clean"], n)[k] for k in
                                        ("explained_fraction", "significant", "p_adjusted")}
                                    for n in names}
    return confusion


def _markdown(table: list[dict], fp: dict, two: dict, confusion: dict, names: list[str]) -> list[str]:
    lines = ["| noise | effect | rank | explained | p_adj | significant | verdict | param error | residual fall (of excess, SSE / rms) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for t in table:
        err = ", ".join(f"{k} {100 * v:.0f}%" for k, v in t["param_error"].items())
        lines.append(f"| {t['noise']} | {t['effect']} | {t['rank']} | {t['explained_fraction']:.2f} | {t['p_adjusted']:.1e} | "
                     f"{t['significant']} | {t['verdict']} | {err} | {100 * t['fall_of_excess_sse']:.0f}% / {100 * t['fall_of_excess_rms']:.0f}% |")
    lines += ["", "False positives (runs with any significant effect, no hidden effect):"]
    for k, v in fp.items():
        lines.append(f"- {k}: {v['runs_with_any_significant']}/{v['runs']}  {v['flagged']}")
    lines += ["", "Two effects at once:"] + [f"- {k}: significant {v['significant']}" for k, v in two.items()]
    for key in [k for k in confusion if k.endswith("top1")]:
        lines += ["", f"Confusion, {key}: injected -> ranked first"] + [f"- {n} -> {m}" for n, m in confusion[key].items()]
    for key in [k for k in confusion if k.endswith("overlap")]:
        m = confusion[key]
        lines += ["", f"Regressor overlap ({key}): share of row effect's default signature fitted by column effect",
                  "| | " + " | ".join(n[:10] for n in names) + " |", "|---" * (len(names) + 1) + "|"]
        for n in names:
            lines.append(f"| {n} | " + " | ".join("-" if m[n][c] is None else f"{m[n][c]:.2f}" for c in names) + " |")
    return lines


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--calibrate", action="store_true")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--out", default=str(REPO / "benchmarks" / "results"))
    ap.add_argument("--skip-plain", action="store_true")
    ap.add_argument("--insert-fp", action="store_true",
                    help="only the false-positive rate on the plain insertion (seeds x noise, start jitter)")
    a = ap.parse_args()
    if a.calibrate:
        calibrate()
        return
    if a.insert_fp:
        insert_fp(a)
        return
    from kinadapt_nn.features.effect_library import LIBRARY

    names = list(LIBRARY)
    jobs = _jobs(a, names)
    keys = list(jobs)
    with ProcessPoolExecutor(max_workers=a.jobs) as ex:
        results = dict(zip(keys, ex.map(diagnose, [jobs[k] for k in keys])))
    table = _table(results, names)
    fp = _false_positives(results, a.seeds)
    two = _two_effects(results)
    confusion = _confusion(results, names, not a.skip_plain)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "effect_library.json").write_text(json.dumps({"table": table, "false_positives": fp, "two_effects": two,
                                                          "confusion": confusion}, indent=1, default=float))
    lines = _markdown(table, fp, two, confusion, names)
    (out / "effect_library.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
