"""Where contacts act: the contact point on the tool, estimated from the wrench.

In contact the sensor reads the tool's own wrench plus the contact's. With the calibrated tool
model taken out, a point contact at ``p`` (sensor frame s, [m]) leaves ``w_c = [f, p x f]``, linear
in ``p``::

    m_c = -[f]x p        (3 rows per sample; [f]x the cross-product matrix of the contact force)

so ``p`` is a least-squares fit over the contact samples. Along the force's line of action ``p``
is not seen by one sample; the force's direction changes pin it. Its sd is the larger of the
information sd and a delete-one-block jackknife over the contact's time blocks (a moving contact
gives correlated residuals), with the calibration's covariance added (``with_calibration``: the
point moves with the tool model it is fitted after). A component whose sd stays above ``UNDETERMINED_M`` is reported as
undetermined with the direction it lies along. The moment this point leaves unexplained
(``residual_moment_rms_Nm``) tells a point contact from a face or line contact.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

MIN_FORCE_N = 2.0  #: [N] contact samples with a weaker contact force are not used
MIN_SAMPLES = 20
UNDETERMINED_M = 0.01  #: [m] a direction of the point with a larger sd is undetermined
#: the calibration's share of the point's sd (``with_calibration``: the point's derivative in each
#: calibration parameter) from at most this many contact samples, evenly spaced (``sensitivity_samples``)
SENSITIVITY_SAMPLES = 50_000
BLOCKS = 10


@dataclass(frozen=True)
class ContactPoint:
    """The contact point in the sensor frame (``estimate``)."""

    point_s_m: np.ndarray  #: (3,) [m] the point, sensor frame
    sd_m: np.ndarray  #: (3,) [m] its sd along the sensor axes
    undetermined_along_s: np.ndarray | None  #: (3,) unit direction the data leave free, or None
    samples: int  #: contact samples used
    residual_moment_rms_Nm: float  #: [N m] moment the point leaves unexplained
    force_rms_N: float  #: [N] contact force, RMS over the samples used

    def to_json(self) -> dict:
        und = self.undetermined_along_s
        return {"point_sensor_m": [float(v) for v in self.point_s_m], "sd_m": [float(v) for v in self.sd_m],
                "undetermined_along_sensor": None if und is None else [float(v) for v in und],
                "samples": self.samples, "residual_moment_rms_Nm": self.residual_moment_rms_Nm,
                "contact_force_rms_N": self.force_rms_N,
                "method": "least squares of m_c = p x f over the contact samples (calibrated tool model taken out); "
                          "sd = max(information, block jackknife), with the calibration's covariance added"}


def _skews(f: np.ndarray) -> np.ndarray:
    z = np.zeros(len(f))
    return np.stack([np.stack([z, -f[:, 2], f[:, 1]], 1), np.stack([f[:, 2], z, -f[:, 0]], 1),
                     np.stack([-f[:, 1], f[:, 0], z], 1)], 1)


def _solve(f: np.ndarray, m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    A = -_skews(f).reshape(-1, 3)  # (3n, 3): m = -[f]x p
    y = m.reshape(-1)
    H = A.T @ A
    H_reg = H + 1e-12 * max(np.trace(H), 1e-300) * np.eye(3)
    p = np.linalg.solve(H_reg, A.T @ y)
    return p, y - A @ p, H_reg


def estimate(w_contact_s: np.ndarray, contact: np.ndarray) -> ContactPoint | None:
    """The contact point from the contact wrench ``w_contact_s`` (n, 6) [N, N m] (measured minus
    the calibrated tool model, sensor frame, about its origin) on the samples ``contact`` (n,)
    bool. None when fewer than ``MIN_SAMPLES`` contact samples carry ``MIN_FORCE_N``."""
    use = contact & (np.linalg.norm(w_contact_s[:, :3], axis=1) > MIN_FORCE_N)
    idx = np.flatnonzero(use)
    if len(idx) < MIN_SAMPLES:
        return None
    f, m = w_contact_s[idx, :3], w_contact_s[idx, 3:]
    p, r, H = _solve(f, m)
    s2 = float(r @ r) / max(len(r) - 3, 1)
    cov = s2 * np.linalg.inv(H)
    groups = np.array_split(np.arange(len(idx)), min(BLOCKS, len(idx) // MIN_SAMPLES))
    if len(groups) >= 3:
        reps = np.array([_solve(np.delete(f, g, 0), np.delete(m, g, 0))[0] for g in groups])
        nb = len(groups)
        sd_jk = np.sqrt((nb - 1) / nb * np.sum((reps - reps.mean(0)) ** 2, axis=0))
        cov_jk = (nb - 1) / nb * (reps - reps.mean(0)).T @ (reps - reps.mean(0))
    else:
        sd_jk, cov_jk = np.zeros(3), np.zeros((3, 3))
    sd = np.maximum(np.sqrt(np.maximum(np.diag(cov), 0.0)), sd_jk)
    lam, vec = np.linalg.eigh(cov + cov_jk)
    und = vec[:, -1] if np.sqrt(max(lam[-1], 0.0)) > UNDETERMINED_M else None
    return ContactPoint(p, sd, und, len(idx), float(np.sqrt(np.mean(r.reshape(-1, 3) ** 2) * 3)),
                        float(np.sqrt(np.mean(np.sum(f**2, axis=1)))))


def sensitivity_samples(m: int) -> np.ndarray:
    """Positions of at most ``SENSITIVITY_SAMPLES`` of ``m`` contact samples, evenly spaced (so the
    same whatever the chunking): the derivative of ``with_calibration`` is a property of the
    motion, not of every sample, and 27 model evaluations on an hour's contact would dominate it."""
    if m <= SENSITIVITY_SAMPLES:
        return np.arange(m)
    return np.linspace(0, m - 1, SENSITIVITY_SAMPLES).round().astype(int)


def with_calibration(point: ContactPoint | None, w_meas_s: np.ndarray, model_at, contact: np.ndarray,
                     cov_x: np.ndarray | None) -> ContactPoint | None:
    """The point with the calibration's covariance added to its sd: the point is fitted to the measured
    wrench ``w_meas_s`` (n, 6) minus the calibrated tool model, ``model_at(dx)`` (n, 6) the model with its
    parameters moved by ``dx`` (k,) (``dx = 0``: as fitted), ``cov_x`` (k, k) their covariance. The point's
    derivative in each parameter by central differences of one sd; ``sd^2 = sd_point^2 + diag(J cov_x J^T)``
    (the calibration is fitted on free space, the point on contact: independent noise)."""
    if point is None or cov_x is None:
        return point
    w0 = w_meas_s - model_at(np.zeros(len(cov_x)))
    idx = np.flatnonzero(contact & (np.linalg.norm(w0[:, :3], axis=1) > MIN_FORCE_N))
    sd_x = np.sqrt(np.clip(np.diag(cov_x), 0.0, None))
    J = np.zeros((3, len(cov_x)))
    for j in np.flatnonzero(sd_x > 0):
        dx = np.zeros(len(cov_x))
        dx[j] = sd_x[j]
        pp, pm = (_solve(w[:, :3], w[:, 3:])[0] for w in (w_meas_s[idx] - model_at(dx)[idx],
                                                          w_meas_s[idx] - model_at(-dx)[idx]))
        J[:, j] = (pp - pm) / (2.0 * sd_x[j])
    sd = np.sqrt(point.sd_m**2 + np.clip(np.diag(J @ cov_x @ J.T), 0.0, None))
    return replace(point, sd_m=sd)


__all__ = ["ContactPoint", "SENSITIVITY_SAMPLES", "estimate", "sensitivity_samples", "with_calibration"]
