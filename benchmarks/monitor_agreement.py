"""The live monitor against ``kinadapt diagnose`` of the same run (issue 53; docs/monitor.md "Agreement
with the offline diagnosis").

    python benchmarks/monitor_agreement.py [--seeds 3] [--first-seed 0] [--scenarios payload snag]
                                           [--whole-log] [--save benchmarks/results/monitor_agreement.txt]

For each scenario of ``benchmarks/monitor_events.py`` (payload, drift, frame rotation, snag, slip on
``online/monitor.toml``, each effect at its default size, its onset drawn uniformly in [1, 4] s from the
seed) and each seed: ``kinadapt online --monitor`` into a run folder, then ``kinadapt diagnose`` of that
folder -- which judges the log from the monitor's first open event on, the part before as its baseline
(``diagnostics.ownrun.monitor_window``). Where an open event names a hint shape (a world-frame force: no
library effect), the run is diagnosed again with the monitor's effect file of it
(``agreement.effect_file``; ``kinadapt diagnose RUN --effects FILE``, as a hint's effect file is passed
back). The monitor's open events at the end of the run (their end-of-run look: shape and near-ties; what
they imply: a payload's inertia) and the diagnosis's present effects, near-ties and leading hint are
compared through ``kinadapt_nn.monitor.agreement`` (its docstring: agree, same ties, names equal,
compatible). "agree, plain" is the diagnosis without the effect file; "names equal, live" the rule before
the end-of-run look and the near-ties (the live event's shape and what it implies against the plain
diagnosis's present effects and leading hint). With ``--whole-log`` the diagnosis of the whole log as one
(``kinadapt diagnose --whole-log``) is compared too. Prints per scenario the counts and, per seed, what
each side said.
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
from kinadapt_nn.monitor.agreement import (OFFLINE_NAME, agreement, diagnosis_names, effect_file,  # noqa: E402
                                           implied_names)

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
    summary = json.loads((run / "summary.json").read_text())
    files = _effect_files(summary, run, work / f"{effect}-{seed}-monitor-effects")
    todo = [("report", []), ("whole", ["--whole-log"])][: 2 if whole_log else 1]
    if files:
        todo.append(("files", [a for f in files for a in ("--effects", str(f))]))
    reports = {}
    for key, flags in todo:
        dia = work / f"{effect}-{seed}-diagnosis-{key}"
        if fresh or not (dia / "diagnosis.json").is_file():
            rc = cli(["diagnose", str(run), "--quiet", "--overwrite", "--out", str(dia), *flags])
            if rc != 0:
                raise SystemExit(f"kinadapt diagnose {' '.join(flags)} failed ({rc}) on {name} seed {seed}")
        reports[key] = json.loads((dia / "diagnosis.json").read_text())
    return dict(monitor=summary["monitor"], report=reports["report"], whole=reports.get("whole"),
                files=reports.get("files", reports["report"]), run=run)


def _effect_files(summary: dict, run: Path, folder: Path) -> list[Path]:
    """The monitor's effect files of its open hint-shaped events (``agreement.effect_file``), written to
    ``folder``; the relevant force the run's set-up's."""
    from kinadapt_nn.config import load_config
    from kinadapt_nn.diagnostics.ownrun import setup_of_run

    rel = setup_of_run(load_config(run / "config.toml")).analysis.relevant_force_N
    out = []
    for ev in summary["monitor"]["events"]:
        made = effect_file(ev, rel) if ev["open"] else None
        if made:
            folder.mkdir(parents=True, exist_ok=True)
            (folder / made[0]).write_text(made[1])
            out.append(folder / made[0])
    return out


def names_live(monitor: dict, report: dict) -> bool:
    """The rule before the end-of-run look and the near-ties: the open events' live shapes (and what they
    imply) against the diagnosis's present effects and leading hint, as sets."""
    opened = [e for e in monitor["events"] if e["open"]]
    mon = {":".join(OFFLINE_NAME[e["shape"]]) for e in opened} | {n for e in opened for n in implied_names(e)}
    return mon == set(diagnosis_names(report))


def _code_state() -> str:
    """The commit measured, and the package's files that differ from it (uncommitted edits)."""
    import subprocess

    def git(*a: str) -> str:
        return subprocess.run(["git", *a], cwd=REPO, capture_output=True, text=True).stdout.strip()

    dirty = git("diff", "--name-only", "HEAD", "--", "kinadapt_nn").split()
    return f"HEAD {git('rev-parse', '--short', 'HEAD')}" + (f", edited: {' '.join(dirty)}" if dirty else "")


def _said(names: list[str]) -> str:
    return ", ".join(names) if names else "nothing"


def _monitor_said(monitor: dict) -> str:
    """The open events as printed live, and their end-of-run looks."""
    out = []
    for e in monitor["events"]:
        if not e["open"]:
            continue
        end = e.get("at_end")
        enc = (end or {}).get("encoder_offset")  # the end look's rival that is not named live
        out.append(e["line"] + ("; at the end, on %d samples %.2f-%.2f s: %s%s (delta BIC %.1f)" % (
            end["rows"], end["from_s"], end["to_s"], end["shape"],
            f" or {' or '.join(end['ties'])}" if end["ties"] else ", no near-tie", end["delta_bic"]) if end else "")
                   + (f"; encoder_offset: joint {enc['joint']}, {enc['offset_deg']:+.2f} deg, BIC {enc['delta_bic']:+.1f}"
                      " on the best's" if enc else ""))
    return " / ".join(out) or "no open event"


def _diagnosis_said(report: dict, names: list[str]) -> str:
    """The diagnosis's verdict on each of ``names`` (offline names), with its reason and near-ties."""
    from kinadapt_nn.monitor.agreement import _verdicts

    v = _verdicts(report)
    out = []
    for n in names:
        e = v.get(n)
        if e is None:
            hints = [h["shape"] for h in ((report.get("unexplained") or {}).get("hints") or [])]
            out.append(f"{n}: " + (f"hint {hints.index(n[5:]) + 1} of {len(hints)}" if n[5:] in hints else
                                   "not judged (no library effect; no hint: " + ("the model explains the log"
                                   if report.get("model_complete") else "incomplete") + ")"))
            continue
        est = (" (" + ", ".join(f"{k} {v['value']:.4g} ± {v['sd']:.2g} {v['unit']}" for k, v in e["estimate"].items())
               + ")") if e["effect"].startswith("monitor_") and e.get("estimate") else ""
        out.append(f"{n}: {e['verdict']}{est}" + (f" ({e['reason']})" if e.get("reason") else "")
                   + (f", tied with {', '.join(e['indistinguishable_from'])}" if e.get("indistinguishable_from") else ""))
    return "; ".join(out)


def _verdict_words(summary: str) -> str:
    """The summary's verdict on the model and its present effects (its first sentences after the window's)."""
    import re

    at = min((summary.find(k) for k in ("The model", "Something the model") if k in summary), default=0)
    said = [x for x in re.split(r"(?<=\.) ", summary[at:]) if x.startswith(("The model", "Something", "No library",
                                                                                 "Present", "It looks like",
                                                                                 "Fitted beside them"))]
    return " ".join(said)


def scenario(name: str, seeds: list[int], work: Path, whole_log: bool, say, reuse: bool = False) -> dict:
    """Every seed of scenario ``name``: agreement of the diagnosis (and of the whole log's); prints each
    seed's names on both sides and the diagnosis's verdicts on the monitor's names."""
    n = dict(agree=0, same=0, equal=0, compatible=0, plain=0, live=0, whole=0)
    for seed in seeds:
        t0 = time.perf_counter()
        r = run_and_diagnose(name, seed, work, whole_log=whole_log, reuse=reuse)
        a = agreement(r["monitor"], r["files"])
        plain = agreement(r["monitor"], r["report"])
        live = names_live(r["monitor"], r["report"])
        for key, ok in (("agree", a.agree), ("same", a.same_ties), ("equal", a.names_equal),
                        ("compatible", a.compatible), ("plain", plain.agree), ("live", live)):
            n[key] += bool(ok)
        win = r["report"].get("window")
        files = r["files"] is not r["report"]
        line = (f"  seed {seed} (onset {onset_of(seed):.2f} s): the monitor: {_monitor_said(r['monitor'])}"
                f"\n    as offline names: {_said(a.monitor_as_offline)}"
                + (f" (undecided: {'; '.join(k + ' or ' + ', '.join(sorted(set(v) - {k})) for k, v in a.undecided.items())})"
                   if a.undecided else "")
                + "\n    the diagnosis " + (f"from {win['from_s']:.2f} s" if win else "of the whole log (no open event)")
                + (" with the monitor's effect file" if files else "") + f": names {_said(a.diagnosis)}; "
                + _diagnosis_said(r["files"], a.monitor_as_offline))
        if files:
            line += (f"\n    the plain diagnosis (no effect file): names {_said(plain.diagnosis)}; "
                     + _diagnosis_said(r["report"], plain.monitor_as_offline) + "; its summary: "
                     + _verdict_words(r["report"]["summary"]))
        if win and (win.get("before") or {}).get("present"):
            line += f"\n    before the onset: {', '.join(win['before']['present'])}"
        if whole_log:
            b = agreement(r["monitor"], r["whole"])
            n["whole"] += b.agree
            line += "\n    the whole log: " + ("agrees" if b.agree else _said(b.diagnosis))
        verdict = ("agree, same ties" if a.same_ties else "agree" if a.agree else "compatible" if a.compatible
                   else "differ")
        say(line + f"\n    [{verdict}; {time.perf_counter() - t0:.0f} s]")
    return dict(name=name, n=len(seeds), **n)


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
        "agree, same ties, names equal, compatible: kinadapt_nn/monitor/agreement.py's docstring")
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
    cols = [("agree", "agree"), ("same", "same ties"), ("equal", "names equal"), ("compatible", "compatible"),
            ("plain", "agree, plain diagnosis"), ("live", "names equal, live (the rule before)")]
    if args.whole_log:
        cols.append(("whole", "agree, the whole log"))
    say("| scenario | " + " | ".join(c for _, c in cols) + " |")
    say("|---|" + "---|" * len(cols))
    for r in rows:
        say(f"| {r['name']} | " + " | ".join(f"{r[k]}/{r['n']}" for k, _ in cols) + " |")
    say(f"wall {time.perf_counter() - t_all:.0f} s")
    if args.save:
        args.save.parent.mkdir(parents=True, exist_ok=True)
        args.save.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
