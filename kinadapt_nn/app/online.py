"""``kinadapt online``: one episode, its run folder (config, summary, trace, figure, TensorBoard)
and the summary lines it prints."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from kinadapt_nn.app.common import default_out


def summary_lines(summary: dict, out: Path) -> list[str]:
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
    rows = summary.get("insertions") or []
    if len(rows) > 1 and all("monitor_shapes" in r for r in rows):  # a work cell: a monitor per insertion
        head += f" in insertion {len(rows)}"
        per = "; ".join(f"{r['insertion']}: {r['monitor_events']}"
                        + (f" ({', '.join(r['monitor_shapes'])})" if r["monitor_shapes"] else "") for r in rows)
        return [head, *(f"    {e['line']}" for e in mon["events"]), f"    events per insertion: {per}"]
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


def write_online(stage: Path, cfg, result) -> None:
    """The run folder contents (config, summary, trace, figure, TensorBoard) into ``stage``."""
    from kinadapt_nn.config import config_to_toml
    from kinadapt_nn.runio import write_json

    (stage / "config.toml").write_text(config_to_toml(cfg))
    write_json(stage / "summary.json", result.summary)
    result.trace.save(stage / "trace.npz")
    png = None
    if cfg.run.figure:
        from kinadapt_nn.figures import rollout_figure, save_figure  # (matplotlib only when a figure is wanted)

        png = stage / "rollout.png"
        save_figure(rollout_figure(result.trace, result.summary, cfg), png)
    if cfg.run.tensorboard:
        from kinadapt_nn.runs.tb import write_run

        hp = {"features": cfg.run.features, "law": result.summary["law"], "seed": cfg.run.seed}
        write_run(stage / "tb", result.trace, result.summary, hp, png)


def cmd_online(args: argparse.Namespace) -> int:
    from kinadapt_nn.config import load_config
    from kinadapt_nn.controller.laws import law_spec
    from kinadapt_nn.features import features_spec
    from kinadapt_nn.runio import check_output_dir, staged_output

    cfg = load_config(Path(args.config) if args.config else None,
                      [*(args.set or []), *(["monitor.enabled=true"] if args.monitor else []),
                       *(["run.progress=false"] if args.quiet else [])])  # (--quiet: no live lines either)
    # the registered names (features type, law, effects), checked before anything compiles or prints
    features_spec(cfg.run.features)
    law_spec(cfg.adaptation.mode)
    if cfg.model.effects:  # (the effect library imports the built-in effects: only when some are named)
        from kinadapt_nn.features.effect_library import online_of

        for eff in cfg.model.effects:
            online_of(eff)
    out = args.run_dir = Path(args.out) if args.out else default_out("online")
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
        write_online(stage, cfg, result)
    if not args.quiet:
        print("\n".join(summary_lines(result.summary, out)))
    return 0 if result.summary["success"] else 1
