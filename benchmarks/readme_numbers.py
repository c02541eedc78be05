"""Re-measure the numbers at the top of the README with the package's own commands.

    python benchmarks/readme_numbers.py [--jobs N] [--no-foreign]

Runs, each in a fresh process exactly as a user types it (outputs in a temporary folder):

1. ``kinadapt online`` (the default run: adjoint features, the default kalman law, the paper's
   bore setting) and ``kinadapt compare`` restricted to the bore, the adjoint and the nominal tool
   family with ``laws = ["kalman", "composite"]`` (4 held-out tools, median): the default law
   against the paper's composite law.
2. ``kinadapt online --config online/identify_socket.toml``: where identification works.
3. ``kinadapt diagnose LOG --setup SETUP`` on the 24 foreign logs of ``examples/foreign_rig.py``
   (rig A as csv.gz and Parquet, rig B as csv), counted as ``benchmarks/foreign_logs.py`` counts
   them: the set of effects reported ``present`` must equal the hidden set.

4. With ``--pretrain`` (or ``--only-pretrain``): ``kinadapt pretrain`` with its default config, timed
   as a user waits for it.

Prints the machine first and one block per headline. About 2 min on an idle 2-core VM
(``--no-foreign``: about 30 s; ``--pretrain``: about 65 s more).
"""

from __future__ import annotations

import argparse
import csv
import importlib.util
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

COMPARE_TOML = """\
features = ["adjoint"]
families = ["nominal"]
laws = ["kalman", "composite"]
jobs = {jobs}
[scenarios]
bore = []
"""


def _cli(*args: str) -> subprocess.CompletedProcess:
    """``kinadapt ARGS`` in a fresh process, from the repository root."""
    return subprocess.run([sys.executable, "-m", "kinadapt_nn.app.cli", *args], cwd=ROOT, capture_output=True, text=True)


def _summary(out: Path) -> dict:
    return json.loads((out / "summary.json").read_text())


def _pct(x: float) -> str:
    return f"{100 * x:.2f} %"


def machine() -> str:
    gpu = "none visible"
    try:
        import torch

        if torch.cuda.is_available():
            gpu = torch.cuda.get_device_name(0)
    except Exception:  # torch is a dependency, but the machine line must not fail on it
        gpu = "unknown"
    return (f"machine: processor={platform.processor() or platform.machine()!r} cpu_count={os.cpu_count()} "
            f"platform={platform.platform()} python={platform.python_version()} gpu={gpu}")


def headline_default(tmp: Path, jobs: int) -> list[str]:
    out = tmp / "default"
    p = _cli("online", "--out", str(out), "--quiet")
    if p.returncode not in (0, 1):
        raise RuntimeError(f"kinadapt online failed: {p.stderr.strip()}")
    s = _summary(out)
    err = np.asarray(s["offset_error_final_m"]) * 1e3
    paper = tmp / "paper_contact"
    p = _cli("online", "--set", "scene.contact_friction_timeconst_s=0", "--out", str(paper), "--quiet")
    if p.returncode not in (0, 1):
        raise RuntimeError(f"kinadapt online (the paper's contact) failed: {p.stderr.strip()}")
    sp = _summary(paper)
    lines = ["[1] kinadapt online  (default config: adjoint, kalman law, the bore with its rattle-free contact)",
             f"    contact transitions per s {s['contact_transitions_per_s']:.1f} (with the paper's contact, "
             f"scene.contact_friction_timeconst_s=0: {sp['contact_transitions_per_s']:.1f}, seated={sp['success']})",
             f"    seated={s['success']} seat_time_s={s['seat_time_s']:.3f} max|F|={s['max_force_N']:.2f} N "
             f"max|F_lat|={s['max_lateral_force_N']:.2f} N max|M|={s['max_moment_Nm']:.2f} N m "
             f"min_lambda_JJt={s['min_lambda_JJt']:.1f}",
             f"    sensor depth {1e3 * s['final_depth_m']:.2f} mm vs true tip depth "
             f"{1e3 * s['true_final_depth_m']:.2f} mm; "
             f"offset error [{err[0]:+.2f}, {err[1]:+.2f}, {err[2]:+.2f}] mm",
             f"    jacobian error {_pct(s['jacobian_rel_error_initial'])} -> {_pct(s['jacobian_rel_error_final'])}; "
             f"identification: {s['identification']['text']}"]
    cfg = tmp / "compare_bore.toml"
    cfg.write_text(COMPARE_TOML.format(jobs=jobs))
    cout = tmp / "compare"
    p = _cli("compare", "--config", str(cfg), "--out", str(cout), "--quiet")
    if p.returncode:
        raise RuntimeError(f"kinadapt compare failed: {p.stderr.strip()}")
    with open(cout / "comparison.csv", newline="") as fh:
        rows = {r["law"]: r for r in csv.DictReader(fh)}
    k, c = rows["kalman"], rows["composite"]

    def errs(r: dict) -> str:
        return (f"{_pct(float(r['jacobian_rel_error_initial_median']))} -> "
                f"{_pct(float(r['jacobian_rel_error_final_median']))}")

    lines += ["    kinadapt compare, bore, adjoint, nominal family (median of "
              f"{k['episodes']} held-out tools):",
              f"      kalman    success {float(k['success_rate']):.2f}  jacobian error {errs(k)}",
              f"      composite success {float(c['success_rate']):.2f}  jacobian error {errs(c)}"
              f"  ({float(c['jacobian_rel_error_final_median']) / float(k['jacobian_rel_error_final_median']):.1f}x "
              "the kalman law's final error)"]
    return lines


def headline_socket(tmp: Path) -> list[str]:
    out = tmp / "socket"
    p = _cli("online", "--config", "online/identify_socket.toml", "--out", str(out), "--quiet")
    if p.returncode not in (0, 1):
        raise RuntimeError(f"kinadapt online --config online/identify_socket.toml failed: {p.stderr.strip()}")
    s = _summary(out)
    e = np.asarray(s["offset_error_final_m"]) * 1e3
    return ["[3] kinadapt online --config online/identify_socket.toml  (socket contact + 0.05 rad/s dither)",
            f"    seated={s['success']} seat_time_s={s['seat_time_s']:.3f}; "
            f"identification: {s['identification']['text']}",
            f"    lateral offset error {1e3 * s['offset_error_lateral_initial_m']:.2f} mm -> "
            f"{1e3 * s['offset_error_lateral_final_m']:.2f} mm "
            f"(axial {abs(e[2]):.3f} mm); jacobian error {_pct(s['jacobian_rel_error_initial'])} -> "
            f"{_pct(s['jacobian_rel_error_final'])}"]


def _load(name: str, path: Path):
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod


def headline_foreign(tmp: Path, jobs: int) -> list[str]:
    rig = _load("foreign_rig", ROOT / "examples" / "foreign_rig.py")
    jobs_list = []  # (rig, case, format, log, setup, truth)
    for rig_name, cases in (("A", rig.CASES), ("B", rig.CASES_B)):
        for case in cases:
            d = rig.make_case(case, tmp / "foreign" / rig_name, seed=0, rig=rig_name)
            truth = json.loads((d / "truth.json").read_text())
            if (d / "log.csv.gz").exists():
                variants = [("csv.gz", "log.csv.gz", "setup_csv.toml"),
                            ("parquet", "log.parquet", "setup_parquet.toml")]
            else:
                variants = [("csv", "log.csv", "setup.toml")]
            for fmt, log, setup in variants:
                jobs_list.append((rig_name, case, fmt, d / log, d / setup, truth))

    def one(job):
        rig_name, case, fmt, log, setup, truth = job
        out = tmp / "foreign_out" / rig_name / case / fmt
        t0 = time.perf_counter()
        p = _cli("diagnose", str(log), "--setup", str(setup), "--out", str(out), "--quiet")
        wall = time.perf_counter() - t0
        if p.returncode:
            return rig_name, case, fmt, None, False, wall
        rep = json.loads((out / "diagnosis.json").read_text())
        present = sorted(e["effect"] for e in rep["ranking"] if e["verdict"] == "present")
        want = sorted(truth["effects"]) if truth.get("detectable", True) else []
        return rig_name, case, fmt, present, present == want and rep.get("model_complete") is True, wall

    with ThreadPoolExecutor(max_workers=jobs) as ex:
        res = list(ex.map(one, jobs_list))
    right = sum(r[4] for r in res)
    lines = ["[2] kinadapt diagnose LOG --setup SETUP  (examples/foreign_rig.py: rig A csv.gz + Parquet, rig B csv)",
             f"    right set of present effects and model_complete: {right}/{len(res)} logs "
             f"(wall per log median {np.median([r[5] for r in res]):.1f} s with {jobs} in parallel)"]
    lines += [f"    WRONG: rig {r[0]} {r[1]} {r[2]}: present {r[3]}" for r in res if not r[4]]
    out = _load("outside_logs", ROOT / "benchmarks" / "outside_logs.py").run(tmp / "outside_logs", seed=0)
    lines += ["[2b] physics outside the library (benchmarks/outside_logs.py, one log at a time)",
              f"    incomplete {out['outside_incomplete']}/{out['outside']}, right top hint "
              f"{out['outside_top_hint_right']}/{out['outside']}, no clean library finding "
              f"{out['outside_no_clean_finding']}/{out['outside']}, effect-free complete {out['effect_free_complete']}; "
              f"wall per 15 s 500 Hz log max {out['wall_s_max']:.1f} s"]
    ue = [c["user_effect"] for c in out.get("cases", []) if c.get("user_effect")]
    if ue:
        ratios = [u["residual_after_vs_effect_free"] for u in ue]
        lines.append(f"    the user's own effect file: present {sum(u['verdict'] == 'present' for u in ue)}/{len(ue)}, "
                     f"model complete {sum(bool(u['model_complete']) for u in ue)}/{len(ue)}, worst parameter error "
                     f"{100 * max(u['worst_param_error'] for u in ue):.1f} %, residual after / effect-free "
                     f"{min(ratios):.2f}-{max(ratios):.2f}x")
    cal = _load("calibration_logs", ROOT / "benchmarks" / "calibration_logs.py").run(
        ["ur5e", "iiwa14"], None, 0, None, None)
    w = cal["unknown_mount_worst"]
    lines += ["[2c] real-log kinds (benchmarks/calibration_logs.py: UR5e DH/URDF, iiwa14 DH; static poses, no clock, "
              "unknown mounts, N mm)",
              f"    right verdicts {cal['right_present_set']}/{cal['logs']}; unknown mount vs an independent calibration "
              f"(worst of {w['logs']}): rotation {w['rotation_deg']:.3f} deg, mass {w['mass_pct']:.3f} %, COM "
              f"{w['com_mm']:.3f} mm, force residual {w['force_residual_ratio']:.2f}x; wall per log median "
              f"{cal['wall_s_median']:.1f} s, max {cal['wall_s_max']:.1f} s"]
    return lines


def headline_pretrain(tmp: Path) -> list[str]:
    """``kinadapt pretrain`` with its default config (pretrain/default.toml): how long a user waits
    (the whole command, a fresh process) and what the checkpoint reaches."""
    out = tmp / "pretrain"
    t0 = time.perf_counter()
    p = _cli("pretrain", "--out", str(out), "--quiet")
    wall = time.perf_counter() - t0
    if p.returncode:
        raise RuntimeError(f"kinadapt pretrain failed: {p.stderr.strip()}")
    m = json.loads((out / "metrics.json").read_text())
    return ["[4] kinadapt pretrain  (pretrain/default.toml)",
            (f"    {m['steps']} steps on {m['device']}: the command {wall:.0f} s (training {m['wall_time_s']:.0f} s); "
             f"held-out Jacobian error (median) {m['heldout_rel_jacobian_error_median']:.2g}")]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="parallel processes (default: all cores)")
    ap.add_argument("--no-foreign", action="store_true", help="skip the 24 foreign-log diagnoses")
    ap.add_argument("--pretrain", action="store_true", help="also time kinadapt pretrain (about 65 s more)")
    ap.add_argument("--only-pretrain", action="store_true", help="time kinadapt pretrain only")
    ap.add_argument("--save", type=Path, help="also write what it prints to this file (the README's headline list is "
                                                 "traced to benchmarks/results/readme_numbers.txt by docs_check)")
    a = ap.parse_args()
    if a.jobs < 1:
        ap.error("--jobs must be >= 1")
    t0 = time.perf_counter()
    saved: list[str] = []

    def say(text: str) -> None:
        print(text, flush=True)
        saved.append(text)
    say(f"{machine()}; {time.strftime('%Y-%m-%d')}")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        blocks = [lambda: headline_default(tmp, a.jobs),
                  lambda: [] if a.no_foreign else headline_foreign(tmp, a.jobs),
                  lambda: headline_socket(tmp)]
        if a.only_pretrain:
            blocks = []
        if a.pretrain or a.only_pretrain:
            blocks.append(lambda: headline_pretrain(tmp))
        for block in blocks:
            lines = block()
            if lines:
                say("\n".join(lines))
    say(f"total wall {time.perf_counter() - t0:.0f} s")
    if a.save:
        a.save.write_text("\n".join(saved) + "\n")


if __name__ == "__main__":
    main()
