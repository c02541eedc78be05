"""``kinadapt diagnose LOG --setup SETUP.toml``: a user's own robot log against the physical
nominal model of their set-up (``physical``), effects ranked with verdicts (``selection``).

Pipeline: read (``readers``) -> sensor kinematics from the encoders -> the declared tool's
wrench -> contact detection -> rows (free space: the six wrench channels; contact: the moment
about the declared tip) -> forward selection with verdicts -> joint re-estimate of the present
effects -> (once) contact re-detected with the present effects in the model -> report.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import numpy as np

from kinadapt_nn.diagnostics import physical as ph
from kinadapt_nn.diagnostics import selection as sel
from kinadapt_nn.features.effect_library import moving_average
from kinadapt_nn.diagnostics.setup import SetupCfg
from kinadapt_nn.errors import KinadaptError

FREE_CHANNELS = ("F_x", "F_y", "F_z", "M_x", "M_y", "M_z")  # sensor frame
TIP_CHANNELS = ("Mtip_x", "Mtip_y", "Mtip_z")  # moment about the declared tip, sensor frame
CHANNELS = FREE_CHANNELS + TIP_CHANNELS
UNITS = ("N", "N", "N", "N m", "N m", "N m", "N m", "N m", "N m")


class RowCfg(NamedTuple):
    smooth_s: float = 0.02  #: [s] centred moving average on the residual AND the columns
    stride_s: float = 0.01  #: [s] row spacing
    block_s: float = 0.5  #: [s] shortest CV block (at most ``max_blocks`` blocks)
    max_blocks: int = 40
    edge_s: float = 0.06  #: [s] rows this close to the log's ends are left out (derivative edges)
    force_floor_N: float = 0.01  #: [N] smallest per-sample force noise used for the channel weights
    moment_floor_Nm: float = 0.001  #: [N m] the same for moments


def noise_sigma(r: np.ndarray, rc: RowCfg) -> np.ndarray:
    """Per-channel sample noise of the reading (6,) from second differences (robust MAD)."""
    if len(r) < 5:
        return np.array([rc.force_floor_N] * 3 + [rc.moment_floor_Nm] * 3)
    d2 = r[2:] - 2 * r[1:-1] + r[:-2]
    s = 1.4826 * np.median(np.abs(d2 - np.median(d2, axis=0)), axis=0) / np.sqrt(6.0)
    return np.maximum(s, [rc.force_floor_N] * 3 + [rc.moment_floor_Nm] * 3)


def detect_contact(e: np.ndarray, t_s: np.ndarray, setup: SetupCfg, rc: RowCfg) -> tuple[np.ndarray, np.ndarray]:
    """Contact samples from the force the tool model does not explain (N, 6) -> (contact (N,)
    bool, the offset taken out (6,)). The offset is the median of the residual (the free-space
    value when most of the log is free); contact = |force - offset| > ``detect_force_N`` after a
    20 ms average, gaps shorter than 2 ``margin_s`` filled, then widened by ``margin_s``."""
    n = len(t_s)
    if setup.contact.mode == "none":
        return np.zeros(n, bool), np.zeros(6)
    dt = float(np.median(np.diff(t_s)))
    es = moving_average(e, max(1, int(round(rc.smooth_s / dt))))
    off = np.median(es, axis=0)
    raw = np.linalg.norm(es[:, :3] - off[:3], axis=1) > setup.contact.detect_force_N
    k = int(round(setup.contact.margin_s / dt))
    if k > 0 and raw.any():
        c = np.convolve(raw.astype(float), np.ones(2 * k + 1), "same") > 0  # widen
        # fill short free gaps between contact runs
        idx = np.flatnonzero(c)
        gaps = np.flatnonzero(np.diff(idx) > 1)
        for g in gaps:
            a, b = idx[g], idx[g + 1]
            if (b - a) <= 2 * k:
                c[a:b] = True
        raw = c
    return raw, off


class Prep(NamedTuple):
    """Everything that depends on the log and the setup but not on the contact mask."""

    t_s: np.ndarray
    q: np.ndarray
    qdot: np.ndarray
    r: np.ndarray  #: (N, 6) tool on sensor, s
    w_nom: np.ndarray  #: (N, 6)
    kin: ph.KinSeries
    arm: ph.ArmModel
    sigma: np.ndarray  #: (6,) per-sample noise
    enc_cols: np.ndarray | None  #: (N, 6, 7) encoder-offset columns (cached)


def prepare(log, setup: SetupCfg, rc: RowCfg, progress: Callable[[str], None]) -> Prep:
    """Kinematics and the nominal tool wrench of every sample."""
    arm = ph.ArmModel(setup)
    t = np.asarray(log.t_s, dtype=float)
    q = np.asarray(log.q_rad, dtype=float)
    qdot = np.asarray(log.qdot_rad_s, dtype=float) if log.qdot_rad_s is not None else ph.derivative(q, t)
    progress(f"kinematics of {len(t)} samples")
    kin = arm.series(q, qdot, t)
    m, mc, I_O = ph.nominal_inertials(setup)
    r = setup.log.sign * np.asarray(log.wrench_log, dtype=float)
    return Prep(t, q, qdot, r, ph.tool_wrench(kin, m, mc, I_O), kin, arm, noise_sigma(r, rc), None)


def prepared(prep: Prep, setup: SetupCfg, contact: np.ndarray, offset: np.ndarray) -> ph.Prepared:
    e = prep.r - prep.w_nom - offset
    f_c = np.where(contact[:, None], e[:, :3], 0.0)
    return ph.Prepared(prep.t_s, prep.q, prep.qdot, prep.r, prep.w_nom, prep.kin, contact, f_c,
                       ph.tip_moment_map(setup.tool.tip_sensor_m), setup, prep.arm)


def build_design(pp: ph.Prepared, prep: Prep, names: list[str], rc: RowCfg,
                 cols_cache: dict) -> sel.Design:
    """Rows of the regression (module docstring) with per-channel weights 1/noise. ``cols_cache``
    receives every effect's sample columns (N, 6, k) of this design (the encoder columns, which do
    not depend on the contact mask, are reused from it)."""
    setup = pp.setup
    t = pp.t_s
    n = len(t)
    dt = float(np.median(np.diff(t)))
    k_s = max(1, int(round(rc.smooth_s / dt)))
    stride = max(1, int(round(rc.stride_s / dt)))
    ok = (t >= t[0] + rc.edge_s) & (t <= t[-1] - rc.edge_s)
    for a, b in setup.analysis.exclude_s:
        ok &= ~((t - t[0] >= a) & (t - t[0] <= b))
    if setup.contact.mode == "exclude":
        ok &= ~pp.contact
    rows = np.flatnonzero(ok)[::stride]
    if len(rows) < 20:
        raise KinadaptError(f"the log leaves {len(rows)} rows after [analysis] exclude_s and the ends; "
                            "give a longer log or exclude less")
    L = pp.L
    sig = prep.sigma
    w_free = 1.0 / sig
    tip = np.asarray(setup.tool.tip_sensor_m, dtype=float)
    sig_tip = np.sqrt(sig[3:] ** 2 + float(tip @ tip) * np.mean(sig[:3] ** 2))
    w_tip = 1.0 / sig_tip
    con = pp.contact[rows]

    def to_rows(x: np.ndarray) -> np.ndarray:
        """(N, 6, k) sample wrenches -> (R, k) weighted rows (free: 6 channels; contact: 3)."""
        xs = moving_average(x, k_s)[rows]  # (r, 6, k)
        free = xs[~con] * w_free[None, :, None]
        tipm = np.einsum("ij,njk->nik", L, xs[con]) * w_tip[None, :, None]
        return np.concatenate([free.reshape(-1, x.shape[2]), tipm.reshape(-1, x.shape[2])], axis=0)

    e = (pp.r - pp.w_nom)[:, :, None]
    y = to_rows(e)[:, 0]
    X = {}
    for name in names:
        C = cols_cache.get(name)
        if C is None or name != "encoder_offset":  # the encoder columns do not depend on the contact mask
            C = cols_cache[name] = ph.SPECS[name].columns(pp)
        X[name] = to_rows(C)
    Z = to_rows(np.broadcast_to(np.eye(6)[None], (n, 6, 6)).copy()) if setup.log.tared else np.zeros((len(y), 0))
    nf, nc = int((~con).sum()), int(con.sum())
    channel = np.concatenate([np.tile(np.arange(6), nf), np.tile(np.arange(6, 9), nc)])
    W = np.concatenate([np.tile(w_free, nf), np.tile(w_tip, nc)])
    tr = np.concatenate([np.repeat(t[rows][~con], 6), np.repeat(t[rows][con], 3)]) - t[0]
    dur = float(t[-1] - t[0])
    blen = max(rc.block_s, dur / rc.max_blocks)
    nb = max(2, int(np.ceil(dur / blen)))
    block = np.minimum((tr / blen).astype(int), nb - 1)
    return sel.Design(y, X, Z, block, nb, {nm: ph.SPECS[nm].relevant for nm in names},
                      {nm: ph.SPECS[nm].one_of for nm in names}, W, channel, CHANNELS, tr)


def sign_check(pp: ph.Prepared, setup: SetupCfg) -> dict:
    """Fit the tool's total mass from the force (with a constant offset: it does not turn with
    gravity) on every sample, then again on the 60 % that fit best (contact and effects are the
    outliers; a flipped convention flips every sample, so it cannot hide there). A negative mass
    means the wrench convention is flipped. Independent of the contact detection."""
    kin = pp.kin
    ga = kin.g_s - kin.a_s  # (N, 3)
    n = len(ga)
    y = pp.r[:, :3].reshape(-1)
    A = np.zeros((3 * n, 4))
    A[:, 0] = ga.reshape(-1)
    for j in range(3):
        A[j::3, 1 + j] = 1.0
    keep = np.ones(n, bool)
    coef = np.zeros(4)
    for _ in range(2):
        rows = np.repeat(keep, 3)
        coef, *_ = np.linalg.lstsq(A[rows], y[rows], rcond=None)
        res = np.linalg.norm((y - A @ coef).reshape(n, 3), axis=1)
        keep = res <= np.quantile(res, 0.6)
    m_fit = float(coef[0])
    spread = float(np.linalg.norm(ga[keep] - ga[keep].mean(0), axis=1).max()) if keep.any() else 0.0
    out = {"fitted_total_mass_kg": m_fit, "declared_mass_kg": setup.tool.mass_kg, "ok": True}
    if spread < 1.0:
        out["note"] = "the tool hardly turns in the log: the mass (and sign) cannot be checked"
        return out
    if m_fit < -0.05 and (setup.tool.mass_kg == 0 or m_fit < -0.3 * setup.tool.mass_kg):
        out["ok"] = False
        out["message"] = (f"the tool weighs {m_fit:.3g} kg by the measured force (declared {setup.tool.mass_kg:g} kg): "
                          f"is [log] wrench_acts = \"{setup.log.wrench_acts}\" right? (try the other one)")
    return out


class Result(NamedTuple):
    report: dict  #: diagnosis.json content (without the header)
    design: sel.Design
    before: np.ndarray | None  #: (R,) rows before --add (nuisance fitted), or None
    after: np.ndarray | None  #: (R,) rows after --add
    prep: Prep
    contact: np.ndarray


NOT_JUDGED = ("contact-model effect: not judged without a declared contact geometry (a tip contact obeys the same "
              "moment balance whatever the surface's stiffness); judged on this package's own bore/socket runs")


def _not_judged(name: str) -> dict:
    """A ranking entry for a contact-model effect on a user's log: cannot_decide, nothing fitted."""
    return {"effect": name, "verdict": "cannot_decide", "significant": False, "reason": NOT_JUDGED,
            "judged": False, "explained_fraction": None, "explained_fraction_alone": None, "p_value": None,
            "p_adjusted": None, "selected_round": None, "estimate": {}, "excitation": {"enough": False}}


def _rms_by_channel(des: sel.Design, e: np.ndarray) -> dict:
    out = {}
    for c, name in enumerate(CHANNELS):
        m = des.channel == c
        if m.any():
            out[name] = float(np.sqrt(np.mean((e[m] / des.W[m]) ** 2)))
    out["total_w"] = float(np.sqrt(np.mean(e**2))) if len(e) else None
    return out


def _entry_report(e: dict, setup: SetupCfg) -> dict:
    n = e["effect"]
    spec = ph.SPECS[n]
    out = {k: v for k, v in e.items() if k not in ("params", "sd", "columns_used")}
    out["judged"] = True
    cols = e["columns_used"]
    p, sd = e["params"], e["sd"]
    if spec.one_of:
        full = ph.to_user(n, p, sd, setup)
        out["estimate"] = {spec.params[c]: full[spec.params[c]] for c in cols}
    else:
        out["estimate"] = ph.to_user(n, p, sd, setup)
    if e["excitation"]["weak_parameters"]:
        out["excitation"] = {**e["excitation"], "weak_parameters": [spec.params[j] for j in e["excitation"]["weak_parameters"]]}
    out["estimate_params"] = {"names": list(spec.params), "units": list(spec.units),
                              "value": [float(v) for v in p], "sd": [float(v) for v in sd]}
    return out


def diagnose(log, setup: SetupCfg, add: list[str] | None = None, rc: RowCfg = RowCfg(),
             sc: sel.SelCfg = sel.SelCfg(), progress: Callable[[str], None] | None = None) -> Result:
    """The whole diagnosis of a user's log (module docstring). ``add``: effects to refit with
    (``--add``). -> ``Result``."""
    progress = progress or (lambda msg: None)
    names = ph.applicable_effects(setup)
    add = list(add or [])
    for a in add:
        if a not in ph.PHYSICAL_EFFECTS:
            raise KinadaptError(f"--add {a}: unknown effect for a user's log (choose from {', '.join(ph.PHYSICAL_EFFECTS)})")
        if a not in names:
            raise KinadaptError(f"--add {a}: this effect is left out for this set-up (see [analysis] and "
                                f"[log] tared; judged: {', '.join(names)})")
    if not names:
        raise KinadaptError("no effect left to judge ([analysis] effects / exclude_effects leave none)")
    prep = prepare(log, setup, rc, progress)
    contact, off = detect_contact(prep.r - prep.w_nom, prep.t_s, setup, rc)
    pp = prepared(prep, setup, contact, off)
    check = sign_check(pp, setup)
    hints = {n: ph.SPECS[n].excite_hint for n in names}
    hints["_params"] = {n: ph.SPECS[n].params for n in names}
    cache: dict = {}
    block = None if check["ok"] else "the sign check failed: " + check["message"]
    des, result, contact, pp = _rank(prep, pp, setup, names, contact, rc, sc, hints, block, cache, progress)
    fit_check = tip_consistency(des, list(result.present), sc)
    contact_rows = "used (moment about the declared tip)" if setup.contact.mode == "tip" else setup.contact.mode
    if not fit_check["ok"] and setup.contact.mode == "tip":
        # the data contradict "contacts act through the declared tip": judge on free space alone
        # rather than let an effect absorb a contact the model cannot describe
        progress("contact does not act through the declared tip: ranking again without the contact rows")
        setup_x = setup.model_copy(update={"contact": setup.contact.model_copy(update={"mode": "exclude"})})
        names_x = [n for n in names if n in ph.applicable_effects(setup_x)]
        des, result, contact, pp = _rank(prep, pp._replace(setup=setup_x), setup_x, names_x,
                                         contact, rc, sc, hints, block, cache, progress)
        fit_check["action"] = "contact rows left out; verdicts from free space alone"
        contact_rows = "left out (tip check failed)"
    entries = [_entry_report(e, setup) for e in result.entries]
    dt = float(np.median(np.diff(prep.t_s)))
    report = {
        "setup_summary": {"tared": setup.log.tared, "wrench_acts": setup.log.wrench_acts,
                          "tool_mass_kg": setup.tool.mass_kg, "contact_mode": setup.contact.mode},
        "log": {"samples": int(len(prep.t_s)), "duration_s": float(prep.t_s[-1] - prep.t_s[0]),
                "rate_Hz": float(1.0 / dt), "qdot": "logged" if log.qdot_rad_s is not None else "differentiated from q"},
        "contact": {"fraction": float(contact.mean()), "windows_s": _windows(contact, prep.t_s), "rows": contact_rows},
        "noise_sigma": dict(zip(FREE_CHANNELS, (float(v) for v in prep.sigma))),
        "sign_check": check,
        "tip_contact_check": fit_check,
        "warnings": [m for m in (check.get("message"), fit_check.get("message")) if m],
        "ranking": entries + [_not_judged(n) for n in ph.CONTACT_MODEL_EFFECTS],
        "not_judged": [{"effect": n, "reason": NOT_JUDGED} for n in ph.CONTACT_MODEL_EFFECTS],
        "residual_rms_by_channel": _rms_by_channel(des, des.y),
        "explained_by_present": float(1.0 - result.sse_after / max(result.sse_total, 1e-300)),
        "method": {"rows": rc._asdict(), "selection": sc._asdict(), "blocks": des.n_blocks,
                   "nuisance": "constant offset (tared log)" if setup.log.tared else "none"},
    }
    before = after = None
    if add:
        before, after, fitted_add = sel.refit(des, add, sc)
        report["residual_rms_before"] = _rms_by_channel(des, before)
        report["residual_rms_after"] = _rms_by_channel(des, after)
        report["added"] = {}
        for n, (c, full) in fitted_add.items():
            spec = ph.SPECS[n]
            est = ph.to_user(n, full, np.full(len(full), np.nan), setup)
            if spec.one_of:
                est = {spec.params[j]: est[spec.params[j]] for j in c}
            report["added"][n] = {"estimate": est}
    report["summary"] = summary_text(report)
    return Result(report, des, before, after, prep, contact)


def _rank(prep: Prep, pp: ph.Prepared, setup: SetupCfg, names: list[str], contact: np.ndarray, rc: RowCfg,
          sc: sel.SelCfg, hints: dict, block: str | None, cache: dict, progress: Callable[[str], None]):
    """Design + selection; once more with contact re-detected when the present effects change it.
    -> (Design, Selection, contact mask, Prepared)."""
    result = des = None
    for it in range(2):
        progress("effect columns" if it == 0 else "contact re-detected with the present effects; ranking again")
        des = build_design(pp, prep, names, rc, cache)
        progress(f"ranking {len(names)} effects on {len(des.y)} rows, {des.n_blocks} blocks")
        result = sel.select(des, sc, lambda n, p: ph.implausible(n, p, setup), hints, block)
        if it == 1 or not result.present or setup.contact.mode == "none":
            break
        fitted = np.zeros_like(prep.r)
        for n, (c, p_phys, _) in result.present.items():
            fitted += cache[n][:, :, c] @ p_phys  # the columns this design was built from
        new_contact, new_off = detect_contact(prep.r - prep.w_nom - fitted, prep.t_s, setup, rc)
        if np.mean(new_contact != contact) < 0.005:
            break
        contact = new_contact
        pp = prepared(prep, setup, contact, new_off)
    return des, result, contact, pp


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


def _windows(mask: np.ndarray, t: np.ndarray) -> list[list[float]]:
    edges = np.flatnonzero(np.diff(np.r_[0, mask.astype(int), 0]))
    return [[float(t[a] - t[0]), float(t[min(b, len(t)) - 1] - t[0])] for a, b in zip(edges[::2], edges[1::2])]


def summary_text(rep: dict) -> str:
    """A paragraph a person reads first."""
    parts = []
    chk = rep["sign_check"]
    if not chk["ok"]:
        return ("WARNING: " + chk["message"] + ". Every effect is 'cannot_decide' until the wrench convention "
                "is right (nothing can be judged against a tool that weighs less than nothing).")
    if not rep["tip_contact_check"]["ok"]:
        parts.append("WARNING: " + rep["tip_contact_check"]["message"] + ".")
    pres = [e for e in rep["ranking"] if e["verdict"] == "present"]
    und = [e for e in rep["ranking"] if e["verdict"] == "cannot_decide" and e.get("judged", True)]
    if pres:
        txt = []
        for e in pres:
            est = e["estimate"]
            keys = [k for k in est if not k.startswith("total_") and est[k]["value"] is not None][:4]
            txt.append(f"{e['effect']} (" + ", ".join(f"{k} {est[k]['value']:.3g} ± {est[k]['sd']:.2g} {est[k]['unit']}"
                                                     for k in keys) + ")")
        parts.append("Present: " + "; ".join(txt) + f" — together {100 * rep['explained_by_present']:.0f}% of the "
                     "residual of the declared model, held-out.")
    else:
        parts.append("No effect is present: the declared set-up explains the log as well as any library effect.")
    if und:
        parts.append("Cannot decide: " + "; ".join(
            f"{e['effect']} ({e.get('reason') or ''}"
            + (f"; indistinguishable from {', '.join(e['indistinguishable_from'])}" if e.get("indistinguishable_from") else "")
            + (f"; unexcited: {', '.join(e['excitation']['weak_parameters'])}" if e["excitation"].get("weak_parameters")
               and e["verdict"] == "cannot_decide" and not e.get("indistinguishable_from") else "")
            + ")" for e in und) + ".")
    absent = [e["effect"] for e in rep["ranking"] if e["verdict"] == "absent"]
    if absent:
        parts.append("Absent: " + ", ".join(absent) + ".")
    nj = [e["effect"] for e in rep["ranking"] if not e.get("judged", True)]
    if nj:
        parts.append("Not judged (no contact geometry declared): " + ", ".join(nj) + ".")
    if "residual_rms_after" in rep:
        b, a = rep["residual_rms_before"]["total_w"], rep["residual_rms_after"]["total_w"]
        parts.append(f"With {', '.join(rep['added'])} added, the residual falls from {b:.3g} to {a:.3g} "
                     "(noise-weighted RMS, all rows).")
    return " ".join(parts)
