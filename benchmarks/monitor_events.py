"""The live monitor on the five onset scenarios, clean runs and its costs (issue 53; docs/monitor.md).

    python benchmarks/monitor_events.py [--seeds 20] [--clean 20] [--save benchmarks/results/monitor_events.txt]

Scenarios (``online/monitor.toml``: free-space reorientations with sensor noise 0.02 N / 0.002 N m,
the model frozen): each truth-side effect at its default size (``kinadapt config``), its onset
drawn uniformly in [1, 4] s per seed (``run.seed`` seeds the onset and the sensor noise).

* detected: an event at or after the onset (an event before it is a false alarm);
* delay: the first such event's time (its alarm) minus when the effect reaches its relevant size -- the
  onset (plus the ramp) for a step (the frame rotation's 2 deg are above its relevant 1 deg at once); for
  the drift, when it reaches 3 noise sd of its largest channel; named after: when the event was named
  (printed with its shape and estimate, ``t_first_named_s``) minus the same time;
* named: the event's shape is the effect's (the grasp slip reads as the library's ``tool_tilt``);
* covered: the event's 95 % region covers the truth (the payload's mass and the drift's rate on its
  channel: intervals; the snag's world force, the sensor's rotation vector and the slip's two angles:
  ellipsoids at the chi^2 95 % quantile).

Control (``--bias-step``, not a target): a sensor bias step of 0.03 N in F_y (``faults.ft_bias_N``), what
the first event after it is named.

False alarms: events in clean runs of ``online/rollout.toml`` (the default) and ``online/excite.toml``
(34.4 s), each with the same sensor noise, ``--clean`` seeds each.

Costs: the monitor's kernel per control period (median and p99 of single calls on a run's samples),
an episode's wall with ``monitor.enabled`` over without (median of 5 each, warm), and ``--follow``
on a CSV of a run (samples per second of one core).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import kinadapt_nn.monitor.monitor  # noqa: E402,F401  (registers the live monitor with the episode loop)
from kinadapt_nn.config import load_config  # noqa: E402
from kinadapt_nn.runs.episode import run_episode  # noqa: E402

NOISE = ["faults.ft_noise_N=0.02", "faults.ft_noise_Nm=0.002"]
#: scenario -> (effect key, the shape that names it)
SCENARIOS = {"payload": ("tool_gravity", "tool_gravity"), "drift": ("ft_bias_drift", "ft_bias_drift"),
             "frame rotation": ("ft_frame_rotation", "ft_frame_rotation"), "snag": ("world_force", "world_force"),
             "slip": ("grasp_slip", "tool_tilt")}


#: --set overrides applied to every run (e.g. monitor.rotation_test=true)
SETS: list[str] = []


def _cfg(path: str, extra: list[str]):
    return load_config(REPO / path, ["run.progress=false", "run.tensorboard=false", "run.figure=false", *extra, *SETS])


def relevant_time(cfg, onset: float) -> float:
    """When the effect reaches its relevant size (module docstring)."""
    e = cfg.effects
    if e.ft_bias_drift.enabled:
        rate = np.abs(np.asarray(e.ft_bias_drift.rate_f))
        i = int(np.argmax(rate))
        sd = cfg.faults.ft_noise_N if i < 3 else cfg.faults.ft_noise_Nm
        return onset + 3.0 * sd / rate[i]
    for name in ("tool_gravity", "ft_frame_rotation", "world_force", "grasp_slip"):
        sub = getattr(e, name)
        if sub.enabled:
            return onset + getattr(sub, "ramp_s", 0.0)
    return onset


def _inside(x, truth, cov, q: float) -> bool:
    """``truth`` within the estimate's 95 % region: (x - truth)^T cov^-1 (x - truth) <= q."""
    d = np.asarray(x, dtype=float) - np.asarray(truth, dtype=float)
    return float(d @ np.linalg.solve(np.asarray(cov, dtype=float), d)) <= q


#: chi^2 quantiles at 95 % for 1, 2, 3 degrees of freedom
Q95 = {1: 3.841, 2: 5.991, 3: 7.815}


def covered(cfg, ev: dict) -> bool:
    """The event's 95 % region covers the truth (module docstring): the payload's mass, the drift's
    rate on its channel (intervals); the snag's force (world), the rotation vector, the slip's two
    angles (ellipsoids, chi^2 at 95 %)."""
    e, est = cfg.effects, ev["estimate"]
    if ev["shape"] == "tool_gravity" and e.tool_gravity.enabled:
        return _inside([est["mass_kg"]], [e.tool_gravity.mass_kg], [[est["mass_sd_kg"] ** 2]], Q95[1])
    if ev["shape"] == "world_force" and e.world_force.enabled:
        return _inside(est["force_w_N"], e.world_force.force_w_N, est["force_cov_w_N2"], Q95[3])
    if ev["shape"] == "ft_bias_drift" and e.ft_bias_drift.enabled:
        rate = np.asarray(e.ft_bias_drift.rate_f)
        i = int(np.argmax(np.abs(rate)))
        return _inside([est["rate_s"][i]], [rate[i]], [[est["rate_sd_s"][i] ** 2]], Q95[1])
    if ev["shape"] == "ft_frame_rotation" and e.ft_frame_rotation.enabled:
        return _inside(est["rotvec_deg"], e.ft_frame_rotation.rotvec_deg, est["rotvec_cov_deg2"], Q95[3])
    if ev["shape"] == "tool_tilt" and e.grasp_slip.enabled:
        return _inside(est["tilt_deg"], e.grasp_slip.slip_deg, est["tilt_cov_deg2"], Q95[2])
    return False


def scenario(name: str, seeds: int, first_seed: int = 0) -> dict:
    effect, shape = SCENARIOS[name]
    rows = []
    for seed in range(first_seed, first_seed + seeds):
        onset = float(np.random.default_rng(seed).uniform(1.0, 4.0))
        cfg = _cfg("online/monitor.toml", [f"run.seed={seed}", f"effects.{effect}.enabled=true",
                                           f"effects.{effect}.onset_s={onset}"])
        res = run_episode(cfg)
        evs = res.summary["monitor"]["events"]
        alarms = [x for x in res.summary["monitor"].get("alarms", []) if x["t_s"] >= onset]
        bound = np.nan
        if effect == "ft_frame_rotation":  # the largest change a turn by |delta| makes: |r| |delta| (force, moment) in noise sd
            w = res.trace["wrench_raw_f"]
            d = np.deg2rad(np.linalg.norm(cfg.effects.ft_frame_rotation.rotvec_deg))
            bound = (float(np.linalg.norm(w[:, :3], axis=1).max() * d / cfg.faults.ft_noise_N),
                     float(np.linalg.norm(w[:, 3:], axis=1).max() * d / cfg.faults.ft_noise_Nm))
        early = [e for e in evs if e["t_s"] < onset]
        after = [e for e in evs if e["t_s"] >= onset]
        first = after[0] if after else None
        rows.append(dict(onset=onset, early=len(early), detected=first is not None,
                         delay=first["t_s"] - relevant_time(cfg, onset) if first else np.nan,
                         named_after=first["t_first_named_s"] - relevant_time(cfg, onset) if first else np.nan,
                         named=bool(first and first["shape"] == shape), covered=bool(first and covered(cfg, first)),
                         line=first["line"] if first else "-",
                         alarm=alarms[0]["t_s"] - relevant_time(cfg, onset) if alarms else np.nan,
                         outcome=alarms[0]["outcome"] if alarms else "-",
                alarm_shape=alarms[0]["shape"] if alarms else "-", bound=bound))
    return dict(name=name, rows=rows)


def bias_step(seeds: int, size_N: float = 0.03, first_seed: int = 0) -> dict:
    """A sensor bias step of ``size_N`` in F_y at a random time (``faults.ft_bias_N``, ``bias_onset_s``; a
    control, not a target): the first event after it -> {shape: runs}."""
    out: dict = {}
    for seed in range(first_seed, first_seed + seeds):
        onset = float(np.random.default_rng(seed).uniform(1.0, 4.0))
        cfg = _cfg("online/monitor.toml", [f"run.seed={seed}", f"faults.ft_bias_N=[0,{size_N},0]",
                                           f"faults.bias_onset_s={onset}"])
        evs = [e for e in run_episode(cfg).summary["monitor"]["events"] if e["t_s"] >= onset]
        key = evs[0]["shape"] if evs else "none"
        out[key] = out.get(key, 0) + 1
    return out


def clean_alarms(path: str, seeds: int) -> tuple[int, int, float, int]:
    """(runs with an event, events, simulated seconds watched, alarms of any outcome)."""
    runs = events = alarms = 0
    sim = 0.0
    for seed in range(seeds):
        r = run_episode(_cfg(path, [f"run.seed={seed}", "monitor.enabled=true", *NOISE]))
        n = len(r.summary["monitor"]["events"])
        runs += n > 0
        events += n
        alarms += len(r.summary["monitor"].get("alarms", []))
        sim += float(r.trace["t_s"][-1])
    return runs, events, sim, alarms


def trace_kinematics(tr) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A run's trace as the monitor's loop got it: (inp (N, 2n+6) [q; qdot; raw wrench], p_O (N, 3), R_wf
    (N, 3, 3), J (N, 6, n)) -- the controller's own flange kinematics (``core.fk_batch``) from the logged
    encoders."""
    import mujoco

    from kinadapt_nn.controller import core
    from kinadapt_nn.robot import FLANGE_SITE

    arm = mujoco.MjModel.from_xml_path(str(REPO / "models" / "panda.xml"))
    chain = core.arm_chain(arm, mujoco.mj_name2id(arm, mujoco.mjtObj.mjOBJ_SITE, FLANGE_SITE))
    q, qd, w = tr["q_rad"], tr["qdot_rad_s"], tr["wrench_raw_f"]
    N, n = len(q), q.shape[1]
    inp = np.concatenate([q, qd, w], axis=1)
    p_O, R, J = np.zeros((N, 3)), np.zeros((N, 3, 3)), np.zeros((N, 6, n))
    core.fk_batch(chain, inp, p_O, R, J)
    return inp, p_O, R, J


def kernel_cost(reps: int = 3) -> tuple[float, float]:
    """Median and p99 [us] of one ``Monitor.loop_step`` call on a run's control periods (the
    controller's flange kinematics recomputed for each from the logged encoders, outside the timing)."""
    from kinadapt_nn.monitor.monitor import monitor_of_run

    cfg = _cfg("online/monitor.toml", ["effects.world_force.enabled=true", "effects.world_force.onset_s=3"])
    tr = run_episode(cfg).trace
    inp, p_O, R, J = trace_kinematics(tr)
    N = len(inp)
    times = []
    for _ in range(reps):
        mon = monitor_of_run(cfg.model_copy(update={"run": cfg.run.model_copy(update={"progress": False})}))
        t = tr["t_s"]
        mon.loop_step(float(t[0]), inp[0], R[0], p_O[0], J[0])  # compiled / loaded first
        ns = np.empty(N - 1)
        for k in range(1, N):
            a = time.perf_counter_ns()
            mon.loop_step(float(t[k]), inp[k], R[k], p_O[k], J[k])
            ns[k - 1] = time.perf_counter_ns() - a
        times.append(ns)
    ns = np.concatenate(times)
    return float(np.median(ns)) / 1e3, float(np.percentile(ns, 99)) / 1e3


def step_latency_us(monitor: bool) -> tuple[float, float]:
    """p50 and p99 [us] of one control period in a closed loop on ``online/monitor.toml`` with a snag at
    3 s: ``Controller.step`` and, with ``monitor``, the monitor's ``loop_step`` on the controller's own
    input row and flange kinematics (what the episode loop hands it); sensor I/O and physics excluded."""
    from kinadapt_nn.monitor.monitor import monitor_of_run
    from kinadapt_nn.runs.build import make_controller
    from kinadapt_nn.sim.adapter import PegInHoleSim

    cfg = _cfg("online/monitor.toml", ["effects.world_force.enabled=true", "effects.world_force.onset_s=3"])
    sim, ctrl = PegInHoleSim(cfg), make_controller(cfg)
    ctrl.compile_kernels()
    mon = monitor_of_run(cfg)
    n = int(round(cfg.run.duration_s / cfg.run.dt_s))
    lat = np.empty(n)
    obs = sim.sense()
    inp, R, p, J = ctrl._inp[0], ctrl._R[0], ctrl._p_O[0], ctrl._J[0]  # noqa: SLF001  (the controller's buffers)
    for k in range(n):
        t = sim.time_s
        a = time.perf_counter()
        cmd = ctrl.step(t, obs.q_rad, obs.qdot_rad_s, obs.wrench_raw_f)
        if monitor:
            mon.loop_step(t, inp, R, p, J)
        lat[k] = time.perf_counter() - a
        sim.apply(cmd.q_ref_rad, cmd.qdot_ref_rad_s)
        sim.step()
        obs = sim.sense()
    lat = lat[100:] * 1e6  # (the first steps compile or load the kernels)
    return float(np.percentile(lat, 50)), float(np.percentile(lat, 99))


def wall_ratio(reps: int = 5) -> tuple[float, float]:
    """An episode's wall [s] without and with the monitor (medians, warm)."""
    walls = {False: [], True: []}
    for on in (False, True, False, True):  # warm both first
        run_episode(_cfg("online/monitor.toml", [f"monitor.enabled={str(on).lower()}"]))
    for _ in range(reps):
        for on in (False, True):
            a = time.perf_counter()
            run_episode(_cfg("online/monitor.toml", [f"monitor.enabled={str(on).lower()}"]))
            walls[on].append(time.perf_counter() - a)
    return float(np.median(walls[False])), float(np.median(walls[True]))


def follow_rate() -> float | None:
    """Samples per CPU second of ``kinadapt diagnose --follow`` replaying a run's CSV (None: no follow)."""
    try:
        from kinadapt_nn.monitor.follow import benchmark_follow
    except ImportError:
        return None
    return benchmark_follow(REPO)


def costs(say) -> None:
    med, p99 = kernel_cost()
    say(f"monitor per control period: median {med:.2f} us, p99 {p99:.2f} us (Monitor.loop_step)")
    c50, c99 = step_latency_us(False)
    m50, m99 = step_latency_us(True)
    say(f"control period, closed loop: controller p50 {c50:.1f} us, p99 {c99:.1f} us; controller + monitor p50 "
        f"{m50:.1f} us, p99 {m99:.1f} us")
    w0, w1 = wall_ratio()
    say(f"episode wall (online/monitor.toml, 6 s): {w0:.3f} s without, {w1:.3f} s with the monitor: {w1 / w0:.2f}x")
    fr = follow_rate()
    if fr is not None:
        say(f"--follow: {fr:.0f} samples per CPU second ({fr / 1000:.1f}x a 1 kHz log on one core)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20, help="seeds per scenario")
    ap.add_argument("--first-seed", type=int, default=0, metavar="N",
                    help="the scenarios' and the control's seeds are N, N+1, ... (default 0; the clean runs keep 0, 1, ...)")
    ap.add_argument("--clean", type=int, default=20, help="clean runs of each configuration")
    ap.add_argument("--save", type=Path, default=None, help="also write the table to this file")
    ap.add_argument("--lines", action="store_true", help="print each run's event line")
    ap.add_argument("--costs-only", action="store_true", help="only the costs (no scenarios, no clean runs)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="a config override for every run")
    ap.add_argument("--only", action="append", default=[], choices=list(SCENARIOS), help="only these scenarios")
    ap.add_argument("--bias-step", type=int, default=0, metavar="SEEDS",
                    help="also a control: a 0.03 N sensor bias step in F_y, what its first event is named (SEEDS runs)")
    ap.add_argument("--no-clean", action="store_true", help="skip the clean runs and the costs (while iterating)")
    a = ap.parse_args()
    SETS.extend(a.set)
    out = []
    say = lambda s="": (print(s, flush=True), out.append(s))  # noqa: E731
    if a.costs_only:
        costs(say)
        if a.save:
            a.save.parent.mkdir(parents=True, exist_ok=True)
            a.save.write_text("\n".join(out) + "\n")
        return
    say(f"monitor_events: {a.seeds} seeds per scenario"
        + (f" ({a.first_seed}-{a.first_seed + a.seeds - 1})" if a.first_seed else "")
        + ", onset uniform in [1, 4] s, online/monitor.toml"
        + (f" (--set {' '.join(a.set)})" if a.set else ""))
    say(f"{'scenario':<16}{'detected':>10}{'delay med [s]':>15}{'delay max [s]':>15}{'named':>8}{'covered':>9}"
        f"{'early':>7}{'named after med [s]':>21}")
    for name in a.only or SCENARIOS:
        r = scenario(name, a.seeds, a.first_seed)["rows"]
        d = np.array([x["delay"] for x in r])
        det = int(sum(x["detected"] for x in r))
        say(f"{name:<16}{det:>7}/{len(r):<2}{np.nanmedian(d) if det else np.nan:>15.3f}"
            f"{np.nanmax(d) if det else np.nan:>15.3f}{sum(x['named'] for x in r):>5}/{len(r):<2}"
            f"{sum(x['covered'] for x in r):>6}/{len(r):<2}{sum(x['early'] for x in r):>7}"
            f"{np.nanmedian([x['named_after'] for x in r]) if det else np.nan:>21.3f}")
        al = np.array([x["alarm"] for x in r])
        if np.isfinite(al).any():
            outs = sorted({x["outcome"] for x in r if x["outcome"] != "-"})
            shp = sorted({x["alarm_shape"] for x in r if x["outcome"] != "-"})
            say(f"    first alarm after the onset (any outcome): {int(np.isfinite(al).sum())}/{len(r)}, delay median "
                f"{np.nanmedian(al):.3f} s, max {np.nanmax(al):.3f} s; outcomes: "
                + ", ".join(f"{o} {sum(x['outcome'] == o for x in r)}" for o in outs) + "; best shapes: "
                + ", ".join(f"{o} {sum(x['alarm_shape'] == o for x in r)}" for o in shp))
        if name == "frame rotation":
            bf = max(x["bound"][0] for x in r)
            bm = max(x["bound"][1] for x in r)
            say(f"    the largest change the turn can make, |r| |delta| / noise sd over the runs: force {bf:.2f}, "
                f"moment {bm:.2f}")
        if a.lines:
            for x in r:
                say(f"    onset {x['onset']:.2f} s: {x['line']}")
    if a.bias_step:
        shp = bias_step(a.bias_step, first_seed=a.first_seed)
        say(f"control, a sensor bias step of 0.03 N in F_y ({a.bias_step} runs): first event named "
            + ", ".join(f"{k} {v}" for k, v in sorted(shp.items())))
    if a.no_clean:
        if a.save:
            a.save.parent.mkdir(parents=True, exist_ok=True)
            a.save.write_text("\n".join(out) + "\n")
        return
    for label, path in (("default (rollout.toml)", "online/rollout.toml"), ("excite (excite.toml)", "online/excite.toml")):
        runs, evs, sim, als = clean_alarms(path, a.clean)
        say(f"clean {label:<24} {a.clean} runs, {sim:.0f} s watched: {runs} with an alarm ({evs} events; "
            f"{als} alarms of any outcome)")
    costs(say)
    if a.save:
        a.save.parent.mkdir(parents=True, exist_ok=True)
        a.save.write_text("\n".join(out) + "\n")


if __name__ == "__main__":
    main()
