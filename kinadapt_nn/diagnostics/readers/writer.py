"""``write_log``: a CSV / gzip CSV / Parquet log in a ``LogCfg``'s column names (tests, examples)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from kinadapt_nn.diagnostics.readers.base import import_pyarrow
from kinadapt_nn.errors import KinadaptError

if TYPE_CHECKING:
    from kinadapt_nn.diagnostics.setup import LogCfg


def write_log(path: str | Path, t_s: np.ndarray | None, q: np.ndarray, qdot: np.ndarray | None, wrench: np.ndarray,
              columns: LogCfg) -> None:
    """Write a log in ``columns``' names (``.csv``, ``.csv.gz`` or ``.parquet``/``.pq`` by suffix),
    atomically. Raw column values: ``t_s`` (N,) in the time column's unit (an integer array stays
    integer), or None for a static log without time (``columns.time = ""``: no time column);
    ``q`` (N, dof) and ``qdot`` (N, dof) with ``dof = len(columns.q)`` in ``columns.angle_unit``
    (``qdot`` is written only when ``columns.qdot`` names columns, and then required); ``wrench``
    (N, 6) in ``columns.force_unit`` / ``columns.torque_unit``."""
    pa = import_pyarrow()
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
