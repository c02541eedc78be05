"""``kinadapt diagnose LOG --setup S --follow``: the live monitor on a log another program is still writing.

The log is read as it grows -- a CSV line by line (a last line without its newline waits for the
next read), a Parquet file row group by row group (the file re-opened at each poll; a footer
being rewritten is retried) -- with the set-up's ``[log]`` columns and units. Each good sample goes
to the same monitor as ``kinadapt online --monitor`` (``monitor.Monitor``: the set-up's nominal
model, the same test and shapes), its kinematics from the set-up's arm (``diagnostics.physical.
ArmModel``) a poll at a time. Memory stays bounded: a poll's rows, the monitor's ring and the events.

Bad input never stops it: a truncated line, a row whose column count changed (a column that
disappeared), a value that is not a finite number, a time that does not increase -- each gives one
line (repeats of one kind within a second of log are counted, not printed) and the monitor goes on
with the next good sample.
"""

from __future__ import annotations

import csv
import io
import math
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from kinadapt_nn.config import MonitorCfg
from kinadapt_nn.diagnostics.setup import SetupCfg
from kinadapt_nn.errors import KinadaptError
from kinadapt_nn.monitor.monitor import Event, Monitor

#: samples used to measure the log's sample time before the monitor starts
DT_SAMPLES = 50
#: [s] poll period when the log has not grown
POLL_S = 0.05


class _Source:
    """New rows of a growing log as (line or row number, dict of column -> text or value)."""

    def rows(self) -> list[tuple[int, list]]:
        raise NotImplementedError


class _CsvSource(_Source):
    def __init__(self, path: Path, say: Callable[[str], None]) -> None:
        if path.suffix == ".gz":
            raise KinadaptError(f"--follow reads a plain CSV or Parquet log as it grows; '{path}' is compressed "
                                "(follow the uncompressed file the recorder writes)")
        self.path, self.say = path, say
        self.offset, self.line_no, self.header, self.delim, self.tail = 0, 0, None, ",", b""

    def rows(self) -> list[tuple[int, list]]:
        with open(self.path, "rb") as fh:
            fh.seek(self.offset)
            data = fh.read(1 << 22)  # at most 4 MiB a poll (bounded memory; the rest at the next)
        if not data:
            return []
        self.offset += len(data)
        data = self.tail + data
        cut = data.rfind(b"\n")
        if cut < 0:
            self.tail = data
            return []
        self.tail = data[cut + 1:]
        out = []
        for raw in data[:cut].split(b"\n"):
            self.line_no += 1
            text = raw.decode("utf-8", errors="replace").rstrip("\r")
            if not text.strip() or text.lstrip().startswith("#"):
                continue
            if self.header is None:
                self.delim = max((",", ";", "\t"), key=text.count)
                self.header = [h.strip() for h in next(csv.reader([text], delimiter=self.delim))]
                continue
            out.append((self.line_no, next(csv.reader([text], delimiter=self.delim))))
        return out


class _ParquetSource(_Source):
    def __init__(self, path: Path, say: Callable[[str], None]) -> None:
        self.path, self.say, self.done, self.header, self.row = path, say, 0, None, 0

    def rows(self) -> list[tuple[int, list]]:
        import pyarrow.parquet as pq

        try:
            pf = pq.ParquetFile(self.path)
        except Exception:  # noqa: BLE001  (being written: its footer is not there yet; the next poll)
            return []
        out = []
        for g in range(self.done, pf.num_row_groups):
            tab = pf.read_row_group(g)
            names = list(tab.column_names)
            if self.header is None:
                self.header = names
            cols = [tab.column(n).to_numpy(zero_copy_only=False) if n in names else None for n in self.header]
            missing = [n for n, c in zip(self.header, cols) if c is None]
            if missing:
                self.say(f"row group {g}: column '{missing[0]}' is missing (a column that disappeared); its "
                         f"{tab.num_rows} samples skipped")
                self.row += tab.num_rows
                continue
            for i in range(tab.num_rows):
                out.append((self.row, [c[i] for c in cols]))
                self.row += 1
        self.done = pf.num_row_groups
        return out


class Follower:
    """The monitor on a growing log (module docstring). ``poll()`` reads what is new and returns the
    events named meanwhile; ``run(idle_stop_s)`` polls until the log has not grown for that long
    (None: until interrupted)."""

    def __init__(self, path: Path, setup: SetupCfg, mcfg: MonitorCfg = MonitorCfg(),
                 on_event: Callable[[Event], None] | None = None, say: Callable[[str], None] = print) -> None:
        from kinadapt_nn.diagnostics.physical import ArmModel

        self.path, self.setup, self.mcfg, self.on_event, self._say = Path(path), setup, mcfg, on_event, say
        if not self.path.is_file():
            raise KinadaptError(f"--follow: log '{path}' not found (start the recorder first, or give its path)")
        suffix = self.path.suffix.lower()
        self.src = _ParquetSource(self.path, self._bad) if suffix in (".parquet", ".pq") else \
            _CsvSource(self.path, self._bad)
        lg = setup.log
        if not lg.time:
            raise KinadaptError("--follow needs a time column ([log] time): a static log of poses is not a stream")
        self.want = [lg.time, *lg.q, *lg.qdot, *lg.wrench]
        self.dof = len(lg.q)
        self.scale_t, self.deg = lg.time_scale_s, lg.angle_unit == "deg"
        self.wscale = lg.wrench_scale()
        self.arm = ArmModel(setup)
        self.idx: list[int] | None = None
        self.monitor: Monitor | None = None
        self.pre: list[np.ndarray] = []  # the first samples, before the sample time is known
        self.t0 = self.t_last = None
        self.q_prev = None
        self.n_good = self.n_bad = 0
        self.events: list[Event] = []
        self._last_kind, self._last_t, self._repeats = None, -math.inf, 0

    # -- bad input: one line each (repeats of a kind within a second of log counted) ------------------
    def _bad(self, msg: str, kind: str = "") -> None:
        self.n_bad += 1
        t = self.t_last if self.t_last is not None else 0.0
        if kind and kind == self._last_kind and t - self._last_t < 1.0:
            self._repeats += 1
            return
        if self._repeats:
            self._say(f"{self.path.name}: ({self._repeats} more like the last)")
        self._repeats, self._last_kind, self._last_t = 0, kind, t
        self._say(f"{self.path.name}: {msg}; skipped, going on with the next good sample")

    def _columns(self) -> bool:
        hdr = self.src.header
        if hdr is None:
            return False
        missing = [c for c in self.want if c not in hdr]
        if missing:
            raise KinadaptError(f"--follow: log '{self.path}' has no column '{missing[0]}' ([log] of the set-up); "
                                f"its columns: {', '.join(hdr[:20])}")
        self.idx = [hdr.index(c) for c in self.want]
        return True

    def _parse(self, where: int, fields: list) -> np.ndarray | None:
        """One row -> [t; q; qdot; wrench] in the log's units, or None (bad: said once)."""
        label = f"line {where}" if isinstance(self.src, _CsvSource) else f"sample {where}"
        if isinstance(self.src, _CsvSource) and len(fields) != len(self.src.header):
            self._bad(f"{label} has {len(fields)} fields, the header {len(self.src.header)} (a truncated line or "
                      "a column that disappeared)", "fields")
            return None
        vals = np.empty(len(self.idx))
        for k, i in enumerate(self.idx):
            try:
                v = float(fields[i])
            except (TypeError, ValueError):
                v = math.nan
            if not math.isfinite(v):
                self._bad(f"{label}: column '{self.want[k]}' is not a finite number ('{str(fields[i])[:20]}')",
                          "nan")
                return None
            vals[k] = v
        return vals

    # -- reading ----------------------------------------------------------------------------------------
    def poll(self) -> list[Event]:
        """Read and monitor what the log gained since the last poll. -> the events named meanwhile."""
        rows = self.src.rows()
        if not rows or (self.idx is None and not self._columns()):
            return []
        n_ev = len(self.events)
        good = []
        for where, fields in rows:
            v = self._parse(where, fields)
            if v is None:
                continue
            t = v[0] * self.scale_t
            if self.t0 is not None and t <= self.t0 + self.t_last:
                self._bad(f"{'line' if isinstance(self.src, _CsvSource) else 'sample'} {where}: time {t:g} s does "
                          "not increase", "time")
                continue
            if self.t0 is None:
                self.t0 = t
            self.t_last = t - self.t0
            v[0] = self.t_last
            good.append(v)
        if good:
            self._feed(np.array(good))
        return self.events[n_ev:]

    def _feed(self, rows: np.ndarray) -> None:
        """Good samples (n, 1 + dof + n_qdot + 6) in the log's units into the monitor."""
        if self.monitor is None:
            self.pre.append(rows)
            allrows = np.concatenate(self.pre)
            if len(allrows) < DT_SAMPLES:
                return
            self.pre = []
            dt = float(np.median(np.diff(allrows[:, 0])))
            self.monitor = Monitor(self.setup, self.mcfg, dt, self._event)
            rows = allrows
        dof, lg = self.dof, self.setup.log
        t = rows[:, 0]
        q = rows[:, 1:1 + dof]
        qd = rows[:, 1 + dof:1 + 2 * dof] if lg.qdot else None
        w = rows[:, -6:] * self.wscale
        if self.deg:
            q = np.deg2rad(q)
            qd = None if qd is None else np.deg2rad(qd)
        if qd is None:  # velocities from the encoders (backward differences; the first from the last poll)
            prev = q[:1] if self.q_prev is None else self.q_prev
            qd = np.diff(np.concatenate([prev, q]), axis=0) / np.maximum(np.diff(np.concatenate([[t[0] - 1.0], t])),
                                                                          1e-9)[:, None]
        self.q_prev = q[-1:]
        R_wf, x_w, Jp, Jr = self.arm._frames(q)  # noqa: SLF001  (the arm's batched kinematics)
        R_ws = R_wf @ self.arm.R_fs
        lever = R_wf @ self.arm.p_fs
        p_ws = x_w + lever
        w_w = np.einsum("nij,nj->ni", Jr, qd)
        v_w = np.einsum("nij,nj->ni", Jp, qd) + np.cross(w_w, lever)
        mon = self.monitor
        for k in range(len(t)):
            mon.sample(float(t[k]), R_ws[k], p_ws[k], v_w[k], w_w[k], w[k], Jr[k])
        self.n_good += len(t)

    def _event(self, ev: Event) -> None:
        if ev not in self.events:
            self.events.append(ev)
        if self.on_event is not None:
            self.on_event(ev)

    def run(self, idle_stop_s: float | None = None, clock=time.monotonic, sleep=time.sleep) -> list[Event]:
        """Poll until the log has not grown for ``idle_stop_s`` [s] (None: until interrupted); then an
        alarm still waiting is named on what there is. -> every event."""
        last_size, last_change = -1, clock()
        try:
            while True:
                self.poll()
                size = self.path.stat().st_size if self.path.exists() else -1
                behind = isinstance(self.src, _CsvSource) and self.src.offset < size  # more than a poll's read
                if size != last_size or behind:
                    last_size, last_change = size, clock()
                if behind:
                    continue
                if idle_stop_s is not None and clock() - last_change >= idle_stop_s:
                    break
                sleep(POLL_S)
        finally:
            if self.monitor is not None:
                self.monitor.finish()
        return self.events


def benchmark_follow(repo: Path) -> float:
    """Samples per CPU second of a ``Follower`` reading a whole 6 s run's CSV (1 kHz) at once: the
    reading, parsing, kinematics and monitor of every sample (``benchmarks/monitor_events.py``)."""
    import tempfile

    from kinadapt_nn.config import load_config
    from kinadapt_nn.diagnostics.ownrun import setup_of_run
    from kinadapt_nn.runs.episode import run_episode

    cfg = load_config(repo / "online" / "monitor.toml", ["run.progress=false", "effects.world_force.enabled=true",
                                                          "effects.world_force.onset_s=3.0"])
    tr = run_episode(cfg).trace
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "log.csv"
        write_csv(path, tr["t_s"], tr["q_rad"], tr["qdot_rad_s"], tr["wrench_raw_f"])
        fol = Follower(path, setup_of_run(cfg), cfg.monitor, say=lambda m: None)
        c0 = time.process_time()
        fol.poll()
        cpu = time.process_time() - c0
        return fol.n_good / cpu


def csv_text(t: np.ndarray, q: np.ndarray, qd: np.ndarray, w: np.ndarray, header: bool = True) -> str:
    """Rows as the package's run CSV writes them: t, q1.., qd1.., fx, fy, fz, tx, ty, tz."""
    n = q.shape[1]
    buf = io.StringIO()
    if header:
        buf.write(",".join(["t", *(f"q{j}" for j in range(1, n + 1)), *(f"qd{j}" for j in range(1, n + 1)),
                            "fx", "fy", "fz", "tx", "ty", "tz"]) + "\n")
    np.savetxt(buf, np.column_stack([t, q, qd, w]), delimiter=",", fmt="%.9g")
    return buf.getvalue()


def write_csv(path: Path, t, q, qd, w) -> None:
    Path(path).write_text(csv_text(t, q, qd, w))
