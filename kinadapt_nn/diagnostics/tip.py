"""The tool's tip in a user's log: the tip as a nuisance fitted beside the effects
(``tip_nuisance``, ``_tip_columns``), the tip the contact rows use (``_effective_tip``), the rows the two
contact accounts dispute (``_without_disputed``), the set-up the data say (``effective_setup``) and
whether the contact acts through the tip (``tip_consistency``)."""

from __future__ import annotations

import dataclasses
from typing import Callable

import numpy as np

from kinadapt_nn.effects import contact_model
from kinadapt_nn.diagnostics import selection as sel
from kinadapt_nn.diagnostics import signals as sg
from kinadapt_nn.diagnostics.accounts import ContactAccounts, _windows
from kinadapt_nn.diagnostics.setup import SetupCfg


def tip_nuisance(s: sg.LogSignals) -> bool:
    """The tip is fitted beside the effects (``_tip_columns``): ``[tool] tip_known = false`` with
    contacts acting through it and contact rows to fit it on."""
    return (not s.setup.tool.tip_known) and s.setup.contact.mode == "tip" and bool(s.contact.any())


def _tip_columns(s: sg.LogSignals) -> np.ndarray:
    """The tip's position in the sensor frame as a nuisance (n, 6, 3) [per m]: a tip moved by ``dp``
    moves the contact force's moment about the sensor by ``dp x F_c`` and a declared socket's spring
    with it (``contact_model.tip_derivative``); what the point estimated before any effect got wrong
    (an effect that acts in contact, e.g. a rotated sensor, rotates that point) is refitted jointly
    with the effects instead of absorbed by it."""
    C = np.zeros((s.n, 6, 3))
    for j in range(3):
        e = np.zeros(3)
        e[j] = 1.0
        C[:, 3:, j] = np.cross(e, s.contact_force_s)
        C[:, :, j] += contact_model.tip_derivative(s.setup, s.R_ws, s.p_ws, e, contact_model.log_times(s))
    return C


def _tip_consistent(declared: SetupCfg, point) -> tuple[bool, float]:
    """Is the estimated contact point the declared tip (within 3 sd or 2 mm, across the line the
    data leave free)? Each sensor axis against its own sd: a point pinned to 0.02 mm across the tool
    is not excused by a wide sd along it. -> (consistent, distance [m])."""
    tip = np.asarray(declared.tool.tip_sensor_m, dtype=float)
    d = point.point_s_m - tip
    if point.undetermined_along_s is not None:  # only the part across the line the data leave free
        d = d - (d @ point.undetermined_along_s) * point.undetermined_along_s
    z = float(np.linalg.norm(d / np.maximum(np.asarray(point.sd_m, dtype=float), 1e-9)))
    return bool(z < 3.0 or np.linalg.norm(d) < 0.002), float(np.linalg.norm(d))


def _effective_tip(log, cal, declared: SetupCfg):
    """``cal`` (a ``userlog.Calibration``, named, not imported: ``userlog`` imports this module) with
    the tip the contact rows use: the declared one; where none is declared ([tool] tip_sensor_m
    left at 0) or it is a first guess ([tool] tip_known = false) and the contact wrench pins a point
    (every direction determined), that point (``effective_setup.tip_used``), and the tip check tests
    it. A declared contact geometry's wrench is computed again at the point (its lever and anchor
    move with the tip). A known declared tip is kept (and tested): the point is estimated before any
    effect, so it would absorb an effect that acts in contact (crosstalk)."""
    setup, point = cal.setup, cal.contact_point
    if point is None or point.undetermined_along_s is not None or setup.contact.mode != "tip":
        return cal
    if any(declared.tool.tip_sensor_m) and declared.tool.tip_known:
        return cal
    far = float(np.linalg.norm(np.asarray(point.point_s_m) - np.asarray(declared.tool.tip_sensor_m)))
    if not declared.tool.tip_known and far > declared.tool.tip_within_m:  # not the tip: the guess stands
        return cal
    return at_tip(log, cal, point.point_s_m)


def at_tip(log, cal, tip_s_m):
    """``cal`` (a ``userlog.Calibration``) with the contact rows' tip at ``tip_s_m`` (3,) [m, sensor
    frame]: the set-up's tool tip, a declared geometry's account and signals computed again there."""
    from kinadapt_nn.diagnostics.physical import tip_moment_map

    s, setup = cal.signals, cal.setup
    tip = tuple(float(v) for v in tip_s_m)
    setup = setup.model_copy(update={"tool": setup.tool.model_copy(update={"tip_sensor_m": tip})})
    acc, contact = cal.accounts, s.contact
    if acc is not None and "declared_windows_s" in acc.report:  # the declared geometry's account at the point
        acc = ContactAccounts.of(acc.data, contact_model.declared_contact(setup, s.R_ws, s.p_ws), s.t, setup)
        contact = acc.used
    if setup.contact.declared_geometry:  # its anchor and lever at the point: the signals again
        s = sg.from_log(log, setup)
    else:
        s = dataclasses.replace(s, setup=setup, tip_map=tip_moment_map(np.asarray(tip)))
    return dataclasses.replace(cal, signals=s.with_contact(contact, _free_offset(s, contact)), setup=setup, accounts=acc)


#: [m] a Gauss-Newton step of the tip shorter than this ends the iteration (``judged_at_tip``)
TIP_STEP_M = 5e-4
#: the most Gauss-Newton steps of the tip after the first ranking
TIP_STEPS = 2


def judged_at_tip(log, cal0, declared: SetupCfg, judged: Callable, progress: Callable[[str], None]) -> tuple:
    """``cal0`` (a ``userlog.Calibration`` at the declared tip): the checks and the ranking at the tip
    the contact rows use. A known tip, or none declared: ``_effective_tip`` (the estimated contact
    point where it pins one). A first guess (``[tool] tip_known = false``): the tip is a nonlinear
    nuisance (the socket's anchor and lever move with it) fitted by first-order columns about the
    point it starts from, so the ranking starts at the declared guess and moves there to the tip it
    fitted (Gauss-Newton steps, at most ``TIP_STEPS``, until a step is shorter than ``TIP_STEP_M``).
    It does not start at the contact point estimated before any effect: an effect that acts in contact
    moves that point (a grasp that yields under moment lengthens the apparent lever through the
    fixture's angular spring: 109 mm for a 100 mm tool in the excitation run, docs/diagnose.md), and
    about it the tip's columns traded the tip for the effect. ``judged(calibration)`` -> (calibration,
    checks, ``_RankCtx``, ``Ranked``). -> those and the iteration's account (or None)."""
    guess = np.asarray(declared.tool.tip_sensor_m, dtype=float)
    if declared.tool.tip_known or not guess.any() or not tip_nuisance(cal0.signals):
        return (*judged(_without_disputed(_effective_tip(log, cal0, declared))), None)
    cur = judged(_without_disputed(cal0))
    if cur[2].block is not None:
        return (*cur, None)
    path = []
    for k in range(TIP_STEPS + 1):
        at = np.asarray(cur[0].setup.tool.tip_sensor_m, dtype=float)
        fitted = at + np.asarray(cur[3].result.nuisance[-3:], dtype=float)
        path.append({"about_sensor_m": [float(v) for v in at], "fitted_sensor_m": [float(v) for v in fitted],
                     "step_m": float(np.linalg.norm(fitted - at))})
        if k == TIP_STEPS or path[-1]["step_m"] < TIP_STEP_M or np.linalg.norm(fitted - guess) > declared.tool.tip_within_m:
            break
        progress(f"the tip: ranking again about the tip fitted ({path[-1]['step_m'] * 1e3:.2f} mm away: a Gauss-Newton step)")
        cur = judged(_without_disputed(at_tip(log, cal0, fitted)))
    lin = {"steps": path, "converged": path[-1]["step_m"] < TIP_STEP_M,
           "why": "the tip is fitted by first-order columns about a point: from the declared first guess, the ranking "
                  "is repeated about the tip it fitted until the step is below "
                  f"{TIP_STEP_M * 1e3:g} mm (at most {TIP_STEPS} steps); the contact point estimated before the "
                  "effects is not a start (an effect acting in contact moves it)"}
    return (*cur, lin)


def _without_disputed(cal):
    """``cal`` (a ``userlog.Calibration``) with the rows whose phase the two accounts dispute
    (``ContactAccounts``) left out of the ranking where contact rows are fitted (``[contact] mode =
    "tip"``), as ``[analysis] exclude_s`` windows: a declared socket that the data show released (its
    tip read from encoders a joint offset moved) predicts a spring force the sensor never saw, which
    no first-order column describes."""
    acc, setup, s = cal.accounts, cal.setup, cal.signals
    if acc is None or acc.disputed is None or setup.contact.mode != "tip" or not setup.contact.declared_geometry:
        return cal
    # the contradictions: the declared geometry's wrench predicts a force the data do not show, or the
    # data show a force where the declared geometry cannot touch
    f_pred = np.linalg.norm(contact_model.nominal_wrench(setup, s.R_ws, s.p_ws)[:, :3], axis=1)
    bad = acc.disputed & ((~acc.data & (f_pred > setup.contact.detect_force_N)) | acc.data)
    if bad.mean() < 0.002:
        return cal
    win = tuple(tuple(w) for w in _windows(bad, s.t))
    setup = setup.model_copy(update={"analysis": setup.analysis.model_copy(
        update={"exclude_s": tuple(setup.analysis.exclude_s) + win})})
    return dataclasses.replace(cal, signals=dataclasses.replace(cal.signals, setup=setup), setup=setup)


def _free_offset(s: sg.LogSignals, contact: np.ndarray) -> np.ndarray:
    """(6,) the free-space offset of the force beyond the declared model (``LogSignals.with_contact``)."""
    off = np.zeros(6)
    if (~contact).any():
        off[:3] = np.median(s.wrench[~contact, :3] - s.w_nom[~contact, :3], axis=0)
    return off


def effective_setup(declared: SetupCfg, used: SetupCfg, fitm, point, tip_fit=None) -> dict:
    """The set-up the data say (beside the declared one): the mount used, the calibrated tool, and
    where contacts act -- tested against the declared tip, not assumed."""
    m = float(fitm.x[3])
    out = {"sensor_rpy_flange_deg": [float(v) for v in used.sensor.rpy_flange_deg],
           "mount": "estimated" if not declared.sensor.mount_known else "declared",
           "tool_mass_kg": m, "tool_mass_sd_kg": float(fitm.sd[3]),
           "tool": ("estimated (sensor-mount fit)" if fitm.report.get("determined", True) else
                    "declared (the log does not turn the sensor enough to calibrate: sensor_mount.undetermined)"),
           "tool_com_sensor_m": [float(v) for v in fitm.x[4:7] / m] if abs(m) > 1e-9 else None,
           "contact_point": None if point is None else point.to_json()}
    if point is not None:
        ok, dist = _tip_consistent(declared, point)
        out["contact_point"]["declared_tip_sensor_m"] = [float(v) for v in declared.tool.tip_sensor_m]
        out["contact_point"]["declared_tip_distance_m"] = dist
        out["contact_point"]["declared_tip_consistent"] = ok
    out["tip_used_sensor_m"] = [float(v) for v in used.tool.tip_sensor_m]
    same = tuple(used.tool.tip_sensor_m) == tuple(declared.tool.tip_sensor_m)
    out["tip_used"] = ("the declared tip" if same else
                       "the estimated contact point ([tool] tip_known = false: the declared tip is a first guess)"
                       if not declared.tool.tip_known else "the estimated contact point (no tip declared)")
    if tip_fit is not None:  # a finding about the tool: where its tip is, fitted with the effects
        tip = np.asarray(used.tool.tip_sensor_m) + tip_fit[0]
        d = tip - np.asarray(declared.tool.tip_sensor_m)
        out["tool_tip"] = {"tip_sensor_m": [float(v) for v in tip], "sd_m": [float(v) for v in tip_fit[1]],
                           "declared_sensor_m": [float(v) for v in declared.tool.tip_sensor_m],
                           "difference_m": [float(v) for v in d], "distance_m": float(np.linalg.norm(d)),
                           "how": "the contact point estimated before the effects, then fitted beside them (a nuisance of "
                                  "the ranking: method.nuisance); sd from that joint fit"}
    return out


def tip_consistency(des: sel.Design, present: list[str], sc: sel.SelCfg, factor: float = 4.0) -> dict:
    """Does the contact act through the declared tip? The residual left by the final model in the
    contact rows (moment about the tip) against the free-space rows, both noise-weighted. A wrong
    tip, a face contact or a second contact point leaves a tip moment no effect explains."""
    _, after, _ = sel.refit(des, present, sc)
    free, tip = des.channel < 6, des.channel >= 6
    if not tip.any() or not free.any():
        return {"ok": True, "note": "no contact rows" if not tip.any() else "no free-space rows"}
    r_free = float(np.sqrt(np.mean(after[free] ** 2)))
    r_tip = float(np.sqrt(np.mean(after[tip] ** 2)))
    out = {"ok": True, "residual_rms_w_free": r_free, "residual_rms_w_tip_moment": r_tip}
    if r_tip > factor * max(r_free, 1.0):
        out["ok"] = False
        out["message"] = (f"in contact the moment about the declared tip is {r_tip / max(r_free, 1.0):.1f}x the free-space "
                          "residual: the contact does not act through [tool] tip_sensor_m (check it; a flat face pressed "
                          "flat or a second contact point: set [contact] mode = \"exclude\")")
    return out
