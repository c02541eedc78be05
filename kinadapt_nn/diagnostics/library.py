"""``kinadapt diagnose`` effect part: calibration, ranking, confusion, ``--add`` (see
``kinadapt_nn.diagnostics.ranking`` for the method and ``.effects`` for the library)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Callable, NamedTuple

import numpy as np

from kinadapt_nn.config import ExperimentCfg, load_config
from kinadapt_nn.diagnostics import ranking as rk
from kinadapt_nn.diagnostics.effects import build_signals
from kinadapt_nn.features.effect_library import LIBRARY, Signals
from kinadapt_nn.diagnostics.residual import load_log, replay
from kinadapt_nn.diagnostics.selection import tie_words
from kinadapt_nn.errors import KinadaptError, did_you_mean
from kinadapt_nn.runio import atomic_write
from kinadapt_nn.sensing import channel_metric


def signals_of(path_or_log, cfg: ExperimentCfg) -> Signals:
    """Replay a log (run folder, trace, CSV or a RawLog) and build the effect signals."""
    log = load_log(Path(path_or_log)) if isinstance(path_or_log, (str, Path)) else path_or_log
    rep = replay(log, cfg, np.asarray(cfg.sensing.nominal_offset_f_m, dtype=float))
    return build_signals(rep, log, cfg)


def baseline_calibration(baseline: Path, cfg: ExperimentCfg, rc: rk.RankCfg) -> dict[str, list[float]]:
    """Calibrate the nominal model on a reference run (its own config.toml when it has one)."""
    b = Path(baseline)
    bcfg = load_config(b / "config.toml") if (b.is_dir() and (b / "config.toml").is_file()) else cfg
    if bcfg.effects.enabled():
        raise KinadaptError(f"--baseline {b}: that run has hidden effects {bcfg.effects.enabled()}; "
                            "calibrate on a run without any")
    return rk.calibrate(design_of(signals_of(b, bcfg), bcfg, rc), rc)


def save_calibration(path: Path, program: str, calib: dict, source: str) -> None:
    """Merge one program's calibration into a calibration file (atomic)."""
    path = Path(path)
    data = {"format": "kinadapt-calibration", "version": 1, "programs": {}}
    if path.is_file():
        try:
            data = json.loads(path.read_text())
            data.setdefault("programs", {})
        except ValueError:
            raise KinadaptError(f"calibration '{path}' is not JSON; remove it or pick another file") from None
    data["programs"][program] = {"source": source, "params": calib}
    atomic_write(path, lambda p: Path(p).write_text(json.dumps(data, indent=1)))


def check_effect_names(names: list[str]) -> None:
    for a in names:
        if a not in LIBRARY:
            hint = did_you_mean(a, LIBRARY)
            raise KinadaptError(f"--add {a}: unknown effect{'; ' + hint if hint else ''} "
                                f"(choose from {', '.join(LIBRARY)})")


def choose_calibration(src: Path, cfg: ExperimentCfg, rc: rk.RankCfg, baseline: Path | None, calibration: Path | None,
                       none: bool) -> tuple[dict | None, str]:
    """The calibrated nominal model for ``src`` and where it came from: ``--baseline RUN`` (fitted
    now), ``--no-calibration``, an external CSV log (none unless a file is given), else a
    calibration file (default: the shipped one) for the run's ``control.program``."""
    program = cfg.control.program
    if baseline is not None:
        return baseline_calibration(baseline, cfg, rc), str(baseline)
    if none:
        return None, "none"
    if Path(src).suffix.lower() == ".csv" and calibration is None:  # the shipped one is for our simulator
        return None, "none (external log: give --baseline RUN or --calibration FILE for a calibrated model)"
    path = calibration if calibration is not None else rk.DEFAULT_CALIBRATION
    label = str(calibration) if calibration is not None else "shipped models/nominal_calibration.json"
    return rk.load_calibration(path, program), f"{label} [{program}]"


def check_rerun(src: Path, add: list[str]) -> None:
    if not add:
        raise KinadaptError("--rerun needs --add EFFECT (the effect to put into the online model)")
    if not (Path(src).is_dir() and (Path(src) / "config.toml").is_file()):
        raise KinadaptError(f"--rerun needs a simulated run folder with config.toml (got '{src}')")


def rerun_with_effects(src: Path, add: list[str]):
    """Repeat the simulated run ``src`` with ``model.effects += add`` (adapted online: a frozen or
    tracking-only run gets the default ``kalman`` law), TensorBoard on.
    -> (config, EpisodeResult, the ``rerun`` entry of diagnosis.json)."""
    from kinadapt_nn.runs.episode import run_episode

    check_rerun(src, add)
    src = Path(src)
    run_cfg = load_config(src / "config.toml")
    over = {"model": run_cfg.model.model_copy(update={"effects": tuple(dict.fromkeys((*run_cfg.model.effects, *add)))}),
            "run": run_cfg.run.model_copy(update={"tensorboard": True, "progress": False})}  # TB: the point of a rerun
    if run_cfg.adaptation.mode in ("frozen", "tracking"):  # the effect must adapt: the default law
        over["adaptation"] = run_cfg.adaptation.model_copy(update={"mode": "kalman"})
    cfg = run_cfg.model_copy(update=over)
    result = run_episode(cfg)
    before = json.loads((src / "summary.json").read_text()) if (src / "summary.json").is_file() else {}
    info = {"model_effects": list(cfg.model.effects), "adaptation_mode": cfg.adaptation.mode,
            "model_effect_params": result.summary["model_effect_params"],
            "pred_error_rms_contact_w": {"original": before.get("pred_error_rms_contact_w"),
                                         "rerun": result.summary["pred_error_rms_contact_w"]},
            "folder": "rerun/ (tensorboard --logdir_spec original:RUN/tb,rerun:OUT/rerun/tb)"}
    return cfg, result, info


def design_of(sig: Signals, cfg: ExperimentCfg, rc: rk.RankCfg) -> rk.Design:
    """The regression rows of a log (``ranking.build_design`` with the config's channel metric)."""
    return rk.build_design(sig, channel_metric(cfg.sensing), rc)


def analyse_effects(des: rk.Design, calib: dict | None, add: list[str], rc: rk.RankCfg) -> dict:
    """Ranking, confusion and (for ``add``) the refit with residual before/after, all against the
    calibrated nominal model (``ranking.calibrated_residual`` and ``ranking.calibrated_design``)."""
    check_effect_names(add)
    y = rk.calibrated_residual(des, calib)
    des = rk.calibrated_design(des, calib)  # the encoder columns differentiate the calibrated prediction too
    ranking = rk.rank(des, y, rc, calib)
    out = {"ranking": ranking, "confusion": rk.confusion(des),
           "residual_level_rms": rk.rms_by_channel(des, y),
           "method": {**rc.as_dict(), "calibrated": calib is not None}}
    if add:
        named = {r["effect"]: r["columns_used"] for r in ranking}  # a one-of effect: the column the ranking named
        e_after, params = rk.refit(des, y, add, rc, named)
        out["residual_rms_before"] = rk.rms_by_channel(des, y)
        out["residual_rms_after"] = rk.rms_by_channel(des, e_after)
        out["added"] = {n: {"params": dict(zip(LIBRARY[n].params, (float(v) for v in p))),
                            "units": list(LIBRARY[n].units)} for n, p in params.items()}
        out["_series"] = (des, y, e_after)
    return out


class RunDiagnosis(NamedTuple):
    """``diagnose_run``'s result: the report ``diagnosis.json`` is written from, and what the
    figures, TensorBoard and ``--rerun`` outputs need."""

    report: dict  #: diagnosis.json content (summary first)
    config: ExperimentCfg  #: the known model the log was judged against
    replay: object  #: ``residual.Replay`` of the log
    effects: dict  #: ``analyse_effects``' result with its private ``_series`` (for effects.png)
    design: rk.Design  #: the regression rows (``--save-calibration``)
    rerun: tuple | None  #: (config, EpisodeResult) of ``--rerun``, or None


class CalibrationChoice(NamedTuple):
    """Which calibrated nominal model a run is judged against (``choose_calibration``)."""

    baseline: Path | None = None  #: ``--baseline RUN``: fitted now on that effect-free run
    calibration: Path | None = None  #: ``--calibration FILE``
    none: bool = False  #: ``--no-calibration``


def diagnose_run(src: Path, cfg: ExperimentCfg, theta=None, add: list[str] | None = None, rerun: bool = False,
                 choice: CalibrationChoice = CalibrationChoice(),
                 progress: Callable[[str], None] = lambda msg: None) -> RunDiagnosis:
    """The whole diagnosis of this package's run (a run folder, trace or CSV log) against the
    known model ``cfg``: replay, residual analysis, the effect ranking against the calibrated
    nominal model, ``--add`` and ``--rerun``. One call; the CLI only writes and prints.
    ``progress(message)`` is called as each stage starts. Bad input (effect names, a calibration
    file) is refused before any stage runs."""
    from kinadapt_nn.diagnostics.residual import analyse, plain_summary

    add = list(add or [])
    check_effect_names(add)
    if rerun:
        check_rerun(src, add)
    baseline, calibration, no_calibration = choice
    if calibration is not None and baseline is None and not no_calibration:
        rk.load_calibration(calibration, cfg.control.program)  # a malformed file: its error before the work
    progress("reading the log")
    log = load_log(Path(src))
    progress("replaying the log through the known model")
    rep = replay(log, cfg, theta)
    progress("residual by channel and phase")
    a = analyse(rep, channel_metric(cfg.sensing))
    rc = rk.RankCfg()
    # the effect library works on the nominal model (the CAD offset; the channels it takes from the
    # replay -- s, the tared wrench, the drive flag -- do not depend on theta)
    progress("the effect library's signals")
    sig = build_signals(rep, log, cfg)
    progress("the calibrated nominal model")
    calib, calib_src = choose_calibration(Path(src), cfg, rc, baseline, calibration, no_calibration)
    progress("the effect columns")
    des = design_of(sig, cfg, rc)
    progress("ranking the library's effects (held-out, block cross-validation)")
    fx = analyse_effects(des, calib, add, rc)
    series = fx.pop("_series", None)
    rr = None
    if rerun:
        progress("re-running the episode with the effects adapted online (--rerun)")
        rerun_cfg, rerun_res, fx["rerun"] = rerun_with_effects(Path(src), add)
        rr = (rerun_cfg, rerun_res)
    summary = plain_summary(a) + " " + summary_sentence(fx)
    if calib is None:
        summary += " (Effects judged against the bare nominal model, not a calibrated one.)"
    report = {"summary": summary, "source": log.source, "format": "kinadapt-diagnosis", "version": 2,
              "calibration": calib_src, **fx, **a}
    return RunDiagnosis(report, cfg, rep, {**fx, **({"_series": series} if series else {})}, des, rr)


def summary_sentence(res: dict) -> str:
    top = res["ranking"][0] if res["ranking"] else None
    sig = [r for r in res["ranking"] if r["significant"]]
    undecided = [r for r in res["ranking"] if r.get("verdict") == "cannot_decide" and r.get("selected")]
    if not sig:
        txt = "No library effect is significant (relative to the calibrated nominal model)"
        if top is not None:
            txt += f"; the best candidate, {top['effect']}, explains {100 * top['explained_fraction']:.0f}% held-out"
        txt += "."
    else:
        parts = []
        for r in sig[:3]:
            est = ", ".join(f"{k} {v['value']:.3g} ± {v['sd']:.2g} {v['unit']}" for k, v in list(r["estimate"].items())[:4]
                            if abs(v["value"]) > 2 * v["sd"] or k in ("mass", "stiffness_factor", "radius", "compliance"))
            parts.append(f"{r['effect']} explains {100 * r['explained_fraction']:.0f}% ({est})")
        txt = ("Of the level residual the calibrated nominal model leaves (held-out, block CV): "
               + "; then ".join(parts) + ".")
    if undecided:
        txt += " Cannot decide: " + "; ".join(
            f"{r['effect']} ({r['reason']}"
            + (f"; {tie_words(r['effect'], r.get('columns_used', []), r['indistinguishable_from'])}"
               if r.get("indistinguishable_from") else "") + ")" for r in undecided) + "."
    weak = [r["effect"] for r in res["ranking"] if not r["excitation"]["enough"]]
    if weak:
        txt += f" Not excited enough to decide: {', '.join(weak)} (see 'to_excite')."
    if "residual_rms_after" in res:
        b, a = res["residual_rms_before"]["total_w"], res["residual_rms_after"]["total_w"]
        txt += f" With {', '.join(res['added'])} added, the level residual falls from {b:.3g} to {a:.3g} (W-scaled RMS)."
    return txt


def effects_figure(res: dict, path: Path) -> None:
    """Ranking bars (held-out explained fraction alone and given the effects selected before it;
    red = significant; each bar's value written beside it) and, after --add, the level residual
    before/after per channel over time (robust y-limits, spikes marked)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = _effects_fig(res)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _effects_fig(res: dict):
    """The figure of ``effects_figure`` (built, not saved)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch

    from kinadapt_nn.features.effect_library import LEVEL_CHANNELS
    from kinadapt_nn.figures import bar_values, before_after_panel

    rows = res["ranking"]
    has_add = "_series" in res
    fig, ax = plt.subplots(1, 3 if has_add else 1, figsize=(18 if has_add else 8, 5), constrained_layout=True,
                           squeeze=False, width_ratios=[1.1, 1, 1] if has_add else None)
    a = ax[0, 0]
    yy = np.arange(len(rows))[::-1]
    alone = np.array([r["explained_fraction_alone"] for r in rows], dtype=float)
    given = np.array([r["explained_fraction"] for r in rows], dtype=float)
    a.barh(yy + 0.2, alone, height=0.4, color="0.8", edgecolor="0.5", lw=0.5)
    a.barh(yy - 0.2, given, height=0.4, color=["C3" if r["significant"] else "0.45" for r in rows])
    a.set_yticks(yy, [f"{r['effect']}  [{r['verdict']}]" if r.get("verdict") else r["effect"] for r in rows],
                 fontsize=8)
    vals = np.r_[alone, given]
    vals = vals[np.isfinite(vals)]
    lo = min(-0.1, float(vals.min()) - 0.12) if vals.size else -0.1
    a.set_xlim(lo, 1.12)
    a.set_ylim(-0.7, len(rows) - 0.3)
    a.axvline(0, color="k", lw=0.8)
    bar_values(a, yy + 0.2, alone)
    bar_values(a, yy - 0.2, given)
    a.set_xlabel("held-out explained fraction of the level residual (block CV)")
    a.set_title("which effect is missing (red = significant)")
    a.legend(handles=[Patch(facecolor="0.8", edgecolor="0.5", lw=0.5, label="alone"),
                      Patch(facecolor="C3", label="given the selected before it: significant"),
                      Patch(facecolor="0.45", label="given the selected before it: not significant")],
             fontsize=7, loc="lower right")
    if has_add:
        des, y, e = res["_series"]
        for col, (chans, unit) in enumerate((((0, 1, 2), "N"), ((3, 4, 5), "N m"))):
            before_after_panel(ax[0, 1 + col], (des.t_s, des.channel, y / des.W, e / des.W), chans, LEVEL_CHANNELS,
                               unit, list(res["added"]))
            ax[0, 1 + col].set_ylabel(f"level residual [{unit}]")
    return fig
