"""The real HIRO snap-assembly recordings (``../shared/realdata/hiro_snap_assembly``, public data
the project does not ship), each trial alone and all pooled, against an independent free-space
gravity fit (``tests/diagnostics/test_realdata_hiro.py``: numpy URDF kinematics, least squares).

    python benchmarks/realdata_hiro.py [--out DIR]

Prints per trial: the package's tool mass ± sd, the independent fit's mass and force residual,
the contact onset (package vs independent), the contact point ± sd, what is undetermined; then
the pooled tool and mount and the trials named as contradicting the others.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.diagnostics.test_realdata_hiro import REAL, SETUP, TRIALS, URDF, independent_fit


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", help="output folder (default: a temporary one)")
    args = ap.parse_args()
    if not TRIALS:
        print(f"{REAL} is absent: nothing to measure (public data, not shipped)")
        return 0
    out = Path(args.out or tempfile.mkdtemp(prefix="hiro-"))
    out.mkdir(parents=True, exist_ok=True)
    setup = out / "hiro.toml"
    setup.write_text(SETUP.format(urdf=URDF.as_posix()))
    t0 = time.perf_counter()
    cmd = [sys.executable, "-m", "kinadapt_nn.app.cli", "diagnose", *map(str, TRIALS), "--setup", str(setup),
           "--out", str(out / "pooled"), "--overwrite", "--quiet"]
    subprocess.run(cmd, check=True)
    wall = time.perf_counter() - t0
    print(f"{'trial':24s} {'mass [kg]':>16s} {'indep.':>7s} {'res N':>6s} {'onset s':>7s} {'indep.':>7s} "
          f"{'contact point [mm] ± sd':>34s}  undetermined")
    for p in TRIALS:
        r = json.loads((out / "pooled" / p.stem / "diagnosis.json").read_text())
        ind = independent_fit(p)
        sm, seg = r["sensor_mount"], r["segmentation"]
        cp = r["effective_setup"]["contact_point"]
        pt = "-" if cp is None else ("[" + ", ".join(f"{1000 * v:.1f}" for v in cp["point_sensor_m"]) + "] ± "
                                     + ", ".join(f"{1000 * v:.1f}" for v in cp["sd_m"]))
        ons = seg["contact_onsets_s"][0] if seg["contact_onsets_s"] else float("nan")
        und = ", ".join(u["parameter"] for u in sm["undetermined"]) or "-"
        print(f"{p.stem:24s} {sm['tool_mass_kg']:8.4f} ± {sm['tool_mass_sd_kg']:.4f} {ind['mass_kg']:7.4f} "
              f"{ind['residual_N']:6.3f} {ons:7.3f} {ind['onset_s']:7.3f} {pt:>34s}  {und}")
    pooled = json.loads((out / "pooled" / "diagnosis.json").read_text())
    print()
    print(pooled["summary"])
    print(f"\n{len(TRIALS)} trials, one `kinadapt diagnose` command: {wall:.1f} s wall; outputs in {out}")
    masses = np.array([independent_fit(p)["mass_kg"] for p in TRIALS])
    print(f"independent free-space masses: {masses.min():.3f}-{masses.max():.3f} kg")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
