"""Insertions in sequence: a work cell (one tool, one arm, several bores) and its prefixes, for one
cell or several cells stepped together on the batched kernels.

Insertion i of a cell aims at bore ``cell.bore_of(i)`` of ``cell.bores_w_m`` (the scene's one bore
without a cell) with seed ``run.seed + i`` (its start jitter); the controller's theta and its
law's covariance are carried from one insertion to the next (``cell.between = "refit"``: theta is
refitted on every logged insertion in between, ``kinadapt_nn.runs.refit``). Cells that differ only
in the hidden truth (tool, arm errors, seed) run their insertion i as one batch
(``runs.batch.run_episodes``): each cell's results are what it gives alone, to the last bit but
the wall times (``tests/runs/test_cell.py``).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from kinadapt_nn.config import ExperimentCfg
from kinadapt_nn.controller import core
from kinadapt_nn.controller.controller import Controller
from kinadapt_nn.errors import ConfigError
from kinadapt_nn.runs.batch import compile_loop, run_episodes
from kinadapt_nn.runs.build import make_controller
from kinadapt_nn.runs.episode import EpisodeResult, run_episode


def run_insertions(cfg: ExperimentCfg, progress: bool = False) -> EpisodeResult:
    """``run.insertions`` consecutive insertions of the same tool on the same arm (a work cell, module
    docstring). Each insertion seats or fails on its own. -> the last insertion's result, with
    ``summary["insertions"]`` one row per insertion and, for a work cell, ``summary["cell"]``:
    the cell Jacobian error on the held-out configurations before the first insertion and after
    each (``kinadapt_nn.runs.cell``, truth side). One insertion without a cell is ``run_episode``."""
    n = cfg.run.insertions
    return run_insertion_prefixes(cfg, [n], progress)[n]


def run_insertion_prefixes(cfg: ExperimentCfg, counts, progress: bool = False) -> dict[int, EpisodeResult]:
    """:func:`run_insertions` for several ``run.insertions`` at once (``counts``, each >= 1;
    ``cfg.run.insertions`` is ignored): insertion i depends only on the insertions before it, so
    the run of max(counts) insertions holds the others as its prefixes. -> {k: the result
    ``run_insertions`` gives with ``run.insertions = k``}, each with its own summary (the rows of
    its k insertions, the cell error up to insertion k)."""
    return run_cells([cfg], counts, progress)[0]


def _cell_layout(cfg: ExperimentCfg, n: int) -> tuple:
    """What cells stepped together must share: the bores and the order they are visited in."""
    return tuple(map(tuple, cfg.cell.bores(cfg.scene))), tuple(cfg.cell.bore_of(i) for i in range(n)), \
        cfg.cell.between


def run_cells(cfgs: list[ExperimentCfg], counts, progress: bool = False,
              on_insertion: Callable[[int], None] | None = None) -> list[dict[int, EpisodeResult]]:
    """:func:`run_insertion_prefixes` for every config of ``cfgs`` -- cells that differ only in the
    hidden truth (tool, arm errors, seed) -- with insertion i of every cell stepped as one batch
    (``runs.batch.run_episodes``; one cell: ``run_episode``, with its progress bar). -> one
    {k: result} per config, each what ``run_insertion_prefixes(cfg, counts)`` gives (to the last
    bit, but ``wall_time_s``: the insertion's share of the batch). Cells with other bores, bore
    order or refit settings, or any other known setting, get a ``ConfigError``. ``on_insertion(n)``
    is called as each insertion's batch steps (n: the episodes' share of the steps done, a fraction
    of len(cfgs)) and as it ends (the rest): a job runner's progress, in episodes."""
    tell = on_insertion or (lambda _n: None)
    counts = sorted({int(k) for k in counts})
    if not counts or counts[0] < 1:
        raise ValueError(f"insertion counts must be >= 1, got {counts}")
    if not cfgs:
        return []
    n = counts[-1]
    layout = _cell_layout(cfgs[0], n)
    if any(_cell_layout(c, n) != layout for c in cfgs[1:]):
        raise ConfigError("cells run together share cell.bores_w_m, their order and cell.between; these differ "
                          "-- run them separately")
    is_cell = bool(cfgs[0].cell.bores_w_m)
    told = [0.0]  # episodes reported during the current insertion's batch

    def share(f: float) -> None:
        told[0] += len(cfgs) * f
        tell(len(cfgs) * f)

    def finish() -> None:  # the insertion's rest (its episodes may stop before the batch's last step)
        tell(len(cfgs) - told[0])
        told[0] = 0.0

    steps = share if on_insertion is not None else None
    if n == 1 and not is_cell:
        out = [{1: r} for r in _episodes(cfgs, [None] * len(cfgs), progress, False, steps)]
        finish()
        return out
    with core.compiling(progress) as phase:  # a first run's one-time compile: its own bar
        ctrls = [make_controller(c) for c in cfgs]
        for k in ctrls:
            k.compile_kernels()
        compile_loop(cfgs[0])  # the episode loop's and the scenes' kernels too (a two-step episode)
    compile_s = phase.wall_s if phase.cold else 0.0  # reported apart from the insertions' wall times
    cells = [_Cell(c, k) for c, k in zip(cfgs, ctrls)]
    bar = None
    if progress:  # the insertions' own bar above each episode's
        from tqdm import tqdm

        bar = tqdm(total=n, desc="insertions", unit="insertion", leave=False)
    keep = cells[0].refit is not None  # a refit between insertions needs the regressor rows
    for i in range(n):
        cfg_i = [_start_insertion(c, k, i) for c, k in zip(cfgs, ctrls)]
        for cell, r in zip(cells, _episodes(cfg_i, ctrls, progress, keep, steps)):
            cell.after(i, r, counts, is_cell)
        finish()
        if bar is not None:
            bar.update(1)
    if bar is not None:
        bar.close()
    for cell in cells:
        for r in cell.out.values():
            r.summary["compile_time_s"] = compile_s
    return [cell.out for cell in cells]


def judged_whole(summary: dict) -> dict:
    """A run of several insertions judged from the first insertion's start to the last one's end
    (``kinadapt compare``'s rows, ``kinadapt sweep``'s records): ``success`` only when every
    insertion seated, ``failure`` the first failed insertion's class ("none" else),
    ``jacobian_rel_error_initial`` the first insertion's, ``insertions_seated`` how many seated
    and, for a work cell, ``jacobian_error_cell_median_final`` (after the last insertion); the
    other fields are the last insertion's. A one-insertion summary is returned as it is."""
    rows = summary.get("insertions")
    if not rows:
        return summary
    failed = [r for r in rows if not r["success"]]
    out = dict(summary, success=not failed, failure=failed[0]["failure"] if failed else "none",
               jacobian_rel_error_initial=rows[0]["jacobian_rel_error_initial"],
               insertions_seated=len(rows) - len(failed))
    if summary.get("cell"):
        out["jacobian_error_cell_median_final"] = summary["cell"]["jacobian_error_cell_median"][-1]
    return out


def _episodes(cfgs: list[ExperimentCfg], ctrls: list, progress: bool, keep_regressor: bool,
              on_steps: Callable[[float], None] | None = None) -> list[EpisodeResult]:
    """One episode per (cfg, ctrl) (ctrl None: a new one), stepped as one batch (``run_episodes``;
    the steps' progress bar for one episode alone, else ``on_steps``); each result is the episode's own."""
    return run_episodes(cfgs, ctrls, keep_regressor=keep_regressor, progress=progress and len(cfgs) == 1,
                        on_steps=on_steps)


def run_insertion(cfg: ExperimentCfg, ctrl: Controller, i: int, progress: bool = False,
                  keep_regressor: bool = False) -> EpisodeResult:
    """Insertion ``i`` (0-based) of a work cell with the controller ``ctrl`` carried over: bore
    ``cell.bore_of(i)``, seed ``run.seed + i``; theta and the law's state kept from insertion i - 1
    (``reset(carry_estimate=True)``). ``keep_regressor`` as for ``run_episode``."""
    return run_episode(_start_insertion(cfg, ctrl, i), progress, ctrl=ctrl, keep_regressor=keep_regressor)


def _finite_or_none(x: float | None) -> float | None:
    return float(x) if x is not None and math.isfinite(x) else None


def _start_insertion(cfg: ExperimentCfg, ctrl: Controller, i: int) -> ExperimentCfg:
    """Carry ``ctrl`` into insertion ``i`` (0-based) of ``cfg``'s cell: theta and the law's state
    kept from insertion i - 1 (``reset(carry_estimate=True)``), aimed at bore ``cell.bore_of(i)``.
    -> the insertion's config: seed ``run.seed + i``, the scene's bore there."""
    bore = tuple(cfg.cell.bores(cfg.scene)[cfg.cell.bore_of(i)])
    if i:
        ctrl.reset(carry_estimate=True)
    ctrl.set_bore(bore)
    return cfg.model_copy(update={"run": cfg.run.model_copy(update={"seed": (cfg.run.seed + i) % 2**32}),
                                  "scene": cfg.scene.model_copy(update={"bore_entry_w_m": bore})})


class _Cell:
    """One cell's bookkeeping between insertions: its refit, the held-out cell error (truth side,
    evaluation only), the per-insertion rows and the results of its prefixes."""

    def __init__(self, cfg: ExperimentCfg, ctrl: Controller) -> None:
        from kinadapt_nn.runs.cell import CellJacobianError

        self.cfg, self.ctrl = cfg, ctrl
        self.truth = CellJacobianError(cfg, ctrl)
        self.cell_err = [self.truth.median(ctrl)]  # insertion 0: before the first
        self.refit = None
        if cfg.cell.between == "refit":
            from kinadapt_nn.runs.refit import Refit

            neural = cfg.run.features == "neural"
            cap = cfg.cell.refit_max_directions_neural if neural else 0
            # the evidence prior (default on) gives way to the timing offset's refit when that is asked for
            choice = cfg.cell.refit_neural_prior_choice if neural and cfg.cell.refit_timing_sd_s <= 0 else 0.0
            alt = ctrl.features.prior_cov("calibrated_arm") if choice > 0 else None
            self.refit = Refit(ctrl, cfg.cell.refit_channels, cfg.cell.refit_prior_weight,
                               timing_sd_s=cfg.cell.refit_timing_sd_s, max_directions=cap, alt_prior_cov=alt,
                               alt_evidence_per_insertion=choice)
            self.refit.step_sd = cfg.cell.refit_step_sd  # the trust region between insertions
        self.rows: list[dict] = []
        self.out: dict[int, EpisodeResult] = {}

    def after(self, i: int, res: EpisodeResult, counts: list[int], is_cell: bool) -> None:
        """Insertion ``i`` (0-based) has run with result ``res``: refit, judge, record."""
        cfg, ctrl, s = self.cfg, self.ctrl, res.summary
        refit_note = self.refit.after_insertion(res.trace) if self.refit is not None else None
        if i == 0 and 1 in counts and not is_cell:  # one insertion without a cell: what run_episode gives
            res.trace.arrays.pop("law_Phi_fT", None)
            self.out[1] = EpisodeResult(res.trace, dict(s))
        errs = self.truth.errors(ctrl)
        self.cell_err.append(float(np.median(errs)))
        bores = cfg.cell.bores(cfg.scene)
        b = cfg.cell.bore_of(i)
        self.rows.append({"insertion": i + 1, "bore": b, "bore_entry_w_m": list(bores[b]), "success": s["success"],
                          "failure": s["failure"], "seat_time_s": s["seat_time_s"],
                          "jacobian_rel_error_initial": s["jacobian_rel_error_initial"],
                          "jacobian_rel_error_final": s["jacobian_rel_error_final"],
                          "jacobian_error_cell_median": self.cell_err[-1],
                          "jacobian_error_cell_p90": float(np.percentile(errs, 90)),
                          "offset_error_lateral_final_m": s.get("offset_error_lateral_final_m"),
                          "theta_uncertainty": _finite_or_none(ctrl.law.uncertainty_ratio()),
                          "identified": s["identification"].get("identified"),
                          "refit": refit_note,
                          "theta_sd_final": s.get("theta_sd_final"), "max_force_N": s["max_force_N"]})
        if s.get("monitor"):  # the insertion's own live monitor (a new one each insertion): what it found
            self.rows[-1]["monitor_events"] = len(s["monitor"]["events"])
            self.rows[-1]["monitor_shapes"] = [e["shape"] for e in s["monitor"]["events"]]
        k = i + 1
        if k in counts and k not in self.out:
            self.out[k] = EpisodeResult(res.trace, dict(s, insertions=list(self.rows), cell={
                "bores_w_m": [list(x) for x in bores],
                "order": [cfg.cell.bore_of(j) for j in range(k)],
                "between": cfg.cell.between,
                "heldout_configurations": int(len(self.truth.q)),
                "jacobian_error_cell_median": list(self.cell_err),  # [before the first, after insertion 1, ..., k]
                "all_seated": all(r["success"] for r in self.rows),
            }))
