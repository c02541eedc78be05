"""The contact-task rig (``examples/contact_rig.py``): a 10 s, 200 Hz, tared UR5e log that is 70 %
contact, with 18 deg of free-space rotation about one axis, the mount unknown, a guessed tool and
no tip declared (issue 38, "your rig's version of the same"). The diagnosis must still calibrate
on the free-space part (mass within 5 %, plausible), find the contact onset within 0.1 s and the
contact point on the tool within 5 mm."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tests.diagnostics.example_scripts import load_example

rig = load_example("contact_rig")


@pytest.fixture(scope="module")
def point_case(tmp_path_factory):
    """(report, truth) of the ``point`` case, diagnosed as a user would (hints off: faster)."""
    from kinadapt_nn.diagnostics import readers
    from kinadapt_nn.diagnostics.setup import load_setup
    from kinadapt_nn.diagnostics.userlog import diagnose

    case = rig.make_case("point", tmp_path_factory.mktemp("contact_rig"), seed=0)
    setup = load_setup(case / "setup.toml")
    report = diagnose(readers.read_log(case / "log.csv", setup), setup, hints=False).report
    return report, json.loads((case / "truth.json").read_text())


def test_rig_log_is_mostly_contact(point_case):
    _, truth = point_case
    assert 0.68 < truth["contact_fraction"] < 0.72 and truth["contact_onset_s"] == pytest.approx(3.0)


def test_point_contact_calibrates_on_free_space(point_case):
    report, truth = point_case
    sm = report["sensor_mount"]
    assert sm["plausible"], sm.get("warning")
    assert abs(sm["tool_mass_kg"] - truth["tool_mass_kg"]) <= 0.05 * truth["tool_mass_kg"], sm["tool_mass_kg"]
    onsets = report["segmentation"]["contact_onsets_s"]
    assert onsets and abs(onsets[0] - truth["contact_onset_s"]) <= 0.1, onsets
    cp = report["effective_setup"]["contact_point"]
    assert cp is not None
    err = np.linalg.norm(np.subtract(cp["point_sensor_m"], truth["contact_point_sensor_m"]))
    assert err <= 0.005, (cp["point_sensor_m"], err)


def test_point_contact_mount_within_its_interval(point_case):
    """The estimated mount agrees with the true one within 3 sd per roll/pitch/yaw angle (a 0.5 deg
    floor), or the angle is named undetermined. (The sd of the rotation's magnitude,
    ``rotation_sd_deg``, is not the test: an error across the rotation axis barely changes the
    magnitude.) Gauss-Newton stopped at 40 iterations 61.7 deg short of the minimum on this log
    before the cap was raised and the weak axis scanned."""
    report, truth = point_case
    sm = report["sensor_mount"]
    d = (np.asarray(sm["rpy_flange_deg"]) - np.asarray(truth["sensor_rpy_flange_deg"]) + 180.0) % 360.0 - 180.0
    named = [u for u in sm["undetermined"] if u["parameter"].startswith("mount rotation")]
    assert named or np.all(np.abs(d) <= np.maximum(3 * np.asarray(sm["sd_deg"]), 0.5)), (d, sm["sd_deg"])


def test_rich_free_motion_before_the_same_face_contact():
    """``flat_face_rich``: a free-space phase that turns the wrist >= 25 deg about world x and world
    y and >= 45 deg about the tool axis, all in free space, then exactly the ``flat_face``
    experiment (same joint motion and contact wrench, delayed by ``T_RICH_S``)."""
    rich, flat = rig.trajectory(rig.CASES["flat_face_rich"]), rig.trajectory(rig.CASES["flat_face"])
    n0 = round(rig.T_RICH_S * rig.RATE_HZ)
    assert np.allclose(rich.q[n0:], flat.q, atol=1e-9) and np.allclose(rich.f_w[n0:], flat.f_w, atol=1e-9)
    assert np.allclose(rich.m_w[n0:], flat.m_w, atol=1e-12) and not rich.normal_n[:n0].any()
    r0 = rich.r_ws[0]
    tilt_w = np.rad2deg([rig.matrix_rotvec(r @ r0.T) for r in rich.r_ws[:n0]])  # (n0, 3) [deg]
    rel_s = np.einsum("ji,njk->nik", r0, rich.r_ws[:n0])  # R_s0^T R_s(t)
    turn = np.rad2deg(np.arctan2(rel_s[:, 1, 0] - rel_s[:, 0, 1], rel_s[:, 0, 0] + rel_s[:, 1, 1]))
    assert np.abs(tilt_w[:, 0]).max() >= 25.0 and np.abs(tilt_w[:, 1]).max() >= 25.0, np.abs(tilt_w).max(0)
    assert np.abs(turn).max() >= 45.0, np.abs(turn).max()
    assert np.abs(rich.qd[0]).max() < 1e-9  # at rest at the tare


def test_hidden_sensor_effects_beside_the_face():
    """The face cases that hide a library effect (issue 51) differ from the effect-free face log only by it:
    the measuring axes' rotation reports ``R^T F``, ``R^T M`` of the same wrench (R from the rotation vector by
    scipy, not the rig's Rodrigues), the drift adds ``rate * t``, the encoder reads joint 4 one degree short;
    the set-up declares the mount known and the truth names the effect in the report's terms."""
    from scipy.spatial.transform import Rotation

    base = rig.case_signals("flat_face_alone_rich", noise=False)
    rot = rig.case_signals("flat_face_rotation", noise=False)
    R = Rotation.from_rotvec(np.deg2rad(rig.AXES_ROTVEC_DEG)).as_matrix()
    w = base["wrench_true"]
    expect = np.hstack([w[:, :3] @ R, w[:, 3:] @ R])  # row-wise R^T w
    assert np.allclose(rot["wrench"], expect - expect[0], atol=1e-12)
    drift = rig.case_signals("flat_face_drift", noise=False)
    t = base["t"] - base["t"][0]
    assert np.allclose(drift["wrench"] - base["wrench"], t[:, None] * np.asarray(rig.DRIFT_PER_S), atol=1e-12)
    enc = rig.case_signals("flat_face_encoder", noise=False)
    dq = base["q"] - enc["q"]
    assert np.allclose(dq[:, 3], np.deg2rad(1.0)) and np.allclose(np.delete(dq, 3, axis=1), 0.0)
    assert "mount_known = true" in rig.setup_toml("flat_face_rotation")
    truth = rig.truth("flat_face_rotation", rot, 0)
    assert truth["effects"]["ft_frame_rotation"] == dict(zip(("rot_x", "rot_y", "rot_z"), rig.AXES_ROTVEC_DEG))
