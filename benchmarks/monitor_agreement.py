"""The live monitor against ``kinadapt diagnose`` of the same run (issue 53; docs/monitor.md "Agreement
with the offline diagnosis").

    python benchmarks/monitor_agreement.py [--seeds 3] [--first-seed 0] [--scenarios payload snag]
                                           [--whole-log] [--save benchmarks/results/monitor_agreement.txt]

For each scenario of ``benchmarks/monitor_events.py`` (payload, drift, frame rotation, snag, slip on
``online/monitor.toml``, each effect at its default size, its onset drawn uniformly in [1, 4] s from the
seed) and each seed: ``kinadapt online --monitor`` into a run folder, then ``kinadapt diagnose`` of that
folder -- which judges the log from the monitor's first open event on, the part before as its baseline
(``diagnostics.ownrun.monitor_window``). The monitor's open events at the end of the run (and what they
imply: a payload's inertia) and the diagnosis's present effects and leading hint are compared through
``kinadapt_nn.monitor.agreement`` (one map between the two vocabularies; they agree when the name sets
are equal; compatible when neither names what the other does not name or leave undecided). With
``--whole-log`` the diagnosis of the whole log as one (``kinadapt diagnose --whole-log``) is compared
too. Prints per scenario how many seeds agree and, for those that do not, what each side said.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path
import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from kinadapt_nn.app.cli import main as cli  # noqa: E402
from kinadapt_nn.monitor.agreement import agreement, diagnosis_candidates  # noqa: E402

#: scenario -> (the truth-side effect, the monitor's shape that names it): benchmarks/monitor_events.py's five
SCENARIOS = {"payload": ("tool_gravity", "tool_gravity"), "drift": ("ft_bias_drift", "ft_bias_drift"),
             "frame rotation": ("ft_frame_rotation", "ft_frame_rotation"), "snag": ("world_force", "world_force"),
             "slip": ("grasp_slip", "tool_tilt")}
def onset_of(seed: int) -> float:
    """The scenario's onset [s] of seed ``seed`` (as ``benchmarks/monitor_events.py`` draws it)."""
    return float(np.random.default_rng(seed).uniform(1.0, 4.0))


def run_and_diagnose(name: str, seed: int, work: Path, extra: list[str] = (), whole_log: bool = False,
                     reuse: bool = False) -> dict:
    """One seed of scenario ``name``: the run with ``--monitor``, its diagnosis (``kinadapt diagnose RUN``:
    from the monitor's event on where it raised one); ``whole_log``: also ``--whole-log``'s; ``reuse``: a
    run and diagnosis already in ``work`` (``--keep``) are read, not made again. -> the run's monitor
    summary, the diagnosis's report (and the whole log's, or None) and the run folder."""
    effect, _shape = SCENARIOS[name]
    run = work / f"{effect}-{seed}"
    sets = [f"run.seed={seed}", f"effects.{effect}.enabled=true", f"effects.{effect}.onset_s={onset_of(seed)}",
            "run.tensorboard=false", "run.figure=false", *extra]
    fresh = not (reuse and (run / "summary.json").is_file())
    if fresh:
        rc = cli(["online", "--config", str(REPO / "online" / "monitor.toml"), "--monitor", "--quiet", "--overwrite",
                  "--out", str(run), *[a for s in sets for a in ("--set", s)]])
        if rc not in (0, 1):
            raise SystemExit(f"kinadapt online failed ({rc}) on {name} seed {seed}")
    reports = {}
    for key, flags in (("report", []), ("whole", ["--whole-log"]))[: 2 if whole_log else 1]:
        dia = work / f"{effect}-{seed}-diagnosis-{key}"
        if fresh or not (dia / "diagnosis.json").is_file():
            rc = cli(["diagnose", str(run), "--quiet", "--overwrite", "--out", str(dia), *flags])
            if rc != 0:
                raise SystemExit(f"kinadapt diagnose {' '.join(flags)} failed ({rc}) on {name} seed {seed}")
        reports[key] = json.loads((dia / "diagnosis.json").read_text())
    summary = json.loads((run / "summary.json").read_text())
    return dict(monitor=summary["monitor"], report=reports["report"], whole=reports.get("whole"), run=run)


def _code_state() -> str:
    """The commit measured, and the package's files that differ from it (uncommitted edits)."""
    import subprocess

    def git(*a: str) -> str:
        return subprocess.run(["git", *a], cwd=REPO, capture_output=True, text=True).stdout.strip()

    dirty = git("diff", "--name-only", "HEAD", "--", "kinadapt_nn").split()
    return f"HEAD {git('rev-parse', '--short', 'HEAD')}" + (f", edited: {' '.join(dirty)}" if dirty else "")


def _said(names: list[str]) -> str:
    return ", ".join(names) if names else "nothing"


def scenario(name: str, seeds: list[int], work: Path, whole_log: bool, say, reuse: bool = False) -> dict:
    """Every seed of scenario ``name``: agreement of the diagnosis (and of the whole log's); prints each
    seed's names, and for a disagreement what the diagnosis could not rule out."""
    agree, compatible, whole = 0, 0, 0
    for seed in seeds:
        t0 = time.perf_counter()
        r = run_and_diagnose(name, seed, work, whole_log=whole_log, reuse=reuse)
        a = agreement(r["monitor"], r["report"])
        agree += a.agree
        compatible += a.compatible
        win = r["report"].get("window")
        line = (f"  seed {seed} (onset {onset_of(seed):.2f} s): monitor {_said(a.monitor_as_offline)}; diagnosis "
                + (f"from {win['from_s']:.2f} s" if win else "of the whole log (no open event)")
                + (": agrees" if a.agree else f": {_said(a.diagnosis)}"))
        if not a.agree:
            line += f" (cannot rule out: {_said([n for n in diagnosis_candidates(r['report']) if n in a.monitor_as_offline])})"
            line += "".join(f"; its {e['effect']}: {e['verdict']}, {e.get('reason') or ''}"
                            + (f" ({', '.join(e['indistinguishable_from'])})" if e.get("indistinguishable_from") else "")
                            for e in r["report"]["ranking"] if f"effect:{e['effect']}" in a.monitor_as_offline
                            and e["verdict"] != "present")
            chosen = [e for e in r["report"]["ranking"] if e.get("selected_round") is not None]
            line += "; its selection took " + (", ".join(
                f"{e['effect']} (round {e['selected_round']}, {e['verdict']}"
                + (f": {e['reason']}" if e["verdict"] != "present" and e.get("reason") else "") + ")"
                for e in sorted(chosen, key=lambda e: e["selected_round"])) or "nothing")
            line += "; the monitor said: " + " / ".join(
                f"{e['text']} (runner-up {e.get('runner_up')}, delta BIC {e.get('delta_bic', float('nan')):.1f})"
                for e in r["monitor"]["events"] if e["open"])
        if win and (win.get("before") or {}).get("present"):
            line += f"; before the onset: {', '.join(win['before']['present'])}"
        if whole_log:
            b = agreement(r["monitor"], r["whole"])
            whole += b.agree
            line += "; the whole log: " + ("agrees" if b.agree else _said(b.diagnosis))
        say(line + f"   [{'agree' if a.agree else 'compatible' if a.compatible else 'differ'}; "
                   f"{time.perf_counter() - t0:.0f} s]")
    return dict(name=name, n=len(seeds), agree=agree, compatible=compatible, whole=whole)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3, help="seeds per scenario (first-seed .. first-seed + seeds - 1)")
    ap.add_argument("--first-seed", type=int, default=0, help="the first seed (default 0)")
    ap.add_argument("--scenarios", nargs="+", default=list(SCENARIOS), choices=list(SCENARIOS), metavar="NAME",
                    help=f"scenarios ({', '.join(SCENARIOS)}; default: all)")
    ap.add_argument("--whole-log", action="store_true", help="also the diagnosis of the whole log as one (kinadapt "
                    "diagnose --whole-log)")
    ap.add_argument("--keep", type=Path, default=None, help="keep the run folders and diagnoses in this folder "
                    "(default: a temporary one)")
    ap.add_argument("--reuse", action="store_true", help="with --keep: read the runs and diagnoses already there "
                    "instead of making them again (the output says so)")
    ap.add_argument("--save", type=Path, default=None, help="also write the output to this file")
    args = ap.parse_args()
    lines: list[str] = []

    def say(s: str) -> None:
        print(s, flush=True)
        lines.append(s)

    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    say(f"monitor_agreement: seeds {seeds[0]}-{seeds[-1]} per scenario, online/monitor.toml, onset uniform in [1, 4] s; "
        "agree = the monitor's open events (and what they imply) and kinadapt diagnose of the run name the same set, "
        "compatible = neither names what the other does not name or leave undecided (kinadapt_nn/monitor/agreement.py)")
    made = args.keep / "code.txt" if args.keep is not None else None
    if args.reuse and made is not None and made.is_file():  # the code the kept runs and diagnoses were made with
        say(f"code: {made.read_text().strip()} (runs and diagnoses made then, read again from {args.keep}; "
            f"agreement evaluated at {_code_state()})")
    else:
        say(f"code: {_code_state()}")
        if made is not None:
            made.parent.mkdir(parents=True, exist_ok=True)
            made.write_text(_code_state() + "\n")
    rows = []
    t_all = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="monitor_agreement-") as tmp:
        work = Path(tmp) if args.keep is None else args.keep
        work.mkdir(parents=True, exist_ok=True)
        for name in args.scenarios:
            say(f"{name}:")
            rows.append(scenario(name, seeds, work, args.whole_log, say, args.reuse and args.keep is not None))
    say("")
    say("| scenario | agree | compatible |" + (" agree, the whole log |" if args.whole_log else ""))
    say("|---|---|---|" + ("---|" if args.whole_log else ""))
    for r in rows:
        say(f"| {r['name']} | {r['agree']}/{r['n']} | {r['compatible']}/{r['n']} |"
            + (f" {r['whole']}/{r['n']} |" if args.whole_log else ""))
    say(f"wall {time.perf_counter() - t_all:.0f} s")
    if args.save:
        args.save.parent.mkdir(parents=True, exist_ok=True)
        args.save.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
