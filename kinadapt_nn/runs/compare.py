"""``kinadapt compare``: every features type on the same held-out tools, side by side.

Tool families:
* ``nominal``    -- rigid tools on the nominal arm (the adjoint represents them exactly);
* ``arm_errors`` -- the same kind of tools on an arm with small kinematic errors (link lengths,
  joint zero offsets), which the 3-parameter adjoint cannot represent.

Tools are drawn with ``seed`` (never the pretraining seed, so they are held out): lateral
offset uniform in a disc, length ``100 mm +- length_spread`` (the depth channel uses the
nominal length, so a long tool would bottom out in the 50 mm bore before ``d`` reads 45 mm).
Each (scenario, family, features, tool) episode writes one TensorBoard run with the same tags
and hparams; the table ``comparison.csv`` / ``comparison.md`` has one row per (scenario,
features, tool family), and ``jacobian_error.png`` the Jacobian error vs time per features type.
A work-cell scenario (``cell.bores_w_m``, ``run.insertions``) adds one row per insertion
(``insertion`` 0 = before the first; ``jacobian_error_cell_median``: the median over tools of the
cell Jacobian error on the held-out configurations, ``kinadapt_nn.runs.cell``), the run's row
``insertion = "all"``, the TensorBoard scalar ``cell/jacobian_error_median`` (step = insertion) and
``cell_learning.png`` (cell error vs insertion, every features type, every family).
"""

from __future__ import annotations

import csv
import itertools
import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from kinadapt_nn.config import load_toml_model
from kinadapt_nn.errors import ConfigError
from kinadapt_nn.features import FEATURES, compared_types, features_spec
from kinadapt_nn.runs.jobs import Job, Runner, Task, group_tasks, run_task_cells

FAMILIES = ("nominal", "arm_errors")


class CompareCfg(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    features: list[str] = Field(default_factory=compared_types)  # features types to compare (default: all but the oracle)
    families: list[str] = list(FAMILIES)  # tool families
    n_tools: int = Field(4, ge=1, le=200)  # tools per family
    seed: int = Field(1000, ge=0)  # draws the tools and arm errors (not the pretraining seed)
    lateral_radius_m: float = Field(0.006, ge=0.0)  # [m] tool lateral offset disc
    length_spread_m: float = Field(0.003, ge=0.0, le=0.004)  # [m] tool length 0.100 +- this
    link_sigma_m: float = Field(0.001, ge=0.0)  # [m] arm_errors: link length error std
    joint_sigma_rad: float = Field(0.004, ge=0.0)  # [rad] arm_errors: joint zero offset std
    jobs: int = Field(2, ge=1, le=64)  # worker processes
    base: list[str] = []  # overrides applied to every episode (online config keys)
    laws: list[str] = []  # adaptation laws to compare (adaptation.mode values); [] = the default law only
    scenarios: dict[str, list[str]] = {
        "bore": [],
        "socket_dither": ["scene.contact_model=socket", "control.dither_rad_s=[0.05,0.05,0.05]"],
        "socket_dither_x3": ["scene.contact_model=socket", "control.dither_rad_s=[0.05,0.05,0.05]", "run.insertions=3"],
    }


def load_compare_config(path: Path | None, overrides=()) -> CompareCfg:
    cfg = load_toml_model(CompareCfg, path, overrides, "online/compare.toml")
    for f in cfg.features:
        features_spec(f, key="features")
    from kinadapt_nn.controller.laws import LAWS as MODES

    for law in cfg.laws:
        if law not in MODES:
            raise ConfigError(f"compare: unknown law {law!r} (choose from {', '.join(MODES)})")
    for f in cfg.families:
        if f not in FAMILIES:
            raise ConfigError(f"compare: unknown tool family {f!r} (choose from {', '.join(FAMILIES)})")
    return cfg


def draw_tools(cfg: CompareCfg) -> dict[str, list[list[str]]]:
    """Per family, a list of override lists describing each (tool, arm). Deterministic."""
    from kinadapt_nn.sim.truth import random_arm_errors

    rng = np.random.default_rng(cfg.seed)
    tools = []
    for _ in range(cfg.n_tools):
        rad = cfg.lateral_radius_m * math.sqrt(rng.random())
        ang = 2 * math.pi * rng.random()
        length = 0.100 + rng.uniform(-cfg.length_spread_m, cfg.length_spread_m)
        tools.append([round(float(rad * math.cos(ang)), 6), round(float(rad * math.sin(ang)), 6), round(float(length), 6)])
    out: dict[str, list[list[str]]] = {}
    for fam in cfg.families:
        rows = []
        for t in tools:
            over = [f"tool.offset_f_m={t}"]
            if fam == "arm_errors":
                link, joint = random_arm_errors(rng, cfg.link_sigma_m, cfg.joint_sigma_rad)
                over += [f"arm.link_length_error_m={[round(float(x), 7) for x in link]}",
                         f"arm.joint_offset_rad={[round(float(x), 7) for x in joint]}"]
            rows.append(over)
        out[fam] = rows
    return out


@dataclass(frozen=True)
class CompareJob(Job):
    """One run of the comparison: a (scenario, family, features, law) on one tool."""

    scenario: str = ""
    family: str = ""  #: tool family (``FAMILIES``)
    features: str = ""  #: features type
    tool: int = 0  #: tool index within its family (``draw_tools``)
    tb_dir: str = ""  #: its TensorBoard folder
    law: str | None = None  #: adaptation.mode; None: the config's default law


#: tool cells per task in ``kinadapt compare``. Measured on the 2-core VM, 2 workers, the bore
#: scenario only: 24 episodes, 6.01 s with 8 per batch, 6.18 s with 4, 6.15-6.28 s as single
#: episodes; 72 episodes, 16.72 s with 8 per batch, 17.6 s with 4, 16.6-16.9 s single. In one
#: process, 8 adjoint episodes take 0.83 of their single-episode time batched, 8 RBF ones 0.99
#: (``benchmarks/bench_traced_batch.py``): the step kernel and each episode's fixed costs (start
#: pose, offline evaluation) are the same either way, and the pool already keeps both cores busy.
BATCH_MAX = 8


def compare_tasks(jobs: list[CompareJob], batch_max: int | None = None) -> list[Task]:
    """The comparison's tasks (``runs.jobs.group_tasks``): the tools of the same scenarios,
    features and law stepped together (at most ``batch_max`` tools, default :data:`BATCH_MAX`),
    runs that differ only in ``run.insertions`` simulated once. A task's cost: its tools' longest
    jobs' (``FeaturesSpec.cost`` x insertions), times 0.85 for a batch (measured: a batch of 8
    costs ~0.85 of its single episodes)."""
    tasks = group_tasks(jobs, batch_max or BATCH_MAX, cost=_job_cost)
    return [replace(t, cost=0.85 * t.cost) if len(t.cells) > 1 else t for t in tasks]


def _job_cost(job: CompareJob) -> float:
    """A job's expected cost: the features type's (``FeaturesSpec.cost``) x insertions."""
    ins = [o.split("=", 1)[1] for o in job.overrides if o.startswith("run.insertions=")]
    spec = FEATURES.get(job.features)
    return (spec.cost if spec else 1.0) * (int(ins[-1]) if ins and ins[-1].isdigit() else 1)


def _run_task(task: Task, report) -> list[dict]:
    """A task's jobs (``runs.jobs.run_task_cells``), each one's row material; writes each job's
    TensorBoard run."""
    return [_job_result(job, cfg, res) for job, (cfg, res) in zip(task.jobs, run_task_cells(task, report))]


def _job_result(job: CompareJob, cfg, res) -> dict:
    """A job's row material from its run ``res``; writes its TensorBoard run."""
    from kinadapt_nn.runs.insertions import judged_whole
    from kinadapt_nn.runs.outcome import monitor_brief
    from kinadapt_nn.runs.tb import write_run

    s = judged_whole(res.summary)  # several insertions: judged from the first one's start to the last one's end
    hp = {"features": job.features, "tool_family": job.family, "scenario": job.scenario, "tool": job.tool,
          "n_params": int(s["n_params"]), "law": s["law"]}
    write_run(Path(job.tb_dir), res.trace, s, hp)  # (--monitor: its events as text beside the trace's monitor_z)
    t = res.trace["t_s"]
    idx = np.arange(0, len(t), 10)
    return {
        "scenario": job.scenario, "tool_family": job.family, "features": job.features, "tool": job.tool,
        "summary": s, "law": cfg.adaptation.mode,
        "t": t[idx].tolist(), "jac_err": res.trace["truth_jacobian_rel_error"][idx].tolist(),
        "insertions": s.get("insertions"), "cell": s.get("cell"),
        "monitor": s.get("monitor"), "monitor_brief": monitor_brief(s),
    }


def _median(xs):
    xs = [x for x in xs if x is not None and not (isinstance(x, float) and math.isnan(x))]
    return float(np.median(xs)) if xs else None


def compare_jobs(cfg: CompareCfg, out: Path) -> list[CompareJob]:
    """Every run of the comparison, the tools drawn by :func:`draw_tools`."""
    tools = draw_tools(cfg)
    jobs = []
    laws = list(cfg.laws) or [None]
    for scen, scen_over in cfg.scenarios.items():
        for fam, rows in tools.items():
            for feat in cfg.features:
                for law in laws:
                    for i, over in enumerate(rows):
                        tb = out / "tb" / scen / fam / feat / (f"{law}/" if len(laws) > 1 else "") / f"tool{i}"
                        over_all = (*cfg.base, *scen_over, *over, f"run.features={feat}",
                                    *([f"adaptation.mode={law}"] if law else []))
                        jobs.append(CompareJob(id=f"{scen}/{fam}/{feat}/{law or ''}/tool{i}", overrides=over_all,
                                               scenario=scen, family=fam, features=feat, tool=i, tb_dir=str(tb),
                                               law=law))
    return jobs


def run_compare(cfg: CompareCfg, out: Path, progress: bool = True, worker_setup=None) -> list[dict]:
    """Run every episode, write tb/, comparison.csv/.md and jacobian_error.png into ``out``; with the live
    monitor on (``base`` sets ``monitor.enabled``; ``worker_setup`` registers it in each worker,
    ``runs.jobs.Runner``) also ``monitor.json`` (each run's events) and the table's monitor columns."""
    results = _run_jobs(cfg, out, progress, worker_setup)
    rows = _rows(cfg, results)
    if any(r["monitor_brief"] is not None for r in results):
        _monitor_json(results, out / "monitor.json")
    cols = list(rows[0].keys()) if rows else []
    with open(out / "comparison.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=cols)
        w.writeheader()
        w.writerows(rows)
    (out / "comparison.md").write_text(_markdown(rows, cols))
    _figure(results, cfg, out / "jacobian_error.png")
    if any(r.get("cell") for r in results):
        from kinadapt_nn.figures import cell_learning_figure, save_figure

        save_figure(cell_learning_figure(results), out / "cell_learning.png")
    return rows


def _run_jobs(cfg: CompareCfg, out: Path, progress: bool, worker_setup=None) -> list[dict]:
    """Every job of the comparison on ``cfg.jobs`` workers (``runs.jobs.Runner``) -> each job's
    row material (:func:`_job_result`), in :func:`compare_jobs`' order."""
    jobs = compare_jobs(cfg, out)
    tasks = compare_tasks(jobs)  # single episodes batched; insertion prefixes once

    def figures() -> None:  # matplotlib, while the workers run: the figure then only draws
        import kinadapt_nn.figures  # noqa: F401

    with Runner(cfg.jobs, progress=progress, setup=worker_setup) as runner:
        kinds = {(j.features, j.law): j for j in jobs}  # the tool changes no kernel
        runner.precompile(j.config() for j in kinds.values())  # before the workers
        per_task = runner.run(_run_task, tasks, f"compare ({len(jobs)} runs)", meanwhile=figures)
    index = {j.id: i for i, j in enumerate(jobs)}
    results: list = [None] * len(jobs)
    for task, res in zip(tasks, per_task):
        for job, r in zip(task.jobs, res):
            results[index[job.id]] = r
    return results


def _rows(cfg: CompareCfg, results: list[dict]) -> list[dict]:
    """The table: one row per (scenario, features, family, law); a work cell adds one per insertion."""
    rows = []
    law_names = list(dict.fromkeys(r["law"] for r in results))
    for scen, feat, fam, law in itertools.product(cfg.scenarios, cfg.features, cfg.families, law_names):
        grp = [r["summary"] for r in results
               if (r["scenario"], r["features"], r["tool_family"], r["law"]) == (scen, feat, fam, law)]
        if not grp:
            continue
        rows.append({
            "scenario": scen,
            "features": feat,
            "tool_family": fam,
            "law": law,
            "episodes": len(grp),
            "success_rate": sum(g["success"] for g in grp) / len(grp),
            "seat_time_s_median": _median([g["seat_time_s"] for g in grp]),
            "jacobian_rel_error_initial_median": _median([g["jacobian_rel_error_initial"] for g in grp]),
            "jacobian_rel_error_final_median": _median([g["jacobian_rel_error_final"] for g in grp]),
            "pred_error_rms_median": _median([g["pred_error_rms_contact_w"] for g in grp]),
            "offset_error_lateral_final_m_median": _median([g["offset_error_lateral_final_m"] for g in grp]),
            "min_lambda_JJt_median": _median([g["min_lambda_JJt"] for g in grp]),
            "contact_transitions_per_s_median": _median([g.get("contact_transitions_per_s") for g in grp]),
            "longest_contact_span_s_median": _median([g.get("longest_contact_span_s") for g in grp]),
            "n_params": grp[0]["n_params"],
            "wall_time_s_median": _median([g["wall_time_s"] for g in grp]),
            "insertion": None,
            "jacobian_error_cell_median": None,
        })
        briefs = [r["monitor_brief"] for r in results
                  if (r["scenario"], r["features"], r["tool_family"], r["law"]) == (scen, feat, fam, law)]
        if any(b is not None for b in briefs):  # --monitor: per run (tool), its events and their shapes
            rows[-1]["monitor_events"] = " ".join(str(b.events) for b in briefs)
            rows[-1]["monitor_shapes"] = _shape_counts(briefs)
        cells = [g["cell"] for g in grp if g.get("cell")]
        if cells:  # a work cell: one row per insertion (0 = before the first), medians over tools
            rows += _cell_rows(rows.pop(), grp, cells)
    return rows


def _shape_counts(briefs: list) -> str:
    """The shapes the runs' monitors named, with how many runs named each: ``"world_force x4"``
    (``-``: none)."""
    counts: dict[str, int] = {}
    for b in briefs:
        for sh in dict.fromkeys(b.shapes if b is not None else []):
            counts[sh] = counts.get(sh, 0) + 1
    return ", ".join(f"{k} x{v}" for k, v in counts.items()) or "-"


def _monitor_json(results: list[dict], path: Path) -> None:
    """``monitor.json``: per run (its job's TensorBoard folder's name, ``scenario/family/features/tool``)
    how many events, their shapes and its monitor's summary (the last insertion's for a work cell)."""
    from kinadapt_nn.runio import write_json

    write_json(path, {"/".join((r["scenario"], r["tool_family"], r["features"], r["law"], f"tool{r['tool']}")):
                      {"events": r["monitor_brief"].events, "shapes": r["monitor_brief"].shapes,
                       "monitor": r["monitor"]} for r in results if r["monitor_brief"] is not None})


def _cell_rows(row: dict, grp: list[dict], cells: list[dict]) -> list[dict]:
    """A work cell's rows: its run's (``insertion = "all"``, the cell error after the last
    insertion) and one per insertion (0 = before the first), medians over tools."""
    row = dict(row, insertion="all",
               jacobian_error_cell_median=_median([c["jacobian_error_cell_median"][-1] for c in cells]))
    rows = [row]
    for k in range(len(cells[0]["jacobian_error_cell_median"])):
        ins = [g["insertions"][k - 1] for g in grp] if k else []

        def med(key: str, ins=ins):
            return _median([r.get(key) for r in ins]) if ins else None

        rows.append({
            "scenario": row["scenario"], "features": row["features"], "tool_family": row["tool_family"],
            "law": row["law"], "episodes": len(grp),
            "success_rate": sum(r["success"] for r in ins) / len(ins) if ins else None,
            "seat_time_s_median": med("seat_time_s"),
            "jacobian_rel_error_initial_median": med("jacobian_rel_error_initial"),
            "jacobian_rel_error_final_median": med("jacobian_rel_error_final"),
            "pred_error_rms_median": None,
            "offset_error_lateral_final_m_median": med("offset_error_lateral_final_m"),
            "min_lambda_JJt_median": None,
            "contact_transitions_per_s_median": med("contact_transitions_per_s"),
            "longest_contact_span_s_median": med("longest_contact_span_s"),
            "n_params": grp[0]["n_params"], "wall_time_s_median": None,
            "insertion": k,
            "jacobian_error_cell_median": _median([c["jacobian_error_cell_median"][k] for c in cells]),
        })
        if "monitor_events" in row:  # --monitor: each insertion's own monitor, per run (tool)
            from kinadapt_nn.runs.outcome import MonitorBrief

            briefs = [MonitorBrief(r["monitor_events"], r["monitor_shapes"]) for r in ins]
            rows[-1]["monitor_events"] = " ".join(str(b.events) for b in briefs) if ins else None
            rows[-1]["monitor_shapes"] = _shape_counts(briefs) if ins else None
    return rows


def _fmt(v) -> str:
    if v is None:
        return "–"
    if isinstance(v, float):
        return f"{v:.3g}"
    return str(v)


def _markdown(rows: list[dict], cols: list[str]) -> str:
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for r in rows:
        lines.append("| " + " | ".join(_fmt(r.get(c)) for c in cols) + " |")
    note = ("\npred_error_rms: W-scaled prediction error RMS in contact; jacobian errors: |W (J_hat - J_true)| / "
            "|W J_true| at the last step (initial: first step); J_true includes the arm errors.\n")
    if "monitor_events" in cols:
        note += ("monitor_events: the live monitor's events of each run (tool), in tool order; monitor_shapes: the "
                 "shapes they were named, with how many runs named each (monitor.json: every event).\n")
    return "\n".join(lines) + "\n" + note


#: the figure's grid [in]: left (y tick labels + y label), right, top (title), bottom (x label),
#: between columns (the next panel's y labels) and rows (x labels + the next title)
_GRID_IN = dict(left=1.2, right=0.2, top=0.4, bottom=0.6, wgap=1.3, hgap=0.95)


#: how each features type's curves are drawn, in the order of ``cfg.features``: the first widest
#: and lowest, each later one narrower and on top, with its own dashes and sparse markers -- where two
#: types' curves coincide (rbf and neural start from the same prior) both stay visible, the earlier
#: one as the wide band around the later one
_FEATURE_STYLES = (
    {"ls": "-", "lw": 2.6, "alpha": 0.55, "marker": "o"},
    {"ls": (0, (5, 2)), "lw": 1.6, "alpha": 0.9, "marker": "s"},
    {"ls": (0, (1, 1.5)), "lw": 1.1, "alpha": 1.0, "marker": "^"},
    {"ls": (0, (6, 2, 1, 2)), "lw": 0.9, "alpha": 1.0, "marker": "D"},
)
#: markers along each curve (one every 1 / _MARKS of it; each type's shifted so they do not stack)
_MARKS = 8


def _feature_style(k: int, n_points: int, n_types: int) -> dict:
    """Line keywords of the ``k``-th features type (``_FEATURE_STYLES``) for a curve of ``n_points``."""
    st = dict(_FEATURE_STYLES[k % len(_FEATURE_STYLES)])
    step = max(1, n_points // _MARKS)
    return {**st, "color": f"C{k}", "ms": 3.5, "mfc": "none", "zorder": 2 + k,
            "markevery": ((k * step) // max(n_types, 1), step)}


def _figure(results: list[dict], cfg: CompareCfg, path: Path) -> None:
    """Jacobian error vs time, one panel per (scenario, family), one colour, line style and marker
    per features type (``_feature_style``: none hidden under another where their curves coincide).
    Fixed margins (``_GRID_IN``) rather than constrained_layout: its solver measured half of the
    figure's drawing time (it draws every tick label to size them, then the figure again)."""
    from kinadapt_nn.figures import labelled_ticks, plt

    scen = list(cfg.scenarios)
    fams = list(cfg.families)
    w, h = 5.5 * len(fams), 3.6 * len(scen)
    fig, axes = plt.subplots(len(scen), len(fams), figsize=(w, h), squeeze=False)
    g = _GRID_IN
    aw = (w - g["left"] - g["right"] - (len(fams) - 1) * g["wgap"]) / len(fams)
    ah = (h - g["top"] - g["bottom"] - (len(scen) - 1) * g["hgap"]) / len(scen)
    fig.subplots_adjust(left=g["left"] / w, right=1 - g["right"] / w, bottom=g["bottom"] / h, top=1 - g["top"] / h,
                        wspace=g["wgap"] / aw, hspace=g["hgap"] / ah)
    for a, sc in enumerate(scen):
        for b, fam in enumerate(fams):
            ax = axes[a, b]
            n_ins = 1
            for k, feat in enumerate(cfg.features):
                for r in results:
                    if (r["scenario"], r["tool_family"], r["features"]) == (sc, fam, feat):
                        ax.semilogy(r["t"], r["jac_err"], label=feat if r["tool"] == 0 else None,
                                    **_feature_style(k, len(r["t"]), len(cfg.features)))
                        n_ins = len(r["insertions"] or [None])
            # several insertions: the trace is the last one's (its own clock from 0)
            ax.set_title(f"{sc} / {fam}" + (f": insertion {n_ins} of {n_ins}" if n_ins > 1 else ""))
            ax.set_xlabel("time [s]" if n_ins == 1 else f"time in insertion {n_ins} [s]")
            ax.set_ylabel("|W(J_hat - J_true)| / |W J_true|")
            labelled_ticks(ax.yaxis)
            ax.legend(fontsize=8)
    fig.savefig(path, dpi=120)
    plt.close(fig)
