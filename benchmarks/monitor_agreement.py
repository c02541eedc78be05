"""The live monitor against ``kinadapt diagnose`` of the same run (issue 53; docs/monitor.md "Agreement
with the offline diagnosis").

    python benchmarks/monitor_agreement.py [--seeds 3] [--scenarios payload snag] [--no-segment]
                                           [--save benchmarks/results/monitor_agreement.txt]

For each scenario of ``benchmarks/monitor_events.py`` (payload, drift, frame rotation, snag, slip on
``online/monitor.toml``, each effect at its default size, its onset drawn uniformly in [1, 4] s from the
seed) and each seed: ``kinadapt online --monitor`` into a run folder, then ``kinadapt diagnose`` of that
folder; the monitor's open events at the end of the run and the diagnosis's present effects and leading
hint are compared through ``kinadapt_nn.monitor.agreement`` (one map between the two vocabularies; they
agree when the name sets are equal). The offline diagnosis takes an effect as present through the whole
log, while these effects start mid-run; so, unless ``--no-segment``, the log from the monitor's first
open event's onset on (the first 20 ms after it left out, as the monitor does) is diagnosed too, where
that assumption holds. Prints per scenario how many seeds agree and, for those that do not, what each
side said.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from kinadapt_nn.app.cli import main as cli  # noqa: E402
from kinadapt_nn.monitor.agreement import agreement  # noqa: E402

#: scenario -> (the truth-side effect, the monitor's shape that names it): benchmarks/monitor_events.py's five
SCENARIOS = {"payload": ("tool_gravity", "tool_gravity"), "drift": ("ft_bias_drift", "ft_bias_drift"),
             "frame rotation": ("ft_frame_rotation", "ft_frame_rotation"), "snag": ("world_force", "world_force"),
             "slip": ("grasp_slip", "tool_tilt")}
#: [s] after the onset, left out of the segment's diagnosis (the monitor's SETTLE_S: the arm's transient)
SETTLE_S = 0.02


def onset_of(seed: int) -> float:
    """The scenario's onset [s] of seed ``seed`` (as ``benchmarks/monitor_events.py`` draws it)."""
    return float(np.random.default_rng(seed).uniform(1.0, 4.0))


def run_and_diagnose(name: str, seed: int, work: Path, extra: list[str] = ()) -> dict:
    """One seed of scenario ``name``: the run with ``--monitor``, its diagnosis; -> the run's monitor
    summary, the diagnosis's report and the run folder."""
    effect, _shape = SCENARIOS[name]
    run, dia = work / f"{effect}-{seed}", work / f"{effect}-{seed}-diagnosis"
    sets = [f"run.seed={seed}", f"effects.{effect}.enabled=true", f"effects.{effect}.onset_s={onset_of(seed)}",
            "run.tensorboard=false", "run.figure=false", *extra]
    rc = cli(["online", "--config", str(REPO / "online" / "monitor.toml"), "--monitor", "--quiet", "--out", str(run),
              *[a for s in sets for a in ("--set", s)]])
    if rc not in (0, 1):
        raise SystemExit(f"kinadapt online failed ({rc}) on {name} seed {seed}")
    rc = cli(["diagnose", str(run), "--quiet", "--out", str(dia)])
    if rc != 0:
        raise SystemExit(f"kinadapt diagnose failed ({rc}) on {name} seed {seed}")
    summary = json.loads((run / "summary.json").read_text())
    return dict(monitor=summary["monitor"], report=json.loads((dia / "diagnosis.json").read_text()), run=run)


def segment_report(run: Path, t_from: float):
    """The diagnosis (its ``Report``, a mapping as ``diagnosis.json``) of the run's log from ``t_from`` [s]
    on, with the run's own set-up."""
    from kinadapt_nn.config import load_config
    from kinadapt_nn.diagnostics.ownrun import log_of_run, setup_of_run
    from kinadapt_nn.diagnostics.userlog import diagnose

    tr = np.load(run / "trace.npz")
    m = tr["t_s"] > t_from
    raw = SimpleNamespace(t_s=tr["t_s"][m], q_rad=tr["q_rad"][m], qdot_rad_s=tr["qdot_rad_s"][m],
                          wrench_raw_f=tr["wrench_raw_f"][m], source=f"{run} from {t_from:.3f} s")
    return diagnose(log_of_run(raw), setup_of_run(load_config(run / "config.toml")), progress=lambda msg: None).report


def _code_state() -> str:
    """The commit measured, and the package's files that differ from it (uncommitted edits)."""
    import subprocess

    def git(*a: str) -> str:
        return subprocess.run(["git", *a], cwd=REPO, capture_output=True, text=True).stdout.strip()

    dirty = git("diff", "--name-only", "HEAD", "--", "kinadapt_nn").split()
    return f"HEAD {git('rev-parse', '--short', 'HEAD')}" + (f", edited: {' '.join(dirty)}" if dirty else "")


def _said(names: list[str]) -> str:
    return ", ".join(names) if names else "nothing"


def scenario(name: str, seeds: list[int], work: Path, segment: bool, say) -> dict:
    """Every seed of scenario ``name``: whole-run (and segment) agreement; prints each disagreement."""
    whole, seg, n_seg = 0, 0, 0
    for seed in seeds:
        t0 = time.perf_counter()
        r = run_and_diagnose(name, seed, work)
        a = agreement(r["monitor"], r["report"])
        whole += a.agree
        line = f"  seed {seed} (onset {onset_of(seed):.2f} s): monitor {_said(a.monitor_as_offline)}"
        if not a.agree:
            line += f"; diagnosis of the run {_said(a.diagnosis)}"
        opened = [e for e in r["monitor"]["events"] if e["open"]]
        if segment and opened:
            b = agreement(r["monitor"], segment_report(r["run"], opened[0]["onset_s"] + SETTLE_S))
            n_seg += 1
            seg += b.agree
            line += (f"; from the onset {opened[0]['onset_s']:.2f} s: " +
                     ("agrees" if b.agree else f"diagnosis {_said(b.diagnosis)}"))
        say(line + f"   [{'agree' if a.agree else 'differ'}; {time.perf_counter() - t0:.0f} s]")
    return dict(name=name, n=len(seeds), whole=whole, seg=seg, n_seg=n_seg)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3, help="seeds per scenario (0 .. seeds - 1)")
    ap.add_argument("--scenarios", nargs="+", default=list(SCENARIOS), choices=list(SCENARIOS), metavar="NAME",
                    help=f"scenarios ({', '.join(SCENARIOS)}; default: all)")
    ap.add_argument("--no-segment", action="store_true", help="only the whole run's diagnosis")
    ap.add_argument("--save", type=Path, default=None, help="also write the output to this file")
    args = ap.parse_args()
    lines: list[str] = []

    def say(s: str) -> None:
        print(s, flush=True)
        lines.append(s)

    say(f"monitor_agreement: {args.seeds} seed(s) per scenario, online/monitor.toml, onset uniform in [1, 4] s; "
        "agree = the monitor's open events and the diagnosis name the same set (kinadapt_nn/monitor/agreement.py)")
    say(f"code: {_code_state()}")
    rows = []
    with tempfile.TemporaryDirectory(prefix="monitor_agreement-") as tmp:
        for name in args.scenarios:
            say(f"{name}:")
            rows.append(scenario(name, list(range(args.seeds)), Path(tmp), not args.no_segment, say))
    say("")
    say("| scenario | agree, whole run | agree, from the monitor's onset |")
    say("|---|---|---|")
    for r in rows:
        seg = f"{r['seg']}/{r['n_seg']}" if not args.no_segment else "-"
        say(f"| {r['name']} | {r['whole']}/{r['n']} | {seg} |")
    if args.save:
        args.save.parent.mkdir(parents=True, exist_ok=True)
        args.save.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
