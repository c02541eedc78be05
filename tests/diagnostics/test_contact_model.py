"""The declared socket's wrench (``effects.contact_model``) against closed forms, and the
declared damper against the simulator's socket kernel's own coefficients."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from kinadapt_nn.effects import contact_model
from kinadapt_nn.diagnostics.setup import ContactDeclCfg, SetupCfg, ToolDeclCfg

TIP_S = (0.0, 0.0, 0.1)
K_LAT, K_ROT, C_LAT, C_ROT = 2.0e4, 20.0, 150.0, 0.27


def _setup(c_lat=C_LAT, c_rot=C_ROT) -> SetupCfg:
    contact = ContactDeclCfg(mode="tip", geometry="socket", entry_w_m=(0.0, 0.0, 0.0), axis_w=(0.0, 0.0, -1.0),
                             stiffness_lat_N_per_m=K_LAT, stiffness_rot_Nm_per_rad=K_ROT,
                             damping_lat_N_s_per_m=c_lat, damping_rot_Nm_s_per_rad=c_rot)
    return SetupCfg(tool=ToolDeclCfg(mass_kg=0.1, tip_sensor_m=TIP_S), contact=contact)


def _pose(t, w_z, v_x):
    """Sensor pose (R_ws (n,3,3), p_ws (n,3)): the sensor above the tip (tip 0.1 m along the sensor z,
    sensor z pointing down the bore), the tip 5 mm into the fixture, turning about the bore axis at
    ``w_z`` [rad/s] and sliding along world x at ``v_x`` [m/s]."""
    R_down = Rotation.from_euler("x", np.pi).as_matrix()  # sensor z -> world -z
    R = Rotation.from_euler("z", (w_z * t)[:, None]).as_matrix() @ R_down
    tip_w = np.stack([v_x * t, 0 * t, -0.005 + 0 * t], axis=1)
    p = tip_w - R @ np.asarray(TIP_S)
    return R, p


@pytest.mark.parametrize("c_lat,c_rot", [(C_LAT, C_ROT), (0.0, 0.0)])
def test_socket_with_damper_matches_closed_form(c_lat, c_rot):
    t = np.linspace(0.0, 0.5, 501)
    w_z, v_x = 0.02, 0.004
    R, p = _pose(t, w_z, v_x)
    w = contact_model.nominal_wrench(_setup(c_lat, c_rot), R, p, t)
    # closed form, world: anchored at t = 0 (the tip is inside from the first sample)
    f_w = np.stack([-K_LAT * v_x * t - c_lat * v_x, 0 * t, 0 * t], axis=1)
    tau_w = np.stack([0 * t, 0 * t, -K_ROT * w_z * t - c_rot * w_z], axis=1)
    f_s = np.einsum("nji,nj->ni", R, f_w)
    m_s = np.einsum("nji,nj->ni", R, tau_w) + np.cross(np.asarray(TIP_S), f_s)
    # central differences of the pose: exact for the linear motion, O(dt^2 w^3) for the turn
    assert np.allclose(w[:, :3], f_s, atol=1e-9)
    assert np.allclose(w[:, 3:], m_s, atol=1e-9)


def test_no_time_no_damper():
    t = np.linspace(0.0, 0.5, 101)
    R, p = _pose(t, 0.02, 0.004)
    w_t = contact_model.nominal_wrench(_setup(0.0, 0.0), R, p, t)
    w_none = contact_model.nominal_wrench(_setup(), R, p)
    assert np.array_equal(w_t, w_none)


def test_ownrun_declares_the_fixtures_dampers():
    """A package run's set-up declares the socket's dampers the simulator applies (the fixture as
    built), never a hidden effect's change of them."""
    from pathlib import Path

    from kinadapt_nn.config import load_config
    from kinadapt_nn.diagnostics.ownrun import setup_of_run
    from kinadapt_nn.sim.socket import P_C_LAT, P_C_ROT, socket_params

    cfg = load_config(Path(__file__).resolve().parents[2] / "online" / "excite.toml")
    c = setup_of_run(cfg).contact
    prm = socket_params(cfg, np.zeros(3), np.array([0.0, 0.0, -1.0]))
    assert c.damping_lat_N_s_per_m == pytest.approx(prm[P_C_LAT], rel=1e-12)
    assert c.damping_rot_Nm_s_per_rad == pytest.approx(prm[P_C_ROT], rel=1e-12)
    assert c.damping_rot_Nm_s_per_rad > 0.0
