"""Sensor-side success and failure: the seat check and the failure classes, from the
controller's own signals (the sensor vector s and the tared wrench), never from the truth.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from kinadapt_nn.config import ExperimentCfg, SuccessCfg

#: the failure classes of an unseated run (:func:`classify_failure`; "none": seated)
FAILURES = ("none", "timeout", "jam", "block_face", "divergence")


@nb.njit(cache=True)
def seat_step(t, s, lim, clock) -> bool:
    """One control step of the seat check, for the single episode and every batch episode alike:
    depth reached, |F_lat| and |M| inside their limits, all three held ``hold_s``. s (6,) the
    sensor vector; lim = [d_seat, max |F_lat|, max |M|, hold_s]; clock = [since, seat_time] [s],
    NaN while not yet, updated in place. -> whether all three conditions hold now."""
    ok = (s[0] >= lim[0] and math.hypot(s[1], s[2]) < lim[1]
          and math.sqrt(s[3] * s[3] + s[4] * s[4] + s[5] * s[5]) < lim[2])
    if ok:
        if np.isnan(clock[0]):
            clock[0] = t
        if np.isnan(clock[1]) and t - clock[0] >= lim[3] - 1e-12:
            clock[1] = t
    else:
        clock[0] = np.nan
    return ok


def seat_limits(success: SuccessCfg) -> np.ndarray:
    """The seat check's limits (``seat_step``'s ``lim``): [d_seat = depth_m - depth_tol_m [m],
    max |F_lat| [N], max |M| [N m], hold_s [s]]. -> (4,)."""
    return np.array([success.depth_m - success.depth_tol_m, success.max_lateral_force_N, success.max_moment_Nm,
                     success.hold_s])


class SeatMonitor:
    """Sensor-side success of one episode (``seat_step``): ``update(t, s)`` each step with the drive on."""

    def __init__(self, cfg: ExperimentCfg) -> None:
        self.lim = seat_limits(cfg.success)
        self.d_seat, self.f_max, self.m_max = (float(v) for v in self.lim[:3])
        self.clock = np.full(2, np.nan)  # [since, seat_time]

    @property
    def seat_time(self) -> float | None:
        """When the seat check first held for ``hold_s`` [s], else None."""
        return None if math.isnan(self.clock[1]) else float(self.clock[1])

    def update(self, t: float, s: np.ndarray) -> bool:
        """One step; s (6,) the sensor vector. -> whether all three conditions hold now."""
        return seat_step(t, s, self.lim, self.clock)


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
