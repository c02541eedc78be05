"""The figure worker: the worker and its fork write the same PNG as ``save_figure`` in this
process, and a part that fails or dies makes ``wait`` raise ``FigureWorkerError`` at once, not hang."""

from __future__ import annotations

import os
import time

import numpy as np
import pytest

from kinadapt_nn.app.figure_worker import FigureWorker, FigureWorkerError, can_fork
from kinadapt_nn.config import load_config
from kinadapt_nn.runs.episode import run_episode

pytestmark = pytest.mark.skipif(not can_fork(), reason="the two-part worker is forked")

QUIET = ["run.progress=false", "run.tensorboard=false", "run.figure=false"]


@pytest.fixture(scope="module")
def short_run():
    cfg = load_config(None, [*QUIET, "run.duration_s=1.5"])
    return cfg, run_episode(cfg)


def _pixels(path) -> np.ndarray:
    """(height, width, 3) int RGB of a PNG."""
    from PIL import Image

    with Image.open(path) as im:
        return np.asarray(im.convert("RGB")).astype(int)


def test_two_parts_write_the_same_png_as_save_figure(short_run, tmp_path):
    from kinadapt_nn.figures import rollout_figure, save_figure

    cfg, res = short_run
    assert (res.summary.get("identification") or {}).get("text"), "no footer: part 0's figure texts go untested"
    worker = FigureWorker.start(fork=True, parts=2)
    try:
        (tmp_path / "worker").mkdir()
        png = tmp_path / "worker" / "rollout.png"
        worker.submit(res.trace, res.summary, cfg, png)
        assert worker.wait(timeout_s=120) == png
    finally:
        worker.close()
    assert [p.name for p in (tmp_path / "worker").iterdir()] == ["rollout.png"], "a temporary file was left"
    save_figure(rollout_figure(res.trace, res.summary, cfg), tmp_path / "here.png")
    a, b = _pixels(png), _pixels(tmp_path / "here.png")
    assert a.shape == b.shape
    diff = np.abs(a - b)
    assert diff.max() <= 3 and diff.mean() < 0.05, f"max {diff.max()}, mean {diff.mean():.4f} (8-bit levels)"


def _fails_fast(worker: FigureWorker, submit: tuple) -> str:
    """Submit, wait; the ``FigureWorkerError`` message (it must come well before the timeout)."""
    t0 = time.monotonic()
    try:
        worker.submit(*submit)
        with pytest.raises(FigureWorkerError) as err:
            worker.wait(timeout_s=90)
    finally:
        worker.close()
    assert time.monotonic() - t0 < 30, "wait() ran into its timeout instead of seeing the failure"
    assert not worker._proc.is_alive(), "close() left the worker running"
    return str(err.value)


def test_a_bad_job_raises_figure_worker_error(short_run, tmp_path):
    cfg, res = short_run
    msg = _fails_fast(FigureWorker.start(fork=True, parts=2), ("not a trace", res.summary, cfg, tmp_path / "r.png"))
    assert "did not finish" not in msg and "TypeError" in msg, msg
    assert not list(tmp_path.iterdir())


def test_a_dead_part_1_raises_figure_worker_error(short_run, tmp_path, monkeypatch):
    """The fork that draws part 1 dies before sending its pixels (the worker, forked from this
    process, inherits the patched module): part 0 sees end-of-file and the parent an error."""
    import kinadapt_nn.app.figure_worker as fw

    draw = fw._draw_part

    def dying(*args, part, link):
        if part == 1:
            os._exit(9)
        return draw(*args, part=part, link=link)

    monkeypatch.setattr(fw, "_draw_part", dying)
    cfg, res = short_run
    msg = _fails_fast(FigureWorker.start(fork=True, parts=2), (res.trace, res.summary, cfg, tmp_path / "r.png"))
    assert "part 1" in msg, msg
    assert not list(tmp_path.iterdir())
