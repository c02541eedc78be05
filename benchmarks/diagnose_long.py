"""A long recording through ``kinadapt diagnose``: peak memory and wall time against one pass that
reads the same file and runs the arm's kinematics on every sample (issue 37, section 2).

    python benchmarks/diagnose_long.py [--minutes 60] [--case tool_gravity] [--out DIR] [--json FILE]

The log comes from the independent foreign rig B (``examples/foreign_rig.py --rig B``: MuJoCo's
inverse dynamics of a 12 s experiment at 1 kHz, free-space moves then a tip pressed and circled on
a tilted table). A long recording plays that motion forward and backward in turn (the wrench of a
rigid tool is invariant under time reversal except the contact friction, whose moment about the
tip is zero), each pass with fresh sensor noise (seed = pass index), for ``--minutes`` minutes at
1 kHz; it is written as Parquet (rig B's columns) with the rig's nominal setup.

Each measurement runs in a fresh child process (``resource.getrusage(RUSAGE_CHILDREN)``: max RSS
is the peak resident memory of that child): (a) read the log and compute the sensor's
kinematics on every sample (``readers.read_log`` + ``signals.from_log``), (b) the whole command
(``python -m kinadapt_nn.app.cli diagnose LOG --setup SETUP --out DIR``). Prints the wall time,
the CPU time and the peak memory of both and the ratios (b)/(a); on a shared, loaded machine the
CPU-time ratio is the one that measures the code (the wall time measures the neighbours too).
It also prints whether the verdicts are right: the present effects against the rig's hidden ones
(``foreign_rig._effects_truth``), and each true parameter's error in units of its reported sd.
"""

from __future__ import annotations

import argparse
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
    """``examples/foreign_rig.py`` loaded as a module (the same loader as benchmarks/foreign_logs.py)."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from foreign_logs import _rig as load_rig

    return load_rig()


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


def _child(cmd: list[str]) -> tuple[float, float, float, str]:
    """Run ``cmd`` in a fresh child; -> (wall [s], CPU time of the child [s], peak RSS of the child
    [MB], stdout). ``ru_maxrss`` of RUSAGE_CHILDREN is the largest peak of any child so far, so
    the children run in order of increasing memory (the diagnosis last) and a peak that does not
    grow is an error."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    res = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    wall = time.perf_counter() - t0
    if res.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd[:4])} failed:\n{res.stderr[-3000:]}")
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if after.ru_maxrss <= before.ru_maxrss:
        raise RuntimeError("the child's peak RSS is not above an earlier child's: it cannot be told apart")
    cpu = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    return wall, cpu, after.ru_maxrss / 1024.0, res.stdout


def measure(log_path: Path, setup_path: Path, out: Path, case: str = "tool_gravity") -> dict:
    """(a) read + kinematics and (b) the whole ``diagnose`` command, each in a fresh child process.
    -> {"read_kinematics": {...}, "diagnose": {...}, "ratio_wall": float}."""
    py = sys.executable
    wall_a, cpu_a, rss_a, stdout_a = _child([py, "-c", _KINEMATICS, str(setup_path), str(log_path)])
    wall_b, cpu_b, rss_b, _ = _child([py, "-m", "kinadapt_nn.app.cli", "diagnose", str(log_path), "--setup",
                                      str(setup_path), "--out", str(out / "diagnosis"), "--overwrite", "--quiet"])
    rep = json.loads((out / "diagnosis" / "diagnosis.json").read_text())
    return {"truth": truth_check(rep, case),"read_kinematics": {"wall_s": wall_a, "cpu_s": cpu_a, "peak_rss_MB": rss_a,
                                "samples": int(stdout_a.split()[0])},
            "diagnose": {"wall_s": wall_b, "cpu_s": cpu_b, "peak_rss_MB": rss_b,
                         "verdicts": {e["effect"]: e["verdict"] for e in rep["ranking"] if e.get("judged", True)}},
            "ratio_wall": wall_b / wall_a, "ratio_cpu": cpu_b / cpu_a}


def truth_check(rep: dict, case: str) -> dict:
    """The diagnosis against rig B's hidden effects of ``case``: {"present": [...], "truth": [...],
    "right": bool, "errors_sd": {effect: {param: (estimate - truth) / sd}}}."""
    fr = _rig()
    truth = fr._effects_truth(fr._hidden(case, "B"))
    present = sorted(e["effect"] for e in rep["ranking"] if e["verdict"] == "present")
    errors = {}
    for name, params in truth.items():
        est = next((e.get("estimate") or {} for e in rep["ranking"] if e["effect"] == name), {})
        errors[name] = {k: (est[k]["value"] - v) / est[k]["sd"] for k, v in params.items()
                        if isinstance(est.get(k), dict) and est[k].get("value") is not None and est[k].get("sd")}
    return {"present": present, "truth": sorted(truth), "right": present == sorted(truth), "errors_sd": errors}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--minutes", type=float, default=60.0, help="length of the recording [min] (default 60)")
    ap.add_argument("--case", default="tool_gravity", help="rig B case (default tool_gravity)")
    ap.add_argument("--out", default=None, help="folder for the log and the diagnosis (default: a temporary one)")
    ap.add_argument("--json", default=None, help="also write the figures to this JSON file")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(args.out) if args.out else Path(tmp)
        t0 = time.perf_counter()
        log_path, setup_path, n = write_long_log(out, args.minutes, args.case)
        print(f"log: {n} samples ({args.minutes:g} min at {RATE_HZ:g} Hz, rig B case '{args.case}'), "
              f"{log_path.stat().st_size / 1e6:.0f} MB Parquet, written in {time.perf_counter() - t0:.0f} s")
        res = measure(log_path, setup_path, out, args.case)
    b = res["diagnose"]
    res.update(minutes=args.minutes, case=args.case)
    for key, what in (("read_kinematics", "(a) read + kinematics of every sample"),
                      ("diagnose", "(b) kinadapt diagnose (whole command)")):
        r = res[key]
        print(f"{what}: wall {r['wall_s']:.1f} s, CPU {r['cpu_s']:.1f} s, peak RSS {r['peak_rss_MB']:.0f} MB")
    print(f"ratio (b)/(a): wall {res['ratio_wall']:.2f}, CPU {res['ratio_cpu']:.2f} (target <= 3); peak (b) "
          f"{b['peak_rss_MB'] / 1024:.2f} GB (target <= 2 GB)")
    print("verdicts: " + ", ".join(f"{k} {v}" for k, v in b["verdicts"].items()))
    tc = res["truth"]
    print(f"present {tc['present']}, the rig's hidden effects {tc['truth']}: {'right' if tc['right'] else 'WRONG'}; "
          "errors in sd: " + "; ".join(f"{n} " + ", ".join(f"{k} {v:+.1f}" for k, v in ps.items())
                                       for n, ps in tc["errors_sd"].items()))
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
