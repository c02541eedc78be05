"""``paper.floor``'s figure: every scenario of the ladder readable -- point labels that overlap no
other label and no point, and a key that names each one (the matched sockets' three points nearly
coincide: their names were printed on top of each other)."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np

from kinadapt_nn.paper.floor import LADDER, floor_figure

#: (b_rms / sigma_min [m], lateral error [m]) of the ladder as ``benchmarks/identification_floor.py`` measured it
MEASURED = [(0.556, 0.0177), (2.10e-4, 0.0207), (2.69e-4, 0.0209), (7.19e-5, 0.0190), (3.08e-5, 0.0167),
            (9.44e-6, 0.00864), (8.42e-7, 4.43e-4), (7.71e-7, 4.16e-4), (7.51e-7, 4.17e-4)]


def _rows() -> list[dict]:
    return [{"scenario": name, "b_over_sigma_m": b, "lateral_error_rms_last_m": e}
            for (name, _), (b, e) in zip(LADDER, MEASURED)]


def test_bias_floor_labels_overlap_nothing_and_the_key_names_every_scenario(tmp_path, monkeypatch):
    figs = []
    monkeypatch.setattr(plt, "close", figs.append)  # keep the figure to measure it
    floor_figure(_rows(), tmp_path / "bias_floor.png")
    assert (tmp_path / "bias_floor.png").stat().st_size > 10_000
    fig, = figs
    ax = fig.axes[0]
    fig.canvas.draw()  # the Agg renderer: text extents as saved
    r = fig.canvas.get_renderer()
    labels = [t for t in ax.texts if t.get_text()]
    assert len(labels) == len(LADDER)
    boxes = [t.get_window_extent(r) for t in labels]
    clash = [(labels[i].get_text(), labels[j].get_text()) for i in range(len(boxes)) for j in range(i + 1, len(boxes))
             if boxes[i].overlaps(boxes[j])]
    assert not clash, clash
    pts = ax.transData.transform(np.array([(1e3 * b, 1e3 * e) for b, e in MEASURED]))
    for t, b in zip(labels, boxes):  # no label covers a point (its own or another's)
        assert not any(b.contains(px, py) for px, py in pts), t.get_text()
        assert ax.get_window_extent(r).contains(b.x0, b.y0) and ax.get_window_extent(r).contains(b.x1, b.y1)
    key = " ".join(t.get_text() for leg in fig.legends for t in leg.get_texts())
    assert all(name in key for name, _ in LADDER), key
    plt.close(fig)
