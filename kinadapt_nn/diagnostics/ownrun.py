"""A run of this package as a user's log: its trace plus a set-up generated from its config.

``kinadapt diagnose RUN_DIR`` can judge a simulated run with the same stages as a robot's log
(``userlog.diagnose``): the run's encoders, wrist F/T reading and time become a ``readers.UserLog``
and its config the ``setup.SetupCfg`` a user would write for that cell:

=================  ===========================================================================
set-up             from the run's config (what the cell's integrator knows)
=================  ===========================================================================
[arm]              the arm model the controller uses (``scene.arm_mjcf``), flange site ``flange``
[sensor]           at the flange, axes of the flange (the simulated wrist sensor)
[log]              raw reading, the flange's wrench on the tool (``wrench_acts = "sensor_on_tool"``),
                   not tared (the package tares inside its controller, the log is raw)
[tool]             the peg (``tool.mass_kg``, a ``side_m`` x ``side_m`` x ``length_m`` box) on the
                   NOMINAL axis, its tip at the nominal offset ``sensing.nominal_offset_f_m`` as a
                   first guess (``tip_known = false``: the controller adapts the tool, so where the
                   contact wrench pins the tip, the diagnosis uses that point and reports it)
[contact]          a socket scene (``scene.contact_model = "socket"``): ``geometry = "socket"``, the
                   known bore entrance and axis, the nominal map's stiffnesses
                   ``sensing.stiffness_lat_N_per_m`` / ``stiffness_rot_Nm_per_rad``, the fixture's
                   dampers as built (``scene.socket_damping_ratio``, ``sim.socket.socket_damping``;
                   a hidden ``contact_stiffness`` is not read); a bore scene:
                   ``mode = "exclude"``, ``zone = "entrance"`` (the bore's contacts act along the
                   peg's side and at the entrance edge, not through the tip, and are often under
                   the detection threshold: every row where the tip can touch is contact, left out)
=================  ===========================================================================

The hidden effects (``[effects]``) and the true tool pose are not read: the set-up is the
nominal model, as the package's own diagnosis uses it.

A run with the live monitor (``kinadapt online --monitor``) says in ``summary.json`` when the wrench
changed: an effect that starts mid-run is present only after its onset, while every effect of the
diagnosis is taken as present through the whole log it judges. ``monitor_window`` reads the first
open event there (only the ``monitor`` section: the summary's truth, ``hidden_effects``, is not read);
the diagnosis then judges the log from that onset on (the monitor's settle time after it left out,
as the monitor's own fit does), and the log before the onset is its effect-free baseline, diagnosed
on its own (``kinadapt diagnose RUN``; ``--whole-log`` judges the whole log as one).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import NamedTuple

import numpy as np

from kinadapt_nn.config import ExperimentCfg, arm_mjcf_path, load_config
from kinadapt_nn.diagnostics.readers import UserLog
from kinadapt_nn.diagnostics.setup import (ArmDeclCfg, ContactDeclCfg, LogCfg, SensorCfg, SetupCfg, ToolDeclCfg)
from kinadapt_nn.errors import KinadaptError
from kinadapt_nn.sim.socket import socket_damping
from kinadapt_nn.known import BORE_AXIS_W


def _tool(cfg: ExperimentCfg) -> ToolDeclCfg:
    """The nominal peg in the sensor (= flange) frame: a box along the nominal offset."""
    tip = np.asarray(cfg.sensing.nominal_offset_f_m, dtype=float)
    axis = tip / max(float(np.linalg.norm(tip)), 1e-12)
    t = cfg.tool
    com = tip - 0.5 * t.length_m * axis
    a = t.side_m
    i_side = t.mass_kg / 12.0 * (a * a + t.length_m ** 2)
    i_axis = t.mass_kg / 6.0 * a * a
    # the box's inertia about its COM, axes of f: i_side across the axis, i_axis along it
    I_c = i_side * np.eye(3) + (i_axis - i_side) * np.outer(axis, axis)
    inertia = (I_c[0, 0], I_c[1, 1], I_c[2, 2], I_c[0, 1], I_c[0, 2], I_c[1, 2])
    return ToolDeclCfg(mass_kg=t.mass_kg, com_sensor_m=tuple(float(v) for v in com),
                       inertia_com_kg_m2=tuple(float(v) for v in inertia), tip_sensor_m=tuple(float(v) for v in tip))


def setup_of_run(cfg: ExperimentCfg, effects_files=(), tip_sensor_m=None) -> SetupCfg:
    """The set-up of a package run (module docstring); ``tip_sensor_m`` (3,) [m]: a calibrated tip
    (``calibrated_tip``) in place of the nominal offset. -> ``SetupCfg``."""
    dof = 7
    log = LogCfg(q=tuple(f"q{j}" for j in range(1, dof + 1)), qdot=tuple(f"qd{j}" for j in range(1, dof + 1)),
                 wrench_acts="sensor_on_tool", tared=False)
    entry, axis = tuple(float(v) for v in cfg.scene.bore_entry_w_m), tuple(float(v) for v in BORE_AXIS_W)
    if cfg.scene.contact_model == "socket":  # the nominal map's own contact model, the fixture's dampers
        c_lat, _, c_rot = socket_damping(cfg.scene)
        contact = ContactDeclCfg(mode="tip", geometry="socket", entry_w_m=entry, axis_w=axis,
                                 stiffness_lat_N_per_m=cfg.sensing.stiffness_lat_N_per_m,
                                 stiffness_rot_Nm_per_rad=cfg.sensing.stiffness_rot_Nm_per_rad,
                                 damping_lat_N_s_per_m=c_lat, damping_rot_Nm_s_per_rad=c_rot)
    else:  # a rigid bore: its contacts act along the peg's side and at the entrance edge, not through the
        # tip, and are often lighter than the detection threshold: counted wherever the tip can touch, left out
        contact = ContactDeclCfg(mode="exclude", zone="entrance", entry_w_m=entry, axis_w=axis)
    # the controller's nominal tip: a first guess, within the bounds the controller's own estimate keeps to
    tool = _tool(cfg).model_copy(update={"tip_known": False, "tip_within_m": max(cfg.adaptation.omega_lateral_m,
                                                                                 cfg.adaptation.omega_axial_m)})
    if tip_sensor_m is not None:  # a calibrated tip (a baseline run's): declared known
        tool = tool.model_copy(update={"tip_sensor_m": tuple(float(v) for v in tip_sensor_m), "tip_known": True})
    setup = SetupCfg(log=log, sensor=SensorCfg(), tool=tool,
                     arm=ArmDeclCfg(mjcf=str(arm_mjcf_path(cfg.scene)), flange_site="flange"), contact=contact)
    if effects_files:
        setup = setup.model_copy(update={"analysis": setup.analysis.model_copy(
            update={"effects_files": tuple(str(p) for p in effects_files)})})
    return setup


#: [s] after the monitor's onset, left out of the judged log: the arm's transient (the monitor's own
#: ``monitor.SETTLE_S``, which its fit leaves out; the monitor is a layer above, so the value is here too)
SETTLE_S = 0.02


class Window(NamedTuple):
    """The part of a monitored run its diagnosis judges: from the monitor's first open event on."""

    from_s: float  #: [s] run time the judged log starts at (the event's onset + the monitor's settle time)
    onset_s: float  #: [s] run time of the event's onset (the log before it is the baseline)
    line: str  #: the event as the monitor printed it
    shapes: tuple  #: the monitor's shapes of every open event, in order
    later: tuple  #: [s] onsets of the other open events (inside the judged log)


def monitor_window(folder) -> Window | None:
    """The first open event of a run's monitor (``folder/summary.json``, section ``monitor``), or None
    (not a run folder, no monitor, no open event). A summary that is not JSON is a one-line error."""
    path = Path(folder) / "summary.json"
    if not path.is_file():
        return None
    try:
        mon = json.loads(path.read_text()).get("monitor")
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise KinadaptError(f"'{path}' is not a run's summary ({exc}); pass --whole-log to diagnose the log "
                            "without the monitor's events") from None
    opened = [e for e in (mon or {}).get("events", []) if e.get("open", True)]
    if not opened:
        return None
    first = min(opened, key=lambda e: float(e["onset_s"]))
    t0 = float(first["onset_s"])
    return Window(t0 + SETTLE_S, t0, str(first.get("line", first.get("shape", ""))),
                  tuple(str(e.get("shape", "")) for e in opened),
                  tuple(sorted(float(e["onset_s"]) for e in opened if e is not first)))


def cut(raw, from_s: float | None = None, to_s: float | None = None):
    """The samples of a ``RawLog`` with ``from_s < t_s <= to_s`` [s] (run time; None: no bound), its
    source saying which; a part too short to judge is a one-line error. -> ``RawLog``."""
    from kinadapt_nn.diagnostics.importers import RawLog

    t = np.asarray(raw.t_s, dtype=float)
    keep = np.ones(len(t), bool)
    if from_s is not None:
        keep &= t > from_s
    if to_s is not None:
        keep &= t <= to_s
    span = f"{'start' if from_s is None else f'{from_s:.3f} s'} to {'end' if to_s is None else f'{to_s:.3f} s'}"
    if keep.sum() < 2:
        raise KinadaptError(f"'{raw.source}' has {int(keep.sum())} samples from {span}: too few to diagnose (pass "
                            "--whole-log)")
    return RawLog(t[keep], np.asarray(raw.q_rad)[keep], np.asarray(raw.qdot_rad_s)[keep],
                  np.asarray(raw.wrench_raw_f)[keep], f"{raw.source} ({span})")


def log_of_run(raw) -> UserLog:
    """A ``importers.RawLog`` (a run's trace or the package's CSV) as a ``UserLog``: time from the
    first sample, the raw reading as logged (its convention is the set-up's ``wrench_acts``)."""
    t = np.asarray(raw.t_s, dtype=float)
    return UserLog(t - t[0], np.asarray(raw.q_rad, dtype=float), np.asarray(raw.qdot_rad_s, dtype=float),
                   np.asarray(raw.wrench_raw_f, dtype=float), str(raw.source))


def as_log(src, cfg: ExperimentCfg | None = None, effects_files=(), tip_sensor_m=None,
           span_s: tuple[float | None, float | None] = (None, None)) -> tuple[UserLog, SetupCfg]:
    """A package run (a run folder, its ``trace.npz``, the package's CSV or a ``RawLog``) and its
    config (the folder's ``config.toml`` when ``cfg`` is None) -> (log, set-up) for
    ``userlog.diagnose``; ``span_s`` (from, to) [s] run time: only that part of the log (``cut``)."""
    from kinadapt_nn.diagnostics.importers import load_log

    raw = load_log(Path(src)) if isinstance(src, (str, Path)) else src
    if span_s != (None, None):
        raw = cut(raw, *span_s)
    if cfg is None:
        folder = Path(src) if isinstance(src, (str, Path)) else None
        folder = folder if folder is not None and folder.is_dir() else (folder.parent if folder is not None else None)
        if folder is None or not (folder / "config.toml").is_file():
            raise KinadaptError(f"'{src}': no config.toml beside the log; give the run's config (the set-up is "
                                "generated from it)")
        cfg = load_config(folder / "config.toml")
    return log_of_run(raw), setup_of_run(cfg, effects_files, tip_sensor_m)


def calibrated_tip(baseline, cfg: ExperimentCfg | None = None) -> np.ndarray:
    """Where contacts act on a baseline run (a run without hidden effects of the same cell): the
    calibration stage's contact point (``userlog.calibrate``, the declared socket's own wrench
    taken out). The package's nominal offset is off by the tool error the controller adapts; this
    is the calibration a diagnosis of the cell's other runs starts from. -> (3,) [m], sensor frame."""
    from kinadapt_nn.diagnostics import signals as sg
    from kinadapt_nn.diagnostics import userlog

    log, setup = as_log(baseline, cfg)
    s = sg.from_log(log, setup)
    rc = userlog.RowCfg()
    cal = userlog.calibrate(log, s, setup, userlog.noise_sigma(s.wrench, rc), rc, lambda msg: None)
    if cal.contact_point is None or cal.contact_point.undetermined_along_s is not None:
        raise KinadaptError(f"baseline '{baseline}': its contact does not pin the tip (too little contact, or the "
                            "force barely changed direction); use a run with contact in several directions")
    return np.asarray(cal.contact_point.point_s_m, dtype=float)


def check_rerun(src: Path, add: list[str]) -> None:
    """``--rerun`` needs ``--add`` effects the online model knows and a run folder with its config."""
    from kinadapt_nn.features.effect_library import LIBRARY

    if not add:
        raise KinadaptError("--rerun needs --add EFFECT (the effect to put into the online model)")
    for a in add:
        if a.partition(":")[0] not in LIBRARY:
            raise KinadaptError(f"--rerun --add {a}: the online model adapts only {', '.join(LIBRARY)} "
                                "(model.effects)")
    if not (Path(src).is_dir() and (Path(src) / "config.toml").is_file()):
        raise KinadaptError(f"--rerun needs a simulated run folder with config.toml (got '{src}')")


def rerun_with_effects(src: Path, add: list[str]):
    """Repeat the simulated run ``src`` with ``model.effects += add`` (adapted online: a frozen or
    tracking-only run gets the default ``kalman`` law), TensorBoard on.
    -> (config, EpisodeResult, the ``rerun`` entry of diagnosis.json)."""
    from kinadapt_nn.runs.episode import run_episode

    add = [a.partition(":")[0] for a in add]
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


__all__ = ["Window", "as_log", "calibrated_tip", "check_rerun", "cut", "log_of_run", "monitor_window",
           "rerun_with_effects", "setup_of_run"]
