"""What tells a turned mount from a joint encoder's zero offset in the monitor's end-of-run look (issue 53;
docs/monitor.md, "Agreement with the offline diagnosis").

    python benchmarks/monitor_encoder_rivals.py DIR [--effect ft_frame_rotation] [--seeds 0 1 2]

``DIR``: run folders kept by ``benchmarks/monitor_agreement.py --keep DIR`` (``EFFECT-SEED``, each with its
``trace.npz``; the diagnosis beside it, ``EFFECT-SEED-diagnosis-report``, is read for what it selected). Each run's encoders, rates and raw wrench are fed again, control period by control period,
to a fresh monitor (``Monitor.loop_step``, the flange kinematics from the controller's own chain, as the run
did; its live events are the run's). On the end-of-run look's rows of its open event (``Monitor.end_rows``)
it prints, in the look's own chi^2 (rows in the sd the event was named with):

* per channel, the chi^2 the best live shape and the best single joint's offset explain;
* for four forms of the offset -- one joint (the shape, as the library's one-of), every joint free at
  once, the force rows only (the moment rows left out), one joint with the tool's first moment free
  beside both (``tool_gravity``'s ``dmc`` columns: an offset about ``a`` is the mount turned about ``a``
  plus the first moment turned about ``a``, ``shapes``' docstring) -- the share of the best's explained chi^2 it
  explains (a near-tie needs ``shapes.TIE_RATIO``), the chi^2 the best adds beyond it against the best's
  ``k ln(rows)``, and what it adds beyond the best against its own (``shapes.ties``: either beyond its cost
  tells the two apart).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "benchmarks"))

from kinadapt_nn.monitor import kernel as K  # noqa: E402
from kinadapt_nn.monitor import shapes  # noqa: E402


def replay(run: Path):
    """A fresh monitor fed the run's trace (``Monitor.loop_step``), finished. -> the monitor."""
    from monitor_events import trace_kinematics

    from kinadapt_nn.config import load_config
    from kinadapt_nn.monitor.monitor import monitor_of_run

    cfg = load_config(run / "config.toml")
    cfg = cfg.model_copy(update={"run": cfg.run.model_copy(update={"progress": False})})
    tr = np.load(run / "trace.npz")
    inp, p_O, R, J = trace_kinematics(tr)
    mon = monitor_of_run(cfg)
    for k in range(len(inp)):
        mon.loop_step(float(tr["t_s"][k]), inp[k], R[k], p_O[k], J[k])
    mon.finish()
    return mon


def _pair(A1, P1, A2, P2, b, nuisance=None) -> tuple[float, float, float]:
    """(share of A1's explained chi^2 that A2 explains, chi^2 A1 adds beyond A2, chi^2 A2 adds beyond A1);
    ``nuisance`` (rows, z): columns fitted beside every one (a weak prior)."""
    N = np.zeros((len(b), 0)) if nuisance is None else nuisance
    PN = np.full(N.shape[1], 1.0)

    def misfit(*A) -> float:
        return shapes._misfit(np.hstack([N, *[a for a, _ in A]]), b, np.concatenate([PN, *[p for _, p in A]]))  # noqa: SLF001

    none, c1, c2, both = misfit(), misfit((A1, P1)), misfit((A2, P2)), misfit((A1, P1), (A2, P2))
    return (none - c2) / (none - c1), c2 - both, c1 - both


def rivals(mon, say) -> None:
    ev = next(e for e in mon.events if e.open and e.at_end)
    y, sd, slow_sd, fmask = mon.end_rows(ev)
    t0, tool = ev.onset_s, mon.tool
    best = shapes.end_look(y, sd, tool, t0, fmask, slow_sd=slow_sd)[0]
    enc = shapes.fit("encoder_offset", y, sd, tool, t0, fmask)
    e = y[:, K.G_E:K.G_E + 6] / sd
    none = np.sum(e ** 2, axis=0)
    for f in (best, enc):
        r = e - shapes.evaluate(f, y, tool, t0) / sd
        say(f"    {f.shape + (f' (joint {f.joint + 1})' if f.joint >= 0 else ''):27s} explains per channel "
            + " ".join(f"{c} {g:7.1f}" for c, g in zip(shapes.CHANNELS, none - np.sum(r ** 2, axis=0))))
    A1, b, P1 = shapes._target(best, y, sd, tool, t0, fmask)  # noqa: SLF001
    joints = shapes.encoder_joints(y)
    prior = 1.0 / shapes.prior_sd("encoder_offset") ** 2
    one = (shapes.columns("encoder_offset", y, tool, t0, enc.joint) / sd[None, :, None]).reshape(-1, 1)
    every = np.concatenate([shapes.columns("encoder_offset", y, tool, t0, j) for j in joints], axis=2)
    every = (every / sd[None, :, None]).reshape(-1, len(joints))
    force = np.tile([True] * 3 + [False] * 3, len(y))
    k1, ln_m, ln_f = A1.shape[1], np.log(len(b)), np.log(int(force.sum()))
    dmc = (shapes.columns("tool_gravity", y, tool, t0)[:, :, 1:] / sd[None, :, None]).reshape(-1, 3)
    forms = [("one joint", one, b, A1, ln_m, None), (f"every joint ({len(joints)})", every, b, A1, ln_m, None),
             ("one joint, force rows", one[force], b[force], A1[force], ln_f, None),
             ("one joint, tool's dmc free", one, b, A1, ln_m, dmc)]
    for name, A2, bb, AA1, lm, nuis in forms:
        share, beyond_best, beyond_enc = _pair(AA1, P1, A2, np.full(A2.shape[1], prior[0]), bb, nuis)
        say(f"    offset, {name:28s}: explains {share:.2f} of {best.shape}'s chi^2; {best.shape} adds {beyond_best:7.1f} "
            f"beyond it (its cost {k1 * lm:.1f}); it adds {beyond_enc:6.1f} beyond {best.shape} (its cost "
            f"{A2.shape[1] * lm:.1f})")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("keep", type=Path, help="run folders of monitor_agreement.py --keep")
    ap.add_argument("--effect", default="ft_frame_rotation", help="the runs' truth-side effect (folder prefix)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    a = ap.parse_args()
    import subprocess

    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True, text=True).stdout
    print(f"monitor_encoder_rivals: runs of {a.keep}, the monitor at HEAD {head.strip()}")
    for seed in a.seeds:
        mon = replay(a.keep / f"{a.effect}-{seed}")
        end = next(e for e in mon.events if e.open and e.at_end).at_end
        print(f"{a.effect} seed {seed}: end-of-run look {end['shape']}"
              + (f" or {' or '.join(end['ties'])}" if end["ties"] else ", no near-tie")
              + f" on {end['rows']} samples; encoder_offset joint {end['encoder_offset']['joint']}, "
              f"{end['encoder_offset']['offset_deg']:+.2f} deg, BIC {end['encoder_offset']['delta_bic']:+.1f} on the best's")
        rivals(mon, print)
        dia = a.keep / f"{a.effect}-{seed}-diagnosis-report" / "diagnosis.json"
        if dia.is_file():  # what the offline diagnosis of the same window selected, round by round
            import json

            sel = sorted((e for e in json.loads(dia.read_text())["ranking"] if e.get("selected_round") is not None),
                         key=lambda e: e["selected_round"])
            print("    the diagnosis selected: " + "; ".join(
                f"round {e['selected_round']}: {e['effect']} (explains {e['explained_fraction']:.2f}, {e['verdict']}"
                + (f", tied with {', '.join(e['indistinguishable_from'])}" if e.get("indistinguishable_from") else "") + ")"
                for e in sel))


if __name__ == "__main__":
    main()
