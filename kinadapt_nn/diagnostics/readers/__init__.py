"""Log readers for ``kinadapt diagnose LOG --setup SETUP.toml``: a user's log, whatever its format.

``read_log(path, setup)`` returns a ``UserLog``: time [s] from the first sample, joint positions
[rad] of the ``dof = len(setup.log.q)`` declared joints (and velocities [rad/s] when the log has
them) and the F/T reading in SI units (N, N m: ``log.force_unit``/``log.torque_unit`` converted)
but otherwise *as logged* (the log's own sign convention and sensor frame;
``setup.log.wrench_acts`` says which it is, and ``kinadapt_nn.diagnostics.physical`` converts).
The setup's ``[log]`` section names the columns (``kinadapt_nn.diagnostics.setup.LogCfg``).

One module per format, each a ``LogReader`` (the contract and the registry: ``base.py``), chosen by the path
(``reader_for``: the file's suffix, a folder by the files it holds):

* ``csv_log``: ``*.csv``, ``*.csv.gz``; ``parquet_log``: ``*.parquet``, ``*.pq``;
* ``ros2_bag``: a folder with ``metadata.yaml``, or a ``.mcap`` / ``.db3`` file;
* ``run_trace``: this package's ``trace.npz`` or its run folder.

A static log (``log.static = true``, F/T calibration: each row is a pose at rest) needs no time
column (``log.time = ""``, or left at its default ``"t"`` with no such column: ``UserLog.t_s`` is
None); a time column it has is read (finite, [s] from the earliest row) but need not increase and
may have gaps, as the rows' order carries no meaning. It needs ``MIN_POSES`` rows.

Every format is validated alike (``base.assemble``); each problem is a one-line ``KinadaptError``
naming the file, the row (CSV: the file's line number, header = line 1; otherwise "sample i",
0-based) and the column. An unknown format is a one-line error listing the registered ones
(``SUPPORTED``, derived from the registry).

Adding a format: one module (``examples/readers/json_lines.py`` is a complete one) registered by
one line -- ``register(READER)`` below for a built-in, the same call or the entry-point group
``kinadapt_nn.log_readers`` for another package's.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from kinadapt_nn.diagnostics.readers import csv_log, parquet_log, ros2_bag, run_trace
from kinadapt_nn.diagnostics.readers.base import (ENTRY_POINT_GROUP, GAP_FACTOR, MIN_POSES, MIN_SAMPLES, Layout,
                                                  LogReader, UserLog, assemble, from_table, lookup, reader_for,
                                                  register, registered, supported, unregister)
from kinadapt_nn.diagnostics.readers.run_trace import check_trace
from kinadapt_nn.diagnostics.readers.writer import write_log

if TYPE_CHECKING:
    from kinadapt_nn.diagnostics.setup import SetupCfg

# the built-in formats, in the order messages list them (a folder is tried against each in turn)
register(csv_log.READER)
register(parquet_log.READER)
register(ros2_bag.READER)
register(run_trace.READER)


def log_format(path: Path) -> str:
    """The name of the reader of ``path`` ("csv", "parquet", "bag", "trace" or a registered one's);
    one-line error naming the supported formats otherwise."""
    return reader_for(Path(path)).name


def read_log(path: str | Path, setup: SetupCfg) -> UserLog:
    """Read and validate a user's log (module docstring); one-line ``KinadaptError`` otherwise."""
    path = Path(path)
    return reader_for(path).read(path, setup.log)


def __getattr__(name: str) -> str:
    if name == "SUPPORTED":  # the registered formats, as messages list them (read when asked: plug-ins count)
        return supported()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["ENTRY_POINT_GROUP", "GAP_FACTOR", "MIN_POSES", "MIN_SAMPLES", "SUPPORTED", "Layout", "LogReader",
           "UserLog", "assemble", "check_trace", "from_table", "log_format", "lookup", "read_log", "reader_for",
           "register", "registered", "supported", "unregister", "write_log"]
