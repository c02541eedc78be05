"""The sensor-mount calibration fit (``diagnostics.mount``) against closed-form data.

The data here are written from the rigid-body statics directly (random sensor orientations,
``F = m D^T g``, ``M = c x F``), not through the package's kinematics, so a wrong sign, frame or
rotation convention in the fit shows up as a wrong estimate."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from kinadapt_nn.diagnostics import mount
from kinadapt_nn.diagnostics.setup import load_setup, rpy_matrix

SIGMA = np.array([0.05] * 3 + [0.003] * 3)
MASS, COM = 1.05, np.array([0.004, -0.003, 0.062])
BIAS = np.array([1.2, -0.8, 2.5, 0.05, 0.03, -0.04])


def _signals(rpy_true_deg, overrides=(), n=200, seed=0, sign=1.0):
    """Static poses: the declared sensor frame is the flange (rpy 0 unless overridden); the true
    sensor axes are turned by ``rpy_true_deg`` (setup convention) from the flange."""
    rng = np.random.default_rng(seed)
    setup = load_setup(None, ["tool.mass_kg=0.9", *overrides])
    R_wf = Rotation.random(n, random_state=seed + 1).as_matrix()
    R_decl = setup.sensor.R_fs()
    g_decl = np.einsum("nji,j->ni", R_wf @ R_decl, [0.0, 0.0, -9.81])  # gravity in the declared s
    R_true = rpy_matrix(np.deg2rad(rpy_true_deg))
    g_true = np.einsum("nji,j->ni", R_wf @ R_true, [0.0, 0.0, -9.81])
    F = MASS * g_true
    w = np.concatenate([F, np.cross(COM, F)], axis=1) + BIAS + rng.normal(0.0, SIGMA, (n, 6))
    z = np.zeros((n, 3))
    return SimpleNamespace(g_s=g_decl, a_s=z, omega_s=z, alpha_s=z, wrench=sign * w, setup=setup, n=n)


@pytest.mark.parametrize("rpy", [(0.0, 0.0, 137.0), (12.0, -7.0, 220.0), (178.0, 3.0, -90.0), (0.5, -0.3, 0.2)])
def test_fit_recovers_any_mount(rpy):
    s = _signals(rpy)
    f = mount.fit(s, np.ones(s.n, bool), np.arange(s.n) % 20, SIGMA)
    R_err = rpy_matrix(np.deg2rad(f.rpy_deg)).T @ rpy_matrix(np.deg2rad(rpy))
    err_deg = np.rad2deg(mount.rotation_angle(R_err))
    assert err_deg < 0.1
    assert abs(f.x[3] - MASS) < 0.002 * MASS
    assert np.linalg.norm(f.x[4:7] / f.x[3] - COM) < 5e-4
    assert np.allclose(f.x[7:], BIAS, atol=[0.02] * 3 + [0.002] * 3)
    assert np.all(np.isfinite(f.sd)) and np.all(f.sd > 0) and np.all(np.isfinite(f.rpy_sd_deg))
    assert abs(f.x[3] - MASS) < 5 * f.sd[3]  # the sd is not wildly optimistic
    rep = f.report
    assert rep["declared_consistent"] == (max(abs(a) for a in rpy) < 1.0)
    assert np.isclose(rep["rotation_from_declared_deg"], np.rad2deg(mount.rotation_angle(rpy_matrix(np.deg2rad(rpy)))),
                      atol=0.1)


def test_declared_mount_is_the_reference():
    """The estimate is reported in the setup's convention whatever the declared guess."""
    s = _signals((10.0, 20.0, 30.0), overrides=["sensor.rpy_flange_deg=[0, 0, 90]"])
    f = mount.fit(s, np.ones(s.n, bool), np.arange(s.n) % 20, SIGMA)
    assert np.allclose(f.rpy_deg, [10.0, 20.0, 30.0], atol=0.1)


def test_flipped_convention_gives_a_negative_mass():
    s = _signals((0.0, 0.0, 137.0), sign=-1.0)
    f = mount.fit(s, np.ones(s.n, bool), np.arange(s.n) % 20, SIGMA)
    assert f.x[3] + 3 * f.sd[3] < 0  # no proper rotation undoes a negated wrench
    assert mount.plausibility(f, s.setup)


def test_offset_beyond_declared_range_is_impossible():
    s = _signals((0.0, 0.0, 0.0), overrides=["sensor.range_force_N=2.0"])
    f = mount.fit(s, np.ones(s.n, bool), np.arange(s.n) % 20, SIGMA)
    assert any("range" in w for w in mount.plausibility(f, s.setup))  # the 2.5 N bias on z


def test_rpy_round_trip():
    rng = np.random.default_rng(1)
    for _ in range(50):
        rpy = rng.uniform([-np.pi, -1.5, -np.pi], [np.pi, 1.5, np.pi])
        assert np.allclose(mount.matrix_rpy(rpy_matrix(rpy)), rpy, atol=1e-9)
        v = rng.normal(size=3)
        assert np.allclose(mount.rotvec_matrix(v), Rotation.from_rotvec(v).as_matrix(), atol=1e-12)


def test_inertia_moment_columns_equal_the_cross_product_form():
    """``_inertia_moment`` (written out) against ``dI alpha + omega x (dI omega)`` evaluated from
    each symmetric basis matrix directly (``np.cross``), on random rates."""
    rng = np.random.default_rng(3)
    om, al = rng.normal(size=(50, 3)), rng.normal(size=(50, 3))
    basis = []
    for i, j in ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)):
        E = np.zeros((3, 3))
        E[i, j] = E[j, i] = 1.0
        basis.append(E)
    want = np.stack([al @ E.T + np.cross(om, om @ E.T) for E in basis], axis=2)
    np.testing.assert_allclose(mount._inertia_moment(om, al), want, rtol=1e-13, atol=1e-13)


def test_a_sensor_that_does_not_turn_keeps_the_declared_calibration():
    """One orientation (gravity fixed in the sensor, 0.3 deg of wobble): any rotation and mass fit
    with a matching offset, so none is fitted -- the declared mount and tool stand, the offset is
    fitted (it is what the declared tool leaves), and the report says why and what would pin it."""
    rng = np.random.default_rng(4)
    n = 400
    setup = load_setup(None, [f"tool.mass_kg={MASS}", f"tool.com_sensor_m=[{COM[0]}, {COM[1]}, {COM[2]}]"])
    g = np.array([0.0, 0.0, -9.81]) + rng.normal(0.0, 0.03, (n, 3))  # the sensor hardly turns
    F = MASS * g
    w = np.concatenate([F, np.cross(COM, F)], axis=1) + BIAS + rng.normal(0.0, SIGMA, (n, 6))
    z = np.zeros((n, 3))
    s = SimpleNamespace(g_s=g, a_s=z, omega_s=z, alpha_s=z, wrench=w, setup=setup, n=n)
    f = mount.fit(s, np.ones(n, bool), np.arange(n) % 20, SIGMA)
    rep = f.report
    assert rep["determined"] is False and rep["turn_mps2"] < mount.TURN_MIN_MPS2
    assert np.allclose(f.x[:3], 0.0) and f.x[3] == MASS and rep["declared_consistent"]
    assert np.all(np.abs(f.x[7:] - BIAS) < 4 * f.sd[7:]), (f.x[7:] - BIAS, f.sd[7:])
    assert np.all(f.sd[7:] < SIGMA)  # the offset is determined by the mean of 400 samples
    assert rep["sd_deg"] == [None] * 3 and "1 needed" in rep["undetermined"][0]["why"]
    assert not mount.plausibility(f, setup)
    # the same samples turned through 90 deg about x half of the time: now it calibrates
    half = np.arange(n) < n // 2
    g2 = g.copy()
    g2[half] = g[half] @ mount.rotvec_matrix(np.array([np.pi / 2, 0.0, 0.0]))
    F2 = MASS * g2
    s2 = SimpleNamespace(g_s=g2, a_s=z, omega_s=z, alpha_s=z, setup=setup, n=n,
                         wrench=np.concatenate([F2, np.cross(COM, F2)], axis=1) + BIAS + rng.normal(0.0, SIGMA, (n, 6)))
    f2 = mount.fit(s2, np.ones(n, bool), np.arange(n) % 20, SIGMA)
    assert f2.report["determined"] is True and abs(f2.x[3] - MASS) < 0.01
