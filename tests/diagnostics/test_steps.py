"""Progress inside a step (``diagnostics.steps``): the sensor-mount fit's jackknife announces its
first refit before it runs, through the progress callable ``diagnose`` gave; silent outside."""

from __future__ import annotations

import numpy as np

from kinadapt_nn.diagnostics import mount, steps
from tests.diagnostics.test_units import _signals


def test_counted_announces_the_first_item_before_its_work():
    events = []
    with steps.reporting(lambda msg: events.append(("say", msg))):
        for x in steps.counted([1, 2, 3], "refit"):
            events.append(("work", x))
    assert events[:2] == [("say", "refit 1 of 3"), ("work", 1)]
    assert [e for e in events if e[0] == "work"] == [("work", 1), ("work", 2), ("work", 3)]
    assert list(steps.counted([1, 2], "refit")) == [1, 2]  # outside ``reporting``: silent


def test_the_mount_fit_says_where_it_is_before_its_refits(monkeypatch):
    """The calibration's Gauss-Newton from each start, then its jackknife refits (4 iterations, one
    per block left out): a progress line comes before the first of each -- the order, not a clock."""
    s, sigma = _signals(moving=True)
    events = []
    gn = mount._gauss_newton

    def recorded(d, D0, iters=mount.GN_ITERS):
        events.append(("refit", iters))
        return gn(d, D0, iters)

    monkeypatch.setattr(mount, "_gauss_newton", recorded)
    with steps.reporting(lambda msg: events.append(("say", msg))):
        mount.fit(s, np.ones(s.n, bool), np.arange(s.n) % 20, sigma, max_blocks=20)
    said = [i for i, e in enumerate(events) if e[0] == "say"]
    assert said and said[0] == 0 and events[0][1].startswith("sensor mount: rotation, start 1 of")  # before any
    jack = [i for i, e in enumerate(events) if e == ("refit", 4)]
    first = events.index(("say", "sensor mount: its uncertainty, refit without block 1 of 20"))
    assert jack and first < jack[0], events
