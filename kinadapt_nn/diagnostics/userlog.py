"""``kinadapt diagnose LOG --setup SETUP.toml``: a user's own robot log against the physical
nominal model of their set-up (``physical``), effects ranked with verdicts (``selection``).

Stages, each a function that returns a frozen result (a package run goes through the same ones,
its set-up generated from its config: ``ownrun``):

==================  =================================  ======================================
stage               function                           result
==================  =================================  ======================================
read                ``readers.read_log``               ``readers.UserLog``
signals             ``signals.from_log``               ``signals.LogSignals`` (sensor kinematics
                                                       from the encoders, the declared tool's
                                                       wrench)
segmentation        ``segmentation.free_space``        ``segmentation.Segmentation``
calibration         ``calibrate``                      ``Calibration`` (mount, tool, offset;
                                                       contact detected against it)
checks              ``_checks``                        ``Checks`` (sign, units, mount)
rows + selection    ``_ranked``                        ``Ranked`` (the effect library's columns
                                                       as per-block normal equations; forward
                                                       selection with verdicts; contact
                                                       re-detected once with the present effects)
completeness        ``completeness.assess``            ``completeness.Completeness`` (and hints)
report              ``report.Report.of``               ``report.Report`` (read-only; writes
                                                       ``diagnosis.json`` itself)
==================  =================================  ======================================

``diagnose`` runs them and returns ``Result`` (the report and what the figures draw); the CLI
only parses, prints and writes.
"""

from __future__ import annotations

import dataclasses
from typing import Callable, NamedTuple

import numpy as np

from kinadapt_nn.diagnostics import contact_point, nonlinear, release, segmentation, steps, stream
from kinadapt_nn.diagnostics import selection as sel
from kinadapt_nn.diagnostics import signals as sg
from kinadapt_nn.effects import contact_model
from kinadapt_nn.effects.builtin import BUILTINS, CONTACT_MODEL_EFFECTS
from kinadapt_nn.effects.contract import Effect, load_effect_files
from kinadapt_nn.diagnostics.report import Report
from kinadapt_nn.diagnostics.setup import SetupCfg
from kinadapt_nn.errors import KinadaptError, did_you_mean
from kinadapt_nn.diagnostics.stream import RowMap
from kinadapt_nn.diagnostics.accounts import ContactAccounts, _widen, _windows  # noqa: F401 (re-exported)
from kinadapt_nn.diagnostics.summary import (  # noqa: F401 (re-exported)
    SUMMARY_PARAMETERS, _nuisance_text, _payload_text, completeness_text, summary_text)
from kinadapt_nn.diagnostics.tip import (  # noqa: F401 (re-exported)
    _effective_tip, _free_offset, _tip_columns, _tip_consistent, _without_disputed, effective_setup,
    judged_at_tip, tip_consistency, tip_nuisance)

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
    #: a log with more row times than this is ranked on every m-th span of ``span_s`` (by time from
    #: its start: the same whatever the chunking): an hour at 1 kHz on 20 minutes of rows spread over
    #: the whole hour (``RowMap.span_every``; the report's ``method.rows_cover_s``)
    max_row_times: int = 120_000
    span_s: float = 5.0  #: [s]
    chunk_samples: int = stream.CHUNK_SAMPLES  #: samples per chunk of the design's passes (not in the report)


def noise_sigma(r: np.ndarray, rc: RowCfg) -> np.ndarray:
    """Per-channel sample noise of the reading (6,) from second differences (robust MAD)."""
    return np.maximum(sg.sample_noise(r), [rc.force_floor_N] * 3 + [rc.moment_floor_Nm] * 3)


def static_sigma(s: sg.LogSignals, residual: np.ndarray, rc: RowCfg) -> tuple[np.ndarray, str]:
    """Per-channel noise (6,) of a static-pose log: the pooled scatter of repeated samples of the
    same pose when at least a fifth of the rows repeat a pose, else the robust scale (MAD) of the
    calibration fit's residual (then model errors count as noise: a conservative floor).
    -> (sigma, how)."""
    floor = np.array([rc.force_floor_N] * 3 + [rc.moment_floor_Nm] * 3)
    key = np.round(s.q, 9)
    _, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    rep = counts[inv] > 1
    if rep.mean() >= 0.2:
        means = np.zeros((len(counts), 6))
        np.add.at(means, inv, s.wrench)
        means /= counts[:, None]
        dev = (s.wrench - means[inv])[rep]
        dof = float(np.sum(counts[counts > 1] - 1))
        return np.maximum(np.sqrt(np.sum(dev**2, axis=0) / max(dof, 1.0)), floor), "scatter of repeated poses"
    mad = 1.4826 * np.median(np.abs(residual - np.median(residual, axis=0)), axis=0)
    return np.maximum(mad, floor), "robust scale of the calibration fit's residual (no repeated poses)"


def detect_contact(e: np.ndarray, t_s: np.ndarray, setup: SetupCfg, rc: RowCfg,
                   free: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Contact samples from the force the tool model does not explain (N, 6), or its force part
    (N, 3), -> (contact (N,) bool, the offset taken out (6,): in a log in time, the force's only).
    The offset is the median of the residual over ``free`` (n,)
    bool, the samples known to be free space (``segmentation``; all samples when not given --
    never the median of a log that may be mostly contact); contact = |force - offset| >
    ``detect_force_N`` after a 20 ms average, gaps shorter than 2 ``margin_s`` filled, then
    widened by ``margin_s``."""
    n = len(t_s)
    ref = np.ones(n, bool) if free is None or not free.any() else free
    if setup.contact.mode == "none":
        return np.zeros(n, bool), np.zeros(6)
    if setup.log.static:  # poses at rest: each row on its own
        off = np.median(e[ref], axis=0)
        return np.linalg.norm(e[:, :3] - off[:3], axis=1) > setup.contact.detect_force_N, off
    dt = float(np.median(np.diff(t_s)))
    es = stream.smooth(e[:, :3], max(1, int(round(rc.smooth_s / dt))))  # the force; in chunks
    off = np.zeros(6)  # only the force's offset is used (the contact force)
    off[:3] = [np.median(es[ref, j]) for j in range(3)]  # a column at a time: no (n, 3) copy
    es -= off[:3]
    raw = np.einsum("ij,ij->i", es, es) > setup.contact.detect_force_N ** 2  # |force - offset| > detect_force_N
    del es
    k = int(round(setup.contact.margin_s / dt))
    if k > 0 and raw.any():
        c = _widen(raw, k)
        # fill short free gaps between contact runs
        idx = np.flatnonzero(c)
        gaps = np.flatnonzero(np.diff(idx) > 1)
        for g in gaps:
            a, b = idx[g], idx[g + 1]
            if (b - a) <= 2 * k:
                c[a:b] = True
        raw = c
    return raw, off


def library(setup: SetupCfg, effects_files=()) -> dict[str, Effect]:
    """The effect library of this diagnosis: the built-ins and the effects of the user's files
    (``[analysis] effects_files`` and ``effects_files``), one registry, by name."""
    files = [*setup.analysis.effects_files, *effects_files]
    return {n: e.for_setup(setup) for n, e in {**BUILTINS, **load_effect_files(files, BUILTINS)}.items()}


def judged(lib: dict[str, Effect], setup: SetupCfg) -> list[str]:
    """The effects judged for this set-up: those that apply, after ``[analysis] effects`` /
    ``exclude_effects`` (an unknown name there is a one-line error)."""
    for key in ("effects", "exclude_effects"):
        for n in getattr(setup.analysis, key):
            if n not in lib:
                hint = did_you_mean(n, lib)
                raise KinadaptError(f"[analysis] {key}: unknown effect '{n}'{'; ' + hint if hint else ''} (choose from "
                                    f"{', '.join(lib)}; your own effects come with --effects FILE or [analysis] "
                                    "effects_files)")
    names = [n for n, e in lib.items() if e.applies is None or e.applies(setup)]
    if setup.analysis.effects:
        names = [n for n in names if n in setup.analysis.effects]
    return [n for n in names if n not in setup.analysis.exclude_effects]


def _straddles(contact: np.ndarray, rows: np.ndarray, k: int) -> np.ndarray:
    """(r,) bool: the rows whose smoothing window (``stream.mean_at``'s ``[i - k // 2, i + k - k // 2)``)
    holds samples of both phases. Such a row is neither: as a free-space row it averages in the declared
    contact's wrench up to the sample where the socket lets go (a step of newtons against a noise of
    centinewtons: one row outweighed the whole log's rest on the package's excitation runs), as a contact
    row the moment of a tool that is not touching. ``contact`` (n,) bool, ``rows`` (r,) sample indices."""
    rows = np.asarray(rows)
    if k <= 1 or not len(rows):
        return np.zeros(len(rows), bool)
    n = len(contact)
    cs = np.r_[0, np.cumsum(np.asarray(contact, dtype=np.int64))]
    lo, hi = np.clip(rows - k // 2, 0, n), np.clip(rows + (k - k // 2), 0, n)
    touching = cs[hi] - cs[lo]
    return (touching > 0) & (touching < hi - lo)


def row_map(s: sg.LogSignals, sigma: np.ndarray, rc: RowCfg) -> RowMap:
    """The rows of a log (module docstring of ``RowMap``); one-line error when too few are left."""
    setup, t = s.setup, s.t
    if s.static:  # every pose is a row; no smoothing, no stride, no ends
        dt, stride = 1.0, 1
        ok = ~setup.analysis.left_out(t - t[0]) if s.has_time else np.ones(s.n, bool)
    else:
        dt = float(np.median(np.diff(t)))
        stride = max(1, int(round(rc.stride_s / dt)))
        ok = (t >= t[0] + rc.edge_s) & (t <= t[-1] - rc.edge_s) & ~setup.analysis.left_out(t - t[0])
    if setup.contact.mode == "exclude":
        ok &= ~s.contact
    rows = np.flatnonzero(ok)[::stride]
    every = 1
    if not s.static:  # a long log: every m-th span (``RowCfg.max_row_times``)
        keep, every = stream.every_mth_span(s.clock[rows] - s.clock[0], rc.max_row_times, rc.span_s)
        rows = rows if keep is None else rows[keep]
    k_smooth = 1 if s.static else max(1, int(round(rc.smooth_s / dt)))
    rows = rows[~_straddles(s.contact, rows, k_smooth)]
    if len(rows) < (12 if s.static else 20):
        raise KinadaptError(f"the log leaves {len(rows)} {'poses' if s.static else 'rows'} after [analysis] exclude_s"
                            f"{', contact' if s.static else ' and the ends'}; give a longer log or exclude less")
    tip = np.asarray(setup.tool.tip_sensor_m, dtype=float)
    sig_tip = np.sqrt(sigma[3:] ** 2 + float(tip @ tip) * np.mean(sigma[:3] ** 2))
    return RowMap(rows, s.contact[rows], k_smooth, 1.0 / sigma, 1.0 / sig_tip, s.tip_map, every)


def build_design(s: sg.LogSignals, lib: dict[str, Effect], names: list[str], sigma: np.ndarray, rc: RowCfg,
                 cols_cache: dict, chunk: int | None = None) -> tuple[sel.Design, RowMap]:
    """Rows of the regression with per-channel weights 1/noise, streamed: the per-block normal
    equations of the effects' columns from one chunked pass (``stream``; ``chunk`` samples per
    chunk), never the columns themselves. ``cols_cache`` gets each effect's column ``Source``."""
    rm = row_map(s, sigma, rc)
    y = stream.row_values(s, rm, stream.Source("_residual", _residual_columns, [0]), chunk)[:, 0]
    con = rm.contact
    nf, nc = int((~con).sum()), int(con.sum())
    channel = np.concatenate([np.tile(np.arange(6, dtype=np.int8), nf), np.tile(np.arange(6, 9, dtype=np.int8), nc)])
    W = np.concatenate([np.tile(rm.w_free, nf), np.tile(rm.w_tip, nc)])
    t = s.clock  # a static log: the pose index (rows are in groups of similar poses)
    tr = np.concatenate([np.repeat(t[rm.rows][~con], 6), np.repeat(t[rm.rows][con], 3)]) - t[0]
    block, nb = _row_blocks(s, rm, tr, rc)
    block = block.astype(np.int32)  # (R,): an hour's 2e6 rows
    for name in names:
        cols_cache[name] = stream.Source(name, lib[name].evaluate, list(range(lib[name].k)), lib[name].depth)
    nuis = [stream.Source("_offset", _offset_columns, list(range(6)))] if s.setup.log.tared else []
    if tip_nuisance(s):
        nuis.append(stream.Source("_tip", _tip_columns, [0, 1, 2], release.tip_depth))
    extra = release.extra_rows(s, release.find(s, float(np.linalg.norm(sigma[:3]))), tr, block)  # the socket's releases
    bs = stream.block_stats(s, rm, nuis + [cols_cache[n] for n in names], y, block, nb, chunk,
                            stream.PassOpts(keep=True, extra=extra))
    R = len(y)
    X = {nm: sel.Width((R, lib[nm].k)) for nm in names}
    return sel.Design(y, X, sel.Width((R, sum(len(n.cols) for n in nuis))), block, nb,
                      {nm: lib[nm].relevant for nm in names},
                      {nm: lib[nm].one_of for nm in names}, W, channel, CHANNELS, tr, bs), rm


def _residual_columns(s: sg.LogSignals) -> np.ndarray:
    """The declared model's residual as one column (n, 6, 1): the rows' ``y``."""
    return (s.wrench - s.w_nom)[:, :, None]


def _offset_columns(s: sg.LogSignals) -> np.ndarray:
    """A tared log's unknown constant offset: the identity on every sample (n, 6, 6)."""
    return np.broadcast_to(np.eye(6)[None], (s.n, 6, 6))


def _row_blocks(s: sg.LogSignals, rm: RowMap, tr: np.ndarray, rc: RowCfg) -> tuple[np.ndarray, int]:
    """(R,) the cross-validation block of each row and the number of blocks: groups of poses of a
    static log, else contiguous time blocks (``tr`` (R,) the rows' times from the first sample)."""
    con = rm.contact
    if s.static:  # blocks are groups of poses
        pb = s.pose_block[rm.rows]
        block = np.concatenate([np.repeat(pb[~con], 6), np.repeat(pb[con], 3)])
        _, block = np.unique(block, return_inverse=True)
        block = block.reshape(-1)
        return block, int(block.max()) + 1
    dur = float(s.clock[-1] - s.clock[0])
    blen = max(rc.block_s, dur / rc.max_blocks)
    nb = max(2, int(np.ceil(dur / blen)))
    return np.minimum((tr / blen).astype(int), nb - 1), nb


def sign_check(fitm, s: sg.LogSignals, setup: SetupCfg) -> dict:
    """Is the wrench convention right? The tool's mass from the sensor-mount fit (``mount``: the
    rotation free, so a wrong mount cannot fake it): a flipped convention negates the whole wrench,
    which no rotation can undo, so the fitted mass comes out negative. A mass below zero by more
    than 3 sd fails the check; one that is not positive within its uncertainty is not measurable."""
    m, sd = float(fitm.x[3]), float(fitm.sd[3])
    ga = s.g_s - s.a_s
    free = ~s.contact
    spread = float(np.linalg.norm(ga[free] - ga[free].mean(0), axis=1).max()) if free.any() else 0.0
    out = {"fitted_total_mass_kg": m, "sd_kg": sd, "declared_mass_kg": setup.tool.mass_kg, "ok": True,
           "method": "tool mass of the sensor-mount fit (rotation, mass, centre of mass and offset jointly)"}
    if spread < 1.0:
        out["note"] = "the tool hardly turns in the log: the mass (and sign) cannot be checked"
        return out
    if m + 3.0 * sd < 0.0:
        out["ok"] = False
        out["message"] = (f"the tool weighs {m:.3g} ± {sd:.2g} kg by the measured force (declared "
                          f"{setup.tool.mass_kg:g} kg): is [log] wrench_acts = \"{setup.log.wrench_acts}\" right? "
                          "(try the other one)")
    elif m <= 0.0:
        out["note"] = f"the tool's weight is not measurable in this log (fitted {m:.3g} ± {sd:.2g} kg)"
    return out


def sample_blocks(s: sg.LogSignals, rc: RowCfg) -> np.ndarray:
    """(n,) the cross-validation block of every sample: time blocks, or groups of poses."""
    if s.static:
        return np.asarray(s.pose_block)
    t = s.t - s.t[0]
    dur = float(t[-1])
    blen = max(rc.block_s, dur / rc.max_blocks)
    return np.minimum((t / blen).astype(int), max(2, int(np.ceil(dur / blen))) - 1)


def excluded_samples(s: sg.LogSignals, setup: SetupCfg) -> np.ndarray:
    """(n,) bool: the samples ``[analysis] exclude_s`` leaves out (windows from the first sample)."""
    if s.static and not s.has_time:
        return np.zeros(s.n, bool)
    return setup.analysis.left_out(s.t - s.t[0])


def calibrate(log, s: sg.LogSignals, setup: SetupCfg, sigma: np.ndarray | None, rc: RowCfg,
              progress: Callable[[str], None]) -> "Calibration":
    """The sensor-mount fit (``mount``) and what follows from it, before any effect is judged:
    fit on every sample (robust loss), contact detected against the calibrated model, fit again on
    free space; a static log's noise from that fit; with ``[sensor] mount_known = false`` the
    signals in the estimated mount. -> (fit, signals with contact, setup used, sigma, how sigma
    was estimated) as ``Calibration``; the contact point estimated from the contact wrench.
    ``sigma`` (6,) the per-channel noise, None: from the reading (``noise_sigma``; a static log's
    from the calibration fit)."""
    from kinadapt_nn.diagnostics import mount

    if sigma is None:
        sigma = noise_sigma(s.wrench, rc) if not s.static else np.array([1.0] * 3 + [0.1] * 3)

    progress("free space found from the data (segmentation)")
    declared = contact_model.declared_contact(setup, s.R_ws, s.p_ws)  # the declared geometry's account
    excl = excluded_samples(s, setup)
    # one account: the data's free span never takes rows where the declared geometry can touch
    seg = segmentation.free_space(s, excl if declared is None else excl | declared)
    progress("sensor mount: rotation, mass, centre of mass and offset fitted jointly on free space")
    blocks = sample_blocks(s, rc)
    fit0 = mount.fit(s, seg.free, blocks, sigma, max_blocks=0, residual=s.static)  # the point only (no sd yet)
    how = "second differences of the reading"
    if s.static:
        sigma, how = static_sigma(s, fit0.residual, rc)
    e_cal = np.empty((s.n, 3 if not s.static else 6))  # what the calibrated tool leaves (the force), in chunks
    for a, b in stream.chunks(s.n, stream.CHUNK_SAMPLES):
        e_cal[a:b] = (s.wrench[a:b] - mount.predict(fit0.x, s, np.arange(a, b)))[:, :e_cal.shape[1]]
    contact, _ = detect_contact(e_cal, s.t, setup, rc, seg.free)
    del e_cal
    accounts = ContactAccounts.of(contact, declared, s.t, setup)
    contact = accounts.used
    free = ~contact & ~excl if (~contact & ~excl).sum() > 20 else ~excl
    fitm = mount.fit(s, free, blocks, sigma, residual=False)
    # the contact wrench: beyond the calibrated tool and a declared contact geometry's own wrench
    ci = np.flatnonzero(contact & ~excl)  # the contact samples: only they are needed here
    w_c = s.wrench[ci] - (s.w_nom[ci] - ph_tool_wrench(s, ci))
    point = contact_point.estimate(w_c - mount.predict(fitm.x, s, ci), np.ones(len(ci), bool))
    j = contact_point.sensitivity_samples(len(ci))  # the calibration's share of the point's sd
    point = contact_point.with_calibration(point, w_c[j], lambda dx: mount.predict(mount.shifted(fitm.x, dx), s, ci[j]),
                                           np.ones(len(j), bool), fitm.cov)
    if not setup.sensor.mount_known:
        setup = setup.model_copy(update={"sensor": setup.sensor.model_copy(
            update={"rpy_flange_deg": tuple(float(v) for v in fitm.rpy_deg)})})
        progress("the signals turned into the estimated sensor mount")
        s = sg.in_mount(s, setup) if sg.can_turn(s, setup) else sg.from_log(log, setup)
    return Calibration(fitm, s.with_contact(contact, _free_offset(s, contact)), setup, sigma, how, seg, point, accounts)


def ph_tool_wrench(s: sg.LogSignals, idx: np.ndarray | None = None) -> np.ndarray:
    """(n, 6) the declared tool's own wrench (``s.w_nom`` without a declared contact geometry's);
    on the samples ``idx`` (m,) only when given (-> (m, 6))."""
    from kinadapt_nn.diagnostics import physical as ph

    i = slice(None) if idx is None else idx
    m, mc, I_O = ph.nominal_inertials(s.setup)
    kin = ph.KinSeries(*(np.asarray(x[i], dtype=float) for x in (s.R_ws, s.g_s, s.a_s, s.omega_s, s.alpha_s, s.p_ws)))
    return ph.tool_wrench(kin, m, mc, I_O)


@dataclasses.dataclass(frozen=True)
class Calibration:
    """What ``calibrate`` found before any effect is judged."""

    fit: object  #: ``mount.MountFit`` on free space
    signals: sg.LogSignals  #: in the effective mount, with the contact mask
    setup: SetupCfg  #: the effective set-up (the estimated mount where it was unknown)
    sigma: np.ndarray  #: (6,) per-channel noise [N, N m]
    sigma_how: str  #: how ``sigma`` was estimated
    segmentation: segmentation.Segmentation  #: the free-space span found from the data
    contact_point: contact_point.ContactPoint | None  #: where contacts act (None: too little contact)
    accounts: "ContactAccounts | None" = None  #: the data's and the declared geometry's contact


@dataclasses.dataclass(frozen=True)
class Result:
    """The diagnosis of one log: its report and what the figures draw."""

    report: Report  #: diagnosis.json's sections and summary (``Report.to_json`` adds the header)
    design: sel.Design
    before: np.ndarray | None  #: (R,) rows before --add (nuisance fitted), or None
    after: np.ndarray | None  #: (R,) rows after --add
    signals: sg.LogSignals
    contact: np.ndarray
    heldout: np.ndarray | None = None  #: (R,) held-out residual rows of the final model
    lib: dict | None = None  #: the effect library used (name -> Effect)
    hint_files: dict | None = None  #: {file name: Python source} of the hints' effect files


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


def to_log_units(est: dict, setup: SetupCfg) -> dict:
    """An estimate ``{param: {value, sd, unit}}`` with its force and moment quantities (N, N m and
    their rates) given in the log's own units ([log] force_unit, torque_unit)."""
    from kinadapt_nn.diagnostics.setup import FORCE_UNITS, TORQUE_UNITS

    fu, tu = setup.log.force_unit, setup.log.torque_unit
    if fu == "N" and tu == "N m":
        return est
    conv = {"N": (FORCE_UNITS[fu], fu), "N m": (TORQUE_UNITS[tu], tu), "N/s": (FORCE_UNITS[fu], fu + "/s"),
            "N m/s": (TORQUE_UNITS[tu], tu + "/s")}
    out = {}
    for k, v in est.items():
        if isinstance(v, dict) and v.get("unit") in conv and v.get("value") is not None:
            f, u = conv[v["unit"]]
            v = {**v, "value": v["value"] / f, "sd": None if v.get("sd") is None else v["sd"] / f, "unit": u}
        out[k] = v
    return out


def _entry_report(e: dict, eff: Effect, setup: SetupCfg) -> dict:
    out = {k: v for k, v in e.items() if k not in ("params", "sd", "columns_used", "equivalence", "model_sd", "left_sd",
                                                  "left_rows", "left_undetermined")}
    out["judged"] = True
    out["source"] = eff.source
    out["doc"] = eff.doc
    cols = e["columns_used"]
    p, sd = e["params"], e["sd"]
    full = to_log_units(eff.user_report(p, sd, setup), setup)
    out["estimate"] = {eff.params[c]: full[eff.params[c]] for c in cols if eff.params[c] in full} if eff.one_of \
        else full
    und = e["excitation"]["weak_parameters"]
    if und:
        out["excitation"] = {**e["excitation"], "weak_parameters": [eff.params[j] for j in und]}
        out["undecided_parameters"] = [eff.params[j] for j in und]
        out["to_shrink"] = eff.excite
    if "equivalence" in e:
        q = e["equivalence"]
        out["equivalence"] = {"level": q["level"], "parameters": {
            eff.params[j]: {"ci": [float(q["ci_low"][j]), float(q["ci_high"][j])], "relevant": float(q["relevant"][j]),
                            "unit": eff.units[j]} for j in range(eff.k)}}
    out["estimate_params"] = {"names": list(eff.params), "units": list(eff.units),
                              "value": [float(v) for v in p], "sd": [float(v) for v in sd]}
    if "model_sd" in e:  # the part of sd from the choices the data could not make (selection._with_model_sd)
        out["estimate_params"]["model_sd"] = [float(v) for v in e["model_sd"]]
    if "left_sd" in e:  # the change from leaving out the rows that carry what no model has (completeness.robust)
        out["estimate_params"]["left_sd"] = [float(v) for v in e["left_sd"]]
        out["estimate_params"]["left_rows"] = list(e["left_rows"])
        out["estimate_params"]["left_undetermined"] = [eff.params[j] for j in e["left_undetermined"]]
    return out


def diagnose(log, setup: SetupCfg, add: list[str] | None = None, rc: RowCfg = RowCfg(),
             sc: sel.SelCfg = sel.SelCfg(), progress: Callable[[str], None] | None = None,
             effects_files=(), hints: bool = True) -> Result:
    """The whole diagnosis of a user's log (module docstring). ``add``: effects to refit with
    (``--add``); ``effects_files``: the user's effect files (``--effects``); ``rc.chunk_samples``:
    samples per chunk of the design's passes (``stream``; the report does not depend on it beyond
    rounding). Steps: ``_library_for`` -> ``signals.from_log`` -> ``calibrate`` -> ``_checks`` ->
    ``_ranked`` -> ``_base_report`` -> completeness -> ``_added``. -> ``Result``."""
    from kinadapt_nn.diagnostics import completeness as cp

    progress = progress or (lambda msg: None)
    if log.t_s is None and setup.log.time:  # a static log read without its optional time column
        setup = setup.model_copy(update={"log": setup.log.model_copy(update={"time": ""})})
    lib, names, add, forced = _library_for(log, setup, add, effects_files)
    declared = setup
    # the log's signals held by ``calibrate`` alone: it can let them go once it has them in the estimated mount
    with steps.reporting(progress):  # the mount fit says where it is
        cal = calibrate(log, sg.from_log(log, setup, progress), setup, None, rc, progress)
    excite = {n: lib[n].excite for n in names}
    excite["_params"] = {n: lib[n].params for n in names}

    def judged(c: Calibration) -> tuple:  # the checks and the ranking with the contact rows' tip of ``c``
        chk = _checks(c, declared, log)
        rk = _RankCtx(lib, c.sigma, rc, sc, excite, chk.block, {}, progress)
        return c, chk, rk, _ranked(rk, c.signals, names)

    cal, chk, rk, ranked, lin = judged_at_tip(log, cal, declared, judged, progress)
    setup = cal.setup
    ranked = cp.robust(ranked, cal.sigma, rc.stride_s, sc)  # structure left: estimates from the rows it spares
    sections = _base_report(log, declared, cal, chk, ranked, rk)
    if lin is not None:  # the tip the contact rows use: the guess, or where its Gauss-Newton steps went
        sections["effective_setup"]["tip_linearised_at"] = lin
        if len(lin["steps"]) > 1:
            sections["effective_setup"]["tip_used"] = "the tip fitted about the declared first guess (tip_linearised_at)"
    progress("completeness of the final model" + (" and hints" if hints else ""))
    comp = cp.assess(ranked, sc, cal.sigma, rc.stride_s, with_hints=hints and chk.block is None,
                     source=str(getattr(log, "source", "the log")))
    sections.update(comp.sections())
    sections["ranking"] = cp.caveated(sections["ranking"], comp.model_complete)
    added = _added(ranked, add, forced, lib, setup, sc) if add else None
    if added is not None:
        sections.update(added.sections)
        sections["warnings"] = [*sections["warnings"], *added.warnings]
    report = Report.of(sections, summary_text)
    return Result(report, ranked.des, None if added is None else added.before, None if added is None else added.after,
                  ranked.s, ranked.s.contact, ranked.result.heldout, lib, comp.files)


def check_request(setup: SetupCfg, add: list[str] | None, effects_files=()) -> tuple[dict, list[str], list[str], dict]:
    """The effect library, the judged effects and ``--add`` checked against them, before any log
    is read (one-line errors). -> (library, judged names, --add names, {effect: forced column})."""
    lib = library(setup, effects_files)
    names = judged(lib, setup)
    add, forced = _parse_add(add or [], lib)
    for a in add:
        if a not in lib:
            hint = did_you_mean(a, lib)
            raise KinadaptError(f"--add {a}: unknown effect{'; ' + hint if hint else ''} (choose from "
                                f"{', '.join(lib)}; your own effects come with --effects FILE)")
        if a not in names:
            raise KinadaptError(f"--add {a}: this effect is left out for this set-up (see [analysis] and "
                                f"[log] tared; judged: {', '.join(names)})")
    if not names:
        raise KinadaptError("no effect left to judge ([analysis] effects / exclude_effects leave none)")
    return lib, names, add, forced


def _library_for(log, setup: SetupCfg, add: list[str] | None, effects_files) -> tuple[dict, list[str], list[str], dict]:
    """``check_request``, and the log holds the set-up's extra columns (one-line errors)."""
    lib, names, add, forced = check_request(setup, add, effects_files)
    for name in setup.log.extra:
        if name not in (getattr(log, "extra", None) or {}):
            raise KinadaptError(f"[log] extra '{name}' was not read from the log (use a CSV, Parquet or ROS 2 bag log "
                                "that has it)")
    return lib, names, add, forced


@dataclasses.dataclass(frozen=True)
class Checks:
    """The checks of the set-up before any effect is judged."""

    sign: dict  #: ``sign_check``
    sensor_mount: dict  #: the mount fit's report, its plausibility and warning
    unit_msg: str | None  #: the wrench units look wrong
    mount_msg: str | None  #: the declared mount is off by more than a first-order rotation
    block: str | None  #: the reason every verdict is ``cannot_decide`` (None: judge)
    time_msg: str | None = None  #: the time column's unit looks wrong (``units.check_time``)


def _checks(cal: Calibration, declared: SetupCfg, log=None) -> Checks:
    """Sign, the time and wrench units (``log``: the log as read, for its time) and the mount's
    plausibility (``Checks``)."""
    from kinadapt_nn.diagnostics import mount, units

    fitm, s, setup = cal.fit, cal.signals, cal.setup
    check = sign_check(fitm, s, setup)
    sensor_mount = dict(fitm.report)
    why_not = mount.plausibility(fitm, setup)
    unit_msg = units.check(fitm, s, setup, cal.sigma).message
    time_chk = None if log is None else units.check_time(log, declared)
    time_msg = None if time_chk is None else time_chk.message
    sensor_mount["plausible"] = not why_not
    heavy = mount.heavier_than_declared(fitm, setup)
    if heavy:
        sensor_mount["mass_note"] = heavy
    if why_not:
        sensor_mount["warning"] = "physically impossible calibration, not a finding: " + "; ".join(why_not)
    mount_msg = None
    if declared.sensor.mount_known and not sensor_mount["declared_consistent"] and not why_not:
        mount_msg = (f"the declared sensor mount is off by {fitm.angle_deg:.1f} ± {fitm.angle_sd_deg:.1g} deg, "
                     f"more than a first-order rotation can represent: the data say {sensor_mount['paste']} (± "
                     + ", ".join(f"{v:.2g}" for v in fitm.rpy_sd_deg) + " deg); paste it into the setup or set "
                     "[sensor] mount_known = false")
    elif not declared.sensor.mount_known and not sensor_mount.get("determined", True):
        mount_msg = ("the sensor mount cannot be estimated from this log ([sensor] mount_known = false): "
                     + sensor_mount["undetermined"][0]["why"] + "; declare [sensor] rpy_flange_deg with mount_known = "
                     "true, or record " + sensor_mount["undetermined"][0]["to_pin"])
    elif not declared.sensor.mount_known:
        sensor_mount["used"] = "the estimated rotation replaces [sensor] rpy_flange_deg for the whole diagnosis"
    block = None
    if not check["ok"]:
        block = "the sign check failed: " + check["message"]
    elif time_msg:
        block = "the time unit looks wrong: " + time_msg
    elif unit_msg:
        block = "the wrench units look wrong: " + unit_msg
    elif why_not:
        block = sensor_mount["warning"]
    elif mount_msg:
        block = mount_msg
    return Checks(check, sensor_mount, unit_msg, mount_msg, block, time_msg)


class _RankCtx(NamedTuple):
    """What the ranking needs besides the signals and the judged effects."""

    lib: dict
    sigma: np.ndarray
    rc: RowCfg
    sc: sel.SelCfg
    excite: dict
    block: str | None
    cache: dict
    progress: Callable


@dataclasses.dataclass(frozen=True)
class Ranked:
    """The ranking's outcome."""

    des: sel.Design
    rm: RowMap
    result: sel.Selection
    s: sg.LogSignals  #: the signals ranked (contact as finally detected; the set-up used)
    names: list  #: the effects judged
    fit_check: dict  #: ``tip_consistency``
    contact_rows: str  #: how the contact rows were used


def _ranked(rk: _RankCtx, s: sg.LogSignals, names: list[str]) -> Ranked:
    """``_rank``, then the tip check; where the data contradict "contacts act through the declared
    tip", judged again on free space alone rather than let an effect absorb a contact the model
    cannot describe."""
    setup, lib = s.setup, rk.lib
    des, rm, result, s = _rank(rk, s, names)
    fit_check = tip_consistency(des, list(result.present), rk.sc)
    contact_rows = "used (moment about the declared tip)" if setup.contact.mode == "tip" else setup.contact.mode
    if not fit_check["ok"] and setup.contact.mode == "tip":
        rk.progress("contact does not act through the declared tip: ranking again without the contact rows")
        setup_x = setup.model_copy(update={"contact": setup.contact.model_copy(update={"mode": "exclude"})})
        names = [n for n in names if lib[n].applies is None or lib[n].applies(setup_x)]
        s = dataclasses.replace(s, setup=setup_x)
        des, rm, result, s = _rank(rk, s, names)
        fit_check["action"] = "contact rows left out; verdicts from free space alone"
        contact_rows = "left out (tip check failed)"
    result = nonlinear.refine(result, des, rm, s, lib, rk.cache, rk.sc)  # first-order effects made exact
    return Ranked(des, rm, result, s, names, fit_check, contact_rows)


def _base_report(log, declared: SetupCfg, cal: Calibration, chk: Checks, rd: Ranked, rk: _RankCtx) -> dict:
    """The report before completeness and ``--add`` (the keys of ``diagnosis.json``)."""
    setup, s, des, result, lib = cal.setup, rd.s, rd.des, rd.result, rk.lib
    entries = [_entry_report(e, lib[e["effect"]], setup) for e in result.entries]
    dt = None if s.static else float(np.median(np.diff(s.t)))
    return {
        "setup_summary": {"tared": setup.log.tared, "wrench_acts": setup.log.wrench_acts,
                          "tool_mass_kg": setup.tool.mass_kg, "contact_mode": setup.contact.mode},
        "log": {"samples": int(s.n), "static": bool(s.static), "time_column": bool(s.has_time),
                "duration_s": float(np.ptp(s.t)) if s.has_time else None,
                "rate_Hz": None if dt is None else float(1.0 / dt),
                "qdot": ("zero (poses at rest)" if s.static else "logged" if log.qdot_rad_s is not None
                         else "differentiated from q"),
                "joints": int(s.q.shape[1]), "force_unit": setup.log.force_unit, "torque_unit": setup.log.torque_unit,
                "extra_columns": list(s.extra)},
        "library": {n: {"source": lib[n].source, "doc": lib[n].doc,
                        "params": dict(zip(lib[n].params, lib[n].units)), "judged": n in rd.names} for n in lib},
        "contact": {"fraction": float(s.contact.mean()), "windows_s": _windows(s.contact, s.t),
                    "rows": rd.contact_rows, "accounts": None if cal.accounts is None else cal.accounts.report,
                    "releases": _releases(s, cal.sigma)},
        "segmentation": cal.segmentation.to_json(),
        "effective_setup": effective_setup(declared, setup, cal.fit, cal.contact_point,
                                           (result.nuisance[-3:], result.nuisance_sd[-3:]) if tip_nuisance(s) else None),
        "noise_sigma": dict(zip(FREE_CHANNELS, (float(v) for v in cal.sigma))),
        "noise_sigma_method": cal.sigma_how,
        "sensor_mount": chk.sensor_mount,
        "sign_check": chk.sign,
        "tip_contact_check": rd.fit_check,
        "warnings": [m for m in (chk.sign.get("message"), chk.time_msg, chk.unit_msg, chk.sensor_mount.get("warning"),
                                 chk.mount_msg, chk.sensor_mount.get("mass_note"), rd.fit_check.get("message")) if m],
        "blocked": chk.block,
        "ranking": entries + [_not_judged(n) for n in CONTACT_MODEL_EFFECTS if n not in rd.names],
        "not_judged": [{"effect": n, "reason": NOT_JUDGED} for n in CONTACT_MODEL_EFFECTS if n not in rd.names],
        "residual_rms_by_channel": _rms_by_channel(des, des.y),
        "explained_by_present": float(1.0 - result.sse_after / max(result.sse_total, 1e-300)),
        "method": {"rows": {k: v for k, v in rk.rc._asdict().items() if k != "chunk_samples"},
                   "rows_cover_s": _rows_cover(s, rd.rm, rk.rc),
                   "selection": rk.sc._asdict(), "blocks": des.n_blocks,
                   "nuisance": _nuisance_text(s)},
    }


def _releases(s: sg.LogSignals, sigma: np.ndarray) -> dict | None:
    """The report's ``contact.releases``: a declared socket's releases the data show, rows of the fit
    (``release``)."""
    rel = release.find(s, float(np.linalg.norm(sigma[:3])))
    return None if rel is None else rel.to_json()


@dataclasses.dataclass(frozen=True)
class Added:
    """``--add``: the named effects refitted on all rows."""

    sections: dict  #: ``residual_rms_before``, ``residual_rms_after``, ``added`` (the report's sections)
    warnings: list  #: a physically impossible refit, one line each
    before: np.ndarray  #: (R,) rows before (nuisance fitted)
    after: np.ndarray  #: (R,) rows after


def _rows_cover(s: sg.LogSignals, rm: RowMap, rc: RowCfg) -> dict:
    """How much of the log the ranking's rows cover: every row time, or every m-th span of a long
    log (``RowCfg.max_row_times``)."""
    if s.static or not s.has_time:  # poses, not a clock: every pose is a row
        return {"span_every": 1, "covered_s": None, "of_s": None}
    dur = float(s.clock[-1] - s.clock[0])
    if rm.span_every == 1:
        return {"span_every": 1, "covered_s": dur, "of_s": dur}
    spans = np.unique(stream.span_index(s.clock[rm.rows] - s.clock[0], rc.span_s))
    return {"span_every": int(rm.span_every), "span_s": rc.span_s, "covered_s": float(len(spans) * rc.span_s),
            "of_s": dur}


def _added(rd: Ranked, add: list[str], forced: dict, lib: dict, setup: SetupCfg, sc: sel.SelCfg) -> Added:
    """``--add``: the named effects refitted on all rows (``Added``)."""
    des = rd.des
    named = {e["effect"]: e["columns_used"] for e in rd.result.entries}  # a one-of effect: the column the ranking named
    named.update(forced)  # or the one the user named (--add encoder_offset:joint5)
    before, after, fitted_add = sel.refit(des, add, sc, named)
    added, warnings = {}, []
    for n, (c, full, sd) in fitted_add.items():
        eff = lib[n]
        est = to_log_units(eff.user_report(full, sd, setup), setup)
        if eff.one_of:
            est = {eff.params[j]: est[eff.params[j]] for j in c}
        entry = {"estimate": est}
        why = eff.why_impossible(full, setup)
        if why:
            why = f"physically impossible estimate: {why}"
        elif not np.any(np.asarray(full, float)[c]) and not np.any(np.asarray(sd, float)[c]):
            why = ("no estimate: its column is zero on this log, the effect gives it no signal here (encoder_offset: "
                   "a joint turning about the sensor's z axis, which ft_frame_rotation's rot_z reports)")
        if why:
            entry["warning"] = f"{why}; not a finding"
            warnings.append(f"--add {n}: {entry['warning']}")
        added[n] = entry
    return Added({"residual_rms_before": _rms_by_channel(des, before), "residual_rms_after": _rms_by_channel(des, after),
                  "added": added}, warnings, before, after)


def _parse_add(add: list[str], lib: dict[str, Effect]) -> tuple[list[str], dict[str, list[int]]]:
    """``--add`` names; ``EFFECT:PARAM`` picks the parameter of a one-of effect (``encoder_offset:joint5``
    or ``encoder_offset:offset_joint5``). -> (effect names, {effect: [column]})."""
    names, forced = [], {}
    for a in add:
        name, _, which = a.partition(":")
        if which and name in lib:
            eff = lib[name]
            hits = [j for j, pn in enumerate(eff.params) if pn == which or pn.endswith("_" + which)]
            if not eff.one_of or len(hits) != 1:
                hint = did_you_mean(which, eff.params) if not hits else ""
                raise KinadaptError(f"--add {a}: '{which}' is not one parameter of the one-of effect '{name}'"
                                    f"{'; ' + hint if hint else ''} (its parameters: {', '.join(eff.params)})")
            forced[name] = hits
        names.append(name)
    return list(dict.fromkeys(names)), forced


def _rank(rk: _RankCtx, s: sg.LogSignals, names: list[str]):
    """Design + selection; once more with contact re-detected when the present effects change it.
    -> (Design, RowMap, Selection, LogSignals)."""
    result = des = rm = None
    setup, lib = s.setup, rk.lib
    for it in range(2):
        rk.progress("effect columns" if it == 0 else "contact re-detected with the present effects; ranking again")
        des, rm = build_design(s, lib, names, rk.sigma, rk.rc, rk.cache, rk.rc.chunk_samples)
        rk.progress(f"ranking {len(names)} effects on {len(des.y)} rows, {des.n_blocks} blocks")
        result = sel.select(des, rk.sc, lambda n, p: lib[n].why_impossible(p, setup), rk.excite, rk.block)
        if it == 1 or not result.present or setup.contact.mode == "none":
            break
        srcs = [rk.cache[n]._replace(cols=list(c)) for n, (c, _, _) in result.present.items()]
        fitted = stream.sample_sum(s, srcs, [p for _, p, _ in result.present.values()], rm.k_smooth,
                                   des.stats.chunk, channels=3)  # the force of the columns this design was built from
        fitted -= s.wrench[:, :3]
        fitted += s.w_nom[:, :3]
        new_contact, new_off = detect_contact(-fitted, s.t, setup, rk.rc, ~s.contact)
        del fitted
        declared = contact_model.declared_contact(setup, s.R_ws, s.p_ws)
        if declared is not None:  # the declared geometry's account stands (``ContactAccounts``)
            new_contact |= declared
        if np.mean(new_contact != s.contact) < 0.005:
            break
        s = s.with_contact(new_contact, new_off)
        des = rm = result = None  # this design (its kept rows) let go before the next is built
    return des, rm, result, s
