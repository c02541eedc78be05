"""A flat-faced peg pressed and slid on a flat face (issue 38; ``examples/contact_rig.py``, cases
``flat_face_alone_rich``, ``flat_face_alone`` and ``flat_face_rich``): a 20 x 20 mm box-peg face whose pressure centre
moves with the friction force and whose torsional friction resists the twist -- a moment about the
declared tip of a few hundredths of a N m in contact, not a point contact.

* The effect-free face log (nothing else hidden) is called incomplete, and the hint that explains
  it is ``contact_moment``; with the hint's own effect file passed back (``--effects``, as
  docs/missing_physics.md says) the model is complete.
* A crosstalk hidden beside the face contact (the sensor reports Fx + 0.04 Fz) is estimated within
  10 %, its interval holding the truth, once the face's moment is in the model
  (``examples/effects/face_contact.py``)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from kinadapt_nn.diagnostics.readers import read_log
from kinadapt_nn.diagnostics.setup import load_setup
from kinadapt_nn.diagnostics.userlog import diagnose
from tests.diagnostics.example_scripts import load_example

ROOT = Path(__file__).resolve().parents[2]
EFFECTS = ROOT / "examples" / "effects"
rig = load_example("contact_rig")


def _diag(case_dir: Path, files=(), add=(), hints=True):
    setup = load_setup(case_dir / "setup.toml")
    return diagnose(read_log(case_dir / "log.csv", setup), setup, list(add), effects_files=[str(f) for f in files],
                    hints=hints)


@pytest.fixture(scope="module")
def alone(tmp_path_factory):
    """(case folder, truth, result) of the effect-free face log, diagnosed with hints."""
    d = rig.make_case("flat_face_alone_rich", tmp_path_factory.mktemp("face"), seed=0)
    return d, json.loads((d / "truth.json").read_text()), _diag(d)


def test_the_face_moment_is_what_the_issue_describes(alone):
    """In contact the face's moment about the tip is 0.03-0.06 N m (RMS to peak); nothing else hidden."""
    _, truth, _ = alone
    face = truth["face"]
    assert 0.03 <= face["moment_about_tip_rms_Nm"] and face["moment_about_tip_max_Nm"] <= 0.075, face
    assert "crosstalk" not in truth and face["side_m"] == pytest.approx(0.02)


def test_effect_free_face_log_is_incomplete_and_the_hint_is_contact_moment(alone):
    _, _, res = alone
    rep = res.report
    assert rep["model_complete"] is False
    assert set(rep["unexplained"]["carried_by"]) <= {"Mtip_x", "Mtip_y", "Mtip_z"}, rep["unexplained"]["carried_by"]
    hints = [h["shape"] for h in rep["unexplained"]["hints"]]
    assert hints and hints[0] == "contact_moment", hints
    assert "No shape of the hint dictionary" not in rep["summary"]
    assert "hint_contact_moment.py" in res.hint_files


def test_with_the_contact_moment_hint_file_the_model_is_complete(alone, tmp_path):
    d, _, res = alone
    hint = tmp_path / "hint_contact_moment.py"
    hint.write_text(res.hint_files["hint_contact_moment.py"])
    rep = _diag(d, files=[hint], hints=False).report
    assert rep["model_complete"] is True, rep["unexplained"]["carried_by"]
    verdicts = {e["effect"]: e["verdict"] for e in rep["ranking"]}
    assert verdicts["hint_contact_moment"] == "present", verdicts


def test_weakly_excited_face_log_is_complete_with_the_contact_moment_hint_file(tmp_path):
    """``flat_face_alone``: the same face contact after the weak free motion (18 deg about one axis),
    where the tool's mass and centre of mass cannot be told from a drift. ``contact_moment`` is among
    the hints (``wrench_linear``, which also takes in some of the tool model's error, may explain
    more of the whole residual); its file alone completes the model."""
    d = rig.make_case("flat_face_alone", tmp_path, seed=0)
    res = _diag(d)
    assert res.report["model_complete"] is False
    assert "contact_moment" in [h["shape"] for h in res.report["unexplained"]["hints"]]
    hint = tmp_path / "hint_contact_moment.py"
    hint.write_text(res.hint_files["hint_contact_moment.py"])
    rep = _diag(d, files=[hint], hints=False).report
    assert rep["model_complete"] is True, rep["unexplained"]["carried_by"]


@pytest.fixture(scope="module")
def crosstalk_beside_face(tmp_path_factory):
    """(truth, report) of ``flat_face_rich`` (the sensor mount declared known) with the user's
    crosstalk and face-contact effect files, refitted with the tool model (``--add``)."""
    d = rig.make_case("flat_face_rich", tmp_path_factory.mktemp("face_crosstalk"), seed=0, mount_known=True)
    files = [EFFECTS / "crosstalk_fx_fz.py", EFFECTS / "face_contact.py"]
    res = _diag(d, files=files, add=["tool_gravity", "tool_inertia", "crosstalk_fx_fz", "face_contact"], hints=False)
    return json.loads((d / "truth.json").read_text()), res.report


def test_a_crosstalk_beside_the_face_contact_is_estimated_within_10_percent(crosstalk_beside_face):
    """Found (``present``) and estimated within 10 %, its 95 % interval holding the truth, both in the
    ranking and refitted with the tool model; the face's own parameters come out near the rig's."""
    truth, rep = crosstalk_beside_face
    k = truth["crosstalk"]["fx_from_fz"]
    entry = next(e for e in rep["ranking"] if e["effect"] == "crosstalk_fx_fz")
    for est in (entry["estimate"]["fx_from_fz"], rep["added"]["crosstalk_fx_fz"]["estimate"]["fx_from_fz"]):
        assert abs(est["value"] - k) <= 0.1 * k, est
        assert abs(est["value"] - k) <= 2.0 * est["sd"], est
    assert entry["verdict"] == "present", entry
    assert rep["model_complete"] is True, rep["unexplained"]["carried_by"]
    face = rep["added"]["face_contact"]["estimate"]
    lever = rig.COP_LEAD_M / rig.MU  # [m] the pressure-centre shift per unit of friction/normal force
    assert abs(face["tilt_lever"]["value"] - lever) <= 0.25 * lever, face
    # [m] friction coefficient x the face's effective radius; the file's sticking speed is not the
    # rig's smoothing of the slip, so only the size is checked
    r_t = rig.MU * rig.FACE_RADIUS_M
    assert 0.5 * r_t <= face["torsion_radius"]["value"] <= 1.5 * r_t, face


@pytest.fixture(scope="module")
def crosstalk_face_unmodelled(tmp_path_factory):
    """(truth, report) of ``flat_face_crosstalk_mount_known`` (``flat_face_rich`` with the mount declared)
    diagnosed with the user's crosstalk effect file only: the face's moment about the tip stays unmodelled."""
    d = rig.make_case("flat_face_crosstalk_mount_known", tmp_path_factory.mktemp("face_unmodelled"), seed=0)
    return json.loads((d / "truth.json").read_text()), _diag(d, files=[EFFECTS / "crosstalk_fx_fz.py"],
                                                             hints=False).report


def test_a_user_effect_beside_an_unmodelled_contact_keeps_an_honest_estimate(crosstalk_face_unmodelled):
    """Issue 51: the model stays incomplete (the face), and the user's crosstalk estimate is within 20 % of
    the truth or inside 2 of its own sd; it comes from the rows the final model explains (the tip moments
    that carry the face left out: ``left_rows``), with the change that makes in its sd. On all rows it was
    0.0129 +- 0.011 for 0.04 (68 % and 2.5 sd off, seed 0)."""
    truth, rep = crosstalk_face_unmodelled
    k = truth["crosstalk"]["fx_from_fz"]
    assert rep["model_complete"] is False
    entry = next(e for e in rep["ranking"] if e["effect"] == "crosstalk_fx_fz")
    est = entry["estimate"]["fx_from_fz"]
    assert abs(est["value"] - k) <= 0.2 * k or abs(est["value"] - k) <= 2.0 * est["sd"], est
    left = entry["estimate_params"]
    assert set(left["left_rows"]) == set(rep["unexplained"]["carried_by"]) and left["left_sd"][0] > 0, left


def test_the_tool_beside_an_unmodelled_contact_is_inside_its_interval(crosstalk_face_unmodelled):
    """The tool's first moment (declared 0.5 kg on the axis for 0.62 kg off it: dm c = true - declared) is
    inside 2 of its sd per axis; on all rows its x was 2.8 sd off (0.0063 +- 0.0004 for 0.00744 kg m)."""
    truth, rep = crosstalk_face_unmodelled
    m, c = truth["tool_mass_kg"], truth["tool_com_sensor_m"]
    m_d, c_d = truth["declared"]["tool_mass_kg"], truth["declared"]["tool_com_sensor_m"]
    entry = next(e for e in rep["ranking"] if e["effect"] == "tool_gravity")
    assert entry["verdict"] == "present", entry
    for a, ci, cdi in zip("xyz", c, c_d):
        est = entry["estimate"][f"first_moment_{a}"]
        assert abs(est["value"] - (m * ci - m_d * cdi)) <= 2.0 * est["sd"], (a, est)
