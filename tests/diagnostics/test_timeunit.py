"""The time-unit check (``diagnostics.units.check_time``) on arm motions written here: a time column in ms
(or us) read as seconds, or seconds read as ms, is named with the ``time_scale_s`` that fits --
from logged joint velocities where the log has them, else from the sample rate and the arm's
speed -- and a right one, a slow arm or a static log draw no warning."""

from __future__ import annotations

import numpy as np
import pytest

from kinadapt_nn.diagnostics import units
from kinadapt_nn.diagnostics.readers import UserLog
from kinadapt_nn.diagnostics.setup import load_setup


def _log(per_s: float = 1.0, declared: float = 1.0, rate_hz: float = 200.0, amp_rad: float = 0.4,
         period_s: float = 6.0, qdot: bool = False, seconds: float = 18.0):
    """An arm swinging its joints (amplitude ``amp_rad``, period ``period_s``) sampled at ``rate_hz``,
    its time column logged in units of ``per_s`` seconds and read as ``declared`` seconds per unit."""
    t = np.arange(0.0, seconds, 1.0 / rate_hz)
    w = 2 * np.pi / period_s
    phase = np.arange(6) * 0.7
    q = amp_rad * np.sin(w * t[:, None] + phase)
    qd = amp_rad * w * np.cos(w * t[:, None] + phase)
    t_read = t / per_s * declared  # the column's numbers times the declared seconds per unit
    setup = load_setup(None, [f"log.time_scale_s={declared}"])
    log = UserLog(t_read, q, qd if qdot else None, np.zeros((len(t), 6)), "test")
    return units.check_time(log, setup)


@pytest.mark.parametrize("qdot", [False, True])
@pytest.mark.parametrize("per_s,declared", [(1e-3, 1.0), (1e-6, 1.0), (1.0, 1e-3), (1e-3, 1e-6)])
def test_a_wrong_time_unit_is_named(per_s, declared, qdot):
    c = _log(per_s, declared, qdot=qdot)
    assert c.message is not None and c.likely.time_scale_s == pytest.approx(per_s), c.message
    assert f"set [log] time_scale_s = {per_s:g}" in c.message


def test_ms_read_as_seconds_says_ms():
    c = _log(1e-3)
    assert "(the time column in ms)" in c.message and c.declared.rate_hz == pytest.approx(0.2)


@pytest.mark.parametrize("qdot", [False, True])
@pytest.mark.parametrize("rate_hz,amp_rad,period_s", [(200.0, 0.4, 6.0), (1000.0, 0.05, 30.0), (10.0, 1.0, 4.0),
                                                      (8000.0, 0.3, 2.0)])
def test_right_time_draws_no_warning(rate_hz, amp_rad, period_s, qdot):
    """Fast and slow loggers, a slow arm (0.01 rad/s) and a fast one: as declared."""
    assert _log(rate_hz=rate_hz, amp_rad=amp_rad, period_s=period_s, qdot=qdot).message is None


def test_an_arm_that_does_not_move_tells_only_its_rate():
    """Joints within MOVE_MIN_RAD: no speed to read; a 200 Hz log in ms read as s is still named by its rate."""
    c = _log(1e-3, amp_rad=0.001)
    assert c.declared.speed_rad_s is None and c.message is not None


def test_velocities_in_another_angle_unit_are_not_a_time_unit():
    """qdot 57x dq/dt (deg/s beside rad) is not a power of 1000: the rate and speed decide (right here)."""
    t = np.arange(0.0, 10.0, 0.005)
    q = 0.4 * np.sin(t[:, None] + np.arange(6))
    log = UserLog(t, q, np.rad2deg(0.4 * np.cos(t[:, None] + np.arange(6))), np.zeros((len(t), 6)), "test")
    assert units.check_time(log, load_setup(None, [])).message is None


def test_a_static_log_is_not_checked():
    t = np.arange(30) * 5.0
    log = UserLog(t, np.random.default_rng(0).normal(size=(30, 6)), None, np.zeros((30, 6)), "test", static=True)
    assert units.check_time(log, load_setup(None, ["log.static=true"])) is None
