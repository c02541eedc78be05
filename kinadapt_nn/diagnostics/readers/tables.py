"""A table of named columns (Arrow) -> ``UserLog``: the setup's columns picked, typed and validated.

The CSV and Parquet readers read their files into Arrow tables and hand them here; a reader of any
format that yields named columns does the same (``from_table``; ``examples/readers/json_lines.py``).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from kinadapt_nn.diagnostics.readers.base import Label, UserLog, assemble, check_count, clean, layout, list_names
from kinadapt_nn.diagnostics.readers.registry import supported
from kinadapt_nn.errors import KinadaptError

if TYPE_CHECKING:
    import pyarrow as pa

    from kinadapt_nn.diagnostics.setup import LogCfg


def import_pyarrow():
    """``pyarrow``, or a one-line error saying to install it."""
    try:
        import pyarrow as pa
    except ImportError:
        raise KinadaptError("reading CSV/Parquet logs needs the 'pyarrow' package (pip install pyarrow)") from None
    return pa


def _numbers(path: Path, col: pa.ChunkedArray, name: str, label: Label, time: bool = False,
             log: LogCfg | None = None) -> tuple[np.ndarray, float]:
    """One table column as numbers: (values, seconds per unit). Integers stay integers for the
    time column (exact differences of nanosecond stamps); timestamps and durations become
    integers in their own unit."""
    pa = import_pyarrow()
    typ = col.type
    if col.null_count:
        i = int(np.flatnonzero(col.is_null().to_numpy(zero_copy_only=False))[0])
        raise KinadaptError(f"log '{path}', {label(i)}: column '{name}' is empty; fill in a number or remove that row")
    if time and (pa.types.is_timestamp(typ) or pa.types.is_duration(typ)):
        if log is not None and log.time_scale_s != 1.0:
            raise KinadaptError(f"log '{path}': the time column '{name}' is a {typ} column (its unit is known); "
                                "set log.time_scale_s = 1.0")
        per_s = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}[typ.unit]
        return col.cast(pa.int64()).to_numpy(), per_s
    if time and pa.types.is_integer(typ):
        return col.cast(pa.int64()).to_numpy(), 1.0
    if pa.types.is_integer(typ) or pa.types.is_floating(typ) or pa.types.is_decimal(typ):
        return col.cast(pa.float64()).to_numpy(), 1.0
    if pa.types.is_string(typ) or pa.types.is_large_string(typ) or pa.types.is_string_view(typ):
        return _parse_strings(path, col.to_pylist(), name, label), 1.0
    raise KinadaptError(f"log '{path}': column '{name}' holds {clean(typ)} values, not numbers; "
                        "give it plain numbers")


def _parse_strings(path: Path, values: list, name: str, label: Label) -> np.ndarray:
    """A text column's values as float64; the first that is not a number as a one-line error."""
    try:
        return np.array(values, dtype=np.float64)
    except ValueError:
        for i, v in enumerate(values):
            try:
                float(v)
            except ValueError:
                what = "empty" if not v.strip() else f"'{clean(v, 30)}', not a number"
                raise KinadaptError(f"log '{path}', {label(i)}: column '{name}' is {what}; "
                                    "fix or remove that row") from None
        raise KinadaptError(f"log '{path}': column '{name}' is not all numbers; "  # pragma: no cover
                            "fix its values") from None


class Columns(NamedTuple):
    """A file's columns, read in batches: ``batches(names)`` yields tables of those columns, in row order."""

    names: list  #: the file's column names (as stored)
    rows: int
    batches: Callable


def from_table(path: Path, table: pa.Table, log: LogCfg, label: Label, unit: str = "samples") -> UserLog:
    """Pick the setup's columns out of an Arrow ``table`` (one row per sample) and validate them
    (``base.assemble``); ``label(i)`` names row i in messages, ``unit`` what a row is ("data rows")."""
    return from_batches(path, Columns(list(table.column_names), table.num_rows, lambda names: [table.select(names)]),
                        log, label, unit)


def _missing_column(path: Path, header: list[str], fields: list[tuple[str, str]]) -> None:
    """A one-line error for the first setup column the file lacks."""
    for field, c in fields:
        if c not in header:
            hint = ""
            if not any(f[1] in header for f in fields):
                hint = (" (none of the setup's columns is there: is the first line a header? "
                        f"supported formats: {supported()})")
            raise KinadaptError(f"log '{path}' has no column '{c}' (log.{field} in the setup); its columns: "
                                f"{list_names(header)}; fix the name in the setup's [log] section{hint}")


def from_batches(path: Path, src: Columns, log: LogCfg, label: Label, unit: str) -> UserLog:
    """Pick the setup's columns out of a file read in batches (CSV: one; Parquet: row groups) and
    validate them; only the setup's columns are read, each batch straight into the result."""
    from kinadapt_nn.diagnostics.setup import LogCfg

    header = [str(c).strip() for c in src.names]
    if log.static and log.time == LogCfg.model_fields["time"].default and log.time not in header:
        log = log.model_copy(update={"time": ""})  # a static log's time is optional: the default column absent
    fields = ([("time", log.time)] if log.time else []) + [("q", c) for c in log.q] + \
        [("qdot", c) for c in log.qdot] + [("wrench", c) for c in log.wrench] + [("extra", c) for c in log.extra]
    _missing_column(path, header, fields)
    check_count(path, src.rows, unit, log.static)
    raw = {c: src.names[header.index(c)] for _, c in fields}  # the stored name of each
    names = [*log.q, *log.qdot, *log.wrench, *log.extra]
    n = src.rows
    # the final arrays, filled batch by batch (in the log's units): no (N, all columns) table besides them
    q, wrench = np.empty((n, len(log.q))), np.empty((n, 6))
    qdot = np.empty((n, len(log.qdot))) if log.qdot else None
    extra = {c: np.empty(n) for c in log.extra}
    dest = [(c, q, j) for j, c in enumerate(log.q)] + [(c, qdot, j) for j, c in enumerate(log.qdot)] + \
        [(c, wrench, j) for j, c in enumerate(log.wrench)] + [(c, extra[c], None) for c in log.extra]
    times, per_s, a = [], 1.0, 0
    for tab in src.batches(list(dict.fromkeys(raw.values()))):
        m = tab.num_rows
        at = (lambda i, a=a: label(i + a)) if a else label  # noqa: E731  (a row of the file, not of the batch)
        if log.time:  # a static log may have none
            tv, per_s = _numbers(path, tab.column(raw[log.time]), log.time, at, time=True, log=log)
            times.append(tv)
        for c, arr, j in dest:
            v = _numbers(path, tab.column(raw[c]), c, at)[0]
            if j is None:
                arr[a:a + m] = v
            else:
                arr[a:a + m, j] = v
        a += m
    time = (np.concatenate(times) if len(times) > 1 else times[0]) if log.time else None
    return assemble(path, time, per_s * log.time_scale_s, (q, qdot, wrench, extra),
                    layout(log, names, len(log.qdot)), label, log.time)
