"""The live monitor: the diagnosis beside the controller (docs/monitor.md).

Per sample it gets what the controller gets -- encoders and the raw wrench, never the truth -- and
compares the reading with the nominal model of the set-up (``diagnostics.setup.SetupCfg``: the
declared tool, its gravity and inertia; contact per the declared contact) in ``kernel.sample``.
For the first ``calib_s`` (the robot at rest at the start) it measures the sensor's offset and its
noise sd per channel (at least the floor); then a two-sided CUSUM per channel on residual / sd
fires when the residual leaves the noise (threshold from ``false_alarms_per_h``:
``kernel.threshold``). After an alarm it collects ``window_s`` more of free-space samples, names the
best-fitting shape (``shapes.best``) and reports an :class:`Event` with the shapes its window cannot
tell from it (``shapes.ties``); the fitted shape then joins the model (the test restarts on what is
left, so a second change is a second event). At the end of the stream (``finish``) each open event
gets a last look: every shape fitted again on all the free samples since its onset (``Event.at_end``),
what ``monitor.agreement`` compares with the offline diagnosis of the same log.

Contact is not judged: its force is unknown to the model. Where the set-up declares a fixture
(its entrance plane), the samples with the nominal tip within ``contact_zone_m`` of the plane or
past it are contact; otherwise, when contact is declared, a force beyond the model by more than
``contact.detect_force_N`` is.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from kinadapt_nn.config import MonitorCfg
from kinadapt_nn.diagnostics.physical import nominal_inertials
from kinadapt_nn.diagnostics.setup import SetupCfg
from kinadapt_nn.monitor import kernel as K
from kinadapt_nn.monitor import shapes

CHANNELS = shapes.CHANNELS
#: BIC margin by which the best shape must beat the runner-up before an event is named
DECISIVE = 10.0
#: [s] the model's slow error before a change: the residual's means over blocks this long ...
MODEL_BLOCK_S = 0.1
#: [s] ... over this long before it (``Monitor._model_sd``)
MODEL_LOOK_S = 2.0
#: [s] right after a change the arm's transient (a sudden load) is left out of the fit
SETTLE_S = 0.02
#: an alarm becomes an event only when its best shape's estimate differs from none beyond this chance
#: (chi^2 of the estimate against its whole covariance: noise, the window's jackknife, the model's error),
#: and when the estimate reaches the effect's relevant size in SI, the offline diagnosis's (``shapes.relevance``
#: >= 1: a 1 deg turn, 30 g, 0.03 N/s, ...; docs/monitor.md)
CONFIRM_P = 1e-3
#: [s] the residual's mean over this long before a change is taken from the rows an event is fitted on
#: (``Monitor._baseline``; 0: none)
BASELINE_S = 0.5
#: windows (``window_s`` each) an alarm may wait for a clear winner before the best is named anyway
MAX_WINDOWS = 6


#: shapes whose wrench does not depend on the pose: one of them beats a pose-dependent shape (a tool that
#: turned in the grasp, a payload) clearly only once gravity has turned in the sensor frame by TURN_DEG
POSE_FREE = ("sensor_constant",)
TURN_DEG = 8.0


def _turned_deg(rows: np.ndarray) -> float:
    """[deg] the largest angle between gravity in s (g - a) at the window's first sample and at any other."""
    ga = rows[:, K.G_GA:K.G_GA + 3]
    u = ga / np.maximum(np.linalg.norm(ga, axis=1, keepdims=True), 1e-300)
    return float(np.degrees(np.arccos(np.clip(np.min(u @ u[0]), -1.0, 1.0))))


def _nparams(f) -> int:
    return int(np.count_nonzero(np.diag(f.cov) > 0)) if f.shape == "ft_bias_drift" else len(f.p)


@dataclass
class Event:
    """One change the monitor found."""

    t_s: float  #: [s] when the test fired
    onset_s: float  #: [s] the change's estimated start (the CUSUM's last restart on its channels)
    channels: list[str]  #: the channels whose test fired
    phase: str  #: "free space" (contact is not judged)
    shape: str  #: the best-fitting shape (``shapes.SHAPES``)
    text: str  #: what happened, with the estimate and its 95 % interval
    estimate: dict  #: the shape's estimate and sds
    runner_up: str  #: the next-best shape
    delta_bic: float  #: its BIC minus the best's (how clearly the best won)
    rows: int  #: residual rows fitted
    t_named_s: float = float("nan")  #: [s] the last sample its estimate has seen
    t_first_named_s: float = float("nan")  #: [s] when it was first named (reported with its shape)
    open: bool = True  #: still open at the end (its shape stays in the model)
    updates: int = 0  #: times a later look refitted its estimate (the same effect seen better)
    #: the shapes its window cannot tell from ``shape`` (``shapes.ties``: a near-tie); empty: it is decided
    ties: list[str] = field(default_factory=list)
    #: the end-of-run look at an open event (``Monitor.finish``): every shape fitted again on all the free
    #: samples since its onset -- {"shape", "ties", "delta_bic", "rows", "from_s", "to_s", "encoder_offset":
    #: {"joint", "offset_deg", "offset_sd_deg", "delta_bic"}} -- or None
    at_end: dict | None = None

    @property
    def line(self) -> str:
        alt = f" (or {' or '.join(self.ties)}: the window cannot tell them apart)" if self.ties else ""
        return f"{self.t_s:.2f} s: {self.text} -- looks like {self.shape}{alt}"

    def as_dict(self) -> dict:
        return {"t_s": self.t_s, "onset_s": self.onset_s, "t_named_s": self.t_named_s,
                "t_first_named_s": self.t_first_named_s, "channels": self.channels,
                "phase": self.phase, "shape": self.shape, "text": self.text, "line": self.line,
                "estimate": self.estimate, "runner_up": self.runner_up, "delta_bic": self.delta_bic,
                "rows": self.rows, "open": self.open, "updates": self.updates, "ties": list(self.ties),
                "at_end": self.at_end}


def consts(setup: SetupCfg, mcfg: MonitorCfg, dt_s: float) -> np.ndarray:
    """The kernel's constants (``kernel.NC``) of a set-up and the monitor's config."""
    c = np.zeros(K.NC)
    m, mc, I_O = nominal_inertials(setup)
    c[K.C_DT], c[K.C_M], c[K.C_MC:K.C_MC + 3], c[K.C_IO:K.C_IO + 9] = dt_s, m, mc, I_O.ravel()
    c[K.C_GW:K.C_GW + 3] = setup.world.g_w()
    c[K.C_PFS:K.C_PFS + 3] = setup.sensor.position_flange_m
    c[K.C_RFS:K.C_RFS + 9] = setup.sensor.R_fs().ravel()
    c[K.C_SIGN] = setup.log.sign
    c[K.C_K] = mcfg.cusum_k
    c[K.C_H] = K.threshold(mcfg.false_alarms_per_h, mcfg.cusum_k, dt_s)
    c[K.C_HROT] = K.rotation_threshold(mcfg.false_alarms_per_h, dt_s) if mcfg.rotation_test else 0.0
    c[K.C_CALIB], c[K.C_WINDOW] = mcfg.calib_s, mcfg.window_s
    ct = setup.contact
    if ct.mode == "none":
        c[K.C_ZONE] = K.ZONE_NONE
    elif ct.geometry == "socket" or ct.zone == "entrance":
        c[K.C_ZONE] = K.ZONE_GEOMETRY
        axis = np.asarray(ct.axis_w, dtype=float)
        c[K.C_ENTRY:K.C_ENTRY + 3], c[K.C_UP:K.C_UP + 3] = ct.entry_w_m, -axis / np.linalg.norm(axis)
    else:
        c[K.C_ZONE] = K.ZONE_FORCE
    c[K.C_ZONE_M], c[K.C_TIP:K.C_TIP + 3] = mcfg.contact_zone_m, setup.tool.tip_sensor_m
    c[K.C_DETECT], c[K.C_FLOOR_N], c[K.C_FLOOR_M] = ct.detect_force_N, mcfg.floor_N, mcfg.floor_Nm
    c[K.C_ENGAGE] = np.inf  # (``monitor_of_run``: a socket engaged at the drive start)
    return c


@dataclass
class Monitor:
    """A monitor of one stream of samples (``sample`` per sample; ``loop_step`` per control period of
    the episode loop); ``events`` what it found; ``on_event(event)`` is called as each is named."""

    setup: SetupCfg
    mcfg: MonitorCfg
    dt_s: float
    on_event: object = None
    frame: str = "world"
    events: list[Event] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.c = consts(self.setup, self.mcfg, self.dt_s)
        nj = len(self.setup.log.q)  # the arm's joints: their axes ride in the ring (``shapes.encoder_offset``)
        self.st, self.ring = K.new_state(nj)
        c = self.c
        self.tool = shapes.Tool(float(c[K.C_M]), c[K.C_MC:K.C_MC + 3].copy(), c[K.C_IO:K.C_IO + 9].reshape(3, 3).copy())
        self.h = float(self.c[K.C_H])
        self._loop_fn = None
        self._kin = np.zeros((6 + nj, 3))  # [R_ws; p_ws; v_w; w_w; z_j (nj)] of one sample (``kernel.sample``)
        self._alarm: dict | None = None  #: the alarm whose window is being collected
        self.alarms: list[dict] = []  #: every alarm named: when, which test, its best shape, what came of it
        self.dismissed = 0  #: alarms whose best shape was not significant (``CONFIRM_P``): no event
        self._fits: list = []  #: (fit, onset, event) of each event, as its correction stands in the model
        self._history: dict = {}  #: id(event) -> [(time from which, fit)]: its correction's versions in the model
        #: id(event) -> (naming sd, the model's slow error, fired channels, baseline) it was named with
        self._named: dict = {}
        self.res_log = self.z_log = None  #: (rows, 6) residual and residual / sd at logged rows (``record``)
        self.pauses: list[list] = []  #: [from_s, to_s or None: still paused] of the law (``law_paused``)

    def start_log(self, rows: int) -> None:
        """Keep the residual of ``rows`` logged rows (``record``)."""
        self.res_log = np.full((rows, 6), np.nan, dtype=np.float32)
        self.z_log = np.full((rows, 6), np.nan, dtype=np.float32)

    def record(self, j: int) -> None:
        """Logged row ``j``: the last sample's residual [N, N m] and residual / sd (NaN while calibrating
        and in contact, where nothing is judged)."""
        if self.res_log is None or j >= len(self.res_log):
            return
        st = self.st
        if st[K.S_MODE] != K.MODE_CALIB and st[K.S_ZONE] == 0.0:
            self.res_log[j] = st[K.S_E:K.S_E + 6]
            self.z_log[j] = st[K.S_Z:K.S_Z + 6]

    # -- per sample -------------------------------------------------------------------------------
    def loop_step(self, t: float, inp: np.ndarray, R_wf: np.ndarray, p_O: np.ndarray, J: np.ndarray) -> None:
        """One control period of the episode loop (``kernel.loop_sample``: the controller's input row
        and the flange kinematics it computed from the encoders)."""
        if self._loop_fn is None:
            import numba

            from kinadapt_nn.controller.core import entry_point

            args = (t, inp, R_wf, p_O, J, self.c, self.st, self.ring)
            K.loop_sample.compile(tuple(numba.typeof(a) for a in args))
            self._loop_fn = entry_point(K.loop_sample, args)
        r = self._loop_fn(t, inp, R_wf, p_O, J, self.c, self.st, self.ring)
        if r == K.R_WINDOW:
            self.name_event()

    def sample(self, t: float, R_ws, p_ws, v_w, w_w, raw, axes_w=None) -> int:
        """One sample (``kernel.sample``); ``axes_w`` (3, nj): the arm's joint axes in the world (the angular
        Jacobian's columns; None: unknown, no ``encoder_offset`` shape). An event named when its window is
        complete. -> the kernel's code."""
        kin = self._kin
        kin[:3], kin[3], kin[4], kin[5] = R_ws, p_ws, v_w, w_w
        if axes_w is not None:
            kin[6:] = np.asarray(axes_w)[:, :len(kin) - 6].T
        r = K.sample(t, kin, raw, self.c, self.st, self.ring)
        if r == K.R_WINDOW:
            self.name_event()
        return r

    # -- what it knows ----------------------------------------------------------------------------
    @property
    def calibrated(self) -> bool:
        return self.st[K.S_MODE] != K.MODE_CALIB

    @property
    def noise_sd(self) -> np.ndarray:
        """(6,) the noise sd per channel [N, N m] (after the calibration)."""
        return self.st[K.S_SD:K.S_SD + 6].copy()

    @property
    def residual(self) -> np.ndarray:
        """(6,) the last sample's residual (reading - model) [N, N m], tool on sensor, s."""
        return self.st[K.S_E:K.S_E + 6]

    @property
    def in_contact(self) -> bool:
        return bool(self.st[K.S_ZONE])

    @property
    def n_bad(self) -> int:
        return int(self.st[K.S_NBAD])

    @property
    def event_open(self) -> bool:
        """Whether an alarm is being named (its window) or an event is open (its shape in the model: to
        the end of the stream)."""
        return self.st[K.S_MODE] == K.MODE_WINDOW or any(e.open for e in self.events)

    def law_paused(self, t: float) -> bool:
        """``monitor.pause_law``: whether the law pauses in the control period at ``t`` [s] -- an event
        open after the samples before it (``event_open``); each pause's interval is kept (``pauses``)."""
        on = self.event_open
        if on and (not self.pauses or self.pauses[-1][1] is not None):
            self.pauses.append([t, None])
        elif not on and self.pauses and self.pauses[-1][1] is None:
            self.pauses[-1][1] = t
        return on

    # -- an event ---------------------------------------------------------------------------------
    def name_event(self, final: bool = False) -> Event | None:
        """An alarm's window is complete: fit the shapes to the residual since the change's onset. While
        the best shape does not win clearly (BIC by ``DECISIVE``) the window grows (up to ``MAX_WINDOWS``
        windows, or ``final``). Then either the last open event's own shape, refitted on everything since
        its onset, explains the new change too (its estimate is updated: a better look at the same
        effect, not a new one), or a new event is reported. Its shape joins the model and the test
        restarts. -> the new event, or None."""
        st = self.st
        if self._alarm is None:
            fired = [i for i in range(6) if st[K.S_GP + i] > self.h or st[K.S_GM + i] > self.h]
            onsets = [st[K.S_TP + i] if st[K.S_GP + i] > self.h else st[K.S_TM + i] for i in fired]
            if st[K.S_RFIRED] > 0.0:  # the rotation test (force channels): its best window's start
                fired = sorted({*fired, 0, 1, 2})
                onsets.append(float(st[K.S_RTON]))
            self._alarm = dict(t=float(st[K.S_TALARM]), fired=fired,
                               t_on=float(min(onsets)) if onsets else float(st[K.S_TALARM]), windows=0,
                               test="rotation" if st[K.S_RFIRED] > 0.0 else "cusum")
        al = self._alarm
        al["windows"] += 1
        t_on, fired = al["t_on"], al["fired"]
        rows = K.ring_rows(st, self.ring, t_on)
        # t_on: the last sample before the change; the first SETTLE_S after it left out (the arm's transient)
        rows = rows[(rows[:, K.G_FREE] > 0.5) & (rows[:, K.G_T] > t_on + SETTLE_S)]
        base = self._baseline(t_on) if BASELINE_S > 0.0 else np.zeros(6)
        if BASELINE_S > 0.0 and len(rows):  # the change, not what the model already missed before it
            rows = rows.copy()
            rows[:, K.G_E:K.G_E + 6] -= base
        if len(rows) < 20 and not final:
            st[K.S_TALARM] = st[K.S_TLAST]  # wait for another window of free-space samples
            return None
        if len(rows) < 8:
            self._log_alarm("too few free samples")
            self._alarm = None
            self._restart()
            return None
        sd = self.noise_sd
        fmask = np.isin(np.arange(6), fired)
        naming_sd = self._naming_sd(t_on)
        f, fits = shapes.best(rows, naming_sd, self.tool, t_on, fmask, slow_sd=self._model_sd(t_on))
        margin = float(fits[1].bic - f.bic) if len(fits) > 1 else np.inf
        unturned = f.shape in POSE_FREE and _turned_deg(rows) < TURN_DEG
        if (margin < DECISIVE or unturned) and al["windows"] < MAX_WINDOWS and not final:
            st[K.S_TALARM] = st[K.S_TLAST]  # not yet clear: look longer
            return None
        self._log_alarm("", f.shape)
        self._alarm = None
        if self._refit_last(rows, shapes.fit(f.shape, rows, sd, self.tool, t_on, fmask)):  # chi^2 in noise sd, as its refit
            self.alarms[-1]["outcome"] = "update"
            self._restart()
            return None
        f = shapes.fit(f.shape, rows, sd, self.tool, t_on, fmask, jackknife=True,
                       model_sd=np.maximum(self._model_sd(t_on, beyond_noise=True), self._left_sd(f, rows, t_on)))
        change = np.max(np.abs(shapes.evaluate(f, rows, self.tool, t_on)), axis=0)  # (6,) [N, N m] within the window
        rel = shapes.relevance(f, self.setup.analysis.relevant_force_N)
        self.alarms[-1]["size_sd"], self.alarms[-1]["size_relevant"] = float(np.max(change / sd)), rel
        sig = shapes.significant(f, CONFIRM_P)
        if not sig or rel < 1.0:  # within the model's own errors, or smaller than the effect's relevant size
            self.alarms[-1]["outcome"] = "not significant" if not sig else "too small"
            self.dismissed += 1
            self._restart()
            return None
        text, est = shapes.describe(f, self.tool, self.frame, float(self.c[K.C_SIGN]))
        named = next(g for g in fits if g.shape == f.shape)  # its fit on the naming sd, as the others'
        ev = Event(al["t"], t_on, [CHANNELS[i] for i in fired], "free space", f.shape, text, est,
                   fits[1].shape if len(fits) > 1 else "", margin, f.rows, float(rows[-1, K.G_T]),
                   float(rows[-1, K.G_T]), ties=shapes.ties(named, fits, rows, naming_sd, self.tool, t_on, fmask))
        self.alarms[-1]["outcome"] = "event"
        self._named[id(ev)] = (naming_sd, self._model_sd(t_on), fmask, base)  # for its end-of-run look
        self._apply(f, t_on, +1.0)
        self._fits.append((f, t_on, ev))
        self._history[id(ev)] = [(ev.t_named_s, f)]
        self._restart()
        self.events.append(ev)
        if self.on_event is not None:
            self.on_event(ev)
        return ev

    def _log_alarm(self, outcome: str, shape: str = "") -> None:
        al = self._alarm
        self.alarms.append({"t_s": al["t"], "onset_s": al["t_on"], "test": al["test"], "shape": shape,
                            "outcome": outcome, "size_sd": float("nan"), "size_relevant": float("nan")})

    def _left_sd(self, f, rows: np.ndarray, t_on: float) -> np.ndarray:
        """(6,) [N, N m] what the fitted shape leaves of the change that persists: the RMS of the fit
        residual's ``MODEL_BLOCK_S`` means over the window (the model's error after the change)."""
        k = max(1, int(round(MODEL_BLOCK_S / self.dt_s)))
        nb = len(rows) // k
        if nb < 3:
            return np.zeros(6)
        r = rows[:nb * k, K.G_E:K.G_E + 6] - shapes.evaluate(f, rows[:nb * k], self.tool, t_on)
        return self._beyond_noise(r.reshape(nb, k, 6).mean(axis=1), k)

    def _naming_sd(self, t_on: float) -> np.ndarray:
        """(6,) [N, N m] the sd each channel's rows are divided by to name a change: the noise sd, widened
        by the model's own slow error before the change. Over the ``MODEL_LOOK_S`` before ``t_on`` the
        residual's ``MODEL_BLOCK_S`` means (k samples each) vary by more than white noise would (``sd^2 /
        k``) where the nominal model misses something that changes with the pose (the declared tool's
        centre of mass: the moment rows); that excess variance, spread over the k samples of a block,
        ``sd^2 + k * excess``, is what a row of that channel carries besides the noise, so a shape is not
        named for fitting the model's own error better (docs/monitor.md). The excess is estimated
        without a test (floored at 0): a channel of noise alone is widened by its chance excess, within
        ``sqrt(chi^2_(n-1) / (n - 1))`` of its sd (n blocks). The noise sd where there are fewer than three
        blocks."""
        k = max(1, int(round(MODEL_BLOCK_S / self.dt_s)))
        sd = self.noise_sd
        rows = K.ring_rows(self.st, self.ring, t_on - MODEL_LOOK_S)
        rows = rows[(rows[:, K.G_FREE] > 0.5) & (rows[:, K.G_T] <= t_on)]
        nb = len(rows) // k
        if nb < 3:
            return sd
        means = rows[:nb * k, K.G_E:K.G_E + 6].reshape(nb, k, 6).mean(axis=1)
        excess = np.maximum(means.var(axis=0, ddof=1) - sd ** 2 / k, 0.0)
        return np.sqrt(sd ** 2 + k * excess)

    def _baseline(self, t_on: float) -> np.ndarray:
        """(6,) [N, N m] the residual's mean over the free samples of the ``BASELINE_S`` before ``t_on``
        (zero when there are fewer than 50): the model's slow error just before the change."""
        rows = K.ring_rows(self.st, self.ring, t_on - BASELINE_S)
        rows = rows[(rows[:, K.G_FREE] > 0.5) & (rows[:, K.G_T] <= t_on)]
        return rows[:, K.G_E:K.G_E + 6].mean(axis=0) if len(rows) >= 50 else np.zeros(6)

    def _model_sd(self, t_on: float, beyond_noise: bool = False) -> np.ndarray:
        """(6,) [N, N m] the model's slow error before a change: the RMS of the residual's
        ``MODEL_BLOCK_S`` means over the free samples of the ``MODEL_LOOK_S`` before ``t_on`` (noise / 10
        when there are too few)."""
        rows = K.ring_rows(self.st, self.ring, t_on - MODEL_LOOK_S)
        rows = rows[(rows[:, K.G_FREE] > 0.5) & (rows[:, K.G_T] <= t_on)]
        k = max(1, int(round(MODEL_BLOCK_S / self.dt_s)))
        nb = len(rows) // k
        if nb < 3:
            return self.noise_sd / 10.0
        means = rows[:nb * k, K.G_E:K.G_E + 6].reshape(nb, k, 6).mean(axis=1)
        return self._beyond_noise(means, k) if beyond_noise else np.sqrt(np.mean(means ** 2, axis=0))

    def _beyond_noise(self, means: np.ndarray, k: int) -> np.ndarray:
        """(6,) [N, N m] the RMS of block means (nb, 6) of ``k`` samples each less what the noise alone puts
        there: ``sqrt(max(mean(means^2) - sd^2 / k, 0))`` per channel (the white noise's own share of a block
        mean, ``sd^2 / k``, is already in the estimate's white-noise covariance; counted again as a constant
        error of the model it would widen the interval by the noise twice)."""
        return np.sqrt(np.maximum(np.mean(means ** 2, axis=0) - self.noise_sd ** 2 / k, 0.0))

    def _apply(self, f, t_on: float, sign: float) -> None:
        """Add (sign +1) or take out (-1) a fitted shape's correction of the model."""
        corr = shapes.correction(f, self.tool, t_on)
        st = self.st
        if f.shape == "ft_bias_drift":  # one drift slot: a drift already there is re-expressed from t_on
            t0 = st[K.S_CORR + K.K_T0]
            if np.isfinite(t0) and t0 != t_on:
                rate = st[K.S_CORR + K.K_RATE:K.S_CORR + K.K_RATE + 6]
                st[K.S_CORR + K.K_CONST:K.S_CORR + K.K_CONST + 6] += rate * (t_on - t0)
            st[K.S_CORR + K.K_T0] = t_on
        st[K.S_CORR:K.S_CORR + K.NCORR] += sign * corr

    def _restart(self) -> None:
        st = self.st
        st[K.S_GP:K.S_GP + 6] = 0.0
        st[K.S_GM:K.S_GM + 6] = 0.0
        st[K.S_TP:K.S_TP + 6] = st[K.S_TLAST]
        st[K.S_TM:K.S_TM + 6] = st[K.S_TLAST]
        K.rotation_reset(st)
        st[K.S_MODE] = K.MODE_WATCH

    def _refit_last(self, rows_new: np.ndarray, f_new) -> bool:
        """Whether the last event's shape, refitted on every free sample since its onset (the ring's),
        explains the residual at least as well as keeping it and adding ``f_new`` (BIC); if so, its
        estimate and the model's correction are updated."""
        if not self._fits:
            return False
        f_old, t0, ev = self._fits[-1]
        rows = K.ring_rows(self.st, self.ring, t0)
        rows = rows[(rows[:, K.G_FREE] > 0.5) & (rows[:, K.G_T] > t0 + SETTLE_S)]
        if len(rows) == 0 or rows[0, K.G_T] > t0 + SETTLE_S + 2.0 * self.dt_s + 1e-9 or f_old.shape == "ft_bias_drift" \
                and f_new.shape != "ft_bias_drift":
            return False  # its onset has left the ring
        y = self._without(ev, rows, t0)
        sd = self.noise_sd
        fmask = np.isin(np.arange(6), [CHANNELS.index(c) for c in ev.channels])
        one = shapes.fit(f_old.shape, y, sd, self.tool, t0, fmask, jackknife=True, model_sd=self._model_sd(t0))
        m = one.rows
        before = y[~np.isin(y[:, K.G_T], rows_new[:, K.G_T])]
        if len(before) == 0:
            return False
        kept = shapes.chi2_of(f_old, before, sd, self.tool, t0) + f_new.chi2
        k_old = len(f_old.p) if f_old.shape != "ft_bias_drift" else 6 + int(fmask.sum())
        if one.chi2 + k_old * np.log(m) > kept + (k_old + _nparams(f_new)) * np.log(m):
            return False
        self._apply(f_old, t0, -1.0)
        self._apply(one, t0, +1.0)
        text, est = shapes.describe(one, self.tool, self.frame, float(self.c[K.C_SIGN]))
        ev.text, ev.estimate, ev.rows, ev.t_named_s = text, est, one.rows, float(rows[-1, K.G_T])
        ev.updates += 1
        self._fits[-1] = (one, t0, ev)
        self._history[id(ev)].append((ev.t_named_s, one))
        if self.on_event is not None:
            self.on_event(ev)
        return True

    def _without(self, ev: Event, rows: np.ndarray, t0: float) -> np.ndarray:
        """Ring rows with the residual as it would be without event ``ev``'s correction (each version of it
        added back over the rows it was in the model)."""
        y = rows.copy()
        hist = self._history[id(ev)]  # (from when, the fit then in the model) of this event's correction
        for i, (t_a, f_a) in enumerate(hist):
            t_b = hist[i + 1][0] if i + 1 < len(hist) else np.inf
            seg = (rows[:, K.G_T] > t_a) & (rows[:, K.G_T] <= t_b)
            y[seg, K.G_E:K.G_E + 6] += shapes.evaluate(f_a, rows[seg], self.tool, t0)
        return y

    def finish(self) -> list[Event]:
        """At the end of the stream: an alarm whose window is still open is named on what there is; then each
        open event gets its end-of-run look (``Event.at_end``)."""
        if self.st[K.S_MODE] == K.MODE_WINDOW:
            self.name_event(final=True)
        for f, t0, ev in self._fits:
            if ev.open and ev.at_end is None:
                ev.at_end = self._end_look(ev, t0)
        return self.events

    def end_rows(self, ev: Event) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """What the end-of-run look of event ``ev`` fits (``_end_look``): (ring rows (n, NCOL + 3 nj): the free
        samples from its onset (after ``SETTLE_S``) to the next event's onset or the end, the residual without
        its own correction less its baseline; the naming sd (6,), the model's slow error (6,) and the fired
        channels (6,) bool it was named with)."""
        t0 = ev.onset_s
        naming_sd, slow_sd, fmask, base = self._named[id(ev)]
        later = [e.onset_s for e in self.events if e.onset_s > t0]
        t_to = min(later) if later else np.inf
        rows = K.ring_rows(self.st, self.ring, t0)
        rows = rows[(rows[:, K.G_FREE] > 0.5) & (rows[:, K.G_T] > t0 + SETTLE_S) & (rows[:, K.G_T] <= t_to)]
        y = self._without(ev, rows, t0)
        y[:, K.G_E:K.G_E + 6] -= base
        return y, naming_sd, slow_sd, fmask

    def _end_look(self, ev: Event, t0: float) -> dict | None:
        """Every shape (``shapes.END_SHAPES``: the live ones and ``encoder_offset``) fitted again on the free
        samples from the event's onset (after ``SETTLE_S``; the ring's oldest where the onset has left it) to the
        next event's onset or the end, the residual without the event's own correction less its baseline, rows
        divided by the sd it was named with: the best live shape and its near-ties among every shape
        (``shapes.end_look``) on everything the run saw of it -- the window the offline diagnosis of the run
        judges (``diagnostics.ownrun.monitor_window``). ``encoder_offset`` is a rival only (it may tie the best,
        it is not named best); its fit is kept under its name (joint, offset, its BIC less the best's; its
        ``delta_bic`` the runner-up live shape's). -> ``Event.at_end``, or None (too few rows)."""
        y, naming_sd, slow_sd, fmask = self.end_rows(ev)
        if len(y) < 20:
            return None
        f, fits, tied = shapes.end_look(y, naming_sd, self.tool, t0, fmask, slow_sd=slow_sd)
        live = [g for g in fits if g.shape in shapes.SHAPES]
        out = {"shape": f.shape, "ties": tied,
               "delta_bic": float(live[1].bic - f.bic) if len(live) > 1 else float("inf"), "rows": int(len(y)),
               "from_s": float(y[0, K.G_T]), "to_s": float(y[-1, K.G_T])}
        for g in fits:
            if g.shape not in shapes.SHAPES:  # a rival only: its fit, for the record
                text, est = shapes.describe(g, self.tool, self.frame, float(self.c[K.C_SIGN]))
                out[g.shape] = {**est, "delta_bic": float(g.bic - f.bic)}
        return out

    def summary(self) -> dict:
        """What summary.json keeps of the monitor."""
        return {"events": [e.as_dict() for e in self.events], "noise_sd": self.noise_sd.tolist(),
                "threshold_sd": self.h, "rotation_threshold": float(self.c[K.C_HROT]), "cusum_k": float(self.c[K.C_K]),
                "false_alarms_per_h": self.mcfg.false_alarms_per_h, "samples_left_out": self.n_bad,
                "alarms_dismissed": self.dismissed, "alarms": self.alarms,
                "alarm_pending": bool(self.st[K.S_MODE] == K.MODE_WINDOW), **self._pause_summary()}

    def _pause_summary(self) -> dict:
        """``monitor.pause_law``: the law's pauses, ``law_paused_s`` [[from, to]] [s] (the control periods
        from ``from`` up to ``to``; one still paused at the end runs to the end of its last period), and
        their total ``law_paused_total_s``."""
        if not self.mcfg.pause_law:
            return {}
        end = float(self.st[K.S_TLAST]) + self.dt_s
        spans = [[round(float(a), 9), round(end if b is None else float(b), 9)] for a, b in self.pauses]
        return {"law_paused_s": spans, "law_paused_total_s": round(float(sum(b - a for a, b in spans)), 9),
                "law_paused_at_end": bool(self.pauses and self.pauses[-1][1] is None)}


def monitor_of_run(cfg, on_event=None) -> Monitor:
    """The monitor of a package run: the set-up its diagnosis uses (``diagnostics.ownrun.setup_of_run``,
    the nominal tool and contact from the run's known config), ``cfg.monitor``, ``cfg.run.dt_s``."""
    from kinadapt_nn.diagnostics.ownrun import setup_of_run

    if on_event is None and cfg.run.progress:  # the console: each event as it is named
        from tqdm import tqdm

        on_event = lambda ev: tqdm.write(f"monitor {ev.line}" + (" (updated)" if ev.updates else ""))  # noqa: E731
    mon = Monitor(setup_of_run(cfg), cfg.monitor, cfg.run.dt_s, on_event)
    if cfg.scene.contact_model == "socket" and cfg.scene.socket_engage == "drive":  # the fixture holds the tip
        mon.c[K.C_ENGAGE] = cfg.start.settle_s  # from the drive start (``sim.socket``), at any depth: contact
    return mon


def _register() -> None:
    from kinadapt_nn.runs.loop import register_monitor

    register_monitor(monitor_of_run)


_register()
