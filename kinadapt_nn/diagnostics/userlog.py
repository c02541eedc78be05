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
import math
from typing import Callable, NamedTuple

import numpy as np

from kinadapt_nn.diagnostics import contact_model, contact_point, nonlinear, segmentation, steps, stream
from kinadapt_nn.diagnostics import selection as sel
from kinadapt_nn.diagnostics import signals as sg
from kinadapt_nn.diagnostics.builtin import BUILTINS, CONTACT_MODEL_EFFECTS
from kinadapt_nn.diagnostics.contract import Effect, load_effect_files
from kinadapt_nn.diagnostics.report import Report
from kinadapt_nn.diagnostics.setup import SetupCfg
from kinadapt_nn.errors import KinadaptError, did_you_mean
from kinadapt_nn.diagnostics.stream import RowMap

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


def _widen(mask: np.ndarray, k: int) -> np.ndarray:
    """(n,) bool ``mask`` widened by ``k`` samples on each side (unchanged for k <= 0)."""
    if k <= 0 or not mask.any():
        return mask
    return np.convolve(mask.astype(float), np.ones(2 * k + 1), "same") > 0


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


def row_map(s: sg.LogSignals, sigma: np.ndarray, rc: RowCfg) -> RowMap:
    """The rows of a log (module docstring of ``RowMap``); one-line error when too few are left."""
    setup, t = s.setup, s.t
    if s.static:  # every pose is a row; no smoothing, no stride, no ends
        dt, stride = 1.0, 1
        ok = np.ones(s.n, bool)
        if s.has_time:
            for a, b in setup.analysis.exclude_s:
                ok &= ~((t >= a) & (t <= b))
    else:
        dt = float(np.median(np.diff(t)))
        stride = max(1, int(round(rc.stride_s / dt)))
        ok = (t >= t[0] + rc.edge_s) & (t <= t[-1] - rc.edge_s)
        for a, b in setup.analysis.exclude_s:
            ok &= ~((t - t[0] >= a) & (t - t[0] <= b))
    if setup.contact.mode == "exclude":
        ok &= ~s.contact
    rows = np.flatnonzero(ok)[::stride]
    every = 1
    if not s.static:  # a long log: every m-th span (``RowCfg.max_row_times``)
        keep, every = stream.every_mth_span(s.clock[rows] - s.clock[0], rc.max_row_times, rc.span_s)
        rows = rows if keep is None else rows[keep]
    if len(rows) < (12 if s.static else 20):
        raise KinadaptError(f"the log leaves {len(rows)} {'poses' if s.static else 'rows'} after [analysis] exclude_s"
                            f"{', contact' if s.static else ' and the ends'}; give a longer log or exclude less")
    tip = np.asarray(setup.tool.tip_sensor_m, dtype=float)
    sig_tip = np.sqrt(sigma[3:] ** 2 + float(tip @ tip) * np.mean(sigma[:3] ** 2))
    k_smooth = 1 if s.static else max(1, int(round(rc.smooth_s / dt)))
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
        cols_cache[name] = stream.Source(name, lib[name].evaluate, list(range(lib[name].k)))
    nuis = [stream.Source("_offset", _offset_columns, list(range(6)))] if s.setup.log.tared else []
    if tip_nuisance(s):
        nuis.append(stream.Source("_tip", _tip_columns, [0, 1, 2]))
    bs = stream.block_stats(s, rm, nuis + [cols_cache[n] for n in names], y, block, nb, chunk, stream.PassOpts(keep=True))
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
        C[:, :, j] += contact_model.tip_derivative(s.setup, s.R_ws, s.p_ws, e)
    return C


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
    out = np.zeros(s.n, bool)
    if s.static and not s.has_time:
        return out
    t = s.t - s.t[0]
    for a, b in setup.analysis.exclude_s:
        out |= (t >= a) & (t <= b)
    return out


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
class ContactAccounts:
    """One account of free space and contact: the data's (the force beyond the calibrated tool,
    ``detect_contact``) and the declared geometry's (``contact_model.declared_contact``); the rows
    used as contact are those either calls contact, so that no row is fitted as free space while
    one account says it touches."""

    used: np.ndarray  #: (n,) bool contact as used
    report: dict  #: the report's ``contact.accounts``
    data: np.ndarray  #: (n,) bool the data's account
    disputed: np.ndarray | None = None  #: (n,) bool where the two disagree (beyond the data's margin)

    @staticmethod
    def of(data: np.ndarray, declared: np.ndarray | None, t: np.ndarray, setup: SetupCfg) -> "ContactAccounts":
        if declared is None:
            return ContactAccounts(data, {"data_windows_s": _windows(data, t), "declared": None,
                                          "used": "the data's (no contact geometry declared)"}, data)
        used = data | declared
        wide = declared  # the data's windows are widened by margin_s (``detect_contact``): compared beyond it
        if len(t) > 1 and not setup.log.static:
            wide = _widen(declared, int(round(setup.contact.margin_s / float(np.median(np.diff(t))))))
        only_geom, only_data = declared & ~data, data & ~wide
        why = []
        if only_geom.mean() >= 0.005:
            why.append(f"{only_geom.mean():.0%} of the log is contact by the declared geometry but under the data's "
                       f"detection threshold ({setup.contact.detect_force_N:g} N): taken as contact (light contacts "
                       "there are not free space)")
        if only_data.mean() >= 0.005:
            why.append(f"{only_data.mean():.0%} shows a force beyond the tool model where the declared geometry cannot "
                       "touch: taken as contact (something touched outside the declared geometry)")
        disputed = only_geom | only_data
        if why and setup.contact.mode == "tip" and setup.contact.declared_geometry:
            why.append("where the declared geometry's wrench predicts more than the threshold and the data show "
                       "nothing, or the data show a force where it cannot touch, the rows are left out of the fit "
                       "([analysis] exclude_s in the set-up used)")
        return ContactAccounts(used, {
            "data_windows_s": _windows(data, t), "declared_windows_s": _windows(declared, t),
            "disputed_windows_s": _windows(disputed, t),
            "used": "contact where either account says so" + ("; " + "; ".join(why) if why else
                                                              " (the two agree)")}, data, disputed)


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


def _effective_tip(log, cal: "Calibration", declared: SetupCfg) -> "Calibration":
    """The tip the contact rows use: the declared one; where none is declared ([tool] tip_sensor_m
    left at 0) or it is a first guess ([tool] tip_known = false) and the contact wrench pins a point
    (every direction determined), that point (``effective_setup.tip_used``), and the tip check tests
    it. A declared contact geometry's wrench is computed again at the point (its lever and anchor
    move with the tip). A known declared tip is kept (and tested): the point is estimated before any
    effect, so it would absorb an effect that acts in contact (crosstalk)."""
    s, setup, point = cal.signals, cal.setup, cal.contact_point
    if point is None or point.undetermined_along_s is not None or setup.contact.mode != "tip":
        return cal
    if any(declared.tool.tip_sensor_m) and declared.tool.tip_known:
        return cal
    far = float(np.linalg.norm(np.asarray(point.point_s_m) - np.asarray(declared.tool.tip_sensor_m)))
    if not declared.tool.tip_known and far > declared.tool.tip_within_m:  # not the tip: the guess stands
        return cal
    from kinadapt_nn.diagnostics.physical import tip_moment_map

    tip = tuple(float(v) for v in point.point_s_m)
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


def _without_disputed(cal: "Calibration") -> "Calibration":
    """Rows whose phase the two accounts dispute (``ContactAccounts``) left out of the ranking where
    contact rows are fitted (``[contact] mode = "tip"``), as ``[analysis] exclude_s`` windows: a
    declared socket that the data show released (its tip read from encoders a joint offset moved)
    predicts a spring force the sensor never saw, which no first-order column describes."""
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
    cal = _without_disputed(_effective_tip(log, cal, declared))
    s, setup = cal.signals, cal.setup
    chk = _checks(cal, declared, log)
    excite = {n: lib[n].excite for n in names}
    excite["_params"] = {n: lib[n].params for n in names}
    rk = _RankCtx(lib, cal.sigma, rc, sc, excite, chk.block, {}, progress)
    ranked = _ranked(rk, s, names)
    ranked = cp.robust(ranked, cal.sigma, rc.stride_s, sc)  # structure left: estimates from the rows it spares
    sections = _base_report(log, declared, cal, chk, ranked, rk)
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
    time_msg: str | None = None  #: the time column's unit looks wrong (``timeunit``)


def _checks(cal: Calibration, declared: SetupCfg, log=None) -> Checks:
    """Sign, the time and wrench units (``log``: the log as read, for its time) and the mount's
    plausibility (``Checks``)."""
    from kinadapt_nn.diagnostics import mount, timeunit, units

    fitm, s, setup = cal.fit, cal.signals, cal.setup
    check = sign_check(fitm, s, setup)
    sensor_mount = dict(fitm.report)
    why_not = mount.plausibility(fitm, setup)
    unit_msg = units.check(fitm, s, setup, cal.sigma).message
    time_chk = None if log is None else timeunit.check(log, declared)
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
                    "rows": rd.contact_rows, "accounts": None if cal.accounts is None else cal.accounts.report},
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
            entry["warning"] = f"physically impossible estimate: {why}; not a finding"
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


def completeness_text(rep: dict) -> str:
    """The verdict on the model itself, in words (the summary's first sentence)."""
    un = rep.get("unexplained", {})
    if rep.get("model_complete", True):
        return "The model explains the log: no systematic residual of a relevant size is left."
    ch = un.get("channels", {})
    parts = [f"{c} ({ch[c]['structured_rms']:.3g} {ch[c]['unit']}, {ch[c]['ratio_to_noise']:.1f}x the noise floor)"
             for c in un.get("carried_by", [])]
    txt = ("Something the model does not contain is left: a structured residual in " + ", ".join(parts)
           + f" ({', '.join(un.get('phases', []))}).")
    hs = un.get("hints", [])
    if hs:
        txt += " It looks like " + "; ".join(f"{h['shape']} ({h['words'].split(':')[0]}; explains "
                                             f"{100 * h['explains']:.0f}% of it held-out, see {h['effect_file']})" for h in hs[:3]) + "."
    else:
        txt += " No shape of the hint dictionary explains it."
    return txt


def _why_undetermined(u: dict) -> str:
    """An undetermined calibration parameter's reason: its sd, or why it was not fitted at all."""
    return u["why"] if u.get("sd") is None else f"sd {u['sd']:.2g} {u['unit']}"


#: the summary names at most this many parameters of an effect (the rest: "… (+k more)")
SUMMARY_PARAMETERS = 4


def _is_payload(est: dict) -> bool:
    return "total_mass" in est and all(f"total_com_{a}" in est for a in "xyz")


def _payload_text(est: dict, rep: dict) -> str:
    """``tool_gravity`` as a user thinks of the tool: everything beyond the sensor (its mass and
    centre of mass, mm), the declared mass beside it and the difference, and where the added mass sits."""
    tm, com = est["total_mass"], [est[f"total_com_{a}"] for a in "xyz"]
    out = f"the whole tool {tm['value']:.4g} ± {tm['sd']:.2g} kg"
    if all(c["value"] is not None for c in com):
        out += (", centre of mass [" + ", ".join(f"{1000 * c['value']:.1f}" for c in com) + "] ± ["
                + ", ".join(f"{1000 * c['sd']:.2g}" for c in com) + "] mm")
    m0 = (rep.get("setup_summary") or {}).get("tool_mass_kg")
    dm = est["mass"]
    out += (f"; declared {m0:.4g} kg: " if m0 is not None else "; ") + f"{dm['value']:+.3g} ± {dm['sd']:.2g} kg"
    added = [est.get(f"com_{a}") or {} for a in "xyz"]
    if m0 and abs(dm["value"]) < 0.2 * m0:  # a correction of the declared tool, not a body added somewhere
        out += " (a correction of the declared tool)"
    elif all(a.get("value") is not None for a in added):
        out += " added at [" + ", ".join(f"{1000 * a['value']:.1f}" for a in added) + "] mm"
    return out


def _estimate_text(est: dict) -> str:
    """An effect's parameters for the summary: the ``SUMMARY_PARAMETERS`` largest by |value / sd|
    (the best-determined, so the largest is never hidden) in the estimate's own order, then how many
    are left out (``… (+2 more)``; diagnosis.json has them all)."""
    keys = [k for k in est if not k.startswith("total_") and est[k]["value"] is not None
            and not (k.startswith("first_moment_") and (est.get("com_" + k[-1]) or {}).get("value") is not None)]
    # (a first moment m c is the same parameter as its centre of mass: shown where the com is not defined)

    def z(k: str) -> float:
        v, sd = abs(float(est[k]["value"])), float(est[k]["sd"] or 0.0)
        return v / sd if sd > 0 else (math.inf if v > 0 else 0.0)

    shown = set(sorted(keys, key=z, reverse=True)[:SUMMARY_PARAMETERS])
    text = ", ".join(f"{k} {est[k]['value']:.3g} ± {est[k]['sd']:.2g} {est[k]['unit']}" for k in keys if k in shown)
    hidden = len(keys) - len(shown)
    return text + (f", … (+{hidden} more)" if hidden else "")


def summary_text(rep: dict) -> str:
    """A paragraph a person reads first: the verdict on the model, then the effects."""
    chk = rep["sign_check"]
    if not chk["ok"]:
        return ("WARNING: " + chk["message"] + ". Every effect is 'cannot_decide' until the wrench convention "
                "is right (nothing can be judged against a tool that weighs less than nothing).")
    if rep.get("blocked"):
        return ("WARNING: " + rep["blocked"] + ". Every effect is 'cannot_decide' until the set-up is right "
                "(no effect can be judged against a model the data contradict at first sight).")
    parts = [completeness_text(rep)]  # the verdict on the model leads, whatever else is estimated
    sm = rep.get("sensor_mount")
    if sm and not sm.get("mount_known", True):
        parts.append(_mount_text(rep, sm))
    if not rep["tip_contact_check"]["ok"]:
        parts.append("WARNING: " + rep["tip_contact_check"]["message"] + ".")
    if sm and sm.get("undetermined"):
        parts.append("Undetermined by this log's motion (the rest stands): " + "; ".join(
            f"{u['parameter']} ({_why_undetermined(u)}; to pin it: {u['to_pin']})" for u in sm["undetermined"]) + ".")
    seg = rep.get("segmentation")
    if seg and seg.get("contact_onsets_s"):
        parts.append(f"Free space found from the data: {seg['free_span_s'][0]:.2f}–{seg['free_span_s'][1]:.2f} s "
                     f"({seg['free_samples']} samples, the calibration's); contact from "
                     + ", ".join(f"{v:.2f} s" for v in seg["contact_onsets_s"]) + ".")
    cpt = (rep.get("effective_setup") or {}).get("contact_point")
    if cpt:
        parts.append(_contact_point_text(cpt))
    parts.extend(_accounts_text(rep))
    parts.extend(_verdicts_text(rep))
    parts.append(_spans_text(rep.get("method", {}).get("rows_cover_s") or {}))
    if "residual_rms_after" in rep:
        b, a = rep["residual_rms_before"]["total_w"], rep["residual_rms_after"]["total_w"]
        parts.append(f"With {', '.join(rep['added'])} added, the residual falls from {b:.3g} to {a:.3g} "
                     "(noise-weighted RMS, all rows)" + _effect_free_text(rep) + ".")
    return " ".join(p for p in parts if p)


def _mount_text(rep: dict, sm: dict) -> str:
    """The summary's sentence on an estimated sensor mount (and the tool, unless tool_gravity's
    entry gives it)."""
    com = sm["tool_com_sensor_m"]
    payload_said = any(e["effect"] == "tool_gravity" and e["verdict"] == "present" for e in rep["ranking"])
    return ("Sensor mount estimated: " + sm["paste"] + " (± " + ", ".join(f"{v:.2g}" for v in sm["sd_deg"])
            + f" deg; {sm['rotation_from_declared_deg']:.1f} deg from the guess)"
            + ("" if payload_said else  # the tool is said once: tool_gravity's entry gives it
               f"; tool {sm['tool_mass_kg']:.4g} ± {sm['tool_mass_sd_kg']:.2g} kg"
               + (", centre of mass [" + ", ".join(f"{1000 * v:.1f}" for v in com) + "] mm in the sensor frame"
                  if com[0] is not None else "")) + ".")


def _contact_point_text(cpt: dict) -> str:
    """The summary's sentence on the estimated contact point (``effective_setup.contact_point``)."""
    p, sd = cpt["point_sensor_m"], cpt["sd_m"]
    return ("Contacts act at [" + ", ".join(f"{1000 * v:.1f}" for v in p) + "] ± ["
            + ", ".join(f"{1000 * v:.1g}" for v in sd) + "] mm in the sensor frame"
            + (" (along the force's line of action, direction [" + ", ".join(
                f"{v:.2f}" for v in cpt["undetermined_along_sensor"]) + "], undetermined: the force "
               "barely changed direction)" if cpt["undetermined_along_sensor"] else "")
            + ("" if cpt["declared_tip_consistent"] else
               f", {1000 * cpt['declared_tip_distance_m']:.0f} mm from the declared tip") + ".")


def _verdicts_text(rep: dict) -> list[str]:
    """The summary's sentences on the effects, verdict by verdict: present (with their estimates),
    cannot decide, absent, not judged."""
    parts = _present_text(rep)
    und = [e for e in rep["ranking"] if e["verdict"] == "cannot_decide" and e.get("judged", True)]
    if und:
        parts.append("Cannot decide: " + "; ".join(
            f"{e['effect']} ({e.get('reason') or ''}"
            + (f"; {sel.tie_words(e['effect'], list(e.get('estimate', {})), e['indistinguishable_from'])}"
               if e.get("indistinguishable_from") else "")
            + (f"; undecided: {', '.join(e['undecided_parameters'])}" if e.get("undecided_parameters")
               and not e.get("indistinguishable_from") else "")
            + ")" for e in und) + ".")
    absent = [e["effect"] for e in rep["ranking"] if e["verdict"] == "absent"]
    if absent:
        parts.append("Absent (intervals inside their relevant sizes): " + ", ".join(absent) + ".")
    nj = [e["effect"] for e in rep["ranking"] if not e.get("judged", True)]
    if nj:
        parts.append("Not judged (no contact geometry declared): " + ", ".join(nj) + ".")
    return parts


def _present_text(rep: dict) -> list[str]:
    """The summary's sentences on the present effects: their estimates, what they explain, and the
    caution when the model stays incomplete."""
    pres = [e for e in rep["ranking"] if e["verdict"] == "present"]
    if not pres:
        return ["No library effect is present."]
    txt = []
    for e in pres:
        est = e["estimate"]
        txt.append(f"{e['effect']} ({_payload_text(est, rep) if _is_payload(est) else _estimate_text(est)})")
    parts = ["Present: " + "; ".join(txt) + f" — together {100 * rep['explained_by_present']:.0f}% of the "
             "residual of the declared model, held-out."]
    if not rep.get("model_complete", True):
        parts.append("Caution: the model stays incomplete, so these may stand in for part of what is unexplained.")
        left = next((e["estimate_params"]["left_rows"] for e in pres if "left_rows" in e.get("estimate_params", {})),
                    None)
        if left:  # completeness.robust
            parts.append(f"Their estimates leave out the rows of {', '.join(left)}, which carry it; each ± "
                         "includes the change this makes where the other rows pin the parameter "
                         "(diagnosis.json: left_sd, left_undetermined).")
    return parts


def _effect_free_text(rep: dict) -> str:
    lv = rep.get("effect_free_level")
    if not lv:
        return ""
    return (f"; the effect-free run {lv['baseline']} leaves {lv['residual_rms_total_w']:.3g}: "
            f"{lv['after_over_effect_free']:.2f}x the effect-free level")


def _nuisance_text(s: sg.LogSignals) -> str:
    parts = (["constant offset (tared log)"] if s.setup.log.tared else []) + (
        ["the tip's position (tip_known = false)"] if tip_nuisance(s) else [])
    return "; ".join(parts) or "none"


def _accounts_text(rep: dict) -> list[str]:
    """The tool's tip where the data put it, and the contact account where the two accounts disagree."""
    out = []
    tt = (rep.get("effective_setup") or {}).get("tool_tip")
    if tt:
        out.append("The tool's tip, fitted with the effects ([tool] tip_known = false): ["
                   + ", ".join(f"{1000 * v:.2f}" for v in tt["tip_sensor_m"]) + "] ± ["
                   + ", ".join(f"{1000 * e:.2g}" for e in tt["sd_m"]) + "] mm, "
                   + ", ".join(f"{a} {1000 * v:+.2f}" for a, v in zip("xyz", tt["difference_m"]))
                   + " mm from the declared first guess; contact effects are judged at it.")
    acc = (rep.get("contact") or {}).get("accounts")
    if acc and acc.get("disputed_windows_s") and ";" in acc.get("used", ""):
        out.append("Free space and contact: " + acc["used"] + ".")
    return out


def _spans_text(cov: dict) -> str:
    """A long log ranked on spans (``method.rows_cover_s``) in words; "" when every row time was used."""
    m = int(cov.get("span_every", 1))
    if m == 1:
        return ""
    nth = f"{m}{ {1: 'st', 2: 'nd', 3: 'rd'}.get(m % 10 if m % 100 not in (11, 12, 13) else 0, 'th')}"
    return (f"A long log: ranked on every {nth} {cov['span_s']:g} s span ({cov['covered_s']:.0f} s of "
            f"{cov['of_s']:.0f} s, spread over the whole log).")
