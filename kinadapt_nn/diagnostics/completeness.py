"""Is the final model complete? What it leaves unexplained, and the shape of what is missing.

Verdict. The held-out residual of the final model (nuisance + selected effects; each CV block
predicted by the fit on the other blocks, ``selection.heldout_residual``) is compared, channel by
channel, with the sensor's own noise floor: a row averages ``k`` samples of per-sample noise
``sigma`` (``userlog.noise_sigma``), so white noise alone gives a row RMS of ``sigma/sqrt(k)``.
Its *structured* part is what survives a longer moving average (``struct_window_s``) beyond what
white noise leaves there: ``sqrt(max(rms_long^2 - sigma^2/n_long, 0))``. A channel carries an
unexplained effect when that structured part is clearly above the white-noise level
(``struct_factor``) AND at least the relevant size (``[analysis] relevant_force_N`` /
``relevant_moment_Nm``). ``model_complete`` is true when no channel does.

Hints. When the model is incomplete, the held-out residual is tested against a generic dictionary
of shapes (``SHAPES``), each with its physical readings, with the selection's own statistics:
block cross-validation given the final model, a Hotelling-type test with the block-jackknife
covariance, Benjamini-Hochberg over the shapes, ``min_explained`` of what the final model leaves
held-out, and a relevant size (a parameter is scaled so that 1 changes some channel's RMS, over
that channel's rows, by its relevant size). A shape is listed only where it passes, ranked by its held-out gain; each comes
with a ready effect file (``hint_files``) in the public contract. A shape with more parameters than
``max_dense``, or than the blocks minus two (a block jackknife's covariance has rank B - 1 at most: a
short log's few blocks hold no Hotelling test of a 12-parameter shape), has its entries selected
sparsely (``_sparse_test``). A complete model that is complete only through effects the verdict
leaves undecided (``held_undecided``: selected, none a finding; without them, ``without_held``, some
channel carries a relevant structured residual -- a snag's pull taken by ``ft_offset``, which the
undecided effects beside it then swallow) is tested too, those effects beside the present ones as
nuisance: a shape is listed only for what it explains beyond them (docs/monitor.md, "Agreement"). Where
what they explain is below the relevant size (an effect-free log's undecided ``tool_tilt``), no hint
is sought: they stand in for nothing relevant.

Estimates when structure is left (``robust``). A residual the model cannot describe biases the
estimates of the effects whose columns reach the rows that carry it (a face contact's moment about
the tip pulls a tool's centre of mass, a crosstalk), and their block-jackknife sd knows nothing of
it. When the verdict names channels that carry something unexplained, every present and
undecided effect is re-estimated with the final model on the rows of the channels that do not
(``explained_rows``: the carrying channels' rows left out, per phase); the reported estimate
moves by the change ``delta`` this makes and its sd becomes ``sqrt(max(sd, sd_rows)^2 + delta^2)``
(``left_sd`` = ``|delta|``): an interval that holds whichever rows the truth agrees with.
docs/missing_physics.md gives the alternatives measured (the leading hints as nuisance columns).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, NamedTuple

import numpy as np

from kinadapt_nn.diagnostics import selection as sel
from kinadapt_nn.effects.online import moving_average

FORCE_UNIT, MOMENT_UNIT = "N", "N m"
WRENCH = ("fx", "fy", "fz", "tx", "ty", "tz")
WRENCH_LABEL = ("F_x", "F_y", "F_z", "M_x", "M_y", "M_z")
#: [rad/s] smoothing of sign(qdot) in the joint_velocity shape
SIGN_EPS_RAD_S = 0.02
#: [rad/s] smoothing of sign(omega) in the contact_moment shape (torsional friction)
TORSION_EPS_RAD_S = 0.02
#: the words of each shape (its physical readings)
WORDS = {
    "sensor_constant": "a constant wrench in the sensor frame: an offset, a bias step",
    "world_force": "a constant force in the world frame at a fixed point on the tool: a cable or hose, a spring or "
                   "counterweight, a fixture pulling",
    "time": "a slow change in time per channel: drift, warm-up",
    "wrench_linear": "a linear map of the measured wrench: a calibration-matrix error, crosstalk, a gain error",
    "joint_velocity": "per-joint velocity (and its sign) into the wrench: cable drag, a dragging hose, friction in a "
                      "tool joint",
    "joint_position": "per-joint position into the wrench: a cable whose pull depends on the pose",
    "extra": "a declared extra log column into the wrench: temperature, supply voltage, a second sensor",
    "contact_moment": "a moment about the contact point while in contact: a face or line contact, a contact patch, "
                      "torsional friction, a contact away from the declared tip",
}
#: the shape vocabulary (``unexplained.hints[i].shape``; ``extra`` stands for ``extra:<column>``)
SHAPES = tuple(WORDS)


class CompCfg(NamedTuple):
    struct_window_s: float = 0.25  #: [s] the long moving average that keeps the structured part
    static_window_poses: int = 8  #: static logs: the long average over this many neighbouring poses
    struct_factor: float = 3.0  #: structured part / its white-noise level above which it is "structured"
    time_order: int = 3  #: Legendre order of the ``time`` shape
    max_dense: int = 12  #: a shape with more parameters has its entries selected sparsely
    max_entries: int = 8  #: at most this many entries of a sparse shape
    min_entry_gain: float = 0.01  #: [-] an entry must explain this share of what the final model leaves
    #: the hint test's rows: at most this many row times (10 ms apart: 5 min); a longer log is tested on
    #: every m-th span of ``hint_span_s`` (``hint_rows``), so that an hour costs what 5 minutes do
    hint_max_row_times: int = 30_000
    hint_span_s: float = 5.0  #: [s]


class Shape(NamedTuple):
    """A generic shape: sample columns (n, 6, k) over ``LogSignals`` and its parameters."""

    name: str
    columns: Callable  #: LogSignals -> (n, 6, k)
    params: Callable  #: LogSignals -> (names (k,), units (k,))
    words: str


# ------------------------------------------------------------------------------------------ shapes
def _unit(i: int) -> str:
    return FORCE_UNIT if i < 3 else MOMENT_UNIT


def _sensor_constant(s) -> np.ndarray:
    return np.broadcast_to(np.eye(6)[None], (s.n, 6, 6)).copy()


def world_force_columns(R_ws: np.ndarray) -> np.ndarray:
    """A constant world-frame force at a fixed point of the tool, linear in ``F_w`` (3) and
    ``M = p F^T`` (9, p the point of action in s): (n, 6, 12) columns along the sensor's axes
    ``R_ws`` (n, 3, 3) -- force rows ``R^T F``, moment rows ``p x R^T F`` = sum_il M_il (e_i x R^T e_l).
    The hint ``world_force`` and the live monitor's shape of the same name."""
    R_ws = np.asarray(R_ws)
    C = np.zeros((len(R_ws), 6, 12))
    for l_ in range(3):
        u = R_ws[:, l_, :]  # (n, 3): R_ws^T e_l, the world axis l in s
        C[:, :3, l_] = u
        for i in range(3):
            e = np.zeros(3)
            e[i] = 1.0
            C[:, 3:, 3 + 3 * i + l_] = np.cross(e, u)
    return C


def _world_force(s) -> np.ndarray:
    return world_force_columns(s.R_ws)


def _whole(s, key: str, local: Callable):
    """A whole-log number: from ``s.whole`` on a chunk of the log, else computed on ``s``."""
    w = getattr(s, "whole", None)
    return w[key] if w is not None else local()


def _legendre(s, order: int) -> np.ndarray:
    t0, t1 = _whole(s, "t_span", lambda: (float(np.min(s.t)), float(np.max(s.t))))
    u = 2.0 * (s.t - t0) / max(t1 - t0, 1e-9) - 1.0
    return np.stack([np.polynomial.legendre.Legendre.basis(d)(u) for d in range(1, order + 1)], axis=1)


def _per_channel(x: np.ndarray) -> np.ndarray:
    """(n, m) signals -> (n, 6, 6 m): each signal into each channel (channel-major)."""
    n, m = x.shape
    C = np.zeros((n, 6, 6 * m))
    for i in range(6):
        C[:, i, i * m:(i + 1) * m] = x
    return C


def _wrench_linear(s) -> np.ndarray:
    return _per_channel(s.wrench)


def _joint_velocity(s) -> np.ndarray:
    return _per_channel(np.hstack([s.qdot, np.tanh(s.qdot / SIGN_EPS_RAD_S)]))


def _joint_position(s) -> np.ndarray:
    return _per_channel(s.q - _whole(s, "q_mean", lambda: s.q.mean(axis=0)))


def contact_moment_sources(s) -> np.ndarray:
    """(n, 7) what a contact's own moment follows, zero in free space: 1 (a constant moment), the
    contact force f_c (3, [N]: a lever, a shifted point), |f_c| tanh(omega / eps) (3, [N]:
    torsional friction about each sensor axis)."""
    c = np.asarray(s.contact, dtype=float)[:, None]
    f = s.contact_force_s
    tors = np.linalg.norm(f, axis=1, keepdims=True) * np.tanh(s.omega_s / TORSION_EPS_RAD_S)
    return c * np.hstack([np.ones((s.n, 1)), f, tors])


def _contact_moment(s) -> np.ndarray:
    src = contact_moment_sources(s)
    C = np.zeros((s.n, 6, 21))
    for i in range(3):
        C[:, 3 + i, 7 * i:7 * (i + 1)] = src
    return C


def _params_contact_moment(s):
    names, units = [], []
    for i in "xyz":
        names += [f"t{i}_in_contact"] + [f"t{i}_from_fc{j}" for j in "xyz"] + [f"t{i}_torsion_{j}" for j in "xyz"]
        units += ["N m"] + ["m"] * 6
    return names, units


def _names_per_channel(labels: list[str], units: list[str]) -> tuple[list[str], list[str]]:
    names, out_units = [], []
    for i in range(6):
        for lab, u in zip(labels, units):
            names.append(f"{WRENCH[i]}_from_{lab}")
            out_units.append(f"{_unit(i)}/{u}" if u != "-" else _unit(i))
    return names, out_units


def _params_world_force(s):
    names = ["fx_w", "fy_w", "fz_w"] + [f"p{'xyz'[i]}*f{'xyz'[l_]}_w" for i in range(3) for l_ in range(3)]
    return names, [FORCE_UNIT] * 3 + ["N m"] * 9


def _params_wrench_linear(s):
    names, out = [], []
    for i in range(6):
        for j in range(6):
            names.append(f"{WRENCH[i]}_from_{WRENCH[j]}")
            out.append("-" if (i < 3) == (j < 3) else ("m" if i >= 3 else "1/m"))
    return names, out


def _params_joint_velocity(s):
    dof = s.q.shape[1]
    return _names_per_channel([f"qdot{j + 1}" for j in range(dof)] + [f"sign_qdot{j + 1}" for j in range(dof)],
                              ["rad/s"] * dof + ["-"] * dof)


def _params_joint_position(s):
    dof = s.q.shape[1]
    return _names_per_channel([f"q{j + 1}" for j in range(dof)], ["rad"] * dof)


def shapes(s, cc: CompCfg = CompCfg()) -> list[Shape]:
    """The dictionary for this log (the ``extra:<column>`` shapes from its declared columns)."""
    out = [
        Shape("sensor_constant", _sensor_constant, lambda s_: (list(WRENCH), [_unit(i) for i in range(6)]),
              WORDS["sensor_constant"]),
        Shape("world_force", _world_force, _params_world_force, WORDS["world_force"]),
        Shape("time", lambda s_: _per_channel(_legendre(s_, cc.time_order)),
              lambda s_: _names_per_channel([f"P{d}(t)" for d in range(1, cc.time_order + 1)], ["-"] * cc.time_order),
              WORDS["time"]),
        Shape("wrench_linear", _wrench_linear, _params_wrench_linear, WORDS["wrench_linear"]),
        Shape("joint_velocity", _joint_velocity, _params_joint_velocity, WORDS["joint_velocity"]),
        Shape("joint_position", _joint_position, _params_joint_position, WORDS["joint_position"]),
    ]
    if getattr(s, "contact", None) is not None and np.any(s.contact) and s.setup.contact.mode == "tip":
        out.append(Shape("contact_moment", _contact_moment, _params_contact_moment, WORDS["contact_moment"]))
    if not getattr(s, "has_time", True):  # a static log without time: no time axis to judge on
        out = [x for x in out if x.name != "time"]
    if getattr(s, "static", False):  # poses at rest: no velocities
        out = [x for x in out if x.name != "joint_velocity"]
    for col in s.extra:
        out.append(Shape(f"extra:{col}", (lambda c: lambda s_: _per_channel(
            (s_.extra[c] - _whole(s_, "extra_mean", lambda: {c: s_.extra[c].mean()})[c])[:, None]))(col),
                         lambda s_: _names_per_channel(["x"], ["unit"]), WORDS["extra"]))
    return out


# ------------------------------------------------------------------------------------------ verdict
def _runs(t: np.ndarray, gap: float) -> list[np.ndarray]:
    """Index runs of rows (sorted times) with no gap longer than ``gap``."""
    if len(t) == 0:
        return []
    cut = np.flatnonzero(np.diff(t) > gap) + 1
    return np.split(np.arange(len(t)), cut)


def _spans(t: np.ndarray, mask: np.ndarray, gap: float) -> list[list[float]]:
    out = []
    for r in _runs(t[mask], gap):
        if len(r):
            out.append([float(t[mask][r[0]]), float(t[mask][r[-1]])])
    return out


def unexplained(des: sel.Design, e_ho: np.ndarray, rm, sigma: np.ndarray, setup, spacing: tuple[float, float],
                cc: CompCfg = CompCfg(), static: bool = False) -> dict:
    """Per channel: the held-out residual against the noise floor and its structured part
    (module docstring). -> {"complete": bool, "channels": {...}, "carried_by": [...], ...}.
    ``spacing`` = (dt, stride_s): the sample period and the row spacing [s].
    ``static``: rows are poses (ordered by group of similar poses, ``des.t_s`` their index): the
    long average runs over ``cc.static_window_poses`` neighbouring poses and no time spans are given."""
    dt, stride_s = spacing
    if static:
        dt, stride_s = 1.0, 1.0
        cc = cc._replace(struct_window_s=float(cc.static_window_poses))
    sig_tip = 1.0 / rm.w_tip
    sig_ch = np.concatenate([sigma, sig_tip])
    rel_ch = np.array([setup.analysis.relevant_force_N] * 3 + [setup.analysis.relevant_moment_Nm] * 6)
    names = des.channel_names
    chans, carried, phases, spans = {}, [], set(), []
    n_long = max(1, int(round(cc.struct_window_s / stride_s)))
    for c, name in enumerate(names):
        m = des.channel == c
        if not m.any():
            continue
        t = des.t_s[m]
        x = e_ho[m] / des.W[m]  # physical units
        floor = sig_ch[c] / np.sqrt(rm.k_smooth)
        long = np.empty_like(x)
        for r in _runs(t, 2.5 * stride_s):
            long[r] = moving_average(x[r], n_long)
        rms, rms_long = float(np.sqrt(np.mean(x**2))), float(np.sqrt(np.mean(long**2)))
        white_long = sig_ch[c] / np.sqrt(max(n_long * stride_s / dt, rm.k_smooth))
        struct = float(np.sqrt(max(rms_long**2 - white_long**2, 0.0)))
        structured = rms_long > cc.struct_factor * white_long
        relevant = bool(structured and struct >= rel_ch[c])
        unit = FORCE_UNIT if c < 3 else MOMENT_UNIT
        entry = {"phase": "free space" if c < 6 else "contact (moment about the tip)", "unit": unit,
                 "rms": rms, "noise_floor_rms": float(floor), "ratio_to_noise": float(rms / max(floor, 1e-300)),
                 "structured_rms": struct, "structured": bool(structured), "relevant_size": float(rel_ch[c]),
                 "unexplained": relevant}
        if relevant and static:
            carried.append(name)
            phases.add(entry["phase"])
        elif relevant:
            sp = _spans(t, np.abs(long) >= rel_ch[c], 2.5 * stride_s)
            sp = [w for w in sp if w[1] - w[0] >= 0.5 * cc.struct_window_s]
            entry["spans_s"] = sp[:8]
            spans += [(w, name) for w in sp]
            carried.append(name)
            phases.add(entry["phase"])
        chans[name] = entry
    return {"complete": not carried, "carried_by": carried, "phases": sorted(phases), "channels": chans,
            "spans_s": [{"t_s": w, "channel": ch} for w, ch in sorted(spans, key=lambda z: -(z[0][1] - z[0][0]))[:10]],
            "method": {**cc._asdict(), "white_floor": "per-sample noise / sqrt(samples a row averages)"}}


# ------------------------------------------------------------------------------------------ hints
def _relevant_of_sq(col_sq: np.ndarray, n_rows: np.ndarray, rel9: np.ndarray) -> np.ndarray:
    """Per parameter: the size that changes some channel's RMS by that channel's relevant size,
    the RMS taken over the rows of that channel, as the verdict takes it (``unexplained``): the six
    free-space channels over the free-space rows, the three tip-moment channels over the contact
    rows. A shape that acts in contact only is not diluted by the free space (and vice versa).
    ``col_sq`` (9, k): the columns' squares summed per channel (``RowMap.channel_sq``); ``n_rows``
    (9,) the rows of each channel; ``rel9`` (9,) the channels' relevant sizes."""
    rms = np.sqrt(col_sq / np.maximum(n_rows, 1)[:, None])  # (9, k)
    worst = np.max(rms / rel9[:, None], axis=0)
    return np.where(worst > 0, 1.0 / np.maximum(worst, 1e-300), 1.0)


def hints(s, des: sel.Design, rm, result, sc: sel.SelCfg, cc: CompCfg = CompCfg(),
          beside: dict | None = None) -> list[dict]:
    """Test every shape against the held-out residual given the final model (module docstring);
    ``beside`` {effect: its columns}: effects fitted beside the present ones as nuisance (the
    undecided effects a complete model holds, ``held_undecided``)."""
    from scipy.stats import false_discovery_control

    rel9 = np.array([s.setup.analysis.relevant_force_N] * 3 + [s.setup.analysis.relevant_moment_Nm] * 6)
    sh = [x for x in shapes(s, cc) if not (x.name == "sensor_constant" and s.setup.log.tared)]
    hd = hint_design(s, des, rm, result, sh, rel9, cc, beside)
    info = {x.name: (x, None) for x in sh}
    scale, X = hd.scale, hd.X
    st = sel.Stats(hd)
    b = st.z_idx
    sse0, _, _ = st.cv(b, sc.ridge)
    rest = float(sse0.sum()) or 1e-300
    # a block jackknife's covariance has rank B - 1 at most: a shape with more parameters than B - 2 (a short log's
    # few blocks) has no Hotelling test of its whole; it is tested as a large shape is, entries selected sparsely
    dense = min(cc.max_dense, hd.n_blocks - 2)
    tests = {n: (sel._test(st, hd, n, b, sse0, sc) if hd.X[n].shape[1] <= dense
                 else _sparse_test(st, hd, n, b, sse0, sc, cc)) for n in X}
    padj = false_discovery_control([tests[n].p_value for n in X], method="bh")
    out = []
    for n, pa in zip(X, padj):
        t = tests[n]
        share = float(t.gain.sum() / rest)
        big = bool(np.max(np.abs(t.p)) >= 1.0) if len(t.p) else False
        if not (pa < sc.alpha and share >= sc.min_explained and big):
            continue
        x, C = info[n]
        k = hd.X[n].shape[1]
        p, sd = np.zeros(k), np.zeros(k)
        p[t.cols] = t.p * scale[n][t.cols]
        sd[t.cols] = np.sqrt(np.clip(np.diag(t.cov), 0, None)) * scale[n][t.cols]
        names, units = x.params(s)
        if n.startswith("extra:"):
            col = n.split(":", 1)[1]
            names = [f"{WRENCH[i]}_per_{col}" for i in range(6)]
            units = [f"{_unit(i)} per unit of {col}" for i in range(6)]
        out.append({"shape": n, "explains": share, "p_adjusted": float(pa), "words": x.words,
                    "convention": "change of the wrench the tool exerts on the sensor (sensor frame, about its origin)",
                    "fitted": _fitted(n, names, units, p, sd, scale[n], t.cols, cc), "_p": p, "_sd": sd,
                    "_names": names, "_units": units, "_rel": scale[n], "_cols": list(t.cols)})
    out.sort(key=lambda h: -h["explains"])
    return out


def hint_rows(s, rm, cc: CompCfg) -> tuple[object, np.ndarray | None]:
    """The rows of the hint test on ``LogSignals`` s: all of them, or on a log with more than ``cc.hint_max_row_times``
    row times every m-th span of ``cc.hint_span_s`` (by row time from the log's start, so the same
    whatever the chunking) -- a shape's test needs minutes of log, not hours. -> (the ``RowMap`` of
    the rows kept, their positions in the design built on ``rm`` (R',) ascending; None: every row)."""
    from kinadapt_nn.diagnostics.stream import every_mth_span

    keep, _ = every_mth_span(s.clock[rm.rows] - s.clock[0], cc.hint_max_row_times, cc.hint_span_s)  # the design's t_s
    if keep is None:
        return rm, None
    sub = rm._replace(rows=rm.rows[keep], contact=rm.contact[keep])
    start = rm.positions()[keep]
    width = np.where(rm.contact[keep], 3, 6)
    pos = np.sort(np.concatenate([start[width == 6][:, None] + np.arange(6), start[width == 3][:, None]
                                  + np.arange(3)], axis=None) if len(start) else np.zeros(0, int))
    return sub, pos.astype(np.int64)


def hint_design(s, des: sel.Design, rm, result, sh: list[Shape], rel9: np.ndarray, cc: CompCfg = CompCfg(),
                beside: dict | None = None) -> sel.Design:
    """The design of the hint test: the shapes ``sh`` as candidates, the final model's columns
    (nuisance and present effects) as nuisance; each shape's parameters scaled by ``_relevant_of_sq``
    (``rel9`` (9,): the relevant size of the six free-space channels and the three tip moments).
    A streamed ``des``: one chunked pass (``stream.block_stats``), never the shapes' columns, on the
    rows of ``hint_rows``."""
    if des.stats is not None:
        from kinadapt_nn.diagnostics import stream

        rm, pos = hint_rows(s, rm, cc)
        if pos is not None:
            des = des._replace(y=des.y[pos], block=des.block[pos], W=des.W[pos], channel=des.channel[pos],
                               t_s=des.t_s[pos])
        bs = des.stats
        pres = {n: list(c) for n, (c, _, _) in result.present.items()}
        pres.update({n: list(c) for n, c in (beside or {}).items()})
        nuis = [src for src in bs.sources if src.name == "_offset"]
        nuis += [src._replace(cols=pres[src.name]) for src in bs.sources if src.name in pres]
        srcs = [stream.Source(x.name, x.columns, list(range(len(x.params(s)[0])))) for x in sh]
        st = stream.block_stats(s, rm, nuis + srcs, des.y, des.block, des.n_blocks, bs.chunk,
                                stream.PassOpts(squares=True, extra=bs.extra))
        kz = sum(len(src.cols) for src in nuis)
        R, X, scale, k0 = len(des.y), {}, {}, kz
        for src in srcs:
            k = len(src.cols)
            X[src.name] = sel.Width((R, k))
            scale[src.name] = _relevant_of_sq(st.col_sq[:, k0:k0 + k], rm.phase_rows(), rel9)
            k0 += k
        return sel.Design(des.y, X, sel.Width((R, kz)), des.block, des.n_blocks, scale, {n: False for n in X}, des.W,
                          des.channel, des.channel_names, des.t_s, st)
    base = [des.Z] if des.Z.shape[1] else []
    for n, (c, _, _) in result.present.items():
        base.append(des.X[n][:, c])
    for n, c in (beside or {}).items():
        base.append(des.X[n][:, list(c)])
    Z = np.concatenate(base, axis=1) if base else np.zeros((len(des.y), 0))
    X, scale = {}, {}
    for x in sh:
        C = x.columns(s)
        X[x.name] = rm.apply(C)
        xs = moving_average(C, rm.k_smooth)[rm.rows]
        scale[x.name] = _relevant_of_sq(rm.channel_sq(xs, rm.contact), rm.phase_rows(), rel9)
    return sel.Design(des.y, X, Z, des.block, des.n_blocks, scale, {n: False for n in X}, des.W, des.channel,
                      des.channel_names, des.t_s)


def _sparse_test(st: sel.Stats, hd: sel.Design, name: str, base: np.ndarray, sse0: np.ndarray, sc: sel.SelCfg,
                 cc: CompCfg) -> sel.Candidate:
    """A many-parameter shape, entries selected sparsely: forward selection of single columns by
    held-out gain (each added entry must beat the model without it block by block, one-sided
    paired t, Bonferroni over the candidates), at most ``max_entries``. The shape's test is then
    the paired block test of its held-out gain over the final model."""
    idx_all = st.idx[name]
    chosen: list[int] = []
    sse_cur = sse0
    rest = float(sse0.sum()) or 1e-300
    while len(chosen) < cc.max_entries:
        cur = np.concatenate([base, idx_all[chosen]])
        best = None
        for j in range(len(idx_all)):
            if j in chosen:
                continue
            sse, reps, p = st.cv(np.concatenate([cur, idx_all[[j]]]), sc.ridge)
            g = float((sse_cur - sse).sum())
            if best is None or g > best[1]:
                best = (j, g, sse, reps[:, -1:], p[-1:])
        if best is None:
            break
        j, g, sse, reps, p = best
        n_cand = len(idx_all) - len(chosen)
        if g / rest < cc.min_entry_gain or \
                sel.wald_pvalue(p, sel.jackknife_cov(reps), len(reps)) * n_cand >= sc.alpha:
            break
        chosen.append(j)
        sse_cur = sse
    if not chosen:
        return sel.Candidate(name, [], np.zeros_like(sse0), sse0, np.zeros(0), np.zeros((0, 0)), 1.0)
    idx = np.concatenate([base, idx_all[chosen]])
    sse, reps, p = st.cv(idx, sc.ridge)
    cov = sel.jackknife_cov(reps[:, len(base):])
    pval = min(1.0, sel.wald_pvalue(p[len(base):], cov, len(reps)) if len(chosen) < len(reps) - 1 else 1.0)
    return sel.Candidate(name, chosen, sse0 - sse, sse, p[len(base):], cov, min(pval, sel.paired_p(sse, sse0)))


def _fitted(shape: str, names, units, p, sd, rel, cols, cc: CompCfg) -> dict:
    """The fitted numbers a person reads: every parameter of a small shape; the largest
    significant entries of a large one; the world force's point of action."""
    def q(i):
        return {"value": float(p[i]), "sd": float(sd[i]), "unit": units[i]}

    if shape == "world_force":
        F = p[:3]
        M = p[3:].reshape(3, 3)
        point = M @ F / max(float(F @ F), 1e-300)
        return {"force_w": {"value": [float(v) for v in F], "sd": [float(v) for v in sd[:3]], "unit": "N"},
                "point_s": {"value": [float(v) for v in point], "unit": "m",
                            "note": "least-squares point of action (from M = p F^T)"}}
    if len(p) <= cc.max_dense:
        return {names[i]: q(i) for i in range(len(p))}
    order = sorted(cols, key=lambda i: -abs(p[i] / rel[i]))
    return {names[i]: q(i) for i in order}


def held_undecided(result) -> dict:
    """{effect: its columns} of the effects the final model holds (selected) that the verdict leaves
    undecided (``summary.undecided_in_model``): the model's fit needs them, none is a finding."""
    return {e["effect"]: list(e["columns_used"]) for e in result.entries
            if e.get("selected_round") is not None and e.get("verdict") != "present" and e.get("columns_used")}


def without_held(des: sel.Design, result, held: dict, sc: sel.SelCfg) -> np.ndarray:
    """(R,) the held-out residual rows of the final model less the effects ``held`` ({effect: columns})."""
    st = sel.Stats(des)
    out = np.concatenate([st.idx[n][list(c)] for n, c in held.items()])
    return sel.heldout_residual(st, des, np.asarray([j for j in result.final_idx if j not in set(out)], dtype=int), sc)


@dataclass(frozen=True)
class Completeness:
    """The completeness stage's outcome: is the final model complete, what it leaves, the hints."""

    model_complete: bool
    unexplained: dict  #: the ``unexplained`` section (``hints`` included)
    files: dict  #: the hints' effect files {file name: Python source}

    def sections(self) -> dict:
        """The report's sections of this stage: ``model_complete``, ``unexplained``."""
        return {"model_complete": self.model_complete, "unexplained": self.unexplained}


def assess(ranked, sc: sel.SelCfg, sigma: np.ndarray, stride_s: float, with_hints: bool = True,
           cc: CompCfg = CompCfg(), source: str = "the log") -> Completeness:
    """Is the final model complete; the ``unexplained`` section (with ``hints`` when incomplete)
    and the hints' effect files (``Completeness``). ``ranked``: the ranking's outcome (its
    signals ``s``, design ``des``, row map ``rm`` and selection ``result``); ``sigma`` (6,): the
    per-sample noise of the wrench channels; ``stride_s``: the row spacing [s]."""
    s, des, rm, result = ranked.s, ranked.des, ranked.rm, ranked.result
    from kinadapt_nn.diagnostics.hintfiles import effect_file, public

    static = bool(getattr(s, "static", False))
    dt = 1.0 if static else float(np.median(np.diff(s.t)))
    un = unexplained(des, result.heldout, rm, sigma, s.setup, (dt, stride_s), cc, static)
    complete = un.pop("complete")
    un["hints"] = []
    files: dict[str, str] = {}
    held = held_undecided(result) if complete and with_hints else {}
    if held and unexplained(des, without_held(des, result, held, sc), rm, sigma, s.setup, (dt, stride_s), cc,
                            static)["complete"]:
        held = {}  # what they explain is below the relevant size: no stand-in for anything relevant
    if with_hints and (not complete or held):
        for h in hints(s, des, rm, result, sc, cc, held if complete else None):
            name, text = effect_file(h, source)
            files[name] = text
            un["hints"].append({**public(h), "effect_file": name})
    return Completeness(bool(complete), un, files)


# ------------------------------------------------------------------------------------------ robust estimates
#: [relevant sizes] a parameter whose sd on the explained rows exceeds this is not determined there
LEFT_UNDETERMINED = 10.0


def explained_rows(s, rm, des: sel.Design, carried: list[int]) -> sel.Design:
    """``des`` (built on the ``LogSignals`` s and the ``RowMap`` rm; both unused for a design that holds its
    columns) with the rows of the channels ``carried`` (indices into ``des.channel_names``) out of every
    block's statistics (a streamed design: one more pass, those rows in a block of their own that is then
    dropped; they keep their place in the rows, their prediction zero)."""
    out = np.isin(des.channel, carried)
    if des.stats is None:
        keep = ~out
        return des._replace(y=des.y[keep], X={n: x[keep] for n, x in des.X.items()}, Z=des.Z[keep],
                            block=des.block[keep], W=des.W[keep], channel=des.channel[keep], t_s=des.t_s[keep])
    from kinadapt_nn.diagnostics import stream

    bs, nb = des.stats, des.n_blocks
    block = np.where(out, nb, des.block).astype(des.block.dtype)
    st = stream.block_stats(s, rm, list(bs.sources), des.y, block, nb + 1, bs.chunk, stream.PassOpts(extra=bs.extra))
    combine = st.combine

    def combine_kept(P: np.ndarray) -> np.ndarray:
        return combine(np.vstack([P, np.zeros((1, P.shape[1]))]))

    st = st._replace(G=st.G[:nb], h=st.h[:nb], yy=st.yy[:nb], combine=combine_kept)
    return des._replace(stats=st, block=block)


def _fit(st: sel.Stats, idx: np.ndarray, sc: sel.SelCfg) -> tuple[np.ndarray, np.ndarray]:
    """(estimate (k,), sd (k,)) of the columns ``idx`` (scaled units) of ``st``: the sd the larger of the
    block jackknife's (t-widened) and the white-noise / block-robust one (as the selection's)."""
    from kinadapt_nn.diagnostics import intervals

    _, reps, p = st.cv(idx, sc.ridge)
    if len(reps) < 2:  # the rows left hold fewer than two blocks: they pin nothing (no jackknife either)
        return p, np.full(len(idx), np.inf)
    var = np.diag(sel.jackknife_cov(reps)) * intervals.t_widen(len(reps) - 1)
    rows = int(np.count_nonzero(st.des.block < st.des.n_blocks))
    var_h = intervals.honest_sd(st.G[:, idx][:, :, idx], st.h[:, idx], st.yy, p, rows) ** 2
    return p, np.sqrt(np.clip(np.maximum(var, var_h), 0.0, None))


def robust(ranked, sigma: np.ndarray, stride_s: float, sc: sel.SelCfg, cc: CompCfg = CompCfg()):
    """The ranking's estimates when the final model leaves structure (module docstring): ``ranked``
    (``userlog.Ranked``) with each present and undecided effect's estimate moved by ``delta`` =
    (its fit with the final model on the explained rows) - (the same fit on all rows) and its sd
    ``sqrt(max(sd, sd_rows)^2 + delta^2)``; ``left_sd`` (k,) = ``|delta|`` and ``left_rows`` (the
    channels left out) in the entry. A parameter the explained rows do not determine (their sd beyond
    ``LEFT_UNDETERMINED`` relevant sizes: an effect seen only where the residual is unexplained) keeps
    its estimate and is named in ``left_undetermined``. Unchanged when the model is complete.
    ``sigma`` (6,) and ``stride_s`` as in ``assess``."""
    import dataclasses

    s, des, rm, result = ranked.s, ranked.des, ranked.rm, ranked.result
    static = bool(getattr(s, "static", False))
    dt = 1.0 if static else float(np.median(np.diff(s.t)))
    carried = unexplained(des, result.heldout, rm, sigma, s.setup, (dt, stride_s), cc, static)["carried_by"]
    if not carried:
        return ranked
    names = list(des.channel_names)
    des_x = explained_rows(s, rm, des, [names.index(c) for c in carried])
    st, st_x = sel.Stats(des), sel.Stats(des_x)
    final = np.asarray(result.final_idx)
    present = dict(result.present)
    entries = []
    for e in result.entries:
        n = e["effect"]
        if e["verdict"] == "absent" or not e.get("columns_used"):
            entries.append(e)
            continue
        c = list(e["columns_used"])
        own = st.idx[n][c]
        idx = final if n in present else np.concatenate([final, own])
        pos = np.array([int(np.flatnonzero(idx == j)[0]) for j in own])
        p_all, _ = _fit(st, idx, sc)
        p_x, sd_x = _fit(st_x, idx, sc)
        scale = np.asarray(des.scale[n], dtype=float)[c]
        ok = sd_x[pos] <= LEFT_UNDETERMINED  # scaled units: 1 = the relevant size
        delta, sd_x = np.where(ok, p_x[pos] - p_all[pos], 0.0) * scale, np.where(ok, sd_x[pos], 0.0) * scale
        e = {**e, "params": np.asarray(e["params"], dtype=float).copy(), "sd": np.asarray(e["sd"], dtype=float).copy()}
        e["params"][c] += delta
        e["sd"][c] = np.sqrt(np.maximum(e["sd"][c], sd_x) ** 2 + delta ** 2)
        e["left_sd"] = np.zeros(len(e["sd"]))
        e["left_sd"][c] = np.abs(delta)
        e["left_rows"] = list(carried)
        e["left_undetermined"] = [int(j) for j, o in zip(c, ok) if not o]
        if n in present:
            present[n] = (present[n][0], e["params"][c], e["sd"][c])
        entries.append(e)
    return dataclasses.replace(ranked, result=result._replace(entries=entries, present=present))


def caveated(ranking: list[dict], complete: bool) -> list[dict]:
    """The ranking's entries; when the model stays incomplete, each ``present`` one (a new dict) with
    its share and a warning."""
    if complete:
        return list(ranking)
    out = []
    for e in ranking:
        if e.get("verdict") == "present":
            e = {**e, "explains_share": e.get("explained_fraction"),
                 "warning": ("the model stays incomplete: this effect explains "
                             f"{100 * (e.get('explained_fraction') or 0):.0f}% of the residual and may stand in for "
                             "part of what is unexplained")}
        out.append(e)
    return out


__all__ = ["CompCfg", "Completeness", "SHAPES", "assess", "caveated", "explained_rows", "hints", "robust", "shapes",
           "unexplained", "WORDS"]
