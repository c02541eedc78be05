"""One short episode for every features type x law: the loop runs, the trace is finite, and each
law does what it claims to the parameters (frozen holds them; the others move them only in
contact, inside Omega's box where the law projects onto it)."""

from __future__ import annotations

import numpy as np
import pytest

from kinadapt_nn.config import load_config
from kinadapt_nn.runs.episode import run_episode

FEATURES = ("adjoint", "rbf", "neural")
LAWS = ("kalman", "composite", "prediction", "tracking", "frozen")


@pytest.mark.parametrize("law", LAWS)
@pytest.mark.parametrize("features", FEATURES)
def test_every_features_type_runs_every_law(features, law):
    cfg = load_config(None, ["run.progress=false", "run.duration_s=2.5", f"run.features={features}",
                             f"adaptation.mode={law}"])
    res = run_episode(cfg)
    tr, s = res.trace, res.summary
    assert s["law"] == law and s["n_params"] == tr["theta"].shape[1]
    for name in ("s", "F_value", "xi", "theta", "q_ref_rad", "w_env_w", "s_dot_pred"):
        assert np.all(np.isfinite(tr[name])), name
    theta = tr["theta"]
    moved = np.any(theta != theta[0], axis=1)
    if law == "frozen":
        assert not moved.any(), "the frozen law changed theta"
        return
    # the free-space rule from the sensor (|f| or |m| above its threshold), computed here independently
    contact = (np.linalg.norm(tr["w_env_w"][:, :3], axis=1) >= cfg.adaptation.contact_force_N) | (
        np.linalg.norm(tr["w_env_w"][:, 3:], axis=1) >= cfg.adaptation.contact_moment_Nm)
    assert contact.any(), "the 2.5 s episode never touched the bore"
    if law == "kalman":  # information is gathered in contact; theta moves only along identified directions
        u = tr["theta_uncertainty"]
        assert u[-1] < u[0], "the kalman law learned nothing in contact"
        assert np.all(u[: int(np.argmax(contact))] == u[0]), "the kalman law learned in free space"
        if not moved.any():
            return
    first = int(np.argmax(moved)) if moved.any() else None
    assert first is not None, f"{law} never adapted theta in contact"
    # theta_k is the estimate *used* at step k: the first change follows a contact step
    assert contact[:first].any(), f"{law} adapted theta before any contact"
    if features == "adjoint" and law != "kalman":  # the paper's laws project onto Omega's box
        l_nom = np.asarray(cfg.sensing.nominal_offset_f_m)
        half = np.array([cfg.adaptation.omega_lateral_m] * 2 + [cfg.adaptation.omega_axial_m])
        assert np.all(np.abs(theta - l_nom) <= half + 1e-12)
