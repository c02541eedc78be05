"""A long recording through ``kinadapt diagnose``: peak memory and wall time against one pass that
reads the same file and runs the arm's kinematics on every sample (issue 37, section 2).

    python benchmarks/diagnose_long.py [--minutes 60] [--case tool_gravity] [--out DIR] [--keep]

The log comes from the independent foreign rig B (``examples/foreign_rig.py --rig B``: MuJoCo's
inverse dynamics of a 12 s experiment at 1 kHz, free-space moves then a tip pressed and circled on
a tilted table). A long recording plays that motion forward and backward in turn (the wrench of a
rigid tool is invariant under time reversal except the contact friction, whose moment about the
tip is zero), each pass with fresh sensor noise (seed = pass index), for ``--minutes`` minutes at
1 kHz; it is written as Parquet (rig B's columns) with the rig's nominal setup.

Each measurement runs in a fresh child process (``resource.getrusage(RUSAGE_CHILDREN)`` max RSS
is the peak resident memory of that child): (a) read the log and compute the sensor's
kinematics on every sample (``readers.read_log`` + ``signals.from_log``), (b) the whole command
(``python -m kinadapt_nn.app.cli diagnose LOG --setup SETUP --out DIR``). Prints both figures
and the ratio of the wall times.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RATE_HZ = 1000.0


def _rig():
    spec = importlib.util.spec_from_file_location("foreign_rig", ROOT / "examples" / "foreign_rig.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules["foreign_rig"] = mod
    spec.loader.exec_module(mod)
    return mod


def write_long_log(out: Path, minutes: float, case: str = "tool_gravity", rows_per_group: int = 200_000
                   ) -> tuple[Path, Path, int]:
    """Write ``out/log.parquet`` (``minutes`` of rig B's experiment played forward and backward,
    fresh noise per pass) and ``out/setup.toml``. -> (log path, setup path, samples)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    fr = _rig()
    if fr.B_RATE_HZ != RATE_HZ:
        raise RuntimeError(f"rig B logs at {fr.B_RATE_HZ} Hz, this benchmark assumes {RATE_HZ} Hz")
    out.mkdir(parents=True, exist_ok=True)
    n_total = int(round(minutes * 60.0 * RATE_HZ))
    names = (fr.B_CSV_TIME, *fr.B_CSV_Q, *fr.B_CSV_WRENCH)
    schema = pa.schema([(n, pa.float64()) for n in names])
    log_path = out / "log.parquet"
    n_done, k = 0, 0
    with pq.ParquetWriter(log_path, schema) as wr:
        while n_done < n_total:
            sig = fr._case_signals_b(case, seed=k, noise=True)
            q, w = sig["q"], sig["wrench"]
            if k % 2:  # backward: the same poses in reverse order
                q, w = q[::-1], w[::-1]
            q, w = q[1:], w[1:]  # the turning sample belongs to the previous pass
            m = min(len(q), n_total - n_done)
            t = (n_done + np.arange(m)) / RATE_HZ
            block = np.hstack([t[:, None], q[:m], w[:m]])
            for a in range(0, m, rows_per_group):
                sl = block[a:a + rows_per_group]
                wr.write_table(pa.table({nm: pa.array(np.ascontiguousarray(sl[:, j])) for j, nm in enumerate(names)},
                                        schema=schema))
            n_done += m
            k += 1
    setup_path = out / "setup.toml"
    setup_path.write_text(fr.setup_toml("csv", True, "B"))
    return log_path, setup_path, n_total


_KINEMATICS = """
import sys, time
from kinadapt_nn.diagnostics import readers, signals
from kinadapt_nn.diagnostics.setup import load_setup
t0 = time.perf_counter()
setup = load_setup(sys.argv[1])
log = readers.read_log(sys.argv[2], setup)
s = signals.from_log(log, setup)
print(s.n, time.perf_counter() - t0)
"""


def _child(cmd: list[str]) -> tuple[float, float, str]:
    """Run ``cmd`` in a fresh child; -> (wall [s], peak RSS of the child [MB], stdout)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    t0 = time.perf_counter()
    res = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    wall = time.perf_counter() - t0
    if res.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd[:4])} failed:\n{res.stderr[-3000:]}")
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    if peak <= before:
        raise RuntimeError("the child's peak RSS is not above an earlier child's: run each measurement in its own "
                           "benchmark process")
    return wall, peak / 1024.0, res.stdout
