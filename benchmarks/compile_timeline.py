"""Where a cold first run's compile goes: every numba compile, per process, on one time axis.

    python benchmarks/compile_timeline.py [--depth 0] [--set KEY=VALUE ...] [--save FILE]

Runs ``kinadapt online --quiet`` once in a fresh process with an empty numba cache
(``NUMBA_CACHE_DIR`` a new temporary folder, as on a fresh clone) and records numba's own compile
events (``numba.core.event``, kind ``numba:compile``: start and end of each function's compile,
nested callees inside their caller) in that process and in the two-core compile's helper
(``python -m kinadapt_nn.controller.core``): a ``sitecustomize`` module on the child's
``PYTHONPATH`` installs the listener in every Python process started from it. Prints, per
process, each compile of nesting depth <= ``--depth`` (0: the functions compiled from Python, not
as a callee) as ``start end seconds name`` in seconds since the first compile began, then per
process the busy time (depth 0) and when it ended, and the run's wall and CPU.

What it is for: seeing which process compiles what, and what waits (issue 52: the helper had
finished its callees at 7.1 s while the step kernel compiled two of its parts on one core).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: installed in every child process: numba's compile events, appended to $KINADAPT_COMPILE_LOG as JSON
#: lines {pid, depth, start, end, name} (perf_counter seconds: one clock for every process of the machine)
_SITECUSTOMIZE = '''
import json, os, time
_log = os.environ.get("KINADAPT_COMPILE_LOG")
if _log:
    from numba.core import event as _event

    class _Listener(_event.Listener):
        depth = 0
        starts = []

        def on_start(self, ev):
            self.starts.append(time.perf_counter())
            _Listener.depth += 1

        def on_end(self, ev):
            _Listener.depth -= 1
            t0 = self.starts.pop()
            fn = ev.data["dispatcher"].py_func
            with open(_log, "a") as f:
                f.write(json.dumps({"pid": os.getpid(), "depth": _Listener.depth, "start": t0,
                                    "end": time.perf_counter(), "name": fn.__qualname__}) + "\\n")

    _event.register("numba:compile", _Listener())
'''


def _rows(log: Path) -> list[tuple[int, int, float, float, str]]:
    events = [json.loads(line) for line in log.read_text().splitlines()]
    return [(e["pid"], e["depth"], e["start"], e["end"], e["name"]) for e in events]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--depth", type=int, default=0, help="deepest nesting printed (0: compiled from Python)")
    ap.add_argument("--set", action="append", default=[], help="a config override for the run, KEY=VALUE")
    ap.add_argument("--save", type=Path, help="also write the printed lines to this file")
    args = ap.parse_args()
    lines: list[str] = []

    def say(s: str) -> None:
        print(s, flush=True)
        lines.append(s)

    with tempfile.TemporaryDirectory(prefix="kinadapt-timeline-") as tmp:
        site = Path(tmp) / "site"
        site.mkdir()
        (site / "sitecustomize.py").write_text(_SITECUSTOMIZE)
        log = Path(tmp) / "compile.log"
        env = dict(os.environ, NUMBA_CACHE_DIR=str(Path(tmp) / "numba"), KINADAPT_COMPILE_LOG=str(log),
                   PYTHONPATH=os.pathsep.join([str(site), str(ROOT), os.environ.get("PYTHONPATH", "")]))
        cmd = [sys.executable, "-m", "kinadapt_nn.app.cli", "online", "--out", str(Path(tmp) / "run"), "--quiet",
               *[a for kv in args.set for a in ("--set", kv)]]
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, env=env, cwd=ROOT, capture_output=True, text=True)
        wall = time.perf_counter() - t0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        if proc.returncode not in (0, 1) or not log.exists():
            sys.exit(f"compile_timeline: the run failed (exit {proc.returncode}): {proc.stderr.strip()[-500:]}")
        rows = _rows(log)
    origin = min(r[2] for r in rows)
    pids = sorted({r[0] for r in rows}, key=lambda p: min(r[2] for r in rows if r[0] == p))
    say(f"# a cold `kinadapt online --quiet` {' '.join(args.set)} (empty numba cache); seconds since the first "
        "compile began")
    for k, pid in enumerate(pids):
        mine = sorted((r for r in rows if r[0] == pid), key=lambda r: r[2])
        say(f"== process {k} ({'the run' if k == 0 else 'a helper'}): start end seconds name")
        for _pid, depth, a, b, name in mine:
            if depth <= args.depth:
                say(f"{'  ' * depth}{a - origin:7.2f} {b - origin:7.2f} {b - a:6.2f}  {name}")
    for k, pid in enumerate(pids):
        top = [r for r in rows if r[0] == pid and r[1] == 0]
        say(f"process {k}: compiling {sum(b - a for _p, _d, a, b, _n in top):.2f} s, its last compile ended at "
            f"{max(b for *_x, b, _n in top) - origin:.2f} s")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    say(f"run: wall {wall:.2f} s, cpu {cpu:.2f} s (every process of it), exit {proc.returncode}")
    if args.save:
        args.save.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
