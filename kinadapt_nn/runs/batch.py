"""Many episodes stepped together: ``mujoco.batch.Batch`` physics + the controller's kernels.

The controller is ``kinadapt_nn.controller.core`` -- the same kernels ``Controller.step`` runs at
B = 1 -- on (B, ...) state, so the per-step maths exists once. The truth firewall holds the same
way: the controller's kinematics come from its own model of the *bare arm* fed with the
encoder readings (forward kinematics of the bare arm's chain, in the kernel); the scene batch only
supplies encoders and raw F/T readings.

Every law (kalman by default), the rigid loop, dither, the excitation program and the
sensor-side rank gate run as in the single episode; the adjoint and the neural basis are fused in
their step kernels (``core.FUSED``: adjoint, neural basis, RBF), other features (library effect
columns, ``model.effects``, included: one features object per episode, since they keep state)
supply their rows from Python per episode, as ``Controller`` does. The truth side runs per
episode as ``PegInHoleSim`` does: hidden sensor effects and simulated sensor faults on each
sample (``sim.effects.SensorEffects``, ``sim.faults.SensorFaults``), the socket contact model's
wrench (``sim.socket.socket_step`` on the rows of the bound arrays), hidden effects with a
truth-side knob in each episode's model. Stepping each model with ``mj_step`` as the single
episode does, a batch episode reproduces ``run_episode`` exactly (``tests/controller/test_core.py``,
``tests/runs/test_batch.py``). :func:`run_batch` gives summaries only (``kinadapt sweep``);
:func:`run_episodes` each episode's whole trace and summary, as ``run_episode`` gives them, from
the episodes' own controllers (``kinadapt compare``): it logs what the single loop logs, the
truth from the batch's bound buffers (the true tip, MuJoCo's contact sensor on the peg <-> block
contacts) and ends each episode in the single episode's post-processing
(``runs.episode.episode_result``).
"""

from __future__ import annotations

import functools
import math
import time
from typing import NamedTuple

import mujoco
import mujoco.batch
import numba as nb
import numpy as np

from kinadapt_nn.controller import core
from kinadapt_nn.config import ExperimentCfg
from kinadapt_nn.controller.controller import Controller, core_consts, feature_consts, rank_margin, sensor_error_message
from kinadapt_nn.controller.laws.base import law_state
from kinadapt_nn.controller.core import RANK_GATE
from kinadapt_nn.runs.episode import (EpisodeLogs, EpisodeResult, episode_result, rank_breach_reason, sensor_reason,
                                      warning_reason)
from kinadapt_nn.runs.monitor import SeatMonitor, classify_failure, seat_step
from kinadapt_nn.runs.build import make_controller, make_features
from kinadapt_nn.runs.build import one_blas_thread
from kinadapt_nn.errors import ConfigError
from kinadapt_nn.features import features_spec
from kinadapt_nn.features.base import KinState
from kinadapt_nn.known import KnownCfg
from kinadapt_nn.sensing import channel_metric
from kinadapt_nn.robot import FLANGE_SITE, SERVO_KP, SERVO_KV
from kinadapt_nn.sim.adapter import PegInHoleSim, SensorSample
from kinadapt_nn.sim.faults import SensorFaults
from kinadapt_nn.sim.socket import socket_step


class BatchResult(NamedTuple):
    summaries: list[dict]  #: per episode: success, seat_time_s, failure, forces, offset error
    steps: int  #: control steps taken (the longest episode)
    sim_steps: int  #: sum over episodes of the physics steps actually simulated
    wall_s: float  #: wall time of the stepping loop
    setup_s: float  #: wall time to build models and start poses
    theta_final: np.ndarray | None = None  #: (B, p) the controllers' final estimates
    ctrl_log: np.ndarray | None = None  #: (steps, B, n) servo set-points, when asked (record_ctrl)


def _known_of(cfgs: list[ExperimentCfg]) -> KnownCfg:
    known = KnownCfg.of(cfgs[0])
    for c in cfgs[1:]:
        if KnownCfg.of(c) != known:
            raise ConfigError("a batch shares every KNOWN setting (sensing, control, adaptation, features, bore pose); "
                              "these configs differ in one -- run them as separate batches")
    return known


def batch_scene(cfgs: list[ExperimentCfg], nthread: int = 1, persistent: bool | None = None):
    """One ``mujoco.batch.Batch`` of the episodes' scenes (per-episode tool models), every arm at
    its start pose and at rest, servo set-points there. ``persistent`` (default: nthread > 1):
    each episode keeps its whole MjData (contacts, warnings: ``get_data``). -> (sims, scene, qpos,
    qvel, ctrl): the PegInHoleSim per episode (models, ids, truth side) and the batch's bound (B, .)
    buffers."""
    sims = [PegInHoleSim(c) for c in cfgs]
    scene = mujoco.batch.Batch(sims[0].model, len(cfgs), nthread, nthread > 1 if persistent is None else persistent)
    try:
        scene.set_models([s.model for s in sims])
    except mujoco.FatalError as exc:
        raise ConfigError("a batch shares the scene's structure (contact model, chamfer, the friction reference "
                          "scene.contact_friction_timeconst_s on or off, hidden effects); these configs differ in it -- "
                          f"run them as separate batches ({exc})") from None
    ids = sims[0].ids
    qpos, qvel, ctrl_b = scene.bind("qpos"), scene.bind("qvel"), scene.bind("ctrl")
    q0 = np.array([s.q_start for s in sims])
    qpos[:, ids.qpos_adr] = q0
    qvel[:] = 0.0
    ctrl_b[:] = q0
    scene.forward()
    return sims, scene, qpos, qvel, ctrl_b


@nb.njit(cache=True)
def _gather(qpos, qvel, sens, qadr, vadr, fadr, inp):
    """The controller's input rows [q; qdot; raw F/T] (B, 2n+6) from the batch's buffers."""
    n = qadr.shape[0]
    for b in range(inp.shape[0]):
        for j in range(n):
            inp[b, j] = qpos[b, qadr[j]]
            inp[b, n + j] = qvel[b, vadr[j]]
        for j in range(6):
            inp[b, 2 * n + j] = sens[b, fadr[j]]


@nb.njit(cache=True)
def _monitor(t, out, i_s, i_w, i_rho, i_lam, lam_ext, lim, active, clock, stop_at, peaks, lam, breach):
    """Per episode with the drive on: the seat check (``runs.monitor.seat_step``, clock (B, 2) =
    [since, seat_time]), peak wrenches and the rank gate on lambda_min (out's column ``i_lam``,
    or ``lam_ext`` (B,) when i_lam < 0: features not fused). lim = [d_seat, max |F_lat|, max |M|,
    hold_s, stop_after_seat_s]; peaks (B, 3) = [max |f_env|, max |F_lat|, max |m_env|]; lam (B, 3)
    = [minimum since the last logged step, minimum of the episode, first breach time (NaN: none)]
    as ``run_episode`` keeps them."""
    for b in range(out.shape[0]):
        if not (active[b] and out[b, i_rho] > 0.0):
            clock[b, 0] = np.nan
            continue
        seated = not np.isnan(clock[b, 1])
        seat_step(t, out[b, i_s:i_s + 6], lim[:4], clock[b])
        if not seated and not np.isnan(clock[b, 1]):
            stop_at[b] = t + lim[4]
        fm = math.sqrt(out[b, i_w] ** 2 + out[b, i_w + 1] ** 2 + out[b, i_w + 2] ** 2)
        mm = math.sqrt(out[b, i_w + 3] ** 2 + out[b, i_w + 4] ** 2 + out[b, i_w + 5] ** 2)
        peaks[b, 0] = max(peaks[b, 0], fm)
        peaks[b, 1] = max(peaks[b, 1], math.hypot(out[b, i_s + 1], out[b, i_s + 2]))
        peaks[b, 2] = max(peaks[b, 2], mm)
        lm = out[b, i_lam] if i_lam >= 0 else lam_ext[b]
        if lm < lam[b, 0]:
            lam[b, 0] = lm
        if lm < lam[b, 1]:
            lam[b, 1] = lm
            if lm < RANK_GATE and np.isnan(lam[b, 2]):
                lam[b, 2] = t
        if lm < RANK_GATE:
            breach[b] = True


def _bound(fn, args):
    """``fn`` compiled (or loaded from numba's cache) for the types of ``args``, and its compiled
    entry (``core.entry_point``): for arguments whose types never change in the loop."""
    fn.compile(tuple(nb.typeof(a) for a in args))
    return core.entry_point(fn, args)


def _sensor_side(t: float, row: np.ndarray, n: int, sensor_fx, faults) -> None:
    """One episode's sample ``row`` = [q; qdot; raw F/T] (2n+6,), in place, as the single episode
    reads it: hidden sensor effects on the wrench (``PegInHoleSim.sense``), then the simulated
    faults (``SensorFaults``: quantisation, bias, noise, saturation, dropout, latency)."""
    w = row[2 * n:]
    if sensor_fx is not None:
        sensor_fx(t, w)
    if faults is not None:
        o = faults(t, SensorSample(row[:n].copy(), row[n:2 * n].copy(), w.copy()))
        row[:n], row[n:2 * n], row[2 * n:] = o.q_rad, o.qdot_rad_s, o.wrench_raw_f


def run_batch(cfgs: list[ExperimentCfg], nthread: int = 2, record_ctrl: bool = False) -> BatchResult:
    """Run len(cfgs) episodes together, summaries only. All cfgs share every KNOWN setting
    (sensing, control, adaptation, success, bore pose) and differ in hidden truth (tool, start,
    seed). BLAS at one thread meanwhile (``runs.build.one_blas_thread``)."""
    with one_blas_thread():
        return _run_batch(cfgs, nthread, record_ctrl)


def run_episodes(cfgs: list[ExperimentCfg], ctrls: list | None = None, keep_regressor: bool = False,
                 nthread: int = 1) -> list[EpisodeResult]:
    """``run_episode(cfg, ctrl=ctrl, keep_regressor=...)`` for every (cfg, ctrl) pair, stepped
    together: one batched physics (a persistent ``mujoco.batch.Batch``, which keeps each episode's
    contacts for the truth logs) and the controllers' batched kernels. Each result -- trace and
    summary -- is what ``run_episode`` gives to the last bit (``tests/runs/test_batch.py``), but
    ``wall_time_s``: the episode's share of the batch's wall time (set-up and loop, in proportion
    to its physics steps). ``ctrls``: controllers to step from their current state (a work cell
    carries them from one insertion to the next), None or None entries for new ones; each ends in
    the state its single episode leaves. The cfgs share every KNOWN setting and ``run.duration_s``,
    ``run.log_every``, ``run.stop_after_seat_s`` (else a ``ConfigError`` saying which)."""
    wall0 = time.perf_counter()
    with one_blas_thread():
        with core.compiling() as phase:  # a cold cache's one-time compile, reported apart from the wall time
            ctrls = [k if k is not None else make_controller(c) for c, k in zip(cfgs, ctrls or [None] * len(cfgs))]
            for k in ctrls:
                k.compile_kernels()
        compile_s = phase.wall_s if phase.cold else 0.0
        episodes = _run_batch(cfgs, nthread, False, ctrls=ctrls, traces=True, keep_regressor=keep_regressor,
                              wall0=wall0 + compile_s).episodes
    for e in episodes:
        e.summary["compile_time_s"] = compile_s  # as run_episode's
    return episodes


_SHARED_RUN = ("duration_s", "log_every", "stop_after_seat_s")  #: run settings a traced batch shares


def _controllers(cfgs: list[ExperimentCfg], ctrls: list) -> list[Controller]:
    """The episodes' controllers (new ones where None), compiled, checked to share every constant
    the batched kernels read once for all rows (else ``ConfigError``)."""
    ctrls = [k if k is not None else make_controller(c) for c, k in zip(cfgs, ctrls)]
    for k in ctrls:
        k.compile_kernels()
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
    return ctrls


class _Run(NamedTuple):
    batch: BatchResult
    episodes: list[EpisodeResult] | None


def _run_batch(cfgs: list[ExperimentCfg], nthread: int, record_ctrl: bool, ctrls: list | None = None,
               traces: bool = False, keep_regressor: bool = False, wall0: float | None = None):
    """The batched loop of :func:`run_batch` and :func:`run_episodes`. -> ``BatchResult`` with the
    summaries, or with ``traces`` a ``_Run`` (the ``BatchResult`` without summaries, and each
    episode's ``EpisodeResult``)."""
    t_setup = time.perf_counter() if wall0 is None else wall0
    c0 = cfgs[0]
    known = _known_of(cfgs)
    B = len(cfgs)
    sims, scene, qpos, qvel, ctrl_b = batch_scene(cfgs, nthread, persistent=True if traces else None)
    ids = sims[0].ids
    sensordata = scene.bind("sensordata")
    if traces:  # the episodes' own controllers: their constants (shared) and their state rows
        ctrls = _controllers(cfgs, ctrls)
        k0 = ctrls[0]
        feats, chain, cs, law, lay = k0.features, k0.chain, k0.consts, k0.law_spec, k0.layout
        feats_b = [k.features for k in ctrls]
        st = core.ControllerState(lay, B)
        for b, k in enumerate(ctrls):
            st.x[b], st.k[b] = k.state.x[0], k.state.k[0]
        n, m, p = lay.n, lay.m, lay.p
        monitors = [SeatMonitor(c) for c in cfgs]
    else:
        # controller side: the bare arm's kinematic chain (forward kinematics in the kernel, from encoders)
        arm_model = mujoco.MjModel.from_xml_path(str(known.arm_mjcf))
        site = mujoco.mj_name2id(arm_model, mujoco.mjtObj.mjOBJ_SITE, FLANGE_SITE)
        chain = core.arm_chain(arm_model, site)
        # the controllers: one ControllerState for B, the same kernels as Controller.step
        feats, theta_c0 = make_features(c0)  # the known side is shared; theta0 is per episode (experiment design)
        per_episode = features_spec(known.features_kind).theta0_per_episode or bool(known.model_effects)
        built = [make_features(c) if per_episode else (feats, theta_c0) for c in cfgs]
        theta0 = np.array([th for _f, th in built])
        # effect columns keep per-episode state (what the last step observed): one features object each
        feats_b = [f for f, _th in built] if known.model_effects else [feats] * B
        cs, law = core_consts(known, feats)
        n, m, p = arm_model.nq, 6, feats.n_params
        lay = core.Layout(n, m, p, law.sizes(m, p))
        st = core.ControllerState(lay, B)
        st.theta[:] = theta0
        law.reset(cs.lc, law_state(law, st.law_x, st.law_k, st.unc, m, p), False)
        cs.c[core.RANK_ON] = 2.0  # the rank gate every step as a Cholesky test; lambda_min itself only on a breach
    observe = [getattr(f, "observe", None) for f in feats_b]
    fused = core.FUSED.get(int(cs.c[core.FEAT]))  # the step kernel of features computed in the kernel
    fx = feature_consts(feats)
    W = channel_metric(known.sensing) if fused is None else None  # the rank gate of features not fused
    inp = np.zeros((B, 2 * n + 6))
    p_O, R, J = np.zeros((B, 3)), np.zeros((B, 3, 3)), np.zeros((B, 6, n))
    reg, ext_J = np.zeros((B, 1 + p, m)), np.zeros((B, m, max(n, 6)))
    out = np.zeros((B, lay.nout))
    ob = {k: out[:, o:o + size] for k, (o, size) in lay.out_blocks.items()}
    i_rho = lay.out_blocks["rho"][0]
    i_lam = lay.out_blocks["lam_min"][0] if fused is not None else -1
    lam_ext = np.full(B, np.inf)  # lambda_min from Python (features not fused)
    f_adr = np.r_[np.arange(ids.force_adr, ids.force_adr + 3), np.arange(ids.torque_adr, ids.torque_adr + 3)]
    dt = known.dt_s
    su = c0.success
    d_seat = su.depth_m - su.depth_tol_m
    true_off = np.array([sm.cfg.tool.offset_f_m for sm in sims])  # the truth-side tool (hidden effects folded in)
    clock = np.full((B, 2), np.nan)  # per episode [since, seat_time] (runs.monitor.seat_step)
    seat = clock[:, 1]
    stop_at = np.full(B, np.inf)
    active = np.ones(B, bool)
    breach = np.zeros(B, bool)
    diverged = np.zeros(B, bool)
    reason: list[str | None] = [None] * B
    lam = np.full((B, 3), np.inf)
    lam[:, 2] = np.nan
    kv_kp = SERVO_KV / SERVO_KP
    n_steps = int(round(c0.run.duration_s / dt))
    log_every = c0.run.log_every if traces else 10
    n_rec = n_steps // log_every + 1
    logs = {k: [] for k in ("t", "s", "w")}
    ctrl_log = np.zeros((n_steps, B, n)) if record_ctrl else None
    peaks = np.zeros((B, 3))  # max |f_env|, max |F_lat|, max |m_env| while the drive is on
    lim = np.array([d_seat, su.max_lateral_force_N, su.max_moment_Nm, su.hold_s, c0.run.stop_after_seat_s])
    i_s, i_w = lay.out_blocks["s"][0], lay.out_blocks["w_env"][0]
    qadr, vadr = np.ascontiguousarray(ids.qpos_adr), np.ascontiguousarray(ids.dof_adr)
    # the truth side per episode (as PegInHoleSim.sense / .step): hidden sensor effects and simulated
    # faults on the samples, the socket contact's wrench on the tool body
    sensor_fx = [sm._sensor_fx if sm._sensor_fx.active else None for sm in sims]
    faults = [SensorFaults(c.faults, c.run.seed, c.start.settle_s) if SensorFaults.active(c.faults) else None
              for c in cfgs]
    sensor_side = [b for b in range(B) if sensor_fx[b] is not None or faults[b] is not None]
    socket_b = [b for b in range(B) if sims[b]._socket]
    sock_views = {}
    if socket_b or traces:
        xpos = scene.bind("site_xpos")
    if socket_b:
        xmat, xipos, cvel, scom, xfrc = (scene.bind(f) for f in ("xmat", "xipos", "cvel", "subtree_com", "xfrc_applied"))
        for b in socket_b:
            m_b = sims[b].model
            tb, vb = sims[b]._tool_body, int(m_b.site_bodyid[ids.tip_site])
            sock_views[b] = (xpos[b, ids.tip_site], xmat[b, tb], xipos[b, tb], cvel[b, vb],
                             scom[b, int(m_b.body_rootid[vb])], xfrc[b, tb])
    if traces:  # the loop's raw logs per episode (runs.episode.EpisodeLogs), the truth side's buffers
        t_log = np.zeros((B, n_rec))
        out_log = np.zeros((B, n_rec, lay.nout))
        io_log = np.zeros((B, n_rec, 3 * n + 6))
        phi_log = np.zeros((B, n_rec, p * m)) if (feats.theta_is_offset or keep_regressor) else None
        tip_log = np.zeros((B, n_rec, 3))
        truth_log = np.zeros((B, n_rec, 4))
        lam_log = np.full((B, n_rec), np.inf)
        n_logged = np.zeros(B, dtype=np.int64)
        f0 = lay.x_blocks["filt"][0] + 2 * m  # Phi_f^T rows of the state
        ncon, sim_time = scene.bind("ncon"), scene.bind("time")
        dbuf = mujoco.MjData(sims[0].model)  # one episode's whole MjData, copied out (contacts, warnings)
        data_of = [functools.partial(scene.get_data, b, dbuf) for b in range(B)]
        warn0 = np.array([int(scene.get_data(b, dbuf).warning.number.sum()) for b in range(B)])
    n_sim = np.zeros(B, dtype=np.int64)  # physics steps per episode
    n_ctrl = np.zeros(B, dtype=np.int64)  # control steps per episode (a sample refused as diverged is one, as in run_episode)
    setup = time.perf_counter() - t_setup
    t0 = time.perf_counter()
    t = 0.0  # accumulated as mj_step does (d.time += dt), so t < settle switches on the same step
    k = 0
    # compiled entries bound once (the dispatcher's type resolution skipped: ~0.5 us per argument array)
    gather = _bound(_gather, (qpos, qvel, sensordata, qadr, vadr, f_adr, inp))
    monitor = _bound(_monitor, (0.0, out, i_s, i_w, i_rho, i_lam, lam_ext, lim, active, clock, stop_at, peaks, lam, breach))
    if fused is not None:
        fused = core.entry_point(fused, (0.0, inp, chain, p_O, R, J, reg, st.x, st.k, lay.arr, cs.c, cs.mats, cs.pv,
                                         cs.lc, cs.law_fn, cs.seg, fx, out))
    is_socket = [sm._socket for sm in sims]
    every_one = True  # every episode still running (whole-array operations, no masks)
    for k in range(n_steps):
        if every_one:
            n_ctrl += 1
        else:
            n_ctrl[active] += 1
        gather(qpos, qvel, sensordata, qadr, vadr, f_adr, inp)
        for b in sensor_side:
            if active[b]:
                _sensor_side(t, inp[b], n, sensor_fx[b], faults[b])
        logged = traces and k % log_every == 0
        if logged:
            j = k // log_every
            act = slice(None) if every_one else active
            io_log[act, j, :2 * n + 6] = inp[act]  # the sample as given (before any dropout hold)
        if fused is not None:
            fused(t, inp, chain, p_O, R, J, reg, st.x, st.k, lay.arr, cs.c, cs.mats, cs.pv, cs.lc, cs.law_fn, cs.seg,
                  fx, out)
        else:
            core.intake_kernel(inp, st.x, st.k, lay.arr, cs.c)
            core.fk_batch(chain, inp, p_O, R, J)
            core.sense_kernel(t, inp, p_O, R, st.x, st.k, lay.arr, cs.c, cs.mats, out)
            for b in np.flatnonzero(active & (st.k[:, core.K_ERROR] == 0)):  # rows from Python (Controller._generic_step)
                fb = feats_b[b]
                kin = KinState(inp[b, :n], p_O[b], R[b], J[b])
                if observe[b] is not None:  # effect columns: the sensor-side context of this step
                    observe[b](t, ob["s"][b], ob["w_env"][b], out[b, i_rho] > 0.0)
                rg = fb.regressor(kin, inp[b, n:2 * n])
                reg[b, 0], reg[b, 1:] = rg.known, rg.Phi.T
                if cs.c[core.EXCITE]:
                    continue
                J_xi = fb.twist_jacobian(kin, st.theta[b])
                if J_xi is not None:
                    cs.c[core.FEAT] = core.FEAT_TWIST
                    ext_J[b, :, :6] = J_xi
                else:
                    cs.c[core.FEAT] = core.FEAT_JHAT
                    ext_J[b, :, :n] = fb.jacobian(kin, st.theta[b])
            core.act_kernel(t, inp, p_O, R, J, reg, ext_J, st.x, st.k, lay.arr, cs.c, cs.mats, cs.pv, cs.lc,
                            cs.law_fn, cs.seg, out)
            for b in np.flatnonzero(active & (out[:, i_rho] > 0.0) & (st.k[:, core.K_ERROR] == 0)):
                kin = KinState(inp[b, :n].copy(), p_O[b], R[b], J[b])  # the rank gate (Controller.rank_margin_now)
                lam_ext[b] = rank_margin(W, feats_b[b].jacobian(kin, st.theta[b]))
        if st.k[:, core.K_ERROR].any():  # a dropout longer than max_dropout_s: divergence
            err = st.k[:, core.K_ERROR] != 0
            for b in np.flatnonzero(err & active):
                reason[b] = sensor_reason(sensor_error_message(t, int(st.k[b, core.K_BAD_RUN])))
            diverged |= err & active
            active &= ~err
            every_one = False
        monitor(t, out, i_s, i_w, i_rho, i_lam, lam_ext, lim, active, clock, stop_at, peaks, lam, breach)
        if logged:  # as run_episode logs a step (its truth before the physics step)
            act = slice(None) if every_one else active
            lam_log[act, j] = lam[act, 0]
            lam[act, 0] = np.inf
            t_log[act, j] = t
            out_log[act, j] = out[act]
            io_log[act, j, 2 * n + 6:] = st.q_ref[act]
            if phi_log is not None:
                phi_log[act, j] = st.x[act, f0:f0 + p * m]
            tip_log[act, j] = xpos[act, ids.tip_site]
            n_logged[act] = j + 1
            nc = ncon.tolist()
            for b in (range(B) if every_one else np.flatnonzero(active)):
                if is_socket[b] or nc[b]:
                    truth_log[b, j, 1:] = sims[b].contacts_of(sensordata[b], data_of[b])
        elif not traces and k % log_every == 0:
            logs["t"].append(t)
            logs["s"].append(ob["s"].copy())
            logs["w"].append(ob["w_env"].copy())
        # servo set-points and physics for the active episodes
        ctrl_b[:] = st.q_ref + kv_kp * ob["qdot_ref"]
        if record_ctrl:
            ctrl_log[k] = ctrl_b
        for b in socket_b:
            if active[b]:
                socket_step(t, sims[b]._sock_st, sims[b]._sock_prm, *sock_views[b])
        if every_one:
            scene.step(None)
            n_sim += 1
        else:
            act_ids = np.flatnonzero(active)
            scene.step(act_ids)
            n_sim[act_ids] += 1
        t = t + dt
        if breach.any() or t >= stop_at.min():
            active &= (t < stop_at) & ~breach
        if traces and k % 100 == 0:  # divergence watch at 10 Hz: MuJoCo warnings (as run_episode)
            for b in np.flatnonzero(active):
                if int(scene.get_data(b, dbuf).warning.number.sum()) > warn0[b]:
                    diverged[b], active[b], reason[b] = True, False, warning_reason(t)
        if every_one and not active.all():
            every_one = False
        if not every_one:
            st.k[~active, core.K_DONE] = 1  # the kernels skip episodes that have stopped
            if not active.any():
                break
    wall = time.perf_counter() - t0
    sim_steps = int(n_sim.sum())
    theta = st.theta.copy()
    result = BatchResult([], k + 1, sim_steps, wall, setup, theta, None if ctrl_log is None else ctrl_log[: k + 1])
    if traces:
        episodes = []
        for b in range(B):
            kb = ctrls[b]  # the controller's state: the batch row it was stepped in
            kb.state.x[0], kb.state.k[0] = st.x[b], st.k[b]
            kb.state.k[0, core.K_ERROR] = kb.state.k[0, core.K_DONE] = 0
            kb.out[0] = out[b]
            kb._stepped = True
            monitors[b].clock[:] = clock[b]
            if breach[b]:
                diverged[b], reason[b] = True, rank_breach_reason(lam[b, 1], lam[b, 2])
            logs_b = EpisodeLogs(t_log[b], out_log[b], io_log[b], None if phi_log is None else phi_log[b], tip_log[b],
                                 truth_log[b], lam_log[b])
            share = (setup + wall) * n_sim[b] / max(1, sim_steps)
            episodes.append(episode_result(
                cfgs[b], sims[b], kb, monitors[b], logs_b, int(n_logged[b]), steps=int(n_ctrl[b]),
                t_end_s=float(sim_time[b]), wall_s=share, diverged=bool(diverged[b]), divergence_reason=reason[b],
                lam_min_all=float(lam[b, 1]), rank_breach_t=None if np.isnan(lam[b, 2]) else float(lam[b, 2]),
                keep_regressor=keep_regressor))
        return _Run(result, episodes)
    tl = np.array(logs["t"])
    sl = np.array(logs["s"])  # (T, B, 6)
    wl = np.array(logs["w"])
    for b in range(B):
        success = not np.isnan(seat[b]) and not breach[b] and not diverged[b]
        act = tl >= c0.start.settle_s
        failure = "none" if success else ("rank_gate" if breach[b] else
                                          classify_failure(cfgs[b], tl[act], sl[act, b], wl[act, b], bool(diverged[b])))
        err = theta[b, :3] - true_off[b] if feats.theta_is_offset else np.full(3, np.nan)
        result.summaries.append({
            "success": bool(success), "failure": failure, "seat_time_s": float(seat[b]) if success else None,
            "max_force_N": float(peaks[b, 0]), "max_lateral_force_N": float(peaks[b, 1]), "max_moment_Nm": float(peaks[b, 2]),
            "offset_error_final_m": err.tolist(), "offset_error_lateral_final_m": float(math.hypot(err[0], err[1])),
            "seed": cfgs[b].run.seed, "law": law.name, "steps": int(n_ctrl[b]),
        })
    return result


def _run_chunk(args) -> BatchResult:
    cfgs, nthread = args
    return run_batch(cfgs, nthread=nthread)


def run_batch_processes(cfgs: list[ExperimentCfg], processes: int = 2) -> BatchResult:
    """Split the episodes over ``processes`` worker processes, each one batch on one thread.

    Measured better than one batch on two threads: the vectorised controller is numpy on one
    core (GIL), so two processes also parallelise the controller, not only the physics. The
    loop wall time reported is the slowest chunk's (the chunks run concurrently)."""
    from concurrent.futures import ProcessPoolExecutor

    chunks = [cfgs[i::processes] for i in range(processes) if cfgs[i::processes]]
    with ProcessPoolExecutor(max_workers=len(chunks)) as ex:
        parts = list(ex.map(_run_chunk, [(c, 1) for c in chunks]))
    order = [i for k in range(len(chunks)) for i in range(k, len(cfgs), processes)]
    summaries: list = [None] * len(cfgs)
    for idx, s in zip(order, [s for p in parts for s in p.summaries]):
        summaries[idx] = s
    return BatchResult(summaries, max(p.steps for p in parts), sum(p.sim_steps for p in parts),
                       max(p.wall_s for p in parts), max(p.setup_s for p in parts))
