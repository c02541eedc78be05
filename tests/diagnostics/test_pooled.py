"""Several logs of one set-up pooled (``diagnostics.pooled``): the logs that contradict the others
are named, not averaged in; the pooled interval covers the truth as often as it claims."""

from __future__ import annotations

import numpy as np

from kinadapt_nn.diagnostics.mount import matrix_rpy
from kinadapt_nn.diagnostics.pooled import _rpy_matrix, pool, summary_text

MASS, COM, RPY = 0.44, np.array([0.024, 0.002, -0.038]), np.array([-67.0, 62.0, -79.0])


def _report(mass, com, rpy, sd_m=0.01, sd_c=0.002, sd_deg=2.0, plausible=True) -> dict:
    return {"sensor_mount": {"tool_mass_kg": float(mass), "tool_mass_sd_kg": sd_m, "tool_com_sensor_m": list(com),
                             "tool_com_sd_m": [sd_c] * 3, "rpy_flange_deg": list(rpy), "sd_deg": [sd_deg] * 3,
                             "plausible": plausible}}


def _draw(rng, sd_m=0.01, sd_c=0.002, sd_deg=2.0):
    R = _rpy_matrix(RPY)
    v = rng.normal(0, np.deg2rad(sd_deg), 3)
    th = np.linalg.norm(v)
    k = v / th
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    R = R @ (np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K)
    return _report(MASS + rng.normal(0, sd_m), COM + rng.normal(0, sd_c, 3), np.rad2deg(matrix_rpy(R)), sd_m, sd_c,
                   sd_deg)


def test_contradicting_logs_named_not_averaged():
    rng = np.random.default_rng(3)
    reps = [(f"trial{i:02d}", _draw(rng)) for i in range(10)]
    reps.append(("other_mount", _report(MASS, COM, RPY + [30.0, -20.0, 10.0])))
    reps.append(("other_tool", _report(0.375, COM + [-0.05, 0, 0.02], RPY)))
    reps.append(("broken", _report(-1.9, COM, RPY, plausible=False)))
    p = pool(reps)
    named = {c["log"]: c["why"] for c in p["contradicting"]}
    assert set(named) == {"other_mount", "other_tool", "broken"}
    assert named["other_mount"] == "another mount" and named["other_tool"] == "another tool"
    assert sorted(p["agreeing"]) == [f"trial{i:02d}" for i in range(10)]
    q = p["pooled"]
    assert abs(q["tool_mass_kg"] - MASS) < 4 * q["tool_mass_sd_kg"]
    text = summary_text(p)
    assert "other_mount contradicts the others: another mount" in text and "Pooled over 10" in text


def test_pooled_interval_covers_the_truth():
    """Over 200 draws of 8 agreeing logs, the pooled 95 % interval holds the true mass and centre of
    mass in 95 % of them (binomial bounds for 200 draws: 90-99 %)."""
    rng = np.random.default_rng(7)
    hit_m = hit_c = 0
    for _ in range(200):
        p = pool([(f"t{i}", _draw(rng)) for i in range(8)])
        q = p["pooled"]
        hit_m += abs(q["tool_mass_kg"] - MASS) <= 1.96 * q["tool_mass_sd_kg"]
        hit_c += abs(q["tool_com_sensor_m"][0] - COM[0]) <= 1.96 * q["tool_com_sd_m"][0]
        assert not p["contradicting"] or len(p["contradicting"]) <= 1  # 4 sd: a rare false alarm at most
    assert 0.90 <= hit_m / 200 <= 0.995 and 0.90 <= hit_c / 200 <= 0.995


def test_too_few_plausible_logs_pool_nothing():
    p = pool([("a", _report(MASS, COM, RPY)), ("b", _report(-1.0, COM, RPY, plausible=False))])
    assert p["pooled"] is None and p["contradicting"][0]["log"] == "b"
