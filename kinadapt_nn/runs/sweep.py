"""``kinadapt sweep``: many episodes over groups (named override sets) x seeds, locally or on Ray.

Each episode is identified by ``<group>-s<seed>``; its summary is written atomically to
``OUT/episodes/<id>.json`` the moment it finishes, so an interrupted sweep loses no finished
episode and a re-run skips every episode already written. ``sweep.csv`` (one row per episode)
and ``sweep.json`` (success rate with a 95 % Wilson interval, seat-time quantiles, failure
counts, overall and per group) are rebuilt from the episode files at the end.

With ``random_tools = true`` each seed also draws its tool (lateral offset in a disc, length
100 mm +- spread) from its own seed, so seeds x groups is a randomised-tool sweep.

With ``batch = true`` each worker task steps up to ``batch_size`` seeds of one group together
(``kinadapt_nn.runs.batch.run_batch``: the same kernels, one batched physics), and each episode's
record is the batch summary: success, failure class, seat time, peak forces and moment, final
offset error, control steps -- equal to what ``run_episode`` gives for them (tested), without the
trace-based evaluation columns (Jacobian errors, prediction errors, identification). Episodes are
written as each batch ends.
"""

from __future__ import annotations

import csv
import io
import itertools
import json
import math
import re
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from kinadapt_nn.config import load_config, load_toml_model
from kinadapt_nn.errors import ConfigError, KinadaptError
from kinadapt_nn.features import features_spec
from kinadapt_nn.runio import write_text_atomic
from kinadapt_nn.runs.jobs import Job, Runner, Task, group_tasks, run_task_cells


class SweepCfg(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    seeds: int = Field(20, ge=1, le=100000)  # seeds 0..seeds-1 per group
    seed_offset: int = Field(0, ge=0, le=2**32 - 100001)  # first seed (run.seed <= 2^32 - 1)
    base: list[str] = []  # overrides applied to every episode (online config keys)
    groups: dict[str, list[str]] = {"default": []}  # named conditions: name -> overrides
    grid: dict[str, list] = {}  # key -> values; the cartesian product is added as groups
    random_tools: bool = True  # each seed draws its tool from its own seed
    lateral_radius_m: float = Field(0.004, ge=0.0)  # [m] random tools: lateral offset disc
    length_spread_m: float = Field(0.002, ge=0.0, le=0.004)  # [m] random tools: length 0.100 +- this
    jobs: int = Field(2, ge=1, le=256)  # local worker processes
    batch: bool = False  # each worker steps a group's seeds together (runs.batch): summaries without traces
    batch_size: int = Field(32, ge=1, le=4096)  # episodes per batch (one worker task)


def load_sweep_config(path: Path | None, overrides=()) -> SweepCfg:
    cfg = load_toml_model(SweepCfg, path, overrides, "online/sweep.toml")
    # every group's overrides must make a valid online config (fail before running anything)
    for name, over in expand_groups(cfg).items():
        features_spec(load_config(None, [*cfg.base, *over]).run.features)  # a registered features type
        if not re.fullmatch(r"[A-Za-z0-9_.=+\-, \[\]]+", name):
            raise ConfigError(f"sweep group name {name!r}: use letters, digits, spaces and _ . = + - , [ ]")
    return cfg


def expand_groups(cfg: SweepCfg) -> dict[str, list[str]]:
    groups = dict(cfg.groups)
    if cfg.grid:
        keys = list(cfg.grid)
        for values in itertools.product(*(cfg.grid[k] for k in keys)):
            over = [f"{k}={json.dumps(v)}" for k, v in zip(keys, values)]
            groups[",".join(over)] = over
    return groups


def _slug(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.=+\-]+", "_", name).strip("_") or "group"


def tool_overrides(cfg: SweepCfg, seed: int) -> list[str]:
    if not cfg.random_tools:
        return []
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x7001]))
    rad = cfg.lateral_radius_m * math.sqrt(rng.random())
    ang = 2 * math.pi * rng.random()
    length = 0.100 + rng.uniform(-cfg.length_spread_m, cfg.length_spread_m)
    return [f"tool.offset_f_m=[{rad * math.cos(ang):.7f}, {rad * math.sin(ang):.7f}, {length:.7f}]"]


@dataclass(frozen=True)
class SweepJob(Job):
    """One episode (or work cell) of a sweep: ``<group>-s<seed>``."""

    group: str = ""  #: the group's name
    seed: int = 0  #: run.seed


def episode_jobs(cfg: SweepCfg) -> list[SweepJob]:
    jobs = []
    for name, over in expand_groups(cfg).items():
        for seed in range(cfg.seed_offset, cfg.seed_offset + cfg.seeds):
            full = (*cfg.base, *over, *tool_overrides(cfg, seed), f"run.seed={seed}", "run.progress=false")
            jobs.append(SweepJob(id=f"{_slug(name)}-s{seed}", overrides=full, group=name, seed=seed))
    return jobs


def run_task(task: Task, report) -> list[dict]:
    """A task's episode -> its flat record (no files, so it can run anywhere: a local worker or
    Ray): one episode, or ``run.insertions`` of them (a work cell), what ``run_insertions`` gives."""
    return [_record(j, r.summary) for j, (_c, r) in zip(task.jobs, run_task_cells(task, report))]


def run_batch_task(task: Task, report) -> list[dict]:
    """``batch = true``: a task's episodes stepped together by ``runs.batch.run_batch`` ->
    their flat records, in order (summaries without traces). Runs of several insertions or work
    cells step each insertion together (``runs.insertions.run_cells``)."""
    cfgs = [j.config() for j in task.jobs]
    if any(c.run.insertions > 1 or c.cell.bores_w_m for c in cfgs):
        return run_task(task, report)
    from kinadapt_nn.runs.batch import run_batch

    res = run_batch(cfgs, nthread=1)
    report(len(cfgs))
    return [_record(j, s) for j, s in zip(task.jobs, res.summaries)]


def _record(job: SweepJob, s: dict) -> dict:
    """A flat record of a run's summary: its scalars and short number lists; several insertions
    are judged as a whole (``runs.insertions.judged_whole``)."""
    from kinadapt_nn.runs.insertions import judged_whole

    from kinadapt_nn.runs.outcome import monitor_brief

    brief = monitor_brief(s)  # (before judged_whole: a cell's insertions' monitors summed)
    s = judged_whole(s)
    rec = {"id": job.id, "group": job.group, "seed": job.seed, "overrides": " ".join(job.overrides)}
    for k, v in s.items():
        if isinstance(v, (bool, int, float, str)) or v is None:
            rec[k] = v
        elif isinstance(v, list) and len(v) <= 3 and all(isinstance(x, (int, float)) for x in v):
            for i, x in enumerate(v):
                rec[f"{k}_{i}"] = x
    if brief is not None:  # --monitor: how many events, their shapes (";"-joined), the first one's time
        evs = s["monitor"]["events"]
        rec.update(monitor_events=brief.events, monitor_shapes=";".join(brief.shapes),
                   monitor_first_event_s=evs[0]["t_s"] if evs and not s.get("insertions") else None)
    return rec


def sweep_tasks(cfg: SweepCfg, todo: list[SweepJob]) -> list[Task]:
    """``todo`` split into worker tasks (``runs.jobs.group_tasks``): one episode each, or with
    ``batch = true`` episodes that share every known setting, at most ``batch_size``, and such a
    group split into at least ``jobs`` tasks where it has that many episodes, so every worker has work."""
    if not cfg.batch:
        return group_tasks(todo, 1)
    return group_tasks(todo, cfg.batch_size, min_tasks=cfg.jobs)


def wilson_interval(k: int, n: int, z: float = 1.959964) -> tuple[float, float]:
    """95 % Wilson score interval of a binomial proportion."""
    if n == 0:
        return (0.0, 1.0)
    p = k / n
    den = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return (max(0.0, centre - half), min(1.0, centre + half))


def _stats(recs: list[dict]) -> dict:
    n = len(recs)
    k = sum(1 for r in recs if r.get("success"))
    lo, hi = wilson_interval(k, n)
    seats = np.array([r["seat_time_s"] for r in recs if r.get("seat_time_s") is not None])
    fails: dict[str, int] = {}
    for r in recs:
        if not r.get("success"):
            fails[r.get("failure", "?")] = fails.get(r.get("failure", "?"), 0) + 1
    q = {f"p{p}": float(np.percentile(seats, p)) for p in (5, 25, 50, 75, 95)} if len(seats) else {}
    out = {"episodes": n, "successes": k, "success_rate": k / n if n else None, "success_rate_ci95": [lo, hi],
           "seat_time_s_quantiles": q, "failures": fails}
    mon = [r for r in recs if r.get("monitor_events") is not None]
    if mon:  # --monitor: episodes with an event, events, and how many episodes named each shape
        shapes: dict[str, int] = {}
        for r in mon:
            for sh in dict.fromkeys(filter(None, r["monitor_shapes"].split(";"))):
                shapes[sh] = shapes.get(sh, 0) + 1
        out["monitor"] = {"episodes": len(mon), "episodes_with_events": sum(r["monitor_events"] > 0 for r in mon),
                          "events": sum(r["monitor_events"] for r in mon), "shapes": shapes}
    return out


def aggregate(out: Path, jobs: list[dict]) -> dict:
    recs = []
    for j in jobs:
        p = out / "episodes" / f"{j.id}.json"
        if p.is_file():
            recs.append(json.loads(p.read_text()))
    cols: list[str] = []
    for r in recs:
        for k in r:
            if k not in cols and k != "wall_time_s":
                cols.append(k)
    cols.append("wall_time_s")
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=cols, extrasaction="ignore")
    w.writeheader()
    w.writerows(recs)
    write_text_atomic(out / "sweep.csv", buf.getvalue())
    groups = {}
    for g in dict.fromkeys(r["group"] for r in recs):
        groups[g] = _stats([r for r in recs if r["group"] == g])
    summary = {"total": _stats(recs), "groups": groups, "episodes_expected": len(jobs)}
    summary["episodes"] = summary["total"]["episodes"]
    summary["success_rate"] = summary["total"]["success_rate"]
    summary["success_rate_ci95"] = summary["total"]["success_rate_ci95"]
    write_text_atomic(out / "sweep.json", json.dumps(summary, indent=1) + "\n")
    return summary


def run_sweep(cfg: SweepCfg, out: Path, executor: str = "local", address: str | None = None,
              progress: bool = True, worker_setup=None) -> dict:
    """Run the sweep's episodes not yet in ``out/episodes`` on ``cfg.jobs`` local workers or on Ray
    (``runs.jobs.Runner``: without ``address`` a Ray of this call's own), each episode's record
    written as its task ends; then ``sweep.csv`` and ``sweep.json`` from every record. -> the
    aggregate (``sweep.json``) plus ``wall_time_s_this_run``. With the live monitor on (``base`` sets
    ``monitor.enabled``; ``worker_setup`` registers it in each worker, ``runs.jobs.Runner``) each record
    has ``monitor_events``, ``monitor_shapes`` and ``monitor_first_event_s`` and each group's statistics
    a ``monitor`` entry."""
    out = Path(out)
    (out / "episodes").mkdir(parents=True, exist_ok=True)
    cfg_text = json.dumps(cfg.model_dump(mode="json"), indent=1, sort_keys=True)
    cfg_path = out / "sweep_config.json"
    if cfg_path.is_file() and cfg_path.read_text() != cfg_text:
        raise KinadaptError(f"'{out}' holds a different sweep (sweep_config.json differs); use another --out")
    write_text_atomic(cfg_path, cfg_text)
    jobs = episode_jobs(cfg)
    todo = [j for j in jobs if not (out / "episodes" / f"{j.id}.json").is_file()]

    def done(_task: Task, records: list[dict]) -> None:
        for rec in records:
            write_text_atomic(out / "episodes" / f"{rec['id']}.json", json.dumps(rec) + "\n")

    t0 = time.perf_counter()
    with Runner(cfg.jobs, executor, address, progress, setup=worker_setup) as runner:
        if todo:  # the kernels once here, not in every worker at once (one config per group: the seed changes none)
            runner.precompile([j.config() for j in {j.group: j for j in todo}.values()])
        finished = [j for j in jobs if j not in set(todo)]
        runner.run(run_batch_task if cfg.batch else run_task, sweep_tasks(cfg, todo), "sweep", on_done=done,
                   done_before=_episodes_of(finished))
    summary = aggregate(out, jobs)
    summary["wall_time_s_this_run"] = time.perf_counter() - t0
    return summary


def _episodes_of(jobs: list[SweepJob]) -> int:
    """Episodes (insertions) the jobs simulate: ``run.insertions`` each (the seed changes it not)."""
    per_group: dict[str, int] = {}
    for j in jobs:
        if j.group not in per_group:
            per_group[j.group] = j.config().run.insertions
    return sum(per_group[j.group] for j in jobs)
