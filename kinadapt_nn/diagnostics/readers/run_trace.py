"""This package's run log: ``trace.npz`` or its run folder.

Channels ``t_s``, ``q_rad`` and ``qdot_rad_s`` of the seven Panda joints, and ``wrench_raw_f``, the
wrench the flange exerts on the tool (``wrench_acts = "sensor_on_tool"``); the setup's column names
and units are not used, and a trace has no ``[log] extra`` columns.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from kinadapt_nn.diagnostics.readers.base import (Layout, LogReader, UserLog, assemble_columns, sample_label,
                                                  supported)
from kinadapt_nn.errors import KinadaptError

if TYPE_CHECKING:
    from kinadapt_nn.diagnostics.setup import LogCfg


def read(path: Path, log: LogCfg) -> UserLog:
    """A run's trace (module docstring) -> ``UserLog``; one-line ``KinadaptError`` otherwise."""
    from kinadapt_nn.trace import Trace

    if log.extra:
        raise KinadaptError(f"log '{path}' is a kinadapt trace, which has no extra columns; remove [log] extra "
                            f"({', '.join(log.extra)}) from the setup")
    file = path / "trace.npz" if path.is_dir() else path
    try:
        tr = Trace.load(file)
    except KinadaptError as exc:
        raise KinadaptError(f"{exc}; supported formats: {supported()}") from None
    return check_trace(tr, file)


def check_trace(tr, file: Path) -> UserLog:
    """A loaded ``Trace``'s raw channels under the readers' rules (finite, strictly increasing time,
    no gaps, enough samples; one-line ``KinadaptError`` naming ``file``). -> ``UserLog`` (the
    Panda's seven joints, SI as recorded)."""
    t = np.asarray(tr["t_s"])
    n = t.shape[0] if t.ndim == 1 else -1
    parts = []
    for name, width in (("q_rad", 7), ("qdot_rad_s", 7), ("wrench_raw_f", 6)):
        a = np.asarray(tr[name])
        if n < 0 or a.shape != (n, width) or a.dtype.kind not in "iuf" or t.dtype.kind not in "iuf":
            raise KinadaptError(f"trace '{file}': channel '{name}' has shape {a.shape} ({a.dtype}) with 't_s' "
                                f"{t.shape}; expected (N, {width}) numbers for (N,) times (a damaged trace?)")
        parts.append(a.astype(np.float64))
    names = [f"{c}[{j}]" for c, w in (("q_rad", 7), ("qdot_rad_s", 7), ("wrench_raw_f", 6)) for j in range(w)]
    return assemble_columns(file, t.astype(np.float64), 1.0, np.hstack(parts), Layout(names, 7, 7), sample_label,
                            "t_s")


READER = LogReader("trace", "a kinadapt run (trace.npz or its run folder)", "a kinadapt run", read,
                   suffixes=(".npz",), folder_files=("trace.npz",))
