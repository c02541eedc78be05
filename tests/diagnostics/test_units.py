"""The wrench-unit check (``diagnostics.units``) on logs written from the rigid-body equations here
(static poses: ``F = m g``, ``M = c x F``; a moving tool: Newton-Euler about the sensor origin), not
through the package's kinematics: a log in one unit declared in another is named with the unit
that fits, and a right one -- a heavier tool than declared included -- draws no warning."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from kinadapt_nn.diagnostics import mount, units
from kinadapt_nn.diagnostics.setup import FORCE_UNITS, TORQUE_UNITS, load_setup

MASS, COM = 1.05, np.array([0.004, -0.003, 0.062])  # [kg], [m] in s
I_COM = np.diag([0.006, 0.006, 0.002])  # [kg m^2] about the COM
BIAS = np.array([1.2, -0.8, 2.5, 0.05, 0.03, -0.04])  # [N, N m]
SIGMA = np.array([0.05] * 3 + [0.003] * 3)  # [N, N m]
TOOL = ["tool.mass_kg=1.0", "tool.com_sensor_m=[0.0, 0.0, 0.06]", "tool.inertia_com_kg_m2=[0.006, 0.006, 0.002, 0, 0, 0]"]


def _skew(v):
    return np.cross(np.eye(3), v)


def _signals(units_logged=("N", "N m"), declared=("N", "N m"), moving=False, tool=TOOL, mass=MASS, com=COM, n=600,
             seed=0):
    """Samples of the tool's wrench on the sensor in ``units_logged``, with a setup declaring
    ``declared``. Static: random orientations at rest. Moving: 500 Hz, gravity turning through s
    while the sensor spins and accelerates (smooth, so that second differences see the noise). -> (signals, noise
    sigma (6,) in the declared units)."""
    rng = np.random.default_rng(seed)
    z = np.zeros((n, 3))
    if moving:
        t = np.arange(n) / 500.0
        rv = np.stack([1.2 * np.sin(2.1 * t), 0.9 * np.sin(1.3 * t + 1), 1.5 * np.sin(0.8 * t)], axis=1)
        g = Rotation.from_rotvec(rv).apply([0.0, 0.0, -9.81])
        omega = np.stack([6 * np.sin(7 * t), 5 * np.cos(9 * t), 4 * np.sin(5 * t + 2)], axis=1)  # [rad/s]
        alpha = np.stack([42 * np.cos(7 * t), -45 * np.sin(9 * t), 20 * np.cos(5 * t + 2)], axis=1)  # [rad/s^2]
        acc = np.stack([2 * np.sin(3 * t), 1.5 * np.cos(4 * t), np.sin(6 * t)], axis=1)  # [m/s^2]
    else:
        g = Rotation.random(n, random_state=seed + 1).apply([0.0, 0.0, -9.81])
        omega = alpha = acc = z
    I_O = I_COM + mass * (com @ com * np.eye(3) - np.outer(com, com))
    ga = g - acc
    F = mass * ga - np.cross(alpha, mass * com) - np.cross(omega, np.cross(omega, mass * com))
    M = np.cross(mass * com, ga) - alpha @ I_O.T - np.cross(omega, omega @ I_O.T)
    w_si = np.concatenate([F, M], axis=1) + BIAS + rng.normal(0.0, SIGMA, (n, 6))
    per_unit = np.array([FORCE_UNITS[units_logged[0]]] * 3 + [TORQUE_UNITS[units_logged[1]]] * 3)
    as_declared = np.array([FORCE_UNITS[declared[0]]] * 3 + [TORQUE_UNITS[declared[1]]] * 3)
    wrench = w_si / per_unit * as_declared  # the numbers logged, read in the declared units
    setup = load_setup(None, [*tool, f'log.force_unit="{declared[0]}"', f'log.torque_unit="{declared[1]}"',
                              f"log.static={'false' if moving else 'true'}", *(() if moving else ['log.time=""'])])
    s = SimpleNamespace(g_s=g, a_s=acc, omega_s=omega, alpha_s=alpha, wrench=wrench, setup=setup, n=n,
                        static=not moving, contact=np.zeros(n, bool))
    return s, SIGMA * as_declared / per_unit


def _log(*args, **kwargs) -> units.UnitCheck:
    """The units check of ``_signals(*args, **kwargs)``."""
    s, sigma = _signals(*args, **kwargs)
    fitm = mount.fit(s, np.ones(s.n, bool), np.arange(s.n) % 20, sigma, max_blocks=0)
    return units.check(fitm, s, s.setup, sigma)


@pytest.mark.parametrize("moving", [False, True])
@pytest.mark.parametrize("logged,declared", [(("N", "N mm"), ("N", "N m")), (("N", "N m"), ("N", "N mm")),
                                             (("N", "N m"), ("N", "N cm")), (("lbf", "N m"), ("N", "N m")),
                                             (("N", "N m"), ("kN", "N m")), (("kN", "N m"), ("N", "N m")),
                                             (("lbf", "lbf in"), ("N", "N m"))])
def test_a_wrong_unit_is_named_with_the_unit_that_fits(moving, logged, declared):
    c = _log(logged, declared, moving)
    assert c.message is not None and (c.likely.force_unit, c.likely.torque_unit) == logged, c.message
    for k, u_decl, u_log in (("force_unit", *zip(declared, logged).__next__()),
                             ("torque_unit", declared[1], logged[1])):
        if u_decl != u_log:
            assert f'{k} = "{u_log}"' in c.message
    assert abs(c.likely.mass_kg / MASS - 1) < 0.05


@pytest.mark.parametrize("moving", [False, True])
def test_right_units_draw_no_warning(moving):
    for logged in [("N", "N m"), ("N", "N mm"), ("lbf", "lbf in")]:
        c = _log(logged, logged, moving)
        assert c.message is None and c.declared.score == 0.0, (logged, c.declared)


@pytest.mark.parametrize("moving", [False, True])
def test_a_heavier_tool_than_declared_is_not_a_unit(moving):
    """An undeclared payload: 2.4x the declared mass, the centre of mass 1.9x as far -- physics the
    diagnosis should find, not a unit."""
    c = _log(moving=moving, mass=2.4, com=np.array([0.01, 0.0, 0.115]))
    assert c.message is None, c.message


def test_the_torque_unit_is_named_without_a_declared_tool():
    """Nothing declared about the tool: a centre of mass 0.06 mm from the sensor (torques in N m read
    as N mm) is no tool; a moving log's inertia misfit says the same."""
    for moving in (False, True):
        c = _log(("N", "N m"), ("N", "N mm"), moving, tool=["tool.inertia_com_kg_m2=[0.006, 0.006, 0.002, 0, 0, 0]"]
                 if moving else [])
        assert c.message is not None and c.likely.torque_unit == "N m", c.message


def test_a_sensor_range_rules_out_a_unit():
    """Torques in N mm read as N m exceed a 10 N m sensor's range a thousandfold."""
    c = _log(("N", "N mm"), ("N", "N m"), tool=[*TOOL, "sensor.range_torque_Nm=10.0"])
    assert c.declared.score > 3 and c.likely.torque_unit == "N mm"


def test_the_moment_arm_is_read_from_the_torques_whatever_their_unit():
    """``moment_arm``: the first moment from the torques alone; a torque unit scales it and its sd
    alike (pinned either way), and it is the tool's ``m c`` -- the centre of mass is its arm against
    the weight (a moving log: the inertia's moments fitted beside it)."""
    for moving in (False, True):
        s, _ = _signals(moving=moving)
        for k in (1.0, 1000.0):
            d = units._free_data(s, s.setup, SIGMA)
            d = d._replace(r=d.r * np.r_[1, 1, 1, k, k, k], w=d.w / np.r_[1, 1, 1, k, k, k])
            arm = units.moment_arm(np.eye(3), d)
            assert arm.pinned and np.allclose(arm.mc / k, MASS * COM, atol=3e-3), (moving, k, arm)
