"""What the monitor cannot tell apart (``shapes.ties``), the slow error of the model counted beyond the noise
(``Monitor._beyond_noise``) and a hint-shaped event as an effect file for the offline diagnosis
(``agreement.effect_file``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from kinadapt_nn.config import load_config
from kinadapt_nn.diagnostics.ownrun import setup_of_run
from kinadapt_nn.effects.contract import load_effect_file
from kinadapt_nn.monitor import kernel as K
from kinadapt_nn.monitor import shapes
from kinadapt_nn.monitor.agreement import effect_file
from kinadapt_nn.monitor.monitor import Monitor

REPO = Path(__file__).resolve().parents[2]
SD = np.array([0.02, 0.02, 0.02, 0.002, 0.002, 0.002])  # [N, N m] the sensor's noise
MC = np.array([0.0, 0.0, 0.005])  # [kg m] the declared tool's first moment (0.1 kg, 50 mm along z)
TOOL = shapes.Tool(0.1, MC, np.zeros((3, 3)))  # the declared tool (0.1 kg; its inertia unread here)
G_W = np.array([0.0, 0.0, -9.81])


def _turning_rows(n: int, e_of) -> np.ndarray:
    """Ring rows (n, NCOL) of a slow wrist turn (about x by up to 40 deg, then about y; no acceleration):
    R_ws, gravity in s, the declared tool's reading; the residual ``e_of(rows)`` (n, 6) plus the noise."""
    t = np.linspace(0.0, 1.0, n)
    ax, ay = np.deg2rad(40.0) * np.sin(2 * np.pi * t), np.deg2rad(40.0) * np.sin(np.pi * t)
    R = np.zeros((n, 3, 3))
    for i in range(n):
        cx, sx, cy, sy = np.cos(ax[i]), np.sin(ax[i]), np.cos(ay[i]), np.sin(ay[i])
        R[i] = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]]) @ np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    g_s = np.einsum("nji,j->ni", R, G_W)
    rows = np.zeros((n, K.NCOL))
    rows[:, K.G_T] = 1.0 + t
    rows[:, K.G_R:K.G_R + 9] = R.reshape(n, 9)
    rows[:, K.G_GA:K.G_GA + 3] = g_s
    rows[:, K.G_RM:K.G_RM + 3] = 0.1 * g_s
    rows[:, K.G_RM + 3:K.G_RM + 6] = np.cross(MC, g_s)
    rows[:, K.G_FREE] = 1.0
    rng = np.random.default_rng(7)
    rows[:, K.G_E:K.G_E + 6] = e_of(rows) + SD * rng.standard_normal((n, 6))
    return rows


def test_a_tilt_ties_the_payload_shape_that_contains_it_and_nothing_else():
    """The tool turned 8 deg about x in the grasp: a first moment ``delta x mc`` that ``tool_gravity`` holds
    as well (dm = 0, dmc = delta x mc). The tilt is named (fewer parameters) and ``tool_gravity`` ties it;
    the other shapes cannot make a moment that turns with gravity and no force, so the turn tells them apart."""
    delta = np.deg2rad([8.0, 0.0])
    rows = _turning_rows(1500, lambda r: shapes.columns("tool_tilt", r, TOOL, 1.0) @ delta)
    best, fits = shapes.best(rows, SD, TOOL, 1.0)
    assert best.shape == "tool_tilt"
    assert shapes.ties(best, fits, rows, SD, TOOL, 1.0) == ["tool_gravity"]


def test_the_tilts_columns_lie_in_the_payload_shapes_span():
    """Nested: fitted together with ``tool_gravity`` the tilt lowers the chi^2 by nothing (its columns are
    ``tool_gravity``'s first-moment columns times ``-[mc]x``); only the weak priors differ."""
    delta = np.deg2rad([8.0, 0.0])
    rows = _turning_rows(600, lambda r: shapes.columns("tool_tilt", r, TOOL, 1.0) @ delta)
    g = shapes.fit("tool_gravity", rows, SD, TOOL, 1.0)
    tl = shapes.fit("tool_tilt", rows, SD, TOOL, 1.0)
    A_g, b, P_g = shapes._target(g, rows, SD, TOOL, 1.0, None)
    A_t, _, P_t = shapes._target(tl, rows, SD, TOOL, 1.0, None)
    alone = shapes._misfit(A_g, b, P_g)
    both = shapes._misfit(np.hstack([A_g, A_t]), b, np.concatenate([P_g, P_t]))
    assert abs(alone - both) < 1e-3 * alone, (alone, both)


def test_a_snag_is_decided():
    """1.5 N pulling along world -y at a point of the tool: no other shape makes a force fixed in the world
    (a payload's weight is vertical, a constant or a drift does not turn with the wrist): no tie."""
    p = np.array([0.0, -1.5, 0.0, 0.0, 0.02, 0.06])  # f_w [N], point [m]
    pull = shapes.Fit("world_force", p, np.eye(6), 0.0, 0.0, 0)
    rows = _turning_rows(1500, lambda r: shapes.evaluate(pull, r, TOOL, 1.0))
    best, fits = shapes.best(rows, SD, TOOL, 1.0)
    assert best.shape == "world_force"
    assert shapes.ties(best, fits, rows, SD, TOOL, 1.0) == []


def test_without_acceleration_a_payload_is_a_vertical_world_force():
    """0.5 kg at 50 mm on a wrist that turns slowly: its wrench is its weight, a world-frame force along
    gravity at its centre of mass -- the world-force shape, exactly; only the arm's accelerations could tell
    them apart, and this motion has none: they tie (and nothing else does)."""
    p = np.array([0.5, 0.0, 0.0, 0.025])  # dm [kg], dmc [kg m]
    rows = _turning_rows(1500, lambda r: shapes.columns("tool_gravity", r, TOOL, 1.0) @ p)
    best, fits = shapes.best(rows, SD, TOOL, 1.0)
    assert best.shape == "tool_gravity"  # 4 parameters against the world force's 6
    assert shapes.ties(best, fits, rows, SD, TOOL, 1.0) == ["world_force"]


def _monitor() -> Monitor:
    cfg = load_config(REPO / "online/monitor.toml", ["run.progress=false"])
    mon = Monitor(setup_of_run(cfg), cfg.monitor, cfg.run.dt_s)
    mon.st[K.S_SD:K.S_SD + 6] = SD
    return mon


def test_the_models_slow_error_is_what_the_block_means_hold_beyond_the_noise():
    """Block means of k = 100 samples: of white noise alone their RMS is the noise's sd / 10, which the
    estimate's white-noise covariance already holds -- beyond the noise only chance is left: the mean square
    of 400 block means is chi^2_400 / 400 of sd^2 / k, so what is left stays below ``sqrt(chi^2_400(0.9999) /
    400 - 1)`` block-mean sds; with a constant error b of the model added, b is what is left (to 3 %)."""
    from scipy.stats import chi2

    rng = np.random.default_rng(1)
    k, nb = 100, 400
    noise = (SD * rng.standard_normal((nb, k, 6))).mean(axis=1)
    mon = _monitor()
    rms = np.sqrt(np.mean(noise ** 2, axis=0))
    assert np.allclose(rms, SD / np.sqrt(k), rtol=0.1)  # what the old estimate counted as the model's error
    chance = np.sqrt(chi2.ppf(0.9999, nb) / nb - 1.0) * SD / np.sqrt(k)
    assert np.all(mon._beyond_noise(noise, k) < chance)
    b = np.array([0.01, -0.02, 0.0, 0.001, 0.0, -0.002])  # [N, N m] 5 to 10 block-mean noise sds
    got = mon._beyond_noise(noise + b, k)
    big = np.abs(b) > 0
    assert np.allclose(got[big], np.abs(b[big]), rtol=0.03), got
    assert np.all(got[~big] < chance[~big])


def test_a_world_force_event_as_an_effect_file(tmp_path):
    """The file loads in the public contract and its columns times the event's force are the monitor's own
    world-force wrench (``shapes.evaluate``) on the same poses; a library shape has no file (the diagnosis
    has it)."""
    fw, point = np.array([0.1, -1.5, 0.05]), np.array([0.0, 0.02, 0.06])
    ev = {"shape": "world_force", "open": True, "line": "3.00 s: a world-frame force appeared -- looks like world_force",
          "estimate": {"point_s_m": point.tolist(), "force_w_N": fw.tolist()}}
    name, src = effect_file(ev, 0.2)
    (tmp_path / name).write_text(src)
    eff = load_effect_file(tmp_path / name)["monitor_world_force"]
    assert eff.params == ("fx_w", "fy_w", "fz_w") and eff.relevant == (0.2, 0.2, 0.2)
    rows = _turning_rows(50, lambda r: np.zeros((len(r), 6)))
    from types import SimpleNamespace

    s = SimpleNamespace(n=len(rows), R_ws=rows[:, K.G_R:K.G_R + 9].reshape(-1, 3, 3))
    want = shapes.evaluate(shapes.Fit("world_force", np.concatenate([fw, point]), np.eye(6), 0.0, 0.0, 0), rows, TOOL, 1.0)
    assert np.allclose(eff(s) @ fw, want, rtol=1e-12, atol=1e-9)
    assert effect_file({**ev, "shape": "tool_gravity"}, 0.2) is None
