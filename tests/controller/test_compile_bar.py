"""The first run's compile line (``core.compiling``) is honest: the time spent and the last
measured compile, never a percentage that reaches 100 % while numba is still compiling."""

from __future__ import annotations

import threading
import time

from kinadapt_nn.controller import core


def test_compile_line_counts_seconds_and_says_when_it_overruns(capsys):
    phase = core.compiling(progress=True)
    phase._t0, phase._stop = time.perf_counter(), threading.Event()
    phase._tick_honestly(expected_s=0.4)
    time.sleep(1.3)  # past the expected 0.4 s: the line must say it is still compiling
    phase._stop.set()
    phase._bar.close()
    err = capsys.readouterr().err
    assert "so far (the last compile here took 0 s" in err and "still compiling" in err
    assert "%" not in err and "of about" not in err
