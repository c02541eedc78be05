"""``kinadapt_nn.figures``: the work cell's learning curve in % -- the unit of the draws figure
(``benchmarks/cell_learning.py``) and of the README, which sit next to it -- not as a fraction."""

from __future__ import annotations

import numpy as np

from kinadapt_nn.figures import cell_learning_figure, plt


def _records(err_by_feature: dict[str, float]) -> list[dict]:
    """compare's per-episode records of a 2-bore cell, one tool per features type: the error a
    fraction (0.01 = 1 %), halving at each of 3 insertions."""
    return [{"tool_family": "nominal", "features": f, "tool": 0, "scenario": "cell",
             "cell": {"jacobian_error_cell_median": (e * 0.5 ** np.arange(4)).tolist(),
                      "bores_w_m": [[0.45, 0.0, 0.3]] * 2, "between": "refit"}}
            for f, e in err_by_feature.items()]


def test_cell_learning_is_drawn_in_percent():
    errs = {"adjoint": 0.01, "rbf": 0.004}
    fig = cell_learning_figure(_records(errs))
    fig.canvas.draw()
    ax = fig.axes[0]
    assert "[%]" in ax.get_ylabel(), ax.get_ylabel()
    medians = {ln.get_label().split()[0]: np.asarray(ln.get_ydata()) for ln in ax.get_lines()
               if "median" in ln.get_label()}
    for f, e in errs.items():  # the drawn values are the fraction x 100
        assert np.allclose(medians[f], 100 * e * 0.5 ** np.arange(4)), (f, medians[f])
    lo, hi = sorted(ax.get_ylim())
    shown = [t.get_text() for t, v in zip(ax.get_yticklabels(), ax.get_yticks()) if t.get_text() and lo <= v <= hi]
    assert shown and max(float(s) for s in shown) >= 0.5, shown  # plain numbers in %: 1 % reads "1", not "10^-2"
    plt.close(fig)
