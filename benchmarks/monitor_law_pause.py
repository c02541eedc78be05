"""The law listens (issue 53, item 4; docs/monitor.md "The law listens"): the snag scenario with the
adaptive law on, with and without ``monitor.pause_law``, and the Jacobian error against the truth.

    python benchmarks/monitor_law_pause.py [--seeds 10] [--point X Y Z] [--save benchmarks/results/monitor_law_pause.txt]

The scenario is ``benchmarks/monitor_events.py``'s snag (its ``_cfg`` on ``online/monitor.toml``: free-space
reorientations with sensor noise, ``effects.world_force`` at its default size, the onset drawn uniformly in
[1, 4] s from the seed), with the law the package's default (``[adaptation]``'s defaults: mode and initial
error; ``online/monitor.toml`` freezes the model). Three runs per seed: the law adapting (the switch off),
the law paused while the monitor has an event open (``monitor.pause_law = true``), and the same run without
the snag (what the law does when nothing happens). Per run, from the truth-side evaluation
(``runs/evaluate.py``: ``truth_jacobian_rel_error``, the W-scaled relative Frobenius error of J_hat against
the true Jacobian, evaluated every 25 ms): at the end of the run, and its mean from the onset on; the
offset estimate's error at the end (|theta - true offset|, mm); whether the run completed (its whole
duration, no divergence, no rank-gate stop); the seconds the law was paused. Median and range over seeds.
``--point``: the pull acts at this point of the tool (flange frame, m; ``effects.world_force.point_f_m``, its
size unchanged) instead of the effect's default point.
"""

from __future__ import annotations

import argparse
import datetime
import subprocess
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "benchmarks"))

from monitor_events import SCENARIOS, _cfg  # noqa: E402  (the scenarios' construction, reused)

from kinadapt_nn.config import AdaptationCfg, WorldForceCfg  # noqa: E402
from kinadapt_nn.runs.episode import run_episode  # noqa: E402

EFFECT = SCENARIOS["snag"][0]  # world_force
#: the package's default law (online/monitor.toml freezes the model: it watches, it does not adapt)
LAW = [f"adaptation.mode={AdaptationCfg().mode}", f"adaptation.initial_error_m={AdaptationCfg().initial_error_m}"]
VARIANTS = {"law adapting": (True, False), "law paused": (True, True), "no snag": (False, False)}


def onset_of(seed: int) -> float:
    """The snag's onset [s] of seed ``seed``, drawn as ``benchmarks/monitor_events.py`` draws it."""
    return float(np.random.default_rng(seed).uniform(1.0, 4.0))


def one(seed: int, snag: bool, pause: bool, point: list[float] | None = None) -> dict:
    onset = onset_of(seed)
    sets = [f"run.seed={seed}", *LAW, "monitor.enabled=true", f"monitor.pause_law={str(pause).lower()}"]
    if snag:
        sets += [f"effects.{EFFECT}.enabled=true", f"effects.{EFFECT}.onset_s={onset}"]
        if point is not None:
            sets.append(f"effects.{EFFECT}.point_f_m=[{','.join(repr(float(x)) for x in point)}]")
    cfg = _cfg("online/monitor.toml", sets)
    res = run_episode(cfg)
    s, tr = res.summary, res.trace
    t, jerr = tr["t_s"], tr["truth_jacobian_rel_error"]
    mon = s["monitor"]
    completed = (s["failure"] in ("none", "timeout") and s["sim_time_s"] >= cfg.run.duration_s - 2 * cfg.run.dt_s)
    return dict(onset=onset, jerr_final=float(s["jacobian_rel_error_final"]),
                jerr_after=float(np.nanmean(jerr[t >= onset])), jerr_onset=float(jerr[np.searchsorted(t, onset)]),
                off_err_mm=1e3 * float(np.linalg.norm(s["offset_error_final_m"])), completed=completed,
                failure=s["failure"], paused_s=float(mon.get("law_paused_total_s", 0.0)),
                events=[e["shape"] for e in mon["events"]], theta_mm=1e3 * np.asarray(s["offset_estimate_final_f_m"]),
                adapted_s=float(np.sum(tr["adapt_gate"][t >= onset] > 0) * cfg.run.dt_s * cfg.run.log_every))


def _vec(x) -> str:
    return "(" + ", ".join(f"{v:.2f}" for v in x) + ")"


def _stat(x) -> str:
    x = np.asarray(x, dtype=float)
    return f"{np.median(x):.4f} [{x.min():.4f}, {x.max():.4f}]"


def _stat_mm(x) -> str:
    x = np.asarray(x, dtype=float)
    return f"{np.median(x):.2f} [{x.min():.2f}, {x.max():.2f}]"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10, help="seeds (each: three runs)")
    ap.add_argument("--point", type=float, nargs=3, default=None, metavar=("X", "Y", "Z"),
                    help="the pull's point on the tool [m], flange frame (default: the effect's default point)")
    ap.add_argument("--save", type=Path, default=None, help="also write the output to this file")
    a = ap.parse_args()
    out: list[str] = []
    say = lambda s="": (print(s, flush=True), out.append(s))  # noqa: E731
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True, text=True).stdout
    cmd = "python benchmarks/monitor_law_pause.py" + (f" --seeds {a.seeds}" if a.seeds != 10 else "") + (
        f" --point {' '.join(f'{x:g}' for x in a.point)}" if a.point else "") + (f" --save {a.save}" if a.save else "")
    say(f"# {cmd}  (commit {commit.strip() or '?'}, {datetime.date.today()}, the shared 2-core x86_64 VM)")
    point = a.point if a.point is not None else list(WorldForceCfg().point_f_m)
    say(f"monitor_law_pause: {a.seeds} seeds, online/monitor.toml with the snag ({EFFECT}, default size "
        f"{list(WorldForceCfg().force_w_N)} N world, at {point} m on the tool, flange frame) at an onset uniform in "
        f"[1, 4] s; the law: {', '.join(LAW)}; the true offset "
        f"{_vec(1e3 * np.asarray(_cfg('online/monitor.toml', []).tool.offset_f_m))} mm (flange frame)")
    rows = {v: [] for v in VARIANTS}
    say(f"{'seed':>4} {'onset [s]':>9}  {'variant':<13}{'J err end':>10}{'J err mean after onset':>24}"
        f"{'J err at onset':>16}{'|off err| end [mm]':>20}{'offset estimate end [mm]':>27}{'adapted after onset [s]':>25}"
        f"{'paused [s]':>12}  events")
    for seed in range(a.seeds):
        for v, (snag, pause) in VARIANTS.items():
            r = one(seed, snag, pause, a.point)
            rows[v].append(r)
            say(f"{seed:>4} {r['onset']:>9.3f}  {v:<13}{r['jerr_final']:>10.4f}{r['jerr_after']:>24.4f}"
                f"{r['jerr_onset']:>16.4f}{r['off_err_mm']:>20.2f}{_vec(r['theta_mm']):>27}{r['adapted_s']:>25.2f}"
                f"{r['paused_s']:>12.2f}  "
                + (",".join(r["events"]) or "-") + ("" if r["completed"] else f"  NOT COMPLETED ({r['failure']})"))
    say()
    say("median [min, max] over seeds:")
    say(f"{'variant':<14}{'J err end':>32}{'J err mean after onset':>32}{'|off err| end [mm]':>26}{'completed':>11}"
        f"{'paused [s]':>26}")
    for v, rs in rows.items():
        say(f"{v:<14}{_stat([r['jerr_final'] for r in rs]):>32}{_stat([r['jerr_after'] for r in rs]):>32}"
            f"{_stat_mm([r['off_err_mm'] for r in rs]):>26}{sum(r['completed'] for r in rs):>8}/{len(rs):<2}"
            f"{_stat_mm([r['paused_s'] for r in rs]):>26}")
    ad, pa = rows["law adapting"], rows["law paused"]
    better_end = sum(p["jerr_final"] < q["jerr_final"] for p, q in zip(pa, ad))
    better_mean = sum(p["jerr_after"] < q["jerr_after"] for p, q in zip(pa, ad))
    say(f"paused lower than adapting: J err end in {better_end}/{len(pa)} seeds, J err mean after onset in "
        f"{better_mean}/{len(pa)}")
    if a.save:
        a.save.parent.mkdir(parents=True, exist_ok=True)
        a.save.write_text("\n".join(out) + "\n")


if __name__ == "__main__":
    main()
