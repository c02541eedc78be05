"""The log's units, checked against the data: a force, torque or time unit the log does not fit is named.

**The wrench units** (:func:`check`). A unit cannot be read off a rigid tool's statics alone: scaling
the torques by ``k`` scales the fitted first moment ``m c`` by ``k``, scaling the forces scales the
mass. What pins the unit is what a tool on a sensor can be. Every pair of units (``FORCE_UNITS`` x ``TORQUE_UNITS``) is tried on the
free-space samples: the wrench rescaled (SI at the candidate = ``k`` x SI as declared), the
calibration's linear part ``theta = [m, m c, b]`` refitted at the calibrated sensor rotation
(``mount.fit_at``; a moving log's rotation is refitted per torque unit, ``mount.refine_rotation``,
as the declared unit's inertia misfit may have turned it), and the pair scored by how many decades what it implies lies outside what is
plausible (``score``, the sum of):

* the tool's mass within a factor ``DECLARED_FACTOR`` of ``[tool] mass_kg`` (not declared:
  within ``MASS_RANGE_KG``);
* its centre of mass -- the moment arm of its weight, ``|m c| / m`` -- within ``DECLARED_FACTOR`` of
  ``|[tool] com_sensor_m|`` (not declared: within ``COM_RANGE_M``), where the log pins it (``|m c|``
  beyond ``SIGNIFICANT_SD`` sd). ``m c`` is read from the torques alone (``moment_arm``: ``M = m c x
  g_a + b_M`` and, on a moving log, a free inertia's moments), whose significance no unit changes:
  the joint fit also reads ``m c`` from the forces a moving tool's turn exerts, and under a torque
  unit a thousand times off the two disagree and the robust fit drops the torques (a moving log's
  first moment then looked undetermined, its moment arm of 39 m unseen);
* a moving log: the free-space wrench fitted within ``MISFIT_OK`` times the smallest rms misfit
  any pair leaves, or the log's own sample noise (second differences, ``signals.sample_noise``,
  scaled with the unit) if larger. The declared inertia's moments ``I_O alpha + omega x I_O omega``
  do not scale with a unit: under a wrong torque unit they are left unexplained, thousands of times
  the noise, while a unit cannot remove what the model lacks (an inertia declared wrong);
* every reading within ``RANGE_FACTOR`` times the sensor's rated range, where declared.

The declared units are called wrong when they score at least ``WRONG_DECADES`` and another pair
at most ``FITS_DECADES`` (a plain warning; the diagnosis blocks every verdict). The pair named is the
one nearest the declared tool (``UnitCandidate.distance``), then nearest the declared units.

**The time unit** (:func:`check_time`): a time column in ms (or us, ns) read as seconds is named.

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

from kinadapt_nn.diagnostics import mount
from kinadapt_nn.diagnostics.physical import nominal_inertials
from kinadapt_nn.diagnostics.setup import FORCE_UNITS, TORQUE_UNITS, rpy_matrix
from kinadapt_nn.diagnostics.signals import sample_noise

DECLARED_FACTOR = 2.0  #: a declared mass / centre of mass is trusted to this factor either way
MASS_RANGE_KG = (1e-3, 1000.0)  #: [kg] a tool's mass when none is declared
COM_RANGE_M = (0.002, mount.COM_PLAUSIBLE_M)  #: [m] a tool's centre of mass from the sensor, none declared
MISFIT_OK = 10.0  #: a moving log's free-space rms misfit may be this many times the smallest (or the noise)
RANGE_FACTOR = 2.0  #: a reading beyond this many times the rated range is not a reading of that sensor
SIGNIFICANT_SD = 3.0
WRONG_DECADES = 0.5  #: the declared unit(s) score this many decades outside the plausible: wrong
FITS_DECADES = 0.1  #: ... and another candidate scores at most this: the one that fits
MAX_ROWS = 1000  #: free-space samples refitted (evenly spaced subset; the decision is in decades)


class UnitCandidate(NamedTuple):
    """One pair of units, as the data see it."""

    force_unit: str
    torque_unit: str
    mass_kg: float  #: the refitted tool mass
    com_m: float | None  #: [m] |c| of the refitted centre of mass; None where the log does not pin it
    misfit: float | None  #: [noise sd] rms free-space misfit (moving logs), None for a static log
    score: float  #: decades outside the plausible (module docstring); inf for a non-positive mass
    distance: float  #: decades from the declared tool (mass, centre of mass) and from a noise-level fit


class UnitCheck(NamedTuple):
    """The units check of one log (module docstring)."""

    declared: UnitCandidate
    likely: UnitCandidate  #: the best pair (the declared one when nothing fits better)
    message: str | None  #: the warning, None when the declared units fit


def _outside(v: float, lo: float, hi: float) -> float:
    """Decades by which ``v`` > 0 lies outside ``[lo, hi]`` (0 inside)."""
    return max(0.0, math.log10(lo / v), math.log10(v / hi))


def _band(declared: float, default: tuple[float, float]) -> tuple[float, float]:
    return (declared / DECLARED_FACTOR, declared * DECLARED_FACTOR) if declared > 0 else default


def _free_data(s, setup, sigma: np.ndarray) -> mount.MountData:
    """The free-space samples in ``mount``'s form, weighted by the log's own noise (6,) [N, N m]."""
    free = ~np.asarray(s.contact, bool)
    if free.sum() < 20:
        free = np.ones(s.n, bool)
    idx = np.flatnonzero(free)
    if len(idx) > MAX_ROWS:
        idx = idx[np.linspace(0, len(idx) - 1, MAX_ROWS).round().astype(int)]
    _, _, I_O = nominal_inertials(setup)
    return mount.MountData(s.g_s[idx] - s.a_s[idx], s.omega_s[idx], s.alpha_s[idx], s.wrench[idx], 1.0 / sigma,
                           I_O, np.zeros(len(idx), int), inertia=False)  # the declared tool's inertia holds


def _scale(fu: str, tu: str, setup) -> np.ndarray:
    """(6,) SI at the units ``fu``, ``tu`` per SI as declared."""
    kf = FORCE_UNITS[fu] / FORCE_UNITS[setup.log.force_unit]
    kt = TORQUE_UNITS[tu] / TORQUE_UNITS[setup.log.torque_unit]
    return np.array([kf] * 3 + [kt] * 3)


class MomentArm(NamedTuple):
    """The tool's first moment as the torques alone see it (``moment_arm``), in the declared units."""

    mc: np.ndarray  #: (3,) [kg m as declared] m c in the sensor frame
    sd: np.ndarray  #: (3,) its sd (the larger of the information and a delete-one-block jackknife)

    @property
    def pinned(self) -> bool:
        """``|m c|`` beyond ``SIGNIFICANT_SD`` sd: the log determines the moment arm (unit-free)."""
        return bool(np.linalg.norm(self.mc) > SIGNIFICANT_SD * np.linalg.norm(self.sd))


def moment_arm(D: np.ndarray, d: mount.MountData, blocks: int = 10) -> MomentArm:
    """The first moment from the torques alone at the rotation ``D`` (3, 3): ``M = (m c) x g_a + b_M``
    and, where the samples turn the sensor, ``- I alpha - omega x (I omega)`` with the inertia about
    the sensor origin free (Atkeson, An & Hollerbach 1986, the moment rows); least squares, Huber
    reweighted. A torque unit scales ``m c`` and its sd alike: whether it is pinned does not depend
    on the unit, and ``|m c| / m`` under each candidate is the tool's moment arm in metres."""
    ga, om, al = d.ga @ D, d.omega @ D, d.alpha @ D  # (n, 3) rows: D^T v
    n = len(ga)
    moves = bool(np.any(om) or np.any(al))
    A = np.zeros((n, 3, 12 if moves else 6))  # [m c, b_M, I (6, moving logs)]
    A[:, 0, 1], A[:, 0, 2], A[:, 1, 2] = ga[:, 2], -ga[:, 1], ga[:, 0]  # (m c) x g_a = -[g_a]x (m c)
    A[:, 1, 0], A[:, 2, 0], A[:, 2, 1] = -ga[:, 2], ga[:, 1], -ga[:, 0]
    A[:, :, 3:6] = np.eye(3)
    if moves:
        A[:, :, 6:] = -mount._inertia_moment(om, al)
    w = d.w[3:]
    y = d.r[:, 3:]

    def solve(i: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        rw = np.ones((len(i), 3))
        for _ in range(4):
            sw = w * np.sqrt(rw)
            x = mount._normal_solve((A[i] * sw[:, :, None]).reshape(-1, A.shape[2]), (y[i] * sw).reshape(-1))
            e = ((y[i] - np.einsum("nik,k->ni", A[i], x)) * w).reshape(-1)
            a = np.abs(e)
            rw = np.where(a <= mount.HUBER_K, 1.0, mount.HUBER_K / np.maximum(a, 1e-300)).reshape(-1, 3)
        return x, e

    x, e = solve(np.arange(n))
    J = (A * w[None, :, None]).reshape(-1, A.shape[2])
    sd = np.sqrt(np.maximum(np.diag(mount._info_cov(J, e))[:3], 0.0))
    groups = np.array_split(np.arange(n), blocks) if n >= 4 * blocks else []
    if groups:  # contiguous samples: a moving log's correlated residual makes the information sd small
        reps = [solve(np.setdiff1d(np.arange(n), g))[0][:3] for g in groups]
        sd = np.maximum(sd, mount._jackknife_sd(reps))
    return MomentArm(x[:3], sd)


def _candidate(fu: str, tu: str, d: mount.MountData, D: np.ndarray, s, setup, arm: MomentArm,
               peaks: tuple[float, float]) -> UnitCandidate:
    """One unit pair (``arm``: the torques' first moment as declared; ``peaks``: the largest |force|
    and |moment| the log reads, in its units)."""
    k = _scale(fu, tu, setup)
    dk = d._replace(r=d.r * k, w=d.w / k)
    theta, res = mount.fit_at(D, dk, iters=5)
    m = float(theta[0])
    misfit = None if s.static else float(np.sqrt(np.mean((res * dk.w) ** 2)))
    if m <= 0:
        return UnitCandidate(fu, tu, m, None, misfit, math.inf, math.inf)
    m_decl, c_decl = float(setup.tool.mass_kg), float(np.linalg.norm(setup.tool.com_sensor_m))
    lo, hi = _band(m_decl, MASS_RANGE_KG)
    score, dist = _outside(m, lo, hi), abs(math.log10(m / math.sqrt(lo * hi)))
    com = float(np.linalg.norm(arm.mc) * k[3] / m) if arm.pinned else None  # the moment arm of the weight [m]
    if com is not None:
        lo, hi = _band(c_decl, COM_RANGE_M)
        score += _outside(max(com, 1e-12), lo, hi)
        dist += abs(math.log10(max(com, 1e-12) / math.sqrt(lo * hi)))
    rated = (setup.sensor.range_force_N, setup.sensor.range_torque_Nm)
    for j, rng in enumerate(rated):
        peak = peaks[j] * k[3 * j]
        if rng > 0 and peak > 0:
            score += max(0.0, math.log10(peak / (RANGE_FACTOR * rng)))
    return UnitCandidate(fu, tu, m, com, misfit, score, dist)


def _with_misfit(cands: list[UnitCandidate]) -> list[UnitCandidate]:
    """A moving log's misfit, against the smallest any unit leaves (a unit cannot remove physics the
    model lacks, e.g. a tool's inertia declared wrong): decades beyond ``MISFIT_OK`` times that."""
    best = max(min(c.misfit for c in cands), 1e-300)
    ref = max(MISFIT_OK, best)
    return [c._replace(score=c.score + max(0.0, math.log10(max(c.misfit, 1e-300) / ref)),
                       distance=c.distance + math.log10(max(c.misfit, best) / best)) for c in cands]


def check(fitm: mount.MountFit, s, setup, sigma: np.ndarray) -> UnitCheck:
    """The declared units against every pair (module docstring). ``fitm`` the calibration fit,
    ``s`` the ``LogSignals`` in the setup ``setup`` (its contact mask marks what is not free
    space), ``sigma`` (6,) [N, N m] the noise used when the log's own (moving logs) is zero."""
    # the calibrated rotation relative to the frame the signals are in
    D = setup.sensor.R_fs().T @ rpy_matrix(np.deg2rad(fitm.rpy_deg))
    noise = np.asarray(sigma, dtype=float) if s.static else sample_noise(s.wrench)
    noise = np.where(noise > 0, noise, sigma)
    d = _free_data(s, setup, noise)
    arm = moment_arm(D, d)
    cands = []
    peaks = (float(np.max(np.abs(s.wrench[:, :3]))), float(np.max(np.abs(s.wrench[:, 3:]))))
    for tu in TORQUE_UNITS:
        Dt = D
        if not s.static and tu != setup.log.torque_unit:
            # a moving log's rotation was fitted with the declared torques and their inertia misfit:
            # fitted again for this unit (a static log's fit does not depend on a unit)
            k = _scale(setup.log.force_unit, tu, setup)
            Dt = mount.refine_rotation(d._replace(r=d.r * k, w=d.w / k), [D, np.eye(3)])
        cands += [_candidate(fu, tu, d, Dt, s, setup, arm, peaks) for fu in FORCE_UNITS]
    if not s.static:
        cands = _with_misfit(cands)
    lf, lt = setup.log.force_unit, setup.log.torque_unit
    declared = next(c for c in cands if (c.force_unit, c.torque_unit) == (lf, lt))
    fits = [c for c in cands if c.score <= FITS_DECADES and c is not declared]
    if declared.score < WRONG_DECADES or not fits or not math.isfinite(declared.mass_kg) or declared.mass_kg <= 0:
        return UnitCheck(declared, declared, None)

    def away(c: UnitCandidate) -> float:  # decades from the declared units
        return abs(math.log10(FORCE_UNITS[c.force_unit] / FORCE_UNITS[lf])) + \
            abs(math.log10(TORQUE_UNITS[c.torque_unit] / TORQUE_UNITS[lt]))

    likely = min(fits, key=lambda c: (c.distance, away(c)))
    return UnitCheck(declared, likely, _message(declared, likely, setup))


def _length(x_m: float) -> str:
    return f"{1000 * x_m:.3g} mm" if x_m < 1.0 else f"{x_m:.3g} m"


def _describe(c: UnitCandidate) -> str:
    parts = [f"tool mass {c.mass_kg:.3g} kg"]
    if c.com_m is not None:
        parts.append(f"centre of mass {_length(c.com_m)} from the sensor")
    if c.misfit is not None:
        parts.append(f"free-space misfit {c.misfit:.3g}x the noise")
    return ", ".join(parts)


def _message(declared: UnitCandidate, likely: UnitCandidate, setup) -> str:
    tool = setup.tool
    decl = ([f"{tool.mass_kg:g} kg"] if tool.mass_kg > 0 else []) + \
        ([_length(float(np.linalg.norm(tool.com_sensor_m)))] if np.any(tool.com_sensor_m) else [])
    fix = [f'{k} = "{v}"' for k, v, was in (("force_unit", likely.force_unit, declared.force_unit),
                                             ("torque_unit", likely.torque_unit, declared.torque_unit)) if v != was]
    return (f'[log] force_unit = "{declared.force_unit}", torque_unit = "{declared.torque_unit}" do not fit the data: '
            f"as declared, {_describe(declared)}{' (declared: ' + ', '.join(decl) + ')' if decl else ''}; as "
            f'"{likely.force_unit}" and "{likely.torque_unit}", {_describe(likely)}. The unit that fits: set [log] '
            + " and ".join(fix))


# -- the time unit (module docstring) --------------------------------------------------------------
RATE_RANGE_HZ = (1.0, 1e5)  #: [Hz] the sample rate of a logged moving arm (a joint/FT logger: ~10 Hz to ~10 kHz)
SPEED_RANGE_RAD_S = (5e-3, 50.0)  #: [rad/s] an arm's peak joint speed while it moves (0.3 deg/s to a fast wrist)
MOVE_MIN_RAD = 0.05  #: [rad] a joint must turn this far for its peak speed to witness the time unit
SPEED_QUANTILE = 0.99  #: the peak speed: this quantile of the fastest joint's |dq/dt| (a spike is not a speed)
MIN_CORRELATION = 0.9  #: logged qdot and dq/dt must agree this well in shape to give the ratio
TIME_STEPS = range(-3, 4)  #: candidates: the declared time_scale_s times 10^(3 j)
TIME_UNIT_NAMES = {1.0: "s", 1e-3: "ms", 1e-6: "us", 1e-9: "ns"}


class TimeCandidate(NamedTuple):
    """One candidate time scale, as the data see it."""

    time_scale_s: float  #: [s per unit] of the time column
    rate_hz: float  #: the sample rate it implies
    speed_rad_s: float | None  #: the peak joint speed it implies (None: the arm does not move enough)
    velocity_ratio: float | None  #: logged qdot / (dq/dt) at this scale (None: no qdot column to compare)
    score: float  #: decades outside the plausible (module docstring, "The time unit")


class TimeCheck(NamedTuple):
    """The time-unit check of one log (module docstring, "The time unit")."""

    declared: TimeCandidate
    likely: TimeCandidate  #: the candidate that fits (the declared one when nothing fits better)
    message: str | None  #: the warning, None when the declared time fits or the log cannot tell



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
    off = min(abs(math.log10(ratio) + 3 * j) for j in TIME_STEPS) if ratio > 0 else math.inf
    return ratio if off <= FITS_DECADES else None  # not a power of 1000: another error (an angle unit)


def _motion(t: np.ndarray, q: np.ndarray) -> tuple[float, float | None]:
    """(sample rate [Hz], peak joint speed [rad/s] or None) over the time column as read."""
    dt = float(np.median(np.diff(t)))
    if not np.all(np.ptp(q, axis=0) < MOVE_MIN_RAD):
        speed = float(np.quantile(np.max(np.abs(np.gradient(q, t, axis=0)), axis=1), SPEED_QUANTILE))
    else:
        speed = None
    return 1.0 / dt, speed


def check_time(log, setup) -> TimeCheck | None:
    """The declared ``[log] time_scale_s`` against the arm's motion in ``log`` (a ``readers.UserLog``,
    time already in the declared seconds) (module docstring, "The time unit"); None where the log has no
    time to check."""
    if log.static or log.t_s is None or len(log.t_s) < 10 or not setup.log.time:
        return None
    t, q = np.asarray(log.t_s, float), np.asarray(log.q_rad, float)
    rate, speed = _motion(t, q)
    ratio = None if log.qdot_rad_s is None else _velocity_ratio(t, q, np.asarray(log.qdot_rad_s, float))
    if not (rate > 0 and math.isfinite(rate)) or (speed is not None and speed <= 0):
        return None
    declared_scale = float(setup.log.time_scale_s)
    cands = []
    for j in TIME_STEPS:
        f = 10.0 ** (3 * j)  # true seconds per declared second
        if ratio is not None:  # the logged velocities are the truth: dq/dt over true time = ratio x as read
            score = abs(math.log10(max(ratio, 1e-300) * f)) if ratio > 0 else math.inf
            r = ratio * f
        else:
            score = _outside(rate / f, *RATE_RANGE_HZ)
            score += 0.0 if speed is None else _outside(speed / f, *SPEED_RANGE_RAD_S)
            r = None
        cands.append(TimeCandidate(declared_scale * f, rate / f, None if speed is None else speed / f, r, score))
    declared = cands[list(TIME_STEPS).index(0)]
    fits = [c for c in cands if c.score <= FITS_DECADES and c is not declared]
    if declared.score < WRONG_DECADES or not fits:
        return TimeCheck(declared, declared, None)
    likely = min(fits, key=lambda c: abs(math.log10(c.time_scale_s / declared_scale)))
    return TimeCheck(declared, likely, _time_message(declared, likely))


def _time_scale_text(v: float) -> str:
    name = next((u for s, u in TIME_UNIT_NAMES.items() if math.isclose(v, s, rel_tol=1e-9)), None)
    return f"{v:g}" + (f" (the time column in {name})" if name else "")


def _time_describe(c: TimeCandidate) -> str:
    if c.velocity_ratio is not None:
        return f"the logged joint velocities {c.velocity_ratio:.3g}x the derivative of q"
    return f"{c.rate_hz:.3g} samples per s" + ("" if c.speed_rad_s is None else
                                                f", joints at most {c.speed_rad_s:.3g} rad/s")


def _time_message(declared: TimeCandidate, likely: TimeCandidate) -> str:
    return (f"[log] time_scale_s = {declared.time_scale_s:g} does not fit the data: as declared, {_time_describe(declared)}; "
            f"at time_scale_s = {_time_scale_text(likely.time_scale_s)}, {_time_describe(likely)}. The unit that fits: set "
            f"[log] time_scale_s = {likely.time_scale_s:g}")


__all__ = ["MomentArm", "TimeCandidate", "TimeCheck", "UnitCandidate", "UnitCheck", "check", "check_time",
           "moment_arm"]
