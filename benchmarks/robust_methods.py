"""Estimates beside an unmodelled face contact, by method (issue 51, "estimates robust to what is left"): the
alternatives measured before ``completeness.robust`` was chosen.

    python benchmarks/robust_methods.py [--seeds 3] [--seed0 0] [--case flat_face_crosstalk_mount_known]

The log is ``examples/contact_rig.py``'s (standalone): a box-peg face pressed, slid and twisted (a moment about
the declared tip no effect has), a hidden crosstalk ``Fx += 0.04 Fz`` judged with the user's effect file
``examples/effects/crosstalk_fx_fz.py``, the guessed tool (0.5 kg on the axis for 0.62 kg off it), the mount
declared. The diagnosis's steps are run up to the ranking (``userlog``), then the tool's first moment
``dm c`` and the crosstalk are estimated

* ``all rows``: the ranking as it was (the final model on every row; the crosstalk, when not selected, given it);
* ``hint nuisance (1)`` / ``(2)``: the ranking again with the leading one or two hint shapes' fitted columns
  (``completeness.hints``) as nuisance columns beside the offset;
* ``rows out, reselect``: the ranking again on the rows of the channels that carry nothing unexplained
  (``completeness.explained_rows``);
* ``robust (shipped)``: ``completeness.robust``: the same rows, the ranking's choice kept, the estimate moved by
  the change and its sd widened by it.

Printed per seed and method: the crosstalk (verdict, value ± sd, error / sd) and ``dm c`` x, y, z (error / sd).
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.diagnostics.example_scripts import load_example

CROSSTALK = str(ROOT / "examples" / "effects" / "crosstalk_fx_fz.py")


def _ranked(case_dir: Path):
    """The diagnosis's steps up to the ranking (``userlog.diagnose``): (ranked, library, setup, sigma, excite, block)."""
    from kinadapt_nn.diagnostics import selection as sel, signals as sg, userlog as ul
    from kinadapt_nn.diagnostics.readers import read_log
    from kinadapt_nn.diagnostics.setup import load_setup

    setup = load_setup(case_dir / "setup.toml")
    log = read_log(case_dir / "log.csv", setup)
    rc, sc = ul.RowCfg(), sel.SelCfg()
    lib, names, _, _ = ul._library_for(log, setup, [], [CROSSTALK])
    quiet = lambda msg: None  # noqa: E731
    cal = ul._without_disputed(ul._effective_tip(log, ul.calibrate(log, sg.from_log(log, setup, quiet), setup, None,
                                                                  rc, quiet), setup))
    chk = ul._checks(cal, setup, log)
    excite = {n: lib[n].excite for n in names}
    excite["_params"] = {n: lib[n].params for n in names}
    rk = ul._RankCtx(lib, cal.sigma, rc, sc, excite, chk.block, {}, quiet)
    return ul._ranked(rk, cal.signals, names), lib, cal.setup, cal.sigma, excite, chk.block


def _row(entries: list[dict], truth: dict) -> str:
    by = {e["effect"]: e for e in entries}
    x = by["crosstalk_fx_fz"]
    k, dmc = truth["k"], truth["dmc"]
    v, sd = float(x["params"][0]), float(x["sd"][0])
    out = f"crosstalk {x['verdict']:13s} {v:7.4f} ± {sd:6.4f} ({(v - k) / sd:+5.1f} sd)   dm c err/sd:"
    g = by["tool_gravity"]
    if g["verdict"] != "present":
        return out + " (tool_gravity " + g["verdict"] + ")"
    for a in range(3):
        out += f" {(float(g['params'][1 + a]) - dmc[a]) / float(g['sd'][1 + a]):+5.1f}"
    return out


def methods(case_dir: Path, truth: dict) -> list[tuple[str, str]]:
    """(method, printed row) for each method of the module docstring on one log."""
    from kinadapt_nn.diagnostics import completeness as cp, selection as sel, stream

    ranked, lib, setup, sigma, excite, block = _ranked(case_dir)
    sc = sel.SelCfg()
    s, des, rm, res = ranked.s, ranked.des, ranked.rm, ranked.result
    plaus = lambda n, p: lib[n].why_impossible(p, setup)  # noqa: E731
    out = [("all rows", _row(res.entries, truth))]
    hs = cp.hints(s, des, rm, res, sc)
    shapes = {x.name: x for x in cp.shapes(s)}
    bs = des.stats
    base = [src for src in bs.sources if src.name in ("_offset", "_tip")]
    effs = [src for src in bs.sources if src.name not in ("_offset", "_tip")]
    for nh in (1, 2):
        use = [stream.Source("_hint_" + h["shape"], shapes[h["shape"]].columns, list(h["_cols"])) for h in hs[:nh]]
        st = stream.block_stats(s, rm, base + use + effs, des.y, des.block, des.n_blocks, bs.chunk)
        kz = sum(len(x.cols) for x in base + use)
        r = sel.select(des._replace(Z=sel.Width((len(des.y), kz)), stats=st), sc, plaus, excite, block)
        out.append((f"hint nuisance ({'+'.join(h['shape'] for h in hs[:nh])})", _row(r.entries, truth)))
    un = cp.unexplained(des, res.heldout, rm, sigma, setup, (float(np.median(np.diff(s.t))), 0.01))
    names = list(des.channel_names)
    des_x = cp.explained_rows(s, rm, des, [names.index(c) for c in un["carried_by"]])
    r = sel.select(des_x, sc, plaus, excite, block)
    out.append((f"rows out ({', '.join(un['carried_by'])}), reselect", _row(r.entries, truth)))
    rob = cp.robust(ranked, sigma, 0.01, sc)
    out.append(("robust (shipped)", _row(rob.result.entries, truth)))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="Estimates beside an unmodelled face contact, by method.")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--seed0", type=int, default=0)
    ap.add_argument("--case", default="flat_face_crosstalk_mount_known")
    a = ap.parse_args(argv)
    from kinadapt_nn.diagnostics.userlog import RowCfg

    assert RowCfg().stride_s == 0.01, "the rows' spacing this script assumes"
    rig = load_example("contact_rig")
    for seed in range(a.seed0, a.seed0 + a.seeds):
        tmp = Path(tempfile.mkdtemp(prefix="robust-"))
        try:
            d = rig.make_case(a.case, tmp, seed=seed)
            m, c = rig.TOOL_MASS_KG, np.asarray(rig.TOOL_COM_S_M)
            truth = {"k": rig.CROSSTALK_FX_FROM_FZ,
                     "dmc": m * c - rig.DECLARED_MASS_KG * np.asarray(rig.DECLARED_COM_S_M)}
            for name, row in methods(d, truth):
                print(f"seed {seed}  {name:42s} {row}", flush=True)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
