"""The log readers' contract and registry, and what every reader returns: a format = one ``LogReader``,
registered by one line; ``UserLog``, ``assemble``, ``from_table``.

A reader is a module that defines

* ``read(path: Path, log: LogCfg) -> UserLog`` -- the file's columns named by the setup's ``[log]``
  section, validated and converted by ``assemble`` (or, for a table of named columns,
  ``from_table``, which picks the setup's columns and calls ``assemble``); bad input is a
  one-line ``KinadaptError`` naming the file, the row and the column;
* ``READER = LogReader(name, doc, what, read, suffixes=..., folder_files=...)``.

The built-ins (``csv_log``, ``parquet_log``, ``ros2_bag``, ``run_trace``) are written exactly so and
registered in ``readers/__init__.py``. A reader of another package registers with
``register(READER)`` when imported, or without any import through the entry-point group
``kinadapt_nn.log_readers`` (``jsonl = "mypkg.jsonl_log:READER"`` in its ``pyproject.toml``), which
``kinadapt diagnose`` loads on first use. ``examples/readers/json_lines.py`` is a complete one.

A reader turns a file into columns; ``assemble`` validates them and puts
them in SI units, the same way for every format: a one-line ``KinadaptError`` naming the file, the
row (``label(i)``: "line 12" for a CSV, "sample 10" otherwise) and the column for a value that is
not finite, a time that does not increase, a gap (a step over ``GAP_FACTOR`` median steps), fewer
than ``MIN_SAMPLES`` samples (``MIN_POSES`` rows for a static log), an empty log.

A table of named columns (Arrow) -> ``UserLog`` (``from_table``, ``from_batches``): the setup's
columns picked, typed and validated. The CSV and Parquet readers read their files into Arrow tables
and hand them here; a reader of any format that yields named columns does the same (``from_table``;
``examples/readers/json_lines.py``).
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from importlib.metadata import entry_points
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from kinadapt_nn.errors import KinadaptError, did_you_mean

if TYPE_CHECKING:
    import pyarrow as pa

    from kinadapt_nn.diagnostics.setup import LogCfg

MIN_SAMPLES = 50  # fewer samples cannot be diagnosed
MIN_POSES = 12  # fewer rows of a static log (poses at rest) cannot be diagnosed
GAP_FACTOR = 5.0  # a time step over this many median steps is a gap
_LIST_MAX = 25  # names listed in a "missing column" message

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


class Layout(NamedTuple):
    """The columns handed to ``assemble``: q (dof), qdot (0 or dof), wrench (6), extra, in this order."""

    names: Sequence[str]  # one per column (for messages)
    dof: int  # joints
    n_qdot: int  # 0 (no velocities) or dof
    extra: Sequence[str] = ()  # the declared extra columns' names
    angle_unit: str = "rad"  # of q and qdot
    wrench_scale: np.ndarray | None = None  # (6,) SI per log unit of the wrench; None = already SI
    static: bool = False  # poses at rest: any time order, gaps allowed, MIN_POSES rows


def layout(log: LogCfg, names: Sequence[str], n_qdot: int) -> Layout:
    """The ``Layout`` of a setup's ``[log]`` columns (``names``: one per column, for messages)."""
    return Layout(names, len(log.q), n_qdot, log.extra, log.angle_unit, log.wrench_scale(), log.static)


# --------------------------------------------------------------------------------------------- text


def clean(s: object, n: int = 40) -> str:
    """``s`` as one short printable line (file content and library messages go into errors)."""
    text = "".join(c if c.isprintable() else "?" for c in str(s))
    return text if len(text) <= n else text[: n - 3] + "..."


def first_line(exc: BaseException) -> str:
    """An exception's first line, cleaned (a library's message inside a one-line error)."""
    lines = str(exc).strip().splitlines()
    return clean(lines[0] if lines else type(exc).__name__, 120)


def list_names(names: Sequence[str]) -> str:
    """Up to ``_LIST_MAX`` quoted names, then how many more."""
    shown = ", ".join(f"'{clean(x)}'" for x in names[:_LIST_MAX])
    more = f" (+{len(names) - _LIST_MAX} more)" if len(names) > _LIST_MAX else ""
    return (shown or "none") + more


def sample_label(i: int) -> str:
    """The row label of a format without line numbers: "sample i" (0-based)."""
    return f"sample {i}"


# --------------------------------------------------------------------------------------------- checks


def check_count(path: Path, n: int, unit: str = "samples", static: bool = False) -> None:
    """At least ``MIN_SAMPLES`` samples (``MIN_POSES`` rows for a static log)."""
    need = MIN_POSES if static else MIN_SAMPLES
    if n == 0:
        raise KinadaptError(f"log '{path}' is empty (no {unit}); record a log of at least {need} "
                            f"{'poses' if static else 'samples'}")
    if n < need:
        why = (f"a static log needs at least {need} poses (record more poses)" if static
               else f"at least {need} are needed (record a longer log)")
        raise KinadaptError(f"log '{path}' has only {n} {unit}; {why}")


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


def assemble_columns(path: Path, time: np.ndarray | None, scale: float, cols: np.ndarray, lay: Layout,
                     label: Label, time_name: str) -> UserLog:
    """``assemble`` of one (N, dof + n_qdot + 6 + len(extra)) float array laid out as ``lay`` says."""
    d, k = lay.dof, lay.n_qdot
    extra = {name: cols[:, d + k + 6 + j] for j, name in enumerate(lay.extra)}
    return assemble(path, time, scale, (cols[:, :d], cols[:, d:d + k] if k else None, cols[:, d + k:d + k + 6],
                                        extra), lay, label, time_name)


def assemble(path: Path, time: np.ndarray | None, scale: float, parts: tuple, lay: Layout, label: Label,
             time_name: str) -> UserLog:
    """Validate and assemble a log (module docstring). ``time`` (N,) raw (integer or float) times or
    None (a static log without time), ``scale`` [s per unit]; ``parts`` = (q (N, dof), qdot (N, n_qdot)
    or None, wrench (N, 6), {extra name: (N,)}), in the log's units: each kept as it is where it
    already is float64 and contiguous (a long log's reader fills them in place: no second copy)."""
    q, qdot, wrench, extra = parts
    check_count(path, len(q), static=lay.static)
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


# -- the registry ------------------------------------------------------------------------------------

#: the entry-point group another package's readers are announced in
ENTRY_POINT_GROUP = "kinadapt_nn.log_readers"
_NAME = re.compile(r"^[a-z][a-z0-9_]*$")


@dataclass(frozen=True)
class LogReader:
    """One log format: how it is recognised and read."""

    name: str  #: short lower-case name ("csv")
    doc: str  #: the format as listed in messages: "CSV (.csv, .csv.gz)"
    what: str  #: the format in a sentence: "a CSV log"
    read: Callable[[Path, LogCfg], UserLog]  #: (path, the setup's [log] section) -> the validated log
    suffixes: tuple[str, ...] = ()  #: lower-case file-name endings of this format (".csv.gz")
    folder_files: tuple[str, ...] = ()  #: a folder holding one of these files is a log of this format


_READERS: dict[str, LogReader] = {}
_plugins_loaded = False


def register(reader: LogReader) -> LogReader:
    """Add ``reader`` (returned, so that ``READER = register(LogReader(...))`` works); a one-line
    ``KinadaptError`` for a malformed reader or a name, suffix or folder file already registered."""
    if not isinstance(reader, LogReader):
        raise KinadaptError(f"register({clean(reader)}): a log reader is a LogReader "
                            "(kinadapt_nn.diagnostics.readers.LogReader)")
    if not _NAME.match(reader.name):
        raise KinadaptError(f"log reader name {reader.name!r}: use lower-case letters, digits and '_'")
    if not reader.suffixes and not reader.folder_files:
        raise KinadaptError(f"log reader '{reader.name}' declares neither suffixes nor folder_files; "
                            "say which files it reads")
    bad = [s for s in reader.suffixes if not s.startswith(".") or s != s.lower()]
    if bad:
        raise KinadaptError(f"log reader '{reader.name}': suffix {bad[0]!r} must be lower case and start with '.'")
    if reader.name in _READERS and _READERS[reader.name] is not reader:
        raise KinadaptError(f"two log readers named '{reader.name}'; rename one")
    for other in _READERS.values():
        if other.name == reader.name:
            continue
        taken = set(other.suffixes) & set(reader.suffixes) or set(other.folder_files) & set(reader.folder_files)
        if taken:
            raise KinadaptError(f"log reader '{reader.name}' claims {sorted(taken)[0]!r}, which log reader "
                                f"'{other.name}' reads; give it its own suffix")
    _READERS[reader.name] = reader
    return reader


def unregister(name: str) -> None:
    """Remove the reader ``name`` (a test's clean-up); a one-line error naming the registered ones."""
    lookup(name)
    del _READERS[name]


def _load_plugins() -> None:
    """Register the readers other packages announce (``ENTRY_POINT_GROUP``), once."""
    global _plugins_loaded
    if _plugins_loaded:
        return
    _plugins_loaded = True
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        try:
            reader = ep.load()
        except Exception as exc:  # noqa: BLE001 -- any failure of another package's import is its error
            raise KinadaptError(f"log reader '{ep.name}' ({ep.value}, entry point {ENTRY_POINT_GROUP}) could not "
                                f"be imported: {first_line(exc)}") from None
        if _READERS.get(getattr(reader, "name", None)) is not reader:
            register(reader)


def registered() -> tuple[LogReader, ...]:
    """Every registered reader, the built-ins first."""
    _load_plugins()
    return tuple(_READERS.values())


def lookup(name: str) -> LogReader:
    """The reader ``name``; a one-line error listing the registered ones otherwise."""
    _load_plugins()
    try:
        return _READERS[name]
    except KeyError:
        hint = did_you_mean(name, _READERS)
        raise KinadaptError(f"{name!r} is not a registered log reader (registered: {', '.join(_READERS)})"
                            f"{'; ' + hint if hint else ''}") from None


def supported() -> str:
    """The registered formats for messages: "CSV (.csv, .csv.gz), ... or a kinadapt run (...)"."""
    docs = [r.doc for r in registered()]
    return docs[0] if len(docs) == 1 else ", ".join(docs[:-1]) + " or " + docs[-1]


def unreadable(path: Path, what: str, why: str) -> KinadaptError:
    """A file of a known format that its reader cannot parse: one line naming it and the formats."""
    return KinadaptError(f"log '{path}' is not a readable {what} ({why}); supported formats: {supported()}")


def reader_for(path: Path) -> LogReader:
    """The reader of ``path`` by its name (a folder: by the files it holds; the longest matching
    suffix wins); a one-line error naming the registered formats otherwise."""
    readers = registered()
    if not path.exists():
        raise KinadaptError(f"log '{path}' not found; give a log file or folder ({supported()})")
    if path.is_dir():
        for r in readers:
            if any((path / f).is_file() for f in r.folder_files):
                return r
        holds = " nor ".join(f"{r.what} (no {', '.join(r.folder_files)})" for r in readers if r.folder_files)
        raise KinadaptError(f"folder '{path}' is neither {holds}; supported formats: {supported()}")
    name = path.name.lower()
    hits = [(len(s), r) for r in readers for s in r.suffixes if name.endswith(s)]
    if hits:
        return max(hits, key=lambda h: h[0])[1]
    raise KinadaptError(f"log '{path}': unknown format (suffix '{clean(''.join(path.suffixes))}'); "
                        f"supported formats: {supported()}")


# -- a table of named columns -> UserLog (module docstring) ------------------------------------------


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
