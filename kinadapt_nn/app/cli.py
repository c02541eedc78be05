"""``kinadapt`` command line: parse, load a config, call the library. No algorithm here.

Exit codes:

====  ==============================================================================
 0    done (``online``: seated / excitation completed)
 1    ``online`` only: the episode ran to the end but did not seat (outputs written)
 2    bad input: a bad option, config key or value (NaN/inf included), a missing or damaged
      file, an existing output folder -- one line on stderr, nothing written
 3    internal error (a bug): one line on stderr naming a log file with the traceback (in the
      output folder of a command that writes in place -- ``pretrain``, ``sweep`` -- else a
      temp file)
130   interrupted (Ctrl-C)
====  ==============================================================================

MuJoCo's own log (``MUJOCO_LOG.TXT``) never lands in the working directory: it goes to a temp
file while a command runs (``kinadapt_nn.app.mjlog``) and, when MuJoCo wrote one, into the run
folder afterwards (else its path is printed).
"""

from __future__ import annotations

import argparse
import logging
import math
import os
import shutil
import sys
import tempfile
import time
import traceback
from pathlib import Path
from typing import NoReturn

from kinadapt_nn import __version__
from kinadapt_nn.errors import KinadaptError, OutputExistsError, did_you_mean

log = logging.getLogger("kinadapt")

EXIT_OK, EXIT_NOT_SEATED, EXIT_BAD_INPUT, EXIT_INTERNAL, EXIT_INTERRUPTED = 0, 1, 2, 3, 130


class _Parser(argparse.ArgumentParser):
    """argparse with the CLI's bad-input contract: one line on stderr, exit 2 (no usage dump)."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_BAD_INPUT, f"kinadapt: error: {message} (see {self.prog} --help)\n")

    def _check_value(self, action: argparse.Action, value) -> None:
        """argparse's check of a choice (a subcommand, ``--executor``), naming the closest valid one."""
        try:
            super()._check_value(action, value)
        except argparse.ArgumentError:
            hint = did_you_mean(value, action.choices) if isinstance(value, str) else ""
            if not hint:
                raise
            raise argparse.ArgumentError(action, f"invalid choice: {value!r}; {hint} (choose from "
                                                 f"{', '.join(map(repr, action.choices))})") from None


def _int_in(lo: int, hi: int):
    """argparse type: an integer in [lo, hi]."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"{value} is outside [{lo}, {hi}]")
        return value

    return parse


def _float_in(lo: float, hi: float):
    """argparse type: a finite number in (lo, hi] (lo excluded: every such option is a positive quantity)."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
        if not (math.isfinite(value) and lo < value <= hi):
            raise argparse.ArgumentTypeError(f"{text} is outside ({lo:g}, {hi:g}]")
        return value

    return parse


class _Once(argparse.Action):
    """argparse action of an option that takes one value: given twice it is an error, not silently the last."""

    def __call__(self, parser, namespace, values, option_string=None) -> None:
        if getattr(namespace, self.dest, None) is not None:
            raise argparse.ArgumentError(self, f"given twice ({getattr(namespace, self.dest)!r} and {values!r}); "
                                               "give it once")
        setattr(namespace, self.dest, values)


def _progress(args: argparse.Namespace, name: str):
    """A ``progress(msg)`` callable: one time-stamped line on stderr per step, silent with --quiet."""
    t0 = time.perf_counter()

    def progress(msg: str) -> None:
        if not args.quiet:
            print(f"kinadapt {name} [{time.perf_counter() - t0:5.1f} s] {msg}", file=sys.stderr, flush=True)

    return progress


def _default_out(kind: str) -> Path:
    return Path("runs") / f"{kind}-{time.strftime('%Y%m%d-%H%M%S')}"


def _summary_lines(summary: dict, out: Path) -> list[str]:
    if summary.get("program") == "excite":
        ok = "EXCITATION COMPLETED" if summary["success"] else f"EXCITATION FAILED ({summary['failure']})"
    else:
        ok = "SEATED" if summary["success"] else f"NOT SEATED ({summary['failure']})"
    seat = f"{summary['seat_time_s']:.3f} s" if summary["seat_time_s"] is not None else "-"
    err = summary["offset_error_final_m"]
    return [
        f"kinadapt online: {ok}   features={summary['features']} law={summary['law']} seed={summary['seed']}",
        _seat_line(summary, seat),
        f"  depth sensor/true  {1e3 * summary['final_depth_m']:.2f} / {1e3 * summary['true_final_depth_m']:.2f} mm",
        f"  max |F| / |F_lat|  {summary['max_force_N']:.1f} / {summary['max_lateral_force_N']:.1f} N   "
        f"max |M| {summary['max_moment_Nm']:.2f} N m",
        f"  min lambda(JJ^T)   {'-' if summary['min_lambda_JJt'] is None else format(summary['min_lambda_JJt'], '.3g')}"
        f"   offset error "
        f"[{', '.join(f'{1e3 * e:+.2f}' for e in err)}] mm",
        f"  lateral drift      free space {1e3 * summary['lateral_drift_free_space_m']:.3f} mm, "
        f"max {1e3 * summary['lateral_drift_max_m']:.3f} mm",
        *([f"  identification     {summary['identification']['text']}"] if summary.get("identification") else []),
        *_cell_lines(summary),
        *_monitor_lines(summary),
        f"  sim {summary['sim_time_s']:.2f} s in {summary['wall_time_s']:.2f} s wall ({summary['steps']} steps)"
        + (f"; the one-time compile before it {summary['compile_time_s']:.1f} s"
           if summary.get("compile_time_s") else ""),
        f"  wrote {out}/ (config.toml, summary.json, trace.npz, rollout.png, tb/)",
    ]


def _seat_line(summary: dict, seat: str) -> str:
    """The seat-time line: the paper's figure beside it only for an insertion (an excitation run
    does not insert, so it has no seat time to compare)."""
    if summary.get("program") == "excite":
        return "  seat time          -   (an excitation run follows its scripted program; it does not insert)"
    return f"  seat time          {seat}   (paper, with adaptation: 5.1 s)"


def _monitor_lines(summary: dict) -> list[str]:
    """The live monitor's lines (``--monitor``): each event as it was printed, or that there was none."""
    mon = summary.get("monitor")
    if not mon:
        return []
    sd = mon["noise_sd"]
    head = (f"  monitor            {len(mon['events'])} event(s); noise sd {max(sd[:3]):.3g} N / {max(sd[3:]):.3g} N m, "
            f"threshold {mon['threshold_sd']:.1f} sd ({mon['false_alarms_per_h']:g} false alarms/h on white noise)")
    return [head, *(f"    {e['line']}" for e in mon["events"])]


def _cell_lines(summary: dict) -> list[str]:
    """A work cell's lines: seated count and the cell Jacobian error after each insertion."""
    cell = summary.get("cell")
    if not cell:
        return []
    rows = summary["insertions"]
    errs = cell["jacobian_error_cell_median"]
    return [f"  work cell          {sum(r['success'] for r in rows)}/{len(rows)} insertions seated over "
            f"{len(cell['bores_w_m'])} bores (last summary lines: insertion {len(rows)})",
            f"  cell J error       {100 * errs[0]:.3f} % before -> "
            + " ".join(f"{100 * e:.3f}" for e in errs[1:]) + " % after each insertion "
            f"(median over {cell['heldout_configurations']} held-out configurations)"]


def _write_online(stage: Path, cfg, result) -> None:
    """The run folder contents (config, summary, trace, figure, TensorBoard) into ``stage``."""
    from kinadapt_nn.config import config_to_toml
    from kinadapt_nn.runio import write_json

    (stage / "config.toml").write_text(config_to_toml(cfg))
    write_json(stage / "summary.json", result.summary)
    result.trace.save(stage / "trace.npz")
    if cfg.run.tensorboard:
        from kinadapt_nn.runs.tb import write_cell_tensorboard, write_tensorboard

        hp = {"features": cfg.run.features, "law": result.summary["law"], "seed": cfg.run.seed}
        write_tensorboard(stage / "tb", result.trace, result.summary, hp)
        write_cell_tensorboard(stage / "tb", result.summary)  # a work cell: error vs insertion
        if result.summary.get("monitor"):
            from kinadapt_nn.runs.tb import write_monitor_events

            write_monitor_events(stage / "tb", result.summary)
    if not cfg.run.figure:
        return
    from kinadapt_nn.figures import rollout_figure, save_figure  # (matplotlib only when a figure is wanted)

    png = stage / "rollout.png"
    save_figure(rollout_figure(result.trace, result.summary, cfg), png)
    if cfg.run.tensorboard:
        from kinadapt_nn.runs.tb import write_tensorboard_figure

        write_tensorboard_figure(stage / "tb", png)


def cmd_online(args: argparse.Namespace) -> int:
    from kinadapt_nn.config import load_config
    from kinadapt_nn.runio import check_output_dir, staged_output

    cfg = load_config(Path(args.config) if args.config else None,
                      [*(args.set or []), *(["monitor.enabled=true"] if args.monitor else []),
                       *(["run.progress=false"] if args.quiet else [])])  # (--quiet: no live lines either)
    out = args.run_dir = Path(args.out) if args.out else _default_out("online")
    check_output_dir(out, args.overwrite)
    if cfg.monitor.enabled:
        import kinadapt_nn.monitor.monitor  # noqa: F401  (registers the live monitor with the episode loop)
    from kinadapt_nn.controller.core import compile_record, kernels_cached
    from kinadapt_nn.runs.insertions import run_insertions

    if not args.quiet and not cfg.run.progress and not kernels_cached():  # (with a bar: its own bar)
        print(f"kinadapt online: compiling the controller's kernels (the first run on this machine, "
              f"~{compile_record():.0f} s, once)", file=sys.stderr, flush=True)
    result = run_insertions(cfg, progress=cfg.run.progress and not args.quiet)
    with staged_output(out, args.overwrite) as stage:
        _write_online(stage, cfg, result)
    if not args.quiet:
        print("\n".join(_summary_lines(result.summary, out)))
    return 0 if result.summary["success"] else 1


def cmd_pretrain(args: argparse.Namespace) -> int:
    from kinadapt_nn.learning.pretrain import load_pretrain_config, pretrain

    cfg = load_pretrain_config(Path(args.config) if args.config else None, args.set or [])
    out = Path(args.out) if args.out else _default_out("pretrain")
    if out.exists() and not out.is_dir():
        raise OutputExistsError(f"output path '{out}' exists and is not a folder")
    if out.exists() and any(out.iterdir()) and not (out / "train_state.pt").exists() and not args.overwrite:
        raise OutputExistsError(f"output folder '{out}' already exists (pass --overwrite or choose another --out)")
    if args.overwrite and out.exists():  # start afresh, even over a (maybe damaged) resume state
        shutil.rmtree(out)
    args.run_dir = out
    try:
        m = pretrain(cfg, out, progress=not args.quiet)
    except KeyboardInterrupt:
        print(f"kinadapt: interrupted; rerun the same command to resume from {out}/train_state.pt", file=sys.stderr)
        return 130
    if not args.quiet:
        print(
            f"kinadapt pretrain: {m['steps']} steps in {m['wall_time_s']:.1f} s on {m['device']}; "
            f"p = {m['n_params_online']} online parameters, body {m['n_params_body']}\n"
            f"  held-out relative Jacobian error (median): {m['heldout_rel_jacobian_error_median']:.2e} "
            f"(nominal arm {m['heldout_rel_jacobian_error_median_nominal_arm']:.2e}, "
            f"arm errors {m['heldout_rel_jacobian_error_median_arm_errors']:.2e}); "
            f"adjoint best fit: nominal arm {m['adjoint_best_fit_rel_error_median_nominal_arm']:.1e}, "
            f"arm errors {m['adjoint_best_fit_rel_error_median_arm_errors']:.2e}\n"
            f"  wrote {out}/model.safetensors, metrics.json, tb/"
        )
    return 0


def cmd_compare(args: argparse.Namespace) -> int:
    from kinadapt_nn.runs.compare import load_compare_config, run_compare
    from kinadapt_nn.runio import check_output_dir, staged_output

    cfg = load_compare_config(Path(args.config) if args.config else None, args.set or [])
    out = args.run_dir = Path(args.out) if args.out else _default_out("compare")
    check_output_dir(out, args.overwrite)
    with staged_output(out, args.overwrite) as stage:
        run_compare(cfg, stage, progress=not args.quiet)
    if not args.quiet:
        print((out / "comparison.md").read_text())
        wrote = [f for f in ("comparison.csv", "comparison.md", "jacobian_error.png", "cell_learning.png")
                 if (out / f).is_file()]
        print(f"wrote {out}/ ({', '.join(wrote)}, tb/)")
    return 0


def cmd_view(args: argparse.Namespace) -> int:
    import os

    run = Path(args.run)
    if args.out is None and os.environ.get("DISPLAY"):
        from kinadapt_nn.app.view import view_interactive

        view_interactive(run)
        return 0
    from kinadapt_nn.app.view import render_run

    out = Path(args.out) if args.out else run / "rollout.gif"
    if out.exists() and not args.overwrite:
        raise OutputExistsError(f"video '{out}' already exists (pass --overwrite or choose another --out)")
    n = render_run(run, out, fps=args.fps, width=args.width, height=args.height, camera=args.camera, max_s=args.max_s,
                   progress=not args.quiet)
    if not args.quiet:
        print(f"kinadapt view: wrote {out} ({n} frames at {args.fps:g} fps)")
    return 0


def cmd_reproduce(args: argparse.Namespace) -> int:
    from kinadapt_nn.paper.reproduce import PARTS, run_reproduce
    from kinadapt_nn.runio import check_output_dir, staged_output

    if args.only and args.only not in PARTS:
        raise KinadaptError(f"--only {args.only!r}: choose one of {', '.join(PARTS)}")
    out = args.run_dir = Path(args.out) if args.out else _default_out("reproduce")
    check_output_dir(out, args.overwrite)
    t0 = time.perf_counter()
    with staged_output(out, args.overwrite) as stage:
        run_reproduce(stage, only=args.only, jobs=args.jobs, progress=_progress(args, "reproduce"))
    if not args.quiet:
        print((out / "reproduce.md").read_text())
        print(f"wrote {out}/ in {time.perf_counter() - t0:.0f} s (reproduce.json, reproduce.md, figures)")
    return 0


def cmd_sweep(args: argparse.Namespace) -> int:
    import shutil

    from kinadapt_nn.runs.sweep import load_sweep_config, run_sweep

    cfg = load_sweep_config(Path(args.config) if args.config else None, args.set or [])
    out = args.run_dir = Path(args.out) if args.out else _default_out("sweep")
    if out.exists() and not (out / "sweep_config.json").is_file() and any(out.iterdir()):
        if not args.overwrite:
            raise OutputExistsError(f"output folder '{out}' exists and is not a sweep (pass --overwrite or another --out)")
        shutil.rmtree(out)
    try:
        s = run_sweep(cfg, out, executor=args.executor, address=args.address, progress=not args.quiet)
    except KeyboardInterrupt:
        print(f"kinadapt: interrupted; finished episodes are kept in {out}/episodes; rerun to complete", file=sys.stderr)
        return 130
    if not args.quiet:
        lo, hi = s["success_rate_ci95"]
        print(f"kinadapt sweep: {s['episodes']}/{s['episodes_expected']} episodes, success rate "
              f"{s['success_rate']:.3f} (95% CI {lo:.3f}-{hi:.3f})")
        for g, st in s["groups"].items():
            lo, hi = st["success_rate_ci95"]
            med = st["seat_time_s_quantiles"].get("p50")
            print(f"  {g:40s} {st['successes']:4d}/{st['episodes']:<4d} {st['success_rate']:.3f} [{lo:.3f}, {hi:.3f}] "
                  f"seat p50 {med if med is None else round(med, 3)} failures {st['failures']}")
        print(f"wrote {out}/ (sweep.csv, sweep.json, episodes/)")
    return 0


def cmd_diagnose_setup(args: argparse.Namespace) -> int:
    """``kinadapt diagnose LOG --setup SETUP.toml``: a user's log against their declared set-up."""
    import time

    from kinadapt_nn.diagnostics.readers import read_log
    from kinadapt_nn.diagnostics.report import Provenance
    from kinadapt_nn.diagnostics.setup import load_setup
    from kinadapt_nn.diagnostics.userlog import check_request, diagnose
    from kinadapt_nn.runio import check_output_dir

    for opt in ("config", "baseline"):
        if getattr(args, opt, None):
            raise KinadaptError(f"--{opt} is for this package's own runs; with --setup the model is the declared "
                                "set-up (drop the option)")
    if args.rerun:
        raise KinadaptError("--rerun is for this package's own runs; drop it with --setup")
    setup = load_setup(Path(args.setup), args.set or [])
    check_request(setup, list(args.add or []), list(args.effects or []))  # before any log is read
    out = args.run_dir = Path(args.out) if args.out else _default_out("diagnose")
    check_output_dir(out, args.overwrite)
    t0 = time.perf_counter()
    progress = _progress(args, "diagnose")
    logs = [Path(p) for p in args.logs]
    stems = _log_names(logs)
    results = []
    with _one_blas_thread():
        for i, path in enumerate(logs):
            progress(f"reading {path}" + (f" (log {i + 1} of {len(logs)})" if len(logs) > 1 else ""))
            log = read_log(path, setup)
            res = diagnose(log, setup, list(args.add or []), progress=progress, effects_files=list(args.effects or []))
            results.append((stems[i], log, res))
    progress("writing figures")
    _write_diagnosis(out, args, results, setup, Provenance("user_log", results[0][1].source, str(args.setup)), t0)
    return 0


def _one_blas_thread():
    """The diagnosis's BLAS at one thread: its products are small (a block's normal equations, the
    mount fit's 2000 rows), where extra threads only spin -- measured on a shared 2-core VM: 200
    products of a (2000, 41) matrix took 4.6 s of CPU at OpenBLAS's default threads, 0.03 s at
    one. scipy's BLAS is loaded first so that the limit covers it (as ``runs.build.one_blas_thread``)."""
    import importlib

    from threadpoolctl import threadpool_limits

    importlib.import_module("scipy.linalg.cython_lapack")
    return threadpool_limits(1, user_api="blas")


def _log_names(paths: list[Path]) -> list[str]:
    """A folder name per log: its file name without the extensions, made unique."""
    out: list[str] = []
    for p in paths:
        base = p.name.split(".")[0] or "log"
        name, k = base, 2
        while name in out:
            name, k = f"{base}_{k}", k + 1
        out.append(name)
    return out


def cmd_setup_template(args: argparse.Namespace) -> int:
    """Print (or write) a setup-file template for ``kinadapt diagnose LOG --setup``."""
    from kinadapt_nn.diagnostics.setup import template_text
    from kinadapt_nn.runio import write_text_atomic

    text = template_text()
    if args.out:
        p = Path(args.out)
        if p.exists() and not args.overwrite:
            raise KinadaptError(f"'{p}' already exists (pass --overwrite or choose another --out)")
        write_text_atomic(p, text)
        print(f"wrote {p}; edit it, then: kinadapt diagnose YOUR_LOG --setup {p} --out DIR")
    else:
        print(text, end="")
    return 0


class _Lazy:
    """A help-text parameter computed when argparse formats the help (``%(name)s``)."""

    def __init__(self, fn) -> None:
        self.fn = fn

    def __str__(self) -> str:
        return self.fn()


def _builtin_names() -> list[str]:
    from kinadapt_nn.diagnostics.builtin import BUILTINS

    return list(BUILTINS)


def _flat(v) -> list[str]:
    """``--add A B --add C`` -> [A, B, C]."""
    return [x for grp in (v or []) for x in (grp if isinstance(grp, list) else [grp])]


def cmd_diagnose_run(args: argparse.Namespace) -> int:
    """``kinadapt diagnose RUN``: a package run through the same stages as a robot's log, its set-up
    generated from its config (``diagnostics.ownrun``); ``--baseline RUN``: the tip calibrated there;
    ``--rerun``: the online run again with the ``--add`` effects in its model."""
    import dataclasses
    import time

    from kinadapt_nn.config import load_config
    from kinadapt_nn.diagnostics import ownrun
    from kinadapt_nn.diagnostics.report import Provenance
    from kinadapt_nn.diagnostics.userlog import check_request, diagnose
    from kinadapt_nn.runio import check_output_dir

    if len(args.logs) > 1:
        raise KinadaptError(f"{len(args.logs)} logs given: several logs are pooled only with --setup SETUP.toml (a "
                            "package run is diagnosed one at a time)")
    src = Path(args.logs[0])
    cfg_path = Path(args.config) if args.config else (src / "config.toml" if (src / "config.toml").is_file() else None)
    cfg = load_config(cfg_path, args.set or [])
    check_request(ownrun.setup_of_run(cfg, list(args.effects or [])), list(args.add or []), ())  # before any work
    if args.rerun:
        ownrun.check_rerun(src, list(args.add or []))
    out = args.run_dir = Path(args.out) if args.out else _default_out("diagnose")
    check_output_dir(out, args.overwrite)
    t0 = time.perf_counter()
    progress = _progress(args, "diagnose")
    if args.baseline:
        progress(f"where contacts act, calibrated on the baseline {args.baseline}")
    tip = ownrun.calibrated_tip(Path(args.baseline)) if args.baseline else None
    progress("reading the run; its set-up generated from its config")
    log, setup = ownrun.as_log(src, cfg, list(args.effects or []), tip)
    res = diagnose(log, setup, list(args.add or []), progress=progress)
    if args.baseline and args.add:
        res = dataclasses.replace(res, report=_with_effect_free_level(res.report, Path(args.baseline), args,
                                                                      tip, progress))
    rerun = None
    if args.rerun:
        progress("re-running the episode with the effects adapted online (--rerun)")
        rerun = ownrun.rerun_with_effects(src, list(args.add))
        res = dataclasses.replace(res, report=res.report.with_section("rerun", rerun[2]))
    progress("writing diagnosis.json and the figures")
    prov = Provenance("package_run", log.source, "generated from the run's config")
    _write_diagnosis(out, args, [(None, log, res)], setup, prov, t0, rerun)
    return 0


def _with_effect_free_level(report, baseline: Path, args: argparse.Namespace, tip, progress):
    """``report`` with the section ``effect_free_level``: the baseline run (the same program without
    the hidden effect) diagnosed with the same set-up and the same ``--add`` refit, its residual
    after that refit (noise-weighted RMS, all rows) and this run's over it; the summary says it."""
    from kinadapt_nn.diagnostics import ownrun
    from kinadapt_nn.diagnostics.report import Report
    from kinadapt_nn.diagnostics.userlog import diagnose, summary_text

    progress(f"the effect-free level: the baseline {baseline} diagnosed with the same set-up")
    blog, bsetup = ownrun.as_log(baseline, None, list(args.effects or []), tip)
    level = float(diagnose(blog, bsetup, list(args.add), hints=False).report["residual_rms_after"]["total_w"])
    after = float(report["residual_rms_after"]["total_w"])
    sections = {**report.sections, "effect_free_level": {
        "baseline": str(baseline), "residual_rms_total_w": level, "after_over_effect_free": after / level}}
    return Report.of(sections, summary_text)


def _write_diagnosis(out: Path, args: argparse.Namespace, results: list, setup, prov, t0: float,
                     rerun=None) -> None:
    """Write one diagnosis (``results`` = [(None, log, Result)]) or several pooled logs (one folder
    each) into ``out`` (``diagnostics.report`` owns the format), then print the summary and the
    warnings."""
    import dataclasses
    import time

    from kinadapt_nn.diagnostics import userfigures as uf
    from kinadapt_nn.diagnostics.report import pooled_json
    from kinadapt_nn.diagnostics.setup import setup_to_toml
    from kinadapt_nn.runio import staged_output, write_json

    def write_one(stage: Path, res, source: str) -> None:
        for name, text in (res.hint_files or {}).items():
            (stage / name).write_text(text)
        (stage / "setup.toml").write_text(setup_to_toml(setup))
        write_json(stage / "diagnosis.json", res.report.to_json(dataclasses.replace(prov, source=source),
                                                            time.perf_counter() - t0))
        uf.model_vs_measurement(res, setup, stage / "residual.png")
        uf.effects_figure(res, stage / "effects.png")

    pooled = None
    with staged_output(out, args.overwrite) as stage:
        if len(results) == 1:
            write_one(stage, results[0][2], results[0][1].source)
            if rerun is not None:
                (stage / "rerun").mkdir()
                _write_online(stage / "rerun", rerun[0], rerun[1])
        else:
            for name, log, res in results:
                (stage / name).mkdir()
                write_one(stage / name, res, log.source)
            pooled = pooled_json([(name, log.source, res.report) for name, log, res in results], prov.setup_file,
                                 time.perf_counter() - t0)
            write_json(stage / "diagnosis.json", pooled)
    if args.quiet:
        return
    for name, _, res in results:
        for w in res.report["warnings"]:
            print(f"kinadapt: warning: {name + ': ' if pooled else ''}{w}", file=sys.stderr)
    if pooled:
        print(pooled["summary"])
        print(f"wrote {out}/ (diagnosis.json; one folder per log: {', '.join(n for n, _, _ in results)})")
    else:
        res = results[0][2]
        files = res.hint_files or {}
        print(res.report["summary"])
        print(f"wrote {out}/ (diagnosis.json, setup.toml, residual.png, effects.png"
              f"{''.join(', ' + f for f in files)}{', rerun/' if rerun is not None else ''})")


def cmd_diagnose_follow(args: argparse.Namespace) -> int:
    """``kinadapt diagnose LOG --setup S --follow``: the live monitor on a log as it is written."""
    from kinadapt_nn.config import MonitorCfg
    from kinadapt_nn.diagnostics.setup import load_setup
    from kinadapt_nn.monitor.follow import Follower

    if not args.setup:
        raise KinadaptError("--follow needs --setup SETUP.toml (the set-up of the log being written)")
    if len(args.logs) != 1:
        raise KinadaptError(f"--follow watches one log as it grows (got {len(args.logs)})")
    for opt in ("add", "effects", "baseline", "config", "out"):
        if getattr(args, opt, None):
            raise KinadaptError(f"--{opt} does not apply to --follow (it prints events as they happen); drop it")
    setup = load_setup(Path(args.setup), args.set or [])
    path = Path(args.logs[0])
    say = (lambda m: None) if args.quiet else (lambda m: print(f"kinadapt diagnose --follow: {m}", file=sys.stderr,
                                                                flush=True))
    fol = Follower(path, setup, MonitorCfg(), say=say,
                   on_event=lambda ev: print(f"{path.name}: {ev.line}" + (" (updated)" if ev.updates else ""), flush=True))
    if not args.quiet:
        stop = f"stops when it has not grown for {args.idle_stop:g} s" if args.idle_stop else "Ctrl-C stops"
        say(f"following {path} ({stop})")
    try:
        events = fol.run(args.idle_stop)
    except KeyboardInterrupt:
        events = fol.monitor.finish() if fol.monitor is not None else []
    if not args.quiet:
        m = fol.monitor
        sd = "" if m is None else (f"; noise sd {max(m.noise_sd[:3]):.3g} N / {max(m.noise_sd[3:]):.3g} N m")
        say(f"{fol.n_good} samples monitored, {fol.n_bad} left out, {len(events)} event(s){sd}")
    return 0


def cmd_diagnose(args: argparse.Namespace) -> int:
    args.add = _flat(args.add)
    if args.follow:
        return cmd_diagnose_follow(args)
    if args.setup:
        return cmd_diagnose_setup(args)
    return cmd_diagnose_run(args)  # --as-log: accepted, the default (one pipeline)


def cmd_config(args: argparse.Namespace) -> int:
    """Print every key of the experiment config (after --config/--set) with its value, unit and meaning."""
    from kinadapt_nn.config import load_config
    from kinadapt_nn.app.config_doc import describe, format_keys

    cfg = load_config(Path(args.config) if args.config else None, args.set or [])
    src = args.config or "built-in defaults"
    print(f"# kinadapt experiment config ({src}{', with --set' if args.set else ''}): key = value  [unit]  meaning")
    print("# override any key with --set KEY=VALUE (TOML value), e.g. --set control.dither_rad_s=[0.05,0.05,0.05]")
    print(format_keys(describe(cfg)), end="")
    return 0


def _job_parser(sub, name: str, help_: str, config_default: str, set_example: str, func,
                description: str = "") -> argparse.ArgumentParser:
    """The options every job command shares: --config, --set, --out, --overwrite, --quiet."""
    sp = sub.add_parser(name, help=help_, description=description or help_[:1].upper() + help_[1:] + ".")
    sp.add_argument("--config", help=f"TOML config (default: built-in defaults = {config_default})")
    sp.add_argument("--set", action="append", metavar="KEY=VALUE", help=f"override a key, e.g. {set_example}")
    sp.add_argument("--out", help=f"output folder (default: runs/{name}-<timestamp>)")
    sp.add_argument("--overwrite", action="store_true", help="replace an existing output folder")
    sp.add_argument("--quiet", action="store_true", help="no progress bar, no summary")
    sp.set_defaults(func=func)
    return sp


_DESCRIPTIONS = {
    "online": "Run one simulated peg-in-hole insertion of the Panda by feel: the controller sees only the joint "
              "encoders and the wrist F/T sensor and adapts its tool estimate online. Writes a run folder "
              "(config.toml, summary.json, trace.npz, rollout.png, tb/). Exit 0 seated, 1 not seated.",
    "pretrain": "Train the neural Jacobian basis offline on randomised tools and arms. Writes model.safetensors, "
                "metrics.json and tb/ into --out; an interrupted run resumes from train_state.pt when rerun with "
                "the same command (--overwrite starts afresh).",
    "compare": "Compare the adjoint, RBF and neural features on the same held-out tools and arms "
               "(comparison.csv/.md, a Jacobian-error figure, tb/).",
    "view": "Replay a run folder's logged joint positions in its scene: render to a GIF/MP4 offscreen (always with "
            "--out, or when there is no display), else open the interactive MuJoCo viewer. Headless rendering needs "
            "MUJOCO_GL=egl (default here) or osmesa.",
    "reproduce": "Check the paper's claims by running code: rollouts, the observability spectrum, a gain sweep, "
                 "ablations, the QP identities and a video. Writes reproduce.json, reproduce.md (paper vs ours) and "
                 "the figures; takes several minutes (progress on stderr).",
    "sweep": "Run many episodes over groups (named override sets) x seeds, locally or on a Ray cluster, and "
             "aggregate success rates with 95 % intervals; rerun the same command to resume.",
    "diagnose": "Model vs measurement: judge a log against the physical nominal model of its set-up and rank which "
                "physical effect is missing, each with a verdict. With --setup: your robot's log (CSV, Parquet, ROS 2 "
                "bag); without: a run of this package, its set-up generated from its config (the same stages).",
    "setup-template": "Print (or write with --out) a commented setup-file template for kinadapt diagnose LOG --setup.",
    "config": "Print every key of the experiment config (kinadapt online) with its value, unit and meaning, after "
              "--config and --set are applied.",
}


def _add_online(sub) -> None:
    on = _job_parser(sub, "online", "run one insertion episode", "online/rollout.toml", "run.seed=3", cmd_online,
                     _DESCRIPTIONS["online"])
    on.add_argument("--monitor", action="store_true",
                    help="run the live monitor beside the controller: it compares the wrist F/T reading with the "
                         "nominal model and prints each change it finds (monitor.enabled; docs/monitor.md)")


def _add_view(sub) -> None:
    vw = sub.add_parser("view", help="render a run to GIF/MP4 offscreen, or open the viewer when a display exists",
                        description=_DESCRIPTIONS["view"])
    vw.add_argument("run", help="a run folder written by kinadapt online (config.toml + trace.npz)")
    vw.add_argument("--out", help="video file (.gif or .mp4); default: RUN/rollout.gif when headless")
    vw.add_argument("--fps", type=_float_in(0.0, 1000.0), default=25.0,
                    help="frames per second of the video, (0, 1000] (default: 25)")
    vw.add_argument("--width", type=_int_in(16, 4096), default=480,
                    help="frame width in pixels, 16..4096 (default: 480)")
    vw.add_argument("--height", type=_int_in(16, 4096), default=360,
                    help="frame height in pixels, 16..4096 (default: 360)")
    vw.add_argument("--camera", default="side", help="a camera of the scene (default: side; a wrong name lists them)")
    vw.add_argument("--max-s", dest="max_s", type=_float_in(0.0, 1e6), default=None,
                    help="render only the first MAX_S seconds of the run (default: all of it)")
    vw.add_argument("--overwrite", action="store_true", help="replace an existing video file")
    vw.add_argument("--quiet", action="store_true", help="no progress bar, no summary line")
    vw.set_defaults(func=cmd_view)


def _add_reproduce(sub) -> None:
    rp = sub.add_parser("reproduce", help="check the paper's claims by running code; figures + paper-vs-ours table",
                        description=_DESCRIPTIONS["reproduce"])
    rp.add_argument("--only", help="one part: rollout, observability, gain_sweep, ablations, qp, video")
    rp.add_argument("--out", help="output folder (default: runs/reproduce-<timestamp>)")
    rp.add_argument("--jobs", type=_int_in(1, 256), default=2, help="worker processes, 1..256 (default: 2)")
    rp.add_argument("--overwrite", action="store_true", help="replace an existing output folder")
    rp.add_argument("--quiet", action="store_true", help="no progress lines, no table")
    rp.set_defaults(func=cmd_reproduce)


def _add_sweep(sub) -> None:
    sw = _job_parser(sub, "sweep", "many episodes over groups x seeds, locally or on a Ray cluster (rerun to resume)",
                     "online/sweep.toml", "seeds=5", cmd_sweep, _DESCRIPTIONS["sweep"])
    sw.add_argument("--executor", choices=["local", "ray"], default="local",
                    help="run episodes in local worker processes or on a Ray cluster (default: local)")
    sw.add_argument("--address", help="with --executor ray: a running Ray cluster's address (default: start a Ray of "
                    "this command's own with 'jobs' CPUs, stopped at the end)")


def _add_diagnose(sub) -> None:
    dg = sub.add_parser("diagnose", help="model vs measurement: which physical effect is missing (your robot's log "
                        "with --setup, or a run of this package)", description=_DESCRIPTIONS["diagnose"])
    dg.add_argument("logs", nargs="+", metavar="LOG", help="with --setup: .csv, .csv.gz, .parquet, a ROS 2 bag or a "
                    "trace.npz -- several logs of one set-up are pooled (one tool and mount; the logs that "
                    "contradict the others named); without: a run folder, a trace.npz, or a CSV in this package's "
                    "format (kinadapt_nn/diagnostics/importers.py), its set-up generated from its config")
    dg.add_argument("--setup", action=_Once, metavar="SETUP.toml", help="your set-up: columns, wrench convention, sensor mount, tool "
                    "(template: kinadapt setup-template; examples: examples/setups/)")
    dg.add_argument("--config", action=_Once, help="a package run's config, the set-up is generated from it (default: the run's "
                    "config.toml, else built-in defaults)")
    dg.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a set-up key (with --setup) or a "
                    "config key (a package run)")
    add = dg.add_argument("--add", action="append", nargs="+", metavar="EFFECT",
                    help="refit with these effects added and report the residual before/after (--add A B, or "
                    "repeated; a one-of effect's parameter: encoder_offset:joint5): the built-ins "
                    "(%(builtins)s) and your own (--effects)")
    add.builtins = _Lazy(lambda: ", ".join(_builtin_names()))  # read when the help is shown, not on every command
    dg.add_argument("--effects", action="append", metavar="FILE.py",
                    help="a Python file of your own effects (@effect from kinadapt_nn.diagnostics; "
                    "docs/missing_physics.md); judged and --add-able like the built-ins (repeatable). An effects "
                    "file is code that runs, like a test file")
    dg.add_argument("--rerun", action="store_true",
                    help="package runs: repeat the online run with the --add effects in the model (model.effects), "
                         "written to OUT/rerun/ with the same TensorBoard tags")
    dg.add_argument("--baseline", metavar="RUN", help="package runs: where contacts act (the tip) calibrated on this "
                    "run of the same cell (default: the config's nominal tip)")
    dg.add_argument("--as-log", action="store_true",
                    help="accepted for compatibility: a package run always goes through the same stages as a "
                         "robot's log, its set-up generated from its config (diagnostics/ownrun.py)")
    dg.add_argument("--follow", action="store_true",
                    help="with --setup: watch one CSV or Parquet log as another program appends to it and print each "
                         "change of the wrench the set-up's model stops explaining, as kinadapt online --monitor does "
                         "(docs/monitor.md); bad rows are said in one line and skipped")
    dg.add_argument("--idle-stop", dest="idle_stop", type=_float_in(0.0, 1e9), default=None, metavar="S",
                    help="with --follow: stop when the log has not grown for S seconds (default: until Ctrl-C)")
    dg.add_argument("--out", help="output folder (default: runs/diagnose-<timestamp>)")
    dg.add_argument("--overwrite", action="store_true", help="replace an existing output folder")
    dg.add_argument("--quiet", action="store_true", help="no progress lines, no summary")
    dg.set_defaults(func=cmd_diagnose)


def _add_setup_template(sub) -> None:
    st = sub.add_parser("setup-template", help="print a setup-file template for kinadapt diagnose LOG --setup",
                        description=_DESCRIPTIONS["setup-template"])
    st.add_argument("--out", help="write it to this file instead of printing it")
    st.add_argument("--overwrite", action="store_true", help="replace an existing file")
    st.set_defaults(func=cmd_setup_template, uses_mujoco=False)


def _add_config(sub) -> None:
    cf = sub.add_parser("config", help="list every experiment config key with its value, unit and meaning",
                        description=_DESCRIPTIONS["config"])
    cf.add_argument("--config", help="TOML config (default: built-in defaults = online/rollout.toml)")
    cf.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a key, e.g. run.seed=3")
    cf.set_defaults(func=cmd_config, uses_mujoco=False)


def build_parser() -> argparse.ArgumentParser:
    """The ``kinadapt`` parser: one ``_add_*`` step per sub-command (their order is the help's)."""
    p = _Parser(prog="kinadapt", description="Online kinematic adaptation by feel (MuJoCo Panda). "
                "Exit codes: 0 done, 1 online episode not seated, 2 bad input, 3 internal error, 130 interrupted.")
    p.add_argument("--version", action="version", version=f"kinadapt {__version__}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    _add_online(sub)
    _job_parser(sub, "pretrain", "train the neural Jacobian basis on randomised tools and arms (rerun to resume)",
                "pretrain/default.toml", "train.steps=200", cmd_pretrain, _DESCRIPTIONS["pretrain"])
    _job_parser(sub, "compare", "adjoint vs RBF vs neural features on the same held-out tools",
                "online/compare.toml", "n_tools=2", cmd_compare, _DESCRIPTIONS["compare"])
    _add_view(sub)
    _add_reproduce(sub)
    _add_sweep(sub)
    _add_diagnose(sub)
    _add_setup_template(sub)
    _add_config(sub)
    p.set_defaults(in_place=False)
    for name in ("pretrain", "sweep"):  # these write into --out as they go (resumable)
        sub.choices[name].set_defaults(in_place=True)
    return p


def _one_line(text: str, n: int = 300) -> str:
    text = " ".join(str(text).split())
    return text if len(text) <= n else text[: n - 3] + "..."


def _internal_error(args: argparse.Namespace, exc: BaseException, mujoco_log: Path | None) -> int:
    """Write the traceback to a log file (the output folder of an in-place command, else a temp file)
    and print one line naming it. -> exit code 3."""
    run_dir = getattr(args, "run_dir", None)
    text = "".join(traceback.format_exception(exc))
    text = f"kinadapt {__version__} {' '.join(sys.argv[1:]) if sys.argv else ''}\n{text}"
    if mujoco_log is not None and mujoco_log.exists():
        text += f"MuJoCo's log: {mujoco_log}\n"
    if args.in_place and run_dir is not None and Path(run_dir).is_dir():
        path = Path(run_dir) / "kinadapt_error.log"
        path.write_text(text)
    else:
        fd, name = tempfile.mkstemp(prefix="kinadapt-error-", suffix=".log")
        with os.fdopen(fd, "w") as fh:
            fh.write(text)
        path = Path(name)
    print(f"kinadapt: internal error ({type(exc).__name__}: {_one_line(exc, 160)}); the traceback is in {path} "
          "-- please report it", file=sys.stderr)
    return EXIT_INTERNAL


def _run(args: argparse.Namespace, mujoco_log: Path | None) -> int:
    try:
        return int(args.func(args))
    except KinadaptError as exc:
        print(f"kinadapt: error: {_one_line(exc, 1000)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print("kinadapt: interrupted; nothing was written", file=sys.stderr)
        return EXIT_INTERRUPTED
    except Exception as exc:  # a bug: keep the traceback, say where
        return _internal_error(args, exc, mujoco_log)


def _place_mujoco_log(path: Path, args: argparse.Namespace, rc: int) -> None:
    """MuJoCo wrote a log: move it into the run folder of a finished run, else say where it is."""
    if not path.exists():
        return
    run_dir = getattr(args, "run_dir", None)
    finished = rc in (EXIT_OK, EXIT_NOT_SEATED) or (args.in_place and rc == EXIT_INTERRUPTED)
    if finished and run_dir is not None and Path(run_dir).is_dir():
        dest = Path(run_dir) / "MUJOCO_LOG.TXT"
        with open(dest, "a") as fh:
            fh.write(path.read_text(errors="replace"))
        path.unlink()
    else:
        dest = path
    if rc != EXIT_BAD_INPUT and not getattr(args, "quiet", False):
        print(f"kinadapt: MuJoCo logged warnings to {dest}", file=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as exc:  # --help, --version (0) or a bad option (2, one line already printed)
        return exc.code if isinstance(exc.code, int) else EXIT_BAD_INPUT
    args.run_dir = None  # set by a command once it knows its output folder
    if not getattr(args, "uses_mujoco", True):
        return _run(args, None)
    if args.command == "view" and (args.out is not None or not os.environ.get("DISPLAY")):
        os.environ.setdefault("MUJOCO_GL", "egl")  # offscreen: must be chosen before mujoco is imported
    from kinadapt_nn.app.mjlog import fresh_log_path, mujoco_log_to

    mujoco_log = fresh_log_path()
    rc = EXIT_INTERNAL
    try:
        with mujoco_log_to(mujoco_log):
            rc = _run(args, mujoco_log)
    finally:
        _place_mujoco_log(mujoco_log, args, rc)
    return rc


def entry() -> int:
    """The ``kinadapt`` console script (and ``python -m kinadapt_nn.app.cli``): :func:`main`, then
    ``gc.freeze()`` so the interpreter's exit does not walk every object the imports made (numba's
    and pydantic's tables) in its final collections -- measured 0.13-0.17 s of a 2.2 s ``kinadapt
    online`` (``benchmarks/bench_online.py``). Every file is written and closed by then; only the
    exit's cyclic garbage collection is skipped. Not in :func:`main` itself, which tests call in
    one long process."""
    rc = main()
    sys.stdout.flush()
    sys.stderr.flush()
    import gc

    gc.freeze()
    return rc


if __name__ == "__main__":  # pragma: no cover
    sys.exit(entry())
