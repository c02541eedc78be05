"""Sensor-side success and failure: the seat check and the failure classes, from the
controller's own signals (the sensor vector s and the tared wrench), never from the truth.
"""

from __future__ import annotations

import math


import numpy as np

from kinadapt_nn.config import ExperimentCfg

FAILURES = ("none", "timeout", "jam", "block_face", "divergence")


class SeatMonitor:
    """Sensor-side success: depth reached, |F_lat| and |M| inside limits, held ``hold_s``."""

    def __init__(self, cfg: ExperimentCfg) -> None:
        sc = cfg.success
        self.d_seat = sc.depth_m - sc.depth_tol_m
        self.f_max = sc.max_lateral_force_N
        self.m_max = sc.max_moment_Nm
        self.hold = sc.hold_s
        self.since: float | None = None
        self.seat_time: float | None = None

    def update(self, t: float, s: np.ndarray) -> tuple[bool, bool, bool]:
        s0, s1, s2, s3, s4, s5 = s.tolist()
        depth_ok = s0 >= self.d_seat
        force_ok = math.hypot(s1, s2) < self.f_max
        moment_ok = math.sqrt(s3 * s3 + s4 * s4 + s5 * s5) < self.m_max
        if depth_ok and force_ok and moment_ok:
            if self.since is None:
                self.since = t
            if self.seat_time is None and t - self.since >= self.hold - 1e-12:
                self.seat_time = t
        else:
            self.since = None
        return depth_ok, force_ok, moment_ok


def classify_failure(cfg: ExperimentCfg, t: np.ndarray, s: np.ndarray, w_env: np.ndarray, diverged: bool) -> str:
    """Failure class of an unseated run from sensor-side channels only.

    ``divergence``: non-finite samples or a contact force beyond ``diverge_force_N``;
    ``block_face``: the last ``jam_window_s`` spent loaded with the sensor depth above
    ``face_depth_m`` (the peg never entered); ``jam``: loaded inside the bore with no depth
    progress over the last window; otherwise ``timeout``.
    """
    sc = cfg.success
    fmag = np.linalg.norm(w_env[:, :3], axis=1) if len(t) else np.zeros(0)
    if diverged or (len(fmag) and (not np.all(np.isfinite(fmag)) or fmag.max() > sc.diverge_force_N)):
        return "divergence"
    if len(t) == 0:
        return "timeout"
    win = t >= t[-1] - sc.jam_window_s
    loaded = np.median(fmag[win]) > sc.jam_force_N or np.median(np.linalg.norm(s[win, 3:], axis=1)) > sc.max_moment_Nm
    progress = s[win, 0].max() - s[win, 0].min()
    if loaded and progress < sc.jam_progress_m:
        return "block_face" if s[win, 0].mean() < sc.face_depth_m else "jam"
    return "timeout"
