"""The summary's identification words (runs/evaluate.py: identification_words) say what theta and
the law's own state did, for every registered law."""

from __future__ import annotations

import numpy as np
import pytest

from kinadapt_nn.config import load_config
from kinadapt_nn.controller.laws import LAWS
from kinadapt_nn.runs.episode import run_episode

QUIET = ["run.progress=false", "run.tensorboard=false", "run.figure=false"]
SOCKET = ["scene.contact_model=socket", "control.dither_rad_s=[0.05,0.05,0.05]"]
NO_CONTACT = ("no contact was sensed", "nothing to learn from")


def _moved(tr) -> float:
    return float(np.linalg.norm(tr["theta"][-1] - tr["theta"][0]))


@pytest.mark.parametrize("law", list(LAWS))
def test_identification_words_agree_with_theta_for_every_law(law):
    """Socket + dither (contact from ~0.4 s): the words never deny the contact; a law without a
    covariance says that theta moved and how far; the kalman law's words match its P."""
    res = run_episode(load_config(None, [*QUIET, *SOCKET, "run.duration_s=1.5", f"adaptation.mode={law}"]))
    tr, ident = res.trace, res.summary["identification"]
    text = ident["text"]
    assert tr["adapt_gate"].any() and ident["contact_steps"] == int(np.sum(tr["adapt_gate"] > 0))
    assert not any(w in text for w in NO_CONTACT), text
    moved = ident["theta_moved"]
    assert moved == pytest.approx(_moved(tr), rel=0.02, abs=1e-12)  # the trace ends one update earlier
    if law == "frozen":
        assert moved == 0.0 and "held fixed" in text
    elif law == "kalman":
        u = tr["theta_uncertainty"]
        assert ident["uncertainty_ratio"] == pytest.approx(u[-1], rel=0.05) and u[-1] < u[0] == 1.0
        k = ident["identified"]
        assert k > 0 and "directions of theta identified" in text and f"theta moved by {moved:.3g} m" in text
    else:
        assert moved > 0.0 and ident["identified"] is None and np.isnan(tr["theta_uncertainty"]).all()
        assert text.startswith(f"theta moved by {moved:.3g} m from its start; {ident['at_omega_bounds']} of 3 "
                               "components at the bounds of Omega")
        assert f"the {law} law has no covariance" in text


def test_composite_words_in_the_bore_say_theta_went_to_the_walls_of_omega():
    """The paper's law in the bore follows the contact bias to Omega's walls: the words say how far
    theta moved and that it sits on the bounds (the old words said nothing of it, or that no
    contact was sensed)."""
    cfg = load_config(None, [*QUIET, "run.duration_s=3.0", "adaptation.mode=composite"])
    res = run_episode(cfg)
    ident, theta = res.summary["identification"], res.trace["theta"][-1]
    l_nom = np.asarray(cfg.sensing.nominal_offset_f_m)
    half = np.array([cfg.adaptation.omega_lateral_m] * 2 + [cfg.adaptation.omega_axial_m])
    at_wall = int(np.sum(np.isclose(np.abs(theta - l_nom), half, rtol=0.0, atol=1e-12)))
    assert at_wall >= 2 and ident["at_omega_bounds"] == at_wall
    assert ident["text"].startswith(f"theta moved by {ident['theta_moved']:.3g} m from its start; {at_wall} of 3 "
                                    "components at the bounds of Omega; the composite law has no covariance")
    assert not any(w in ident["text"] for w in NO_CONTACT)


@pytest.mark.parametrize("law", list(LAWS))
def test_no_contact_is_said_only_without_contact(law):
    res = run_episode(load_config(None, [*QUIET, "run.duration_s=0.3", f"adaptation.mode={law}"]))
    ident = res.summary["identification"]
    assert not res.trace["adapt_gate"].any() and ident["theta_moved"] == 0.0
    assert ("held fixed" in ident["text"]) if law == "frozen" else ("no contact was sensed" in ident["text"])


def test_contact_quality_counts_a_chattering_and_a_continuous_contact():
    """contact_quality against hand counts: a contact that toggles every 5 ms of a 1 kHz log from
    1 s on (100 on/off changes per second after the first touch, longest span 5 ms) and one that
    stays on (0 changes, the whole span)."""
    from kinadapt_nn.runs.evaluate import contact_quality

    i = np.arange(3000)
    t = i * 1e-3
    chat = np.where((i >= 1000) & (((i - 1000) // 5) % 2 == 0), 2.5, 0.0)
    q = contact_quality(t, chat)
    span = t[-1] - 1.0
    n_changes = int(np.count_nonzero(np.diff(chat[t >= 1.0] > 0)))
    assert q["contact_transitions_per_s"] == pytest.approx(n_changes / span) and 190 < n_changes / span < 210
    assert q["longest_contact_span_s"] == pytest.approx(0.005, abs=1e-9) and q["contact_fraction"] == pytest.approx(0.5, abs=0.01)
    q = contact_quality(t, np.where(t >= 0.5, 1.0, 0.0))
    assert q["contact_transitions_per_s"] == 0.0 and q["longest_contact_span_s"] == pytest.approx(2.5, abs=2e-3)
    assert contact_quality(t, np.zeros_like(t))["contact_transitions_per_s"] is None


def test_summary_reports_contact_quality_and_channel_units():
    """The default bore run's summary carries its contact quality (from the truth's contact force)
    and the units of pred_error_rms."""
    from kinadapt_nn.runs.evaluate import contact_quality

    res = run_episode(load_config(None, [*QUIET, "run.duration_s=2.0"]))
    s, tr = res.summary, res.trace
    assert s["contact_transitions_per_s"] == contact_quality(tr["t_s"], tr["truth_contact_force_N"])["contact_transitions_per_s"]
    assert s["pred_error_rms_units"]["F_lat_x"] == "N/s" and s["pred_error_rms_units"]["d"] == "m/s"
