"""Figures: every panel drawn has content and labelled y ticks, y-limits are robust to spikes
(and mark what they clip), and reference lines that do not apply to a program are not drawn."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from kinadapt_nn.config import load_config
from kinadapt_nn.diagnostics import library as lib
from kinadapt_nn.diagnostics import report
from kinadapt_nn.diagnostics.residual import PHASES, Replay
from kinadapt_nn.figures import (
    ROLLOUT_SIZE_IN,
    SAVE_DPI,
    decimate,
    envelope,
    pixel_columns,
    robust_limits,
    rollout_figure,
    save_figure,
    sliding_mean,
)
from kinadapt_nn.runs.episode import run_episode

ROOT = Path(__file__).resolve().parents[2]
QUIET = ["run.progress=false", "run.tensorboard=false", "run.figure=false"]


def _visible(fig):
    return [a for a in fig.axes if a.get_visible() and a.axison]


def _check_panels(fig) -> None:
    """No empty panel, and every panel has non-empty y tick labels."""
    fig.canvas.draw()
    for a in _visible(fig):
        name = a.get_title() or a.get_ylabel()
        assert a.lines or a.patches or a.collections, f"empty panel '{name}'"
        labels = [t.get_text() for t in a.get_yticklabels() if t.get_visible()]
        assert any(labels), f"panel '{name}' has no y tick labels"


def _legend_texts(a) -> list[str]:
    leg = a.get_legend()
    return [t.get_text() for t in leg.get_texts()] if leg else []


def _clipped_marks(a) -> list:
    return [ln for ln in a.lines if ln.get_label().startswith("clipped")]


@pytest.fixture(scope="module")
def insert_run():
    cfg = load_config(None, [*QUIET, "run.duration_s=1.5"])
    return cfg, run_episode(cfg)


@pytest.fixture(scope="module")
def excite_run():
    cfg = load_config(ROOT / "online" / "excite.toml", [*QUIET, "run.duration_s=1.5"])
    return cfg, run_episode(cfg)


def test_rollout_insert_every_panel_filled_and_ticked(insert_run):
    import matplotlib.pyplot as plt

    cfg, res = insert_run
    fig = rollout_figure(res.trace, res.summary, cfg)
    assert len(_visible(fig)) == 9
    _check_panels(fig)
    depth = next(a for a in fig.axes if a.get_title() == "insertion depth")
    assert any("target 45 mm" in s for s in _legend_texts(depth))
    success = next(a for a in fig.axes if a.get_title().startswith("success channels"))
    lanes = {"sensed contact: 0 %", "depth_ok: 0 %", "force_ok: 0 %", "moment_ok: 0 %"}
    assert lanes <= {t.get_text() for t in success.get_yticklabels()}
    plt.close(fig)


def test_rollout_excite_draws_no_seat_target_or_limits(excite_run):
    import matplotlib.pyplot as plt

    cfg, res = excite_run
    fig = rollout_figure(res.trace, res.summary, cfg)
    assert len(_visible(fig)) == 9
    _check_panels(fig)
    texts = [s for a in fig.axes for s in _legend_texts(a)] + [a.get_title() for a in fig.axes]
    assert not [s for s in texts if "target 45" in s or "seat limit" in s or s.startswith("success channels")]
    depth = fig.axes[0]
    y45 = 1e3 * cfg.success.depth_m
    assert not [ln for ln in depth.lines if np.allclose(ln.get_ydata(), y45)], "a 45 mm line on an excite run"
    # theta is held fixed (adaptation.mode = "frozen"): the bottom row is the prediction error, not identification
    assert not [a for a in fig.axes if a.get_title() == "identification"]
    assert [a for a in fig.axes if a.get_title().startswith("prediction error")]
    plt.close(fig)


def test_rollout_png_is_written_in_process_and_is_a_valid_png(insert_run, tmp_path):
    from PIL import Image

    cfg, res = insert_run
    png = tmp_path / "rollout.png"
    save_figure(rollout_figure(res.trace, res.summary, cfg), png)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with Image.open(png) as im:
        im.verify()  # (the chunks' CRCs and the image data's end)
    with Image.open(png) as im:
        assert im.format == "PNG"
        assert im.size == tuple(round(v * SAVE_DPI) for v in ROLLOUT_SIZE_IN)
        im.load()  # decodes to the end
    assert list(tmp_path.iterdir()) == [png]


def test_decimation_keeps_the_min_and_max_of_a_series():
    rng = np.random.default_rng(1)
    n = 100_000
    x = np.linspace(0.0, 5.0, n)
    y = rng.normal(size=n)
    y[12_345], y[77_777] = 40.0, -35.0  # one-sample spikes, far beyond the bulk
    y[50_000:50_010] = np.nan  # a gap
    env = envelope(x, y, 400)
    assert len(env.x) <= 400
    assert np.nanmax(env.hi) == 40.0 and np.nanmin(env.lo) == -35.0
    assert np.all(env.lo[np.isfinite(env.lo)] <= env.hi[np.isfinite(env.lo)])
    # each column's range holds every sample of the column
    col = np.minimum((x / 5.0 * 400).astype(int), 399)
    for c in (0, 123, 399):
        m = col == c
        assert env.lo[c] == np.nanmin(y[m]) and env.hi[c] == np.nanmax(y[m])
    xd, yd = decimate(x, y, 800)
    assert len(xd) <= 800 + 10 + 2  # (+ the NaN samples, kept as a gap, and both ends)
    assert np.nanmax(yd) == 40.0 and np.nanmin(yd) == -35.0
    assert xd[0] == x[0] and xd[-1] == x[-1] and np.isnan(yd).any()


def test_contact_at_200_switches_per_s_is_a_fraction_not_a_barcode(insert_run):
    """A contact that chatters (5 ms on, 5 ms off) reads as ~50 % in a 50 ms window; the rollout
    figure's lanes draw no more points than the panel has pixel columns (x2: min and max)."""
    import matplotlib.pyplot as plt

    gate = (np.arange(4000) // 5) % 2 == 0  # 1 kHz samples: 200 switches per s
    frac = sliding_mean(gate, 50)
    assert np.all(np.abs(frac[25:-25] - 0.5) <= 0.1)
    assert sliding_mean(np.ones(10, bool), 50).tolist() == [1.0] * 10

    cfg, res = insert_run
    fig = rollout_figure(res.trace, res.summary, cfg)
    lanes = next(a for a in fig.axes if a.get_title().startswith("success channels"))
    assert lanes.lines and all(len(ln.get_xdata()) <= 2 * pixel_columns(lanes) + 2 for ln in lanes.lines)
    assert len(lanes.collections) == 4  # one filled trace per lane, not one patch per contact span
    plt.close(fig)


def _synthetic_replay(n: int = 4000, spike_at: int = 2500) -> Replay:
    rng = np.random.default_rng(0)
    t = np.arange(n) * 1e-3
    meas = np.column_stack([np.sin(2 * np.pi * f * t) * a for f, a in
                            ((0.5, 1e-3), (1, 5), (2, 3), (1.5, 0.2), (3, 0.3), (0.7, 0.1))])
    meas += 0.05 * rng.normal(size=meas.shape) * np.abs(meas).max(axis=0)
    pred = 0.9 * meas
    resid = meas - pred
    resid[spike_at, 1] = 100 * np.abs(resid[:, 1]).max()  # one sample, 100x the bulk
    phase = np.zeros(n, int)
    phase[n // 3: 2 * n // 3] = PHASES.index("entry")
    return Replay(t_s=t, s=np.column_stack([np.linspace(-0.01, 0.02, n), meas[:, 1:]]), w_env=meas,
                  s_dot_meas=meas, s_dot_pred=pred, residual=resid, contact=phase > 0, phase=phase,
                  qdot_norm=np.abs(np.sin(t)), active=np.ones(n, bool))


def test_residual_figure_clips_a_spike_keeps_the_bulk_and_has_no_empty_panel(tmp_path):
    import matplotlib.pyplot as plt

    rep = _synthetic_replay()
    fig = report._residual_fig(rep)
    _check_panels(fig)
    assert len(_visible(fig)) == 12
    a = next(a for a in fig.axes if a.get_ylabel().startswith("d/dt F_lat_x"))
    lo, hi = a.get_ylim()
    r = rep.residual[:, 1]
    assert hi < r.max(), "the 100x spike sets the axis"
    for q in (1, 99):
        p = np.percentile(r, q)
        assert lo <= p <= hi, f"the {q}th percentile of the residual is off the axis"
    assert _clipped_marks(a), "the clipped spike is not marked"
    # a panel without spikes is not clipped: its full range is on the axis, nothing marked
    b = next(a for a in fig.axes if a.get_ylabel().startswith("d/dt F_lat_y"))
    assert not _clipped_marks(b)
    lo, hi = b.get_ylim()
    assert lo <= min(rep.s_dot_meas[:, 2].min(), rep.residual[:, 2].min())
    assert hi >= rep.s_dot_meas[:, 2].max()
    # the phase colour key: every phase present is in the last panel's legend
    assert {"free_space", "entry"} <= set(_legend_texts(fig.axes[-1]))
    plt.close(fig)
    report.residual_figure(rep, tmp_path / "residual.png")  # the public entry point still writes the file
    assert (tmp_path / "residual.png").stat().st_size > 20_000


def test_robust_limits_cut_spikes_only():
    t = np.linspace(0, 10, 5000)
    sine = np.sin(t)
    lo, hi = robust_limits([sine])
    assert lo < -1 and hi > 1  # nothing of a smooth signal is cut
    spiky = sine.copy()
    spiky[[100, 2000, 4000]] = [-300, 250, 400]
    lo, hi = robust_limits([spiky])
    assert -2 < lo < -1 and 1 < hi < 2
    assert robust_limits([np.full(10, np.nan)]) is None
    lo, hi = robust_limits([np.zeros(50)])
    assert lo < 0 < hi


def test_effects_figure_bars_readable_and_before_after_panels_filled():
    import matplotlib.pyplot as plt

    from kinadapt_nn.features.effect_library import LEVEL_CHANNELS

    rows = [{"effect": n, "verdict": v, "significant": s, "explained_fraction": f, "explained_fraction_alone": f}
            for n, v, s, f in (("tool_gravity", "present", True, 0.9), ("ft_bias_drift", "absent", False, -3e-4),
                               ("grasp_compliance", "absent", False, -0.3))]
    n = 600
    t = np.repeat(np.arange(n // 6) * 5e-3, 6)
    t[t > 0.2] += 1.0  # a gap in the rows
    ch = np.tile(np.arange(6), n // 6)
    y = np.sin(7 * t) + 0.1 * ch
    y[12] = 1e3  # a spike (row 12: channel F_lat_x)
    des = SimpleNamespace(t_s=t, channel=ch, W=np.ones(n))
    fig = lib._effects_fig({"ranking": rows, "added": {"tool_gravity": {}}, "_series": (des, y, 0.1 * y)})
    _check_panels(fig)
    assert len(_visible(fig)) == 3
    bars = fig.axes[0]
    assert bars.get_xlim()[0] < -0.3  # a bar below -0.1 is not cut off
    assert {"+0.900", "+0.000", "-0.300"} <= {x.get_text() for x in bars.texts}  # near-zero bars get their value
    force = fig.axes[1]
    assert force.get_ylim()[1] < 100 and _clipped_marks(force)
    assert {"faint: before", *LEVEL_CHANNELS[:3]} <= set(_legend_texts(force))
    plt.close(fig)
