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
``tests/runs/test_batch.py``). Not here: traces (summaries only).
"""

from __future__ import annotations

import math
import time
from typing import NamedTuple

import mujoco
import mujoco.batch
import numba as nb
import numpy as np

from kinadapt_nn.controller import core
from kinadapt_nn.config import ExperimentCfg
from kinadapt_nn.controller.controller import core_consts, feature_consts, rank_margin
from kinadapt_nn.controller.laws.base import law_state
from kinadapt_nn.controller.core import RANK_GATE
from kinadapt_nn.runs.monitor import classify_failure, seat_step
from kinadapt_nn.runs.build import make_features
from kinadapt_nn.runs.build import one_blas_thread
from kinadapt_nn.errors import ConfigError
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


def batch_scene(cfgs: list[ExperimentCfg], nthread: int = 1):
    """One ``mujoco.batch.Batch`` of the episodes' scenes (per-episode tool models), every arm at
    its start pose and at rest, servo set-points there. -> (sims, scene, qpos, qvel, ctrl): the
    PegInHoleSim per episode (models, ids, truth side) and the batch's bound (B, .) buffers."""
    sims = [PegInHoleSim(c) for c in cfgs]
    scene = mujoco.batch.Batch(sims[0].model, len(cfgs), nthread, nthread > 1)
    scene.set_models([s.model for s in sims])
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
def _monitor(t, out, i_s, i_w, i_rho, i_lam, lim, active, clock, stop_at, peaks, breach):
    """Per episode with the drive on: the seat check (``runs.monitor.seat_step``, clock (B, 2) =
    [since, seat_time]), peak wrenches and the rank gate. lim = [d_seat, max |F_lat|, max |M|,
    hold_s, stop_after_seat_s, gate on (0/1)]; peaks (B, 3) = [max |f_env|, max |F_lat|, max |m_env|]."""
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
        if lim[5] > 0.0 and out[b, i_lam] < RANK_GATE:
            breach[b] = True


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
    """Run len(cfgs) episodes together. All cfgs share every KNOWN setting (sensing, control,
    adaptation, success, bore pose) and differ in hidden truth (tool, start, seed). BLAS at one
    thread meanwhile (``runs.build.one_blas_thread``)."""
    with one_blas_thread():
        return _run_batch(cfgs, nthread, record_ctrl)


def _run_batch(cfgs: list[ExperimentCfg], nthread: int, record_ctrl: bool) -> BatchResult:
    t_setup = time.perf_counter()
    c0 = cfgs[0]
    known = _known_of(cfgs)
    B = len(cfgs)
    sims, scene, qpos, qvel, ctrl_b = batch_scene(cfgs, nthread)
    ids = sims[0].ids
    sensordata = scene.bind("sensordata")
    # controller side: the bare arm's kinematic chain (forward kinematics in the kernel, from encoders)
    arm_model = mujoco.MjModel.from_xml_path(str(known.arm_mjcf))
    site = mujoco.mj_name2id(arm_model, mujoco.mjtObj.mjOBJ_SITE, FLANGE_SITE)
    chain = core.arm_chain(arm_model, site)
    # the controllers: one ControllerState for B, the same kernels as Controller.step
    feats, theta_c0 = make_features(c0)  # the known side is shared; theta0 is per episode (experiment design)
    per_episode = known.features_kind in ("adjoint", "oracle") or bool(known.model_effects)
    built = [make_features(c) if per_episode else (feats, theta_c0) for c in cfgs]
    theta0 = np.array([th for _f, th in built])
    # effect columns keep per-episode state (what the last step observed): one features object each
    feats_b = [f for f, _th in built] if known.model_effects else [feats] * B
    observe = [getattr(f, "observe", None) for f in feats_b]
    cs, law = core_consts(known, feats)
    n, m, p = arm_model.nq, 6, feats.n_params
    lay = core.Layout(n, m, p, law.sizes(m, p))
    st = core.ControllerState(lay, B)
    st.theta[:] = theta0
    law.reset(cs.lc, law_state(law, st.law_x, st.law_k, st.unc, m, p), False)
    fused = core.FUSED.get(int(cs.c[core.FEAT]))  # the step kernel of features computed in the kernel
    fx = feature_consts(feats)
    W = channel_metric(known.sensing) if fused is None else None  # the rank gate of features not fused
    cs.c[core.RANK_ON] = 2.0  # the rank gate every step as a Cholesky test; lambda_min itself only on a breach
    inp = np.zeros((B, 2 * n + 6))
    p_O, R, J = np.zeros((B, 3)), np.zeros((B, 3, 3)), np.zeros((B, 6, n))
    reg, ext_J = np.zeros((B, 1 + p, m)), np.zeros((B, m, max(n, 6)))
    out = np.zeros((B, lay.nout))
    ob = {k: out[:, o:o + size] for k, (o, size) in lay.out_blocks.items()}
    i_rho, i_lam = lay.out_blocks["rho"][0], lay.out_blocks["lam_min"][0]
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
    kv_kp = SERVO_KV / SERVO_KP
    n_steps = int(round(c0.run.duration_s / dt))
    log_every = 10
    logs = {k: [] for k in ("t", "s", "w")}
    ctrl_log = np.zeros((n_steps, B, n)) if record_ctrl else None
    peaks = np.zeros((B, 3))  # max |f_env|, max |F_lat|, max |m_env| while the drive is on
    lim = np.array([d_seat, su.max_lateral_force_N, su.max_moment_Nm, su.hold_s, c0.run.stop_after_seat_s,
                    1.0 if fused is not None else 0.0])
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
    if socket_b:
        xpos, xmat, xipos, cvel, scom, xfrc = (scene.bind(f) for f in ("site_xpos", "xmat", "xipos", "cvel",
                                                                        "subtree_com", "xfrc_applied"))
        for b in socket_b:
            m_b = sims[b].model
            tb, vb = sims[b]._tool_body, int(m_b.site_bodyid[ids.tip_site])
            sock_views[b] = (xpos[b, ids.tip_site], xmat[b, tb], xipos[b, tb], cvel[b, vb],
                             scom[b, int(m_b.body_rootid[vb])], xfrc[b, tb])
    sim_steps = 0
    n_sim = np.zeros(B, dtype=np.int64)  # physics steps per episode
    n_ctrl = np.zeros(B, dtype=np.int64)  # control steps per episode (a sample refused as diverged is one, as in run_episode)
    setup = time.perf_counter() - t_setup
    t0 = time.perf_counter()
    t = 0.0  # accumulated as mj_step does (d.time += dt), so t < settle switches on the same step
    k = 0
    for k in range(n_steps):
        n_ctrl[active] += 1
        _gather(qpos, qvel, sensordata, qadr, vadr, f_adr, inp)
        for b in sensor_side:
            if active[b]:
                _sensor_side(t, inp[b], n, sensor_fx[b], faults[b])
        if fused is not None:
            fused(t, inp, chain, p_O, R, J, reg, st.x, st.k, lay.arr, cs.c, cs.mats, cs.pv, cs.lc, cs.law_fn, cs.seg,
                  fx, out)
        else:
            core.intake_kernel(inp, st.x, st.k, lay.arr, cs.c)
            core.fk_batch(chain, inp, p_O, R, J)
            core.sense_kernel(t, inp, p_O, R, st.x, st.k, lay.arr, cs.c, cs.mats, out)
            for b in np.flatnonzero(active):  # the features' rows from Python, per episode (Controller._generic_step)
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
            for b in np.flatnonzero(active & (out[:, i_rho] > 0.0)):  # the rank gate (Controller.rank_margin_now)
                kin = KinState(inp[b, :n].copy(), p_O[b], R[b], J[b])
                if rank_margin(W, feats_b[b].jacobian(kin, st.theta[b])) < RANK_GATE:
                    breach[b] = True
        err = st.k[:, core.K_ERROR] != 0  # a dropout longer than max_dropout_s: divergence
        if err.any():
            diverged |= err & active
            active &= ~err
        _monitor(t, out, i_s, i_w, i_rho, i_lam, lim, active, clock, stop_at, peaks, breach)
        if k % log_every == 0:
            logs["t"].append(t)
            logs["s"].append(ob["s"].copy())
            logs["w"].append(ob["w_env"].copy())
        # servo set-points and physics for the active episodes
        ctrl_b[:] = st.q_ref + kv_kp * ob["qdot_ref"]
        if record_ctrl:
            ctrl_log[k] = ctrl_b
        act_ids = np.flatnonzero(active)
        for b in socket_b:
            if active[b]:
                socket_step(t, sims[b]._sock_st, sims[b]._sock_prm, *sock_views[b])
        scene.step(act_ids)
        sim_steps += len(act_ids)
        n_sim[act_ids] += 1
        t = t + dt
        active &= (t < stop_at) & ~breach
        st.k[~active, core.K_DONE] = 1  # the kernels skip episodes that have stopped
        if not active.any():
            break
    wall = time.perf_counter() - t0
    tl = np.array(logs["t"])
    sl = np.array(logs["s"])  # (T, B, 6)
    wl = np.array(logs["w"])
    summaries = []
    theta = st.theta.copy()
    for b in range(B):
        success = not np.isnan(seat[b]) and not breach[b] and not diverged[b]
        act = tl >= c0.start.settle_s
        failure = "none" if success else ("rank_gate" if breach[b] else
                                          classify_failure(cfgs[b], tl[act], sl[act, b], wl[act, b], bool(diverged[b])))
        err = theta[b, :3] - true_off[b] if feats.theta_is_offset else np.full(3, np.nan)
        summaries.append({
            "success": bool(success), "failure": failure, "seat_time_s": float(seat[b]) if success else None,
            "max_force_N": float(peaks[b, 0]), "max_lateral_force_N": float(peaks[b, 1]), "max_moment_Nm": float(peaks[b, 2]),
            "offset_error_final_m": err.tolist(), "offset_error_lateral_final_m": float(math.hypot(err[0], err[1])),
            "seed": cfgs[b].run.seed, "law": known.law, "steps": int(n_ctrl[b]),
        })
    return BatchResult(summaries, k + 1, sim_steps, wall, setup, theta,
                       None if ctrl_log is None else ctrl_log[: k + 1])


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
