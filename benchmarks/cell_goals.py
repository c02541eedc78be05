"""Issue 40 part 3's checks on finished cell comparisons (``kinadapt compare --config online/compare_cell.toml``).

    python benchmarks/cell_goals.py DIR [DIR ...]

Per folder (one draw): (a) arm_errors neural / adjoint at the last insertion <= 0.5; (b) the nominal
family's final cell error <= 0.2 % per features type; (c) no rise between consecutive insertions
larger than 2 % (relative) AND 0.01 percentage points (a rise fails only when it exceeds both);
(d) every insertion seated. Medians over tools, as ``benchmarks/cell_learning.py`` prints them.
"""

import csv
import sys
from pathlib import Path


def load(f):
    rows = [r for r in csv.DictReader(open(Path(f) / "comparison.csv")) if r["insertion"] not in ("", "all")]
    cur, seat = {}, {}
    for r in rows:
        k = (r["tool_family"], r["features"])
        cur.setdefault(k, []).append(float(r["jacobian_error_cell_median"]))
        if r["success_rate"] not in ("", None):
            seat[k] = seat.get(k, True) and float(r["success_rate"]) == 1.0
    return cur, seat
allok = True
for f in sys.argv[1:]:
    cur, seat = load(f)
    print(f"== {f}")
    a, n = cur[("arm_errors", "adjoint")][-1], cur[("arm_errors", "neural")][-1]
    ok_a = n <= 0.5 * a
    print(f"  (a) arm_errors neural/adjoint = {n/a:.2f}  (neural {100*n:.3f} %, adjoint {100*a:.3f} %)  {'PASS' if ok_a else 'FAIL'}")
    ok_b = True
    for feat in ("adjoint", "rbf", "neural"):
        if ("nominal", feat) in cur:
            e = cur[("nominal", feat)][-1]
            ok_b &= e <= 0.002
            print(f"  (b) nominal {feat:8s} final {100*e:.3f} %  {'PASS' if e <= 0.002 else 'FAIL'}")
    ok_c = True
    for k, c in cur.items():
        rises = [(b / a_ - 1, 100 * (b - a_), i + 2) for i, (a_, b) in enumerate(zip(c[1:], c[2:]))]
        worst = max(rises, key=lambda t: t[0])
        bad = [t for t in rises if t[0] > 0.02 and t[1] > 0.01]
        ok_c &= not bad
        print(f"  (c) {k[0]:10s} {k[1]:8s} largest rise {100*worst[0]:+.1f} % ({worst[1]:+.4f} pp, at insertion {worst[2]})"
              f"  violations(>2 % and >0.01 pp): {len(bad)}  final {100*c[-1]:.3f} %")
    ok_d = all(seat.values())
    print(f"  (d) all seated: {ok_d}")
    print(f"  => a {ok_a} b {ok_b} c {ok_c} d {ok_d}")
