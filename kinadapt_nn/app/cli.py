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
import os
import shutil
import sys
import tempfile
import time
import traceback
from pathlib import Path

from kinadapt_nn import __version__
from kinadapt_nn.app.common import (EXIT_BAD_INPUT, EXIT_INTERNAL, EXIT_INTERRUPTED, EXIT_NOT_SEATED, EXIT_OK, Parser,
                                    default_out, float_in, int_in, progress_printer, with_monitor)
from kinadapt_nn.app.diagnose import add_diagnose, add_setup_template
from kinadapt_nn.app.online import cmd_online
from kinadapt_nn.errors import KinadaptError, OutputExistsError

log = logging.getLogger("kinadapt")


def cmd_pretrain(args: argparse.Namespace) -> int:
    from kinadapt_nn.learning.pretrain import load_pretrain_config, pretrain

    cfg = load_pretrain_config(Path(args.config) if args.config else None, args.set or [])
    out = Path(args.out) if args.out else default_out("pretrain")
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

    cfg, setup = with_monitor(load_compare_config(Path(args.config) if args.config else None, args.set or []), args)
    out = args.run_dir = Path(args.out) if args.out else default_out("compare")
    check_output_dir(out, args.overwrite)
    with staged_output(out, args.overwrite) as stage:
        run_compare(cfg, stage, progress=not args.quiet, worker_setup=setup)
    if not args.quiet:
        print((out / "comparison.md").read_text())
        wrote = [f for f in ("comparison.csv", "comparison.md", "jacobian_error.png", "cell_learning.png",
                             "monitor.json") if (out / f).is_file()]
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
    out = args.run_dir = Path(args.out) if args.out else default_out("reproduce")
    check_output_dir(out, args.overwrite)
    t0 = time.perf_counter()
    with staged_output(out, args.overwrite) as stage:
        run_reproduce(stage, only=args.only, jobs=args.jobs, progress=progress_printer(args, "reproduce"))
    if not args.quiet:
        print((out / "reproduce.md").read_text())
        print(f"wrote {out}/ in {time.perf_counter() - t0:.0f} s (reproduce.json, reproduce.md, figures)")
    return 0


def cmd_sweep(args: argparse.Namespace) -> int:
    import shutil

    from kinadapt_nn.runs.sweep import load_sweep_config, run_sweep

    cfg, setup = with_monitor(load_sweep_config(Path(args.config) if args.config else None, args.set or []), args)
    out = args.run_dir = Path(args.out) if args.out else default_out("sweep")
    if out.exists() and not (out / "sweep_config.json").is_file() and any(out.iterdir()):
        if not args.overwrite:
            raise OutputExistsError(f"output folder '{out}' exists and is not a sweep (pass --overwrite or another --out)")
        shutil.rmtree(out)
    try:
        s = run_sweep(cfg, out, executor=args.executor, address=args.address, progress=not args.quiet,
                      worker_setup=setup)
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
            if st.get("monitor"):
                m = st["monitor"]
                print(f"  {'':40s} monitor: {m['events']} event(s) in {m['episodes_with_events']}/{m['episodes']} "
                      f"episodes" + (f" ({', '.join(f'{k} x{v}' for k, v in m['shapes'].items())})" if m["shapes"]
                                     else ""))
        print(f"wrote {out}/ (sweep.csv, sweep.json, episodes/)")
    return 0


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


#: ``--monitor``'s help for the commands that run many episodes
MONITOR_HELP = ("run the live monitor beside the controller of {where} (monitor.enabled in every run; "
                "docs/monitor.md)")


def _add_view(sub) -> None:
    vw = sub.add_parser("view", help="render a run to GIF/MP4 offscreen, or open the viewer when a display exists",
                        description=_DESCRIPTIONS["view"])
    vw.add_argument("run", help="a run folder written by kinadapt online (config.toml + trace.npz)")
    vw.add_argument("--out", help="video file (.gif or .mp4); default: RUN/rollout.gif when headless")
    vw.add_argument("--fps", type=float_in(0.0, 1000.0), default=25.0,
                    help="frames per second of the video, (0, 1000] (default: 25)")
    vw.add_argument("--width", type=int_in(16, 4096), default=480,
                    help="frame width in pixels, 16..4096 (default: 480)")
    vw.add_argument("--height", type=int_in(16, 4096), default=360,
                    help="frame height in pixels, 16..4096 (default: 360)")
    vw.add_argument("--camera", default="side", help="a camera of the scene (default: side; a wrong name lists them)")
    vw.add_argument("--max-s", dest="max_s", type=float_in(0.0, 1e6), default=None,
                    help="render only the first MAX_S seconds of the run (default: all of it)")
    vw.add_argument("--overwrite", action="store_true", help="replace an existing video file")
    vw.add_argument("--quiet", action="store_true", help="no progress bar, no summary line")
    vw.set_defaults(func=cmd_view)


def _add_reproduce(sub) -> None:
    rp = sub.add_parser("reproduce", help="check the paper's claims by running code; figures + paper-vs-ours table",
                        description=_DESCRIPTIONS["reproduce"])
    rp.add_argument("--only", help="one part: rollout, observability, gain_sweep, ablations, qp, video")
    rp.add_argument("--out", help="output folder (default: runs/reproduce-<timestamp>)")
    rp.add_argument("--jobs", type=int_in(1, 256), default=2, help="worker processes, 1..256 (default: 2)")
    rp.add_argument("--overwrite", action="store_true", help="replace an existing output folder")
    rp.add_argument("--quiet", action="store_true", help="no progress lines, no table")
    rp.set_defaults(func=cmd_reproduce)


def _add_sweep(sub) -> None:
    sw = _job_parser(sub, "sweep", "many episodes over groups x seeds, locally or on a Ray cluster (rerun to resume)",
                     "online/sweep.toml", "seeds=5", cmd_sweep, _DESCRIPTIONS["sweep"])
    sw.add_argument("--monitor", action="store_true", help=MONITOR_HELP.format(
        where="each episode (batched too); sweep.csv and sweep.json say how many events and their shapes"))
    sw.add_argument("--executor", choices=["local", "ray"], default="local",
                    help="run episodes in local worker processes or on a Ray cluster (default: local)")
    sw.add_argument("--address", help="with --executor ray: a running Ray cluster's address (default: start a Ray of "
                    "this command's own with 'jobs' CPUs, stopped at the end)")


def _add_config(sub) -> None:
    cf = sub.add_parser("config", help="list every experiment config key with its value, unit and meaning",
                        description=_DESCRIPTIONS["config"])
    cf.add_argument("--config", help="TOML config (default: built-in defaults = online/rollout.toml)")
    cf.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a key, e.g. run.seed=3")
    cf.set_defaults(func=cmd_config, uses_mujoco=False)


def build_parser() -> argparse.ArgumentParser:
    """The ``kinadapt`` parser: one ``_add_*`` step per sub-command (their order is the help's)."""
    p = Parser(prog="kinadapt", description="Online kinematic adaptation by feel (MuJoCo Panda). "
                "Exit codes: 0 done, 1 online episode not seated, 2 bad input, 3 internal error, 130 interrupted.")
    p.add_argument("--version", action="version", version=f"kinadapt {__version__}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    _add_online(sub)
    _job_parser(sub, "pretrain", "train the neural Jacobian basis on randomised tools and arms (rerun to resume)",
                "pretrain/default.toml", "train.steps=200", cmd_pretrain, _DESCRIPTIONS["pretrain"])
    cp = _job_parser(sub, "compare", "adjoint vs RBF vs neural features on the same held-out tools",
                     "online/compare.toml", "n_tools=2", cmd_compare, _DESCRIPTIONS["compare"])
    cp.add_argument("--monitor", action="store_true", help=MONITOR_HELP.format(
        where="each run; the table says per run how many events and their shapes, monitor.json has them all"))
    _add_view(sub)
    _add_reproduce(sub)
    _add_sweep(sub)
    add_diagnose(sub, _DESCRIPTIONS["diagnose"])
    add_setup_template(sub, _DESCRIPTIONS["setup-template"])
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
