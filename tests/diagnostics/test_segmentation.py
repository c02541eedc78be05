"""Free space found from the data (``segmentation``): the span the calibration runs on."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from kinadapt_nn.diagnostics import segmentation
from kinadapt_nn.diagnostics.setup import load_setup


def _log(m_true: float, push_N: float, m_decl: float = 0.1, n: int = 6000, dt: float = 1e-3) -> SimpleNamespace:
    """3 s of free space turning the sensor +-0.4 rad against gravity, then 3 s of contact at a fixed
    pose with a steady push ``push_N`` along gravity (sensor z)."""
    t = np.arange(n) * dt
    ang = np.where(t < 3.0, 0.4 * np.sin(2 * np.pi * t / 1.5), 0.0)
    g = 9.81
    u = np.stack([g * np.sin(ang), np.zeros(n), g * np.cos(ang)], axis=1)  # g_s - a_s, sensor frame
    F = m_true * u
    push = t >= 3.0
    F[push, 2] += push_N
    wrench = np.concatenate([F, np.zeros((n, 3))], axis=1)
    setup = load_setup(None, [f"tool.mass_kg={m_decl}"])
    return SimpleNamespace(setup=setup, n=n, t=t, wrench=wrench, g_s=u, a_s=np.zeros((n, 3)), static=False)


def test_a_contact_that_reads_as_the_declared_weight_is_passed_over_for_the_span_that_turns():
    s = _log(0.6, -0.5 * 9.81)  # a 0.5 kg payload; the fixture's push cancels its weight: the declared weight
    seg = segmentation.free_space(s)
    lo, hi = seg.span_s
    assert lo == 0.0 and 2.9 < hi < 3.0, seg.to_json()  # the free span, up to the contact onset
    assert not seg.free[s.t >= 3.0].any()
    j = seg.to_json()
    assert j["turn_mps2"] > 3.0 and j["passed_over"] and j["passed_over"][0][2] < 0.2  # the contact barely turned
    assert "turns the sensor against gravity" in j["method"]


def test_the_first_span_stands_when_it_turns():
    s = _log(0.1, 11.0)  # the declared tool pressed with 11 N: the seed is in free space
    seg = segmentation.free_space(s)
    assert seg.span_s[0] == 0.0 and seg.to_json()["passed_over"] == [] and not seg.free[s.t >= 3.0].any()
