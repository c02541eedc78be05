"""The batch-first controller core: a batch equals a loop over its members, and one step of the
kernel equals an independent numpy evaluation of the equations."""

from __future__ import annotations

from dataclasses import replace

import mujoco
import numpy as np
import pytest

from kinadapt_nn.controller import core
from kinadapt_nn.runs.batch import run_batch
from kinadapt_nn.config import load_config
from kinadapt_nn.controller.controller import Controller
from kinadapt_nn.runs.build import make_controller, make_features
from kinadapt_nn.runs.episode import run_episode
from kinadapt_nn.errors import ConfigError
from kinadapt_nn.features import AdjointFeatures
from kinadapt_nn.known import KnownCfg
from kinadapt_nn.robot import FLANGE_SITE
from kinadapt_nn.sensing import channel_metric, nominal_sensor_map
from kinadapt_nn.runs.sweep import SweepCfg, tool_overrides


@pytest.mark.parametrize("law", ["kalman", "composite"])
def test_batch_of_three_equals_three_single_episodes(law):
    """run_batch (B = 3, mujoco.batch, controllers from the known config) and three run_episode
    calls (batches of one: Controller objects, mj_step on each episode's MjData) run the same
    kernels on the same physics: seat times, peak forces and final estimates agree exactly."""
    base = ["run.progress=false", "start.lateral_jitter_m=0.0003", "start.tilt_jitter_deg=0.5",
            "run.stop_after_seat_s=0.05", f"adaptation.mode={law}"]
    cfgs = [load_config(None, [*base, *tool_overrides(SweepCfg(), s), f"run.seed={s}"]) for s in range(3)]
    res = run_batch(cfgs, nthread=1)
    assert len({round(s["seat_time_s"], 6) for s in res.summaries}) == 3  # three different episodes
    steps = 0
    for c, b, theta_b in zip(cfgs, res.summaries, res.theta_final):
        ctrl = make_controller(c)
        e = run_episode(c, ctrl=ctrl).summary
        steps += e["steps"]
        assert b["success"] and e["success"]
        assert b["seat_time_s"] == e["seat_time_s"]
        assert b["max_force_N"] == e["max_force_N"]
        assert b["max_lateral_force_N"] == e["max_lateral_force_N"]
        np.testing.assert_array_equal(theta_b, ctrl.theta)
    assert res.sim_steps == steps


def test_batch_refuses_episodes_that_differ_in_a_known_setting():
    with pytest.raises(ConfigError, match="KNOWN"):
        run_batch([load_config(None, []), load_config(None, ['model.effects=["ft_bias_drift"]'])])


def _jac_site(model, data, q):
    """Independent kinematics: mj_kinematics + mj_comPos + mj_jacSite."""
    data.qpos[:] = q
    mujoco.mj_kinematics(model, data)
    mujoco.mj_comPos(model, data)
    site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, FLANGE_SITE)
    jp, jr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
    mujoco.mj_jacSite(model, data, jp, jr, site)
    return data.site_xpos[site].copy(), data.site_xmat[site].reshape(3, 3).copy(), np.vstack([jp, jr])


def test_kernel_step_equals_numpy_equations():
    """One composite step in contact at B = 1 against the equations written out in numpy:
    eq. ft_force, eq. cp_admittance, the joint reference, eq. ft_pred and eq. ft_composite."""
    cfg = load_config(None, ["run.progress=false", "adaptation.mode=composite"])
    known = KnownCfg.of(cfg)
    feats, _ = make_features(cfg)
    rng = np.random.default_rng(7)
    theta = np.asarray(cfg.sensing.nominal_offset_f_m) + np.array([0.004, -0.003, 0.002])
    ctrl = Controller(known, feats, theta)
    n = ctrl.kin_n
    st = ctrl.state
    # a state in the middle of an insertion: tared, filters primed, a twist, an estimate
    q = np.array([0.05, -0.55, 0.02, -2.35, 0.03, 1.85, 0.75])
    qdot = 0.05 * rng.normal(size=n)
    wrench = np.array([3.0, -2.0, -6.0, 0.2, -0.1, 0.05])
    tare, xi0 = 0.1 * rng.normal(size=6), 1e-3 * rng.normal(size=6)
    y0, known_f0, Phi_f0 = rng.normal(size=6) * 1e-3, rng.normal(size=6), rng.normal(size=(6, 3))
    q_ref0, q_post = q + 1e-3 * rng.normal(size=n), q + 1e-2 * rng.normal(size=n)
    st.tare[0], st.xi[0], st.y[0], st.known_f[0], st.Phi_fT[0] = tare, xi0, y0, known_f0, Phi_f0.T
    st.q_ref[0], st.q_post[0] = q_ref0, q_post
    for col in (core.K_TARED, core.K_PRIMED, core.K_STARTED):
        st.k[0, col] = 1
    t = cfg.start.settle_s + 2.0 * cfg.control.ramp_s + 0.1  # drive fully on
    cmd = ctrl.step(t, q, qdot, wrench)
    lg = ctrl.last

    # ---- the same step, written out independently
    model = mujoco.MjModel.from_xml_path(str(known.arm_mjcf))
    p_O, R, J = _jac_site(model, mujoco.MjData(model), q)
    c, sc, ad, dt = cfg.control, cfg.sensing, cfg.adaptation, cfg.run.dt_s
    n_ax = np.array([0.0, 0.0, -1.0])
    S = nominal_sensor_map(sc, n_ax)
    W = channel_metric(sc)
    l_nom = np.asarray(sc.nominal_offset_f_m)
    w_env = np.r_[R @ (wrench[:3] - tare[:3]), R @ (wrench[3:] - tare[3:])]  # tool -> environment, world
    P_lat = -S[1:3, :3] / sc.stiffness_lat_N_per_m
    s = np.r_[n_ax @ (p_O + R @ l_nom - np.asarray(cfg.scene.bore_entry_w_m)), -P_lat @ w_env[:3], -w_env[3:]]
    np.testing.assert_allclose(lg.w_env_w, w_env, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(lg.s, s, rtol=1e-12, atol=1e-12)
    # eq. ft_force: F = -grad V
    F = np.r_[-np.clip(c.k_depth_N_per_m * (s[0] - c.depth_target_m), -c.depth_force_max_N, c.depth_force_max_N),
              -c.compliance_lat_m_per_N * s[1:3], -c.compliance_mom_rad_per_Nm * s[3:]]
    np.testing.assert_allclose(lg.F, F, rtol=1e-12, atol=1e-15)
    # eq. cp_admittance, implicit in the damping, on the drive (S Ad(R theta))^T F
    J_xi = AdjointFeatures(S, l_nom).twist_jacobian(type("K", (), {"R_wf": R})(), theta)
    tau = np.array([c.tau_trans_s] * 3 + [c.tau_ang_s] * 3)
    g = np.array([c.gain_trans] * 3 + [c.gain_ang] * 3)
    beta = np.array([c.beta_trans] * 3 + [c.beta_ang] * 3)
    M, D = tau / g, (1.0 + beta) / g
    xi = np.linalg.solve(np.diag(M / dt + D), M / dt * xi0 + J_xi.T @ F - w_env)
    assert np.linalg.norm(xi[:3]) < c.v_max_m_per_s and np.linalg.norm(xi[3:]) < c.w_max_rad_per_s
    np.testing.assert_allclose(lg.xi, xi, rtol=1e-9, atol=1e-15)
    # joint reference: qdot = J^+ xi + (I - J^+ J) k_ns (q_0 - q), J^+ = J^T (J J^T + 1e-6 I)^-1
    J_pinv = J.T @ np.linalg.inv(J @ J.T + 1e-6 * np.eye(6))
    z = c.nullspace_gain * (q_post - q)
    qdot_ref = J_pinv @ xi + (np.eye(n) - J_pinv @ J) @ z
    np.testing.assert_allclose(cmd.qdot_ref_rad_s, qdot_ref, rtol=1e-7, atol=1e-12)
    np.testing.assert_allclose(cmd.q_ref_rad, q_ref0 + dt * qdot_ref, rtol=1e-12, atol=1e-14)
    # filters and eq. ft_pred on the adjoint regressor Phi = S_v [w]x R, known = S xi_m + depth lever
    alpha = dt / (sc.filter_tau_s + dt)
    s_dot_meas = (s - y0) / (sc.filter_tau_s + dt)
    np.testing.assert_allclose(lg.s_dot_meas, s_dot_meas, rtol=1e-12, atol=1e-12)
    xi_m = J @ qdot
    w = xi_m[3:]
    S_v = S[:, :3].copy()
    S_v[0] = 0.0
    Phi = S_v @ np.cross(w[:, None], R, axis=0)  # [w]x R column by column
    known_rate = S @ xi_m
    known_rate[0] += n_ax @ np.cross(w, R @ l_nom)
    known_f = known_f0 + alpha * (known_rate - known_f0)
    Phi_f = Phi_f0 + alpha * (Phi - Phi_f0)
    pred = known_f + Phi_f @ theta
    eps_w = W * (s_dot_meas - pred)
    np.testing.assert_allclose(lg.s_dot_pred, pred, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(lg.adapt.eps_w, eps_w, rtol=1e-10, atol=1e-12)
    # eq. ft_composite: tracking + normalised prediction step (spectral norm), then Proj_Omega
    assert lg.adapt.gate == 1.0
    Hw = W[:, None] * Phi_f
    n2 = np.linalg.eigvalsh(Hw.T @ Hw)[-1]
    d_track = -dt * ad.gamma * ad.gamma_d * Phi.T @ F
    d_pred = ad.eta * Hw.T @ eps_w / (n2 + ad.eps_norm)
    half = np.array([ad.omega_lateral_m, ad.omega_lateral_m, ad.omega_axial_m])
    theta_next = np.clip(theta + d_track + d_pred, l_nom - half, l_nom + half)
    assert lg.adapt.phi_norm2 == pytest.approx(n2, rel=1e-12)
    np.testing.assert_allclose(lg.adapt.d_track, d_track, rtol=1e-10, atol=1e-18)
    np.testing.assert_allclose(lg.adapt.d_pred, d_pred, rtol=1e-10, atol=1e-18)
    np.testing.assert_allclose(ctrl.theta, theta_next, rtol=1e-12, atol=1e-15)
    assert not np.array_equal(ctrl.theta, theta)  # the step did move the estimate
    # the rank gate of the next step: lambda_min(W J_hat J_hat^T W), J_hat = J_hat_xi(theta+) J
    J_hat = AdjointFeatures(S, l_nom).twist_jacobian(type("K", (), {"R_wf": R})(), ctrl.theta) @ J
    lam = np.linalg.eigvalsh((W[:, None] * J_hat) @ (W[:, None] * J_hat).T)[0]
    assert ctrl.rank_margin_now() == pytest.approx(lam, rel=1e-8)


def test_dropout_is_held_then_refused():
    """Non-finite samples are held (theta unchanged); a run longer than max_dropout_s raises."""
    from kinadapt_nn.errors import SensorError

    cfg = load_config(None, ["run.progress=false", "sensing.max_dropout_s=0.003"])
    ctrl = make_controller(cfg)
    q, qd, w = np.array([0.0, -0.6, 0.0, -2.4, 0.0, 1.9, 0.7]), np.zeros(7), np.zeros(6)
    ctrl.step(0.0, q, qd, w)
    bad = np.full(6, np.nan)
    for i in range(3):
        cmd = ctrl.step(0.001 * (i + 1), q, qd, bad)
        assert np.all(np.isfinite(cmd.q_ref_rad)) and ctrl.dropouts == i + 1
    with pytest.raises(SensorError, match="non-finite"):
        ctrl.step(0.004, q, qd, bad)


def test_known_cfg_is_the_controllers_only_config():
    cfg = load_config(None, [])
    feats, theta0 = make_features(cfg)
    ctrl = Controller(replace(KnownCfg.of(cfg), law="frozen"), feats, theta0)
    assert ctrl.mode == "frozen" and not hasattr(ctrl, "cfg")


@pytest.mark.parametrize("features", ["neural", "rbf"])
def test_learned_features_in_the_kernel_equal_the_features(features):
    """The neural body and the RBF evaluated in the kernel give NeuralFeatures' / RBFFeatures'
    regressor and J_hat (the rank gate's lambda_min and the filtered regressor after one step from
    zero filter state)."""
    from kinadapt_nn.controller.controller import rank_margin
    from kinadapt_nn.features.base import KinState

    cfg = load_config(None, ["run.progress=false", f"run.features={features}"])
    ctrl = make_controller(cfg)
    assert ctrl.consts.c[core.FEAT] == {"neural": core.FEAT_NEURAL, "rbf": core.FEAT_RBF}[features]
    rng = np.random.default_rng(3)
    ctrl.theta = 0.1 * rng.normal(size=ctrl.features.n_params)
    th = ctrl.theta.copy()
    q = np.array([0.05, -0.55, 0.02, -2.35, 0.03, 1.85, 0.75])
    qdot = 0.05 * rng.normal(size=7)
    t = cfg.start.settle_s + 1.0
    ctrl.state.k[0, core.K_PRIMED] = 1
    ctrl.step(t, q, qdot, np.zeros(6))  # free space: the law does not move theta
    np.testing.assert_array_equal(ctrl.theta, th)
    model = mujoco.MjModel.from_xml_path(str(KnownCfg.of(cfg).arm_mjcf))
    p_O, R, J = _jac_site(model, mujoco.MjData(model), q)
    kin = KinState(q, p_O, R, J)
    reg = ctrl.features.regressor(kin, qdot)
    alpha = cfg.run.dt_s / (cfg.sensing.filter_tau_s + cfg.run.dt_s)
    np.testing.assert_allclose(ctrl.state.known_f[0], alpha * reg.known, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(ctrl.state.Phi_fT[0], alpha * reg.Phi.T, rtol=1e-9, atol=1e-12)
    lam = rank_margin(ctrl.W, ctrl.features.jacobian(kin, th))
    assert ctrl.rank_margin_now() == pytest.approx(lam, rel=1e-8)


@pytest.mark.parametrize("features", ["adjoint", "neural", "rbf"])
def test_compile_kernels_covers_every_kernel_a_step_calls(features):
    """``Controller.compile_kernels`` compiles exactly the specialisations the steps then use: after
    it, a run of steps adds no new signature to any kernel (so the one-time compile is the
    compile phase's, never the episode's first step)."""
    from kinadapt_nn.config import load_config
    from kinadapt_nn.runs.build import make_controller
    from kinadapt_nn.sim.adapter import PegInHoleSim

    cfg = load_config(None, [f"run.features={features}", "run.progress=false"])
    ctrl = make_controller(cfg)
    calls = ctrl.kernel_calls()
    assert calls and all(hasattr(fn, "signatures") for _, fn, _ in calls)
    ctrl.compile_kernels()
    before = {name: len(fn.signatures) for name, fn, _ in calls}
    sim = PegInHoleSim(cfg)
    for k in range(5):
        o = sim.sense()
        ctrl.step(sim.time_s, o.q_rad, o.qdot_rad_s, o.wrench_raw_f)
    assert {name: len(fn.signatures) for name, fn, _ in calls} == before


def test_sym_eigmin_matches_lapack():
    """The rank gate's smallest eigenvalue (cyclic Jacobi, ``dense.sym_eigmin``) against LAPACK on
    random 6x6 Grams of every scale, rank-deficient ones and indefinite ones included."""
    from kinadapt_nn.controller.dense import sym_eigmin

    rng = np.random.default_rng(0)
    for k in range(300):
        A = rng.normal(size=(6, 4 if k % 4 == 0 else 7)) * 10.0 ** rng.uniform(-4, 2, size=(6, 1))
        G = A @ A.T + (np.diag(rng.normal(size=6)) if k % 3 == 0 else 0.0)
        ref = np.linalg.eigvalsh(G)[0]
        assert abs(sym_eigmin(G) - ref) <= 1e-13 * np.linalg.norm(G, 2)


def test_gram_sparse_matches_numpy():
    """The law's Gram (W Phi_f)^T (W Phi_f) from the non-zero entries only (``dense.gram_sparse``)
    equals numpy's A A^T on dense, block-sparse (the RBF's rows) and all-zero regressors."""
    from kinadapt_nn.controller.dense import gram_sparse

    rng = np.random.default_rng(1)
    dense = rng.normal(size=(7, 6))
    blocks = np.zeros((40, 6))
    for i in range(5):
        blocks[8 * i:8 * (i + 1), 1 + i] = rng.normal(size=8)
    for A in (dense, blocks, np.zeros((5, 6))):
        np.testing.assert_allclose(gram_sparse(A), A @ A.T, rtol=1e-13, atol=1e-15)



def test_gram_sparse_log_adds_exactly_what_adding_the_whole_gram_adds():
    """``dense.gram_sparse_log`` (the kernels' Gram and observability log in one pass, blocks only
    where the channels' rows are disjoint) leaves the log bit for bit where ``log += A A^T`` would,
    and returns ``gram_sparse``'s Gram: contiguous blocks (the RBF), scattered disjoint rows,
    overlapping channels, a dense regressor and an all-zero one, over a few steps."""
    from kinadapt_nn.controller.dense import gram_sparse, gram_sparse_log

    rng = np.random.default_rng(2)
    cases = [rng.normal(size=(3, 6)), np.zeros((12, 6))]
    blocks, scattered, overlap = np.zeros((60, 6)), np.zeros((60, 6)), np.zeros((60, 6))
    for i in range(5):
        blocks[12 * i:12 * (i + 1), 1 + i] = rng.normal(size=12)
        scattered[rng.choice(60, 7, replace=False) if i == 0 else np.arange(i, 60, 5)[:7], 1 + i] = rng.normal(size=7)
        overlap[10 * i:10 * i + 15, 1 + i] = rng.normal(size=15)
    scattered[:, 1:] *= (np.cumsum(scattered[:, 1:] != 0, axis=1) <= 1)  # keep each row in one channel
    cases += [blocks, scattered, overlap]
    for A in cases:
        log_ref = rng.normal(size=(A.shape[0],) * 2)
        log = log_ref.copy()
        for _ in range(3):
            G = gram_sparse_log(A, log)
            log_ref += gram_sparse(A)
            np.testing.assert_array_equal(G, gram_sparse(A))
            np.testing.assert_array_equal(log, log_ref)

def test_chol_solve_cols_is_chol_solve_per_column():
    """The kalman law's multi-column solve (``dense.chol_solve_cols``) gives each column exactly
    what ``chol_solve`` gives it alone, and solves the system (against numpy)."""
    from kinadapt_nn.controller.dense import chol, chol_solve, chol_solve_cols

    rng = np.random.default_rng(3)
    A = rng.normal(size=(6, 6))
    S = A @ A.T + 6 * np.eye(6)
    L = S.copy()
    assert chol(L, 6)
    B = rng.normal(size=(6, 40))
    X = B.copy()
    chol_solve_cols(L, 6, X)
    for j in range(B.shape[1]):
        col = B[:, j].copy()
        chol_solve(L, 6, col)
        assert np.array_equal(X[:, j], col)
    np.testing.assert_allclose(S @ X, B, rtol=1e-12, atol=1e-12)


def test_bound_entry_point_steps_as_the_dispatcher_does():
    """``Controller`` calls its fused step through ``core.entry_point`` (types resolved once): 50
    steps give the same outputs and state, to the last bit, as the dispatcher given ``t`` as a
    float, whether ``t`` reaches the entry as a float, an int or a numpy scalar."""
    cfg = load_config(None, [])
    rng = np.random.default_rng(7)
    samples = [(rng.normal(0.0, 0.3, 7), rng.normal(0.0, 0.1, 7), rng.normal(0.0, 2.0, 6)) for _ in range(50)]

    def run(times, via_dispatcher: bool) -> tuple[np.ndarray, np.ndarray]:
        c = make_controller(cfg)
        c.compile_kernels()
        assert c._fused_call is not c._fused  # bound to the compiled entry
        if via_dispatcher:
            c._fused_call = c._fused
        for t, (q, qd, w) in zip(times, samples):
            c.step(t, q, qd, w)
        return c.out.copy(), c.state.x.copy()

    dt = cfg.run.dt_s
    for times in ([i * dt for i in range(50)], list(range(50)), [np.float64(i * dt) for i in range(50)],
                  [np.float32(i * dt) for i in range(50)]):
        want = run([float(t) for t in times], True)
        got = run(times, False)
        assert np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1])


def test_the_kernels_are_one_step_sequence():
    """Every step kernel (the three fused ones and the generic path's) is the one ``_step`` code,
    compiled with its kind's parts, and each is cached under its own name (issue 52); the neural and
    RBF parts are one code each, with their basis, rows and J_hat."""
    from kinadapt_nn.controller import step_kernels as sk

    kernels = [*core.FUSED.values(), sk._step_given]
    assert all(k.py_func.__code__ is sk._step.__code__ for k in kernels)
    assert len({k.py_func.__qualname__ for k in kernels}) == len(kernels)
    parts = [tuple(k.py_func.__globals__[f] for f in ("front_fn", "rows_fn", "drive_fn", "rank_fn"))
             for k in kernels]
    assert len(set(parts)) == len(kernels)  # a kind's own parts
    for generic, kinds in ((sk._learned_rows, (sk._neural_rows_part, sk._rbf_rows_part)),
                           (sk._learned_drive, (sk._neural_drive, sk._rbf_drive)),
                           (sk._learned_rank, (sk._neural_rank, sk._rbf_rank))):  # the learned kinds' parts: one code
        assert all(k.py_func.__code__ is generic.__code__ for k in kinds)


def test_fused_step_equals_the_generic_path():
    """The adjoint's fused kernel (its rows, drive and rank gate in the kernel) against the generic
    path (``sense_kernel``, the rows and J_hat_xi from ``AdjointFeatures`` in numpy, ``act_kernel``),
    both fed the same samples of an episode driven by the first: the same commands, theta and rank
    rate prediction at every step, to the rounding of numpy's sums against the kernel's."""
    import copy

    from kinadapt_nn.sim.adapter import PegInHoleSim

    class NumpyAdjoint(AdjointFeatures):  # the same maths, from Python (no fused kernel serves a subclass)
        def regressor(self, kin, qdot):
            return AdjointFeatures.regressor(self, kin, qdot)

    cfg = load_config(None, ["run.progress=false", "adaptation.mode=composite"])  # (the default kalman holds theta here)
    feats, theta0 = make_features(cfg)
    generic_feats = copy.copy(feats)
    generic_feats.__class__ = NumpyAdjoint
    fused, generic = (Controller(KnownCfg.of(cfg), f, theta0.copy()) for f in (feats, generic_feats))
    assert fused.consts.c[core.FEAT] == core.FEAT_ADJOINT and generic.consts.c[core.FEAT] != core.FEAT_ADJOINT
    sim = PegInHoleSim(cfg)
    sim.reset()
    n_steps = int(round(4.5 / cfg.run.dt_s))  # [s] through contact (the default episode seats at 4.8 s)
    for _ in range(n_steps):
        o = sim.sense()
        a = fused.step(sim.time_s, o.q_rad, o.qdot_rad_s, o.wrench_raw_f)
        b = generic.step(sim.time_s, o.q_rad, o.qdot_rad_s, o.wrench_raw_f)
        np.testing.assert_allclose(b.q_ref_rad, a.q_ref_rad, rtol=0, atol=1e-9)
        np.testing.assert_allclose(b.qdot_ref_rad_s, a.qdot_ref_rad_s, rtol=0, atol=1e-9)
        np.testing.assert_allclose(generic.theta, fused.theta, rtol=0, atol=1e-9)
        np.testing.assert_allclose(generic.last.s_dot_pred, fused.last.s_dot_pred, rtol=0, atol=1e-9)
        sim.apply(a.q_ref_rad, a.qdot_ref_rad_s)
        sim.step()
    assert np.linalg.norm(fused.theta - theta0) > 1e-3 and fused.contact_steps > 1000  # the law moved theta in contact
