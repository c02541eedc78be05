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
error over the largest prediction per group (forces, moments); and every built-in's online columns
(``features.effect_library.LIBRARY``, taken from the built-in's one module since issue 52) against those
the controller used before, written out by hand, recorded in
``tests/data/online_columns_before_52.npz`` (``tests/features/test_builtin_online_columns.py``).

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

    from tests.features.test_effect_one_file import example_errors, pull_runs

    pair = pull_runs(8.0)
    print("\none file, both sides: examples/effects/hose_weight.py (online=True) vs the simulated weight, 8 s")
    for side, (err, scale) in example_errors(pair).items():
        print(f"  {side:10s} forces: max error {err[:3].max():.2g} N of {scale[:3].max():.3g} N "
              f"({100 * err[:3].max() / scale[:3].max():.2f} %); moments: {err[3:].max():.2g} N m of "
              f"{scale[3:].max():.3g} N m ({100 * err[3:].max() / scale[3:].max():.2f} %)")
    print_before_after()


def print_before_after() -> None:
    """Each built-in's online columns now against the hand-written ones recorded before (two windows)."""
    import numpy as np

    from tests.features import test_builtin_online_columns as t

    z = np.load(t.REF)
    sigs = t.windows()
    print("\nonline columns now vs before (hand-written, tests/data/online_columns_before_52.npz): max |now - sign before|")
    for name in t.LIBRARY:
        sign = t.DERIVED_SIGN.get(name, 1.0)
        gaps = []
        for w in t.WINDOWS:
            old, old_steps = t._reference(z, w, name)
            new, new_steps = t._new(sigs[w], z[f"{w}/steps"], name)
            new, new_steps = t._as_before(name, new, 0), t._as_before(name, new_steps, 0)
            gaps.append(f"{w} {max(np.abs(new - sign * old).max(), np.abs(new_steps - sign * old_steps).max()):.2g} "
                        f"of {np.abs(old).max():.3g}")
        side = "from_wrench" if t.BUILTINS[name].online is True else "online=fn"
        print(f"  {name:24s} {side:11s} sign {sign:+.0f}: " + "; ".join(gaps))


if __name__ == "__main__":
    main()
