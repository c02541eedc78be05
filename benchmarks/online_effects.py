"""The README's online-effect table: each of four hidden effects in the excitation run, then
``kinadapt diagnose RUN --add E --rerun`` (the effect adapted online by the default law).

    python benchmarks/online_effects.py [--out DIR]     (~6 min on 2 cores)

Prints, per effect, the W-scaled prediction error in contact of the original (frozen) run and of
the rerun, and the effect's online estimate next to the injected truth.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EFFECTS = ("contact_stiffness", "contact_friction_couple", "grasp_compliance", "ft_frame_rotation")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", help="keep the runs here (default: a temporary folder)")
    a = ap.parse_args()
    from kinadapt_nn.config import load_config
    from kinadapt_nn.features.effect_library import LIBRARY

    tmp = tempfile.TemporaryDirectory() if a.out is None else None
    root = Path(a.out or tmp.name)
    kin = [sys.executable, "-m", "kinadapt_nn.app.cli"]
    print("| effect | frozen | rerun + effect | online estimate | true |")
    for e in EFFECTS:
        run, diag = root / e, root / f"{e}-diag"
        subprocess.run([*kin, "online", "--config", str(ROOT / "online" / "excite.toml"), "--set",
                        f"effects.{e}.enabled=true", "--out", str(run), "--overwrite", "--quiet", "--set",
                        "run.tensorboard=false", "--set", "run.figure=false"], check=False)
        subprocess.run([*kin, "diagnose", str(run), "--add", e, "--rerun", "--out", str(diag), "--overwrite", "--quiet"],
                       check=True)
        r = json.loads((diag / "diagnosis.json").read_text())["rerun"]
        true = LIBRARY[e].default(load_config(None).effects)
        err = r["pred_error_rms_contact_w"]
        print(f"| {e} | {err['original']:.3g} | {err['rerun']:.3g} | "
              f"{[round(float(x), 5) for x in r['model_effect_params']]} | {[round(float(x), 5) for x in true]} |",
              flush=True)
    if tmp is not None:
        tmp.cleanup()


if __name__ == "__main__":
    main()
