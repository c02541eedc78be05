"""Geometry (skew, tool-offset adjoint), the sensor vector s = [d, F_lat, M], the nominal map S,
the adjoint features / regressor, the rate filters and the F/T wrench convention, each checked
against an independent computation (simulated MuJoCo quantities, finite differences, or a
small contact model written out here)."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from numpy.testing import assert_allclose

from kinadapt_nn.config import load_config
from kinadapt_nn.runs.build import make_controller
from kinadapt_nn.geometry import adjoint_offset, skew
from kinadapt_nn.robot import JOINT_LIMITS_RAD, N_JOINTS
from kinadapt_nn.sensing import LowPass, RateFilter, nominal_sensor_map
from kinadapt_nn.known import BORE_AXIS_W
from kinadapt_nn.sim.adapter import PegInHoleSim

N_CONFIGS = 12


# ------------------------------------------------------------------------------------------
# fixtures
# ------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def cfg():
    return load_config(None, [])


@pytest.fixture(scope="module")
def sim(cfg):
    return PegInHoleSim(cfg)


@pytest.fixture(scope="module")
def ctrl(cfg):
    return make_controller(cfg)


def _random_q(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 7) configurations strictly inside the joint limits."""
    lo, hi = JOINT_LIMITS_RAD[:, 0], JOINT_LIMITS_RAD[:, 1]
    margin = 0.05 * (hi - lo)
    return rng.uniform(lo + margin, hi - margin, size=(n, N_JOINTS))


def _set_state(sim: PegInHoleSim, q: np.ndarray, qdot: np.ndarray | None = None) -> None:
    d = sim.data
    d.qpos[sim.ids.qpos_adr] = q
    d.qvel[:] = 0.0
    if qdot is not None:
        d.qvel[sim.ids.dof_adr] = qdot
    mujoco.mj_forward(sim.model, d)


def _site_twist(sim, site_id: int) -> np.ndarray:
    """World-frame twist [v; omega] of a site (mj_objectVelocity with flg_local=0 gives [omega; v])."""
    res = np.zeros(6)
    mujoco.mj_objectVelocity(sim.model, sim.data, mujoco.mjtObj.mjOBJ_SITE, site_id, res, 0)
    return np.concatenate([res[3:], res[:3]])


def _lateral_projector_independent(n: np.ndarray) -> np.ndarray:
    """P (2, 3) for the vertical bore n = -z: world x and y (module docstring of sensing)."""
    assert np.allclose(n, [0.0, 0.0, -1.0])
    return np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


# ------------------------------------------------------------------------------------------
# 1. adjoint_offset against the simulated tip
# ------------------------------------------------------------------------------------------
def test_adjoint_offset_matches_simulated_tip_velocity(cfg, sim):
    """Ad(R_wf l_f) [v_O; w] vs MuJoCo's tip-site velocity (mj_objectVelocity) and vs central FD of site_xpos."""
    m, d, ids = sim.model, sim.data, sim.ids
    rng = np.random.default_rng(101)
    offset_f = np.asarray(cfg.tool.offset_f_m)
    h = 1e-6
    max_rel_vel, max_rel_fd = 0.0, 0.0
    try:
        for q in _random_q(rng, N_CONFIGS):
            qdot = rng.normal(0.0, 1.0, N_JOINTS)
            _set_state(sim, q, qdot)
            # flange (= ft_site, origin O) twist; mj_objectVelocity(flg_local=0) -> [omega; v] at the site
            xi_O = _site_twist(sim, ids.ft_site)
            tip_true = _site_twist(sim, ids.tip_site)
            R_wf = d.site_xmat[ids.ft_site].reshape(3, 3).copy()
            # the site convention itself, independently: mj_jacSite at the tip site
            jacp, jacr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
            mujoco.mj_jacSite(m, d, jacp, jacr, ids.tip_site)
            assert_allclose(tip_true, np.concatenate([jacp @ d.qvel, jacr @ d.qvel]), rtol=0, atol=1e-12)

            tip_pred = adjoint_offset(R_wf @ offset_f) @ xi_O
            scale = np.linalg.norm(tip_true)
            err = np.abs(tip_pred - tip_true).max() / scale
            max_rel_vel = max(max_rel_vel, err)
            assert err < 1e-10, f"Ad vs mj_objectVelocity: rel err {err:.2e}"

            # central finite difference of the true tip position along qdot
            qpos0 = d.qpos.copy()
            pos = []
            for sgn in (+1.0, -1.0):
                qp = qpos0.copy()
                mujoco.mj_integratePos(m, qp, sgn * d.qvel, h)
                d.qpos[:] = qp
                mujoco.mj_kinematics(m, d)
                pos.append(d.site_xpos[ids.tip_site].copy())
            d.qpos[:] = qpos0
            v_fd = (pos[0] - pos[1]) / (2 * h)
            err_fd = np.abs(tip_pred[:3] - v_fd).max() / np.linalg.norm(v_fd)
            max_rel_fd = max(max_rel_fd, err_fd)
            assert err_fd < 1e-8, f"Ad vs FD tip velocity: rel err {err_fd:.2e}"
    finally:
        sim.reset()
    print(f"max rel err Ad vs objectVelocity {max_rel_vel:.1e}, vs FD {max_rel_fd:.1e}")


# ------------------------------------------------------------------------------------------
# 2./3. algebra of Ad and skew
# ------------------------------------------------------------------------------------------
def test_adjoint_offset_affine_and_inverse():
    """Ad(l) algebra vs direct construction: affine in l, Ad(l) Ad(-l) = I, Ad(a)Ad(b) = Ad(a+b), v + w x l."""
    rng = np.random.default_rng(202)
    I6 = np.eye(6)
    for _ in range(50):
        l1, l2 = rng.normal(0.0, 0.2, 3), rng.normal(0.0, 0.2, 3)
        a, b = rng.normal(size=2)
        # difference depends on l1 - l2 only, linearly
        assert_allclose(adjoint_offset(l1) - adjoint_offset(l2), adjoint_offset(l1 - l2) - I6, atol=1e-15)
        assert_allclose(
            adjoint_offset(a * l1 + b * l2),
            a * adjoint_offset(l1) + b * adjoint_offset(l2) + (1.0 - a - b) * I6,
            atol=1e-14,
        )
        assert_allclose(adjoint_offset(l1) @ adjoint_offset(-l1), I6, atol=1e-15)
        assert_allclose(adjoint_offset(l1) @ adjoint_offset(l2), adjoint_offset(l1 + l2), atol=1e-15)
        # the defining relation on a random twist
        xi = rng.normal(size=6)
        v_tip = xi[:3] + np.cross(xi[3:], l1)
        assert_allclose(adjoint_offset(l1) @ xi, np.concatenate([v_tip, xi[3:]]), atol=1e-14)
    assert_allclose(adjoint_offset(np.zeros(3)), I6, atol=0)


def test_skew_equals_cross_product():
    """skew(a) @ b vs np.cross(a, b), and skew(a) antisymmetric."""
    rng = np.random.default_rng(303)
    for _ in range(100):
        a, b = rng.normal(size=3) * 10 ** rng.uniform(-3, 3), rng.normal(size=3)
        assert_allclose(skew(a) @ b, np.cross(a, b), rtol=1e-14, atol=1e-14 * np.linalg.norm(a))
        assert_allclose(skew(a), -skew(a).T, atol=0)
        assert_allclose(skew(a) @ a, np.zeros(3), atol=1e-14 * np.linalg.norm(a) ** 2)


# ------------------------------------------------------------------------------------------
# 4. depth channel
# ------------------------------------------------------------------------------------------
def _depth(ctrl, q: np.ndarray) -> float:
    return float(ctrl.sensor_vector(ctrl.kin(q), np.zeros(6))[0])


#: nominal offsets: the default (along z_f) and one with lateral parts (R_wf vs R_wf^T differ there)
NOMINALS = [None, (0.012, -0.021, 0.095)]


def _cfg_with_nominal(nominal, tool_too: bool):
    if nominal is None:
        return load_config(None, [])
    over = [f"sensing.nominal_offset_f_m=[{nominal[0]}, {nominal[1]}, {nominal[2]}]"]
    if tool_too:
        over.append(f"tool.offset_f_m=[{nominal[0]}, {nominal[1]}, {nominal[2]}]")
    return load_config(None, over)


@pytest.mark.parametrize("nominal", NOMINALS)
def test_depth_row_matches_finite_difference(nominal):
    """Row 0 of features.jacobian(kin, theta) @ qdot vs central FD of the controller's d(q); theta-independent."""
    ctrl = make_controller(_cfg_with_nominal(nominal, tool_too=False))
    rng = np.random.default_rng(404)
    h = 1e-6
    max_rel = 0.0
    for q in _random_q(rng, N_CONFIGS):
        qdot = rng.normal(0.0, 1.0, N_JOINTS)
        kin = ctrl.kin(q.copy())
        th1, th2 = rng.normal(0.0, 0.1, 3), rng.normal(0.0, 0.1, 3)
        J1 = ctrl.features.jacobian(kin, th1)
        J2 = ctrl.features.jacobian(kin, th2)
        assert_allclose(J1[0], J2[0], rtol=0, atol=1e-15)  # the depth row never sees theta
        assert not np.allclose(J1[1:], J2[1:])  # ... but the other rows do
        d_fd = (_depth(ctrl, q + h * qdot) - _depth(ctrl, q - h * qdot)) / (2 * h)
        d_an = J1[0] @ qdot
        rel = abs(d_an - d_fd) / max(abs(d_fd), 1e-3)
        max_rel = max(max_rel, rel)
        assert rel < 1e-7, f"depth rate: analytic {d_an:.6e} vs FD {d_fd:.6e}"
    print(f"max rel err depth row vs FD {max_rel:.1e}")


@pytest.mark.parametrize("nominal", NOMINALS)
def test_depth_equals_true_tip_depth_for_nominal_tool(cfg, nominal):
    """Controller d(q) vs sim.truth().tip_depth_m (true tip site) when the true tool is the nominal one."""
    nom = cfg.sensing.nominal_offset_f_m if nominal is None else nominal
    cfg_nom = load_config(
        None,
        [
            f"sensing.nominal_offset_f_m=[{nom[0]}, {nom[1]}, {nom[2]}]",
            f"tool.offset_f_m=[{nom[0]}, {nom[1]}, {nom[2]}]",
            "tool.tilt_deg=[0.0, 0.0]",
        ],
    )
    sim_nom = PegInHoleSim(cfg_nom)
    ctrl_nom = make_controller(cfg_nom)
    rng = np.random.default_rng(505)
    for i in range(N_CONFIGS):
        q = sim_nom.q_start + (0.0 if i == 0 else 1.0) * rng.normal(0.0, 0.1, N_JOINTS)
        _set_state(sim_nom, q)
        assert_allclose(_depth(ctrl_nom, q), sim_nom.truth().tip_depth_m, rtol=0, atol=1e-12)
    # at the start pose the true tip is tip_height above the entrance
    _set_state(sim_nom, sim_nom.q_start)
    assert_allclose(_depth(ctrl_nom, sim_nom.q_start), -cfg_nom.start.tip_height_m, atol=1e-9)


def test_depth_offset_by_tool_mismatch(cfg, sim, ctrl):
    """Default (mismatched) tool: d(q) - true depth vs n . R_wf (l_nom - l_true) computed from the sim's flange pose."""
    rng = np.random.default_rng(506)
    n = BORE_AXIS_W
    dl = np.asarray(cfg.sensing.nominal_offset_f_m) - np.asarray(cfg.tool.offset_f_m)
    try:
        for i in range(N_CONFIGS):
            q = sim.q_start + (0.0 if i == 0 else 1.0) * rng.normal(0.0, 0.1, N_JOINTS)
            _set_state(sim, q)
            R_wf = sim.data.site_xmat[sim.ids.ft_site].reshape(3, 3)
            assert_allclose(_depth(ctrl, q) - sim.truth().tip_depth_m, n @ R_wf @ dl, rtol=0, atol=1e-12)
    finally:
        sim.reset()


# ------------------------------------------------------------------------------------------
# 5. regressor identity and the adjoint features against adjoint_offset / the simulated tip
# ------------------------------------------------------------------------------------------
def test_regressor_identity_and_fd_in_theta(ctrl):
    """J_hat qdot vs known + Phi theta, Phi vs FD in theta, and J_hat vs S Ad(R theta) J_arm built by hand."""
    rng = np.random.default_rng(606)
    feats, S = ctrl.features, ctrl.S
    l_nom_f = np.asarray(ctrl.l_nom_f)
    max_rel = 0.0
    for q in _random_q(rng, N_CONFIGS):
        kin = ctrl.kin(q.copy())
        qdot = rng.normal(0.0, 1.0, N_JOINTS)
        theta = rng.normal(0.0, 0.1, 3)
        reg = feats.regressor(kin, qdot)
        assert reg.Phi.shape == (6, 3)
        pred = feats.jacobian(kin, theta) @ qdot
        scale = np.abs(pred).max()
        err = np.abs(pred - (reg.known + reg.Phi @ theta)).max() / scale
        max_rel = max(max_rel, err)
        assert err < 1e-12
        assert_allclose(feats.predict_rate(kin, qdot, theta), pred, rtol=0, atol=1e-12 * scale)
        # Phi: finite difference of J_hat(theta) qdot in theta (affine, so any step is exact)
        hstep = 0.01
        Phi_fd = np.column_stack(
            [(feats.jacobian(kin, theta + hstep * e) @ qdot - pred) / hstep for e in np.eye(3)]
        )
        assert_allclose(Phi_fd, reg.Phi, rtol=0, atol=1e-9 * max(np.abs(reg.Phi).max(), 1.0))
        assert_allclose(reg.Phi[0], 0.0, atol=0)  # depth row not adapted
        # independent construction from geometry.adjoint_offset
        xi = kin.J_arm @ qdot
        R = kin.R_wf
        expect = S @ adjoint_offset(R @ theta) @ xi
        expect[0] = S[0] @ adjoint_offset(R @ l_nom_f) @ xi
        assert_allclose(pred, expect, rtol=0, atol=1e-12 * scale)
    print(f"max rel err regressor identity {max_rel:.1e}")


def test_oracle_jacobian_matches_simulated_tip_twist(cfg, sim, ctrl):
    """Rows 1:6 of J_hat(theta = true offset) qdot vs S @ [true tip velocity; omega] read from the simulator."""
    ids = sim.ids
    rng = np.random.default_rng(607)
    theta_true = np.asarray(cfg.tool.offset_f_m)
    try:
        for q in _random_q(rng, N_CONFIGS):
            qdot = rng.normal(0.0, 1.0, N_JOINTS)
            _set_state(sim, q, qdot)
            tip_twist = _site_twist(sim, ids.tip_site)
            pred = ctrl.features.jacobian(ctrl.kin(q.copy()), theta_true) @ qdot
            expect = ctrl.S @ tip_twist
            assert_allclose(pred[1:], expect[1:], rtol=0, atol=1e-10 * np.abs(expect).max())
    finally:
        sim.reset()


# ------------------------------------------------------------------------------------------
# 6. the nominal sensor map S against a point-contact model
# ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("nominal", NOMINALS)
def test_sensor_map_matches_point_contact_model(nominal):
    """S @ [v_tip; w] vs central FD in time of s(t) of a lateral spring at the nominal tip plus a k_r couple."""
    sc = _cfg_with_nominal(nominal, tool_too=False).sensing
    n = BORE_AXIS_W
    S = nominal_sensor_map(sc, n)
    k_t, k_r = sc.stiffness_lat_N_per_m, sc.stiffness_rot_Nm_per_rad
    L = np.sqrt(sum(x * x for x in sc.nominal_offset_f_m))  # |l_nom|: lever along n
    P = _lateral_projector_independent(n)
    assert_allclose(S[3:, 3:], -k_r * np.eye(3), atol=0)
    assert_allclose(S[0], np.concatenate([n, np.zeros(3)]), atol=0)

    def s_of_t(t, v_tip, w):
        # the tip moves by delta = v_tip t; the tool (and the lever O -> tip) rotates by exp([w t]x)
        wn = np.linalg.norm(w)
        K = skew(w / wn) if wn > 0 else np.zeros((3, 3))
        Rt = np.eye(3) + np.sin(wn * t) * K + (1 - np.cos(wn * t)) * K @ K
        l_w = Rt @ (L * n)
        delta = v_tip * t
        f = -k_t * P.T @ P @ delta  # lateral spring force on the tool at the contact (tip)
        M = np.cross(l_w, f) - k_r * (w * t)  # about O, plus the contact couple
        depth = n @ delta  # depth of the tip (entrance at the start position)
        return np.concatenate([[depth], P @ f, M])

    rng = np.random.default_rng(707)
    h = 1e-5
    max_rel = 0.0
    for _ in range(20):
        v_tip, w = rng.normal(0.0, 0.05, 3), rng.normal(0.0, 0.5, 3)
        rate_fd = (s_of_t(h, v_tip, w) - s_of_t(-h, v_tip, w)) / (2 * h)
        rate_S = S @ np.concatenate([v_tip, w])
        err = np.abs(rate_S - rate_fd) / np.array([0.05, k_t * 0.05, k_t * 0.05] + [k_t * L * 0.05] * 3)
        max_rel = max(max_rel, err.max())
        assert_allclose(rate_S[1:], rate_fd[1:], rtol=1e-8, atol=1e-9 * np.abs(rate_S[1:]).max())
        assert_allclose(rate_S[0], rate_fd[0], rtol=1e-8, atol=1e-14)
        # pure rotation at the tip: no lateral force rate, only the couple
        assert_allclose(S[1:3] @ np.concatenate([np.zeros(3), w]), 0.0, atol=0)
        assert_allclose(S[3:] @ np.concatenate([np.zeros(3), w]), -k_r * w, rtol=1e-15)
    print(f"max scaled err S vs point-contact FD {max_rel:.1e}")


def test_sensor_map_lateral_frame_general_axis(cfg):
    """Tilted bore axis: S's force/moment rows vs -k_t P, l x f with P orthonormal and perpendicular to n."""
    rng = np.random.default_rng(708)
    k_t = cfg.sensing.stiffness_lat_N_per_m
    L = np.linalg.norm(cfg.sensing.nominal_offset_f_m)
    for _ in range(20):
        n = rng.normal(size=3)
        n /= np.linalg.norm(n)
        S = nominal_sensor_map(cfg.sensing, 3.0 * n)  # not normalised on purpose
        P = -S[1:3, :3] / k_t
        assert_allclose(P @ P.T, np.eye(2), atol=1e-14)
        assert_allclose(P @ n, 0.0, atol=1e-14)
        assert_allclose(S[0, :3], n, atol=1e-15)
        v = rng.normal(size=3)
        assert_allclose(S[3:, :3] @ v, np.cross(L * n, -k_t * P.T @ P @ v), rtol=1e-12, atol=1e-9)


# ------------------------------------------------------------------------------------------
# 7. filters
# ------------------------------------------------------------------------------------------
def test_rate_filter_ramp_and_lowpass_identity(cfg):
    """RateFilter vs the ramp slope a, and vs LowPass of the backward difference sample by sample."""
    dt, tau = cfg.run.dt_s, cfg.sensing.filter_tau_s
    a = np.array([0.3, -2.0, 5.0])
    rf = RateFilter(tau, dt, 3)
    n_steps = int(round(60 * tau / dt))
    r = None
    for k in range(n_steps):
        r = rf.rate(a * k * dt + np.array([1.0, -4.0, 0.5]))
    assert_allclose(r, a, rtol=1e-12)

    rng = np.random.default_rng(808)
    s = np.cumsum(rng.normal(0.0, 1e-2, size=(400, 4)), axis=0) + rng.normal(size=4)
    rf = RateFilter(tau, dt, 4)
    lp = LowPass(tau, dt, (4,))
    assert_allclose(rf.rate(s[0]), 0.0, atol=0)  # primed on the first sample
    max_err = 0.0
    for k in range(1, len(s)):
        r = rf.rate(s[k])
        z = lp((s[k] - s[k - 1]) / dt).copy()
        err = np.abs(r - z).max()
        max_err = max(max_err, err / max(np.abs(z).max(), 1.0))
        assert_allclose(r, z, rtol=1e-11, atol=1e-12)
    print(f"max err RateFilter vs LowPass(backward diff) {max_err:.1e}")


# ------------------------------------------------------------------------------------------
# 8. wrench sign and transport through the controller
# ------------------------------------------------------------------------------------------
def _settle(sim: PegInHoleSim, n_steps: int):
    for _ in range(n_steps):
        sim.step()
    return sim.sense()


@pytest.mark.parametrize(
    "force_w, torque_w",
    [((3.0, -2.0, 4.0), (0.0, 0.0, 0.0)), ((-1.5, 2.5, 2.0), (0.1, -0.05, 0.2))],
)
def test_wrench_convention_static_external_load(cfg, force_w, torque_w):
    """Controller w_env_w, s[1:] vs applied xfrc (env on tool) moved to O: w_env = -[f; M_O] (statics of the tool)."""
    sim = PegInHoleSim(cfg)
    m, d, ids = sim.model, sim.data, sim.ids
    tool = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "tool")
    dt = cfg.run.dt_s
    obs0 = _settle(sim, 500)  # servo holds q_start (ctrl = q_start from reset)
    assert np.abs(obs0.qdot_rad_s).max() < 1e-4
    # tare through the controller's own path (free-space window just before settle_s)
    ctrl = make_controller(cfg)
    t_tare0 = cfg.start.settle_s - cfg.sensing.tare_window_s
    for t in np.arange(t_tare0, cfg.start.settle_s - 0.5 * dt, dt):
        ctrl.step(float(t), obs0.q_rad, obs0.qdot_rad_s, obs0.wrench_raw_f)
    # apply a known external wrench (world frame, at the tool COM) and let it settle
    f = np.asarray(force_w, dtype=float)
    tau = np.asarray(torque_w, dtype=float)
    d.xfrc_applied[tool, :3] = f
    d.xfrc_applied[tool, 3:] = tau
    obs1 = _settle(sim, 1000)
    assert np.abs(obs1.qdot_rad_s).max() < 1e-4
    assert sim.truth().contact_force_N == 0.0  # no contact: the only external load is xfrc
    p_O = d.site_xpos[ids.ft_site]
    M_O = np.cross(d.xipos[tool] - p_O, f) + tau  # env -> tool wrench about O, world
    ctrl.step(cfg.start.settle_s + 0.5 * cfg.control.ramp_s, obs1.q_rad, obs1.qdot_rad_s, obs1.wrench_raw_f)
    w_env = ctrl.last.w_env_w
    # independent rotation of the raw difference with the simulator's own flange orientation
    R_wf = d.site_xmat[ids.ft_site].reshape(3, 3)
    dr = obs1.wrench_raw_f - obs0.wrench_raw_f
    assert_allclose(w_env, np.concatenate([R_wf @ dr[:3], R_wf @ dr[3:]]), atol=1e-6)
    # sign, from first principles: static tool => flange-on-tool + env-on-tool + weight = 0, so
    # (r - r0) = -(env on tool) = tool on environment
    tol_f = 0.02 * np.linalg.norm(f)
    tol_m = 0.02 * np.linalg.norm(M_O) + 1e-3
    assert np.linalg.norm(w_env[:3] + f) < tol_f, (w_env[:3], -f)
    assert np.linalg.norm(w_env[3:] + M_O) < tol_m, (w_env[3:], -M_O)
    assert w_env[:3] @ f < -0.95 * f @ f
    # s = [d, F_lat, M]: lateral contact force and moment *on the tool*
    s = ctrl.last.s
    P = _lateral_projector_independent(BORE_AXIS_W)
    assert np.linalg.norm(s[1:3] - P @ f) < tol_f
    assert np.linalg.norm(s[3:] - M_O) < tol_m
    print(f"wrench err force {np.linalg.norm(w_env[:3] + f):.1e} N, moment {np.linalg.norm(w_env[3:] + M_O):.1e} N m")


def test_skews_are_the_cross_product_of_each_row():
    """``skews``: column j of each matrix is ``np.cross(a_i, e_j)`` to the bit (the effect columns built
    from it are the cross products they replace), and the matrix times b is ``a_i x b``."""
    from kinadapt_nn.geometry import skews

    rng = np.random.default_rng(7)
    a, b = 10.0 * rng.normal(size=(200, 3)), rng.normal(size=(200, 3))
    S = skews(a)
    for j, e in enumerate(np.eye(3)):
        np.testing.assert_array_equal(S[:, :, j], np.cross(a, e))
    np.testing.assert_allclose(np.einsum("nij,nj->ni", S, b), np.cross(a, b), rtol=0, atol=1e-13)
    np.testing.assert_array_equal(S, -np.swapaxes(S, 1, 2))
