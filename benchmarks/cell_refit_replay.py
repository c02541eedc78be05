"""Between-insertion refit variants replayed on the logged insertions of ``kinadapt compare``'s cell draws.

    python benchmarks/cell_refit_replay.py collect [--seeds 3000 5000] [--features neural adjoint]
        [--families arm_errors nominal] [--set cell.refit_step_sd=0] [--store runs/cell_replay]
    python benchmarks/cell_refit_replay.py replay [--store runs/cell_replay] [--variants shipped polyak ...]

``collect`` runs the cells of ``online/compare_cell.toml`` for the tools ``kinadapt compare`` draws
with each seed (the same overrides, the tools of one family and features type stepped together, as
compare does), with the shipped refit between insertions, and stores per tool every insertion's
refit data (the law's regression rows on the contact samples: measured data only) and the cell
error curve the closed loop gave; it prints per tool that curve and what the refit chose after
each insertion (the neural evidence prior: which prior it acted on and the log-evidence gain; the
trust region: the refit's full step in posterior sd, before the region). ``replay`` rebuilds each tool's controller and its held-out truth
(evaluation only), applies each refit variant to the stored data insertion by insertion (the variant
sees only measured data: the rows of the insertions so far), scores every estimate on the truth, and
prints per draw the median over tools after each insertion, the largest rise between insertions and
whether check (c) holds (no rise above both 2 % and 0.01 percentage points); ``--per-tool``: each
tool's curve and largest rise too. The replay keeps the
logged trajectories (open loop; on the draws checked the closed loop gave the same curves to the
digits printed): ``benchmarks/cell_learning.py`` is the closed-loop confirmation.

Variants (each from the measured rows of the insertions so far only):

* ``shipped`` -- the refit as it is, ``cell.refit_step_sd = 0``;
* ``polyak`` -- the running mean of the refit's acted estimates;
* ``nosel`` -- the posterior mean, every direction acted on;
* ``accept`` -- a measured never-worse test, lagged: the refit without the latest insertion
  replaces the acted estimate only if it predicts that insertion's lateral forces (held out from
  both) no worse;
* ``trustR`` -- the trust region of ``cell.refit_step_sd = R``: the acted estimate steps towards
  the new refit by at most R in the new posterior's metric;
* ``xtrustR`` -- the same cap in the metric of the change a consistent estimate makes between
  nested refits, ``(P_prev - P_new)^+``.
"""

from __future__ import annotations

import argparse
import pickle
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _jobs(seed: int, family: str, features: str) -> list[list[str]]:
    from kinadapt_nn.runs.compare import compare_jobs, load_compare_config

    ccfg = load_compare_config(ROOT / "online" / "compare_cell.toml", [f"seed={seed}"])
    return [["run.progress=false", *j.overrides] for j in compare_jobs(ccfg, Path("/tmp/unused"))
            if j.family == family and j.features == features]


def collect(seed: int, family: str, features: str, store: Path, extra: list[str] = ()) -> None:
    from kinadapt_nn.config import load_config
    from kinadapt_nn.runs import insertions as ins

    t0 = time.perf_counter()
    overs = [[*o, *extra] for o in _jobs(seed, family, features)]
    cfgs = [load_config(None, o) for o in overs]
    ctrls = [ins.make_controller(c) for c in cfgs]
    cells = [ins._Cell(c, k) for c, k in zip(cfgs, ctrls)]
    n = cfgs[0].run.insertions
    for i in range(n):
        cfg_i = [ins._start_insertion(c, k, i) for c, k in zip(cfgs, ctrls)]
        for cell, r in zip(cells, ins._episodes(cfg_i, ctrls, False, True)):
            cell.after(i, r, [n], True)
    rec = [{"overrides": o, "data": cell.refit.data, "curve": cell.cell_err,
            "seated": all(r["success"] for r in cell.rows)} for o, cell in zip(overs, cells)]
    for t, cell in enumerate(cells):  # what the refit chose after each insertion (its summary rows)
        notes = [r.get("refit") or {} for r in cell.rows]
        line = f"  {seed} {family} {features} tool {t}: cell error " + " ".join(f"{100 * e:.3f}" for e in cell.cell_err) + " %"
        if any("simpler_prior" in n for n in notes):
            line += ("; prior acted on " + "".join("c" if n.get("simpler_prior") else "A" for n in notes)
                     + " (A: the features' own, all arms; c: the calibrated arm); log-evidence gain "
                     + " ".join(f"{n['log_evidence_gain']:.1f}" for n in notes))
        if any("step_posterior_sd" in n for n in notes):
            line += "; full step [posterior sd] " + " ".join(f"{n['step_posterior_sd']:.3g}" for n in notes
                                                            if "step_posterior_sd" in n)
        print(line, flush=True)
    store.mkdir(parents=True, exist_ok=True)
    with open(store / f"{seed}_{family}_{features}.pkl", "wb") as fh:
        pickle.dump(rec, fh)
    print(f"collected seed {seed} {family} {features}: {len(rec)} tools ({time.perf_counter() - t0:.0f} s)", flush=True)


# ---------------------------------------------------------------- variants (measured data only)

def _acted(rf, data, k):
    return rf.solve(data[:k])[2]


def _shipped(rf, data, _r):
    return [_acted(rf, data, k) for k in range(1, len(data) + 1)]


def _polyak(rf, data, _r):  # the running mean of the refit's acted estimates
    acc = _shipped(rf, data, _r)
    return [np.mean(acc[:k], axis=0) for k in range(1, len(acc) + 1)]


def _nosel(rf, data, _r):  # the posterior mean, every direction acted on
    return [rf.solve(data[:k])[0] for k in range(1, len(data) + 1)]


def _accept(rf, data, _r):
    """Lagged: the refit without the latest insertion replaces the acted estimate only if it
    predicts that insertion (held out from both) no worse."""
    cur, out = _acted(rf, data, 1), []
    for k in range(1, len(data) + 1):
        if k >= 3:
            cand = _acted(rf, data, k - 1)
            H, y = data[k - 1]
            e = [float(np.mean((y - np.einsum("kmp,p->km", H, th)) ** 2)) for th in (cand, cur)]
            cur = cand if e[0] <= e[1] else cur
        out.append(cur.copy())
    return out


def _trust(rf, data, r, expected_change=False):
    """Step towards each new refit by at most r in the new posterior's metric (``expected_change``:
    in that of (P_prev - P_new)^+, the change's covariance between nested refits). A refit whose
    prior choice (the evidence prior) differs from the one before is taken as it is, as the shipped
    refit does (``Refit.after_insertion``)."""
    cur = P_prev = alt_prev = None
    out = []
    for k in range(1, len(data) + 1):
        _, P, act = rf.solve(data[:k])
        switched = rf.alt is not None and alt_prev is not None and rf.chose_alt != alt_prev
        alt_prev = rf.chose_alt
        if cur is None or switched:
            cur = act
        else:
            d = act - cur
            if expected_change:
                lam, V = np.linalg.eigh(0.5 * ((P_prev - P) + (P_prev - P).T))
                keep = lam > 1e-9 * lam.max()
                s = float(np.sqrt(max(0.0, np.sum((V[:, keep].T @ d) ** 2 / lam[keep]))))
            else:
                s = float(np.sqrt(d @ np.linalg.solve(P, d)))
            cur = cur + d * min(1.0, r / max(s, 1e-12))
        P_prev = P
        out.append(cur.copy())
    return out


VARIANTS = {"shipped": _shipped, "polyak": _polyak, "nosel": _nosel, "accept": _accept,
            "trust": _trust, "xtrust": lambda rf, data, r: _trust(rf, data, r, expected_change=True)}


def variant_curve(name: str, rf, data: list) -> list[np.ndarray]:
    """The theta acted on after each insertion k = 1..len(data), from data[:k] only (``name``: a key
    of VARIANTS, the trust regions with their radius appended, e.g. ``trust0.5``)."""
    base = name.rstrip("0123456789.")
    return VARIANTS[base](rf, data, float(name[len(base):] or 1.0))


def replay(store: Path, variants: list[str], per_tool: bool = False) -> None:
    from kinadapt_nn.config import load_config
    from kinadapt_nn.runs import insertions as ins

    files = sorted(store.glob("*.pkl"))
    for f in files:
        recs = pickle.load(open(f, "rb"))
        curves = {v: [] for v in ["closed loop", *variants]}
        for rec in recs:
            cfg = load_config(None, rec["overrides"])
            ctrl = ins.make_controller(cfg)
            cell = ins._Cell(cfg, ctrl)
            rf = cell.refit
            curves["closed loop"].append(rec["curve"])
            for v in variants:
                ths = variant_curve(v, rf, rec["data"])
                curves[v].append([cell.truth.median(ctrl, ctrl.theta0)] + [cell.truth.median(ctrl, t) for t in ths])
        print(f"== {f.stem}")
        for v, cs in curves.items():
            c = np.median(np.asarray(cs), axis=0)
            pairs = list(zip(c[1:], c[2:]))
            rise = max(b / a - 1 for a, b in pairs)
            fail = any(b / a - 1 > 0.02 and 100 * (b - a) > 0.01 for a, b in pairs)
            print(f"  {v:12s} {100 * c[0]:.3f} % -> " + " ".join(f"{100 * e:.3f}" for e in c[1:])
                  + f" %  rise {100 * rise:+.1f} %  (c) {'FAIL' if fail else 'ok'}", flush=True)
            for t, ct in enumerate(cs if per_tool else []):
                pt = list(zip(ct[1:], ct[2:]))
                r = max(b / a - 1 for a, b in pt)
                bad = any(b / a - 1 > 0.02 and 100 * (b - a) > 0.01 for a, b in pt)
                print(f"    tool {t}     {100 * ct[0]:.3f} % -> " + " ".join(f"{100 * e:.3f}" for e in ct[1:])
                      + f" %  rise {100 * r:+.1f} %  (c) {'FAIL' if bad else 'ok'}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("what", choices=["collect", "replay"])
    ap.add_argument("--seeds", type=int, nargs="+", default=[3000, 4000, 5000, 6000, 7000])
    ap.add_argument("--families", nargs="+", default=["arm_errors"])
    ap.add_argument("--features", nargs="+", default=["neural"])
    ap.add_argument("--store", default=str(ROOT / "runs" / "cell_replay"))
    ap.add_argument("--variants", nargs="+", default=["shipped", "polyak", "accept", "trust0.5", "xtrust1"])
    ap.add_argument("--per-tool", action="store_true", help="replay: each tool's curve too")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="collect: an online config override (e.g. cell.refit_step_sd=0: the loop without the trust region)")
    a = ap.parse_args()
    if a.what == "collect":
        for s in a.seeds:
            for fam in a.families:
                for feat in a.features:
                    collect(s, fam, feat, Path(a.store), a.set)
    else:
        replay(Path(a.store), a.variants, a.per_tool)


if __name__ == "__main__":
    main()
