"""Residual analysis: the measured sensor rate minus the model's prediction, from raw logs.

The logged *raw* channels (time, encoders, raw F/T reading) are replayed through the
controller's own sensing pipeline (``Controller`` with the law frozen at ``theta``): the same
tare, sensor vector ``s``, rate filter and filtered prediction ``known_f + Phi_f theta``. The
residual ``e = s_dot_meas - s_dot_pred`` is the paper's bias ``b`` plus any parametric error
(eq. ft_pred). Nothing here needs the simulator or the truth, so a log from a real Panda works
the same way.

Contact phases, from sensor-side signals only (``d`` the proprioceptive depth, contact = the
controller's gate, |F| >= 1 N or |M| >= 0.05 N m):
* ``free_space`` -- no contact and d < -2 mm (or the still start, before the drive);
* ``approach``   -- no contact and -2 mm <= d < 0;
* ``entry``      -- 0 <= d < 5 mm;
* ``wall_contact`` -- d >= 5 mm, in contact, not seated;
* ``seated``     -- d >= the seat depth (success.depth_m - depth_tol_m).
Samples in none of these (inside the bore without contact) are ``inside_free``.
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np

from kinadapt_nn.config import ExperimentCfg
from kinadapt_nn.diagnostics.importers import RawLog, read_csv_log
from kinadapt_nn.errors import KinadaptError
from kinadapt_nn.sensing import CHANNEL_NAMES, CHANNEL_UNITS

PHASES = ("free_space", "approach", "entry", "wall_contact", "seated", "inside_free")


class Replay(NamedTuple):
    """The controller-side channels recomputed from a RawLog."""

    t_s: np.ndarray  #: (N,)
    s: np.ndarray  #: (N, 6) sensor vector [d, F_lat, M]
    w_env: np.ndarray  #: (N, 6) tared wrench tool -> environment at O (world) [N, N m]
    s_dot_meas: np.ndarray  #: (N, 6) filtered measured rate
    s_dot_pred: np.ndarray  #: (N, 6) filtered predicted rate
    residual: np.ndarray  #: (N, 6) s_dot_meas - s_dot_pred
    contact: np.ndarray  #: (N,) bool, the controller's contact gate
    phase: np.ndarray  #: (N,) int index into PHASES
    qdot_norm: np.ndarray  #: (N,) |qdot| [rad/s]
    active: np.ndarray  #: (N,) bool: after the tare (drive on)


#: what a robot's own log needs (``kinadapt diagnose`` without ``--setup`` reads only this package's runs)
NEEDS_SETUP = ("pass --setup SETUP.toml (a commented template: kinadapt setup-template --out SETUP.toml; complete "
               "ones in examples/setups/)")


def load_log(path: Path) -> RawLog:
    """A run folder, a ``trace.npz`` or a CSV (``kinadapt_nn.diagnostics.importers``); a robot's own
    log (another CSV, Parquet, a ROS 2 bag) is a one-line error saying to pass ``--setup``. A trace obeys
    the log readers' rules (``kinadapt_nn.diagnostics.readers``): finite raw channels, strictly
    increasing time, no gaps, enough samples -- each a one-line ``KinadaptError`` naming the file."""
    from kinadapt_nn.diagnostics import readers
    from kinadapt_nn.trace import Trace

    path = Path(path)
    kind = readers.log_format(path)  # not found, an unknown suffix: one line naming the formats
    if kind == "csv" and path.name.lower().endswith(".csv"):
        try:
            return read_csv_log(path)
        except KinadaptError as exc:
            raise KinadaptError(f"{exc}; for your robot's own CSV log, {NEEDS_SETUP}") from None
    if kind != "trace":
        what = {"csv": "a CSV", "parquet": "a Parquet", "bag": "a ROS 2 bag"}[kind]
        raise KinadaptError(f"log '{path}' is {what} log, not a run of this package; for your robot's own log, "
                            f"{NEEDS_SETUP}")
    if path.is_dir():
        path = path / "trace.npz"
    tr = Trace.load(path)
    readers.check_trace(tr, path)  # the same checks as every user log
    theta = tr["theta"][-1] if "theta" in tr.arrays and len(tr) else None
    return RawLog(tr["t_s"], tr["q_rad"], tr["qdot_rad_s"], tr["wrench_raw_f"], theta, str(path))


def replay(log: RawLog, cfg: ExperimentCfg, theta: np.ndarray | None = None) -> Replay:
    """Feed the log through a frozen controller and collect its sensing channels."""
    from kinadapt_nn.runs.build import make_features
    from dataclasses import replace

    from kinadapt_nn.controller.controller import Controller
    from kinadapt_nn.known import KnownCfg

    feats, theta0 = make_features(cfg.model_copy(update={"run": cfg.run.model_copy(update={"features": "adjoint"})}))
    th = np.asarray(theta if theta is not None else (log.theta if log.theta is not None and len(log.theta) == 3
                                                    else cfg.sensing.nominal_offset_f_m), dtype=float)
    ctrl = Controller(replace(KnownCfg.of(cfg), features_kind="adjoint", law="frozen"), feats, th)
    n = len(log.t_s)
    out = {k: np.zeros((n, 6)) for k in ("s", "w", "m", "p")}
    contact = np.zeros(n, bool)
    active = np.zeros(n, bool)
    for i in range(n):
        ctrl.step(float(log.t_s[i] - log.t_s[0]), log.q_rad[i], log.qdot_rad_s[i], log.wrench_raw_f[i])
        lg = ctrl.last
        out["s"][i], out["w"][i], out["m"][i], out["p"][i] = lg.s, lg.w_env_w, lg.s_dot_meas, lg.s_dot_pred
        contact[i] = lg.adapt.gate > 0
        active[i] = lg.drive_scale > 0
    s = out["s"]
    d = s[:, 0]
    su = cfg.success
    phase = np.full(n, PHASES.index("inside_free"))
    phase[(~contact) & (d < 0.0)] = PHASES.index("approach")
    phase[(~contact) & (d < -0.002)] = PHASES.index("free_space")
    phase[~active] = PHASES.index("free_space")
    phase[active & (d >= 0.0) & (d < 0.005)] = PHASES.index("entry")
    phase[active & (d >= 0.005) & contact] = PHASES.index("wall_contact")
    phase[active & (d >= su.depth_m - su.depth_tol_m)] = PHASES.index("seated")
    return Replay(log.t_s - log.t_s[0], s, out["w"], out["m"], out["p"], out["m"] - out["p"], contact, phase,
                  np.linalg.norm(log.qdot_rad_s, axis=1), active)


def ljung_box(x: np.ndarray, lags: int = 20) -> tuple[float, float]:
    """Ljung-Box Q statistic and p-value for whiteness of a 1-D series (scipy's chi2)."""
    from scipy.stats import chi2

    x = np.asarray(x, dtype=float) - np.mean(x)
    n = len(x)
    den = float(x @ x)
    if n <= lags + 1 or den == 0.0:
        return float("nan"), float("nan")
    r = np.array([float(x[k:] @ x[:-k]) / den for k in range(1, lags + 1)])
    q = n * (n + 2) * float(np.sum(r**2 / (n - np.arange(1, lags + 1))))
    return q, float(chi2.sf(q, lags))


def max_xcorr(a: np.ndarray, b: np.ndarray, max_lag: int) -> tuple[float, int]:
    """Largest |normalised cross-correlation| of two series over lags in [-max_lag, max_lag]."""
    a = a - a.mean()
    b = b - b.mean()
    den = np.sqrt(float(a @ a) * float(b @ b))
    if den == 0.0:
        return 0.0, 0
    best, lag = 0.0, 0
    for k in range(-max_lag, max_lag + 1):
        c = float(a[max(k, 0):len(a) + min(k, 0)] @ b[max(-k, 0):len(b) - max(k, 0)]) / den
        if abs(c) > abs(best):
            best, lag = c, k
    return best, lag


def analyse(rep: Replay, W: np.ndarray, window_s: float = 0.05, top: int = 5) -> dict:
    """Residual RMS by channel and by phase, the largest windows, whiteness, cross-correlations."""
    act = rep.active
    e = rep.residual[act]
    t = rep.t_s[act]
    dt = float(np.median(np.diff(rep.t_s))) if len(rep.t_s) > 1 else 1e-3
    by_channel = {n: float(np.sqrt(np.mean(e[:, i] ** 2))) if len(e) else None for i, n in enumerate(CHANNEL_NAMES)}
    by_phase = {}
    for k, name in enumerate(PHASES):
        m = act & (rep.phase == k)
        if m.any():
            by_phase[name] = {"samples": int(m.sum()), "time_s": float(m.sum() * dt),
                              **{n: float(np.sqrt(np.mean(rep.residual[m, i] ** 2))) for i, n in enumerate(CHANNEL_NAMES)}}
    ew = np.sum((W * e) ** 2, axis=1)
    nw = max(1, int(round(window_s / dt)))
    windows = []
    if len(ew) >= nw:
        sums = np.convolve(ew, np.ones(nw), "valid")
        order = np.argsort(sums)[::-1]
        taken: list[int] = []
        for i in order:
            if all(abs(i - j) >= nw for j in taken):
                taken.append(int(i))
                ph = PHASES[int(np.bincount(rep.phase[act][i:i + nw]).argmax())]
                windows.append({"t_start_s": float(t[i]), "t_end_s": float(t[min(i + nw, len(t) - 1)]),
                                "rms_w": float(np.sqrt(sums[i] / nw)), "phase": ph})
            if len(taken) >= top:
                break
    whiteness = {}
    xcorr = {}
    lag_max = int(round(0.05 / dt))
    fmag = np.linalg.norm(rep.w_env[act, :3], axis=1)
    for i, n in enumerate(CHANNEL_NAMES):
        q, p = ljung_box(e[:, i])
        whiteness[n] = {"ljung_box_Q": q, "p_value": p, "white_at_5pct": bool(p > 0.05) if np.isfinite(p) else None}
        cq, lq = max_xcorr(e[:, i], rep.qdot_norm[act], lag_max)
        cf, lf = max_xcorr(e[:, i], fmag, lag_max)
        xcorr[n] = {"with_joint_speed": cq, "lag_joint_speed_s": lq * dt, "with_force": cf, "lag_force_s": lf * dt}
    tot = float(np.sum(W**2 * np.sum(e**2, axis=0))) or 1.0
    share = {n: float(W[i] ** 2 * np.sum(e[:, i] ** 2) / tot) for i, n in enumerate(CHANNEL_NAMES)}
    return {"residual_rms_by_channel": by_channel, "residual_units": dict(zip(CHANNEL_NAMES, [u + "/s" for u in CHANNEL_UNITS])),
            "residual_share_by_channel_w": share, "residual_rms_by_phase": by_phase, "largest_windows": windows,
            "whiteness": whiteness, "cross_correlation": xcorr}


def plain_summary(a: dict) -> str:
    """One paragraph a person can read first."""
    share = a["residual_share_by_channel_w"]
    mom = sum(share[c] for c in ("M_x", "M_y", "M_z"))
    frc = share["F_lat_x"] + share["F_lat_y"]
    phases = a["residual_rms_by_phase"]
    worst = max(phases, key=lambda k: sum(phases[k][c] ** 2 for c in ("M_x", "M_y", "M_z", "F_lat_x", "F_lat_y"))) if phases else "-"
    white = [c for c, v in a["whiteness"].items() if v["white_at_5pct"]]
    w0 = a["largest_windows"][0] if a["largest_windows"] else None
    txt = (f"{100 * mom:.0f}% of the (W-scaled) residual is in the moment channels and {100 * frc:.0f}% in the "
           f"lateral force channels; the largest residual is in the '{worst}' phase")
    if w0:
        txt += f", worst 50 ms window at t = {w0['t_start_s']:.2f} s ({w0['phase']})"
    txt += ". " + ("No channel's residual is white (Ljung-Box, 5 %): it is structured, i.e. a model effect or "
                   "contact dynamics, not sensor noise." if not white else f"White channels: {', '.join(white)}.")
    return txt
