"""The live monitor (``kinadapt_nn.monitor``): its model against the simulated sensor, its test's
false-alarm rate against a simulation, the events of onset scenarios against their truth, the
``--follow`` reader on bad input, and the command line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from kinadapt_nn.app.cli import main
from kinadapt_nn.config import MonitorCfg, load_config
from kinadapt_nn.diagnostics.ownrun import setup_of_run
from kinadapt_nn.monitor import kernel as K
from kinadapt_nn.monitor.follow import Follower, csv_text
from kinadapt_nn.monitor.monitor import Monitor
from kinadapt_nn.runs.episode import run_episode

REPO = Path(__file__).resolve().parents[2]
QUIET = ["run.progress=false"]


def _run(extra, path="online/monitor.toml"):
    cfg = load_config(REPO / path, QUIET + extra)
    return cfg, run_episode(cfg)


@pytest.fixture(scope="module")
def snag():
    return _run(["effects.world_force.enabled=true", "effects.world_force.onset_s=2.0"])


def test_threshold_gives_the_documented_run_length():
    """Siegmund's approximation, as ``threshold`` solves it, against a simulated one-sided CUSUM on white
    noise: 12 false alarms an hour of 1 s samples on one test is a mean run length of 300 samples."""
    k = 0.5
    h = K.threshold(12.0, k, 1.0, sides=1)
    rng = np.random.default_rng(0)
    n, steps = 4000, 6000
    g = np.zeros(n)
    stop = np.full(n, steps)
    for i in range(steps):
        g = np.maximum(0.0, g + rng.standard_normal(n) - k)
        hit = (g > h) & (stop == steps)
        stop[hit] = i + 1
    assert np.all(stop < steps)
    assert abs(stop.mean() / 300.0 - 1.0) < 0.1, stop.mean()


def test_model_matches_the_simulated_sensor_on_a_clean_run():
    """Noise-free, no hidden effect: the declared tool's Newton-Euler wrench from the encoders is the
    simulator's reading up to the declared tool's own error -- its centre of mass is on the nominal axis,
    the true one (tool.offset_f_m) 3.6 mm beside it, a moment of at most m g |dc|."""
    cfg, r = _run(["faults.ft_noise_N=0", "faults.ft_noise_Nm=0"])
    res = r.trace["monitor_residual"]
    assert np.isfinite(res).sum() > 0.8 * res.size
    dc = 0.5 * np.linalg.norm(np.asarray(cfg.tool.offset_f_m[:2]))  # the peg's centre: half way to the tip
    assert np.nanmax(np.abs(res[:, :3])) < 2e-3
    assert np.nanmax(np.abs(res[:, 3:])) < cfg.tool.mass_kg * 9.81 * 2 * dc + 5e-4
    assert r.summary["monitor"]["events"] == []


@pytest.mark.parametrize("path, seed", [("online/monitor.toml", 1), ("online/rollout.toml", 0)])
def test_no_event_on_a_clean_run(path, seed):
    _cfg, r = _run([f"run.seed={seed}", "monitor.enabled=true", "faults.ft_noise_N=0.02",
                    "faults.ft_noise_Nm=0.002"], path)
    mon = r.summary["monitor"]
    assert mon["events"] == []
    np.testing.assert_allclose(mon["noise_sd"][:3], 0.02, rtol=0.3)  # the sensor's noise, measured at rest
    np.testing.assert_allclose(mon["noise_sd"][3:], 0.002, rtol=0.3)


def test_snag_is_caught_named_and_measured(snag):
    cfg, r = snag
    evs = r.summary["monitor"]["events"]
    assert len(evs) == 1, [e["line"] for e in evs]
    e = evs[0]
    assert e["shape"] == "world_force" and e["phase"] == "free space" and e["open"]
    assert 2.0 <= e["t_s"] <= 2.01 and "F_y" in e["channels"]
    d = np.asarray(e["estimate"]["force_w_N"]) - np.asarray(cfg.effects.world_force.force_w_N)
    assert d @ np.linalg.solve(np.asarray(e["estimate"]["force_cov_w_N2"]), d) <= 7.815  # chi^2_3 at 95 %
    assert "a world-frame force appeared, 1.5 ±" in e["line"] and "along -y -- looks like world_force" in e["line"]
    # the residual is logged, and it leaves the noise at the onset
    z, t = r.trace["monitor_z"], r.trace["t_s"]
    assert np.nanmax(np.abs(z[(t > 0.5) & (t < 2.0)])) < 6.0 < np.nanmax(np.abs(z[(t > 2.0) & (t < 2.01)]))


def test_payload_is_named_with_its_mass():
    cfg, r = _run(["effects.tool_gravity.enabled=true", "effects.tool_gravity.onset_s=2.5"])
    evs = r.summary["monitor"]["events"]
    assert [e["shape"] for e in evs] == ["tool_gravity"], [e["line"] for e in evs]
    est = evs[0]["estimate"]
    assert abs(est["mass_kg"] - cfg.effects.tool_gravity.mass_kg) <= 1.96 * est["mass_sd_kg"]
    assert est["mass_sd_kg"] < 0.01


def test_follow_gives_the_same_event_and_skips_bad_rows(tmp_path, snag):
    """The run's samples written to a CSV as it grows, with a truncated line, a NaN and a row whose column
    disappeared: one line each, the event as the live monitor named it."""
    cfg, r = snag
    tr = r.trace
    lines = csv_text(tr["t_s"], tr["q_rad"], tr["qdot_rad_s"], tr["wrench_raw_f"]).splitlines(keepends=True)
    path = tmp_path / "log.csv"
    path.write_text("".join(lines[:800]))
    said = []
    fol = Follower(path, setup_of_run(cfg), cfg.monitor, say=said.append)
    fol.poll()
    with open(path, "a") as fh:
        fh.write(lines[800][:25])  # the writer stops mid-line ...
    fol.poll()  # ... the partial line waits
    assert said == [] and fol.n_bad == 0
    with open(path, "a") as fh:
        fh.write("\n")  # ... and goes on with the next
        f = lines[801].split(",")
        fh.write(",".join(f[:5] + ["nan"] + f[6:]))
        fh.write(",".join(lines[802].split(",")[:-1]) + "\n")  # the last column is gone
        fh.writelines(lines[803:])
    events = fol.run(idle_stop_s=0.0)
    assert fol.n_bad == 3 and len(said) == 3, said
    assert f"line 801 has {len(lines[800][:25].split(','))} fields" in said[0] and "truncated" in said[0]
    assert "line 802: column 'q5' is not a finite number" in said[1]
    assert "line 803 has 20 fields, the header 21" in said[2]
    assert all(s.count("\n") == 0 for s in said)
    assert fol.n_good == len(lines) - 1 - 3
    live = r.summary["monitor"]["events"]
    assert [e.shape for e in events] == [e["shape"] for e in live]
    assert abs(events[0].t_s - live[0]["t_s"]) < 0.003


def test_follow_parquet_row_groups(tmp_path, snag):
    """A Parquet log re-written with more row groups at each poll; a version without a column: said, skipped."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    cfg, r = snag
    tr = r.trace
    names = ["t", *(f"q{j}" for j in range(1, 8)), *(f"qd{j}" for j in range(1, 8)), "fx", "fy", "fz", "tx", "ty", "tz"]
    data = np.column_stack([tr["t_s"], tr["q_rad"], tr["qdot_rad_s"], tr["wrench_raw_f"]])
    path = tmp_path / "log.parquet"

    def write(upto: int, drop: str | None = None) -> None:
        cols = [n for n in names if n != drop]
        with pq.ParquetWriter(path, pa.schema([(n, pa.float64()) for n in cols])) as w:
            for a in range(0, upto, 1000):
                part = data[a:min(a + 1000, upto)]
                w.write_table(pa.table({n: part[:, names.index(n)] for n in cols}))

    said = []
    write(2000)
    fol = Follower(path, setup_of_run(cfg), cfg.monitor, say=said.append)
    fol.poll()
    assert fol.n_good == 2000
    write(len(data))
    fol.poll()
    assert fol.n_good == len(data) and said == []
    assert [e.shape for e in fol.monitor.finish()] == ["world_force"]
    fol2 = Follower(path, setup_of_run(cfg), cfg.monitor, say=said.append)
    fol2.poll()
    write(len(data) + 0, drop="fy")  # the same rows again, without fy: the new row groups lack it
    fol2.src.done = 3  # (as if groups 3.. were new)
    fol2.poll()
    assert any("column 'fy' is missing" in s for s in said)


def test_monitor_takes_the_samples_only(snag):
    """The same samples replayed through a new monitor (kinematics from the arm model, not the
    controller's) give the same event: the monitor depends on the samples alone, never the truth."""
    cfg, r = snag
    tr = r.trace
    from kinadapt_nn.diagnostics.physical import ArmModel

    setup = setup_of_run(cfg)
    arm = ArmModel(setup)
    R, x, Jp, Jr = arm._frames(tr["q_rad"])  # noqa: SLF001
    v = np.einsum("nij,nj->ni", Jp, tr["qdot_rad_s"])
    w = np.einsum("nij,nj->ni", Jr, tr["qdot_rad_s"])
    mon = Monitor(setup, cfg.monitor, cfg.run.dt_s)
    for k, t in enumerate(tr["t_s"]):
        mon.sample(float(t), R[k], x[k], v[k], w[k], tr["wrench_raw_f"][k])
    evs = mon.finish()
    live = r.summary["monitor"]["events"][0]
    assert [e.shape for e in evs] == ["world_force"]
    np.testing.assert_allclose(evs[0].estimate["force_w_N"], live["estimate"]["force_w_N"], atol=5e-3)


def test_cli_online_monitor_prints_and_writes_the_event(tmp_path, capsys):
    out = tmp_path / "run"
    rc = main(["online", "--config", str(REPO / "online" / "monitor.toml"), "--monitor", "--out", str(out),
               "--set", "effects.world_force.enabled=true", "--set", "effects.world_force.onset_s=3.21",
               "--set", "run.tensorboard=true", "--set", "run.progress=false"])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    assert "3.21 s: a world-frame force appeared, 1.5 ±" in cap.out and "looks like world_force" in cap.out
    summ = json.loads((out / "summary.json").read_text())
    assert summ["monitor"]["events"][0]["shape"] == "world_force"
    z = np.load(out / "trace.npz")
    assert z["monitor_z"].shape == (len(z["t_s"]), 6)
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    acc = EventAccumulator(str(out / "tb"), size_guidance={"tensors": 0, "scalars": 0})
    acc.Reload()
    assert "monitor/residual_over_noise_F_y" in acc.Tags()["scalars"]
    texts = acc.Tensors("monitor/events")
    assert len(texts) == 1 and 3210 <= texts[0].step <= 3215
    assert b"looks like world_force" in texts[0].tensor_proto.string_val[0]


def test_cli_follow_needs_a_setup(capsys, tmp_path):
    p = tmp_path / "log.csv"
    p.write_text("t\n")
    rc = main(["diagnose", str(p), "--follow"])
    err = capsys.readouterr().err
    assert rc == 2 and err.startswith("kinadapt: error: --follow needs --setup") and err.count("\n") == 1


def test_monitor_config_is_validated():
    from kinadapt_nn.errors import ConfigError

    with pytest.raises(ConfigError, match="monitor.false_alarms_per_h"):
        load_config(None, ["monitor.false_alarms_per_h=0"])
    assert MonitorCfg().false_alarms_per_h == 0.1


@pytest.mark.slow
def test_agreement_with_the_offline_diagnosis_on_a_payload():
    """At the end of a run the monitor's open event and ``kinadapt diagnose`` of the run from the event's
    onset on name the same effect (the offline diagnosis takes its effects as present throughout: it
    judges the log from the change on): the payload, and besides it at most what the event implies
    (its inertia: ``agreement.implied_names``, the point-mass bound of the estimate), which the diagnosis
    confirms where the window's accelerations pin it."""
    from kinadapt_nn.monitor.agreement import implied_names
    from kinadapt_nn.diagnostics.ownrun import log_of_run
    from kinadapt_nn.diagnostics.userlog import diagnose

    cfg, r = _run(["effects.tool_gravity.enabled=true", "effects.tool_gravity.onset_s=2.0"])
    ev = [e for e in r.summary["monitor"]["events"] if e["open"]]
    assert [e["shape"] for e in ev] == ["tool_gravity"]
    tr = r.trace
    m = tr["t_s"] > ev[0]["onset_s"] + 0.01
    from types import SimpleNamespace

    raw = SimpleNamespace(t_s=tr["t_s"][m], q_rad=tr["q_rad"][m], qdot_rad_s=tr["qdot_rad_s"][m],
                          wrench_raw_f=tr["wrench_raw_f"][m], source="payload run after the event")
    rep = diagnose(log_of_run(raw), setup_of_run(cfg), progress=lambda msg: None)
    present = [e["effect"] for e in rep.report["ranking"] if e["verdict"] == "present"]
    implied = [n.split(":")[1] for n in implied_names(ev[0])]
    assert implied == ["tool_inertia"]  # 0.5 kg at its centre: beyond tool_inertia's relevant size
    assert "tool_gravity" in present and set(present) <= {"tool_gravity", *implied}, present


def _rest_monitor(rotation_test: bool):
    """A monitor of the scenario's set-up fed samples at rest (the sensor axes the world's, 0.3 m above the
    fixture's entrance: free space)."""
    from kinadapt_nn.diagnostics.physical import nominal_inertials

    cfg = load_config(REPO / "online/monitor.toml", QUIET)
    setup = setup_of_run(cfg)
    mcfg = cfg.monitor.model_copy(update={"rotation_test": rotation_test})
    mon = Monitor(setup, mcfg, cfg.run.dt_s)
    m, mc, _ = nominal_inertials(setup)
    g = np.asarray(setup.world.g_w())
    w = np.concatenate([m * g, np.cross(mc, g)])  # the declared tool's wrench at rest, s = world axes
    p = mon.c[K.C_ENTRY:K.C_ENTRY + 3] + 0.3 * mon.c[K.C_UP:K.C_UP + 3]
    return mon, w, float(setup.log.sign), cfg.run.dt_s, p


def test_rotation_test_fires_within_two_blocks():
    """A sensor turned by delta reads w + w x delta: with the tool hanging, 1.41 deg about x moves the
    force by |F| delta = 1.2 noise sd on one channel, under the CUSUM's reference (1.5 sd). The rotation
    GLR grows by 1.2^2 / 2 nats a sample, past its threshold (``rotation_threshold``: chi^2_3 at 0.1 an
    hour over the windows, about 18 nats) after some 25 samples: it fires within its first two blocks
    (100 samples) of the turn. Before the turn, 3 s of noise give no alarm."""
    from scipy.stats import chi2

    mon, w, sign, dt, p = _rest_monitor(True)
    windows = 3600.0 / dt / K.ROT_BLK * K.ROT_NB
    assert abs(mon.c[K.C_HROT] - 0.5 * chi2.isf(0.1 / windows, 3)) < 1e-9
    assert 17.0 < mon.c[K.C_HROT] < 19.0
    sd = np.array([0.02] * 3 + [0.002] * 3)
    rng = np.random.default_rng(3)
    t_on, fired = 3.0, None
    eye, zero = np.eye(3), np.zeros(3)
    turn = np.array([0.0246, 0.0, 0.0])  # [rad] 1.41 deg about x
    z = np.linalg.norm(np.cross(w[:3], turn)) / 0.02
    assert 1.0 < z < 1.4  # what the turn shows: under the CUSUM's reference
    for k in range(6000):
        t = k * dt
        d = turn if t >= t_on else np.zeros(3)
        r = np.concatenate([w[:3] + np.cross(w[:3], d), w[3:] + np.cross(w[3:], d)])
        if mon.sample(t, eye, p, zero, zero, sign * (r + sd * rng.standard_normal(6))) == K.R_ALARM:
            fired = t
            break
    assert not mon.in_contact
    assert fired is not None and t_on <= fired <= t_on + 2 * K.ROT_BLK * dt, fired
    assert mon.st[K.S_RFIRED] == 1.0  # the rotation test, not the CUSUM


def _tilting_run(mon, w_of, sign, dt, p, change, t_on=3.0, t_end=7.0):
    """Feed ``mon`` a tool that tilts about the world x axis (0.35 rad amplitude, 4 s period, from 0.5 s;
    the sensor's origin fixed, its axes the world's at rest) with white noise at 0.02 N / 0.002 N m, and
    ``change(r) -> reading`` applied from ``t_on``. The reading of each sample belongs to the previous
    sample's pose with the angular acceleration between the two (the kernel's convention)."""
    rng = np.random.default_rng(5)
    sd = np.array([0.02] * 3 + [0.002] * 3)
    zero = np.zeros(3)
    ang = lambda t: 0.35 * np.sin(2 * np.pi * (t - 0.5) / 4.0) if t > 0.5 else 0.0  # noqa: E731
    rate = lambda t: 0.35 * 2 * np.pi / 4.0 * np.cos(2 * np.pi * (t - 0.5) / 4.0) if t > 0.5 else 0.0  # noqa: E731
    prev = None
    for k in range(int(round(t_end / dt))):
        t = k * dt
        c, s = np.cos(ang(t)), np.sin(ang(t))
        R = np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
        om_w = np.array([rate(t), 0.0, 0.0])
        if prev is None:
            r = w_of(R, om_w, zero)
        else:
            R0, om0 = prev
            r = w_of(R0, om0, (om_w - om0) / dt)
        if t >= t_on:
            r = change(r)
        mon.sample(t, R, p, zero, om_w, sign * (r + sd * rng.standard_normal(6)))
        prev = (R, om_w)
    mon.finish()
    return mon.events


def _tool_wrench(setup):
    """The declared tool's Newton-Euler wrench at the sensor, s, for a sensor at rest in position: an
    independent numpy form of ``docs/monitor.md``'s model. -> w_of(R_ws, omega_w, alpha_w) (6,)."""
    from kinadapt_nn.diagnostics.physical import nominal_inertials

    m, mc, I_O = nominal_inertials(setup)
    g_w = np.asarray(setup.world.g_w())

    def w_of(R, om_w, al_w):
        g, om, al = R.T @ g_w, R.T @ om_w, R.T @ al_w
        F = m * g - np.cross(al, mc) - np.cross(om, np.cross(om, mc))
        M = np.cross(mc, g) - I_O @ al - np.cross(om, I_O @ om)
        return np.concatenate([F, M])
    return w_of


def test_a_turned_mount_is_named_and_a_bias_step_is_not_relevant():
    """With the tool tilting by 0.35 rad (20 deg), a sensor mount turned by 2 deg (1.41 deg about x and z)
    changes the reading by at most 1.2 noise sd a sample, but the turn of the reading tells it from a
    constant: the monitor (its rotation test on by default) names ``ft_frame_rotation`` and its 95 %
    region (chi^2_3) holds the turn. A 0.03 N bias step in F_y instead -- the same size on the reading,
    but a constant, below the offline diagnosis's relevant ``ft_offset`` (0.2 N) -- is no rotation
    event (``shapes.relevance``: the turn's 1.99 deg is 1.99 relevant sizes of 1 deg)."""
    from kinadapt_nn.monitor import shapes

    mon, _, sign, dt, p = _rest_monitor(MonitorCfg().rotation_test)
    w_of = _tool_wrench(mon.setup)
    turn = np.deg2rad([1.41, 0.0, 1.41])
    evs = _tilting_run(mon, w_of, sign, dt, p,
                       lambda r: np.concatenate([r[:3] + np.cross(r[:3], turn), r[3:] + np.cross(r[3:], turn)]))
    assert [e.shape for e in evs] == ["ft_frame_rotation"], [e.line for e in evs]
    est = evs[0].estimate
    d = np.asarray(est["rotvec_deg"]) - np.rad2deg(turn)
    assert d @ np.linalg.solve(np.asarray(est["rotvec_cov_deg2"]), d) <= 7.815  # chi^2_3 at 95 %
    assert 3.0 <= evs[0].t_s <= 3.2  # caught within 0.2 s
    f = shapes.Fit("ft_frame_rotation", turn, np.eye(3), 0.0, 0.0, 1)
    assert abs(shapes.relevance(f, 0.2) - np.hypot(1.41, 1.41)) < 1e-9  # the angle in degrees over 1 deg

    mon, _, sign, dt, p = _rest_monitor(MonitorCfg().rotation_test)
    step = np.array([0.0, 0.03, 0.0, 0.0, 0.0, 0.0])
    evs = _tilting_run(mon, w_of, sign, dt, p, lambda r: r + step)
    assert all(e.shape != "ft_frame_rotation" for e in evs), [e.line for e in evs]


def test_naming_sd_widens_a_channel_by_the_models_slow_error():
    """``Monitor._naming_sd``: over the 2 s before a change, a channel whose residual carries a slow error
    (+-a, switching every 0.1 s block) besides white noise is named with sd ``sqrt(sd^2 + k var)``, var
    the variance of its block means beyond the noise's ``sd^2 / k`` (k = 100 samples: here ``a^2 n / (n -
    1)`` over n = 20 blocks, to the noise's share); a channel of white noise alone keeps its sd but for
    its chance excess: within ``sqrt(chi^2_19 at 0.99 / 19)`` of it (each with chance 0.99; seed 1)."""
    mon, _, _, dt, _ = _rest_monitor(True)
    sd = np.array([0.02] * 3 + [0.002] * 3)
    mon.st[K.S_SD:K.S_SD + 6] = sd
    k, n, a = 100, 20, 0.001
    rng = np.random.default_rng(1)
    rows = n * k
    t = 1.0 + dt * np.arange(rows)
    e = sd * rng.standard_normal((rows, 6))
    e[:, 5] += a * np.repeat(np.where(np.arange(n) % 2 == 0, 1.0, -1.0), k)
    mon.ring[:rows, K.G_T], mon.ring[:rows, K.G_E:K.G_E + 6], mon.ring[:rows, K.G_FREE] = t, e, 1.0
    mon.st[K.S_HEAD], mon.st[K.S_COUNT] = rows, rows
    got = mon._naming_sd(float(t[-1]))  # noqa: SLF001
    want = np.sqrt(sd[5] ** 2 + k * a ** 2 * n / (n - 1))
    assert abs(got[5] / want - 1.0) < 0.05, (got[5], want)
    from scipy.stats import chi2

    assert np.all(got[:5] >= sd[:5]) and np.all(got[:5] <= sd[:5] * np.sqrt(chi2.ppf(0.99, n - 1) / (n - 1))), got / sd
