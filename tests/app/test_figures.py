"""Figures: every panel drawn has content and labelled y ticks, y-limits are robust to spikes
(and mark what they clip), and reference lines that do not apply to a program are not drawn."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from kinadapt_nn.config import load_config
from kinadapt_nn.diagnostics import userfigures as uf
from kinadapt_nn.diagnostics.setup import load_setup
from kinadapt_nn.diagnostics.userlog import CHANNELS
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


def _synthetic_result(n: int = 4000, spike_at: int = 2500, add: bool = False) -> SimpleNamespace:
    """A diagnosis ``Result`` in miniature: a reading with one 100x spike on F_y, the declared model
    0.9 of it, contact in the middle third; rows of the nine channels (free six, tip three)."""
    rng = np.random.default_rng(0)
    t = np.arange(n) * 1e-3
    meas = np.column_stack([np.sin(2 * np.pi * f * t) * a for f, a in
                            ((0.5, 1e-3), (1, 5), (2, 3), (1.5, 0.2), (3, 0.3), (0.7, 0.1))])
    meas += 0.05 * rng.normal(size=meas.shape) * np.abs(meas).max(axis=0)
    meas[spike_at, 1] = 100 * np.abs(meas[:, 1]).max()  # one sample, 100x the bulk
    contact = np.zeros(n, bool)
    contact[n // 3: 2 * n // 3] = True
    rows = np.arange(0, n, 10)
    ch = np.concatenate([np.tile(np.arange(6), len(rows)), np.tile(np.arange(6, 9), len(rows))])
    tr = np.concatenate([np.repeat(t[rows], 6), np.repeat(t[rows], 3)])
    y = np.sin(7 * tr) + 0.1 * ch
    y[12] = 1e3  # a spike (row 12: channel F_x)
    des = SimpleNamespace(y=y, t_s=tr, channel=ch, W=np.ones(len(y)), channel_names=CHANNELS)
    rows_ = [{"effect": e, "verdict": v, "explained_fraction": f, "judged": True}
             for e, v, f in (("tool_gravity", "present", 0.9), ("ft_bias_drift", "absent", 3e-4),
                             ("grasp_compliance", "absent", -0.3))]
    report = {"ranking": rows_, "model_complete": True, **({"added": {"tool_gravity": {}}} if add else {})}
    return SimpleNamespace(signals=SimpleNamespace(t=t, wrench=meas, w_nom=0.9 * meas), contact=contact, design=des,
                           before=y if add else None, after=0.1 * y if add else None, heldout=0.5 * y, report=report)


def test_model_vs_measurement_clips_a_spike_keeps_the_bulk_and_has_no_empty_panel(tmp_path):
    import matplotlib.pyplot as plt

    res = _synthetic_result()
    setup = load_setup(None)
    fig = uf._mvm_fig(res, setup)
    _check_panels(fig)
    assert len(_visible(fig)) == 9
    a = next(a for a in fig.axes if a.get_ylabel() == "F_y [N]")
    lo, hi = a.get_ylim()
    r = res.signals.wrench[:, 1]
    assert hi < r.max(), "the 100x spike sets the axis"
    for q in (1, 99):
        p = np.percentile(r, q)
        assert lo <= p <= hi, f"the {q}th percentile of the reading is off the axis"
    assert _clipped_marks(a), "the clipped spike is not marked"
    # a panel without spikes is not clipped: its full range is on the axis, nothing marked
    b = next(a for a in fig.axes if a.get_ylabel() == "F_z [N]")
    assert not _clipped_marks(b)
    lo, hi = b.get_ylim()
    assert lo <= res.signals.wrench[:, 2].min() and hi >= res.signals.wrench[:, 2].max()
    plt.close(fig)
    uf.model_vs_measurement(res, setup, tmp_path / "residual.png")  # the public entry point writes the file
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

    fig = uf._effects_fig(_synthetic_result(add=True))
    _check_panels(fig)
    assert len(_visible(fig)) == 3
    bars = fig.axes[0]
    assert {"+0.900", "+0.000"} <= {x.get_text() for x in bars.texts}  # near-zero bars get their value
    force = fig.axes[1]
    assert force.get_ylim()[1] < 100 and _clipped_marks(force)
    assert {"faint: before", *CHANNELS[:3]} <= set(_legend_texts(force))
    plt.close(fig)


def test_rollout_footer_says_the_summarys_contact_numbers(default_episode):
    """The footer's switching rate is summary.json's ``contact_transitions_per_s`` (one
    computation), not a second count over another signal (it said 0.752 per s, the record 0.488)."""
    import matplotlib.pyplot as plt

    cfg = load_config(None, ["run.progress=false"])
    s = default_episode.summary
    fig = rollout_figure(default_episode.trace, s, cfg)
    footer = fig.texts[-1].get_text().splitlines()[0]
    assert f"{s['contact_transitions_per_s']:.3g} on/off switches per s" in footer, footer
    assert f"{100 * s['contact_fraction']:.0f} % of the time" in footer, footer
    assert footer.count("per s") == 1, footer
    plt.close(fig)


def test_a_static_logs_residual_figure_is_points_against_the_pose_index():
    """A static log (``[log] static``: poses at rest, no clock, rows in the diagnosis's canonical
    order) is drawn against the pose index as points -- not against "time [s]" (its times ran from
    -2000 to 14000 s) with lines joining poses that are neighbours in nothing."""
    import matplotlib.pyplot as plt

    n = 60
    res = _synthetic_result(n=n, spike_at=7)
    rng = np.random.default_rng(1)
    t_file = rng.permutation(np.linspace(-2000.0, 14000.0, n))  # the rows' times, in no order
    res.signals = SimpleNamespace(t=t_file, clock=np.arange(n, dtype=float), static=True, wrench=res.signals.wrench,
                                  w_nom=res.signals.w_nom)
    rows = np.arange(0, n, 10)
    res.design.t_s = np.concatenate([np.repeat(rows, 6), np.repeat(rows, 3)]).astype(float)
    fig = uf._mvm_fig(res, load_setup(None, ["log.static=true", 'log.time=""']))
    for a in _visible(fig):
        assert "pose" in a.get_xlabel() and "time" not in a.get_xlabel(), a.get_xlabel()
        for ln in a.lines:
            if ln.get_label() in ("measured", "declared tool (model)"):
                assert ln.get_linestyle() == "None" and ln.get_marker() not in ("", "None"), ln.get_label()
                x = np.asarray(ln.get_xdata(), dtype=float)
                assert x.min() >= 0 and x.max() <= n - 1
    plt.close(fig)
