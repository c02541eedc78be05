"""The monitor's naming with the model's slow error integrated out (``shapes.slow_bic``) and its phase with a
fixture that holds the tip from the drive start (``kernel.C_ENGAGE``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from kinadapt_nn.config import load_config
from kinadapt_nn.monitor import kernel as K
from kinadapt_nn.monitor import shapes
from kinadapt_nn.monitor.monitor import Monitor  # noqa: F401  (registers the live monitor with the episode loop)
from kinadapt_nn.runs.episode import run_episode

REPO = Path(__file__).resolve().parents[2]
SD = np.array([0.02, 0.02, 0.02, 0.002, 0.002, 0.002])  # [N, N m] the sensor's noise
MC = np.array([0.0, 0.0, -0.005])  # [kg m] the declared tool's first moment (only tool_tilt reads it)
TOOL = shapes.Tool(0.1, MC, np.zeros((3, 3)))  # the declared tool (0.1 kg; its inertia unread here)


def _rows(n: int, reading: np.ndarray, e: np.ndarray) -> np.ndarray:
    """Ring rows (n, NCOL) of a still pose: the reading (n, 6), the residual (n, 6), gravity along -z of s."""
    rows = np.zeros((n, K.NCOL))
    rows[:, K.G_T] = 1.0 + 1e-3 * np.arange(n)
    rows[:, K.G_E:K.G_E + 6] = e
    rows[:, K.G_RM:K.G_RM + 6] = reading
    rows[:, K.G_R:K.G_R + 9] = np.eye(3).ravel()
    rows[:, K.G_GA + 2] = -9.81
    rows[:, K.G_FREE] = 1.0
    return rows


def _exact(shape: str, rows: np.ndarray, slow_sd: np.ndarray) -> float:
    """-2 ln of the Gaussian marginal likelihood (up to the 6n ln 2 pi every shape shares) of the residual in
    noise sd, ``e = A p + B b + noise``: ``b ~ N(0, slow_sd^2)`` per channel, ``p`` under BIC's unit-information
    prior ``N(0, (A^T A / m)^-1)``; both integrated out in closed form: ``e^T S^-1 e + ln det S``, ``S = I +
    A U^-1 A^T + B P^-1 B^T`` (dense, no Laplace step)."""
    n = len(rows)
    A = (shapes.columns(shape, rows, TOOL, 1.0) / SD[None, :, None]).reshape(-1, shapes.prior_sd(shape).size)
    m = A.shape[0]
    B = np.zeros((n, 6, 6))
    B[:, np.arange(6), np.arange(6)] = 1.0 / SD
    B = B.reshape(-1, 6)
    S = np.eye(m) + A @ np.linalg.inv(A.T @ A / m) @ A.T + B @ np.diag(slow_sd ** 2) @ B.T
    e = (rows[:, K.G_E:K.G_E + 6] / SD).reshape(-1)
    return float(e @ np.linalg.solve(S, e) + np.linalg.slogdet(S)[1])


def test_slow_bic_is_the_marginal_likelihood_of_a_linear_shape():
    """For a linear shape the criterion is the exact marginal likelihood with the per-channel constant error
    and the shape's parameters integrated out (the latter under BIC's unit-information prior): the
    difference between two shapes agrees with the dense closed form to within what the weak prior and
    ``ln(m + 1)`` for ``ln m`` change (0.5 here, m = 1200 rows)."""
    rng = np.random.default_rng(3)
    n = 200
    t = np.linspace(0.0, 1.0, n)
    reading = np.zeros((n, 6))  # a reading that turns: the rotation's columns change along the window
    reading[:, 0], reading[:, 2] = 0.9 * np.sin(t), -0.98 * np.cos(t)
    reading[:, 3:] = 0.01 * rng.standard_normal(3)
    delta = np.deg2rad([1.4, 0.0, 1.4])
    e = np.concatenate([np.cross(reading[:, :3], delta), np.cross(reading[:, 3:], delta)], axis=1)
    e += SD * rng.standard_normal((n, 6)) + np.array([0.0, 0.0, 0.0, 3e-4, -2e-4, 1e-4])
    rows = _rows(n, reading, e)
    slow = np.array([0.002, 0.002, 0.003, 2e-4, 3e-4, 2e-4])
    got = {s: shapes.slow_bic(shapes.fit(s, rows, SD, TOOL, 1.0), rows, SD, TOOL, 1.0, slow)
           for s in ("ft_frame_rotation", "sensor_constant")}
    want = {s: _exact(s, rows, slow) for s in got}
    d_got = got["ft_frame_rotation"] - got["sensor_constant"]
    d_want = want["ft_frame_rotation"] - want["sensor_constant"]
    assert abs(d_got - d_want) < 0.5, (d_got, d_want)


def test_a_constant_error_of_the_model_in_the_moments_does_not_name_a_constant():
    """A still tool: the mount turned by 2 deg changes the force rows as a constant force would (a rotation
    about x and z of a reading along -z), and the moment rows carry the model's own constant error of 0.1
    noise sd (a centre-of-mass error: 2e-4 N m). Counted as white noise the moment rows' 3 x 2000 samples
    make the constant the best shape (it fits that error); with the model's slow error (its size known from
    before the change) integrated out the rotation's 3 parameters win over the constant's 6."""
    rng = np.random.default_rng(0)
    n = 2000
    reading = np.tile([0.0, 0.0, -0.98, 0.0, 0.0, 0.0], (n, 1))
    delta = np.deg2rad([1.41, 0.0, 1.41])
    e = np.concatenate([np.cross(reading[:, :3], delta), np.zeros((n, 3))], axis=1)
    e += SD * rng.standard_normal((n, 6)) + np.array([0.0, 0.0, 0.0, 2e-4, -2e-4, 2e-4])
    rows = _rows(n, reading, e)
    white, _ = shapes.best(rows, SD, TOOL, 1.0)
    slow, _ = shapes.best(rows, SD, TOOL, 1.0, slow_sd=np.array([0.002] * 3 + [2e-4] * 3))
    assert white.shape == "sensor_constant"
    assert slow.shape == "ft_frame_rotation"


def test_a_socket_engaged_at_the_drive_start_is_contact_at_any_depth():
    """``online/cell.toml``: the socket holds the tip from the end of the settle window (``socket_engage =
    "drive"``) while the tip is still 5 mm above the entrance, outside the monitor's 4 mm zone; its
    spring's force (the truth's contact force) is not the model's. The monitor takes every sample from
    ``settle_s`` on as contact: nothing is judged there (the residual is NaN) and no event is named (it had
    named a drift at 0.32 s)."""
    cfg = load_config(REPO / "online/cell.toml", ["run.progress=false", "run.tensorboard=false", "run.figure=false",
                                                   "monitor.enabled=true", "run.insertions=1"])
    r = run_episode(cfg)
    tr = r.trace
    t = tr["t_s"]
    after = t > cfg.start.settle_s + 2 * cfg.run.dt_s
    assert np.max(np.abs(tr["truth_contact_force_N"][after])) > 1.0  # the fixture does pull
    assert np.all(tr["truth_tip_depth_m"][(t > cfg.start.settle_s) & (t < 0.45)] < -cfg.monitor.contact_zone_m)
    z = tr["monitor_z"]
    assert np.isfinite(z[(t > cfg.monitor.calib_s + 0.01) & (t < cfg.start.settle_s - 0.01)]).all()
    assert np.isnan(z[after]).all()
    assert r.summary["monitor"]["events"] == []
