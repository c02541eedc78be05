"""``kinadapt compare``'s figures, drawn from small synthetic results: whole-number insertion ticks,
titles that do not overlap, the insertion a work cell's time panel shows, and at least three
labelled y ticks on every log or linear axis however few decades it spans."""

from __future__ import annotations

import numpy as np
import pytest

from kinadapt_nn.figures import cell_learning_figure, labelled_ticks, plt
from kinadapt_nn.runs.compare import CompareCfg, _figure

FEATURES = ("adjoint", "rbf", "neural")


def _cell_results(n_insertions: int = 3, bores: int = 1, between: str = "refit") -> list[dict]:
    """compare's per-episode records of a work cell: every (family, features, tool)."""
    rng = np.random.default_rng(0)
    out = []
    for fam in ("nominal", "arm_errors"):
        for k, feat in enumerate(FEATURES):
            for tool in range(2):
                err = 0.02 * (0.5 + 0.1 * k) ** np.arange(n_insertions + 1) * rng.uniform(0.9, 1.1)
                out.append({"tool_family": fam, "features": feat, "tool": tool, "scenario": "cell",
                            "cell": {"jacobian_error_cell_median": err.tolist(), "bores_w_m": [[0.45, 0, 0.3]] * bores,
                                     "between": between}})
    return out


def _labelled(axis) -> list[str]:
    """The non-empty tick labels of ``axis`` inside its view (after a draw)."""
    lo, hi = sorted(axis.get_view_interval())
    return [t.get_text() for t, v in zip(axis.get_ticklabels(), axis.get_majorticklocs()) if t.get_text()
            and lo <= v <= hi]


def _texts_overlap(fig, texts) -> list[tuple[str, str]]:
    r = fig.canvas.get_renderer()
    boxes = [(t.get_text(), t.get_window_extent(r)) for t in texts if t.get_text()]
    return [(a, b) for i, (a, ba) in enumerate(boxes) for b, bb in boxes[i + 1:] if ba.overlaps(bb)]


@pytest.mark.parametrize(("bores", "between"), [(1, "carry"), (6, "refit"), (6, "carry")])
def test_cell_learning_ticks_are_whole_insertions_and_titles_apart(bores, between):
    fig = cell_learning_figure(_cell_results(n_insertions=2, bores=bores, between=between))
    fig.canvas.draw()  # the Agg renderer: the text extents are real
    axes = fig.axes
    assert len(axes) == 2
    for ax in axes:
        ticks = [v for v in ax.get_xticks() if ax.get_xlim()[0] <= v <= ax.get_xlim()[1]]
        assert ticks and all(float(v).is_integer() for v in ticks), ticks  # no insertion 0.5
    assert len(_labelled(axes[0].yaxis)) >= 3  # the y axis is shared: labelled on the left panel
    assert not _texts_overlap(fig, [ax.title for ax in axes] + [fig._suptitle])
    sup = fig._suptitle.get_text()
    assert (f"{bores} bores" if bores > 1 else "1 bore,") in sup and "1 bores" not in sup
    plt.close(fig)


def test_jacobian_error_names_the_insertion_and_labels_its_log_axes(tmp_path, monkeypatch):
    cfg = CompareCfg(scenarios={"bore": [], "socket_dither_x3": ["run.insertions=3"]})
    t = np.linspace(0.0, 5.0, 50)
    results = [{"scenario": sc, "tool_family": fam, "features": feat, "tool": 0, "t": t.tolist(),
                "jac_err": (lvl * (1 + 0.3 * np.exp(-t))).tolist(),  # within a factor of 2: one decade or less
                "insertions": [{}, {}, {}] if sc.endswith("x3") else None}
               for sc in cfg.scenarios for fam in cfg.families
               for feat, lvl in zip(cfg.features, (0.012, 0.009, 0.015))]
    figs = []
    monkeypatch.setattr(plt, "close", figs.append)  # keep the figure to look at
    _figure(results, cfg, tmp_path / "jacobian_error.png")
    fig, = figs
    assert (tmp_path / "jacobian_error.png").is_file()
    titles = [ax.get_title() for ax in fig.axes]
    assert titles == ["bore / nominal", "bore / arm_errors", "socket_dither_x3 / nominal: insertion 3 of 3",
                      "socket_dither_x3 / arm_errors: insertion 3 of 3"]
    r = fig.canvas.get_renderer()
    for ax in fig.axes:
        assert len(_labelled(ax.yaxis)) >= 3, ax.get_title()
        assert ax.yaxis.label.get_window_extent(r).x0 >= 0, ax.get_title()  # wider tick labels: y label inside
    plt.close(fig)


@pytest.mark.parametrize(("lo", "hi"), [(0.011, 0.013), (0.009, 0.02), (0.003, 0.08), (1e-4, 0.3), (1e-9, 1e3),
                                        (0.5, 1.5)])
@pytest.mark.parametrize("scale", ["log", "linear"])
def test_labelled_ticks_gives_three_to_seven_labels(lo, hi, scale):
    fig, ax = plt.subplots(figsize=(4, 2.5))
    ax.plot([0, 1], [lo, hi])
    ax.set_yscale(scale)
    labelled_ticks(ax.yaxis)
    fig.canvas.draw()
    labels = _labelled(ax.yaxis)
    assert 3 <= len(labels) <= 7, labels
    assert len(set(labels)) == len(labels)
    plt.close(fig)
