"""A real robot's contact-task recordings (``../shared/realdata/hiro_snap_assembly``: a Kawada HIRO
right arm, 6 joints from a URDF, 200 Hz, tared, ~3 s of free-space approach then ~7 s of contact).

Declared as a user would (URDF, tared, the mount unknown, a guessed 0.4 kg tool, no tip), each
trial must give a plausible calibration whose mass agrees with an independent free-space gravity
fit written here (numpy forward kinematics parsed from the URDF, a least-squares fit; no package
code), and a contact onset within 0.1 s of where the wrench first leaves that independent model.

The logs are public data that the project does not ship: the test skips when the folder is absent
(a user's clone has no ``../shared``).
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

REAL = Path(__file__).resolve().parents[2].parent / "shared" / "realdata" / "hiro_snap_assembly"
URDF = REAL / "hiro_rarm_fixedchest.urdf"
G = 9.81
pytestmark = pytest.mark.skipif(not (REAL / "logs").is_dir(),
                                reason="../shared/realdata/hiro_snap_assembly is absent (public data, not shipped)")

SETUP = """
[log]
time = "t"
q = ["RARM_JOINT0", "RARM_JOINT1", "RARM_JOINT2", "RARM_JOINT3", "RARM_JOINT4", "RARM_JOINT5"]
wrench = ["fx", "fy", "fz", "tx", "ty", "tz"]
tared = true
[sensor]
mount_known = false
[tool]
mass_kg = 0.4
[arm]
urdf = "{urdf}"
"""


def _rpy(r: float, p: float, y: float) -> np.ndarray:
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def _axis_angle(k: np.ndarray, a: float) -> np.ndarray:
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * K @ K


def _chain(urdf: Path) -> list[tuple[np.ndarray, np.ndarray | None]]:
    """The URDF's joints from the root along the chain: (origin rotation (3, 3), axis or None if fixed)."""
    joints = {j.find("parent").get("link"): j for j in ET.parse(urdf).getroot().iter("joint")}
    children = {j.find("child").get("link") for j in joints.values()}
    link = next(p for p in joints if p not in children)
    out = []
    while link in joints:
        j = joints[link]
        o = j.find("origin")
        rpy = [float(v) for v in (o.get("rpy", "0 0 0") if o is not None else "0 0 0").split()]
        ax = j.find("axis")
        axis = None if j.get("type") == "fixed" else np.array([float(v) for v in (ax.get("xyz") if ax is not None
                                                                                    else "1 0 0").split()])
        out.append((_rpy(*rpy), axis))
        link = j.find("child").get("link")
    while out and out[-1][1] is None:  # the flange: the last link a joint moves
        out.pop()
    return out


def _gravity_flange(q: np.ndarray) -> np.ndarray:
    """(n, 3) gravity [m/s^2] in the flange frame, numpy forward kinematics of the URDF."""
    chain = _chain(URDF)
    out = np.empty((len(q), 3))
    for i, qi in enumerate(q):
        R, k = np.eye(3), 0
        for R0, axis in chain:
            R = R @ R0
            if axis is not None:
                R = R @ _axis_angle(axis / np.linalg.norm(axis), qi[k])
                k += 1
        out[i] = R.T @ np.array([0.0, 0.0, -G])
    return out


def independent_fit(path: Path) -> dict:
    """Free space = before the force first exceeds 3 N (less 0.25 s); F = B g_f + f0 by least
    squares; mass = the gravity part's gain |B dg| / |dg| over the samples; the onset = the first
    sample after the span where the force leaves that model by 8x its free residual for 20 ms."""
    d = np.loadtxt(path, delimiter=",", skiprows=1)
    t, q, F = d[:, 0] - d[0, 0], d[:, 1:7], d[:, 7:10]
    k = 5  # 25 ms moving average
    Fs = np.stack([np.convolve(F[:, i], np.ones(k) / k, "same") for i in range(3)], axis=1)
    first = int(np.argmax(np.linalg.norm(Fs, axis=1) > 3.0))
    free = t < t[first] - 0.25
    g = _gravity_flange(q)
    X = np.c_[g, np.ones(len(g))]
    beta, *_ = np.linalg.lstsq(X[free], F[free], rcond=None)
    pred = X @ beta
    dg = g[free] - g[free].mean(0)
    dF = pred[free] - pred[free].mean(0)
    mass = float(np.sqrt(np.sum(dF**2) / np.sum(dg**2)) / 1.0)
    res = np.linalg.norm(Fs - pred, axis=1)
    rms = float(np.sqrt(np.mean(np.linalg.norm(F[free] - pred[free], axis=1) ** 2)))
    out_ = res > 8 * rms
    run = np.convolve(out_.astype(float), np.ones(4), "full")[3:] >= 4  # 4 samples = 20 ms in a row from here
    cand = np.flatnonzero(run & ~free)
    return {"mass_kg": mass, "residual_N": rms, "onset_s": float(t[cand[0]]) if len(cand) else None}


def _diagnose(path: Path, tmp_path: Path) -> dict:
    from kinadapt_nn.diagnostics import readers
    from kinadapt_nn.diagnostics.setup import load_setup
    from kinadapt_nn.diagnostics.userlog import diagnose

    f = tmp_path / "hiro.toml"
    f.write_text(SETUP.format(urdf=URDF.as_posix()))
    setup = load_setup(f)
    return diagnose(readers.read_log(path, setup), setup, hints=False).report


TRIALS = sorted((REAL / "logs").glob("*.csv")) if (REAL / "logs").is_dir() else []


#: trials 02-05 scatter 0.6 N about any free-space gravity model (the others 0.06 N) and touch lightly
#: (~2 N) before the main contact: there the independent 8x-residual onset comes late, and the
#: package may only be earlier than it (trial 03: light touch at 3.16 s, main contact at 3.48 s)
NOISY = {"20160930-HIRO_ERROR-02", "20160930-HIRO_ERROR-03", "20160930-HIRO_ERROR-04", "20160930-HIRO_ERROR-05"}


def _check(path: Path, tmp_path: Path) -> None:
    ind = independent_fit(path)
    rep = _diagnose(path, tmp_path)
    sm = rep["sensor_mount"]
    assert sm["plausible"], sm.get("warning")
    assert 0.3 < ind["mass_kg"] < 0.6 and ind["residual_N"] < 1.0  # the independent fit itself is sane (02-05: ~0.6 N)
    assert abs(sm["tool_mass_kg"] - ind["mass_kg"]) <= max(0.05 * ind["mass_kg"], 3 * sm["tool_mass_sd_kg"]), (
        sm["tool_mass_kg"], sm["tool_mass_sd_kg"], ind)
    onsets = rep["segmentation"]["contact_onsets_s"]
    if path.stem in NOISY:
        assert onsets and onsets[0] <= ind["onset_s"] + 0.1, (onsets, ind)
    else:
        assert onsets and abs(onsets[0] - ind["onset_s"]) <= 0.1, (onsets, ind)
    assert rep["contact"]["windows_s"][0][0] > 1.0  # not "contact from t = 0"
    cp = rep["effective_setup"]["contact_point"]  # where contacts act: estimated with its sd, not assumed
    assert cp is not None and np.all(np.isfinite(cp["sd_m"])) and cp["samples"] > 500
    assert np.linalg.norm(cp["point_sensor_m"]) < 0.3  # on a tool the hand holds
    # the tool (mass and centre of mass) said once: by the calibration or by the ranking, never both
    s = rep["summary"]
    assert s.count("the whole tool") + len(re.findall(r"; tool \d", s)) == 1, s
    # declared right: neither the wrench units nor the time unit is called wrong
    assert not any("torque_unit" in w or "force_unit" in w or "time_scale_s" in w for w in rep["warnings"]), rep["warnings"]


@pytest.mark.parametrize("name", ["20160930-HIRO_ERROR-02", "20160930-HIRO_ERROR-06"])
def test_hiro_trial_calibrates_on_free_space(name, tmp_path):
    _check(REAL / "logs" / f"{name}.csv", tmp_path)


@pytest.mark.slow
@pytest.mark.parametrize("path", TRIALS, ids=[p.stem for p in TRIALS])
def test_every_hiro_trial(path, tmp_path):
    _check(path, tmp_path)


@pytest.mark.slow
def test_all_trials_pooled_name_the_ones_that_do_not_fit(tmp_path):
    """All 16 trials pooled: 02-05 (another mount and mass than the rest by their own calibrations,
    and 0.6 N from any gravity model) are named, the other 12 pooled; the pooled mass lies within
    the independent per-trial fits of those 12."""
    from kinadapt_nn.diagnostics.pooled import pool

    p = pool([(t.stem, _diagnose(t, tmp_path)) for t in TRIALS])
    assert {c["log"] for c in p["contradicting"]} == NOISY
    ind = [independent_fit(t)["mass_kg"] for t in TRIALS if t.stem not in NOISY]
    assert min(ind) <= p["pooled"]["tool_mass_kg"] <= max(ind)


def test_cli_pools_several_logs_and_names_the_odd_one(tmp_path):
    """``kinadapt diagnose LOG1 LOG2 LOG3 --setup``: a folder per log, one pooled diagnosis.json;
    trial 02 (another mount and mass by its own calibration) is named, not averaged in, and with
    only two agreeing logs the pool is theirs."""
    import json
    import subprocess
    import sys

    setup = tmp_path / "hiro.toml"
    setup.write_text(SETUP.format(urdf=URDF.as_posix()))
    logs = [REAL / "logs" / f"20160930-HIRO_ERROR-{k}.csv" for k in ("02", "06", "10")]
    out = tmp_path / "pooled"
    r = subprocess.run([sys.executable, "-m", "kinadapt_nn.app.cli", "diagnose", *map(str, logs), "--setup", str(setup),
                        "--out", str(out), "--quiet"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    rep = json.loads((out / "diagnosis.json").read_text())
    assert rep["kind"] == "pooled_logs" and set(rep["logs"]) == {p.stem for p in logs}
    assert all((out / p.stem / "diagnosis.json").is_file() for p in logs)
    p = rep["pooled"]
    assert [c["log"] for c in p["contradicting"]] == ["20160930-HIRO_ERROR-02"]
    assert sorted(p["agreeing"]) == ["20160930-HIRO_ERROR-06", "20160930-HIRO_ERROR-10"]
    assert 0.40 < p["pooled"]["tool_mass_kg"] < 0.48


def _scaled(name: str, tmp_path: Path, torque: float = 1.0, time: float = 1.0) -> Path:
    """Trial ``name`` with its torque columns times ``torque`` and its time column times ``time``."""
    src = REAL / "logs" / f"{name}.csv"
    d = np.loadtxt(src, delimiter=",", skiprows=1)
    d[:, 0] *= time
    d[:, 10:13] *= torque
    out = tmp_path / f"{name}-t{time:g}-m{torque:g}.csv"
    np.savetxt(out, d, delimiter=",", header=src.read_text().splitlines()[0], comments="", fmt="%.10g")
    return out


def _unit_check(path: Path, tmp_path: Path):
    from kinadapt_nn.diagnostics import readers, signals, units
    from kinadapt_nn.diagnostics.setup import load_setup
    from kinadapt_nn.diagnostics.userlog import RowCfg, calibrate

    f = tmp_path / "hiro.toml"
    f.write_text(SETUP.format(urdf=URDF.as_posix()))
    setup = load_setup(f)
    log = readers.read_log(path, setup)
    cal = calibrate(log, signals.from_log(log, setup), setup, None, RowCfg(), lambda msg: None)
    return units.check(cal.fit, cal.signals, cal.setup, cal.sigma)


def test_torques_in_n_mm_declared_n_m_are_named_on_a_moving_trial(tmp_path):
    """Trial 03 (free space ~0.6 N from any gravity model: the misfit cannot tell a torque unit) with
    its torques x1000 and declared in N m: the tool's weight acts 39 m from the sensor as declared,
    40 mm in N mm -- named; the trial as logged draws no warning (moment arm 40 mm)."""
    name = "20160930-HIRO_ERROR-03"
    wrong = _unit_check(_scaled(name, tmp_path, torque=1000.0), tmp_path)
    assert wrong.message is not None and 'torque_unit = "N mm"' in wrong.message, wrong
    assert wrong.declared.com_m > 10.0 and 0.02 < wrong.likely.com_m < 0.08
    right = _unit_check(REAL / "logs" / f"{name}.csv", tmp_path)
    assert right.message is None and 0.02 < right.declared.com_m < 0.08, right


def test_time_in_ms_declared_as_seconds_is_named(tmp_path):
    """Trial 06 with its time column in ms read as seconds: 0.2 samples per s and joints at
    0.0002 rad/s -- the diagnosis is blocked with the setting that fits."""
    rep = _diagnose(_scaled("20160930-HIRO_ERROR-06", tmp_path, time=1000.0), tmp_path)
    assert rep["blocked"] and "time_scale_s = 0.001" in rep["blocked"], rep["blocked"]
