"""Log readers for ``kinadapt diagnose LOG --setup SETUP.toml``: a user's log, whatever its format.

``read_log(path, setup)`` returns a ``UserLog``: time [s] from the first sample, joint positions
[rad] of the ``dof = len(setup.log.q)`` declared joints (and velocities [rad/s] when the log has
them) and the F/T reading in SI units (N, N m: ``log.force_unit``/``log.torque_unit`` converted)
but otherwise *as logged* (the log's own sign convention and sensor frame;
``setup.log.wrench_acts`` says which it is, and ``kinadapt_nn.diagnostics.physical`` converts).
The setup's ``[log]`` section names the columns (``kinadapt_nn.diagnostics.setup.LogCfg``).
Formats, chosen by the path:

* ``*.csv``, ``*.csv.gz``: a header row with the column names, one row per sample; extra columns
  are ignored; the delimiter (``,``, ``;`` or tab) is taken from the header line.
* ``*.parquet``, ``*.pq``: one column per name, read in batches of ``PARQUET_BATCH_ROWS`` rows (only the
  setup's columns). A timestamp/duration time column is converted to
  seconds by its own unit (``log.time_scale_s`` must then be 1).
* A ROS 2 bag (a folder with ``metadata.yaml``, or a ``.mcap`` / ``.db3`` file):
  ``sensor_msgs/msg/JointState`` on ``log.joint_state_topic`` (``log.q`` are joint names; the
  ``velocity`` field is used when ``log.qdot`` is non-empty and every message has it, else
  ``qdot_rad_s`` is None) and ``geometry_msgs/msg/WrenchStamped`` on ``log.wrench_topic``. Time is
  the header stamp (the bag's record time when a stream's stamps are all zero). Joint-state
  messages that do not name all the declared joints (e.g. a gripper's) are skipped. The units
  apply as declared (REP 103 says rad, N and N m). The two streams run on their own clocks; each
  must be finite, strictly increasing and free of gaps. The wrench stream is the master clock:
  its samples are kept as recorded (interpolating them would average neighbouring noisy samples
  and understate the sensor noise), the joint states (positions and velocities, smooth signals)
  and the ``[log] extra`` ``TOPIC:FIELD`` values are linearly interpolated onto the wrench stamps,
  and wrench samples outside the joint-state stream's time span are dropped.
* This package's run log: ``trace.npz`` or its run folder (channels ``t_s``, ``q_rad`` and
  ``qdot_rad_s`` of the seven Panda joints, and ``wrench_raw_f``, the wrench the flange exerts on
  the tool, i.e. ``wrench_acts = "sensor_on_tool"``); the setup's column names and units are not used.

A static log (``log.static = true``, F/T calibration: each row is a pose at rest) needs no time
column (``log.time = ""``, or left at its default ``"t"`` with no such column: ``UserLog.t_s`` is
None); a time column it has is read (finite, [s] from
the earliest row) but need not increase and may have gaps, as the rows' order carries no meaning.
It needs ``MIN_POSES`` rows. A ROS 2 bag's streams are checked as above even when static.

Every format is validated alike; each problem is a one-line ``KinadaptError`` naming the file, the
row (CSV: the file's line number, header = line 1; otherwise "sample i", 0-based) and the column:
a missing column, a value that is not a number or not finite, a time that does not increase, a
gap (a step over ``GAP_FACTOR`` times the median step), fewer than ``MIN_SAMPLES`` samples
(``MIN_POSES`` for a static log), an empty or unreadable file.

``write_log`` writes a CSV / gzip CSV / Parquet log in a ``LogCfg``'s column names (tests, examples).
"""

from __future__ import annotations

import csv
import gzip
import io
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from dataclasses import field as dc_field
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from kinadapt_nn.errors import KinadaptError

if TYPE_CHECKING:
    import pyarrow as pa

    from kinadapt_nn.diagnostics.setup import LogCfg, SetupCfg

SUPPORTED = ("CSV (.csv, .csv.gz), Parquet (.parquet, .pq), a ROS 2 bag (a folder with metadata.yaml, "
             ".mcap, .db3) or a kinadapt run (trace.npz or its run folder)")
MIN_SAMPLES = 50  # fewer samples cannot be diagnosed
MIN_POSES = 12  # fewer rows of a static log (poses at rest) cannot be diagnosed
GAP_FACTOR = 5.0  # a time step over this many median steps is a gap
_LIST_MAX = 25  # names listed in a "missing column" message
PARQUET_BATCH_ROWS = 65_536  # a Parquet log is read this many rows at a time (only the setup's columns)
PARQUET_BUFFER_BYTES = 1 << 20  # [B] read buffer of a Parquet file's column chunks

Label = Callable[[int], str]  # 0-based sample index -> "line 12" / "sample 10"


class UserLog(NamedTuple):
    """A user's log in SI units, one row per sample (N samples, dof joints)."""

    t_s: np.ndarray | None  # (N,) [s] from the first sample, strictly increasing; static: from the earliest row, any order, or None (no time column)
    q_rad: np.ndarray  # (N, dof) [rad] joint positions
    qdot_rad_s: np.ndarray | None  # (N, dof) [rad/s] joint velocities, or None (differentiate q)
    wrench_log: np.ndarray  # (N, 6) [N, N m] the F/T reading in SI, in the log's own sign convention and frame
    source: str  # the path read
    extra: dict | None = None  # declared extra columns ([log] extra): name -> (N,) values, or None
    static: bool = False  # each row is a pose at rest ([log] static): no derivatives, no time order


class _Layout(NamedTuple):
    """The columns handed to ``_build``: q (dof), qdot (0 or dof), wrench (6), extra, in this order."""

    names: Sequence[str]  # one per column (for messages)
    dof: int  # joints
    n_qdot: int  # 0 (no velocities) or dof
    extra: Sequence[str] = ()  # the declared extra columns' names
    angle_unit: str = "rad"  # of q and qdot
    wrench_scale: np.ndarray | None = None  # (6,) SI per log unit of the wrench; None = already SI
    static: bool = False  # poses at rest: any time order, gaps allowed, MIN_POSES rows


def _layout(log: LogCfg, names: Sequence[str], n_qdot: int) -> _Layout:
    return _Layout(names, len(log.q), n_qdot, log.extra, log.angle_unit, log.wrench_scale(), log.static)


# --------------------------------------------------------------------------------------------- helpers


def _clean(s: object, n: int = 40) -> str:
    """``s`` as one short printable line (file content and library messages go into errors)."""
    text = "".join(c if c.isprintable() else "?" for c in str(s))
    return text if len(text) <= n else text[: n - 3] + "..."


def _first_line(exc: BaseException) -> str:
    lines = str(exc).strip().splitlines()
    return _clean(lines[0] if lines else type(exc).__name__, 120)


def _list_names(names: Sequence[str]) -> str:
    shown = ", ".join(f"'{_clean(x)}'" for x in names[:_LIST_MAX])
    more = f" (+{len(names) - _LIST_MAX} more)" if len(names) > _LIST_MAX else ""
    return (shown or "none") + more


def _unreadable(path: Path, what: str, why: str) -> KinadaptError:
    return KinadaptError(f"log '{path}' is not a readable {what} ({why}); supported formats: {SUPPORTED}")


def _check_count(path: Path, n: int, unit: str = "samples", static: bool = False) -> None:
    need = MIN_POSES if static else MIN_SAMPLES
    if n == 0:
        raise KinadaptError(f"log '{path}' is empty (no {unit}); record a log of at least {need} "
                            f"{'poses' if static else 'samples'}")
    if n < need:
        why = (f"a static log needs at least {need} poses (record more poses)" if static
               else f"at least {need} are needed (record a longer log)")
        raise KinadaptError(f"log '{path}' has only {n} {unit}; {why}")


def _sample_label(i: int) -> str:
    return f"sample {i}"


def _check_finite(path: Path, time: np.ndarray | None, parts: Sequence[np.ndarray], names: Sequence[str],
                  label: Label, time_name: str) -> None:
    """The first non-finite time or value, as a one-line error naming its row and column. ``parts``:
    (N, w) arrays (or (N,)) whose columns are ``names`` in order."""
    cols2 = [p.reshape(len(p), -1) for p in parts]
    n = len(cols2[0]) if cols2 else (0 if time is None else len(time))
    bad_row = ~np.isfinite(time) if time is not None and time.dtype.kind == "f" else np.zeros(n, dtype=bool)
    bad_t = bad_row.copy()
    for c in cols2:  # one part at a time: no (N, all columns) temporary
        bad_row |= ~np.isfinite(c).all(axis=1)
    rows = np.flatnonzero(bad_row)
    if rows.size:
        r = int(rows[0])
        if bad_t[r]:
            name, value = time_name, time[r]
        else:
            flat = np.concatenate([c[r] for c in cols2])
            j = int(np.flatnonzero(~np.isfinite(flat))[0])
            name, value = names[j], flat[j]
        raise KinadaptError(f"log '{path}', {label(r)}: column '{name}' is {value} (not finite); "
                            "fix or remove that row")


def _seconds(path: Path, time: np.ndarray, scale: float, label: Label, time_name: str, static: bool) -> np.ndarray:
    """Raw (integer or float) times -> (N,) [s] from the first sample, strictly increasing and free
    of gaps; static: from the earliest row, in any order."""
    ref = time.min() if static else time[0]
    if time.dtype.kind in "iu":  # integer stamps are differenced exactly before scaling
        t = (time.astype(np.int64) - np.int64(ref)).astype(np.float64) * scale
    else:
        t = (time.astype(np.float64) - float(ref)) * scale
    if static:  # rows are poses: their order carries no meaning
        return t
    dt = np.diff(t)
    nonpos = np.flatnonzero(dt <= 0.0)
    if nonpos.size:
        k = int(nonpos[0]) + 1
        raise KinadaptError(f"log '{path}', {label(k)}: the time ('{time_name}') does not increase "
                            f"({t[k]:.6g} s after {t[k - 1]:.6g} s from the start); sort the log by time and "
                            "remove repeated samples")
    med = float(np.median(dt))
    gaps = np.flatnonzero(dt > GAP_FACTOR * med)
    if gaps.size:
        k = int(gaps[0]) + 1
        raise KinadaptError(f"log '{path}', {label(k)}: a gap of {dt[k - 1]:.4g} s in the time ('{time_name}'; "
                            f"the median step is {med:.4g} s); split the log at the gap into separate logs")
    return t


def _build(path: Path, time: np.ndarray | None, scale: float, cols: np.ndarray, lay: _Layout, label: Label,
           time_name: str) -> UserLog:
    """Validate and assemble. ``time`` (N,) raw (integer or float) times or None (a static log
    without time), ``scale`` [s per unit]; ``cols`` (N, dof + n_qdot + 6 + len(extra)) float laid
    out as ``lay`` says, in the log's units."""
    d, k = lay.dof, lay.n_qdot
    extra = {name: cols[:, d + k + 6 + j] for j, name in enumerate(lay.extra)}
    return _build_parts(path, time, scale, (cols[:, :d], cols[:, d:d + k] if k else None, cols[:, d + k:d + k + 6],
                                            extra), lay, label, time_name)


def _build_parts(path: Path, time: np.ndarray | None, scale: float, parts: tuple, lay: _Layout, label: Label,
                 time_name: str) -> UserLog:
    """``_build`` of the columns as ``parts`` = (q (N, dof), qdot (N, n_qdot) or None, wrench (N, 6),
    {extra name: (N,)}), in the log's units: each kept as it is where it already is float64 and
    contiguous (a long log's reader fills them in place: no second copy of the log)."""
    q, qdot, wrench, extra = parts
    _check_count(path, len(q), static=lay.static)
    _check_finite(path, time, [a for a in (q, qdot, wrench, *extra.values()) if a is not None], lay.names, label,
                  time_name)
    t = None if time is None else _seconds(path, time, scale, label, time_name, lay.static)
    if lay.wrench_scale is not None:
        wrench = wrench * lay.wrench_scale  # (N, 6) log units -> N, N m
    extra_cols = {name: np.ascontiguousarray(v, dtype=np.float64) for name, v in extra.items()}
    if lay.angle_unit == "deg":
        q = np.deg2rad(q)
        qdot = None if qdot is None else np.deg2rad(qdot)
    return UserLog(t_s=t, q_rad=np.ascontiguousarray(q, dtype=np.float64),
                   qdot_rad_s=None if qdot is None else np.ascontiguousarray(qdot, dtype=np.float64),
                   wrench_log=np.ascontiguousarray(wrench, dtype=np.float64), source=str(path),
                   extra=extra_cols or None, static=lay.static)


# --------------------------------------------------------------------------------------------- dispatch


def log_format(path: Path) -> str:
    """"csv", "parquet", "bag" or "trace" by the name (a folder: by what it holds); one-line error
    naming the supported formats otherwise."""
    if not path.exists():
        raise KinadaptError(f"log '{path}' not found; give a log file or folder ({SUPPORTED})")
    if path.is_dir():
        if (path / "metadata.yaml").is_file():
            return "bag"
        if (path / "trace.npz").is_file():
            return "trace"
        raise KinadaptError(f"folder '{path}' is neither a ROS 2 bag (no metadata.yaml) nor a kinadapt run "
                            f"(no trace.npz); supported formats: {SUPPORTED}")
    name = path.name.lower()
    if name.endswith((".csv", ".csv.gz")):
        return "csv"
    if name.endswith((".parquet", ".pq")):
        return "parquet"
    if name.endswith((".mcap", ".db3")):
        return "bag"
    if name.endswith(".npz"):
        return "trace"
    raise KinadaptError(f"log '{path}': unknown format (suffix '{_clean(''.join(path.suffixes))}'); "
                        f"supported formats: {SUPPORTED}")


def read_log(path: str | Path, setup: SetupCfg) -> UserLog:
    """Read and validate a user's log (module docstring); one-line ``KinadaptError`` otherwise."""
    path = Path(path)
    kind = log_format(path)
    if kind == "csv":
        try:
            return _read_csv(path, setup.log)
        finally:  # the parsed table's Arrow memory back to the system (its pool keeps freed memory)
            _import_pyarrow().default_memory_pool().release_unused()
    if kind == "parquet":
        return _read_parquet(path, setup.log)
    if kind == "bag":
        return _read_bag(path, setup.log)
    if setup.log.extra:
        raise KinadaptError(f"log '{path}' is a kinadapt trace, which has no extra columns; remove [log] extra "
                            f"({', '.join(setup.log.extra)}) from the setup")
    return _read_trace(path)


# --------------------------------------------------------------------------------------------- tables


def _import_pyarrow():
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
    pa = _import_pyarrow()
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
        values = col.to_pylist()
        try:
            return np.array(values, dtype=np.float64), 1.0
        except ValueError:
            for i, v in enumerate(values):
                try:
                    float(v)
                except ValueError:
                    what = "empty" if not v.strip() else f"'{_clean(v, 30)}', not a number"
                    raise KinadaptError(f"log '{path}', {label(i)}: column '{name}' is {what}; "
                                        "fix or remove that row") from None
            raise KinadaptError(f"log '{path}': column '{name}' is not all numbers; "  # pragma: no cover
                                "fix its values") from None
    raise KinadaptError(f"log '{path}': column '{name}' holds {_clean(typ)} values, not numbers; "
                        "give it plain numbers")


def _from_table(path: Path, table: pa.Table, log: LogCfg, label: Label, unit: str) -> UserLog:
    """Pick the setup's columns out of a table (CSV) and validate them."""
    return _from_batches(path, _Columns(list(table.column_names), table.num_rows, lambda names: [table.select(names)]),
                         log, label, unit)


class _Columns(NamedTuple):
    """A file's columns, read in batches: ``batches(names)`` yields tables of those columns, in row order."""

    names: list  #: the file's column names (as stored)
    rows: int
    batches: Callable


def _from_batches(path: Path, src: _Columns, log: LogCfg, label: Label, unit: str) -> UserLog:
    """Pick the setup's columns out of a file read in batches (CSV: one; Parquet: row groups) and
    validate them; only the setup's columns are read, each batch straight into the result."""
    from kinadapt_nn.diagnostics.setup import LogCfg

    header = [str(c).strip() for c in src.names]
    if log.static and log.time == LogCfg.model_fields["time"].default and log.time not in header:
        log = log.model_copy(update={"time": ""})  # a static log's time is optional: the default column absent
    fields = ([("time", log.time)] if log.time else []) + [("q", c) for c in log.q] + \
        [("qdot", c) for c in log.qdot] + [("wrench", c) for c in log.wrench] + [("extra", c) for c in log.extra]
    for field, c in fields:
        if c not in header:
            hint = ""
            if not any(f[1] in header for f in fields):
                hint = (" (none of the setup's columns is there: is the first line a header? "
                        f"supported formats: {SUPPORTED})")
            raise KinadaptError(f"log '{path}' has no column '{c}' (log.{field} in the setup); its columns: "
                                f"{_list_names(header)}; fix the name in the setup's [log] section{hint}")
    _check_count(path, src.rows, unit, log.static)
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
    return _build_parts(path, time, per_s * log.time_scale_s, (q, qdot, wrench, extra),
                        _layout(log, names, len(log.qdot)), label, log.time)


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
        return _first_line(exc)
    return None


def _read_csv(path: Path, log: LogCfg) -> UserLog:
    _import_pyarrow()
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
        raise _unreadable(path, "CSV file", _csv_bad_row(path, delimiter) or _first_line(exc)) from None
    return _from_table(path, table, log, lambda i: f"line {_csv_line(path, delimiter, i)}", "data rows")


def _read_parquet(path: Path, log: LogCfg) -> UserLog:
    _import_pyarrow()
    import pyarrow as pa
    import pyarrow.parquet as pq

    try:
        # read as it is decoded: without pre-buffering, pyarrow reads every column chunk of the file
        # into memory first (measured on an hour at 1 kHz, 300 row groups: 323 MB of Arrow memory
        # against 22 MB streamed)
        pf = pq.ParquetFile(path, pre_buffer=False, buffer_size=PARQUET_BUFFER_BYTES)
        src = _Columns(list(pf.schema_arrow.names), pf.metadata.num_rows, lambda names: (
            pa.Table.from_batches([b]) for b in pf.iter_batches(batch_size=PARQUET_BATCH_ROWS, columns=names)))
        return _from_batches(path, src, log, _sample_label, "samples")
    except (pa.ArrowException, OSError, EOFError, ValueError) as exc:
        raise _unreadable(path, "Parquet file", _first_line(exc)) from None
    finally:
        pa.default_memory_pool().release_unused()  # the decoded batches' memory back to the system


# --------------------------------------------------------------------------------------------- trace


def _read_trace(path: Path) -> UserLog:
    from kinadapt_nn.trace import Trace

    file = path / "trace.npz" if path.is_dir() else path
    try:
        tr = Trace.load(file)
    except KinadaptError as exc:
        raise KinadaptError(f"{exc}; supported formats: {SUPPORTED}") from None
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
    return _build(file, t.astype(np.float64), 1.0, np.hstack(parts), _Layout(names, 7, 7), _sample_label, "t_s")


# --------------------------------------------------------------------------------------------- ROS 2 bag

_JOINT_STATE = "sensor_msgs/msg/JointState"
_WRENCH = "geometry_msgs/msg/WrenchStamped"
_WRENCH_NAMES = ("force.x", "force.y", "force.z", "torque.x", "torque.y", "torque.z")


@dataclass
class _BagMessages:
    """What a bag holds on the setup's topics, message by message, in record order."""

    js_head: list[int] = dc_field(default_factory=list)  # joint states: header stamp [ns]
    js_rec: list[int] = dc_field(default_factory=list)  # record time [ns]
    js_names: list[tuple[str, ...]] = dc_field(default_factory=list)
    js_pos: list[np.ndarray] = dc_field(default_factory=list)
    js_vel: list[np.ndarray] = dc_field(default_factory=list)
    w_head: list[int] = dc_field(default_factory=list)  # wrench: header stamp [ns]
    w_rec: list[int] = dc_field(default_factory=list)  # record time [ns]
    w_val: list[tuple[float, ...]] = dc_field(default_factory=list)  # (fx, fy, fz, tx, ty, tz)
    ex_t: dict[str, list[int]] = dc_field(default_factory=dict)  # [log] extra name -> stamps [ns]
    ex_v: dict[str, list[float]] = dc_field(default_factory=dict)  # [log] extra name -> values


def _stamps(header_ns: list[int], record_ns: list[int]) -> np.ndarray:
    """Header stamps [ns] (int64); the bag's record times when a stream never fills its stamps."""
    return np.asarray(record_ns if header_ns and not any(header_ns) else header_ns, dtype=np.int64)


def _ns(stamp) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def _extra_topics(log: LogCfg) -> dict[str, list[tuple[str, list[str]]]]:
    """``[log] extra`` in a bag: topic -> [(the column's name, its dotted field's parts)]."""
    topics: dict[str, list[tuple[str, list[str]]]] = {}
    for name in log.extra:  # "TOPIC:FIELD" (a dotted field of the topic's messages)
        topic, _, fld = name.rpartition(":")
        if not topic or not fld:
            raise KinadaptError(f"[log] extra '{name}': in a ROS 2 bag an extra column is 'TOPIC:FIELD' "
                                "(e.g. '/sensor/temperature:temperature'); fix the setup")
        topics.setdefault(topic, []).append((name, fld.split(".")))
    return topics


def _check_topics(path: Path, have: dict[str, str], want: list[tuple[str, str, str]], extra_topics) -> None:
    listing = ", ".join(f"{_clean(t, 60)} [{_clean(m, 60)}]" for t, m in sorted(have.items())) or "none"
    for topic in extra_topics:
        if topic not in have:
            raise KinadaptError(f"ROS 2 bag '{path}' has no topic '{topic}' ([log] extra in the setup); its "
                                f"topics: {listing}; fix [log] extra")
    for topic, msgtype, key in want:
        if topic not in have:
            raise KinadaptError(f"ROS 2 bag '{path}' has no topic '{topic}' ({key} in the setup); its topics: "
                                f"{listing}; set {key}")
        if have[topic] != msgtype:
            raise KinadaptError(f"ROS 2 bag '{path}': topic '{topic}' ({key}) carries "
                                f"{_clean(have[topic], 60)}, not {msgtype}; set {key} to a {msgtype} "
                                f"topic (its topics: {listing})")


def _add_extra(path: Path, m: _BagMessages, msg, topic: str, rec_ns: int, columns) -> None:
    """The ``[log] extra`` values of one message on ``topic``."""
    hdr = getattr(msg, "header", None)
    st = _ns(hdr.stamp) if hdr is not None else 0
    for name, parts in columns:
        v = msg
        for a in parts:
            if not hasattr(v, a):
                raise KinadaptError(f"ROS 2 bag '{path}': messages on '{topic}' have no field "
                                    f"'{'.'.join(parts)}' ([log] extra '{name}'); fix [log] extra")
            v = getattr(v, a)
        try:
            m.ex_v[name].append(float(v))
        except (TypeError, ValueError):
            raise KinadaptError(f"ROS 2 bag '{path}': field '{'.'.join(parts)}' on '{topic}' is "
                                f"not a number ([log] extra '{name}')") from None
        m.ex_t[name].append(st or int(rec_ns))


def _bag_messages(path: Path, log: LogCfg) -> _BagMessages:
    """Every message on the setup's topics (one-line errors for a missing topic or a damaged bag)."""
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise KinadaptError("reading ROS 2 bags needs the 'rosbags' package (pip install rosbags)") from None

    want = [(log.joint_state_topic, _JOINT_STATE, "log.joint_state_topic"),
            (log.wrench_topic, _WRENCH, "log.wrench_topic")]
    streams = {w[:2] for w in want}
    extra_topics = _extra_topics(log)
    m = _BagMessages(ex_t={n: [] for n in log.extra}, ex_v={n: [] for n in log.extra})
    try:
        with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
            have: dict[str, str] = {}
            for c in reader.connections:
                have.setdefault(c.topic, c.msgtype)
            _check_topics(path, have, want, extra_topics)
            conns = [c for c in reader.connections if (c.topic, c.msgtype) in streams or c.topic in extra_topics]
            for conn, rec_ns, raw in reader.messages(connections=conns):
                msg = reader.deserialize(raw, conn.msgtype)
                if conn.topic in extra_topics:
                    _add_extra(path, m, msg, conn.topic, rec_ns, extra_topics[conn.topic])
                if (conn.topic, conn.msgtype) not in streams:
                    continue
                if conn.msgtype == _JOINT_STATE:
                    m.js_head.append(_ns(msg.header.stamp))
                    m.js_rec.append(int(rec_ns))
                    m.js_names.append(tuple(msg.name))
                    m.js_pos.append(np.asarray(msg.position, dtype=np.float64))
                    m.js_vel.append(np.asarray(msg.velocity, dtype=np.float64))
                else:
                    f, t = msg.wrench.force, msg.wrench.torque
                    m.w_head.append(_ns(msg.header.stamp))
                    m.w_rec.append(int(rec_ns))
                    m.w_val.append((f.x, f.y, f.z, t.x, t.y, t.z))
    except KinadaptError:
        raise
    except Exception as exc:  # noqa: BLE001 -- any failure of the bag library on a damaged file is bad input
        raise _unreadable(path, "ROS 2 bag", _first_line(exc)) from None
    for topic, n_msgs in ((log.joint_state_topic, len(m.js_head)), (log.wrench_topic, len(m.w_head))):
        if n_msgs == 0:
            raise KinadaptError(f"ROS 2 bag '{path}' has no messages on '{topic}'; record that topic")
    return m


class _Stream(NamedTuple):
    """One topic's samples on its own clock."""

    t_ns: np.ndarray  # (M,) int64 [ns] stamps
    values: np.ndarray  # (M, k) float
    src: list[int]  # (M,) the message index on the topic of each sample (for messages)


def _joint_stream(path: Path, log: LogCfg, m: _BagMessages) -> tuple[_Stream, int]:
    """The joint-state messages that name every declared joint -> (stream of q (dof) and, when asked
    for and present in every such message, qdot (dof); n_qdot = 0 or dof)."""
    index: dict[tuple[str, ...], list[int] | None] = {}
    keep, rows, vels = [], [], []
    for i, names in enumerate(m.js_names):
        if names not in index:
            index[names] = [names.index(j) for j in log.q] if all(j in names for j in log.q) else None
        idx = index[names]
        if idx is None or len(m.js_pos[i]) != len(names):
            continue
        keep.append(i)
        rows.append(m.js_pos[i][idx])
        vels.append(m.js_vel[i][idx] if len(m.js_vel[i]) == len(names) else None)
    if not keep:
        seen = list(dict.fromkeys(j for names in index for j in names))
        missing = next((j for j in log.q if j not in seen), log.q[0])
        raise KinadaptError(f"ROS 2 bag '{path}': no message on '{log.joint_state_topic}' has positions for joint "
                            f"'{missing}' (log.q in the setup); its joint names: {_list_names(seen)}; set log.q to "
                            "the arm's joints")
    t = _stamps([m.js_head[i] for i in keep], [m.js_rec[i] for i in keep])
    q = np.array(rows)  # (M, dof)
    if log.qdot and all(v is not None for v in vels):
        return _Stream(t, np.hstack([q, np.array(vels)]), keep), q.shape[1]
    return _Stream(t, q, keep), 0


def _check_stream(path: Path, s: _Stream, names: Sequence[str], topic: str, what: str) -> None:
    """A bag stream on its own clock: at least two samples, finite, strictly increasing, no gaps."""
    at = lambda k: f"ROS 2 bag '{path}', {what} sample {s.src[k]} on '{topic}'"  # noqa: E731
    if len(s.t_ns) < 2:
        raise KinadaptError(f"ROS 2 bag '{path}' has only {len(s.t_ns)} {what} message on '{topic}'; "
                            "record it during the whole log")
    bad = np.flatnonzero(~np.isfinite(s.values).all(axis=1))
    if bad.size:
        r = int(bad[0])
        j = int(np.flatnonzero(~np.isfinite(s.values[r]))[0])
        raise KinadaptError(f"{at(r)}: {names[j]} is {s.values[r, j]} (not finite); filter the bag")
    dt = np.diff(s.t_ns)
    if np.any(dt <= 0):
        k = int(np.flatnonzero(dt <= 0)[0]) + 1
        raise KinadaptError(f"{at(k)}: the header stamp does not increase; the {what} stamps must be strictly "
                            "increasing")
    med = float(np.median(dt))
    if np.any(dt > GAP_FACTOR * med):
        k = int(np.flatnonzero(dt > GAP_FACTOR * med)[0]) + 1
        raise KinadaptError(f"{at(k)}: a gap of {dt[k - 1] * 1e-9:.4g} s (the median step is {med * 1e-9:.4g} s); "
                            "split the log at the gap")


def _onto(t_new: np.ndarray, t: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Linear interpolation of (M, k) ``values`` at (M,) times ``t`` onto (N,) ``t_new`` -> (N, k)."""
    return np.stack([np.interp(t_new, t, values[:, k]) for k in range(values.shape[1])], axis=1)


def _extra_onto(path: Path, log: LogCfg, m: _BagMessages, origin: int, tw_ns: np.ndarray) -> list[np.ndarray]:
    """Each ``[log] extra`` value interpolated onto the wrench stamps -> [(N, 1)]."""
    out = []
    for name in log.extra:
        te, ve = np.asarray(m.ex_t[name], dtype=np.int64), np.asarray(m.ex_v[name], dtype=np.float64)
        if len(te) < 2:
            raise KinadaptError(f"ROS 2 bag '{path}' has {len(te)} message(s) for [log] extra '{name}'; "
                                "record it during the whole log")
        order = np.argsort(te, kind="stable")
        out.append(np.interp(tw_ns, (te[order] - origin).astype(np.float64), ve[order])[:, None])
    return out


def _read_bag(path: Path, log: LogCfg) -> UserLog:
    """Both streams validated on their own clocks; the wrench stamps are the master clock."""
    m = _bag_messages(path, log)
    joints, n_qdot = _joint_stream(path, log, m)
    j_names = [*log.q, *(f"{j} velocity" for j in log.q[: n_qdot])]
    _check_stream(path, joints, j_names, log.joint_state_topic, "joint-state")
    wrench = _Stream(_stamps(m.w_head, m.w_rec), np.array(m.w_val, dtype=np.float64), list(range(len(m.w_head))))
    _check_stream(path, wrench, _WRENCH_NAMES, log.wrench_topic, "wrench")
    t_j, t_w = joints.t_ns, wrench.t_ns
    inside = np.flatnonzero((t_w >= t_j[0]) & (t_w <= t_j[-1]))  # wrench samples the joint states span
    if inside.size == 0:
        o = min(int(t_j[0]), int(t_w[0]))
        raise KinadaptError(
            f"ROS 2 bag '{path}': the joint states ({(t_j[0] - o) * 1e-9:.3f} to {(t_j[-1] - o) * 1e-9:.3f} s) and "
            f"the wrench ({(t_w[0] - o) * 1e-9:.3f} to {(t_w[-1] - o) * 1e-9:.3f} s) do not overlap in time; "
            "check both topics' header stamps")
    origin = int(t_w[inside[0]])
    tw_ns = (t_w[inside] - origin).astype(np.float64)  # (N,) [ns] the master clock
    joints_at = _onto(tw_ns, (t_j - origin).astype(np.float64), joints.values)  # (N, dof + n_qdot)
    cols = np.hstack([joints_at, wrench.values[inside], *_extra_onto(path, log, m, origin, tw_ns)])
    names = [*j_names, *_WRENCH_NAMES, *log.extra]
    label: Label = lambda i: f"wrench sample {inside[i]}"  # noqa: E731
    return _build(path, t_w[inside], 1e-9, cols, _layout(log, names, n_qdot), label, "header stamp")


# --------------------------------------------------------------------------------------------- writer


def write_log(path: str | Path, t_s: np.ndarray | None, q: np.ndarray, qdot: np.ndarray | None, wrench: np.ndarray,
              columns: LogCfg) -> None:
    """Write a log in ``columns``' names (``.csv``, ``.csv.gz`` or ``.parquet``/``.pq`` by suffix),
    atomically. Raw column values: ``t_s`` (N,) in the time column's unit (an integer array stays
    integer), or None for a static log without time (``columns.time = ""``: no time column);
    ``q`` (N, dof) and ``qdot`` (N, dof) with ``dof = len(columns.q)`` in ``columns.angle_unit``
    (``qdot`` is written only when ``columns.qdot`` names columns, and then required); ``wrench``
    (N, 6) in ``columns.force_unit`` / ``columns.torque_unit``."""
    pa = _import_pyarrow()
    from kinadapt_nn.runio import atomic_write

    path = Path(path)
    if (t_s is None) != (not columns.time):
        raise KinadaptError(f"write_log('{path}'): give times exactly when the columns name a time column "
                            f"(time = '{columns.time}', t_s {'None' if t_s is None else 'given'})")
    t = None if t_s is None else np.asarray(t_s)
    if t is not None:
        n = t.shape[0] if t.ndim == 1 else -1
    else:  # a static log without time: the rows of q
        n = np.shape(q)[0] if np.ndim(q) == 2 else -1
    dof = len(columns.q)
    arrays = {"q": (q, dof), "wrench": (wrench, 6)}
    if columns.qdot:
        if qdot is None:
            raise KinadaptError(f"write_log('{path}'): the columns name joint velocities (qdot) but none were given")
        arrays["qdot"] = (qdot, dof)
    for name, (a, width) in arrays.items():
        if n < 0 or np.shape(a) != (n, width):
            raise KinadaptError(f"write_log('{path}'): {name} has shape {np.shape(a)}; expected ({n}, {width}) "
                                f"for {n} rows")
    data = {} if t is None else {columns.time: pa.array(t if t.dtype.kind in "iu" else t.astype(np.float64))}
    for names, key in ((columns.q, "q"), (columns.qdot, "qdot"), (columns.wrench, "wrench")):
        if names:
            a = np.asarray(arrays[key][0], dtype=np.float64)
            data.update({c: pa.array(a[:, j]) for j, c in enumerate(names)})
    table = pa.table(data)
    name = path.name.lower()
    if name.endswith(".csv"):
        import pyarrow.csv as pacsv

        atomic_write(path, lambda tmp: pacsv.write_csv(table, tmp))
    elif name.endswith(".csv.gz"):
        import pyarrow.csv as pacsv

        def write_gz(tmp: str) -> None:
            with pa.CompressedOutputStream(tmp, "gzip") as out:
                pacsv.write_csv(table, out)

        atomic_write(path, write_gz)
    elif name.endswith((".parquet", ".pq")):
        import pyarrow.parquet as pq

        atomic_write(path, lambda tmp: pq.write_table(table, tmp))
    else:
        raise KinadaptError(f"write_log('{path}'): unknown suffix; use .csv, .csv.gz, .parquet or .pq")


__all__ = ["UserLog", "read_log", "write_log", "SUPPORTED", "MIN_SAMPLES", "MIN_POSES", "GAP_FACTOR"]
