"""Many episodes stepped together: ``mujoco.batch.Batch`` physics + a vectorised controller.

The same controller as ``kinadapt_nn.controller.controller.Controller`` with the adjoint features and the
composite law (eqs. ft_force, cp_admittance, ft_composite), written on (B, ...) arrays:
one numpy call serves all B episodes, so the per-call overhead that bounds the single-episode
path is paid once per step. The truth firewall holds the same way: the controller's
kinematics come from a second batch of *bare-arm* models fed with the encoder readings; the
scene batch only supplies encoders and raw F/T readings.

Differences from the single-episode path (measured in ``tests/test_batch.py`` and the issue
note): floating-point operations are grouped differently (batched matmuls and solves), and
contact simulation amplifies such 1e-16 differences, so trajectories agree closely before
contact and statistically after it; success and seat time per episode are compared. Not
supported here: learned features, dither, the rigid loop, sensor faults, traces (summaries
only).
"""

from __future__ import annotations

import math
import time
from typing import NamedTuple

import mujoco
import mujoco.batch
import numpy as np

from kinadapt_nn.config import ExperimentCfg, arm_mjcf_path
from kinadapt_nn.runs.episode import classify_failure, initial_estimate
from kinadapt_nn.robot import FLANGE_SITE, SERVO_KP, SERVO_KV
from kinadapt_nn.sensing import channel_metric, lateral_projector, nominal_sensor_map
from kinadapt_nn.known import BORE_AXIS_W
from kinadapt_nn.sim.adapter import PegInHoleSim


class BatchResult(NamedTuple):
    summaries: list[dict]  #: per episode: success, seat_time_s, failure, forces, offset error
    steps: int  #: control steps taken (the longest episode)
    sim_steps: int  #: sum over episodes of the physics steps actually simulated
    wall_s: float  #: wall time of the stepping loop
    setup_s: float  #: wall time to build models and start poses


def _skew_b(v: np.ndarray) -> np.ndarray:
    """(B, 3) -> (B, 3, 3) cross-product matrices."""
    B = v.shape[0]
    S = np.zeros((B, 3, 3))
    S[:, 0, 1], S[:, 0, 2] = -v[:, 2], v[:, 1]
    S[:, 1, 0], S[:, 1, 2] = v[:, 2], -v[:, 0]
    S[:, 2, 0], S[:, 2, 1] = -v[:, 1], v[:, 0]
    return S


def run_batch(cfgs: list[ExperimentCfg], nthread: int = 2) -> BatchResult:
    """Run len(cfgs) episodes together. All cfgs share every KNOWN setting (sensing, control,
    adaptation, success, bore pose) and differ in hidden truth (tool, start, seed)."""
    t_setup = time.perf_counter()
    c0 = cfgs[0]
    for c in cfgs:
        if c.run.features != "adjoint" or any(c.control.dither_rad_s) or c.control.loop != "admittance":
            raise ValueError("the batched path supports adjoint features, no dither, the admittance loop")
    B = len(cfgs)
    sims = [PegInHoleSim(c) for c in cfgs]
    scene = mujoco.batch.Batch(sims[0].model, B, nthread, True)
    scene.set_models([s.model for s in sims])
    ids = sims[0].ids
    qpos, qvel, ctrl_b = scene.bind("qpos"), scene.bind("qvel"), scene.bind("ctrl")
    q0 = np.array([s.q_start for s in sims])
    qpos[:, ids.qpos_adr] = q0
    qvel[:] = 0.0
    ctrl_b[:] = q0
    scene.forward()
    sensordata = scene.bind("sensordata")
    # controller side: bare-arm batch fed with encoders
    arm_model = mujoco.MjModel.from_xml_path(str(arm_mjcf_path(c0.scene)))
    arm = mujoco.batch.Batch(arm_model, B, nthread, True)
    arm_q = arm.bind("qpos")
    site = mujoco.mj_name2id(arm_model, mujoco.mjtObj.mjOBJ_SITE, FLANGE_SITE)
    site_xpos, site_xmat = arm.bind("site_xpos"), arm.bind("site_xmat")
    xaxis, xanchor = arm.bind("xaxis"), arm.bind("xanchor")  # hinge axes and anchors (world)
    # known constants (identical for every episode)
    sc, cc, ad = c0.sensing, c0.control, c0.adaptation
    dt = c0.run.dt_s
    n_axis = BORE_AXIS_W
    S = nominal_sensor_map(sc, n_axis)
    P = lateral_projector(S, sc.stiffness_lat_N_per_m)
    W = channel_metric(sc)
    l_nom = np.asarray(sc.nominal_offset_f_m, dtype=float)
    n_entry = float(n_axis @ np.asarray(c0.scene.bore_entry_w_m))
    S_v = S[:, :3].copy()
    S_v[0] = 0.0
    tau = np.array([cc.tau_trans_s] * 3 + [cc.tau_ang_s] * 3)
    gain = np.array([cc.gain_trans] * 3 + [cc.gain_ang] * 3)
    beta = np.array([cc.beta_trans] * 3 + [cc.beta_ang] * 3)
    M_v = tau / gain
    inv_den = 1.0 / (M_v + dt * (1.0 + beta) / gain)
    a_f = dt / (sc.filter_tau_s + dt)
    inv_tf = 1.0 / (sc.filter_tau_s + dt)
    half = np.array([ad.omega_lateral_m, ad.omega_lateral_m, ad.omega_axial_m])
    lo, hi = l_nom - half, l_nom + half
    if ad.mode == "kalman":
        from kinadapt_nn.errors import ConfigError

        raise ConfigError("batched simulation implements the paper's laws (composite, prediction, tracking, frozen); "
                          "set adaptation.mode=composite (or run episodes one by one for the kalman law)")
    track_gain = ad.gamma * ad.gamma_d if ad.mode in ("composite", "tracking") else 0.0
    use_pred = ad.mode in ("composite", "prediction")
    d_star, k_d, f_max = cc.depth_target_m, cc.k_depth_N_per_m, cc.depth_force_max_N
    c_F, c_M = cc.compliance_lat_m_per_N, cc.compliance_mom_rad_per_Nm
    su = c0.success
    d_seat = su.depth_m - su.depth_tol_m
    # state
    theta = np.array([initial_estimate(c) for c in cfgs])
    true_off = np.array([c.tool.offset_f_m for c in cfgs])
    xi = np.zeros((B, 6))
    q_ref = q0.copy()
    q_post = q0.copy()
    tare_sum = np.zeros((B, 6))
    tare_n = 0
    tare = np.zeros((B, 6))
    y_f = np.zeros((B, 6))
    known_f = np.zeros((B, 6))
    Phi_f = np.zeros((B, 6, 3))
    primed = False
    since = np.full(B, np.nan)
    seat = np.full(B, np.nan)
    stop_at = np.full(B, np.inf)
    active = np.ones(B, bool)
    kv_kp = SERVO_KV / SERVO_KP
    n_steps = int(round(c0.run.duration_s / dt))
    log_every = 10
    logs = {k: [] for k in ("t", "s", "w")}
    max_f = np.zeros(B)
    max_flat = np.zeros(B)
    max_m = np.zeros(B)
    sim_steps = 0
    eye6 = 1e-6 * np.eye(6)
    setup = time.perf_counter() - t_setup
    t0 = time.perf_counter()
    k = 0
    for k in range(n_steps):
        t = k * dt
        q = qpos[:, ids.qpos_adr].copy()
        qd = qvel[:, ids.dof_adr].copy()
        raw = np.concatenate([sensordata[:, ids.force_adr:ids.force_adr + 3],
                              sensordata[:, ids.torque_adr:ids.torque_adr + 3]], axis=1)
        # kinematics of the bare arm at the encoder readings
        arm_q[:] = q
        arm.forward(stage=int(mujoco.mjtStage.mjSTAGE_POS))
        p = site_xpos[:, site].copy()
        R = site_xmat[:, site].reshape(B, 3, 3).copy()
        ax = xaxis.copy()  # (B, 7, 3): the geometric Jacobian of hinges, [axis x (p - anchor); axis]
        J = np.concatenate([np.cross(ax, p[:, None, :] - xanchor), ax], axis=2).transpose(0, 2, 1)  # (B, 6, 7)
        # tare, wrench, s
        if t < c0.start.settle_s:
            if t >= c0.start.settle_s - sc.tare_window_s:
                tare_sum += raw
                tare_n += 1
            rho = 0.0
            w_env = np.zeros((B, 6))
        else:
            if tare_n and not tare.any():
                tare = tare_sum / tare_n
            rho = min(1.0, (t - c0.start.settle_s) / cc.ramp_s) if cc.ramp_s > 0 else 1.0
            dw = (raw - tare).reshape(B, 2, 3)
            w_env = (dw @ R.transpose(0, 2, 1)).reshape(B, 6)  # rows R f, R m
        Rl = R @ l_nom  # (B, 3)
        s = np.empty((B, 6))
        s[:, 0] = (p + Rl) @ n_axis - n_entry
        s[:, 1:3] = -w_env[:, :3] @ P.T
        s[:, 3:] = -w_env[:, 3:]
        if not primed:
            y_f[:] = s
            primed = True
        s_dot = (s - y_f) * inv_tf
        y_f += a_f * (s - y_f)
        # regressor on the realised velocity (adjoint): known = S xi + depth-row lever term
        xi_m = (J @ qd[:, :, None])[:, :, 0]
        w_m = xi_m[:, 3:]
        known = xi_m @ S.T
        known[:, 0] += np.cross(w_m, Rl) @ S[0, :3]
        Phi = S_v @ (_skew_b(w_m) @ R)  # (B, 6, 3)
        # value force (eq. ft_force)
        F = np.empty((B, 6))
        F[:, 0] = -np.clip(k_d * (s[:, 0] - d_star), -f_max, f_max)
        F[:, 1:3] = -c_F * s[:, 1:3]
        F[:, 3:] = -c_M * s[:, 3:]
        # drive (S Ad(R theta))^T F, depth row on the nominal lever
        lt = (R @ theta[:, :, None])[:, :, 0]
        J_xi = np.broadcast_to(S, (B, 6, 6)).copy()
        J_xi[:, :, 3:] -= S_v @ _skew_b(lt)
        J_xi[:, 0, 3:] -= S[0, :3] @ _skew_b(Rl)
        drive = (F[:, None, :] @ J_xi)[:, 0, :]
        # admittance (eq. cp_admittance, implicit damping) + clipping
        xi = (M_v * xi + dt * (rho * drive - w_env)) * inv_den
        vn = np.linalg.norm(xi[:, :3], axis=1)
        sc_v = np.where(vn > cc.v_max_m_per_s, cc.v_max_m_per_s / np.maximum(vn, 1e-300), 1.0)
        xi[:, :3] *= sc_v[:, None]
        wn = np.linalg.norm(xi[:, 3:], axis=1)
        sc_w = np.where(wn > cc.w_max_rad_per_s, cc.w_max_rad_per_s / np.maximum(wn, 1e-300), 1.0)
        xi[:, 3:] *= sc_w[:, None]
        # joint reference: J^+ xi + null-space posture
        z = cc.nullspace_gain * (q_post - q)
        JJt = J @ J.transpose(0, 2, 1) + eye6
        y = np.linalg.solve(JJt, (xi - (J @ z[:, :, None])[:, :, 0])[:, :, None])
        qdot_ref = (y.transpose(0, 2, 1) @ J)[:, 0, :] + z
        q_ref = q_ref + dt * qdot_ref
        # adaptation (eq. ft_composite) with the contact gate and Omega
        known_f += a_f * (known - known_f)
        Phi_f += a_f * (Phi - Phi_f)
        eps_w = W * (s_dot - known_f - (Phi_f @ theta[:, :, None])[:, :, 0])
        gate = (np.linalg.norm(w_env[:, :3], axis=1) >= ad.contact_force_N) | (
            np.linalg.norm(w_env[:, 3:], axis=1) >= ad.contact_moment_Nm)
        if gate.any() and ad.mode != "frozen":
            Pw = W[None, :, None] * Phi_f
            step = np.zeros((B, 3))
            if track_gain:
                step -= dt * track_gain * (F[:, None, :] @ Phi)[:, 0, :]
            if use_pred:
                G = Pw.transpose(0, 2, 1) @ Pw
                n2 = np.linalg.eigvalsh(G)[:, -1]
                step += ad.eta * (eps_w[:, None, :] @ Pw)[:, 0, :] / (n2 + ad.eps_norm)[:, None]
            theta = np.where(gate[:, None], np.clip(theta + step, lo, hi), theta)
        # sensor-side success monitor
        if rho > 0:
            ok = (s[:, 0] >= d_seat) & (np.hypot(s[:, 1], s[:, 2]) < su.max_lateral_force_N) & (
                np.linalg.norm(s[:, 3:], axis=1) < su.max_moment_Nm)
            since = np.where(ok, np.where(np.isnan(since), t, since), np.nan)
            newly = np.isnan(seat) & ok & (t - since >= su.hold_s - 1e-12)
            seat[newly] = t
            stop_at[newly] = t + c0.run.stop_after_seat_s
            fm = np.linalg.norm(w_env[:, :3], axis=1)
            max_f = np.maximum(max_f, np.where(active, fm, 0))
            max_flat = np.maximum(max_flat, np.where(active, np.hypot(s[:, 1], s[:, 2]), 0))
            max_m = np.maximum(max_m, np.where(active, np.linalg.norm(w_env[:, 3:], axis=1), 0))
        if k % log_every == 0:
            logs["t"].append(t)
            logs["s"].append(s.copy())
            logs["w"].append(w_env.copy())
        # servo set-points and physics for the active episodes
        ctrl_b[:] = q_ref + kv_kp * qdot_ref
        act_ids = np.flatnonzero(active)
        scene.step(act_ids)
        sim_steps += len(act_ids)
        active &= (t + dt) < stop_at
        if not active.any():
            break
    wall = time.perf_counter() - t0
    tl = np.array(logs["t"])
    sl = np.array(logs["s"])  # (T, B, 6)
    wl = np.array(logs["w"])
    summaries = []
    for b in range(B):
        success = not np.isnan(seat[b])
        act = tl >= c0.start.settle_s
        failure = "none" if success else classify_failure(cfgs[b], tl[act], sl[act, b], wl[act, b], False)
        err = theta[b] - true_off[b]
        summaries.append({
            "success": bool(success), "failure": failure, "seat_time_s": float(seat[b]) if success else None,
            "max_force_N": float(max_f[b]), "max_lateral_force_N": float(max_flat[b]), "max_moment_Nm": float(max_m[b]),
            "offset_error_final_m": err.tolist(), "offset_error_lateral_final_m": float(math.hypot(err[0], err[1])),
            "seed": cfgs[b].run.seed,
        })
    return BatchResult(summaries, k + 1, sim_steps, wall, setup)


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
