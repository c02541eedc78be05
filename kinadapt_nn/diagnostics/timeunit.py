"""The time unit, checked against the data: a time column in ms (or us, ns) read as seconds is named.

``[log] time_scale_s`` (seconds per unit of the time column) cannot be read off the F/T statics: a
wrong one stretches every derivative but leaves gravity as it is. What tells it is the arm's motion.
Every candidate ``time_scale_s`` (the declared one times ``10^(3 j)``, ``|j| <= 3``: s, ms, us, ns
stamps) is tried, the first witness that applies decides:

* logged joint velocities (``[log] qdot``): their ratio to the derivative of ``q`` over the time
  column is the factor the declared time is off by (1 when right, 1000 for ms read as s); a
  candidate scores the decades between its factor and that ratio. Read only where the two agree
  in shape (correlation ``MIN_CORRELATION``) and the ratio is a power of 1000 (within
  ``FITS_DECADES``): velocities in another angle unit than the positions are another error;
* otherwise the arm's own motion: its sample rate ``1 / median(dt)`` within ``RATE_RANGE_HZ`` and,
  where a joint turns by more than ``MOVE_MIN_RAD``, its peak joint speed (the ``SPEED_QUANTILE``
  of the fastest joint's ``|dq/dt|``) within ``SPEED_RANGE_RAD_S``; a candidate scores the decades
  by which each lies outside.

The declared time is called wrong when it scores at least ``WRONG_DECADES`` and another candidate
at most ``FITS_DECADES``; the one named is the fitting candidate nearest the declared. A static log
(poses at rest: its time carries no motion) and a kinadapt trace (its own ``t_s``) are not checked.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

RATE_RANGE_HZ = (1.0, 1e5)  #: [Hz] the sample rate of a logged moving arm (a joint/FT logger: ~10 Hz to ~10 kHz)
SPEED_RANGE_RAD_S = (5e-3, 50.0)  #: [rad/s] an arm's peak joint speed while it moves (0.3 deg/s to a fast wrist)
MOVE_MIN_RAD = 0.05  #: [rad] a joint must turn this far for its peak speed to witness the time unit
SPEED_QUANTILE = 0.99  #: the peak speed: this quantile of the fastest joint's |dq/dt| (a spike is not a speed)
MIN_CORRELATION = 0.9  #: logged qdot and dq/dt must agree this well in shape to give the ratio
STEPS = range(-3, 4)  #: candidates: the declared time_scale_s times 10^(3 j)
WRONG_DECADES = 0.5  #: the declared time scores this many decades outside the plausible: wrong
FITS_DECADES = 0.1  #: ... and another candidate at most this: the one that fits
UNIT_NAMES = {1.0: "s", 1e-3: "ms", 1e-6: "us", 1e-9: "ns"}


class TimeCandidate(NamedTuple):
    """One candidate time scale, as the data see it."""

    time_scale_s: float  #: [s per unit] of the time column
    rate_hz: float  #: the sample rate it implies
    speed_rad_s: float | None  #: the peak joint speed it implies (None: the arm does not move enough)
    velocity_ratio: float | None  #: logged qdot / (dq/dt) at this scale (None: no qdot column to compare)
    score: float  #: decades outside the plausible (module docstring)


class TimeCheck(NamedTuple):
    """The time-unit check of one log (module docstring)."""

    declared: TimeCandidate
    likely: TimeCandidate  #: the candidate that fits (the declared one when nothing fits better)
    message: str | None  #: the warning, None when the declared time fits or the log cannot tell


def _outside(v: float, lo: float, hi: float) -> float:
    """Decades by which ``v`` > 0 lies outside ``[lo, hi]`` (0 inside)."""
    return max(0.0, math.log10(lo / v), math.log10(v / hi))


def _velocity_ratio(t: np.ndarray, q: np.ndarray, qdot: np.ndarray) -> float | None:
    """Logged ``qdot`` (N, dof) per ``dq/dt`` over ``t`` (N,), least squares over the moving samples;
    None where the two do not agree in shape (``MIN_CORRELATION``) or nothing moves."""
    dq = np.gradient(q, t, axis=0)
    a, b = dq.reshape(-1), qdot.reshape(-1)
    if not np.any(a) or not np.any(b):
        return None
    corr = float(a @ b / math.sqrt(float(a @ a) * float(b @ b)))
    if corr < MIN_CORRELATION:
        return None
    ratio = float(a @ b / (a @ a))
    off = min(abs(math.log10(ratio) + 3 * j) for j in STEPS) if ratio > 0 else math.inf
    return ratio if off <= FITS_DECADES else None  # not a power of 1000: another error (an angle unit)


def _motion(t: np.ndarray, q: np.ndarray) -> tuple[float, float | None]:
    """(sample rate [Hz], peak joint speed [rad/s] or None) over the time column as read."""
    dt = float(np.median(np.diff(t)))
    if not np.all(np.ptp(q, axis=0) < MOVE_MIN_RAD):
        speed = float(np.quantile(np.max(np.abs(np.gradient(q, t, axis=0)), axis=1), SPEED_QUANTILE))
    else:
        speed = None
    return 1.0 / dt, speed


def check(log, setup) -> TimeCheck | None:
    """The declared ``[log] time_scale_s`` against the arm's motion in ``log`` (a ``readers.UserLog``,
    time already in the declared seconds) (module docstring); None where the log has no time to check."""
    if log.static or log.t_s is None or len(log.t_s) < 10 or not setup.log.time:
        return None
    t, q = np.asarray(log.t_s, float), np.asarray(log.q_rad, float)
    rate, speed = _motion(t, q)
    ratio = None if log.qdot_rad_s is None else _velocity_ratio(t, q, np.asarray(log.qdot_rad_s, float))
    if not (rate > 0 and math.isfinite(rate)) or (speed is not None and speed <= 0):
        return None
    declared_scale = float(setup.log.time_scale_s)
    cands = []
    for j in STEPS:
        f = 10.0 ** (3 * j)  # true seconds per declared second
        if ratio is not None:  # the logged velocities are the truth: dq/dt over true time = ratio x as read
            score = abs(math.log10(max(ratio, 1e-300) * f)) if ratio > 0 else math.inf
            r = ratio * f
        else:
            score = _outside(rate / f, *RATE_RANGE_HZ)
            score += 0.0 if speed is None else _outside(speed / f, *SPEED_RANGE_RAD_S)
            r = None
        cands.append(TimeCandidate(declared_scale * f, rate / f, None if speed is None else speed / f, r, score))
    declared = cands[list(STEPS).index(0)]
    fits = [c for c in cands if c.score <= FITS_DECADES and c is not declared]
    if declared.score < WRONG_DECADES or not fits:
        return TimeCheck(declared, declared, None)
    likely = min(fits, key=lambda c: abs(math.log10(c.time_scale_s / declared_scale)))
    return TimeCheck(declared, likely, _message(declared, likely))


def _scale_text(v: float) -> str:
    name = next((u for s, u in UNIT_NAMES.items() if math.isclose(v, s, rel_tol=1e-9)), None)
    return f"{v:g}" + (f" (the time column in {name})" if name else "")


def _describe(c: TimeCandidate) -> str:
    if c.velocity_ratio is not None:
        return f"the logged joint velocities {c.velocity_ratio:.3g}x the derivative of q"
    return f"{c.rate_hz:.3g} samples per s" + ("" if c.speed_rad_s is None else
                                                f", joints at most {c.speed_rad_s:.3g} rad/s")


def _message(declared: TimeCandidate, likely: TimeCandidate) -> str:
    return (f"[log] time_scale_s = {declared.time_scale_s:g} does not fit the data: as declared, {_describe(declared)}; "
            f"at time_scale_s = {_scale_text(likely.time_scale_s)}, {_describe(likely)}. The unit that fits: set "
            f"[log] time_scale_s = {likely.time_scale_s:g}")


__all__ = ["TimeCandidate", "TimeCheck", "check"]
