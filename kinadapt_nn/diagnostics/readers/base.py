"""What every log reader returns and the checks every reader applies: ``UserLog`` and ``assemble``.

A reader (``readers/registry.py``) turns a file into columns; ``assemble`` validates them and puts
them in SI units, the same way for every format: a one-line ``KinadaptError`` naming the file, the
row (``label(i)``: "line 12" for a CSV, "sample 10" otherwise) and the column for a value that is
not finite, a time that does not increase, a gap (a step over ``GAP_FACTOR`` median steps), fewer
than ``MIN_SAMPLES`` samples (``MIN_POSES`` rows for a static log), an empty log.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from kinadapt_nn.errors import KinadaptError

if TYPE_CHECKING:
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
