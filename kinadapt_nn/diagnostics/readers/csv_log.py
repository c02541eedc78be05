"""CSV logs (``*.csv``, ``*.csv.gz``): a header row with the column names, one row per sample.

Extra columns are ignored; the delimiter (``,``, ``;`` or tab) is taken from the header line. Rows
are named by the file's line number in messages (header = line 1).
"""

from __future__ import annotations

import csv
import gzip
import io
from pathlib import Path
from typing import TYPE_CHECKING

from kinadapt_nn.diagnostics.readers.base import (LogReader, UserLog, first_line, from_table, import_pyarrow,
                                                  unreadable)
from kinadapt_nn.errors import KinadaptError

if TYPE_CHECKING:
    from kinadapt_nn.diagnostics.setup import LogCfg


def _open_text(path: Path):
    raw = gzip.open(path, "rb") if path.name.lower().endswith(".gz") else open(path, "rb")
    return io.TextIOWrapper(raw, encoding="utf-8-sig", errors="replace", newline="")


def _sniff_delimiter(path: Path) -> str:
    """The delimiter of the header line: the most frequent of ',', ';' and tab (',' on a tie)."""
    try:
        with _open_text(path) as fh:
            line = fh.readline(1 << 16)
    except (OSError, EOFError, UnicodeError):
        return ","
    counts = {d: line.count(d) for d in (",", ";", "\t")}
    best = max(counts, key=lambda d: counts[d])
    return best if counts[best] > counts[","] else ","


def _csv_records(path: Path, delimiter: str):
    """(line number, fields) of the header and each data row, blank lines skipped (as pyarrow does)."""
    with _open_text(path) as fh:
        reader = csv.reader(fh, delimiter=delimiter)
        for rec in reader:
            if rec:
                yield reader.line_num, rec


def _csv_line(path: Path, delimiter: str, row: int) -> int:
    """The file line (header = 1) of data row ``row`` (0-based); only on the error path."""
    try:
        for k, (line, _) in enumerate(_csv_records(path, delimiter)):
            if k == row + 1:
                return line
    except (OSError, EOFError, csv.Error):
        pass
    return row + 2


def _csv_bad_row(path: Path, delimiter: str) -> str | None:
    """Why the CSV does not parse, if a row has the wrong number of fields (error path only)."""
    try:
        n_header = None
        for line, rec in _csv_records(path, delimiter):
            if n_header is None:
                n_header = len(rec)
            elif len(rec) != n_header:
                return f"line {line} has {len(rec)} fields, the header has {n_header}"
    except (OSError, EOFError, csv.Error) as exc:
        return first_line(exc)
    return None


def read(path: Path, log: LogCfg) -> UserLog:
    """A CSV log (module docstring) -> ``UserLog``; one-line ``KinadaptError`` otherwise."""
    pa = import_pyarrow()
    try:
        return _read(path, log)
    finally:  # the parsed table's Arrow memory back to the system (its pool keeps freed memory)
        pa.default_memory_pool().release_unused()


def _read(path: Path, log: LogCfg) -> UserLog:
    import pyarrow as pa
    import pyarrow.csv as pacsv

    delimiter = _sniff_delimiter(path)
    try:
        table = pacsv.read_csv(
            path,
            parse_options=pacsv.ParseOptions(delimiter=delimiter),
            # no null markers: an empty cell or "N/A" is reported by row, "nan" parses as NaN
            convert_options=pacsv.ConvertOptions(null_values=[], strings_can_be_null=False,
                                                 quoted_strings_can_be_null=False),
        )
    except (pa.ArrowException, OSError, EOFError, UnicodeError, ValueError) as exc:
        if "empty" in str(exc).lower():
            raise KinadaptError(f"log '{path}' is empty (no header row); write a header row with the column "
                                "names, then one row per sample") from None
        raise unreadable(path, "CSV file", _csv_bad_row(path, delimiter) or first_line(exc)) from None
    return from_table(path, table, log, lambda i: f"line {_csv_line(path, delimiter, i)}", "data rows")


READER = LogReader("csv", "CSV (.csv, .csv.gz)", "a CSV log", read, suffixes=(".csv", ".csv.gz"))
