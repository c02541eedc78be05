"""Progress inside one step of a diagnosis, without every function between carrying a callable.

``diagnose`` makes its ``progress(msg)`` the current one for a step (``reporting``); a long loop
deep inside that step -- the sensor-mount fit's Gauss-Newton from each start (the mirror branch's
nine) and its jackknife, which took 9-40 s of a pooled run's log with no word -- announces its
items through ``counted``: the first at once, then at most one line every ``INTERVAL_S``. A context variable: nothing is set at import, and a thread or a
second diagnosis has its own; outside ``reporting`` the loop runs silent.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from contextvars import ContextVar
from typing import TypeVar

INTERVAL_S = 1.0  #: [s] at most one progress line this often within a loop (the first at once)

T = TypeVar("T")
_PROGRESS: ContextVar[Callable[[str], None] | None] = ContextVar("kinadapt_diagnosis_progress", default=None)


@contextmanager
def reporting(progress: Callable[[str], None] | None) -> Iterator[None]:
    """``progress`` is the current progress callable within the ``with`` block."""
    token = _PROGRESS.set(progress)
    try:
        yield
    finally:
        _PROGRESS.reset(token)


def counted(items: Sequence[T], what: str) -> Iterator[T]:
    """``items`` one by one, announced as "``what`` i of n" through the current progress before
    the item's work: the first at once, then at most one line every ``INTERVAL_S``."""
    say = _PROGRESS.get()
    last = -math.inf
    for i, x in enumerate(items):
        now = time.perf_counter()
        if say is not None and (i == 0 or now - last >= INTERVAL_S):
            say(f"{what} {i + 1} of {len(items)}")
            last = now
        yield x


__all__ = ["INTERVAL_S", "counted", "reporting"]
