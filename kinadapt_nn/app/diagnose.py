"""``kinadapt diagnose`` and ``kinadapt setup-template``: their arguments and their handling (a
user's log with ``--setup``, a package run, ``--follow``); the diagnosis itself is
``kinadapt_nn.diagnostics``."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from kinadapt_nn.app.common import Lazy, Once, default_out, float_in, progress_printer
from kinadapt_nn.app.online import write_online
from kinadapt_nn.errors import KinadaptError


def cmd_diagnose(args: argparse.Namespace) -> int:
    args.add = _flat(args.add)
    if args.follow:
        return cmd_diagnose_follow(args)
    if args.setup:
        return cmd_diagnose_setup(args)
    return cmd_diagnose_run(args)  # --as-log: accepted, the default (one pipeline)


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
    if args.whole_log:
        raise KinadaptError("--whole-log is for this package's own runs (a user's log is always judged whole; "
                            "[analysis] exclude_s leaves parts out); drop it with --setup")
    setup = load_setup(Path(args.setup), args.set or [])
    check_request(setup, list(args.add or []), list(args.effects or []))  # before any log is read
    out = args.run_dir = Path(args.out) if args.out else default_out("diagnose")
    check_output_dir(out, args.overwrite)
    t0 = time.perf_counter()
    progress = progress_printer(args, "diagnose")
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
    out = args.run_dir = Path(args.out) if args.out else default_out("diagnose")
    check_output_dir(out, args.overwrite)
    t0 = time.perf_counter()
    progress = progress_printer(args, "diagnose")
    if args.baseline:
        progress(f"where contacts act, calibrated on the baseline {args.baseline}")
    tip = ownrun.calibrated_tip(Path(args.baseline)) if args.baseline else None
    window = None if args.whole_log or not src.is_dir() else ownrun.monitor_window(src)
    progress("reading the run; its set-up generated from its config")
    log, setup = ownrun.as_log(src, cfg, list(args.effects or []), tip, (None, None) if window is None else
                               (window.from_s, None))
    res = diagnose(log, setup, list(args.add or []), progress=progress)
    if window is not None:
        res = dataclasses.replace(res, report=_with_window(res.report, window, src, cfg, args, tip, progress))
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


def _with_window(report, window, src: Path, cfg, args: argparse.Namespace, tip, progress):
    """``report`` (the log from the monitor's event on) with the section ``window``: where it starts
    and why, and the log before the onset diagnosed on its own as the baseline (its present effects
    were there before the change; hints not sought). The summary leads with it."""
    from kinadapt_nn.diagnostics import ownrun
    from kinadapt_nn.diagnostics.report import Report
    from kinadapt_nn.diagnostics.userlog import diagnose, summary_text

    progress(f"the baseline: the log before the monitor's event ({window.onset_s:.2f} s) diagnosed on its own")
    before = {"to_s": window.onset_s}
    try:
        blog, bsetup = ownrun.as_log(src, cfg, list(args.effects or []), tip, (None, window.onset_s))
        brep = diagnose(blog, bsetup, hints=False).report
        before.update(present=[e["effect"] for e in brep["ranking"] if e["verdict"] == "present"],
                      model_complete=brep.get("model_complete"),
                      residual_rms_total_w=brep["residual_rms_by_channel"]["total_w"], summary=brep["summary"])
    except KinadaptError as exc:  # too short a baseline: said, the window stands
        before["not_diagnosed"] = str(exc)
    sections = {**report.sections, "window": {
        "from_s": window.from_s, "onset_s": window.onset_s, "why": "the monitor's first open event",
        "event": window.line, "monitor_shapes": list(window.shapes), "later_onsets_s": list(window.later),
        "before": before}}
    return Report.of(sections, summary_text)


def _with_effect_free_level(report, baseline: Path, args: argparse.Namespace, tip, progress):
    """``report`` with the section ``effect_free_level``: the baseline run (the same program without
    the hidden effect) diagnosed with the same set-up and the same ``--add`` refit, its residual
    after that refit (noise-weighted RMS, all rows: 1 is the noise floor the rows are weighted by) and
    this run's over it; the summary says it -- and, when both are under that floor (a simulated run
    without sensor noise), that the ratio compares two residuals the diagnosis does not resolve."""
    from kinadapt_nn.diagnostics import ownrun
    from kinadapt_nn.diagnostics.report import Report
    from kinadapt_nn.diagnostics.userlog import diagnose, summary_text

    progress(f"the effect-free level: the baseline {baseline} diagnosed with the same set-up")
    blog, bsetup = ownrun.as_log(baseline, None, list(args.effects or []), tip)
    level = float(diagnose(blog, bsetup, list(args.add), hints=False).report["residual_rms_after"]["total_w"])
    after = float(report["residual_rms_after"]["total_w"])
    sections = {**report.sections, "effect_free_level": {
        "baseline": str(baseline), "residual_rms_total_w": level, "after_over_effect_free": after / level,
        "under_noise_floor": bool(after <= 1.0 and level <= 1.0)}}
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
                write_online(stage / "rerun", rerun[0], rerun[1])
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


def _builtin_names() -> list[str]:
    from kinadapt_nn.effects.builtin import BUILTINS

    return list(BUILTINS)


def add_diagnose(sub, description: str) -> None:
    dg = sub.add_parser("diagnose", help="model vs measurement: which physical effect is missing (your robot's log "
                        "with --setup, or a run of this package)", description=description)
    dg.add_argument("logs", nargs="+", metavar="LOG", help="with --setup: .csv, .csv.gz, .parquet, a ROS 2 bag or a "
                    "trace.npz -- several logs of one set-up are pooled (one tool and mount; the logs that "
                    "contradict the others named); without: a run folder, a trace.npz, or a CSV in this package's "
                    "format (kinadapt_nn/diagnostics/importers.py), its set-up generated from its config")
    dg.add_argument("--setup", action=Once, metavar="SETUP.toml", help="your set-up: columns, wrench convention, sensor mount, tool "
                    "(template: kinadapt setup-template; examples: examples/setups/)")
    dg.add_argument("--config", action=Once, help="a package run's config, the set-up is generated from it (default: the run's "
                    "config.toml, else built-in defaults)")
    dg.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a set-up key (with --setup) or a "
                    "config key (a package run)")
    add = dg.add_argument("--add", action="append", nargs="+", metavar="EFFECT",
                    help="refit with these effects added and report the residual before/after (--add A B, or "
                    "repeated; a one-of effect's parameter: encoder_offset:joint5): the built-ins "
                    "(%(builtins)s) and your own (--effects)")
    add.builtins = Lazy(lambda: ", ".join(_builtin_names()))  # read when the help is shown, not on every command
    dg.add_argument("--effects", action="append", metavar="FILE.py",
                    help="a Python file of your own effects (@effect from kinadapt_nn.diagnostics; "
                    "docs/missing_physics.md); judged and --add-able like the built-ins (repeatable). An effects "
                    "file is code that runs, like a test file")
    dg.add_argument("--rerun", action="store_true",
                    help="package runs: repeat the online run with the --add effects in the model (model.effects), "
                         "written to OUT/rerun/ with the same TensorBoard tags")
    dg.add_argument("--baseline", metavar="RUN", help="package runs: where contacts act (the tip) calibrated on this "
                    "run of the same cell (default: the config's nominal tip)")
    dg.add_argument("--whole-log", action="store_true",
                    help="package runs: judge the whole log even when the run's monitor raised an event (default: "
                         "the log from the monitor's first open event on, the part before as its baseline)")
    dg.add_argument("--as-log", action="store_true",
                    help="accepted for compatibility: a package run always goes through the same stages as a "
                         "robot's log, its set-up generated from its config (diagnostics/ownrun.py)")
    dg.add_argument("--follow", action="store_true",
                    help="with --setup: watch one CSV or Parquet log as another program appends to it and print each "
                         "change of the wrench the set-up's model stops explaining, as kinadapt online --monitor does "
                         "(docs/monitor.md); bad rows are said in one line and skipped")
    dg.add_argument("--idle-stop", dest="idle_stop", type=float_in(0.0, 1e9), default=None, metavar="S",
                    help="with --follow: stop when the log has not grown for S seconds (default: until Ctrl-C)")
    dg.add_argument("--out", help="output folder (default: runs/diagnose-<timestamp>)")
    dg.add_argument("--overwrite", action="store_true", help="replace an existing output folder")
    dg.add_argument("--quiet", action="store_true", help="no progress lines, no summary")
    dg.set_defaults(func=cmd_diagnose)


def add_setup_template(sub, description: str) -> None:
    st = sub.add_parser("setup-template", help="print a setup-file template for kinadapt diagnose LOG --setup",
                        description=description)
    st.add_argument("--out", help="write it to this file instead of printing it")
    st.add_argument("--overwrite", action="store_true", help="replace an existing file")
    st.set_defaults(func=cmd_setup_template, uses_mujoco=False)
