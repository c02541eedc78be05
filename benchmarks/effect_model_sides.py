"""How far apart the two model sides of each effect are (issue 52, "the model side of an effect
written once"): the controller's online columns (``features.effect_library``, in its level
channels) against the diagnosis's columns (``effects.builtin``, the wrench on the sensor),
both on one package run of the excitation program.

The diagnosis's columns ``C_s`` (n, 6, k) are mapped into the online level domain the way the
online library maps a wrench, ``to_level(sig, [R_ws f; R_ws m])``, after taring them in the sensor
frame at the online tare sample (as the online reading is); per effect and parameter the script fits ``L_online ~ a * mapped`` (one scalar ``a``: the
two sides' sign conventions differ) and prints ``a`` and the relative misfit ``|L - a M| / |L|``
over the samples where the drive is on. A misfit near 0 means the two sides are one formula
written twice (up to frame, sign and tare); a misfit near 1 means two different models (the
contact-kinematic effects: the online side integrates the admittance's map S at the nominal tip,
the diagnosis differentiates the declared socket's springs).

Then the one-file form (``tests/features/test_effect_one_file.py``): ``examples/effects/hose_weight.py``
(``online=True``) against the simulator's ``world_force`` (its weight) at its clamp, both sides, as the largest
error over the largest prediction per group (forces, moments); and the generic map
``effect_library.from_wrench`` applied to the built-ins' diagnosis functions of the payload, the sensor
rotation and the drift against the online library's hand-written columns.

Usage: python benchmarks/effect_model_sides.py [--duration 20]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    sys.path.insert(0, str(ROOT))
    from tests.diagnostics.test_effect_sides import compare, sides

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=20.0, help="seconds of the excitation program [s]")
    a = ap.parse_args()
    sig, s = sides(a.duration)
    print(f"excitation run {a.duration:g} s, {len(sig.t_s)} online samples, {s.n} diagnosis samples")
    print(f"{'effect':24s} {'parameter (online / diagnosis)':40s} {'scale a':>9s} {'misfit':>7s} {'rms online':>10s} "
          f"{'rms diag':>9s}")
    for name, par, scale, mis, r_on, r_dg in compare(sig, s):
        print(f"{name:24s} {par[:40]:40s} {scale:9.4g} {mis:7.3f} {r_on:10.3g} {r_dg:9.3g}")

    from tests.features.test_effect_one_file import example_errors, generic_map_gaps, pull_runs

    pair = pull_runs(8.0)
    print("\none file, both sides: examples/effects/hose_weight.py (online=True) vs the simulated weight, 8 s")
    for side, (err, scale) in example_errors(pair).items():
        print(f"  {side:10s} forces: max error {err[:3].max():.2g} N of {scale[:3].max():.3g} N "
              f"({100 * err[:3].max() / scale[:3].max():.2f} %); moments: {err[3:].max():.2g} N m of "
              f"{scale[3:].max():.3g} N m ({100 * err[3:].max() / scale[3:].max():.2f} %)")
    print("generic map (from_wrench) on the built-ins' diagnosis functions vs the hand-written online columns")
    for name, (same, opposite, scale) in generic_map_gaps(pair["pull"][0]).items():
        print(f"  {name:20s} max |derived - hand| {same:.3g}, max |derived + hand| {opposite:.3g} (columns up to {scale:.3g})")


if __name__ == "__main__":
    main()
