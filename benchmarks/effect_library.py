"""The effect library's must-holds on package runs, measured with the one diagnosis pipeline
(issue 5, issue 37).

    python benchmarks/effect_library.py [--jobs 2] [--seeds 20] [--out benchmarks/results]
    python benchmarks/effect_library.py --insert-fp        # false positives on the plain insertion

Every run is diagnosed as ``kinadapt diagnose RUN --baseline BASE`` does: its trace and the set-up
generated from its config (``ownrun.as_log``), the tip calibrated on the same program's run without
a hidden effect (``ownrun.calibrated_tip``; clean, seed 0). Measures:
* every effect at its default magnitude on the excitation experiment (online/excite.toml),
  noise-free and with F/T noise (0.5 N, 0.02 N m): the injected effect's verdict and rank, its
  held-out explained fraction, the parameter error vs the injected value, the other effects
  present, and the residual fall after ``--add`` as a fraction of the excess over the same-seed
  run without the effect;
* false positives: runs without a hidden effect over ``--seeds`` seeds (start jitter +-0.5 mm,
  +-1 deg) at both noise levels: how many report any effect present;
* two effects at once (gravity + sensor rotation, stiffness + friction couple);
* the empirical confusion under the plain insertion and under the excitation experiment (the
  first effect present, else the best ranked, for each injected one).
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
NAMES = ("tool_gravity", "ft_bias_drift", "ft_frame_rotation", "tool_tilt", "contact_stiffness",
         "contact_friction_couple", "grasp_compliance", "encoder_offset")


def _run(program: str, sets: list[str]):
    """A simulated run -> (the config without its hidden effects, the run as a ``RawLog``)."""
    from kinadapt_nn.config import load_config
    from kinadapt_nn.diagnostics.importers import RawLog
    from kinadapt_nn.runs.episode import run_episode

    cfg = load_config(EXCITE if program == "excite" else None, [*QUIET, *sets])
    tr = run_episode(cfg).trace
    # the diagnosis sees the config without [effects]: the model does not know them
    return cfg.model_copy(update={"effects": type(cfg.effects)()}), RawLog(tr["t_s"], tr["q_rad"], tr["qdot_rad_s"],
                                                                           tr["wrench_raw_f"], "sim")


def baseline_tip(program: str) -> list[float]:
    """Where contacts act, calibrated on the program's run without a hidden effect (clean, seed 0)."""
    from kinadapt_nn.diagnostics import ownrun

    cfg, raw = _run(program, [])
    return [float(v) for v in ownrun.calibrated_tip(raw, cfg)]


def diagnose(job: tuple) -> dict:
    """One run + the one pipeline. job = (program, sets, add, tip)."""
    from kinadapt_nn.diagnostics import ownrun, userlog

    program, sets, add, tip = job
    cfg, raw = _run(program, sets)
    log, setup = ownrun.as_log(raw, cfg, tip_sensor_m=tip)
    rep = userlog.diagnose(log, setup, add, hints=False).report
    keep = ("ranking", "residual_rms_by_channel", "residual_rms_before", "residual_rms_after", "blocked", "warnings",
            "model_complete", "explained_by_present")
    return {"program": program, "sets": sets, "add": add, **{k: rep.get(k) for k in keep}}


def truth(name: str) -> np.ndarray:
    """The injected default magnitude in the effect's parameters (``effect_library.DEFAULTS``: the
    diagnosis's and the online model's since issue 52; one offset per joint)."""
    from kinadapt_nn.config import EffectsCfg
    from kinadapt_nn.features.effect_library import LIBRARY

    return LIBRARY[name].default(EffectsCfg())


def param_errors(name: str, p_hat: np.ndarray, p_true: np.ndarray) -> dict[str, float]:
    """Relative errors of the physical quantities the injected effect set."""
    def rel(a, b):
        return float(np.linalg.norm(a - b) / max(np.linalg.norm(b), 1e-12))

    if name == "tool_gravity":
        com_hat = p_hat[1:] / p_hat[0] if abs(p_hat[0]) > 1e-9 else np.full(3, np.inf)
        return {"mass": rel(p_hat[:1], p_true[:1]), "com": rel(com_hat, p_true[1:] / p_true[0])}
    return {"params": rel(p_hat, p_true)}


def _jobs(a: argparse.Namespace, tips: dict) -> dict[str, tuple]:
    """Every run of the benchmark: name -> (program, overrides, effects added, tip)."""
    ex = tips["excite"]
    jobs: dict[str, tuple] = {}
    for noise, nz in (("clean", []), ("noise", NOISE)):
        jobs[f"excite/none/{noise}"] = ("excite", [*nz], [], ex)
        for n in NAMES:
            jobs[f"excite/{n}/{noise}"] = ("excite", [f"effects.{n}.enabled=true", *nz], [n], ex)
        for s in range(1, a.seeds + 1):
            jobs[f"fp/excite/{noise}/{s}"] = ("excite", [f"run.seed={s}", *JITTER, *nz], [], ex)
    jobs["two/gravity+rotation"] = ("excite", ["effects.tool_gravity.enabled=true", "effects.ft_frame_rotation.enabled=true"],
                                    ["tool_gravity", "ft_frame_rotation"], ex)
    jobs["two/stiffness+friction"] = ("excite", ["effects.contact_stiffness.enabled=true",
                                                 "effects.contact_friction_couple.enabled=true"],
                                      ["contact_stiffness", "contact_friction_couple"], ex)
    if not a.skip_plain:
        jobs["insert/none/clean"] = ("insert", [], [], tips["insert"])
        for n in NAMES:
            jobs[f"insert/{n}/clean"] = ("insert", [f"effects.{n}.enabled=true"], [n], tips["insert"])
    return jobs


def _present(r) -> list[str]:
    return [x["effect"] for x in r["ranking"] if x["verdict"] == "present"]


def _top(r) -> str:
    pres = _present(r)
    return pres[0] if pres else r["ranking"][0]["effect"]


def _row_of(r, n):
    return next(x for x in r["ranking"] if x["effect"] == n)


def _table(results: dict) -> list[dict]:
    """Per (noise, injected effect): its verdict and rank, explained fraction, parameter error, the
    other effects present and how much of the residual's excess over the run without it adding it
    removes."""
    table = []
    for noise in ("clean", "noise"):
        base = results[f"excite/none/{noise}"]
        for n in NAMES:
            r = results[f"excite/{n}/{noise}"]
            e = _row_of(r, n)
            rank = [x["effect"] for x in r["ranking"]].index(n) + 1
            err = param_errors(n, np.asarray(e["estimate_params"]["value"]), truth(n)) if e.get("estimate_params") else {}
            before, after = r["residual_rms_before"]["total_w"], r["residual_rms_after"]["total_w"]
            nominal = base["residual_rms_by_channel"]["total_w"]
            fall_sse = (before**2 - after**2) / max(before**2 - nominal**2, 1e-300)
            fall_rms = (before - after) / max(before - nominal, 1e-300)
            table.append({"noise": noise, "effect": n, "rank": rank, "verdict": e["verdict"],
                          "explained_fraction": e.get("explained_fraction"), "param_error": err,
                          "also_present": [x for x in _present(r) if x != n], "blocked": r["blocked"],
                          "residual_before": before, "residual_after": after, "residual_nominal": nominal,
                          "fall_of_excess_sse": fall_sse, "fall_of_excess_rms": fall_rms})
    return table


def _false_positives(results: dict, seeds: int) -> dict:
    fp = {}
    for noise in ("clean", "noise"):
        flagged = [_present(results[f"fp/excite/{noise}/{s}"]) for s in range(1, seeds + 1)]
        fp[noise] = {"runs": len(flagged), "runs_with_any_present": sum(bool(f) for f in flagged), "flagged": flagged}
    return fp


def _markdown(table: list[dict], fp: dict, two: dict, confusion: dict) -> list[str]:
    def num(v, fmt):
        return "-" if v is None else format(v, fmt)

    lines = ["| noise | effect | verdict | rank | explained | param error | also present | residual fall (of excess, SSE / rms) |",
             "|---|---|---|---|---|---|---|---|"]
    for t in table:
        err = ", ".join(f"{k} {100 * v:.0f}%" for k, v in t["param_error"].items())
        lines.append(f"| {t['noise']} | {t['effect']} | {t['verdict']} | {t['rank']} | "
                     f"{num(t['explained_fraction'], '.2f')} | {err} | {', '.join(t['also_present']) or '-'} | "
                     f"{100 * t['fall_of_excess_sse']:.0f}% / {100 * t['fall_of_excess_rms']:.0f}% |")
    lines += ["", "False positives (runs with any effect present, no hidden effect):"]
    lines += [f"- {k}: {v['runs_with_any_present']}/{v['runs']}  {v['flagged']}" for k, v in fp.items()]
    lines += ["", "Two effects at once:"] + [f"- {k}: present {v}" for k, v in two.items()]
    for key, m in confusion.items():
        lines += ["", f"Confusion, {key}: injected -> first present (else best ranked)"]
        lines += [f"- {n} -> {v}" for n, v in m.items()]
    return lines


def insert_fp(a) -> None:
    """False positives on the plain insertion: no hidden effect, start jitter, both noise levels."""
    tip = baseline_tip("insert")
    jobs = {f"{noise}/{s}": ("insert", [f"run.seed={s}", "start.lateral_jitter_m=0.0003", "start.tilt_jitter_deg=0.5",
                                        *nz], [], tip)
            for noise, nz in (("clean", []), ("noise", NOISE)) for s in range(1, a.seeds + 1)}
    with ProcessPoolExecutor(max_workers=a.jobs) as ex:
        res = dict(zip(jobs, ex.map(diagnose, jobs.values())))
    out = {}
    for noise in ("clean", "noise"):
        flagged = [_present(r) for k, r in res.items() if k.startswith(noise)]
        out[noise] = {"runs": len(flagged), "runs_with_any_present": sum(bool(f) for f in flagged), "flagged": flagged}
        print(f"insert, {noise}: {out[noise]['runs_with_any_present']}/{out[noise]['runs']} runs with an effect present "
              f"{flagged}")
    Path(a.out).mkdir(parents=True, exist_ok=True)
    (Path(a.out) / "effect_library_insert_fp.json").write_text(json.dumps(out, indent=1))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--out", default=str(REPO / "benchmarks" / "results"))
    ap.add_argument("--skip-plain", action="store_true")
    ap.add_argument("--insert-fp", action="store_true",
                    help="only the false-positive rate on the plain insertion (seeds x noise, start jitter)")
    a = ap.parse_args()
    if a.insert_fp:
        insert_fp(a)
        return
    tips = {p: baseline_tip(p) for p in ("excite", *(() if a.skip_plain else ("insert",)))}
    jobs = _jobs(a, tips)
    keys = list(jobs)
    with ProcessPoolExecutor(max_workers=a.jobs) as ex:
        results = dict(zip(keys, ex.map(diagnose, [jobs[k] for k in keys])))
    table = _table(results)
    fp = _false_positives(results, a.seeds)
    two = {k: _present(results[k]) for k in ("two/gravity+rotation", "two/stiffness+friction")}
    confusion = {"excite": {n: _top(results[f"excite/{n}/clean"]) for n in NAMES}}
    if not a.skip_plain:
        confusion["insert"] = {n: _top(results[f"insert/{n}/clean"]) for n in NAMES}
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "effect_library.json").write_text(json.dumps({"tips_m": tips, "table": table, "false_positives": fp,
                                                          "two_effects": two, "confusion": confusion},
                                                         indent=1, default=float))
    lines = _markdown(table, fp, two, confusion)
    (out / "effect_library.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
