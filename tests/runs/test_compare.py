"""``runs.compare``'s Jacobian-error figure: every features type visible where the curves of two
types coincide (rbf and neural start from the same prior: the rbf curves were drawn in the same
style under the neural ones and did not show)."""

from __future__ import annotations

import matplotlib.colors as mcolors
import numpy as np

from kinadapt_nn.figures import plt
from kinadapt_nn.runs.compare import CompareCfg, _figure


def _results(cfg: CompareCfg) -> list[dict]:
    """Two tools per (family, features type); rbf's curve IS neural's, adjoint's its own."""
    t = np.linspace(0.0, 5.0, 300)
    out = []
    for fam in cfg.families:
        for tool in range(2):
            shared = 0.01 * (1 + 0.3 * tool) * np.exp(-0.2 * t)
            for feat in cfg.features:
                err = 0.02 * (1 + 0.2 * tool) * np.exp(-0.5 * t) if feat == "adjoint" else shared
                out.append({"scenario": "bore", "tool_family": fam, "features": feat, "tool": tool, "t": t.tolist(),
                            "jac_err": err.tolist(), "insertions": None})
    return out


def _raster(fig) -> np.ndarray:
    fig.canvas.draw()
    return np.asarray(fig.canvas.buffer_rgba())[..., :3].astype(int).copy()


def test_every_features_type_shows_where_curves_coincide(tmp_path, monkeypatch):
    cfg = CompareCfg(scenarios={"bore": []})
    figs = []
    monkeypatch.setattr(plt, "close", figs.append)
    _figure(_results(cfg), cfg, tmp_path / "jacobian_error.png")
    fig, = figs
    full = _raster(fig)
    colours = {feat: mcolors.to_hex(f"C{k}") for k, feat in enumerate(cfg.features)}
    styles = set()
    for feat, colour in colours.items():
        lines = [ln for ax in fig.axes for ln in ax.get_lines() if mcolors.to_hex(ln.get_color()) == colour]
        assert lines, feat
        styles.add((str(lines[0].get_linestyle()), lines[0].get_marker()))
        for ln in lines:
            ln.set_visible(False)
        # the pixels this type's curves alone decide: they change clearly when its curves are hidden
        shown = int((np.abs(_raster(fig) - full).max(axis=2) > 90).sum())
        for ln in lines:
            ln.set_visible(True)
        assert shown > 300, (feat, shown)
    assert len(styles) == len(colours), styles  # told apart by style, not only by colour
    plt.close(fig)
