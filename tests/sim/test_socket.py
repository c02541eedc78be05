"""The socket contact kernel (``sim.socket.socket_step``) against an independent numpy evaluation
of its formulas with MuJoCo's own ``mj_objectVelocity``."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from kinadapt_nn.config import load_config
from kinadapt_nn.geometry import rotvec_from_matrix
from kinadapt_nn.known import BORE_AXIS_W
from kinadapt_nn.sim.adapter import PegInHoleSim
from kinadapt_nn.sim.socket import N_STATE, socket_params, socket_step


def _moving_sim(over):
    """A socket scene whose arm moves (servo set-points swept about the start pose)."""
    sim = PegInHoleSim(load_config(None, ["scene.contact_model=socket", *over]))
    for k in range(150):
        sim.data.ctrl[:] = sim.q_start + 0.05 * np.sin(0.05 * k + np.arange(7))
        mujoco.mj_step(sim.model, sim.data)
    return sim


def test_tip_velocity_from_cvel_is_mj_object_velocity():
    sim = _moving_sim([])
    m, d, ids = sim.model, sim.data, sim.ids
    ref = np.zeros(6)
    mujoco.mj_objectVelocity(m, d, mujoco.mjtObj.mjOBJ_SITE, ids.tip_site, ref, 0)
    assert np.linalg.norm(ref) > 1e-3  # it moves
    # the kernel's velocity, read back through a zero-stiffness socket with unit damping
    cfg = sim.cfg.model_copy(update={"scene": sim.cfg.scene.model_copy(update={
        "socket_k_lat_N_per_m": 0.0, "socket_k_rot_Nm_per_rad": 1e-4, "socket_engage": "drive"})})
    prm = socket_params(cfg, sim.entry_w, BORE_AXIS_W)
    prm[3], prm[6], prm[7] = -1.0, 0.0, -1.0  # c_lat, k_rot, c_rot: f_xy = v_xy, tau = w
    st, xfrc = np.zeros(N_STATE), np.zeros(6)
    tb = sim._tool_body
    vb = int(m.site_bodyid[ids.tip_site])
    tip = d.site_xpos[ids.tip_site]
    socket_step(cfg.start.settle_s, st, prm, tip, d.xmat[tb], tip, d.cvel[vb],
                d.subtree_com[int(m.body_rootid[vb])], xfrc)
    np.testing.assert_allclose(xfrc[:2], ref[3:5], rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(xfrc[3:], ref[:3], rtol=1e-12, atol=1e-15)


def _reference(t, anchor, prm_cfg, tip, R, com, vel6, entry):
    """The socket's wrench by its formulas in numpy (the module docstring); anchor: (p0, R0) or None."""
    sc, settle, fc = prm_cfg.scene, prm_cfg.start.settle_s, prm_cfg.effects.contact_friction_couple
    depth = float(BORE_AXIS_W @ (tip - entry))
    if sc.socket_engage == "drive":
        if t < settle:
            return None, anchor
    elif anchor is None and depth < 0.0 or anchor is not None and depth < -1e-3:
        return np.zeros(6), None
    if anchor is None:
        anchor = (tip.copy(), R.copy())
    p0, R0 = anchor
    w, v = vel6[:3], vel6[3:]
    c_lat = 2.0 * sc.socket_damping_ratio * np.sqrt(sc.socket_k_lat_N_per_m * 3.0)
    f = np.zeros(3)
    f[:2] = -sc.socket_k_lat_N_per_m * (tip[:2] - p0[:2]) - c_lat * v[:2]
    if sc.socket_k_axial_N_per_m > 0.0 and depth > 0.0:
        c_ax = 2.0 * sc.socket_damping_ratio * np.sqrt(sc.socket_k_axial_N_per_m * 3.0)
        f -= BORE_AXIS_W * (sc.socket_k_axial_N_per_m * depth + c_ax * float(BORE_AXIS_W @ v))
    c_rot = 2.0 * sc.socket_damping_ratio * np.sqrt(sc.socket_k_rot_Nm_per_rad * 0.01)
    tau = -sc.socket_k_rot_Nm_per_rad * rotvec_from_matrix(R @ R0.T) - c_rot * w
    if fc.enabled:
        tau -= fc.radius_m * np.linalg.norm(f) * w / (np.linalg.norm(w) + fc.omega_eps_rad_s)
    return np.r_[f, tau + np.cross(tip - com, f)], anchor


@pytest.mark.parametrize("over", [
    [],
    ["scene.socket_engage=depth", "scene.socket_k_axial_N_per_m=4000", "effects.contact_friction_couple.enabled=true"],
])
def test_socket_step_is_its_formulas(over):
    """Random tip poses and velocities about the entrance, a sequence of calls (engage, hold,
    release in depth mode): the kernel's wrench and anchor equal the numpy formulas."""
    sim = _moving_sim(over)
    cfg, entry = sim.cfg, sim.entry_w
    prm = socket_params(cfg, entry, BORE_AXIS_W)
    rng = np.random.default_rng(4)
    st, anchor = np.zeros(N_STATE), None
    seen = set()
    for k in range(60):
        t = cfg.start.settle_s + (k - 5) * 1e-3
        tip = entry + np.r_[rng.normal(scale=1e-3, size=2), 0.002 * np.cos(0.2 * k) - 0.0005]  # crosses the plane
        R = sim.data.xmat[sim._tool_body].reshape(3, 3) @ mujoco_rot(rng.normal(scale=0.02, size=3))
        com = tip + rng.normal(scale=0.02, size=3)
        cvel = rng.normal(scale=0.05, size=6)
        sub = tip + rng.normal(scale=0.1, size=3)
        vel6 = np.r_[cvel[:3], cvel[3:] - np.cross(tip - sub, cvel[:3])]
        xfrc = np.full(6, 7.0)
        socket_step(t, st, prm, tip, R.ravel().copy(), com, cvel, sub, xfrc)
        ref, anchor = _reference(t, anchor, cfg, tip, R, com, vel6, entry)
        if ref is None:
            assert np.all(xfrc == 7.0) and st[0] == 0.0  # before the drive: untouched
            seen.add("before")
            continue
        np.testing.assert_allclose(xfrc, ref, rtol=1e-10, atol=1e-12)
        assert bool(st[0]) == (anchor is not None)
        seen.add("engaged" if anchor is not None else "released")
    expected = {"before", "engaged"} if not over else {"engaged", "released"}
    assert expected <= seen


def mujoco_rot(rv):
    """Rotation matrix of a rotation vector (MuJoCo's quaternion helpers)."""
    q, M = np.zeros(4), np.zeros(9)
    angle = float(np.linalg.norm(rv))
    mujoco.mju_axisAngle2Quat(q, rv / angle, angle)
    mujoco.mju_quat2Mat(M, q)
    return M.reshape(3, 3)


@pytest.mark.parametrize("factor", [0.5, 2.0])
def test_hidden_stiffness_changes_the_springs_not_the_dampers(factor):
    """Effect ``contact_stiffness``: the socket's springs scale by the factor, its dampers stay the
    declared ones (the diagnosis's ``contact_stiffness`` is the spring's factor against the set-up's
    declared dampers; before, c = 2 z sqrt(k m) followed k and a friction couple fitted beside it
    absorbed the damper's change, benchmarks/results/excite_reasons.txt)."""
    from kinadapt_nn.sim.effects import truth_config
    from kinadapt_nn.sim.socket import P_C_AX, P_C_LAT, P_C_ROT, P_K_AX, P_K_LAT, P_K_ROT

    base = load_config(None, ["scene.contact_model=socket", "scene.socket_k_axial_N_per_m=3000"])
    hid = truth_config(load_config(None, ["scene.contact_model=socket", "scene.socket_k_axial_N_per_m=3000",
                                          "effects.contact_stiffness.enabled=true",
                                          f"effects.contact_stiffness.factor={factor}"]))
    entry = np.array([0.5, 0.0, 0.1])
    p0, p1 = socket_params(base, entry, BORE_AXIS_W), socket_params(hid, entry, BORE_AXIS_W)
    for k in (P_K_LAT, P_K_AX, P_K_ROT):
        assert p1[k] == pytest.approx(factor * p0[k], rel=1e-12)
    for c in (P_C_LAT, P_C_AX, P_C_ROT):
        assert p0[c] > 0.0
        assert p1[c] == pytest.approx(p0[c], rel=1e-12)
