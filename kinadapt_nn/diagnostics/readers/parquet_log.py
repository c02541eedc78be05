"""Parquet logs (``*.parquet``, ``*.pq``): one column per name.

Read in batches of ``PARQUET_BATCH_ROWS`` rows, only the setup's columns. A timestamp/duration time
column is converted to seconds by its own unit (``log.time_scale_s`` must then be 1). Rows are
named "sample i" (0-based) in messages.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from kinadapt_nn.diagnostics.readers.base import (Columns, LogReader, UserLog, first_line, from_batches,
                                                  import_pyarrow, sample_label, unreadable)

if TYPE_CHECKING:
    from kinadapt_nn.diagnostics.setup import LogCfg

PARQUET_BATCH_ROWS = 65_536  # a Parquet log is read this many rows at a time (only the setup's columns)
PARQUET_BUFFER_BYTES = 1 << 20  # [B] read buffer of a Parquet file's column chunks


def read(path: Path, log: LogCfg) -> UserLog:
    """A Parquet log (module docstring) -> ``UserLog``; one-line ``KinadaptError`` otherwise."""
    pa = import_pyarrow()
    import pyarrow.parquet as pq

    try:
        # read as it is decoded: without pre-buffering, pyarrow reads every column chunk of the file
        # into memory first (measured on an hour at 1 kHz, 300 row groups: 323 MB of Arrow memory
        # against 22 MB streamed)
        pf = pq.ParquetFile(path, pre_buffer=False, buffer_size=PARQUET_BUFFER_BYTES)
        src = Columns(list(pf.schema_arrow.names), pf.metadata.num_rows, lambda names: (
            pa.Table.from_batches([b]) for b in pf.iter_batches(batch_size=PARQUET_BATCH_ROWS, columns=names)))
        return from_batches(path, src, log, sample_label, "samples")
    except (pa.ArrowException, OSError, EOFError, ValueError) as exc:
        raise unreadable(path, "Parquet file", first_line(exc)) from None
    finally:
        pa.default_memory_pool().release_unused()  # the decoded batches' memory back to the system


READER = LogReader("parquet", "Parquet (.parquet, .pq)", "a Parquet log", read, suffixes=(".parquet", ".pq"))
