"""A package run's log for ``kinadapt diagnose RUN``: its ``trace.npz`` or this package's CSV
(``load_log``), as the ``RawLog`` that ``ownrun.as_log`` turns into a log plus a generated set-up.
A robot's own log (any CSV, Parquet, a ROS 2 bag) is read by ``readers`` against its setup file.

CSV format (version 1): a header row, then one row per control sample, comma-separated, SI units:

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
    source: str  #: where it came from


#: what a robot's own log needs (``kinadapt diagnose`` without ``--setup`` reads only this package's runs)
NEEDS_SETUP = ("pass --setup SETUP.toml (a commented template: kinadapt setup-template --out SETUP.toml; complete "
               "ones in examples/setups/)")

COLUMNS = ["t_s", *[f"q{i}" for i in range(1, 8)], *[f"qd{i}" for i in range(1, 8)], "fx", "fy", "fz", "tx", "ty", "tz"]


def load_log(path: Path) -> RawLog:
    """A run folder, a ``trace.npz`` or this package's CSV; a robot's own log (another CSV, Parquet,
    a ROS 2 bag) is a one-line error saying to pass ``--setup``. A trace obeys the log readers'
    rules (``kinadapt_nn.diagnostics.readers``): finite raw channels, strictly increasing time, no
    gaps, enough samples -- each a one-line ``KinadaptError`` naming the file."""
    from kinadapt_nn.diagnostics import readers
    from kinadapt_nn.trace import Trace

    path = Path(path)
    reader = readers.reader_for(path)  # not found, an unknown suffix: one line naming the formats
    if reader.name == "csv" and path.name.lower().endswith(".csv"):
        try:
            return read_csv_log(path)
        except KinadaptError as exc:
            raise KinadaptError(f"{exc}; for your robot's own CSV log, {NEEDS_SETUP}") from None
    if reader.name != "trace":
        raise KinadaptError(f"log '{path}' is {reader.what}, not a run of this package; for your robot's own log, "
                            f"{NEEDS_SETUP}")
    if path.is_dir():
        path = path / "trace.npz"
    tr = Trace.load(path)
    readers.check_trace(tr, path)  # the same checks as every user log
    return RawLog(tr["t_s"], tr["q_rad"], tr["qdot_rad_s"], tr["wrench_raw_f"], str(path))


def read_csv_log(path: Path) -> RawLog:
    """This package's CSV (module docstring) -> ``RawLog``; one-line errors naming the row and column."""
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
    return RawLog(data[:, 0], data[:, 1:8], data[:, 8:15], data[:, 15:21], str(path))


def write_csv_log(path: Path, log) -> None:
    """Export a RawLog in the import format (round trip for tests and for sharing)."""
    from kinadapt_nn.runio import write_text_atomic

    lines = [",".join(COLUMNS)]
    for i in range(len(log.t_s)):
        vals = [log.t_s[i], *log.q_rad[i], *log.qdot_rad_s[i], *log.wrench_raw_f[i]]
        lines.append(",".join(repr(float(v)) for v in vals))
    write_text_atomic(Path(path), "\n".join(lines) + "\n")
