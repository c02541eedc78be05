"""CSV import for ``kinadapt diagnose`` (e.g. a log from a real Panda).

Format (version 1): a header row, then one row per control sample, comma-separated, SI units:

    t_s, q1..q7 [rad], qd1..qd7 [rad/s], fx, fy, fz [N], tx, ty, tz [N m]

``f``/``t`` are the raw wrist F/T reading in the sensor (= flange) frame with kinadapt's sign
convention: the wrench the flange exerts on the tool, about the flange origin O (negate a
sensor that reports the load on the sensor). Extra columns are ignored. A missing column, a
non-number, a non-finite value or a non-increasing time is a one-line error naming it.
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import NamedTuple

import numpy as np

from kinadapt_nn.errors import KinadaptError

class RawLog(NamedTuple):
    """What a real robot logs (the only inputs the diagnosis uses)."""

    t_s: np.ndarray  #: (N,) time [s], strictly increasing
    q_rad: np.ndarray  #: (N, 7) joint positions
    qdot_rad_s: np.ndarray  #: (N, 7) joint velocities
    wrench_raw_f: np.ndarray  #: (N, 6) raw F/T reading: flange on tool, about O, in f [N, N m]
    theta: np.ndarray | None  #: (p,) the run's final parameter estimate, when known
    source: str  #: where it came from



COLUMNS = ["t_s", *[f"q{i}" for i in range(1, 8)], *[f"qd{i}" for i in range(1, 8)], "fx", "fy", "fz", "tx", "ty", "tz"]


def read_csv_log(path: Path):
    path = Path(path)
    try:
        with open(path, newline="") as fh:
            reader = csv.reader(fh)
            header = [h.strip() for h in next(reader)]
            rows = list(reader)
    except (OSError, UnicodeDecodeError, StopIteration) as exc:
        raise KinadaptError(f"CSV log '{path}' could not be read ({type(exc).__name__}); expected a header row "
                            f"with columns {', '.join(COLUMNS)}") from None
    missing = [c for c in COLUMNS if c not in header]
    if missing:
        raise KinadaptError(f"CSV log '{path}' lacks column '{missing[0]}' (needed: {', '.join(COLUMNS)})")
    idx = [header.index(c) for c in COLUMNS]
    data = np.empty((len(rows), len(COLUMNS)))
    for r, row in enumerate(rows):
        for j, (c, k) in enumerate(zip(COLUMNS, idx)):
            try:
                data[r, j] = float(row[k])
            except (IndexError, ValueError):
                raise KinadaptError(f"CSV log '{path}', row {r + 2}: column '{c}' is not a number") from None
    if len(data) < 10:
        raise KinadaptError(f"CSV log '{path}' has {len(data)} rows; at least 10 are needed")
    bad = ~np.isfinite(data)
    if bad.any():
        r, j = np.argwhere(bad)[0]
        raise KinadaptError(f"CSV log '{path}', row {r + 2}: column '{COLUMNS[j]}' is not finite")
    if np.any(np.diff(data[:, 0]) <= 0):
        r = int(np.argmax(np.diff(data[:, 0]) <= 0)) + 3
        raise KinadaptError(f"CSV log '{path}', row {r}: column 't_s' does not increase")
    return RawLog(data[:, 0], data[:, 1:8], data[:, 8:15], data[:, 15:21], None, str(path))


def write_csv_log(path: Path, log) -> None:
    """Export a RawLog in the import format (round trip for tests and for sharing)."""
    from kinadapt_nn.runio import write_text_atomic

    lines = [",".join(COLUMNS)]
    for i in range(len(log.t_s)):
        vals = [log.t_s[i], *log.q_rad[i], *log.qdot_rad_s[i], *log.wrench_raw_f[i]]
        lines.append(",".join(repr(float(v)) for v in vals))
    write_text_atomic(Path(path), "\n".join(lines) + "\n")
