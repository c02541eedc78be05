"""``diagnostics.userfigures``: the residual figure's contact panel when the diagnosis has no contact
rows (the tip check failed, or ``[contact] mode = "exclude"``). It was titled "explained" and left
empty while the warning said the tip moment was 13.3x the free-space residual (HIRO trial 03); it
now draws the contact moment about the declared tip that nothing was fitted to and says why."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import matplotlib.pyplot as plt
import numpy as np
import pytest

from kinadapt_nn.diagnostics import userfigures as uf
from kinadapt_nn.diagnostics.setup import load_setup
from kinadapt_nn.diagnostics.userlog import CHANNELS

HIRO = Path(__file__).resolve().parents[2].parent / "shared" / "realdata" / "hiro_snap_assembly"


def _result(contact_rows: bool, tip_check: dict, n: int = 3000) -> SimpleNamespace:
    """A diagnosis in miniature: contact from the second third on, a 0.3 N m moment about the tip
    there; design rows of the free six channels and, if ``contact_rows``, of the tip three."""
    t = np.arange(n) * 5e-3
    contact = t > t[-1] / 3
    wrench = 0.01 * np.random.default_rng(0).normal(size=(n, 6))
    wrench[contact, 3] += 0.3
    rows = np.arange(0, n, 10)
    chans = list(range(9 if contact_rows else 6))
    ch = np.concatenate([np.full(len(rows), c) for c in chans])
    tr = np.tile(t[rows], len(chans))
    y = 0.01 * np.sin(5 * tr)
    des = SimpleNamespace(y=y, t_s=tr, channel=ch, W=np.ones(len(y)), channel_names=CHANNELS)
    report = {"ranking": [], "model_complete": True, "tip_contact_check": tip_check,
              "contact": {"rows": "left out (tip check failed)" if not tip_check.get("ok", True) else "exclude"}}
    return SimpleNamespace(signals=SimpleNamespace(t=t, wrench=wrench, w_nom=np.zeros_like(wrench)), contact=contact,
                           design=des, before=None, after=None, heldout=0.5 * y, report=report)


def _contact_panel(fig):
    return next(a for a in fig.axes if a.get_title().startswith(("contact: moment about the tip",
                                                                  "contact, moment about the tip")))


def _drawn_points(a) -> int:
    return sum(len(ln.get_xdata()) for ln in a.get_lines() if ln.get_label().startswith("Mtip"))


def test_tip_check_failed_panel_shows_the_contact_moment_and_says_why():
    failed = {"ok": False, "residual_rms_w_free": 10.0, "residual_rms_w_tip_moment": 133.0,
              "message": "in contact the moment about the declared tip is 13.3x the free-space residual: ..."}
    fig = uf._mvm_fig(_result(contact_rows=False, tip_check=failed), load_setup(None))
    a = _contact_panel(fig)
    title = a.get_title()
    assert not title.endswith("explained") and "13.3x" in title and "tip check" in title, title
    assert _drawn_points(a) > 100  # the measured contact moment, not an empty panel
    lo, hi = a.get_ylim()
    assert lo < 0.3 < hi  # the 0.3 N m about the tip is on the axis
    assert "explains the log" not in fig._suptitle.get_text()  # only free space was judged
    fig.canvas.draw()
    box = a.title.get_window_extent(fig.canvas.get_renderer())
    assert box.width <= a.get_window_extent().width, box  # the reason is readable, not cut at the figure's edge
    plt.close(fig)


def test_contact_rows_used_keep_their_verdict_title():
    fig = uf._mvm_fig(_result(contact_rows=True, tip_check={"ok": True}), load_setup(None))
    assert _contact_panel(fig).get_title() == "contact: moment about the tip: explained"
    plt.close(fig)


@pytest.mark.skipif(not (HIRO / "logs").is_dir(), reason="../shared/realdata/hiro_snap_assembly is absent")
def test_hiro_trial_03_without_contact_rows_draws_its_contact(tmp_path):
    from kinadapt_nn.diagnostics import readers
    from kinadapt_nn.diagnostics.userlog import diagnose
    from tests.diagnostics.test_realdata_hiro import SETUP, URDF

    f = tmp_path / "hiro.toml"
    f.write_text(SETUP.format(urdf=URDF.as_posix()) + '[contact]\nmode = "exclude"\n')
    setup = load_setup(f)
    res = diagnose(readers.read_log(HIRO / "logs" / "20160930-HIRO_ERROR-03.csv", setup), setup, hints=False)
    fig = uf._mvm_fig(res, setup)
    a = _contact_panel(fig)
    assert "NOT JUDGED" in a.get_title() and 'mode = "exclude"' in a.get_title(), a.get_title()
    assert _drawn_points(a) > 1000
    plt.close(fig)
