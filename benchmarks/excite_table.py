"""The excitation experiment's table on package runs, as a new user diagnoses them (issue 49).

    python benchmarks/excite_table.py [--seeds 5] [--jobs 2] [--json FILE] [--only TEXT] [--shift-wrench K] [--set KEY=VALUE]
    python benchmarks/excite_table.py --reprint FILE   (the rows of an earlier --json FILE, judged again)

Every run is ``kinadapt online --config online/excite.toml`` with a seed and hidden effects, then
``kinadapt diagnose RUN`` with **no** ``--baseline`` (the set-up generated from the run's config:
``ownrun.as_log``; the nominal tip a first guess, ``tip_known = false``). Rows:

* the effect-free run over ``--seeds`` seeds (start jitter +-0.5 mm, +-1 deg): right when nothing is
  present and the model is complete;
* each library effect alone at its default size and at twice it (twice the deviation: a stiffness
  factor 0.5 -> 0.25, a compliance doubled): right when it is present, every parameter's 95 %
  interval covers the injected value, and nothing else is present -- except ``tool_inertia``
  beside ``tool_gravity`` when the injected payload changes the inertia, whose value is then checked
  against the payload's (a 2 cm sphere at its COM, moved to the tool's COM: the parallel axes);
  ``tool_tilt`` is a tool whose tip is elsewhere: right when the diagnosis reports the tool's tip
  (``effective_setup.tool_tip``) with a 95 % interval covering the tilted tip, and no effect;
* three pairs (payload + sensor rotation, stiffness + friction couple, drift + encoder offset).

It prints one line per row: right or not, what was present, the largest coverage error in sd, and
for every row that is not right the measured reason and each judged estimate against the injected value.
``--shift-wrench K`` pairs each encoder sample with the wrench read K samples later: a timing offset
of K control periods between the encoders and the reading, which no library effect models (a
diagnostic of what such an offset does to a row; the simulator hands out one instant's encoders and
reading, ``sim.ft_sensor``, so K = 0 is the aligned log).
"""

from __future__ import annotations

import argparse
import json
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
EXCITE = REPO / "online" / "excite.toml"
QUIET = ["run.tensorboard=false", "run.figure=false", "run.progress=false"]
JITTER = ["start.lateral_jitter_m=0.0005", "start.tilt_jitter_deg=1.0"]
Z95 = 1.96

#: twice each effect's default size (config overrides)
TWICE = {
    "tool_gravity": ["effects.tool_gravity.mass_kg=1.0"],
    "ft_bias_drift": ["effects.ft_bias_drift.rate_f=[0.4,0,0,0,0,0]"],
    "ft_frame_rotation": ["effects.ft_frame_rotation.rotvec_deg=[2.82,0,2.82]"],
    "tool_tilt": ["effects.tool_tilt.tilt_deg=[4.0,0.0]"],
    "contact_stiffness": ["effects.contact_stiffness.factor=0.25"],
    "contact_friction_couple": ["effects.contact_friction_couple.radius_m=0.01"],
    "grasp_compliance": ["effects.grasp_compliance.stiffness_Nm_per_rad=100.0"],
    "encoder_offset": ["effects.encoder_offset.offset_deg=1.0"],
}
PAIRS = (("tool_gravity", "ft_frame_rotation"), ("contact_stiffness", "contact_friction_couple"),
         ("ft_bias_drift", "encoder_offset"))


def tool_first_moment_error(cfg) -> np.ndarray:
    """(3,) [kg m] the true peg's first moment minus the declared one's (the set-up puts the peg on
    the nominal axis, ``ownrun``; the true peg ends at the true tip)."""
    t = cfg.tool
    tip_nom = np.asarray(cfg.sensing.nominal_offset_f_m, dtype=float)
    c_nom = tip_nom - 0.5 * t.length_m * tip_nom / np.linalg.norm(tip_nom)
    from kinadapt_nn.sim.effects import truth_config
    from kinadapt_nn.geometry import tilt_rotation
    tt = truth_config(cfg).tool
    c_true = np.asarray(tt.offset_f_m) - 0.5 * t.length_m * tilt_rotation(tt.tilt_deg)[:, 2]
    return t.mass_kg * (c_true - c_nom)


def _inertia_about_O(mass: float, c_f: np.ndarray, I_c_f: np.ndarray) -> np.ndarray:
    """[Ixx, Iyy, Izz, Ixy, Ixz, Iyz] [kg m^2] of a body (its COM ``c_f``, inertia ``I_c_f`` (3, 3) about
    the COM, axes of f) about the sensor origin O: the parallel axes."""
    I = I_c_f + mass * (c_f @ c_f * np.eye(3) - np.outer(c_f, c_f))
    return np.array([I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]])


def tool_inertia_error(cfg) -> np.ndarray:
    """(6,) [kg m^2] the true peg's inertia about O minus the declared one's (``tool_inertia``'s
    parameters): the true peg is tilted and ends at the true tip (``sim.scene``: a box about its centre),
    the declared one lies on the nominal axis (``diagnostics.ownrun``) -- the inertia's share of the
    3.6 mm offset that ``tool_first_moment_error`` counts in ``tool_gravity``."""
    from kinadapt_nn.diagnostics.ownrun import setup_of_run
    from kinadapt_nn.geometry import tilt_rotation
    from kinadapt_nn.sim.effects import truth_config

    t, tt = cfg.tool, truth_config(cfg).tool
    R = tilt_rotation(tt.tilt_deg)
    a, L = t.side_m, t.length_m
    I_c = R @ np.diag(t.mass_kg / 12.0 * np.array([a * a + L * L, a * a + L * L, 2 * a * a])) @ R.T
    c_true = np.asarray(tt.offset_f_m, dtype=float) - 0.5 * L * R[:, 2]
    d = setup_of_run(cfg).tool
    xx, yy, zz, xy, xz, yz = d.inertia_com_kg_m2
    I_nom = np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])
    return (_inertia_about_O(t.mass_kg, c_true, I_c)
            - _inertia_about_O(d.mass_kg, np.asarray(d.com_sensor_m, dtype=float), I_nom))


def _truth(name: str, cfg) -> np.ndarray:
    """The injected value in the effect's parameters (``effect_library.DEFAULTS``: one convention on both
    model sides since issue 52 -- the drift of the tool's wrench on the sensor, one offset per joint)."""
    from kinadapt_nn.features.effect_library import LIBRARY

    effects = cfg.effects
    p = np.asarray(LIBRARY[name].default(effects), dtype=float)
    if name == "tool_gravity":  # against the declared tool: the peg's own first moment is off by its offset too
        p = p.copy()
        p[1:] += tool_first_moment_error(cfg)
    return p


def _payload_inertia(cfg) -> np.ndarray:
    """[dIxx, dIyy, dIzz, dIxy, dIxz, dIyz] [kg m^2] the payload adds to the tool's inertia about the
    sensor origin (``tool_inertia``'s parameters): its own (a 2 cm solid sphere, ``sim.scene``) and
    ``m (|c|^2 1 - c c^T)`` of its mass at its COM ``c``."""
    g = cfg.effects.tool_gravity
    return _inertia_about_O(g.mass_kg, np.asarray(g.com_f_m, dtype=float), 0.4 * g.mass_kg * 0.02 ** 2 * np.eye(3))


def run_one(job: tuple) -> dict:
    """One run and its diagnosis. job = (row name, overrides, injected effect names)."""
    from kinadapt_nn.config import load_config
    from kinadapt_nn.diagnostics import ownrun, userlog
    from kinadapt_nn.diagnostics.importers import RawLog
    from kinadapt_nn.runs.episode import run_episode

    name, sets, injected, shift = (*job, 0) if len(job) == 3 else job
    cfg = load_config(EXCITE, [*QUIET, *sets])
    tr = run_episode(cfg).trace
    t, q, qd, w = (np.asarray(tr[k]) for k in ("t_s", "q_rad", "qdot_rad_s", "wrench_raw_f"))
    if shift:  # encoder sample k with the reading of sample k + shift
        t, q, qd, w = t[:-shift], q[:-shift], qd[:-shift], w[shift:]
    raw = RawLog(t, q, qd, w, name)
    seen = cfg.model_copy(update={"effects": type(cfg.effects)()})  # the diagnosis does not know them
    log, setup = ownrun.as_log(raw, seen)
    from kinadapt_nn.diagnostics.report import thaw

    report = userlog.diagnose(log, setup, hints=True).report
    rep = {**thaw(report.sections), "summary": report.summary}  # plain dicts and lists (JSON, the pool)
    out = {"row": name, "sets": sets, "injected": list(injected),
           "present": [e["effect"] for e in rep["ranking"] if e["verdict"] == "present"],
           "model_complete": rep.get("model_complete"), "blocked": rep.get("blocked"),
           "summary": rep["summary"], "coverage": {}, "tool_tip": rep["effective_setup"].get("tool_tip")}
    for n in injected:
        e = next((x for x in rep["ranking"] if x["effect"] == n), None)
        if n == "tool_tilt":  # the tip, from the tilted tool: R(tilt) applied to the true offset
            from kinadapt_nn.geometry import tilt_rotation
            tip_true = tilt_rotation(cfg.effects.tool_tilt.tilt_deg) @ np.asarray(cfg.tool.offset_f_m)
            tt = out["tool_tip"]
            if tt:
                z = (np.asarray(tt["tip_sensor_m"]) - tip_true) / np.maximum(np.asarray(tt["sd_m"]), 1e-12)
                out["coverage"][n] = {"z": [float(v) for v in z], "truth": tip_true.tolist(), "est": tt["tip_sensor_m"]}
            continue
        if e is None or "estimate_params" not in e:
            continue
        ep = e["estimate_params"]
        truth = _truth(n, cfg)
        val, sd = np.asarray(ep["value"], float), np.asarray(ep["sd"], float)
        keep = sd > 0
        z = np.where(keep, (val - truth[:len(val)]) / np.where(keep, sd, 1.0), 0.0)
        out["coverage"][n] = {"z": [float(v) for v in z], "truth": truth.tolist(), "est": val.tolist(),
                              "sd": sd.tolist(), "names": ep["names"]}
    if "tool_gravity" in injected and "tool_inertia" in out["present"]:
        e = next(x for x in rep["ranking"] if x["effect"] == "tool_inertia")
        ep = e["estimate_params"]
        truth = _payload_inertia(cfg) + tool_inertia_error(cfg)
        val, sd = np.asarray(ep["value"], float), np.asarray(ep["sd"], float)
        out["coverage"]["tool_inertia"] = {"z": [float(v) for v in (val - truth) / np.maximum(sd, 1e-15)],
                                           "truth": truth.tolist(), "est": val.tolist()}
    return out


def judge(r: dict) -> tuple[bool, str]:
    """(right, the reason when not)."""
    inj = set(r["injected"]) - {"tool_tilt"}
    allowed = set(inj) | ({"tool_inertia"} if "tool_gravity" in inj else set())
    why = []
    if r["blocked"]:
        why.append(f"blocked: {r['blocked']}")
    missing = inj - set(r["present"])
    extra = set(r["present"]) - allowed
    if missing:
        why.append("not present: " + ", ".join(sorted(missing)))
    if extra:
        why.append("also present: " + ", ".join(sorted(extra)))
    for n, c in r["coverage"].items():
        bad = [i for i, z in enumerate(c["z"]) if abs(z) > Z95]
        if bad and (n in r["present"] or n == "tool_tilt"):
            names = c.get("names") or [f"p{i}" for i in range(len(c["z"]))]
            why.append(f"{n}: the 95 % interval misses the injected value ("
                       + ", ".join(f"{names[i]} {c['z'][i]:+.1f} sd" for i in bad) + ")")
    if "tool_tilt" in r["injected"] and not r["tool_tip"]:
        why.append("tool_tilt: no tool tip reported")
    if not r["injected"] and r["model_complete"] is False:
        why.append("the model is reported incomplete")
    return not why, "; ".join(why)


def intervals(results: list[dict]) -> tuple[int, int]:
    """(intervals judged, intervals that miss the injected value at 95 %) over the rows: each parameter of
    a present effect (and of ``tool_tilt``) whose sd is positive, as ``judge`` reads them."""
    judged = missed = 0
    for r in results:
        for n, c in r["coverage"].items():
            if n not in r["present"] and n != "tool_tilt":
                continue
            sds = c.get("sd") or [1.0] * len(c["z"])
            for z, sd in zip(c["z"], sds):
                if sd and sd > 0:
                    judged += 1
                    missed += abs(z) > Z95
    return judged, missed


def jobs(seeds: int) -> list[tuple]:
    out = [(f"none/seed{s}", [f"run.seed={s}", *JITTER], ()) for s in range(seeds)]
    for n, twice in TWICE.items():
        out.append((f"{n}/default", [f"effects.{n}.enabled=true"], (n,)))
        out.append((f"{n}/twice", [f"effects.{n}.enabled=true", *twice], (n,)))
    for a, b in PAIRS:
        out.append((f"{a}+{b}", [f"effects.{a}.enabled=true", f"effects.{b}.enabled=true"], (a, b)))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--only", default="", help="rows whose name contains this")
    ap.add_argument("--json", default="", help="write every row's result here")
    ap.add_argument("--shift-wrench", type=int, default=0,
                    help="pair each encoder sample with the wrench read K samples later (module docstring)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a config override added to every row (after the row's own), e.g. scene.socket_damping_ratio=0")
    ap.add_argument("--reprint", default="", metavar="JSON",
                    help="judge and print the rows a --json FILE of an earlier run holds (no runs)")
    a = ap.parse_args()
    if a.reprint:
        results = [r for r in json.loads(Path(a.reprint).read_text()) if a.only in r["row"]]
    else:
        todo = [(name, [*ov, *a.set], inj, a.shift_wrench) for name, ov, inj in jobs(a.seeds) if a.only in name]
        with ProcessPoolExecutor(max_workers=a.jobs) as ex:
            results = list(ex.map(run_one, todo))
    n_ok = 0
    for r in results:
        ok, why = judge(r)
        n_ok += ok
        worst = max((abs(z) for c in r["coverage"].values() for z in c["z"]), default=0.0)
        print(f"{'right' if ok else 'WRONG'}  {r['row']:<44} present: {', '.join(r['present']) or '-':<40} "
              f"complete: {r['model_complete']}  worst |z| {worst:.1f}" + (f"\n       why: {why}" if why else ""))
        if not r["injected"] and r.get("tool_tip"):  # the tool's own finding: its tip, fitted beside the effects
            tt = r["tool_tip"]
            print("       tool tip [" + ", ".join(f"{1e3 * v:.2f}" for v in tt["tip_sensor_m"]) + "] +- ["
                  + ", ".join(f"{1e3 * v:.2g}" for v in tt["sd_m"]) + "] mm (the true tool's: 3, -2, 100)")
        if why:
            for n, c in r["coverage"].items():
                names = c.get("names") or [f"p{i}" for i in range(len(c["z"]))]
                sds = c.get("sd") or [float("nan")] * len(c["z"])
                print(f"       {n}: " + ", ".join(f"{names[i]} {c['est'][i]:.4g} +- {sds[i]:.2g} (injected {c['truth'][i]:.4g})"
                                            for i in range(len(c["z"]))))
    print(f"{n_ok}/{len(results)} rows right")
    judged, missed = intervals(results)
    print(f"{judged} parameter intervals judged (the present effects' and tool_tilt's, sd > 0), {missed} miss at 95 %; "
          f"a calibrated diagnosis misses {0.05 * judged:.1f} on average and covers all {judged} in "
          f"{100 * 0.95 ** judged:.1f} % of tables")
    if a.json:
        Path(a.json).write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
