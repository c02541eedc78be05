"""The episode loop: B episodes stepped together; a single episode is a batch of one.

Set-up (:func:`setup`): the episodes' scenes (``sim.scenes.SceneBatch``) and the controller's
kernels on one (B, ...) ``ControllerState`` (from the episodes' own ``Controller`` objects, or
built from the known config alone for summaries). Then per control step (:func:`run`):

1. the sensors' samples, (B, 2n+6) rows [q; qdot; raw F/T] (``SceneBatch.sense_into``);
2. the controller (``controller.core``: one fused kernel call for the adjoint, neural and RBF
   features; other features supply their rows from Python, as ``Controller`` does); with
   ``monitor.enabled`` the live monitor on the same samples and the controller's own flange
   kinematics (``kinadapt_nn.monitor``: never the truth); with ``monitor.pause_law`` the law of the
   next period pauses while the monitor has an event open (``core.K_PAUSED``);
3. the watch (:func:`_watch`: sensor errors, the seat check, peak wrenches, the rank gate);
4. the log (:class:`TraceLog`: every channel of a trace; :class:`SummaryLog`: what a summary needs);
5. the servo set-points and one physics step (``SceneBatch.apply``, ``step``);
6. the stop checks (seated and held, the rank gate, MuJoCo warnings at 10 Hz).

The finish (per-episode results) is the caller's: ``runs.batch``. Truth firewall: the
controller's kernels see the sample rows only; the truth goes from the scenes to the log
(``SceneBatch.truth_into``), never back.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numba as nb
import numpy as np

from kinadapt_nn.config import ExperimentCfg
from kinadapt_nn.controller import core
from kinadapt_nn.controller.controller import (Controller, StepBuffers, feature_consts, generic_step, kernel_parts,
                                               sensor_error_message)
from kinadapt_nn.controller.core import K_ERROR, RANK_GATE
from kinadapt_nn.controller.dense import vcopy
from kinadapt_nn.errors import ConfigError
from kinadapt_nn.known import KnownCfg
from kinadapt_nn.robot import FLANGE_SITE
from kinadapt_nn.runs.build import batch_features, make_controller
from kinadapt_nn.runs.monitor import seat_limits, seat_step
from kinadapt_nn.runs.outcome import sensor_reason, warning_reason
from kinadapt_nn.sensing import channel_metric
from kinadapt_nn.sim import scenes
from kinadapt_nn.sim.adapter import contact_sums
from kinadapt_nn.sim.scenes import SceneBatch

#: one row per episode: what the watch keeps (:func:`_watch`)
WATCH = np.dtype([
    ("active", np.bool_),  # still stepping
    ("error", np.bool_),  # stopped by a sensor error (a dropout longer than max_dropout_s)
    ("breach", np.bool_),  # the rank gate breached
    ("diverged", np.bool_),  # stopped by a sensor error or a MuJoCo warning (the rank gate: ``breach``)
    ("stop_at", np.float64),  # [s] seated: stop at this time (stop_after_seat_s later); inf: not seated
    ("peak_f", np.float64),  # [N] max |f_env| with the drive on
    ("peak_lat", np.float64),  # [N] max |F_lat|
    ("peak_m", np.float64),  # [N m] max |m_env|
    ("lam_since", np.float64),  # min lambda_min(W J_hat J_hat^T W) since the last logged step (inf: none)
    ("lam_min", np.float64),  # its minimum over the episode
    ("breach_t", np.float64),  # [s] the first breach (NaN: none)
    ("n_ctrl", np.int64),  # control steps taken (a sample refused as diverged is one)
    ("n_sim", np.int64),  # physics steps taken
])
#: bits of :func:`_watch`'s result
EV_ERROR, EV_STOP = 1, 2


@nb.njit(cache=True)
def _drive_on(t, b, out, idx, lam_ext, lim, clock, w):
    """Episode ``b`` with the drive on: the seat check (``seat_step``; clock (B, 2) = [since,
    seat_time]), peak wrenches, the rank gate on lambda_min (out's column idx[3], or lam_ext (B,)
    when idx[3] < 0: features not fused). -> EV_STOP when it seated or breached the gate, else 0."""
    i_s, i_w, i_lam = idx[0], idx[1], idx[3]
    ev = 0
    seated = not np.isnan(clock[b, 1])
    seat_step(t, out[b, i_s:i_s + 6], lim[:4], clock[b])
    if not seated and not np.isnan(clock[b, 1]):
        w[b].stop_at = t + lim[4]
        ev = EV_STOP
    fm = math.sqrt(out[b, i_w] ** 2 + out[b, i_w + 1] ** 2 + out[b, i_w + 2] ** 2)
    mm = math.sqrt(out[b, i_w + 3] ** 2 + out[b, i_w + 4] ** 2 + out[b, i_w + 5] ** 2)
    w[b].peak_f = max(w[b].peak_f, fm)
    w[b].peak_lat = max(w[b].peak_lat, math.hypot(out[b, i_s + 1], out[b, i_s + 2]))
    w[b].peak_m = max(w[b].peak_m, mm)
    lm = out[b, i_lam] if i_lam >= 0 else lam_ext[b]
    w[b].lam_since = min(w[b].lam_since, lm)
    if lm < w[b].lam_min:
        w[b].lam_min = lm
        if lm < RANK_GATE and np.isnan(w[b].breach_t):
            w[b].breach_t = t
    if lm < RANK_GATE:
        w[b].breach = True
        ev = EV_STOP
    return ev


@nb.njit(cache=True)
def _watch(t, out, idx, lam_ext, lim, ks, clock, w):
    """After the controller's step, per episode ``w`` (B,) of :data:`WATCH`: an active one's
    control step counted; a sensor error (``ks`` (B, .) counters' K_ERROR) stops it (EV_ERROR);
    with the drive on (out's column idx[2] > 0) :func:`_drive_on`; its physics step counted.
    idx = [i_s, i_w, i_rho, i_lam] columns of out (B, nout); lim = [d_seat, max |F_lat|, max |M|,
    hold_s, stop_after_seat_s]. -> the EV_* bits of what happened."""
    ev = 0
    for b in range(out.shape[0]):
        if not w[b].active:
            clock[b, 0] = np.nan
            continue
        w[b].n_ctrl += 1
        if ks[b, K_ERROR] != 0:
            w[b].active = False
            w[b].error = w[b].diverged = True
            clock[b, 0] = np.nan
            ev |= EV_ERROR
            continue
        if out[b, idx[2]] > 0.0:
            ev |= _drive_on(t, b, out, idx, lam_ext, lim, clock, w)
        else:
            clock[b, 0] = np.nan
        w[b].n_sim += 1
    return ev


@nb.njit(cache=True)
def _log_rows(j, t, every_one, active, src, dst):
    """Logged row ``j`` at time ``t`` [s] of every episode (``every_one``) or the ``active`` (B,)
    ones: src = (out (B, nout), q_ref (B, n), Phi_f^T (B, pm), lambda_min since the last row (B,),
    true tip (B, 3)) into dst = (t (R, B), out (R, B, nout), q_ref (R, B, n), Phi_f^T (R, B, pm),
    lambda_min (R, B), tip (R, B, 3)); the lambda_min since the last row restarts (inf)."""
    out, q_ref, phi, lam, tip = src
    t_log, out_log, q_log, phi_log, lam_log, tip_log = dst
    for b in range(out.shape[0]):
        if every_one or active[b]:
            t_log[j, b] = t
            vcopy(out_log[j, b], out[b])  # (element loops: a slice assignment compiles numba's broadcasting, ~2 s)
            vcopy(q_log[j, b], q_ref[b])
            vcopy(phi_log[j, b], phi[b])
            lam_log[j, b] = lam[b]
            lam[b] = np.inf
            vcopy(tip_log[j, b], tip[b])


@nb.njit(cache=True)
def _log_sample(j, every_one, active, inp, io):
    """The samples ``inp`` (B, 2n+6) as given into row ``j`` of ``io`` (R, B, >= 2n+6), of every
    episode (``every_one``) or the ``active`` (B,) ones."""
    for b in range(inp.shape[0]):
        if every_one or active[b]:
            vcopy(io[j, b, :inp.shape[1]], inp[b])


# a compile phase is cold (and shown) while these are not in numba's cache either
core.cache_probe((_watch, _log_rows, _log_sample, *scenes.KERNELS))

#: probed kernels that a warm-up's two free-space control steps (``batch.compile_loop``) do not
#: call -- the contact truth's sums run at a contact only -- with the numba types they are called
#: with; left out, the cache stays "cold" after the warm-up and every later phase of the process
#: counted as a (near-zero) compile of its own
UNREACHED_BY_WARMUP = ((contact_sums, (nb.float64[::1], nb.int64, nb.int64, nb.float64, nb.float64, nb.float64,
                                       nb.float64)),)


def compile_unreached() -> None:
    """Compile (or load from numba's cache) :data:`UNREACHED_BY_WARMUP` for their types."""
    for fn, sig in UNREACHED_BY_WARMUP:
        fn.compile(sig)


#: the live monitor's factory, ``cfg -> monitor`` (``kinadapt_nn.monitor.monitor.monitor_of_run``), registered by
#: that module when it is imported (it sits above this layer: it uses the diagnosis's model); the loop calls a
#: monitor's ``loop_step(t, inp, R_wf, p_O, J)`` each control period and ``record(row)`` at logged rows
MONITOR_FACTORY: list = [None]


def register_monitor(factory) -> None:
    """Register the live monitor's factory (``MONITOR_FACTORY``)."""
    MONITOR_FACTORY[0] = factory


def new_controllers(cfgs: list[ExperimentCfg], ctrls: list) -> list:
    """``ctrls`` with each None entry replaced by a new controller of its config, its kernels
    compiled (or loaded from the cache); inside the caller's compile phase."""
    out = list(ctrls)
    for i, (c, k) in enumerate(zip(cfgs, out)):
        if k is None:
            out[i] = make_controller(c)
            out[i].compile_kernels()
    return out


def _entry(fn, args):
    """``fn``'s compiled entry for the types of ``args`` (compiled or loaded from the cache first)."""
    fn.compile(tuple(nb.typeof(a) for a in args))
    return core.entry_point(fn, args)


@dataclass
class Kernels:
    """The controller side of B episodes: the batched kernels' constants, state and buffers."""

    ctrls: list[Controller] | None  #: the episodes' own controllers (traces), or None (summaries)
    feats_b: list  #: (B,) features objects (shared where they keep no per-episode state)
    chain: object  #: the bare arm's kinematic chain (``core.arm_chain``)
    cs: core.CoreConsts  #: constants shared by every episode
    law: object  #: the law's LawSpec
    lay: core.Layout  #: n, m, p and the state/out layout
    st: core.ControllerState  #: (B, ...) filter and law state
    fx: np.ndarray  #: the in-kernel features' constants

    def __post_init__(self) -> None:
        B = self.st.x.shape[0]
        self.bufs = StepBuffers.zeros(self.lay, B)  # the kernels' buffers (inp: the samples [q; qdot; raw F/T])
        self.inp, self.p_O, self.R, self.J, self.reg, self.ext_J, self.out = self.bufs
        self.ob = {k: self.out[:, o:o + size] for k, (o, size) in self.lay.out_blocks.items()}
        self.lam_ext = np.full(B, np.inf)  # lambda_min from Python (features not fused)
        self.compile_s = 0.0  # [s] the one-time compile of new controllers' kernels (a cold cache), else 0
        self.W = self.ctrls[0].W if self.ctrls else None  # the channel metric (the rank gate from Python)
        st, cs = self.st, self.cs
        #: the fused step kernel's arguments after t (its buffers, bound once)
        self._fused_args = (self.inp, self.chain, self.p_O, self.R, self.J, self.reg, st.x, st.k, self.lay.arr, cs.c,
                            cs.mats, cs.pv, cs.lc, cs.law_fn, cs.seg, self.fx, self.out)
        fused = core.FUSED.get(int(cs.c[core.FEAT]))  # the step kernel of features computed in it
        self.fused = None if fused is None else _entry(fused, (0.0, *self._fused_args))

    def control(self, t: float, active: np.ndarray) -> None:
        """One control step of every active episode at time ``t`` [s] on the samples in ``inp``."""
        if self.fused is not None:
            self.fused(t, *self._fused_args)
        else:
            self._generic_step(t, active)

    def _generic_step(self, t: float, active: np.ndarray) -> None:
        """Features not fused: the intake, then ``controller.generic_step`` (as ``Controller`` steps
        them) and the rank gate of each active episode with the drive on, from Python."""
        st = self.st
        core.intake_kernel(self.inp, st.x, st.k, self.lay.arr, self.cs.c)
        generic_step(t, self.chain, self.cs, self.lay, st, self.bufs, self.feats_b, active)
        i_rho = self.lay.out_blocks["rho"][0]
        for b in np.flatnonzero(active & (self.out[:, i_rho] > 0.0) & (st.k[:, K_ERROR] == 0)):
            self.lam_ext[b] = self.bufs.rank_margin(b, self.W, self.feats_b[b], st.theta[b])


_SHARED_RUN = ("duration_s", "log_every", "stop_after_seat_s")  #: run settings a traced batch shares


def _known_of(cfgs: list[ExperimentCfg]) -> KnownCfg:
    known = KnownCfg.of(cfgs[0])
    for c in cfgs[1:]:
        if KnownCfg.of(c) != known:
            raise ConfigError("a batch shares every KNOWN setting (sensing, control, adaptation, features, bore pose); "
                              "these configs differ in one -- run them as separate batches")
    return known


def _controllers(cfgs: list[ExperimentCfg], ctrls: list, progress: bool) -> tuple[list[Controller], float]:
    """The episodes' controllers (new ones where None), compiled, checked to share every constant
    the batched kernels read once for all rows (else ``ConfigError``). -> (the controllers, the
    one-time compile of the new ones [s]: 0 when their kernels were cached)."""
    ctrls = list(ctrls)
    compile_s = 0.0
    for i, (c, k) in enumerate(zip(cfgs, ctrls)):
        if k is None:
            with core.compiling(progress) as phase:
                ctrls[i] = make_controller(c)
                ctrls[i].compile_kernels()
            compile_s += phase.wall_s if phase.cold else 0.0
        ctrls[i].compile_kernels(progress)
    c0, k0 = cfgs[0], ctrls[0]
    fx0 = feature_consts(k0.features)
    for c, k in zip(cfgs[1:], ctrls[1:]):
        for f in _SHARED_RUN:
            if getattr(c.run, f) != getattr(c0.run, f):
                raise ConfigError(f"a batch with traces shares run.{f}; these configs differ in it -- run them as "
                                  "separate batches")
        a, b = k.consts, k0.consts
        same = all(np.array_equal(x, y) for x, y in ((a.c, b.c), (a.mats, b.mats), (a.pv, b.pv), (a.lc, b.lc),
                                                     (a.seg, b.seg), (feature_consts(k.features), fx0)))
        if not same or k.layout.arr.tolist() != k0.layout.arr.tolist() or k.mode != k0.mode:
            raise ConfigError("these controllers differ in a constant the batched kernels share (features, law, "
                              "bore, gains) -- run them as separate batches")
    return ctrls, compile_s


def kernels_of_controllers(cfgs: list[ExperimentCfg], ctrls: list, progress: bool = False) -> Kernels:
    """The kernels stepping the episodes' own controllers (None entries: new ones) from their
    current state; ``Kernels.ctrls`` gets the state back at the finish (``Controller.set_state``)."""
    ctrls, compile_s = _controllers(cfgs, ctrls, progress)
    k0 = ctrls[0]
    st = core.ControllerState(k0.layout, len(ctrls))
    for b, k in enumerate(ctrls):
        st.x[b], st.k[b] = k.state.x[0], k.state.k[0]
    kn = Kernels(ctrls, [k.features for k in ctrls], k0.chain, k0.consts, k0.law_spec, k0.layout, st,
                 feature_consts(k0.features))
    kn.compile_s = compile_s
    return kn


def kernels_of_known(cfgs: list[ExperimentCfg]) -> Kernels:
    """The kernels of new controllers built from the known config alone (no ``Controller``
    objects: a sweep's summaries), the rank gate as a Cholesky test (lambda_min only on a breach)."""
    known = _known_of(cfgs)
    # controller side: the bare arm's kinematic chain (forward kinematics in the kernel, from encoders)
    arm_model = mujoco.MjModel.from_xml_path(str(known.arm_mjcf))
    site = mujoco.mj_name2id(arm_model, mujoco.mjtObj.mjOBJ_SITE, FLANGE_SITE)
    built = batch_features(cfgs)  # the known side is shared; theta0 may be per episode (experiment design)
    feats = built[0][0]
    # effect columns keep per-episode state (what the last step observed): one features object each
    feats_b = [f for f, _th in built] if known.model_effects else [feats] * len(cfgs)
    kp = kernel_parts(known, feats, arm_model, site, len(cfgs))
    kp.state.theta[:] = np.array([th for _f, th in built])
    kp.law.reset(kp.consts.lc, kp.law_state, False)
    kp.consts.c[core.RANK_ON] = 2.0  # the rank gate every step as a Cholesky test; lambda_min itself only on a breach
    kn = Kernels(None, feats_b, kp.chain, kp.consts, kp.law, kp.layout, kp.state, kp.fx)
    kn.W = channel_metric(known.sensing)
    return kn


@dataclass
class Loop:
    """Everything the loop steps: the scenes, the kernels, the watch and its constants."""

    cfgs: list[ExperimentCfg]
    world: SceneBatch
    kn: Kernels
    n_steps: int  #: control steps at most (run.duration_s / dt)
    dt: float  #: [s] control period = physics step

    def __post_init__(self) -> None:
        B, lay, su, run = len(self.cfgs), self.kn.lay, self.cfgs[0].success, self.cfgs[0].run
        self.watch = np.zeros(B, WATCH)
        self.watch["active"] = True
        self.watch[["stop_at", "lam_since", "lam_min"]] = (np.inf, np.inf, np.inf)
        self.watch["breach_t"] = np.nan
        self.clock = np.full((B, 2), np.nan)  # per episode [since, seat_time] (runs.monitor.seat_step)
        self.lim = np.r_[seat_limits(su), run.stop_after_seat_s]  # the seat check's, and the stop after a seat
        fused = self.kn.fused is not None
        self.idx = np.array([lay.out_blocks["s"][0], lay.out_blocks["w_env"][0], lay.out_blocks["rho"][0],
                             lay.out_blocks["lam_min"][0] if fused else -1])
        self.reason: list[str | None] = [None] * B  #: what stopped each diverged episode
        self.every_one = True  #: every episode still running
        self.ctrl_log: np.ndarray | None = None  #: (n_steps, B, n) servo set-points, when recorded
        self.watch_fn = _entry(_watch, self._watch_args(0.0))
        #: the live monitors (``kinadapt_nn.monitor``) of the episodes with ``monitor.enabled``: (b, Monitor)
        self.monitors: list = []
        for b, c in enumerate(self.cfgs):
            if c.monitor.enabled:
                if MONITOR_FACTORY[0] is None:
                    raise ConfigError("monitor.enabled: the live monitor is not loaded; import kinadapt_nn.monitor."
                                      "monitor first (it registers itself with the episode loop; kinadapt online "
                                      "--monitor does)")
                self.monitors.append((b, MONITOR_FACTORY[0](c)))
        #: the monitors whose events pause their episode's law (``monitor.pause_law``): (b, Monitor)
        self.pausing = [(b, mon) for b, mon in self.monitors if self.cfgs[b].monitor.pause_law]

    def _watch_args(self, t: float) -> tuple:
        kn = self.kn
        return t, kn.out, self.idx, kn.lam_ext, self.lim, kn.st.k, self.clock, self.watch


def setup(cfgs: list[ExperimentCfg], ctrls: list | None, *, traces: bool, nthread: int = 1,
          progress: bool = False) -> Loop:
    """The loop of the episodes ``cfgs``: their scenes (a persistent batch with ``traces``, for the
    contact truth, or with a live monitor: a batch that is not persistent hands each episode's first
    F/T sample without the tool's weight, which would enter the monitor's noise calibration --
    docs/monitor.md), the controllers (``ctrls``: the episodes' own, None
    entries new; None: built from the known config, summaries only)."""
    _known_of(cfgs)
    persistent = True if traces or any(c.monitor.enabled for c in cfgs) else None
    world = SceneBatch(cfgs, nthread, persistent=persistent)
    kn = kernels_of_controllers(cfgs, ctrls, progress) if ctrls is not None else kernels_of_known(cfgs)
    dt = cfgs[0].run.dt_s
    return Loop(cfgs, world, kn, round(cfgs[0].run.duration_s / dt), dt)


class TraceLog:
    """Every ``every``-th step's raw logs of B episodes, (n_rec, B, ...) each: what
    ``runs.outcome.EpisodeLogs`` holds per episode (its arrays are the columns ``[:, b]``)."""

    def __init__(self, lp: Loop, every: int, keep_phi: bool) -> None:
        lay, B = lp.kn.lay, len(lp.cfgs)
        n, m, p = lay.n, lay.m, lay.p
        n_rec = lp.n_steps // every + 1
        for _b, mon in lp.monitors:
            mon.start_log(n_rec)
        self.every, self.lp, self.n_in = every, lp, 2 * n + 6
        self.t = np.zeros((n_rec, B))
        self.out = np.zeros((n_rec, B, lay.nout))
        self.io = np.zeros((n_rec, B, 3 * n + 6))  # q, qdot, wrench (raw, as given), q_ref
        self.phi = np.zeros((n_rec, B, p * m)) if keep_phi else None
        phi_log = self.phi if keep_phi else np.zeros((n_rec, B, 0))
        self.tip = np.zeros((n_rec, B, 3))
        self.truth = np.zeros((n_rec, B, 4))  # depth (from the tip at the finish), face, bore, normal force
        self.lam = np.full((n_rec, B), np.inf)
        self.f0 = lay.x_blocks["filt"][0] + 2 * m  # Phi_f^T rows of the state (truth_bias_w, evaluation only)
        self.pm = p * m
        # the sources and the logs, bound once (views): out rows, q_ref, Phi_f^T, lambda_min since the last row
        kn = lp.kn
        self._inp, self._world, self._active = kn.inp, lp.world, lp.watch["active"]
        phi_src = kn.st.x[:, self.f0:self.f0 + self.pm] if keep_phi else kn.st.x[:, :0]
        self._src = (kn.out, kn.st.q_ref, phi_src, lp.watch["lam_since"], lp.world.tip_w_m)
        self._dst = (self.t, self.out, self.io[:, :, self.n_in:], phi_log, self.lam, self.tip)
        self._log_rows = _entry(_log_rows, (0, 0.0, True, self._active, self._src, self._dst))
        self._log_sample = _entry(_log_sample, (0, True, self._active, self._inp, self.io))
        self._contact = self.truth[:, :, 1:]  # [face, bore, normal force] of each row

    def sample(self, j: int, rows) -> None:
        """Row ``j``: the samples as given (before any dropout hold), of episodes ``rows``."""
        self._log_sample(j, isinstance(rows, slice), self._active, self._inp, self.io)

    def step(self, j: int, t: float, rows) -> None:
        """Row ``j`` at time ``t`` [s]: the controller's out row, q_ref, the law's filtered regressor,
        lambda_min since the last row and the truth (``SceneBatch.truth_into``: the true tip, from its
        live view ``tip_w_m``, and the contacts), of episodes ``rows``."""
        self._log_rows(j, t, isinstance(rows, slice), self._active, self._src, self._dst)
        self._world.contacts_into(rows, self._contact[j])


class SummaryLog:
    """Every 10th step's sensor vector and wrench of B episodes: what ``classify_failure`` needs."""

    every = 10

    def __init__(self, lp: Loop) -> None:
        self.lp = lp
        self.t, self.s, self.w = [], [], []

    def sample(self, j: int, rows) -> None:
        """(nothing: a summary needs no samples)"""

    def step(self, j: int, t: float, rows) -> None:
        ob = self.lp.kn.ob
        self.t.append(t)
        self.s.append(ob["s"].copy())
        self.w.append(ob["w_env"].copy())


def _sensor_errors(lp: Loop, t: float) -> None:
    """The reasons of the episodes a sensor error stopped at ``t`` [s]; the stopped rows marked done."""
    st = lp.kn.st
    for b in np.flatnonzero(lp.watch["error"]):
        if lp.reason[b] is None:
            lp.reason[b] = sensor_reason(sensor_error_message(t, int(st.k[b, core.K_BAD_RUN])))
    lp.every_one = False


def _stop_checks(lp: Loop, k: int, t: float) -> float:
    """After step ``k`` (time now ``t`` [s]): seated episodes past their stop time and those that
    breached the rank gate stop; at 10 Hz, those MuJoCo warned about (divergence). Stopped rows
    are marked done for the kernels. -> the next stop time of a running episode [s] (inf: none
    seated), NaN when every episode has stopped."""
    w = lp.watch
    active = w["active"]  # a view
    active &= (t < w["stop_at"]) & ~w["breach"]
    if k % 100 == 0:  # divergence watch at 10 Hz: MuJoCo warnings
        warned = lp.world.warned(active)
        for b in np.flatnonzero(warned):
            lp.reason[b] = warning_reason(t)
        w["diverged"] |= warned
        active &= ~warned
    if not (lp.every_one and active.all()):
        lp.every_one = False
        lp.kn.st.k[~active, core.K_DONE] = 1  # the kernels skip episodes that have stopped
        if not active.any():
            return math.nan
    return float(w["stop_at"][active].min())


def run(lp: Loop, log, bar=None) -> int:
    """Step every episode until each has stopped or the duration is up, logging into ``log``
    (:class:`TraceLog` or :class:`SummaryLog`); ``bar``: a tqdm bar of the steps, or None.
    -> control steps taken (the longest episode's)."""
    world, kn = lp.world, lp.kn
    active = lp.watch["active"]  # a view: the watch and the stop checks update it
    q_ref, qdot_ref = kn.st.q_ref, kn.ob["qdot_ref"]
    watch, wargs = lp.watch_fn, lp._watch_args(0.0)[1:]
    every, dt, t, k = log.every, lp.dt, 0.0, 0
    next_stop = math.inf
    for k in range(lp.n_steps):
        world.sense_into(t, kn.inp, active)
        logged = k % every == 0
        rows = slice(None) if lp.every_one else active
        if logged:
            log.sample(k // every, rows)
        for b, mon in lp.pausing:  # monitor.pause_law: the law pauses while an event is open (its samples so far)
            kn.st.k[b, core.K_PAUSED] = mon.law_paused(t) if active[b] else 0
        kn.control(t, active)
        for b, mon in lp.monitors:  # exactly what the controller received, and its own kinematics
            if active[b]:
                mon.loop_step(t, kn.inp[b], kn.R[b], kn.p_O[b], kn.J[b])
                if logged:
                    mon.record(k // every)
        ev = watch(t, *wargs)
        if ev & EV_ERROR:
            _sensor_errors(lp, t)
            rows = active
        if logged:
            log.step(k // every, t, rows)
        world.apply(q_ref, qdot_ref, active)
        if lp.ctrl_log is not None:
            lp.ctrl_log[k] = world.ctrl
        world.step(t, active, lp.every_one)
        t = t + dt  # accumulated as mj_step does (d.time += dt)
        if bar is not None and k % 250 == 0:
            bar.update(250 if k else 1)
        if ev or t >= next_stop or k % 100 == 0:
            next_stop = _stop_checks(lp, k, t)
            if math.isnan(next_stop):  # every episode has stopped
                break
    return k + 1
