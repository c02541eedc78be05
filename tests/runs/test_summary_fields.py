"""summary.json fields a newcomer reads (issue 40, section 2): each checked against an independent
computation from the run's own trace, and the one-time compile kept out of the wall time."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from kinadapt_nn.app.online import summary_lines
from kinadapt_nn.config import load_config
from kinadapt_nn.controller import core
from kinadapt_nn.runs import episode as episode_mod
from kinadapt_nn.runs.episode import run_episode
from kinadapt_nn.sensing import channel_metric

QUIET = ["run.progress=false", "run.tensorboard=false", "run.figure=false"]


@pytest.fixture(scope="module")
def bore_run():
    """The default bore run, 3 s (contact from ~1.2 s), with the law's regressor rows."""
    return run_episode(load_config(None, [*QUIET, "run.duration_s=3.0"]), keep_regressor=True)


def test_pred_error_rms_is_the_rate_error_per_channel_with_its_units(bore_run):
    """``pred_error_rms``: RMS of s_dot_meas - s_dot_pred over the driven steps, in the units of
    ``pred_error_rms_units`` (the rate of each channel of s: m/s, N/s, N m/s)."""
    tr, s = bore_run.trace, bore_run.summary
    on = tr["drive_scale"] > 0
    eps = tr["s_dot_meas"][on] - tr["s_dot_pred"][on]
    names = tr.meta["channel_names"]
    want = np.sqrt(np.mean(eps**2, axis=0))
    np.testing.assert_allclose([s["pred_error_rms"][n] for n in names], want, rtol=1e-12)
    assert [s["pred_error_rms_units"][n] for n in names] == ["m/s", "N/s", "N/s", "N m/s", "N m/s", "N m/s"]


def test_theta_sd_data_only_is_the_least_squares_sd_of_the_contact_data(bore_run):
    """``theta_sd_data_only`` = sqrt(diag(sigma^2 H^-1 (1 + rho1)/(1 - rho1))) with H the summed
    Gram of W Phi_f over the steps where the law adapts, recomputed from the logged regressor rows
    and residuals; it is the data alone (no prior), unlike the law's ``theta_sd_final``."""
    tr, s = bore_run.trace, bore_run.summary
    gate = tr["adapt_gate"] > 0
    W = np.asarray(channel_metric(load_config(None, QUIET).sensing), dtype=float)  # (m,) the controller's W
    A = tr["law_Phi_fT"][gate] * W[None, None, :]  # (N, p, m): (W Phi_f)^T per step
    H = np.einsum("kim,kjm->ij", A, A)
    eps = tr["eps_w"][gate]
    e = eps - eps.mean(axis=0)
    rho1 = min(max(float(np.sum(e[1:] * e[:-1]) / np.sum(e[:-1] ** 2)), 0.0), 0.999)
    cov = np.mean(eps**2) * np.linalg.inv(H) * (1 + rho1) / (1 - rho1)
    np.testing.assert_allclose(s["theta_sd_data_only"], np.sqrt(np.diag(cov)), rtol=1e-6)
    assert s["residual_lag1_autocorr"] == pytest.approx(rho1, rel=1e-9)
    assert "offset_uncertainty_m" not in s


def test_wall_time_excludes_the_one_time_compile(monkeypatch):
    """A compile phase of 0.6 s (standing in for numba's, which a warm cache skips) is reported as
    ``compile_time_s`` and kept out of ``wall_time_s``; the printed line names both."""
    class SlowCold(core.compiling):
        def __enter__(self):
            super().__enter__()
            self._cold = True
            time.sleep(0.6)
            return self

    monkeypatch.setattr(episode_mod.core, "compiling", SlowCold)
    t0 = time.perf_counter()
    res = run_episode(load_config(None, [*QUIET, "run.duration_s=0.3"]))
    total = time.perf_counter() - t0
    s = res.summary
    assert s["compile_time_s"] >= 0.6
    assert s["wall_time_s"] + s["compile_time_s"] <= total + 1e-6
    assert s["wall_time_s"] < total - 0.6
    line = next(ln for ln in summary_lines(s, Path("out")) if ln.startswith("  sim "))
    assert f"{s['wall_time_s']:.2f} s wall" in line and f"one-time compile before it {s['compile_time_s']:.1f} s" in line


def test_excitation_run_prints_no_paper_seat_time(bore_run):
    """An excitation run has no seat time to compare: its line names the program, not the paper's 5.1 s."""
    insert = summary_lines(bore_run.summary, Path("out"))
    excite = summary_lines(dict(bore_run.summary, program="excite", seat_time_s=None), Path("out"))
    assert any("paper, with adaptation: 5.1 s" in ln for ln in insert)
    assert not any("paper" in ln for ln in excite)
    assert any("it does not insert" in ln for ln in excite)
