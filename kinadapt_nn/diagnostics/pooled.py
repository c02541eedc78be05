"""Several recordings of one set-up at once: one tool and mount from all the logs that agree, and
the logs that contradict the others named, not averaged in.

Each log is diagnosed on its own first (its own tare/offset, contact, contact point: a section per
log). The calibrations are then pooled: for the tool mass, its centre of mass and the sensor
mount, a log *contradicts* the others when its estimate is more than ``Z_CONTRADICTS`` combined
sd from the medoid of all logs (the log whose estimates are nearest the rest -- robust to a
minority of outliers), with a floor at the sizes that matter (``FLOOR_*``). The pooled value is
the inverse-variance weighted mean of the logs that agree; its sd is the weighted-mean sd
inflated by ``sqrt(chi^2 / dof)`` when the agreeing logs scatter more than their own sd say
(the Birge ratio), so the interval covers the spread actually seen.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kinadapt_nn.diagnostics.mount import matrix_rpy, rotation_angle

Z_CONTRADICTS = 4.0  #: combined sd beyond which a log contradicts the others
FLOOR_MASS_REL = 0.02  #: a mass difference below 2 % never contradicts
FLOOR_COM_M = 0.003  #: [m]
FLOOR_MOUNT_DEG = 2.0  #: [deg]


def _rpy_matrix(rpy_deg) -> np.ndarray:
    r, p, y = np.deg2rad(rpy_deg)
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


@dataclass(frozen=True)
class LogCalibration:
    """One log's calibration as its report gives it (``sensor_mount``)."""

    name: str
    plausible: bool
    mass_kg: float
    mass_sd_kg: float
    com_m: np.ndarray  #: (3,) sensor frame
    com_sd_m: np.ndarray  #: (3,)
    R_fs: np.ndarray  #: (3, 3) the sensor mount
    mount_sd_deg: float  #: combined sd of the mount's angles

    @classmethod
    def of(cls, name: str, report: dict) -> LogCalibration:
        sm = report["sensor_mount"]
        com = sm["tool_com_sensor_m"]
        ok = com[0] is not None
        return cls(name, bool(sm.get("plausible", True)) and ok, float(sm["tool_mass_kg"]),
                   float(sm["tool_mass_sd_kg"]), np.array(com if ok else [np.nan] * 3, dtype=float),
                   np.array(sm["tool_com_sd_m"] if ok else [np.nan] * 3, dtype=float),
                   _rpy_matrix(sm["rpy_flange_deg"]), float(np.linalg.norm(sm["sd_deg"])))


def _deviations(a: LogCalibration, b: LogCalibration) -> dict[str, float]:
    """z of log a against log b for mass, centre of mass and mount (floors included)."""
    dm = abs(a.mass_kg - b.mass_kg) / np.hypot(np.hypot(a.mass_sd_kg, b.mass_sd_kg), FLOOR_MASS_REL * b.mass_kg)
    dc = float(np.max(np.abs(a.com_m - b.com_m) / np.hypot(np.hypot(a.com_sd_m, b.com_sd_m), FLOOR_COM_M)))
    ang = float(np.rad2deg(rotation_angle(a.R_fs.T @ b.R_fs)))
    dr = ang / np.hypot(np.hypot(a.mount_sd_deg, b.mount_sd_deg), FLOOR_MOUNT_DEG)
    return {"mass": float(dm), "centre of mass": dc, "mount": float(dr), "mount_angle_deg": ang}


def _weighted(x: np.ndarray, sd: np.ndarray) -> tuple[float, float, float]:
    """Inverse-variance mean, its sd (Birge-inflated), chi^2/dof."""
    w = 1.0 / np.maximum(sd, 1e-12) ** 2
    mean = float(np.sum(w * x) / np.sum(w))
    sd_mean = float(1.0 / np.sqrt(np.sum(w)))
    dof = len(x) - 1
    birge = float(np.sum(w * (x - mean) ** 2) / dof) if dof > 0 else 1.0
    return mean, sd_mean * np.sqrt(max(birge, 1.0)), birge


def _mean_rotation(Rs: list[np.ndarray], sd_deg: np.ndarray) -> np.ndarray:
    w = 1.0 / np.maximum(sd_deg, 1e-6) ** 2
    U, _, Vt = np.linalg.svd(sum(wi * R for wi, R in zip(w, Rs)))
    R = U @ Vt
    if np.linalg.det(R) < 0:
        U[:, -1] *= -1
        R = U @ Vt
    return R


def pool(reports: list[tuple[str, dict]]) -> dict:
    """The pooled section of several logs' reports ``[(name, report)]`` (module docstring)."""
    cals = [LogCalibration.of(n, r) for n, r in reports]
    implausible = [c for c in cals if not c.plausible]
    cand = [c for c in cals if c.plausible]
    out: dict = {"logs": [c.name for c in cals], "contradicting": [
        {"log": c.name, "why": "its own calibration is not a plausible tool (see its section)"} for c in implausible]}
    if len(cand) < 2:
        out.update({"agreeing": [c.name for c in cand], "pooled": None,
                    "note": "fewer than two logs with a plausible calibration: nothing to pool"})
        return out
    dev = np.array([[max(v for k, v in _deviations(a, b).items() if k != "mount_angle_deg") for b in cand]
                    for a in cand])
    medoid = cand[int(np.argmin(np.median(dev, axis=1)))]
    agree = []
    for c in cand:
        d = _deviations(c, medoid)
        bad = [k for k in ("mass", "centre of mass", "mount") if d[k] > Z_CONTRADICTS]
        if bad:
            out["contradicting"].append({
                "log": c.name, "why": " and ".join(f"another {k}" for k in sorted(
                    {"mount" if b == "mount" else "tool" for b in bad})),
                "z": {k: round(d[k], 2) for k in bad}, "mass_kg": c.mass_kg,
                "mount_angle_from_the_others_deg": d["mount_angle_deg"]})
        else:
            agree.append(c)
    out["agreeing"] = [c.name for c in agree]
    if len(agree) < 2:
        out["pooled"] = None
        return out
    m, m_sd, m_chi = _weighted(np.array([c.mass_kg for c in agree]), np.array([c.mass_sd_kg for c in agree]))
    com = [_weighted(np.array([c.com_m[i] for c in agree]), np.array([c.com_sd_m[i] for c in agree]))
           for i in range(3)]
    msd = np.array([c.mount_sd_deg for c in agree])
    R = _mean_rotation([c.R_fs for c in agree], msd)
    spread = np.array([np.rad2deg(rotation_angle(R.T @ c.R_fs)) for c in agree])
    mount_sd = max(float(1.0 / np.sqrt(np.sum(1.0 / np.maximum(msd, 1e-6) ** 2))),
                   float(np.sqrt(np.sum(spread**2) / max(len(agree) - 1, 1) / len(agree))))
    out["pooled"] = {
        "tool_mass_kg": m, "tool_mass_sd_kg": m_sd,
        "tool_com_sensor_m": [c[0] for c in com], "tool_com_sd_m": [c[1] for c in com],
        "sensor_rpy_flange_deg": [float(v) for v in np.rad2deg(matrix_rpy(R))], "mount_sd_deg": mount_sd,
        "scatter_to_sd": {"mass": m_chi, "com": [c[2] for c in com]},
        "method": "inverse-variance weighted mean of the agreeing logs; sd inflated by sqrt(chi^2/dof) where they "
                  "scatter more than their sd; each log keeps its own tare/offset and contact"}
    return out


def summary_text(p: dict) -> str:
    """One paragraph for a person."""
    parts = [f"{len(p['logs'])} logs of one set-up."]
    q = p.get("pooled")
    if q:
        com = ", ".join(f"{1000 * v:.1f}" for v in q["tool_com_sensor_m"])
        parts.append(f"Pooled over {len(p['agreeing'])} that agree: tool {q['tool_mass_kg']:.4g} ± "
                     f"{q['tool_mass_sd_kg']:.2g} kg, centre of mass [{com}] mm, sensor mount "
                     "[" + ", ".join(f"{v:.2f}" for v in q["sensor_rpy_flange_deg"]) + f"] ± {q['mount_sd_deg']:.2g} deg.")
    else:
        parts.append(p.get("note") or "Too few logs agree to pool.")
    for c in p["contradicting"]:
        extra = f" (mass {c['mass_kg']:.3g} kg, mount {c['mount_angle_from_the_others_deg']:.1f} deg from the others)" \
            if "mass_kg" in c else ""
        parts.append(f"{c['log']} contradicts the others: {c['why']}{extra}; not pooled.")
    return " ".join(parts)


__all__ = ["LogCalibration", "pool", "summary_text"]
